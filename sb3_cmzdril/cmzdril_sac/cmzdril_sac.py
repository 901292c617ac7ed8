"""CMZDRILSAC: SB3's SAC with CMZ-DRIL's demonstrations, ensemble and reward, off-policy.

The same imitation machinery as :class:`~sb3_cmzdril.cmzdril.CMZDRIL` (the part both share:
:class:`~sb3_cmzdril.common.imitation.ImitationLearner`), with SAC in place of PPO,
as the off-policy imitation learners do it (SQIL, Reddy et al. 2020; DAC, Kostrikov et al. 2019):

1. Pretrain the actor by behaviour cloning: squared error between its deterministic action and the
   expert's (both in SAC's [-1, 1] action scale), early-stopped on held-out demo steps, on inputs
   standardised with the demos' statistics. Then fit the bootstrap ensemble on the same demos.
2. Collect with the actor from the first step (no uniformly random warm-up: the clone is the
   starting point). Each collected step's disagreement ``u`` advances the reward rule's state (the
   CMZ reward's EMA, the highest u seen).
3. Every SAC batch holds ``demo_fraction`` demonstration transitions; every sampled transition,
   the agent's and the expert's, gets its reward from the rule at sampling time
   (:class:`~sb3_cmzdril.cmzdril_sac.demo_replay.DemoReplayBuffer`). A true termination (never a time limit) can be
   scored as entering an absorbing state, as in CMZDRIL: at the highest u seen, or at the u of the
   observation the episode ended in (``absorbing_score``).
4. The actor's loss is SAC's with Q divided by the batch's mean |Q| (at least 1) and multiplied by
   ``q_weight``, plus ``bc_weight`` times the BC loss of a demo minibatch: TD3+BC's form (Fujimoto
   and Gu 2021), which keeps the two terms on one scale whatever the reward's. BC as separate optimiser steps (DRIL's
   way with PPO) lost the clone here: Adam moves every parameter by about its learning rate whatever
   the size of the gradient, so a critic that knows nothing yet walks the actor away from the demos
   between two BC steps (on Walker2d-v5 the agent soon fell at once, even with no reward at all).
5. Optionally (``critic_warmup_steps``), the first gradient steps train the critics alone: they
   learn the clone's values before the actor follows them, as offline-to-online methods warm up a
   critic before they let it move a pretrained policy.

Flat ``Box`` observations and ``Box`` actions (SAC's). Saving keeps the policy, the ensemble, the BC
optimiser, the demonstrations and the reward rule's state; the replay buffer is SB3's to save
(``save_replay_buffer``), the demonstrations are mixed in again at every ``learn()``.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.sac.policies import SACPolicy
from torch.nn import functional as F

from sb3_cmzdril.cmzdril_sac.demo_replay import DemoReplayBuffer, DemoTransitions
from sb3_cmzdril.common.bc import BehaviourCloner, TensorObs
from sb3_cmzdril.common.imitation import (
    DemosLike,
    ImitationLearner,
    arguments_for,
    disagreement_where_ended,
    made_env,
)
from sb3_cmzdril.common.options import check_interval, check_whole_numbers
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError, check_finite
from sb3_cmzdril.rewards import with_absorbing_state

SelfCMZDRILSAC = TypeVar("SelfCMZDRILSAC", bound="CMZDRILSAC")


class ScaledActionMSE:
    """BC loss of a SAC actor: squared error, summed over action dimensions, between its
    deterministic (tanh-squashed) action and the expert's, rescaled from the space's bounds to
    [-1, 1] and clipped there. A squashed Gaussian's likelihood is unbounded at the bounds, where
    experts often act (Walker2d's saturate), so the actor's mean is fitted, not its likelihood.

    :param action_space: the Box the expert's actions live in.
    :param device: where the bounds go.
    """

    def __init__(self, action_space: spaces.Box, device: th.device) -> None:
        self.low = th.as_tensor(action_space.low.reshape(-1), dtype=th.float32, device=device)
        self.high = th.as_tensor(action_space.high.reshape(-1), dtype=th.float32, device=device)

    def __call__(self, actor: Any, obs: TensorObs, actions: th.Tensor) -> th.Tensor:
        target = (2.0 * (actions - self.low) / (self.high - self.low) - 1.0).clamp(-1.0, 1.0)
        return ((actor(obs, deterministic=True) - target) ** 2).sum(dim=1)


def _check_sac_options(
    buffer_size: Any, learning_starts: Any, batch_size: Any, train_freq: Any, gradient_steps: Any,
    target_update_interval: Any, ent_coef: Any, target_entropy: Any,
) -> None:
    """UserError, in one line, for the SAC settings SB3 accepts but cannot learn with, or makes
    something else of: ``gradient_steps=0`` (no update: the clone would be reported as the result),
    ``buffer_size=0`` (a buffer of one transition), a ``batch_size``, ``train_freq`` or
    ``target_update_interval`` below 1 (fails once training runs), a negative ``learning_starts``,
    and an ``ent_coef`` or ``target_entropy`` string SAC cannot read (an assertion or a ValueError
    with a traceback). ``gradient_steps=-1`` is SB3's "as many as the env steps collected"."""
    check_whole_numbers(1, buffer_size=buffer_size, batch_size=batch_size,
                        target_update_interval=target_update_interval)
    check_whole_numbers(0, learning_starts=learning_starts)
    if not (isinstance(gradient_steps, (int, np.integer)) and not isinstance(gradient_steps, bool)
            and (gradient_steps >= 1 or gradient_steps == -1)):
        raise UserError(f"gradient_steps must be a whole number >= 1, or -1 for as many as the env steps collected, "
                        f"got {gradient_steps!r}")
    pair = isinstance(train_freq, (tuple, list)) and len(train_freq) == 2
    frequency, unit = train_freq if pair else (train_freq, "step")
    check_whole_numbers(1, train_freq=frequency)
    if unit not in ("step", "episode"):
        raise UserError(f"train_freq's unit must be 'step' or 'episode', got {unit!r}")
    if isinstance(ent_coef, str):
        head, underscore, initial = ent_coef.partition("_")
        value = _read_number(initial if head == "auto" else ent_coef)
        if head == "auto":  # learnt, from 1 or from the value after "auto_"
            valid = not underscore or (value is not None and value > 0)
        else:
            valid = value is not None and value >= 0
        if not valid:
            raise UserError(f"ent_coef must be a number >= 0, 'auto' or 'auto_<initial value > 0>', got {ent_coef!r}")
    else:
        check_interval("[0, inf)", ent_coef=ent_coef)
    if isinstance(target_entropy, str) and target_entropy != "auto" and _read_number(target_entropy) is None:
        raise UserError(f"target_entropy must be a number or 'auto', got {target_entropy!r}")


def _read_number(text: str) -> float | None:
    """The finite number ``text`` spells (as SAC's ``float()`` reads it), else None."""
    try:
        value = float(text)
    except ValueError:
        return None
    return value if np.isfinite(value) else None


#: The actor's and critics' layers when ``policy_kwargs`` is not given: the ensemble members' size (SAC's
#: default is 256x256), what the command line's shipped settings were chosen with.
DEFAULT_POLICY_KWARGS: dict[str, Any] = {"net_arch": [64, 64]}


class CMZDRILSAC(ImitationLearner, SAC):
    """SAC trained on CMZ-DRIL's disagreement reward, with the demonstrations in every batch and
    BC steps on them (see the module's docstring).

    SAC's arguments (``learning_rate`` ... ``device``) mean what they mean for
    :class:`stable_baselines3.SAC`; the defaults are SAC's except ``ent_coef`` (below).
    ``optimize_memory_usage`` must stay False and ``n_steps`` 1: the replay buffer that mixes in the
    demonstrations keeps next observations apart and samples one-step transitions.
    The imitation arguments mean what they mean for :class:`~sb3_cmzdril.cmzdril.CMZDRIL`:

    :param demonstrations: a :class:`~sb3_cmzdril.data.demos.Demonstrations`, a path to a saved one, or a
        list of episode dicts. Required before the first ``learn()``.
    :param reward: ``"cmz"``, ``"dril"``, ``"zero"`` or ``"env"`` (the true reward; the demos must have
        recorded it when ``demo_fraction`` > 0).
    :param alpha: CMZ reward scale (paper: 10).
    :param ema: CMZ EMA factor (paper: 0.99), over the agent's collected steps.
    :param u0: initial EMA value (paper: 0).
    :param dril_quantile: DRIL threshold quantile of u on the demos.
    :param cmz_clip_quantile: clip u in the ``"cmz"`` reward at this quantile of u on the demos (default
        0.98; None: no clip). Clipped, the reward is bounded as DRIL's is, and so is the absorbing state's value
        (the reward at the highest u seen, for ever): unclipped, one far-off state sets it.
    :param disagreement: ``"std"``, ``"quadratic"``, ``"std_unclipped"`` (Box actions) or ``"auto"`` (the
        default: unclipped where the demonstrations' actions hold a bound; see :mod:`sb3_cmzdril.ensemble`).
    :param ensemble_size: number of ensemble members.
    :param ensemble_hidden: hidden layer widths of each member.
    :param ensemble_epochs: epochs of ensemble fitting.
    :param ensemble_batch_size: minibatch size of ensemble fitting.
    :param ensemble_learning_rate: Adam step size of ensemble fitting.
    :param standardize_observations: actor and critics see observations standardised with fixed
        statistics of the demonstrations; ``"auto"``: only the entries the observation space leaves
        unbounded (as :class:`~sb3_cmzdril.CMZDRIL`'s).
    :param demo_fraction: share of every SAC batch drawn from the demonstrations (in [0, 1)).
    :param bc_pretrain_epochs: most BC epochs before RL (early-stopped as CMZDRIL's).
    :param bc_validation_fraction: share of demo steps held out to stop pretraining.
    :param bc_patience: epochs without improvement before pretraining stops.
    :param bc_weight: weight of the BC loss (on a demo minibatch of ``bc_batch_size``) in the actor's
        loss; 0 gives SAC's own actor loss, unscaled.
    :param q_weight: in the actor's loss Q is divided by the batch's mean |Q| (at least 1) and
        multiplied by this (TD3+BC's alpha, 2.5) when ``bc_weight`` > 0.
    :param bc_batch_size: minibatch size of BC.
    :param bc_learning_rate: Adam step size of BC pretraining (its own optimiser; during SAC the BC
        term is part of the actor's loss and steps with the actor's optimiser).
    :param critic_warmup_steps: the first this many gradient steps (counted over the model's life, so
        a resumed run does not warm up again) update the critics only: the actor and the temperature
        stay as pretraining left them while the critics learn the clone's values from its collected
        steps and the demos. 0 (the default): the actor learns from the first update.
    :param log_std_init: after pretraining (which fits only the actor's mean), the actor's log-std
        head outputs this constant until SAC learns it (None keeps its initialisation, about 0:
        a standard deviation of 1 before the tanh, which buries the clone in noise).
    :param absorbing: score a true termination as entering an absorbing state at the highest u seen
        so far (``True``, the default, ``False`` or ``"auto"``: the ``"cmz"`` reward, where every demonstration
        lasts the env's time limit), as :class:`~sb3_cmzdril.cmzdril.CMZDRIL` does.
    :param absorbing_score: the absorbing state's disagreement: ``"highest"``, the highest u seen so
        far (every termination as bad as the worst state met); ``"terminal"``, the ensemble's u at the
        observation the episode ended in (for the actor's action there where the disagreement needs
        actions), so that ending as the expert ends (a landing, a goal reached) stays worth what the
        state it ends in is worth, and a crash what staying in the crashed state would be. Where the
        expert ends its episodes, ``"highest"`` makes every ending, the expert's own included, the
        worst outcome, and no absorbing state makes it free under the mean-zero reward.
    :param buffer_size: replay buffer size (default 200,000: every step of the shipped budgets, without
        SB3's million transitions held and pickled with every checkpoint).
    :param policy_kwargs: SB3's; None gives :data:`DEFAULT_POLICY_KWARGS` (64x64 layers).
    :param ent_coef: SAC's entropy coefficient; ``"auto_0.01"`` by default (learnt, from 0.01)
        rather than SAC's ``"auto"`` (from 1.0), which spreads a cloned actor's actions before the
        critic has learnt anything.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = SAC.policy_aliases
    learner_name = "CMZDRILSAC"
    off_policy = True
    default_policy_kwargs = DEFAULT_POLICY_KWARGS

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        demonstrations: DemosLike = None,
        reward: str = "cmz",
        alpha: float = 10.0,
        ema: float = 0.99,
        u0: float = 0.0,
        dril_quantile: float = 0.98,
        cmz_clip_quantile: float | None = 0.98,
        disagreement: str = "auto",
        ensemble_size: int = 5,
        ensemble_hidden: Sequence[int] = (64, 64),
        ensemble_epochs: int = 200,
        ensemble_batch_size: int = 64,
        ensemble_learning_rate: float = 1e-3,
        standardize_observations: bool | str = True,
        demo_fraction: float = 0.25,
        bc_pretrain_epochs: int = 1000,
        bc_validation_fraction: float = 0.2,
        bc_patience: int = 20,
        bc_weight: float = 1.0,
        q_weight: float = 2.5,
        bc_batch_size: int = 256,
        bc_learning_rate: float = 1e-3,
        critic_warmup_steps: int = 0,
        log_std_init: float | None = -1.0,
        absorbing: bool | str = True,
        absorbing_score: str = "highest",
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 200_000,
        learning_starts: int = 100,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        ent_coef: str | float = "auto_0.01",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        use_sde_at_warmup: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if isinstance(cmz_clip_quantile, str):
            raise UserError(f"CMZDRILSAC's cmz_clip_quantile is a quantile in (0, 1] or None, got "
                            f"{cmz_clip_quantile!r} ('auto' reads the clone's episodes before PPO's first rollout: "
                            "CMZDRIL's rule)")
        self._init_imitation(**arguments_for(self._init_imitation, locals()))
        check_finite(
            demo_fraction=demo_fraction, bc_learning_rate=bc_learning_rate, bc_weight=bc_weight, q_weight=q_weight,
            log_std_init=log_std_init, learning_rate=learning_rate, tau=tau, gamma=gamma, ent_coef=ent_coef,
            target_entropy=target_entropy,
        )
        if not (bc_weight >= 0 and q_weight > 0):
            raise UserError(f"bc_weight must be >= 0 and q_weight > 0, got {bc_weight} and {q_weight}")
        if isinstance(critic_warmup_steps, bool) or not isinstance(critic_warmup_steps, (int, np.integer)) \
                or critic_warmup_steps < 0:
            raise UserError(f"critic_warmup_steps must be a whole number >= 0, got {critic_warmup_steps!r}")
        _check_sac_options(buffer_size, learning_starts, batch_size, train_freq, gradient_steps,
                           target_update_interval, ent_coef, target_entropy)
        check_interval("(0, 1]", tau=tau)
        check_interval("[0, 1]", gamma=gamma)
        check_interval("(0, inf)", learning_rate=learning_rate)
        if not 0.0 <= demo_fraction < 1.0:
            raise UserError(f"demo_fraction must lie in [0, 1), got {demo_fraction}")
        if optimize_memory_usage:
            raise UserError("optimize_memory_usage=True is not supported: the demo-mixing replay buffer keeps each "
                            "next observation apart; leave it False")
        if n_steps != 1:
            raise UserError(f"n_steps must be 1, got {n_steps!r}: the demo-mixing replay buffer samples one-step "
                            "transitions (SB3's n-step returns need its NStepReplayBuffer)")
        if replay_buffer_class is None:
            replay_buffer_class = DemoReplayBuffer
        elif not (isinstance(replay_buffer_class, type) and issubclass(replay_buffer_class, DemoReplayBuffer)):
            raise UserError(
                f"replay_buffer_class must be a DemoReplayBuffer (or a subclass), got {replay_buffer_class}"
            )
        self.demo_fraction = float(demo_fraction)
        self.bc_weight = float(bc_weight)
        self.q_weight = float(q_weight)
        if callable(bc_learning_rate) or isinstance(bc_learning_rate, str):  # e.g. a YAML 'lin_1e-3'
            raise UserError(f"CMZDRILSAC's bc_learning_rate is a number (its BC optimiser runs only before SAC), "
                            f"got {bc_learning_rate!r}")
        self.bc_learning_rate = float(bc_learning_rate)
        self.critic_warmup_steps = int(critic_warmup_steps)
        self.log_std_init = None if log_std_init is None else float(log_std_init)
        self._u_sum, self._u_count = 0.0, 0
        env = made_env(env, verbose)
        if policy_kwargs is None:
            policy_kwargs = dict(self.default_policy_kwargs)
        super().__init__(**arguments_for(SAC.__init__, locals(), _init_setup_model=False))
        if _init_setup_model:
            self._setup_model()

    # -- the imitation part's hooks ---------------------------------------------------------------
    def _check_learner_spaces(self) -> None:
        if not isinstance(self.observation_space, spaces.Box) or len(self.observation_space.shape) != 1:
            raise UserError(
                f"CMZDRILSAC takes flat Box observations, got {self.observation_space}; CMZDRIL (PPO) takes any"
            )

    def _make_cloner(self, seed: int) -> BehaviourCloner:
        assert isinstance(self.action_space, spaces.Box)  # SAC refuses any other
        return BehaviourCloner(
            self.actor, self.bc_batch_size, self.bc_learning_rate, max_grad_norm=10.0, seed=seed,
            loss=ScaledActionMSE(self.action_space, self.device),
        )

    def _check_demonstrations(self, demos: Demonstrations) -> None:
        if self.reward == "env" and self.demo_fraction > 0 and demos.rewards is None:
            raise UserError("reward='env' replays the demonstrations with their rewards, and these have none; "
                            "set demo_fraction=0 or record the demos with rewards")

    def _pretrain_policy(self, progress_bar: bool) -> dict[str, float]:
        """Standardise the inputs by the demos (the actor's, the critic's and the target critic's) and
        clone them into the actor (early stopping on held-out steps); the loss, best epoch and time it
        took. The clone's inputs are the raw observations, VecNormalize or not."""
        self._fit_standardizers()
        start = time.perf_counter()
        stopping = self.bc.train_early_stopping(
            self.bc_pretrain_epochs, self.bc_validation_fraction, self.bc_patience, progress_bar=progress_bar
        )
        if self.log_std_init is not None:
            head = self.actor.log_std
            if isinstance(head, th.nn.Linear):  # gSDE's log_std is a parameter of another meaning
                with th.no_grad():
                    head.weight.zero_()
                    head.bias.fill_(self.log_std_init)
        self.pretrain_history = {"train_nll": stopping.train_nll, "validation_nll": stopping.validation_nll}
        return {
            "bc_loss": self.bc.nll(),
            "bc_best_epoch": float(stopping.best_epoch),
            "bc_seconds": time.perf_counter() - start,
        }

    def _cloning_summary(self, info: dict[str, float]) -> str:
        return f"BC loss {info['bc_loss']:.4g} (best epoch {int(info['bc_best_epoch'])}, {info['bc_seconds']:.1f}s)"

    # -- training ---------------------------------------------------------------------------------
    def learn(self: SelfCMZDRILSAC, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "CMZDRILSAC", reset_num_timesteps: bool = True,
              progress_bar: bool = False) -> SelfCMZDRILSAC:
        """SAC's ``learn``, after pretraining if the model is not :attr:`pretrained` yet."""
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, progress_bar)

    def _prepare_learning(self, progress_bar: bool) -> None:
        if not self._imitation_ready:
            self.pretrain()
        assert self.demonstrations is not None and self.env is not None
        self.absorbing_active = self.reward != "env" and self._absorbing_applies()
        buffer = self.replay_buffer
        if not isinstance(buffer, DemoReplayBuffer):  # e.g. load_replay_buffer() of a plain SB3 buffer
            raise UserError(f"CMZDRILSAC needs a DemoReplayBuffer, got a {type(buffer).__name__}")
        demos = None
        if self.demo_fraction > 0:
            demos = DemoTransitions(self.demonstrations, self.policy.scale_action)
            demos.disagreements = self._disagreement(demos.observations, demos.actions)
        buffer.set_demonstrations(demos, self.demo_fraction, self._replay_rewards)

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        # The pretrained actor collects from the first step: uniformly random actions would fill the
        # buffer with falls that say nothing about the clone. learning_starts still delays updates.
        return super()._sample_action(0, action_noise, n_envs)

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: Any,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        # The observation acted on, raw: SB3 keeps it in _last_original_obs only under VecNormalize.
        acted_on = self._last_original_obs if self._vec_normalize_env is not None else self._last_obs
        assert self.reward_rule is not None and acted_on is not None
        u = self._disagreement(np.asarray(acted_on), buffer_action)
        self.reward_rule(u, reward)  # advances the rule's state (the CMZ EMA) over the agent's steps
        self.reward_rule.highest_u_so_far(u[None])
        self._u_sum += float(u.sum())
        self._u_count += len(u)
        for info, u_i in zip(infos, u, strict=True):
            # The buffer keeps it with the step, so that sampling does not score the step again while
            # the ensemble stays as it is.
            info["disagreement"] = float(u_i)
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    def _disagreement(self, obs: np.ndarray, buffer_actions: np.ndarray) -> np.ndarray:
        actions = self.policy.unscale_action(buffer_actions) if self.ensemble.needs_actions else None
        return self.ensemble.disagreement(obs, actions)

    def _replay_rewards(
        self, obs: np.ndarray, buffer_actions: np.ndarray, env_rewards: np.ndarray, terminated: np.ndarray,
        next_obs: np.ndarray, scored: np.ndarray | None = None,
    ) -> np.ndarray:
        """The reward of each sampled transition (the agent's and the expert's), from the rule now.
        ``scored`` holds the u each was given when it was stored (NaN or None: none); the ensemble
        does not change after pretraining, so that u is the one it would give now."""
        assert self.reward_rule is not None
        if self.reward == "env":
            return env_rewards
        u = np.full(len(obs), np.nan) if scored is None else np.array(scored, dtype=np.float64)
        missing = np.isnan(u)
        if missing.any():  # steps of a buffer saved before steps kept their u
            u[missing] = self._disagreement(obs[missing], buffer_actions[missing])
        rewards = self.reward_rule.replayed(u, env_rewards)
        if self.absorbing_active:
            seen = np.full(u.shape, self.absorbing_u)
            if self.absorbing_score == "terminal" and terminated.any():
                seen[terminated] = disagreement_where_ended(
                    self.ensemble, self.policy, next_obs[terminated], self.action_space, self._vec_normalize_env
                )
            rewards = with_absorbing_state(self.reward_rule, rewards, u, terminated, seen, self.gamma)
        return rewards

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """SAC's update (temperature, twin critics, actor, target critics), with the actor's loss
        TD3+BC's combination of SAC's and BC's (see the module's docstring); during the critics'
        warm-up (``critic_warmup_steps``) the twin critics and their targets only."""
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        self._update_learning_rate(optimizers)
        logs: dict[str, list[float]] = {"ent_coef": [], "actor_loss": [], "critic_loss": [], "bc_loss": []}
        for step in range(gradient_steps):
            warming_up = self._n_updates + step < self.critic_warmup_steps
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            if self.use_sde:
                # New exploration weights each step: the last ones hang on a graph of log_std that the
                # previous actor step has freed (and log_std has moved since).
                self.actor.reset_noise()
            ent_coef = self.ent_coef_tensor if self.log_ent_coef is None else th.exp(self.log_ent_coef.detach())
            if not warming_up:
                actions_pi, log_prob = self.actor.action_log_prob(data.observations)
                log_prob = log_prob.reshape(-1, 1)
                # Temperature: towards the target entropy.
                if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                    target_entropy = float(self.target_entropy)  # SAC's _setup_model resolved "auto"
                    ent_coef_loss = -(self.log_ent_coef * (log_prob + target_entropy).detach()).mean()
                    self.ent_coef_optimizer.zero_grad()
                    ent_coef_loss.backward()
                    self.ent_coef_optimizer.step()

            # Critics: soft Bellman targets from the target critics; no bootstrap after a termination.
            with th.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(data.next_observations)
                next_q = th.min(th.cat(self.critic_target(data.next_observations, next_actions), dim=1), 1, True)[0]
                next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = data.rewards + (1 - data.dones) * self.gamma * next_q
            critic_loss = 0.5 * sum(F.mse_loss(q, target_q) for q in self.critic(data.observations, data.actions))
            assert isinstance(critic_loss, th.Tensor)
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            if not warming_up:
                # Actor: SAC's loss on the critics' scale of one, plus BC on the demos.
                q_pi = th.min(th.cat(self.critic(data.observations, actions_pi), dim=1), 1, True)[0]
                if self.bc_weight > 0:
                    # Q on a scale of q_weight; at least 1 per unit of Q, so that a critic near zero (no
                    # reward yet) does not have its noise magnified.
                    scale = self.q_weight / q_pi.abs().mean().detach().clamp(min=1.0)
                    bc_loss = self.bc.sample_loss()
                    logs["bc_loss"].append(float(bc_loss.detach()))
                    actor_loss = (ent_coef * log_prob - scale * q_pi).mean() + self.bc_weight * bc_loss
                else:
                    actor_loss = (ent_coef * log_prob - q_pi).mean()
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
                self.actor.optimizer.step()
                logs["actor_loss"].append(float(actor_loss.detach()))

            if step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
            logs["ent_coef"].append(float(ent_coef))
            logs["critic_loss"].append(float(critic_loss.detach()))
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, values in logs.items():
            if values:
                self.logger.record(f"train/{key}", float(np.mean(values)))
        if self._u_count:
            self.logger.record("rollout/disagreement_mean", self._u_sum / self._u_count)
            self._u_sum, self._u_count = 0.0, 0
        assert self.reward_rule is not None
        self._log_reward_state(absorbing=self.absorbing_active)


__all__ = ["CMZDRILSAC", "ScaledActionMSE"]
