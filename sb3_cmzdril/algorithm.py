"""CMZDRIL: SB3's PPO with CMZ-DRIL's imitation machinery (paper, Algorithm 1).

On the first ``learn()`` of a model that is not pretrained yet (or an explicit
:meth:`CMZDRIL.pretrain`) the model checks the demonstrations against the env, sets the policy's
input standardisation to the demos' statistics, pretrains the policy by NLL behaviour cloning until
the NLL of held-out demo steps stops improving, and fits the bootstrap ensemble. ``model.pretrained``
says whether that is done; weights that ``load()`` or ``set_parameters()`` bring are kept (see
:attr:`CMZDRIL.pretrained`). Each rollout is then scored from the rollout buffer (:mod:`sb3_cmzdril.scoring`):
the env stack keeps the true reward, so every Monitor, VecMonitor and ``evaluate_policy`` reports the
true return. Every PPO update is followed by ``bc_epochs_per_update`` NLL epochs on the demos.

``reward`` picks the rule, everything else is shared: ``"cmz"`` (the paper), ``"dril"`` (+1/-1 by the
q-quantile threshold), ``"zero"`` (PPO + BC epochs only), ``"env"`` (the true reward). Plain BC is
the pretrained policy (``model.pretrain()`` without ``learn``).

Saving: the zip holds the policy (with its standardisation statistics), the ensemble, the BC
optimiser, the demonstrations (observations, actions, episode lengths, seeds) and the reward rule's
per-env state, so ``CMZDRIL.load(path, env=env)`` can go on learning without being handed the demos
again; ``load(..., demonstrations=...)`` replaces them (other ones refit the ensemble: :meth:`CMZDRIL.load`).
"""
from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    ProgressBarCallback,
    tqdm,  # SB3's (rich) tqdm; None without it, and then SB3 refuses progress_bar=True first
)
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import update_learning_rate
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_cmzdril._mujoco_log import mujoco_warnings_routed
from sb3_cmzdril.bc import BehaviourCloner
from sb3_cmzdril.demos import Demonstrations, as_demonstrations
from sb3_cmzdril.ensemble import BCEnsemble
from sb3_cmzdril.errors import UserError, check_finite
from sb3_cmzdril.hyperparams import parse_schedule
from sb3_cmzdril.imitation import (
    check_imitation_options,
    check_interval,
    check_saved_learner,
    check_whole_numbers,
    demonstrations_to_go_on,
    parameters_to_set,
    restored_state,
    restoring_saved_model,
    reward_rule,
    rule_bounds,
    weights_brought_by_user,
)
from sb3_cmzdril.io import PathLike
from sb3_cmzdril.policies import DemoStandardizer, floor_log_std, mean_log_std, standardizing_policy_kwargs
from sb3_cmzdril.rewards import DisagreementReward, RewardRule, expert_never_terminates
from sb3_cmzdril.scoring import RolloutRecord, disagreement_where_ended, score_rollout
from sb3_cmzdril.spaces import check_action_space

logger = logging.getLogger(__name__)

SelfCMZDRIL = TypeVar("SelfCMZDRIL", bound="CMZDRIL")
DemosLike = Demonstrations | PathLike | list | None

# Tensors that travel in the zip next to the state dicts (SB3 loads them with weights_only=True).
_SAVED_TENSORS = (
    "_saved_demo_obs",
    "_saved_demo_actions",
    "_saved_demo_lengths",
    "_saved_demo_seeds",
    "_saved_reward_state",
    "_saved_absorbing_u",
)


