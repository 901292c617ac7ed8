"""CMZDRIL: SB3's PPO with CMZ-DRIL's imitation machinery (paper, Algorithm 1).

On the first ``learn()`` of a model that is not pretrained yet (or an explicit
:meth:`CMZDRIL.pretrain`) the model checks the demonstrations against the env, sets the policy's
input standardisation to the demos' statistics, pretrains the policy by NLL behaviour cloning until
the NLL of held-out demo steps stops improving, and fits the bootstrap ensemble. ``model.pretrained``
says whether that is done; weights that ``load()`` or ``set_parameters()`` bring are kept (see
:attr:`CMZDRIL.pretrained`). Each rollout is then scored from the rollout buffer
(:mod:`sb3_cmzdril.cmzdril.scoring`):
the env stack keeps the true reward, so every Monitor, VecMonitor and ``evaluate_policy`` reports the
true return. Every PPO update is followed by ``bc_epochs_per_update`` NLL epochs on the demos.

``reward`` picks the rule, everything else is shared: ``"cmz"`` (the paper), ``"dril"`` (+1/-1 by the
q-quantile threshold), ``"zero"`` (PPO + BC epochs only), ``"env"`` (the true reward). Plain BC is
the pretrained policy (``model.pretrain()`` without ``learn``).

Saving: the zip holds the policy (with its standardisation statistics), the ensemble, the BC
optimiser, the demonstrations (observations, actions, episode lengths, seeds) and the reward rule's
per-env state, so ``CMZDRIL.load(path, env=env)`` can go on learning without being handed the demos
again; ``load(..., demonstrations=...)`` replaces them (other ones refit the ensemble: :meth:`CMZDRIL.load`).
The demonstrations, the ensemble, the reward rule, pretraining and the save/load of them are the
imitation part CMZDRIL shares with CMZDRILSAC (:class:`~sb3_cmzdril.common.imitation.ImitationLearner`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from stable_baselines3 import PPO
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

from sb3_cmzdril.cmzdril.scoring import ReturnScale, RolloutRecord, score_rollout
from sb3_cmzdril.common.bc import AUTO_EPOCHS_NLL, BehaviourCloner, nll_per_action_entry
from sb3_cmzdril.common.drift import AUTO_CLIP_QUANTILE, clone_drift, clone_falls
from sb3_cmzdril.common.imitation import (
    DemosLike,
    ImitationLearner,
    arguments_for,
    disagreement_where_ended,
    made_env,
    rule_bounds,
)
from sb3_cmzdril.common.options import check_interval, check_whole_numbers
from sb3_cmzdril.data.demos import expert_never_terminates, time_limit
from sb3_cmzdril.data.spaces import check_action_space
from sb3_cmzdril.ensemble import disagreement_on_demos
from sb3_cmzdril.errors import OptionError, UserError, check_finite
from sb3_cmzdril.hyperparams import parse_schedule
from sb3_cmzdril.policies import floor_log_std, mean_log_std
from sb3_cmzdril.rewards import DisagreementReward

SelfCMZDRIL = TypeVar("SelfCMZDRIL", bound="CMZDRIL")


class CMZDRIL(ImitationLearner, PPO):
    """PPO trained on CMZ-DRIL's disagreement reward plus NLL behaviour-cloning epochs.

    PPO's arguments (``learning_rate`` ... ``device``) mean what they mean for
    :class:`stable_baselines3.PPO`; the defaults are PPO's. CMZ-DRIL's: five of them default to
    ``"auto"``, a rule that reads the demonstrations, the env or the clone at the first ``learn()``
    and records its decision and reason in :attr:`rules` (docs: "One default for any task"); the
    paper's values, the defaults before 0.3.0, are ``absorbing=False, cmz_clip_quantile=None,
    disagreement="std", standardize_observations=True, bc_epochs_per_update=1``.

    :param demonstrations: a :class:`~sb3_cmzdril.data.demos.Demonstrations`, a path to a saved one, or a
        list of episode dicts. Required before the first ``learn()``.
    :param reward: ``"cmz"``, ``"dril"``, ``"zero"`` or ``"env"``.
    :param alpha: CMZ reward scale (paper: 10).
    :param ema: CMZ EMA factor g (paper: 0.99).
    :param u0: initial EMA value (paper: 0).
    :param dril_quantile: DRIL threshold quantile of u on the demos (DRIL: 0.98).
    :param cmz_clip_quantile: clip u in the ``"cmz"`` reward at this quantile of u on the demos (the
        statistic of DRIL's threshold), so that every state beyond it costs the same and a few
        far-off states cannot dominate the reward (``CMZReward(u_max=...)``); None (the paper) does
        not clip. ``"auto"`` (the default): at :data:`~sb3_cmzdril.common.drift.AUTO_CLIP_QUANTILE` where the absorbing
        state is on and the pretrained clone falls (the env terminates one of the episodes it plays
        at the first ``learn()``), so that a fall costs at most the clip's reward; unclipped otherwise.
    :param disagreement: ``"std"`` (the paper), ``"quadratic"``, ``"std_unclipped"`` (Box actions) or
        ``"auto"`` (the default: unclipped where the demonstrations' actions hold a bound; see
        :mod:`sb3_cmzdril.ensemble`).
    :param ensemble_size: number of ensemble members (paper/DRIL: 5).
    :param ensemble_hidden: hidden layer widths of each member.
    :param ensemble_epochs: epochs of ensemble fitting.
    :param ensemble_batch_size: minibatch size of ensemble fitting.
    :param ensemble_learning_rate: Adam step size of ensemble fitting.
    :param standardize_observations: the policy sees observations standardised with fixed statistics
        of the demonstrations (the ensemble's; :mod:`sb3_cmzdril.policies`). False gives SB3's raw
        inputs (the paper-faithful setting); prefer it where the observations are already scaled to
        about unit range (WaypointNav-v0's, bounded in [-1, 1], cloned worse standardised). ``"auto"``
        (the default): only the entries the observation space leaves unbounded are standardised; a bounded one is
        scaled by the env already and is left as it is (the decision goes to :attr:`rules`). Ignored, with a warning,
        when a VecNormalize already normalises the observations.
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
        disables; a fraction is a pass over that share of the demo steps, drawn at random, so 0.25
        pulls the policy back to the demonstrations a quarter as hard). ``"auto"`` (the default): none
        where the pretrained clone falls (:func:`~sb3_cmzdril.common.drift.clone_falls`, from the episodes it
        plays at the first ``learn()``, whose steps are not counted) or, unless the expert ends its own
        episodes before the env's time limit, where the clone predicts the expert's held-out actions
        loosely (its NLL on the held-out demo steps, per action entry in units of half its bounds'
        range, at least :data:`~sb3_cmzdril.common.bc.AUTO_EPOCHS_NLL`: no probe needed): an epoch
        would pull the policy back to a poor clone. The paper's one elsewhere: it holds a close clone
        on the demonstrations, and keeps a clone's way to an end the expert reaches (a landing, a goal),
        which the disagreement reward does not ask for. The other rewards (DRIL's, the env's) keep the
        paper's one, as their methods define it. The decision and its reason go to :attr:`rules`.
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
        expert never terminates) or, where the expert ends its own episodes, when the env ends the
        pretrained clone's (played at the first ``learn()``) before
        :data:`~sb3_cmzdril.common.drift.EARLY_END_FRACTION` of the shortest demonstration's length on
        average (the expert's one episode ended in a fall, the clone falls at once). The default
        (False before 0.3.0, the paper): on Walker2d-v5 it doubled CMZ-DRIL's final return
        (docs/new_tasks.md).
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
        :mod:`sb3_cmzdril.cmzdril.scoring`); False scores every step inside a
        :class:`~sb3_cmzdril.rewards.DisagreementReward` wrapper, which a reward-normalising
        VecNormalize gets anyway. The rewards are the same.
    :param normalize_reward: divide the reward PPO learns from (the rule's, or the env's for
        ``reward="env"``) by the running standard deviation of its discounted return, as
        ``VecNormalize(norm_obs=False, norm_reward=True)`` does (:class:`~sb3_cmzdril.cmzdril.scoring.ReturnScale`),
        so that its size does not depend on the task's. Needs ``batch_scoring``; a VecNormalize that
        normalises rewards as well is refused. Logged as ``rollout/reward_scale``.

    Pretraining happens once, in the first ``learn()`` (or :meth:`pretrain`) of a model whose
    :attr:`pretrained` is False; it never overwrites weights the user brought (see :attr:`pretrained`).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = PPO.policy_aliases
    learner_name = "CMZDRIL"
    off_policy = False
    loads_plain_sb3 = True  # a PPO agent to go on from
    logs_pretraining = True
    defaults_before: ClassVar[dict[str, dict[str, Any]]] = {
        "0.3.0": {"absorbing": False, "cmz_clip_quantile": None, "disagreement": "std",
                  "standardize_observations": True, "bc_epochs_per_update": 1},  # the paper's (and DRIL's)
    }
    options_added: ClassVar[dict[str, dict[str, Any]]] = {  # in 0.1.0's development (commit b75741f7)
        "2026-11-21T18:56:23+00:00": {"standardize_observations": False, "bc_validation_fraction": 0.0,
                                      "log_std_floor": None},
    }

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
        cmz_clip_quantile: float | str | None = "auto",
        disagreement: str = "auto",
        ensemble_size: int = 5,
        ensemble_hidden: Sequence[int] = (64, 64),
        ensemble_epochs: int = 200,
        ensemble_batch_size: int = 64,
        ensemble_learning_rate: float = 1e-3,
        standardize_observations: bool | str = "auto",
        bc_pretrain_epochs: int = 1000,
        bc_validation_fraction: float = 0.2,
        bc_patience: int = 20,
        bc_refit: bool = False,
        bc_epochs_per_update: float | str = "auto",
        bc_update_std: bool = True,
        bc_batch_size: int = 64,
        bc_learning_rate: float | Schedule | str = 1e-3,
        log_std_floor: float | None = -1.0,
        absorbing: bool | str = "auto",
        absorbing_score: str = "highest",
        critic_warmup_updates: int = 0,
        batch_scoring: bool = True,
        normalize_reward: bool = False,
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
        if isinstance(bc_epochs_per_update, str) and bc_epochs_per_update != "auto":
            raise UserError(f"bc_epochs_per_update must be a number >= 0 or 'auto', got {bc_epochs_per_update!r}")
        if bc_epochs_per_update != "auto":
            check_finite(bc_epochs_per_update=bc_epochs_per_update)
            check_interval("[0, inf)", bc_epochs_per_update=bc_epochs_per_update)
        counts: dict[str, Any] = dict(critic_warmup_updates=critic_warmup_updates)
        self._init_imitation(**arguments_for(self._init_imitation, locals(), counts=counts))
        check_finite(
            bc_learning_rate=bc_learning_rate, log_std_floor=log_std_floor, learning_rate=learning_rate, gamma=gamma,
            gae_lambda=gae_lambda, clip_range=clip_range, clip_range_vf=clip_range_vf, ent_coef=ent_coef,
            vf_coef=vf_coef, max_grad_norm=max_grad_norm, target_kl=target_kl,
        )
        if log_std_floor is not None and not np.isfinite(log_std_floor):
            raise UserError(f"log_std_floor must be finite or None, got {log_std_floor}")
        _check_ppo_options(env, n_steps, batch_size, n_epochs, normalize_advantage)
        check_interval("[0, 1]", gamma=gamma, gae_lambda=gae_lambda)
        check_interval("(0, inf)", learning_rate=learning_rate, clip_range=clip_range, target_kl=target_kl,
                       max_grad_norm=max_grad_norm)
        check_interval("(0, inf)", OptionError, clip_range_vf=clip_range_vf)  # SB3 asserts this one
        check_interval("[0, inf)", vf_coef=vf_coef)
        self.bc_refit = bool(bc_refit)
        self.bc_epochs_per_update: float | str = (
            "auto" if isinstance(bc_epochs_per_update, str) else _whole_if_whole(bc_epochs_per_update)
        )
        self.bc_update_std = bool(bc_update_std)
        #: a number or a schedule of the progress remaining (see :meth:`_bc_learning_rate`)
        self.bc_learning_rate: float | Schedule = parse_schedule(bc_learning_rate, "bc_learning_rate")
        self.log_std_floor = None if log_std_floor is None else float(log_std_floor)
        self.critic_warmup_updates = int(critic_warmup_updates)
        #: value-only updates done so far (saved with the model: a resumed run does not warm up again)
        self.critic_warmup_done = 0
        self.batch_scoring = bool(batch_scoring)
        if normalize_reward and not batch_scoring:
            raise UserError("normalize_reward=True needs batch_scoring=True (or a VecNormalize(norm_reward=True) "
                            "around the env instead)")
        self.normalize_reward = bool(normalize_reward)
        #: the running scale of normalize_reward (saved with the model: a resumed run goes on with it)
        self.return_scale: ReturnScale | None = None
        self.rollout_disagreement: float | None = None
        #: whether the policy was trained on VecNormalize'd observations (saved with the model, so that
        #: an evaluation without the statistics can be refused instead of silently wrong)
        self.vecnormalize_obs = False
        env = made_env(env, verbose)
        super().__init__(**arguments_for(PPO.__init__, locals(), _init_setup_model=False))
        self._check_reward_normalisation()
        if _init_setup_model:
            self._setup_model()

    # -- the imitation part's hooks ---------------------------------------------------------------
    def _check_learner_spaces(self) -> None:
        check_action_space(self.action_space)

    def _make_cloner(self, seed: int) -> BehaviourCloner:
        return BehaviourCloner(self.policy, self.bc_batch_size, self._bc_learning_rate(1.0), self.max_grad_norm,
                               seed=seed)

    def _demo_obs_transform(self) -> Any:
        vec_normalize = self.get_vec_normalize_env()
        if vec_normalize is not None and vec_normalize.norm_obs:
            return vec_normalize.normalize_obs
        return None

    def _pretrain_policy(self, progress_bar: bool) -> dict[str, float]:
        """Set the policy's input standardisation and clone the demos by NLL; the statistics of it."""
        assert self.demonstrations is not None
        transform = self._demo_obs_transform()
        self._fit_standardizers(transform)
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

    def _cloning_summary(self, info: dict[str, float]) -> str:
        return (
            f"BC NLL {info['bc_nll_before']:.3f} -> {info['bc_nll_after']:.3f} (best of {int(info['bc_epochs'])} "
            f"epochs: {int(info['bc_best_epoch'])}, {info['bc_seconds']:.1f}s)"
        )

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

    # -- training ---------------------------------------------------------------------------------
    def learn(self: SelfCMZDRIL, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 1,
              tb_log_name: str = "CMZDRIL", reset_num_timesteps: bool = True,
              progress_bar: bool = False) -> SelfCMZDRIL:
        """PPO's ``learn``, after pretraining if the model is not :attr:`pretrained` yet."""
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, progress_bar)

    def _prepare_learning(self, progress_bar: bool) -> None:
        # learn() has pretrained already. A caller driving collect_rollouts itself after _setup_learn
        # (as SB3's own tests do) gets what scoring needs, the fitted ensemble and the reward rule,
        # and a policy left as it is (pretraining belongs to learn() or pretrain()).
        if self.reward_rule is None:
            if self.demonstrations is None:
                self.pretrain()  # refuses, naming the missing demonstrations
            assert self.demonstrations is not None
            self.demonstrations = self.demonstrations.check_spaces(self.observation_space, self.action_space)
            self.bc.set_demonstrations(self.demonstrations)
            self._prepare_reward(progress_bar)
        self._check_reward_normalisation()
        vec_normalize = self.get_vec_normalize_env()
        self._decide_from_the_clone()
        self._wrap_training_env()
        self.vecnormalize_obs = self.vecnormalize_obs or bool(vec_normalize is not None and vec_normalize.norm_obs)

    def _check_reward_normalisation(self) -> None:
        """UserError where ``normalize_reward`` and a reward-normalising VecNormalize would both divide
        the reward: at construction (before a run writes anything) and again at ``learn()`` (``set_env``)."""
        vec_normalize = self.get_vec_normalize_env()
        if getattr(self, "normalize_reward", False) and vec_normalize is not None and vec_normalize.norm_reward:
            raise UserError("normalize_reward=True and a VecNormalize that normalises rewards would divide the reward "
                            "twice: set norm_reward=False on the VecNormalize, or normalize_reward=False")

    def _decide_from_the_clone(self) -> None:
        """The ``"auto"`` settings read from the pretrained clone's own episodes, each decided once per
        model (a loaded one keeps its decisions; :func:`~sb3_cmzdril.common.drift.clone_drift` plays
        them): ``bc_epochs_per_update`` by whether it falls (where it predicts the held-out demo steps
        closely), ``cmz_clip_quantile`` by whether the env terminates its episodes, and
        ``absorbing`` where the expert ends its own episodes by how soon the env ends the clone's."""
        bc = self.bc_epochs_per_update == "auto" and "bc_epochs_per_update" not in self.rules
        if bc and self.reward != "cmz":  # a baseline runs as its method defines it (DRIL's own BC step)
            self._record_rule("bc_epochs_per_update", 1,
                              f"the {self.reward!r} reward keeps the paper's NLL epoch after each update, as its "
                              "method defines it; the rule decides only for the 'cmz' reward")
            bc = False
        held_out = nll_per_action_entry(self.pretrain_info.get("bc_validation_nll", float("nan")), self.action_space)
        expert_ends = (self.demonstrations is not None and self.env is not None and time_limit(self.env) is not None
                       and not expert_never_terminates(self.demonstrations, self.env))
        loose = held_out is not None and held_out >= AUTO_EPOCHS_NLL
        if bc and loose and not expert_ends:  # decided without a probe
            self._record_rule(
                "bc_epochs_per_update", 0,
                f"the clone's NLL on the held-out demo steps is {held_out:.2f} per action entry (in units of half "
                f"its bounds' range), at least {AUTO_EPOCHS_NLL:g}: it predicts the expert's actions loosely, and "
                "no NLL epoch pulls the policy toward it")
            bc = False
        clip = self.cmz_clip_quantile == "auto" and self.reward == "cmz" and "cmz_clip_quantile" not in self.rules
        # where the expert ends its own episodes, absorbing="auto" asks how soon the env ends the clone's
        ends = self.absorbing == "auto" and self.reward == "cmz" and self.clone_ends is None and expert_ends
        if not (bc or clip or ends) or not (bc or ends or self._absorbing_applies()):
            if clip:  # without an absorbing state there is no fall to clip, and nothing else to probe
                self._record_rule("cmz_clip_quantile", None, _NO_ABSORBING)
            return
        if self.env is None:
            raise UserError("CMZDRIL.learn() needs an environment: pass env= to the constructor or to load()")
        assert self.demonstrations is not None
        vec_normalize = self.get_vec_normalize_env()

        def disagreement(raw_obs: Any) -> np.ndarray:
            return disagreement_where_ended(self.ensemble, self.policy, raw_obs, self.action_space, vec_normalize)

        drift = clone_drift(self.policy, self.env, disagreement,
                            float(np.mean(disagreement_on_demos(self.ensemble, self.demonstrations))), vec_normalize)
        if self.seed is not None:
            self.env.seed(self.seed)  # the first rollout starts where it would have without the probe
        self._last_obs = None  # learn() resets the env after the probe
        if ends:
            self.clone_ends = [float(np.mean(drift.terminated_lengths)) if drift.terminated_lengths else float("inf"),
                               int(np.min(self.demonstrations.episode_lengths))]
        if bc:
            falls, why = clone_falls(drift, self.demonstrations.episode_lengths, time_limit(self.env))
            why += f" (its path scores u {drift.ratio:.2f} times its mean on the demonstrations)"
            close = ("no held-out NLL to judge the clone by" if held_out is None else
                     f"its held-out NLL is {held_out:.2f} per action entry, under {AUTO_EPOCHS_NLL:g}" if not loose
                     else f"the expert ends its own episodes, an end the disagreement reward does not ask for "
                          f"(its held-out NLL, {held_out:.2f} per action entry, is not asked)")
            self._record_rule(
                "bc_epochs_per_update", 0 if falls else 1,
                f"{why}: the clone falls, so no NLL epoch pulls the policy back to it" if falls else
                f"{why}, and {close}: the clone does not fall, and one NLL epoch after each update holds the "
                "policy on the demonstrations")
        if clip and not self._absorbing_applies():
            self._record_rule("cmz_clip_quantile", None, _NO_ABSORBING)
        elif clip:
            falls = drift.terminated > 0
            ended = f"the env terminated {drift.terminated} of the clone's {drift.episodes} episodes"
            early = "" if ends else ", where no demonstration ends early"
            self._record_rule(
                "cmz_clip_quantile", AUTO_CLIP_QUANTILE if falls else None,
                f"{ended}{early}: u is clipped, so a fall costs at most the clip's reward"
                if falls else f"{ended}: the clone does not fall, u is left unclipped",
            )
            if falls:
                self.dril_threshold, self.cmz_u_max = rule_bounds(
                    self.reward, self.ensemble, self.demonstrations, self.dril_quantile, self.clip_quantile)
                self.reward_rule = self._make_rule()

    @property
    def bc_epochs_active(self) -> float:
        """NLL epochs after each PPO update: ``bc_epochs_per_update``, or what ``"auto"`` decided (the
        paper's 1 until it has)."""
        if self.bc_epochs_per_update != "auto":
            return float(self.bc_epochs_per_update)
        return float(self.rules.get("bc_epochs_per_update", {}).get("value", 1))

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
            learned = scores.rewards if self.reward != "env" else record.env_rewards
            stats = scores.stats()
            if getattr(self, "normalize_reward", False):  # a model saved before the option has none
                if self.return_scale is None:
                    self.return_scale = ReturnScale(self.gamma)
                learned = self.return_scale.apply(learned, record.dones)
                stats["reward_scale"] = self.return_scale.scale
            if learned is not record.env_rewards:
                # Swap the env reward for the one learned from; the truncation bootstrap in the buffer stays.
                buffer.rewards += learned - record.env_rewards
                buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
        for key, value in stats.items():
            self.logger.record(f"rollout/{key}", value)
        self.rollout_disagreement = stats.get("disagreement_mean")
        self._log_reward_state(absorbing=self._absorbing_gamma() is not None)

    def _bc_learning_rate(self, progress_remaining: float) -> float:
        """The NLL epochs' step size at ``progress_remaining`` (1 at the start of ``learn()``, 0 at its end)."""
        rate = self.bc_learning_rate
        return float(rate(progress_remaining)) if callable(rate) else float(rate)

    def train(self) -> None:
        self._update()
        self.policy.set_training_mode(False)  # between updates the policy acts: batch norm, dropout in eval mode

    def _update(self) -> None:
        """One PPO update (of the critic alone while it warms up), then the NLL epochs."""
        if self.critic_warmup_done < self.critic_warmup_updates:
            with _critic_only(self.policy):
                super().train()
            self.critic_warmup_done += 1
            self.logger.record("train/critic_warmup", 1.0)
            return
        super().train()
        if self.bc_epochs_active and self.demonstrations is not None:
            transform = self._demo_obs_transform()
            held = [] if self.bc_update_std else _log_std_parameters(self.policy)
            bc_lr = self._bc_learning_rate(self._current_progress_remaining)
            update_learning_rate(self.bc.optimizer, bc_lr)
            self.logger.record("train/bc_learning_rate", bc_lr)
            whole, part = divmod(self.bc_epochs_active, 1.0)
            with _without_gradient(held):
                for _ in range(int(whole)):
                    nll = self.bc.epoch(transform)
                if part > 0:
                    nll = self.bc.epoch(transform, fraction=part)
            self.logger.record("train/bc_nll", nll)


def _whole_if_whole(value: float) -> float:
    """``value`` as an int where it is a whole number (``2.0`` -> ``2``), as it is otherwise."""
    return int(value) if float(value).is_integer() else float(value)


#: cmz_clip_quantile="auto"'s reason where terminations score nothing
_NO_ABSORBING = "no absorbing state: an episode's end costs nothing to clip"


def _check_ppo_options(
    env: GymEnv | str | None, n_steps: Any, batch_size: Any, n_epochs: Any, normalize_advantage: bool
) -> None:
    """UserError, in one line, for the rollout and update sizes PPO cannot learn with: ``n_epochs=0``
    (PPO accepts it and then fails inside ``train()``), ``n_steps`` or ``batch_size`` below 1, and
    below 2 where ``normalize_advantage`` normalises each minibatch and the rollout (SB3's own
    checks of these are assertions, whose traceback says nothing of the option)."""
    check_whole_numbers(1, n_steps=n_steps, n_epochs=n_epochs)
    # SB3's words and its AssertionError (an OptionError): with normalize_advantage, the advantages of one
    # step normalise to nan.
    if normalize_advantage and isinstance(batch_size, (int, np.integer)) and batch_size < 2:
        raise OptionError(f"`batch_size` must be greater than 1 with normalize_advantage=True, got {batch_size}")
    check_whole_numbers(1, batch_size=batch_size)
    n_envs = env.num_envs if isinstance(env, VecEnv) else 1
    if normalize_advantage and env is not None and n_steps * n_envs < 2:
        raise OptionError(f"`n_steps * n_envs` must be greater than 1 with normalize_advantage=True, got "
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


__all__ = ["CMZDRIL"]