class CMZDRIL(PPO):
    """PPO trained on CMZ-DRIL's disagreement reward plus NLL behaviour-cloning epochs.

    PPO's arguments (``learning_rate`` ... ``device``) mean what they mean for
    :class:`stable_baselines3.PPO`; the defaults are PPO's. CMZ-DRIL's:

    :param demonstrations: a :class:`~sb3_cmzdril.demos.Demonstrations`, a path to a saved one, or a
        list of episode dicts. Required before the first ``learn()``.
    :param reward: ``"cmz"``, ``"dril"``, ``"zero"`` or ``"env"``.
    :param alpha: CMZ reward scale (paper: 10).
    :param ema: CMZ EMA factor g (paper: 0.99).
    :param u0: initial EMA value (paper: 0).
    :param dril_quantile: DRIL threshold quantile of u on the demos (DRIL: 0.98).
    :param cmz_clip_quantile: clip u in the ``"cmz"`` reward at this quantile of u on the demos (the
        statistic of DRIL's threshold), so that every state beyond it costs the same and a few
        far-off states cannot dominate the reward (``CMZReward(u_max=...)``); None (the paper) does
        not clip.
    :param disagreement: ``"std"``, ``"quadratic"``, ``"std_unclipped"`` (Box actions) or ``"auto"``
        (unclipped where the demonstrations' actions hold a bound; see :mod:`sb3_cmzdril.ensemble`).
    :param ensemble_size: number of ensemble members (paper/DRIL: 5).
    :param ensemble_hidden: hidden layer widths of each member.
    :param ensemble_epochs: epochs of ensemble fitting.
    :param ensemble_batch_size: minibatch size of ensemble fitting.
    :param ensemble_learning_rate: Adam step size of ensemble fitting.
    :param standardize_observations: the policy sees observations standardised with fixed statistics
        of the demonstrations (the ensemble's; :mod:`sb3_cmzdril.policies`). False gives SB3's raw
        inputs (the paper-faithful setting); prefer it where the observations are already scaled to
        about unit range (WaypointNav-v0's, bounded in [-1, 1], cloned worse standardised). Ignored,
        with a warning, when a VecNormalize already normalises the observations.
    :param bc_pretrain_epochs: most NLL epochs before RL.
    :param bc_validation_fraction: share of the demo steps held out to stop pretraining when their
        NLL has not improved for ``bc_patience`` epochs (the best epoch's weights are kept); 0
        trains all ``bc_pretrain_epochs`` on every step.
    :param bc_patience: epochs without improvement of the held-out NLL before pretraining stops.
    :param bc_refit: the held-out steps only choose the number of pretraining epochs; the policy then
        learns that many epochs afresh on every demo step, so a single demonstration is not cut by a
        fifth. Off by default: the published grids ran without it (measurements:
        docs/bc_single_episode.md).
    :param bc_epochs_per_update: NLL epochs on all demo steps after each PPO update (paper: 1; 0
        disables).
    :param bc_update_std: whether the NLL epochs after each PPO update also fit the policy's
        state-independent log-std (``policy.log_std``: a Gaussian's, or gSDE's exploration
        parameters), as the paper's NLL does. They pull it toward the demonstrations' residual
        (Walker2d-v5: std 0.37 after the floor, 0.10 by 300k steps, 0.04 by 3M, the same under the
        env's reward), so PPO's exploration ends with the epochs, not with its own updates. False
        holds it there: the epochs pull only the actions' mean toward the demonstrations (as DRIL's
        code does, by mean-squared error), and PPO alone sets the spread. Pretraining fits it either
        way. Discrete actions have no log-std: no effect.
    :param bc_batch_size: minibatch size of the NLL epochs.
    :param bc_learning_rate: Adam step size of the NLL epochs: a number, a schedule of the progress
        remaining (1 -> 0, as PPO's ``learning_rate``) or ``"lin_<float>"``, which falls linearly to
        0 over ``learn()``: the pull toward the demonstrations then fades as PPO's own updates go on.
        Pretraining runs at its start value.
    :param log_std_floor: after pretraining, raise the Gaussian policy's log-std to at least this
        (None keeps what NLL learned). NLL on a few demos collapses it (HalfCheetah/Hopper: about
        -2, std 0.13), and PPO then barely leaves the cloned trajectory, so the disagreement reward
        has nothing to correct; from std 0.37 (-1.0) the BC epochs and PPO anneal it again (to about
        0.1 by 300k steps). Measured in results/tuning/logstd-floor-1 against results/tuning/logstd-keep.
    :param absorbing: score an episode's termination (not a time-limit truncation) as entering an
        absorbing state at the highest disagreement seen so far, worth ``gamma / (1 - gamma)`` times
        the reward there (:func:`~sb3_cmzdril.rewards.with_absorbing_state`); without it a mean-zero
        reward makes falling over about as good as walking on. ``True`` for any reward; ``"auto"``:
        for the ``"cmz"`` reward only, when every demonstration lasts the env's time limit (the
        expert never terminates). Off by default: on Walker2d-v5 ``"auto"`` doubled CMZ-DRIL's final
        return, on Hopper-v5 it lowered it in 4 of 5 trials (docs/new_tasks.md).
    :param absorbing_score: the absorbing state's disagreement: ``"highest"``, the highest u seen so
        far (every termination as bad as the worst state met); ``"terminal"``, the ensemble's u at the
        observation the episode ended in (``infos["terminal_observation"]``, at the policy's
        deterministic action there where the disagreement needs actions), so that ending as the
        expert ends (a landing, a goal reached) is worth what the state it ends in is worth. Where the
        expert ends its episodes, ``"highest"`` makes its own ending the worst outcome.
    :param critic_warmup_updates: the first this many PPO updates (one per rollout, counted over the
        model's life, so a resumed run does not warm up again) train the value function only: the
        actor's own parameters (and a features extractor it shares with the critic) stay the clone's,
        and no NLL epoch follows, so the first actor updates see advantages from a fitted value
        function rather than an untrained one. 0 (the default, the paper) does not warm up: with 10,
        CMZ-DRIL's final policy fell on Walker2d-v5 and Hopper-v5 (docs/beyond_home_tasks.md), whose
        PPO runs never lost their clone early as the off-policy learner's did.
    :param batch_scoring: score each rollout from the rollout buffer in one ensemble forward (see
        :mod:`sb3_cmzdril.scoring`); False scores every step inside a
        :class:`~sb3_cmzdril.rewards.DisagreementReward` wrapper, which a reward-normalising
        VecNormalize gets anyway. The rewards are the same.

    Pretraining happens once, in the first ``learn()`` (or :meth:`pretrain`) of a model whose
    :attr:`pretrained` is False; it never overwrites weights the user brought (see :attr:`pretrained`).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = PPO.policy_aliases

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        demonstrations: DemosLike = None,
        reward: str = "cmz",
        alpha: float = 10.0,
        ema: float = 0.99,
        u0: float = 0.0,
        dril_quantile: float = 0.98,
        cmz_clip_quantile: float | None = None,
        disagreement: str = "std",
        ensemble_size: int = 5,
        ensemble_hidden: Sequence[int] = (64, 64),
        ensemble_epochs: int = 200,
        ensemble_batch_size: int = 64,
        ensemble_learning_rate: float = 1e-3,
        standardize_observations: bool = True,
        bc_pretrain_epochs: int = 1000,
        bc_validation_fraction: float = 0.2,
        bc_patience: int = 20,
        bc_refit: bool = False,
        bc_epochs_per_update: int = 1,
        bc_update_std: bool = True,
        bc_batch_size: int = 64,
        bc_learning_rate: float | Schedule | str = 1e-3,
        log_std_floor: float | None = -1.0,
        absorbing: bool | str = False,
        absorbing_score: str = "highest",
        critic_warmup_updates: int = 0,
        batch_scoring: bool = True,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 2048,
        batch_size: int = 64,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: None | float | Schedule = None,
        normalize_advantage: bool = True,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        target_kl: float | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        check_finite(
            alpha=alpha, ema=ema, u0=u0, dril_quantile=dril_quantile, cmz_clip_quantile=cmz_clip_quantile,
            ensemble_learning_rate=ensemble_learning_rate, bc_validation_fraction=bc_validation_fraction,
            bc_learning_rate=bc_learning_rate, log_std_floor=log_std_floor, learning_rate=learning_rate,
            gamma=gamma, gae_lambda=gae_lambda, clip_range=clip_range, clip_range_vf=clip_range_vf,
            ent_coef=ent_coef, vf_coef=vf_coef, max_grad_norm=max_grad_norm, target_kl=target_kl,
        )
        check_imitation_options(
            reward, alpha, ema, u0, dril_quantile, bc_pretrain_epochs, bc_validation_fraction, bc_patience, absorbing,
            cmz_clip_quantile, absorbing_score, bc_epochs_per_update=bc_epochs_per_update,
            critic_warmup_updates=critic_warmup_updates,
        )
        if log_std_floor is not None and not np.isfinite(log_std_floor):
            raise UserError(f"log_std_floor must be finite or None, got {log_std_floor}")
        _check_ppo_options(env, n_steps, batch_size, n_epochs, normalize_advantage)
        check_whole_numbers(1, ensemble_epochs=ensemble_epochs, ensemble_batch_size=ensemble_batch_size,
                            bc_batch_size=bc_batch_size)
        check_interval("[0, 1]", gamma=gamma, gae_lambda=gae_lambda)
        check_interval("(0, inf)", learning_rate=learning_rate, clip_range=clip_range, clip_range_vf=clip_range_vf,
                       target_kl=target_kl, max_grad_norm=max_grad_norm, ensemble_learning_rate=ensemble_learning_rate)
        check_interval("[0, inf)", vf_coef=vf_coef)
        self.demonstrations: Demonstrations | None = (
            None if demonstrations is None else as_demonstrations(demonstrations)
        )
        self.reward = reward
        self.alpha = float(alpha)
        self.ema = float(ema)
        self.u0 = float(u0)
        self.dril_quantile = float(dril_quantile)
        self.dril_threshold: float | None = None
        self.cmz_clip_quantile = None if cmz_clip_quantile is None else float(cmz_clip_quantile)
        #: the CMZ reward's clip of u (``cmz_clip_quantile`` of u on the demos), computed with the ensemble
        self.cmz_u_max: float | None = None
        self.disagreement = disagreement
        self.ensemble_size = int(ensemble_size)
        self.ensemble_hidden = tuple(int(h) for h in ensemble_hidden)
        self.ensemble_epochs = int(ensemble_epochs)
        self.ensemble_batch_size = int(ensemble_batch_size)
        self.ensemble_learning_rate = float(ensemble_learning_rate)
        self.standardize_observations = bool(standardize_observations)
        self.bc_pretrain_epochs = int(bc_pretrain_epochs)
        self.bc_validation_fraction = float(bc_validation_fraction)
        self.bc_patience = int(bc_patience)
        self.bc_refit = bool(bc_refit)
        self.bc_epochs_per_update = int(bc_epochs_per_update)
        self.bc_update_std = bool(bc_update_std)
        self.bc_batch_size = int(bc_batch_size)
        #: a number or a schedule of the progress remaining (see :meth:`_bc_learning_rate`)
        self.bc_learning_rate: float | Schedule = parse_schedule(bc_learning_rate, "bc_learning_rate")
        self.log_std_floor = None if log_std_floor is None else float(log_std_floor)
        self.absorbing = absorbing
        self.absorbing_score = absorbing_score
        #: whether terminations are scored as an absorbing state (``absorbing`` resolved at ``learn()``)
        self.absorbing_active = False
        self.critic_warmup_updates = int(critic_warmup_updates)
        #: value-only updates done so far (saved with the model: a resumed run does not warm up again)
        self.critic_warmup_done = 0
        self.batch_scoring = bool(batch_scoring)
        self.pretrain_info: dict[str, float] = {}
        self.pretrain_history: dict[str, list[float]] = {}
        self.rollout_disagreement: float | None = None
        #: whether the policy was trained on VecNormalize'd observations (saved with the model, so that
        #: an evaluation without the statistics can be refused instead of silently wrong)
        self.vecnormalize_obs = False
        #: the reward rule (and DRIL threshold) is made for the current ensemble
        self._imitation_ready = False
        #: the policy holds pretrained (or loaded) weights: pretraining leaves it alone
        self._policy_pretrained = False
        #: pretrain/* keys waiting for learn()'s logger (it is made after pretraining, in _setup_learn)
        self._pretrain_log_pending = False
        #: set_parameters() brought an ensemble: the rule (and DRIL threshold) is remade for it
        self._ensemble_replaced = False
        if isinstance(env, str):
            with mujoco_warnings_routed():  # e.g. HalfCheetah's settotalmass notice at model compile
                env = maybe_make_env(env, verbose)
        #: how a Dict space's demo observations are packed into one saved tensor (None: not a dict)
        self._demo_obs_layout: list | None = None
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=batch_size,
            n_epochs=n_epochs,
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=clip_range,
            clip_range_vf=clip_range_vf,
            normalize_advantage=normalize_advantage,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            target_kl=target_kl,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        if _init_setup_model:
            self._setup_model()

    # -- model construction and persistence --------------------------------------------------
    @property
    def pretrained(self) -> bool:
        """Whether the policy is pretrained and the ensemble fitted, so that ``learn()`` goes straight
        to RL (as SB3's ``learn()`` continues from the current parameters).

        True after the first ``learn()`` or :meth:`pretrain`, after ``load()`` of a model saved
        pretrained, and after ``set_parameters()`` with a policy and a fitted ensemble. A
        ``set_parameters()`` that brings only some of them (``exact_match=False``) keeps what it
        brought: the next ``learn()`` pretrains only the rest (a loaded policy is not cloned again, a
        loaded fitted ensemble is not refitted). Set it to True after loading weights by hand (e.g.
        ``model.policy.load_state_dict(...)``) to skip pretraining; set it to False to pretrain and
        refit from scratch at the next ``learn()``.
        """
        return self._policy_pretrained and self.ensemble.is_fitted

    @pretrained.setter
    def pretrained(self, value: bool) -> None:
        self._policy_pretrained = bool(value)
        if not value:
            self.ensemble.mark_unfitted()
        elif not self.ensemble.is_fitted:  # members loaded by hand: "auto" reads its form from the demos
            self.ensemble.mark_fitted(None if self.demonstrations is None else self.demonstrations.actions)
        self._imitation_ready = False  # the rule (and DRIL threshold) is remade for the ensemble at learn()

    @property
    def absorbing_u(self) -> float:
        """The absorbing state's disagreement: the highest u scored so far, kept by the reward rule
        (0 before the first rollout)."""
        return 0.0 if self.reward_rule is None else self.reward_rule.absorbing_u

    def _setup_model(self) -> None:
        check_action_space(self.action_space)
        if self.standardize_observations:
            self.policy_kwargs, note = standardizing_policy_kwargs(
                self.policy_class, self.policy_kwargs, self.observation_space
            )
            if note is not None:
                logger.info(note)
                if self.verbose >= 1:
                    print(note)
        super()._setup_model()
        # seed=None: draw from the global RNG, which SB3's set_random_seed (or the user) controls.
        seed = int(np.random.randint(0, 2**31 - 1)) if self.seed is None else int(self.seed)
        self.ensemble_hidden = tuple(self.ensemble_hidden)  # a loaded model gets a JSON list back
        self.ensemble = BCEnsemble(
            self.observation_space, self.action_space, self.ensemble_size, self.ensemble_hidden, self.disagreement, seed
        ).to(self.device)
        self.bc = BehaviourCloner(self.policy, self.bc_batch_size, self._bc_learning_rate(1.0), self.max_grad_norm,
                                  seed=seed)
        self.reward_rule: RewardRule | None = None
        for name in _SAVED_TENSORS:
            setattr(self, name, th.zeros(0))

    def _excluded_save_params(self) -> list:
        return super()._excluded_save_params() + [
            "demonstrations", "reward_rule", "ensemble", "bc", "_ensemble_replaced", "_pretrain_log_pending"
        ]

    def _get_torch_save_params(self) -> tuple[list, list]:
        state_dicts, variables = super()._get_torch_save_params()
        return state_dicts + ["ensemble", "bc.optimizer"], variables + list(_SAVED_TENSORS)

    def save(self, path: Any, exclude: Any | None = None, include: Any | None = None) -> None:
        """Save like PPO, plus ensemble, BC optimiser, demonstrations and reward-rule state."""
        demos = self.demonstrations
        if demos is not None:
            self._saved_demo_obs, self._demo_obs_layout = _pack_observations(demos.observations)
            self._saved_demo_actions = th.as_tensor(demos.actions)
            self._saved_demo_lengths = th.as_tensor(demos.episode_lengths)
            self._saved_demo_seeds = th.as_tensor(demos.seeds)
        if self.reward_rule is not None:
            self._saved_reward_state = th.as_tensor(self.reward_rule.get_state())
            self._saved_absorbing_u = th.tensor([self.reward_rule.absorbing_u], dtype=th.float64)
        super().save(path, exclude=exclude, include=include)

    @classmethod
    def load(
        cls: type[SelfCMZDRIL],
        path: Any,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        demonstrations: DemosLike = None,
        **kwargs: Any,
    ) -> SelfCMZDRIL:
        """Load a saved CMZDRIL (or a plain PPO) model, as PPO's ``load``.

        ``demonstrations`` replaces the ones saved with the model. Where they hold other steps than
        those and the model was saved pretrained, its ensemble is fitted again on them at the next
        ``learn()``, and with it DRIL's threshold, the CMZ reward's clip and a fresh reward state (the
        EMA of the old ensemble's u means nothing to the new one), so that the reward measures the
        distance to the demonstrations the BC epochs pull toward; a line is logged. The policy keeps
        its weights, and with them the input standardisation they were trained with (refitting it
        would change what the trained policy does); set ``pretrained = False`` after loading to
        clone the new demonstrations afresh as well. The saved demonstrations handed again change
        nothing. A model saved by CMZDRILSAC (or another off-policy learner) is refused in one line.
        """
        check_saved_learner(path, "CMZDRIL", off_policy=False, plain_sb3=True)
        with restoring_saved_model():
            model = super().load(
                path,
                env=env,
                device=device,
                custom_objects=custom_objects,
                print_system_info=print_system_info,
                force_reset=force_reset,
                **kwargs,
            )
        model._restore_saved_state(None if demonstrations is None else as_demonstrations(demonstrations))
        return model

    def set_parameters(
        self,
        load_path_or_dict: str | dict[str, Any],
        exact_match: bool = True,
        device: th.device | str = "auto",
    ) -> None:
        """SB3's ``set_parameters``; what it loads is kept by the next ``learn()``: a loaded policy is
        not pretrained again and a loaded fitted ensemble not refitted (see :attr:`pretrained`)."""
        params = parameters_to_set(load_path_or_dict, device)
        super().set_parameters(params, exact_match=exact_match, device=device)
        if "policy" in params and weights_brought_by_user():
            self._policy_pretrained = True
        if "ensemble" in params:
            self._ensemble_replaced = True  # the DRIL threshold and the rule belong to the old ensemble

    def _restore_saved_state(self, demonstrations: Demonstrations | None) -> None:
        # Models saved before the rule kept the absorbing state's u had it as a plain attribute,
        # which SB3's load() put into __dict__ beside the property that now reads it from the rule.
        legacy_absorbing_u = self.__dict__.pop("absorbing_u", None)
        # Models saved before _policy_pretrained existed were pretrained when their rule was ready.
        self._policy_pretrained = self._policy_pretrained or self._imitation_ready
        self._ensemble_replaced = False  # load()'s own set_parameters: threshold and rule came with the ensemble
        saved = None
        if self._saved_demo_obs.numel():
            saved = Demonstrations(
                _unpack_observations(self._saved_demo_obs.cpu().numpy(), getattr(self, "_demo_obs_layout", None)),
                self._saved_demo_actions.cpu().numpy(),
                self._saved_demo_lengths.cpu().numpy(),
                seeds=self._saved_demo_seeds.cpu().numpy(),
            )
        checked, refit = demonstrations_to_go_on(
            saved, demonstrations, self.observation_space, self.action_space, self.ensemble.is_fitted, "CMZDRIL"
        )
        self.demonstrations = demonstrations if demonstrations is not None else saved
        if checked is not None:
            self.bc.set_demonstrations(checked)
        if refit:  # the next learn() fits the ensemble and makes the bounds and the rule for it
            self.ensemble.mark_unfitted()
            self._imitation_ready = False
            self.dril_threshold = self.cmz_u_max = None
        if self._imitation_ready:
            self.reward_rule = self._make_rule()
            saved_state = self._saved_reward_state.cpu().numpy()
            state, remapped = restored_state(saved_state, self.n_envs)
            if remapped:
                warnings.warn(
                    f"the saved reward state is for {saved_state.size} envs but the model now has {self.n_envs}; "
                    "starting every env's EMA from the saved mean",
                    UserWarning,
                    stacklevel=2,
                )
            self.reward_rule.set_state(state)
            if self._saved_absorbing_u.numel():
                self.reward_rule.absorbing_u = float(self._saved_absorbing_u.item())
            elif legacy_absorbing_u is not None:
                self.reward_rule.absorbing_u = float(legacy_absorbing_u)

    # -- imitation set-up ------------------------------------------------------------------------
    def _make_rule(self) -> RewardRule:
        return reward_rule(self.reward, self.alpha, self.ema, self.u0, self.dril_threshold, self.cmz_u_max)

    def _demo_obs_transform(self) -> Any:
        vec_normalize = self.get_vec_normalize_env()
        if vec_normalize is not None and vec_normalize.norm_obs:
            return vec_normalize.normalize_obs
        return None

    def _standardizers(self) -> list[DemoStandardizer]:
        # Two with share_features_extractor=False (the actor's and the critic's).
        return [m for m in self.policy.modules() if isinstance(m, DemoStandardizer)]

    def pretrain(self, progress_bar: bool = False) -> dict[str, float]:
        """Check the demos, set the policy's input standardisation, pretrain the policy by NLL
        (early-stopped on held-out demo steps) and fit the ensemble, each unless already done or
        loaded (:attr:`pretrained`); later calls only re-check the demos. Returns NLLs, epochs, the
        policy's log-std and timings of what ran; the per-epoch curve is in ``pretrain_history``.
        The values reach the logger as ``pretrain/*`` at the next ``learn()``'s first dump."""
        if self.demonstrations is None:
            raise UserError(
                "CMZDRIL needs demonstrations: pass demonstrations=... (a Demonstrations, a path to a "
                "demos.npz, or a list of episode dicts) to the constructor or to load()"
            )
        self.demonstrations = self.demonstrations.check_spaces(self.observation_space, self.action_space)
        self.bc.set_demonstrations(self.demonstrations)
        if self._imitation_ready and not self._ensemble_replaced:
            return self.pretrain_info
        info: dict[str, float] = {}
        if not self._policy_pretrained:
            info.update(self._pretrain_policy(progress_bar))
        info.update(self._prepare_scoring(progress_bar, remake_rule=True))
        self._imitation_ready = True
        self._ensemble_replaced = False
        if info:
            self.pretrain_info = info
            self._pretrain_log_pending = True
        if self.verbose >= 1:
            print(self._pretrain_summary(info))
        return self.pretrain_info

    def _pretrain_policy(self, progress_bar: bool) -> dict[str, float]:
        """Set the policy's input standardisation and clone the demos by NLL; the statistics of it."""
        assert self.demonstrations is not None
        transform = self._demo_obs_transform()
        standardizers = self._standardizers()
        if standardizers:
            if transform is not None:
                warnings.warn(
                    "VecNormalize normalises the observations already: the demo standardisation of the policy "
                    "is left as the identity (CMZDRIL(standardize_observations=False) silences this)",
                    UserWarning,
                    stacklevel=3,
                )
            else:
                for standardizer in standardizers:
                    standardizer.fit(self.demonstrations.observations)
        start = time.perf_counter()
        nll_before = self.bc.nll(transform)
        stopping = self.bc.train_early_stopping(
            self.bc_pretrain_epochs,
            self.bc_validation_fraction,
            self.bc_patience,
            transform,
            progress_bar,
            refit=getattr(self, "bc_refit", False),  # a model saved before the option has none
        )
        nll_after = self.bc.nll(transform)
        log_std_learned = mean_log_std(self.policy)
        if self.log_std_floor is not None:
            floor_log_std(self.policy, self.log_std_floor)
        self._policy_pretrained = True
        self.pretrain_history = {"train_nll": stopping.train_nll, "validation_nll": stopping.validation_nll}
        return {
            "bc_nll_before": nll_before,
            "bc_nll_after": nll_after,
            "bc_validation_nll": min(stopping.validation_nll) if stopping.validation_nll else float("nan"),
            "bc_best_epoch": stopping.best_epoch,
            "bc_epochs": stopping.epochs,
            "bc_refit_epochs": stopping.refit_epochs,
            "bc_log_std_learned": log_std_learned,
            "bc_log_std": mean_log_std(self.policy),
            "bc_seconds": time.perf_counter() - start,
        }

    def _pretrain_summary(self, info: dict[str, float]) -> str:
        """The verbose line of :meth:`pretrain`: what ran, and what was kept as loaded."""
        if "bc_epochs" in info:
            bc = (
                f"BC NLL {info['bc_nll_before']:.3f} -> {info['bc_nll_after']:.3f} (best of {int(info['bc_epochs'])} "
                f"epochs: {int(info['bc_best_epoch'])}, {info['bc_seconds']:.1f}s)"
            )
        else:
            bc = "policy kept as loaded"
        if "ensemble_loss" in info:
            fit = f"ensemble loss {info['ensemble_loss']:.4g} ({info['ensemble_seconds']:.1f}s)"
        else:
            fit = "ensemble kept as loaded"
        threshold = f"; DRIL threshold {self.dril_threshold:.4g}" if self.dril_threshold is not None else ""
        if self.cmz_u_max is not None:
            threshold += f"; CMZ reward clips u at {self.cmz_u_max:.4g}"
        return f"CMZDRIL pretraining: {bc}; {fit}{threshold}"

    def _prepare_scoring(self, progress_bar: bool = False, remake_rule: bool = False) -> dict[str, float]:
        """Fit the ensemble (unless fitted or loaded) and make the reward rule (and DRIL threshold):
        what scoring a rollout needs. ``remake_rule``: for an ensemble that may be new. Returns the
        fit's loss and time, {} when the ensemble was kept."""
        assert self.demonstrations is not None
        info: dict[str, float] = {}
        if not self.ensemble.is_fitted:
            start = time.perf_counter()
            self.ensemble.fit(
                self.demonstrations,
                self.ensemble_epochs,
                self.ensemble_batch_size,
                self.ensemble_learning_rate,
                progress_bar,
            )
            assert self.ensemble.train_loss_ is not None  # set by fit()
            info["ensemble_loss"] = float(np.mean(self.ensemble.train_loss_))
            info["ensemble_seconds"] = time.perf_counter() - start
        missing = (self.reward == "dril" and self.dril_threshold is None) or (
            self.reward == "cmz" and self.cmz_clip_quantile is not None and self.cmz_u_max is None
        )
        if remake_rule or missing:
            self.dril_threshold, self.cmz_u_max = rule_bounds(
                self.reward, self.ensemble, self.demonstrations, self.dril_quantile, self.cmz_clip_quantile
            )
        if remake_rule or self.reward_rule is None:
            self.reward_rule = self._make_rule()
        return info

    def reward_wrapper(self) -> DisagreementReward | None:
        """The per-step DisagreementReward in the training env, or None (the default scores rollouts
        from the buffer and leaves the env stack alone)."""
        env = self.env
        while isinstance(env, VecEnvWrapper):
            if isinstance(env, DisagreementReward):
                return env
            env = env.venv
        return None

    def _per_step_scoring(self) -> bool:
        vec_normalize = self.get_vec_normalize_env()
        return not self.batch_scoring or (vec_normalize is not None and bool(vec_normalize.norm_reward))

    def _wrap_training_env(self) -> None:
        """Per-step scoring only: put the wrapper above every monitor (they report the true return)
        and right below a VecNormalize (which must see the shaped reward and the wrapper raw obs)."""
        if self.env is None:
            raise UserError("CMZDRIL.learn() needs an environment: pass env= to the constructor or to load()")
        assert self.reward_rule is not None
        self.absorbing_active = self._absorbing_applies()
        absorbing_gamma = self._absorbing_gamma()
        wrapper = self.reward_wrapper()
        if wrapper is not None:
            wrapper.ensemble, wrapper.rule, wrapper.absorbing_gamma = self.ensemble, self.reward_rule, absorbing_gamma
            wrapper.terminal_disagreement = self._terminal_disagreement()
            return
        if not self._per_step_scoring():
            return
        vec_normalize = self.get_vec_normalize_env()
        below = self.env if vec_normalize is None else vec_normalize.venv
        wrapped = DisagreementReward(below, self.ensemble, self.reward_rule, absorbing_gamma,
                                     self._terminal_disagreement())
        if vec_normalize is None:
            self.env = wrapped
        else:
            vec_normalize.venv = wrapped
        self._last_obs = None  # the next learn() resets through the wrapper so it sees the first obs

    def _terminal_disagreement(self) -> Callable[[Any], np.ndarray] | None:
        """How terminations' absorbing states are scored when not at the highest u seen: the ensemble's
        u at the raw observations the episodes ended in (see ``absorbing_score``); None otherwise."""
        if self._absorbing_gamma() is None or self.absorbing_score != "terminal":
            return None

        def disagreement(raw_obs: Any) -> np.ndarray:
            return disagreement_where_ended(
                self.ensemble, self.policy, raw_obs, self.action_space, self.get_vec_normalize_env()
            )

        return disagreement

    def _absorbing_gamma(self) -> float | None:
        """The discount of the absorbing state's value where terminations are scored so, else None
        (the true env reward is left as the env gave it)."""
        return self.gamma if self.absorbing_active and self.reward != "env" else None

    def _absorbing_applies(self) -> bool:
        if self.absorbing != "auto":
            return bool(self.absorbing)
        if self.reward != "cmz" or self.demonstrations is None or self.env is None:
            return False
        return expert_never_terminates(self.demonstrations, self.env)

    # -- training ---------------------------------------------------------------------------------
    def learn(
        self: SelfCMZDRIL,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "CMZDRIL",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfCMZDRIL:
        """PPO's ``learn``, after pretraining if the model is not :attr:`pretrained` yet."""
        # Rollouts step MuJoCo: its warnings (e.g. unstable simulation) go to stderr, not MUJOCO_LOG.TXT.
        with mujoco_warnings_routed():
            self.pretrain(progress_bar=progress_bar)
            self._wrap_training_env()
            vec_normalize = self.get_vec_normalize_env()
            self.vecnormalize_obs = self.vecnormalize_obs or bool(vec_normalize is not None and vec_normalize.norm_obs)
            return super().learn(
                total_timesteps=total_timesteps,
                callback=callback,
                log_interval=log_interval,
                tb_log_name=tb_log_name,
                reset_num_timesteps=reset_num_timesteps,
                progress_bar=progress_bar,
            )

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        # learn() has pretrained already. A caller driving collect_rollouts itself after _setup_learn
        # (as SB3's own tests do) gets what scoring needs, the fitted ensemble and the reward rule,
        # and a policy left as it is (pretraining belongs to learn() or pretrain()).
        if self.reward_rule is None:
            if self.demonstrations is None:
                self.pretrain()  # refuses, naming the missing demonstrations
            assert self.demonstrations is not None
            self.demonstrations = self.demonstrations.check_spaces(self.observation_space, self.action_space)
            self.bc.set_demonstrations(self.demonstrations)
            self._prepare_scoring(progress_bar)
        self._wrap_training_env()
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        # learn()'s logger (TensorBoard included) exists only from here: pretraining ran before it.
        if self._pretrain_log_pending:
            for key, value in self.pretrain_info.items():
                self.logger.record(f"pretrain/{key}", value)
            self._pretrain_log_pending = False
        return result

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        # The scorer goes first, so that every user callback's on_rollout_end sees the final rewards.
        user = super()._init_callback(callback, progress_bar=False)
        callbacks: list[BaseCallback] = [_RolloutScoring(rescore=not self._per_step_scoring()), user]
        if progress_bar:
            callbacks.append(_WholeRolloutsProgressBar())
        combined = CallbackList(callbacks)
        combined.init_callback(self)
        return combined

    def _new_rollout_record(self) -> RolloutRecord:
        """An empty record of the rollout about to be collected (batch scoring)."""
        vec_normalize = self.get_vec_normalize_env()
        # The buffer holds what the policy saw; the ensemble needs raw observations.
        raw_from = vec_normalize if vec_normalize is not None and vec_normalize.norm_obs else None
        return RolloutRecord(self.rollout_buffer.buffer_size, self.rollout_buffer.n_envs, raw_from,
                             keep_terminal=self._terminal_disagreement() is not None)

    def _finish_rollout(self, record: RolloutRecord | None, last_values: th.Tensor, dones: np.ndarray) -> None:
        """Score the rollout just collected into the buffer (``record`` None: the per-step wrapper
        scored it already) and log its disagreement statistics."""
        if record is None:
            wrapper = self.reward_wrapper()
            stats = wrapper.pop_stats() if wrapper is not None else {}
        else:
            assert self.reward_rule is not None
            buffer = self.rollout_buffer
            scores = score_rollout(
                record,
                buffer,
                self.ensemble,
                self.reward_rule,
                self.observation_space,
                self.action_space,
                self._absorbing_gamma(),
                self._terminal_disagreement(),
            )
            if self.reward != "env":
                # Swap the env reward for the rule's; the truncation bootstrap in the buffer stays.
                buffer.rewards += scores.rewards - record.env_rewards
                buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
            stats = scores.stats()
        for key, value in stats.items():
            self.logger.record(f"rollout/{key}", value)
        self.rollout_disagreement = stats.get("disagreement_mean")
        state = self.reward_rule.get_state() if self.reward_rule is not None else np.zeros(0)
        if state.size:
            self.logger.record("rollout/ubar_mean", float(state.mean()))
        if self._absorbing_gamma() is not None:
            # How much a termination costs depends on it: the run's highest u so far.
            self.logger.record("rollout/absorbing_u", self.absorbing_u)

    def _bc_learning_rate(self, progress_remaining: float) -> float:
        """The NLL epochs' step size at ``progress_remaining`` (1 at the start of ``learn()``, 0 at its end)."""
        rate = self.bc_learning_rate
        return float(rate(progress_remaining)) if callable(rate) else float(rate)

    def train(self) -> None:
        if self.critic_warmup_done < self.critic_warmup_updates:
            with _critic_only(self.policy):
                super().train()
            self.critic_warmup_done += 1
            self.logger.record("train/critic_warmup", 1.0)
            return
        super().train()
        if self.bc_epochs_per_update and self.demonstrations is not None:
            transform = self._demo_obs_transform()
            held = [] if self.bc_update_std else _log_std_parameters(self.policy)
            bc_lr = self._bc_learning_rate(self._current_progress_remaining)
            update_learning_rate(self.bc.optimizer, bc_lr)
            self.logger.record("train/bc_learning_rate", bc_lr)
            with _without_gradient(held):
                for _ in range(self.bc_epochs_per_update):
                    nll = self.bc.epoch(transform)
            self.logger.record("train/bc_nll", nll)


def _check_ppo_options(
    env: GymEnv | str | None, n_steps: Any, batch_size: Any, n_epochs: Any, normalize_advantage: bool
) -> None:
    """UserError, in one line, for the rollout and update sizes PPO cannot learn with: ``n_epochs=0``
    (PPO accepts it and then fails inside ``train()``), ``n_steps`` or ``batch_size`` below 1, and
    below 2 where ``normalize_advantage`` normalises each minibatch and the rollout (SB3's own
    checks of these are assertions, whose traceback says nothing of the option)."""
    check_whole_numbers(1, n_steps=n_steps, n_epochs=n_epochs)
    # SB3's words, as a UserError: with normalize_advantage, the advantages of one step normalise to nan.
    if normalize_advantage and isinstance(batch_size, (int, np.integer)) and batch_size < 2:
        raise UserError(f"`batch_size` must be greater than 1 with normalize_advantage=True, got {batch_size}")
    check_whole_numbers(1, batch_size=batch_size)
    n_envs = env.num_envs if isinstance(env, VecEnv) else 1
    if normalize_advantage and env is not None and n_steps * n_envs < 2:
        raise UserError(f"`n_steps * n_envs` must be greater than 1 with normalize_advantage=True, got "
                        f"n_steps={n_steps} and n_envs={n_envs}")


@contextmanager
def _critic_only(policy: ActorCriticPolicy) -> Iterator[None]:
    """Within it, only the critic's own parameters (its head, the value branch of the MLP extractor and
    its own features extractor) take gradients: PPO's update then fits the value function alone and
    the optimiser leaves every other parameter as it is (Adam skips a parameter without a gradient)."""
    critic_parts = [policy.value_net, getattr(policy.mlp_extractor, "value_net", None)]
    if not policy.share_features_extractor:
        critic_parts.append(policy.vf_features_extractor)
    critic = {id(p) for part in critic_parts if part is not None for p in part.parameters()}
    with _without_gradient([p for p in policy.parameters() if id(p) not in critic]):
        yield


def _log_std_parameters(policy: ActorCriticPolicy) -> list[th.nn.Parameter]:
    """The policy's state-independent log-std, where it has one (Gaussian or gSDE actions)."""
    log_std = getattr(policy, "log_std", None)
    return [log_std] if isinstance(log_std, th.nn.Parameter) else []


@contextmanager
def _without_gradient(parameters: Iterable[th.nn.Parameter]) -> Iterator[None]:
    """Within it, ``parameters`` take no gradient, so an optimiser step leaves them as they are
    (Adam skips a parameter without a gradient)."""
    frozen = [p for p in parameters if p.requires_grad]
    for p in frozen:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in frozen:
            p.requires_grad_(True)


class _RolloutScoring(BaseCallback):
    """Hands each rollout to its model for scoring: records its steps while it runs and has the
    model score it at its end. The first callback, so that user callbacks' ``on_rollout_end``
    already see the final rewards.

    :param rescore: score from the buffer (False: a per-step wrapper already did).
    """

    def __init__(self, rescore: bool) -> None:
        super().__init__()
        self.rescore = bool(rescore)
        self._record: RolloutRecord | None = None

    @property
    def cmz(self) -> CMZDRIL:
        # Only CMZDRIL._init_callback installs it, so its model is always a CMZDRIL.
        return cast(CMZDRIL, self.model)

    def _on_rollout_start(self) -> None:
        self._record = self.cmz._new_rollout_record() if self.rescore else None

    def _on_step(self) -> bool:
        if self._record is not None:
            # record() copies the rewards: collect_rollouts adds the truncation bootstrap in place afterwards.
            self._record.record(self.locals["rewards"], self.locals["dones"], self.locals["infos"])
        return True

    def _on_rollout_end(self) -> None:
        record, self._record = self._record, None
        self.cmz._finish_rollout(record, self.locals["values"], self.locals["dones"])


class _WholeRolloutsProgressBar(ProgressBarCallback):
    """SB3's progress bar with the steps ``learn()`` really takes as its total: PPO collects whole
    rollouts, so it overshoots ``total_timesteps`` up to the next multiple of ``n_steps * n_envs``,
    and a bar whose count passes its total drops the total (and its percentage and ETA)."""

    def _on_training_start(self) -> None:
        remaining = self.locals["total_timesteps"] - self.model.num_timesteps
        rollout = self.model.n_steps * self.training_env.num_envs  # type: ignore[attr-defined]
        self.pbar = tqdm(total=max(0, math.ceil(remaining / rollout) * rollout))


def _pack_observations(obs: np.ndarray | dict[str, np.ndarray]) -> tuple[th.Tensor, list | None]:
    """A tensor for the zip and, for dict observations, the layout that unpacks it: SB3 saves extra
    variables as single tensors, so a dict's arrays travel as one byte tensor."""
    if not isinstance(obs, dict):
        return th.as_tensor(obs), None
    layout = [[key, value.dtype.str, list(value.shape)] for key, value in obs.items()]
    packed = np.concatenate([np.ascontiguousarray(value).view(np.uint8).reshape(-1) for value in obs.values()])
    return th.as_tensor(packed), layout


def _unpack_observations(saved: np.ndarray, layout: list | None) -> np.ndarray | dict[str, np.ndarray]:
    if layout is None:
        return saved
    out, offset = {}, 0
    for key, dtype, shape in layout:
        size = int(np.prod(shape)) * np.dtype(dtype).itemsize
        out[key] = saved[offset : offset + size].view(np.dtype(dtype)).reshape(shape)
        offset += size
    return out
