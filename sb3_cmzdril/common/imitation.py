"""The imitation part both learners compose: :class:`ImitationLearner`, the mixin that CMZDRIL (PPO) and
CMZDRILSAC (SAC) put in front of their RL algorithm, and the pieces it is made of.

It holds, once for both: the demonstrations (taken as a :class:`~sb3_cmzdril.data.demos.Demonstrations`, a
path or a list of episode dicts, checked against the spaces), the bootstrap ensemble (built in
``_setup_model``, fitted by :meth:`~ImitationLearner.pretrain`), the reward rule the options name
(with the bounds it takes from the fitted ensemble: DRIL's threshold, the CMZ clip), pretraining (the
learner clones the demonstrations into its policy, then the ensemble is fitted and the rule made),
one notion of "pretrained" (:attr:`~ImitationLearner.pretrained`), and the save/load of all of it in
one format (:mod:`sb3_cmzdril.common.saving`). A learner adds what its RL algorithm needs: how it
clones (NLL of the policy, or squared error of SAC's actor), how the reward reaches the algorithm
(rollouts scored from PPO's buffer, rewards relabelled in SAC's replay buffer) and its own options.

A learner sets :attr:`~ImitationLearner.learner_name` and :attr:`~ImitationLearner.off_policy`,
hands its constructor's arguments to :meth:`~ImitationLearner._init_imitation` and on to its
algorithm (:func:`arguments_for`), and implements the hooks ``_check_learner_spaces``,
``_make_cloner``, ``_pretrain_policy``, ``_cloning_summary`` and ``_prepare_learning`` (and
``_check_demonstrations`` where it needs more of the demonstrations).
"""
from __future__ import annotations

import inspect
import logging
import time
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm, maybe_make_env
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.vec_env import VecNormalize

from sb3_cmzdril._mujoco_log import mujoco_warnings_routed
from sb3_cmzdril.common.bc import BehaviourCloner, ObsTransform
from sb3_cmzdril.common.drift import EARLY_END_FRACTION, falls_early
from sb3_cmzdril.common.options import check_imitation_options, check_interval, check_whole_numbers
from sb3_cmzdril.common.saving import (
    SAVED_TENSORS,
    check_saved_learner,
    demo_tensors,
    demonstrations_to_go_on,
    demos_from_tensors,
    pack_observations,
    parameters_to_set,
    restored_state,
    restoring,
    restoring_saved_model,
    unpack_observations,
    weights_brought_by_user,
)
from sb3_cmzdril.data.demos import Demonstrations, as_demonstrations, expert_never_terminates, time_limit
from sb3_cmzdril.data.spaces import indices_as_actions
from sb3_cmzdril.ensemble import AUTO_UNCLIPPED_SHARE, BCEnsemble, quantile_of_disagreement, share_on_bound
from sb3_cmzdril.errors import UserError, check_finite
from sb3_cmzdril.io import PathLike
from sb3_cmzdril.policies import DemoStandardizer, standardizing_policy_kwargs
from sb3_cmzdril.rewards import RewardRule, make_rule

logger = logging.getLogger(__name__)

#: What a learner's ``demonstrations`` takes: a Demonstrations, a path to a saved one (demos.npz), a
#: list of episode dicts, or None (then before the first ``learn()``, to the constructor or to ``load()``).
DemosLike = Demonstrations | PathLike | list | None

SelfImitationLearner = TypeVar("SelfImitationLearner", bound="ImitationLearner")

def arguments_for(function: Callable[..., Any], arguments: dict[str, Any], **given: Any) -> dict[str, Any]:
    """The keyword arguments to hand on to ``function`` from a learner's constructor: the values in
    ``arguments`` (the constructor's ``locals()``) of the parameters ``function`` takes, as they are,
    and ``given``, which replace them."""
    names = [name for name in inspect.signature(function).parameters if name != "self"]
    return {**{name: arguments[name] for name in names if name in arguments}, **given}


def made_env(env: GymEnv | str, verbose: int) -> GymEnv:
    """``env``, made (as SB3 makes it) where it is an id, with MuJoCo's notices at model compile (e.g.
    HalfCheetah's settotalmass) routed to the log."""
    if not isinstance(env, str):
        return env
    with mujoco_warnings_routed():
        return maybe_make_env(env, verbose)


def reward_rule(
    reward: str, alpha: float, ema: float, u0: float, dril_threshold: float | None, u_max: float | None = None
) -> RewardRule:
    """The rule a model's options name (``dril_threshold``: computed from the fitted ensemble)."""
    if reward == "cmz":
        return make_rule("cmz", alpha=alpha, ema=ema, u0=u0, u_max=u_max)
    if reward == "dril":
        assert dril_threshold is not None, "the DRIL threshold is computed when the ensemble is fitted"
        return make_rule("dril", threshold=dril_threshold)
    return make_rule(reward)


def rule_bounds(
    reward: str, ensemble: Any, demos: Demonstrations, dril_quantile: float, cmz_clip_quantile: float | None
) -> tuple[float | None, float | None]:
    """What the rule takes from the fitted ensemble: DRIL's threshold (``reward="dril"``) and the CMZ
    reward's clip of u (``reward="cmz"`` with ``cmz_clip_quantile``), each the named quantile of u on
    the demos, else None."""
    dril_threshold = quantile_of_disagreement(ensemble, demos, dril_quantile) if reward == "dril" else None
    u_max = None
    if reward == "cmz" and cmz_clip_quantile is not None:
        u_max = quantile_of_disagreement(ensemble, demos, cmz_clip_quantile)
        if not u_max > 0:  # an ensemble that agrees exactly on most demo steps: a clip at 0 erases the reward
            raise UserError(
                f"cmz_clip_quantile={cmz_clip_quantile} clips u at {u_max:.4g}, the ensemble's disagreement "
                "on that share of the demos; choose a higher quantile or None"
            )
    return dril_threshold, u_max


def disagreement_where_ended(
    ensemble: Any, policy: Any, raw_obs: Any, action_space: spaces.Space, vec_normalize: VecNormalize | None = None
) -> np.ndarray:
    """The ensemble's u at a batch of raw observations episodes ended in; where u needs actions, at
    the policy's deterministic ones there (no action was taken in them), as the space's actions."""
    actions = None
    if getattr(ensemble, "needs_actions", True):
        policy_obs = raw_obs if vec_normalize is None else vec_normalize.normalize_obs(raw_obs)
        predicted = np.asarray(policy.predict(policy_obs, deterministic=True)[0])
        actions = buffer_actions(predicted.reshape(len(predicted), -1), action_space)
    return ensemble.disagreement(raw_obs, actions)


def buffer_actions(actions: np.ndarray, space: spaces.Space) -> np.ndarray:
    """The rollout buffer's actions (what the policy output, flattened) as the space's actions:
    Box clipped to its bounds as SB3 clips them before the env sees them; Discrete and MultiDiscrete
    indices shifted by the space's ``start``."""
    if isinstance(space, spaces.Box):
        return np.clip(actions, space.low.reshape(-1), space.high.reshape(-1))
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        return indices_as_actions(actions, space)
    return actions


# mypy reads the mixin as the SB3 algorithm it stands in front of; at run time it is a plain class
# (the learner's other base is the algorithm).
if TYPE_CHECKING:
    _Algorithm = BaseAlgorithm
else:
    _Algorithm = object


class ImitationLearner(_Algorithm):
    """CMZ-DRIL's imitation part, for a learner ``class L(ImitationLearner, <SB3 algorithm>)``: the
    demonstrations, the bootstrap ensemble, the reward rule, pretraining, :attr:`pretrained` and the
    save/load of all of it (see the module's docstring)."""

    #: the learner's name, in messages and in the check of what a zip holds (:meth:`load`)
    learner_name: ClassVar[str]
    #: whether the learner learns off-policy (its ``load()`` refuses the other kind's zips)
    off_policy: ClassVar[bool]
    #: whether ``load()`` takes a plain SB3 zip of the learner's kind (CMZDRIL loads a PPO's)
    loads_plain_sb3: ClassVar[bool] = False
    #: whether ``learn()`` logs what pretraining measured (``pretrain/*``) at its first dump
    logs_pretraining: ClassVar[bool] = False
    #: the policy's ``policy_kwargs`` when none are given: SB3's (nothing) unless the learner says
    default_policy_kwargs: ClassVar[dict[str, Any]] = {}
    #: constructor defaults a release changed, by that release: what a run made by an earlier version got
    #: for an argument it left out (its records name the version), e.g. ``{"0.3.0": {"absorbing": False}}``
    defaults_before: ClassVar[dict[str, dict[str, Any]]] = {}
    #: arguments added within a release, by when (UTC, ISO 8601): the value that runs as the code did
    #: before they existed, for a run made earlier (its records name when: config.json's ``created_at``)
    options_added: ClassVar[dict[str, dict[str, Any]]] = {}

    demonstrations: Demonstrations | None
    ensemble: BCEnsemble
    bc: BehaviourCloner
    #: the reward rule, made for the fitted ensemble by :meth:`pretrain` (None before)
    reward_rule: RewardRule | None
    dril_threshold: float | None
    cmz_u_max: float | None
    _saved_demo_obs: th.Tensor
    _saved_reward_state: th.Tensor
    _saved_absorbing_u: th.Tensor

    # -- construction --------------------------------------------------------------------------
    def _init_imitation(
        self,
        demonstrations: DemosLike,
        reward: str,
        alpha: float,
        ema: float,
        u0: float,
        dril_quantile: float,
        cmz_clip_quantile: float | str | None,
        disagreement: str,
        ensemble_size: int,
        ensemble_hidden: Sequence[int],
        ensemble_epochs: int,
        ensemble_batch_size: int,
        ensemble_learning_rate: float,
        standardize_observations: bool | str,
        bc_pretrain_epochs: int,
        bc_validation_fraction: float,
        bc_patience: int,
        bc_batch_size: int,
        absorbing: bool | str,
        absorbing_score: str,
        counts: dict[str, int] | None = None,
    ) -> None:
        """Check the options both learners take (the constructor's arguments of these names, with the
        same meaning in both; ``counts``: the learner's own options that must be whole numbers >= 0)
        and keep them. Run first in the constructor, before anything is built."""
        check_finite(alpha=alpha, ema=ema, u0=u0, dril_quantile=dril_quantile, cmz_clip_quantile=cmz_clip_quantile,
                     ensemble_learning_rate=ensemble_learning_rate, bc_validation_fraction=bc_validation_fraction)
        check_imitation_options(
            reward, alpha, ema, u0, dril_quantile, bc_pretrain_epochs, bc_validation_fraction, bc_patience, absorbing,
            cmz_clip_quantile, absorbing_score, **(counts or {}),
        )
        check_whole_numbers(1, ensemble_epochs=ensemble_epochs, ensemble_batch_size=ensemble_batch_size,
                            bc_batch_size=bc_batch_size)
        check_interval("(0, inf)", ensemble_learning_rate=ensemble_learning_rate)
        self.demonstrations = None if demonstrations is None else as_demonstrations(demonstrations)
        self.reward = reward
        self.alpha = float(alpha)
        self.ema = float(ema)
        self.u0 = float(u0)
        self.dril_quantile = float(dril_quantile)
        self.dril_threshold = None
        self.cmz_clip_quantile: float | str | None = (
            cmz_clip_quantile if cmz_clip_quantile in (None, "auto") else float(cmz_clip_quantile)
        )
        #: the CMZ reward's clip of u (``cmz_clip_quantile`` of u on the demos), computed with the ensemble
        self.cmz_u_max = None
        self.disagreement = disagreement
        self.ensemble_size = int(ensemble_size)
        self.ensemble_hidden = tuple(int(h) for h in ensemble_hidden)
        self.ensemble_epochs = int(ensemble_epochs)
        self.ensemble_batch_size = int(ensemble_batch_size)
        self.ensemble_learning_rate = float(ensemble_learning_rate)
        if standardize_observations not in (True, False, "auto"):
            raise UserError(f"standardize_observations must be True, False or 'auto', got {standardize_observations!r}")
        self.standardize_observations: bool | str = (
            "auto" if standardize_observations == "auto" else bool(standardize_observations)
        )
        self.bc_pretrain_epochs = int(bc_pretrain_epochs)
        self.bc_validation_fraction = float(bc_validation_fraction)
        self.bc_patience = int(bc_patience)
        self.bc_batch_size = int(bc_batch_size)
        self.absorbing = absorbing
        self.absorbing_score = absorbing_score
        #: whether terminations are scored as an absorbing state (``absorbing`` resolved at ``learn()``)
        self.absorbing_active = False
        #: what the last pretraining measured (losses, epochs, timings) and its per-epoch curves
        self.pretrain_info: dict[str, float] = {}
        self.pretrain_history: dict[str, list[float]] = {}
        #: the policy holds pretrained (or brought) weights: pretraining leaves it alone
        self._policy_pretrained = False
        #: the reward rule and its bounds are made for the current fitted ensemble. None only while
        #: ``load()`` runs, until the zip's value replaces it (a zip without one: see _restore_saved_state)
        self._imitation_ready: bool | None = None if restoring() else False
        #: pretrain/* keys waiting for learn()'s logger (it is made after pretraining, in _setup_learn)
        self._pretrain_log_pending = False
        #: how a Dict space's demo observations are packed into one saved tensor (None: not a dict)
        self._demo_obs_layout: list | None = None
        #: what each ``"auto"`` setting was decided to be, and why: ``{name: {"value": ..., "reason": ...}}``
        self.rules: dict[str, dict[str, Any]] = {}
        #: where the expert ends its own episodes, the mean length of the clone's episodes the env ended in its
        #: first ``learn()`` (a learner that plays its clone sets it) and the shortest demonstration's length
        self.clone_ends: list[float] | None = None

    def _setup_model(self) -> None:
        self._check_learner_spaces()
        if self.standardize_observations:
            self.policy_kwargs, note = standardizing_policy_kwargs(
                self.policy_class, self.policy_kwargs, self.observation_space
            )
            if note is not None:
                logger.info(note)
                if self.verbose >= 1:
                    print(note)
        super()._setup_model()  # type: ignore[safe-super]  # the learner's algorithm's
        # seed=None: draw from the global RNG, which SB3's set_random_seed (or the user) controls.
        seed = int(np.random.randint(0, 2**31 - 1)) if self.seed is None else int(self.seed)
        self.ensemble_hidden = tuple(self.ensemble_hidden)  # a loaded model gets a JSON list back
        self.ensemble = BCEnsemble(
            self.observation_space, self.action_space, self.ensemble_size, self.ensemble_hidden, self.disagreement, seed
        ).to(self.device)
        self.bc = self._make_cloner(seed)
        self.reward_rule = None
        for name in SAVED_TENSORS:
            setattr(self, name, th.zeros(0))

    def _check_learner_spaces(self) -> None:
        """UserError where the learner cannot learn in the env's spaces (before anything is built)."""
        raise NotImplementedError

    def _make_cloner(self, seed: int) -> BehaviourCloner:
        """The learner's behaviour cloning of the demonstrations into its policy."""
        raise NotImplementedError

    # -- pretrained ----------------------------------------------------------------------------
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
        refit from scratch at the next ``learn()``. Either way the reward rule (and the bounds it takes
        from the ensemble) is made again for the ensemble at the next ``learn()``.
        """
        return self._policy_pretrained and self.ensemble.is_fitted

    @pretrained.setter
    def pretrained(self, value: bool) -> None:
        self._policy_pretrained = bool(value)
        if not value:
            self.ensemble.mark_unfitted()
        elif not self.ensemble.is_fitted:  # members loaded by hand: "auto" reads its form from the demos
            self.ensemble.mark_fitted(None if self.demonstrations is None else self.demonstrations.actions)
        self._imitation_ready = False  # the rule (and its bounds) is remade for the ensemble at learn()

    @property
    def absorbing_u(self) -> float:
        """The absorbing state's disagreement: the highest u scored so far, kept by the reward rule
        (0 before any)."""
        return 0.0 if self.reward_rule is None else self.reward_rule.absorbing_u

    # -- pretraining ---------------------------------------------------------------------------
    def pretrain(self, progress_bar: bool = False) -> dict[str, float]:
        """Check the demos, set the policy's input standardisation and clone the demos into it (early
        stopping on held-out demo steps), fit the ensemble and make the reward rule for it, each
        unless already done or loaded (:attr:`pretrained`); later calls only re-check the demos.
        Returns the losses, epochs and timings of what ran; the per-epoch curves are in
        ``pretrain_history``. A learner that logs them (CMZDRIL) records them as ``pretrain/*`` at the
        next ``learn()``'s first dump."""
        if self.demonstrations is None:
            raise UserError(
                f"{self.learner_name} needs demonstrations: pass demonstrations=... (a Demonstrations, a path to a "
                "demos.npz, or a list of episode dicts) to the constructor or to load()"
            )
        self.demonstrations = self.demonstrations.check_spaces(self.observation_space, self.action_space)
        self._check_demonstrations(self.demonstrations)
        self.bc.set_demonstrations(self.demonstrations)
        if self._imitation_ready:
            return self.pretrain_info
        info: dict[str, float] = {}
        if not self._policy_pretrained:
            info.update(self._pretrain_policy(progress_bar))
            self._policy_pretrained = True
        info.update(self._prepare_reward(progress_bar, remake_rule=True))
        self._imitation_ready = True
        if info:
            self.pretrain_info = info
            self._pretrain_log_pending = self.logs_pretraining
        if self.verbose >= 1:
            print(self._pretrain_summary(info))
        return self.pretrain_info

    def _check_demonstrations(self, demos: Demonstrations) -> None:
        """UserError where the learner cannot learn from ``demos`` (already checked against the spaces)."""

    def _pretrain_policy(self, progress_bar: bool) -> dict[str, float]:
        """Set the policy's input standardisation and clone the demos into it; what that measured
        (``bc_seconds`` among it)."""
        raise NotImplementedError

    def _cloning_summary(self, info: dict[str, float]) -> str:
        """The verbose words of what :meth:`_pretrain_policy` measured (``info``)."""
        raise NotImplementedError

    def _fit_standardizers(self, obs_transform: ObsTransform | None = None) -> None:
        """Set the policy's input standardisation (one per features extractor) to the demos'
        statistics; where ``obs_transform`` (a VecNormalize's) normalises the observations already, it
        is left as the identity: a rule's decision for ``"auto"``, a warning where it was asked for."""
        assert self.demonstrations is not None
        standardizers = [m for m in self.policy.modules() if isinstance(m, DemoStandardizer)]
        if standardizers and obs_transform is not None:
            if self.standardize_observations == "auto":
                self._record_rule("standardize_observations", False,
                                  "a VecNormalize normalises the observations already: the policy sees its inputs")
            else:
                warnings.warn(
                    "VecNormalize normalises the observations already: the demo standardisation of the policy "
                    f"is left as the identity ({self.learner_name}(standardize_observations=False) silences this)",
                    UserWarning,
                    stacklevel=4,
                )
            return
        by_bounds = self.standardize_observations == "auto"
        scaled = [standardizer.fit(self.demonstrations.observations, by_bounds) for standardizer in standardizers]
        if by_bounds and scaled:
            bounded, total = scaled[0]
            value = False if bounded == total else True if bounded == 0 else "unbounded entries"
            self._record_rule("standardize_observations", value,
                              f"{bounded} of {total} observation entries have finite bounds in the observation space: "
                              "the env scales those, every other one is standardised by the demonstrations")

    def _prepare_reward(self, progress_bar: bool = False, remake_rule: bool = False) -> dict[str, float]:
        """Fit the ensemble (unless fitted or loaded) and make the reward rule (and its bounds): what
        scoring needs. ``remake_rule``: for an ensemble that may be new. Returns the fit's loss and
        time, {} when the ensemble was kept."""
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
        self._record_disagreement_rule()
        missing = (self.reward == "dril" and self.dril_threshold is None) or (
            self.reward == "cmz" and self.clip_quantile is not None and self.cmz_u_max is None
        )
        if remake_rule or missing:
            self.dril_threshold, self.cmz_u_max = rule_bounds(
                self.reward, self.ensemble, self.demonstrations, self.dril_quantile, self.clip_quantile
            )
        if remake_rule or self.reward_rule is None:
            self.reward_rule = self._make_rule()
        return info

    @property
    def clip_quantile(self) -> float | None:
        """``cmz_clip_quantile`` resolved: what ``"auto"`` decided (no clip until it has)."""
        if self.cmz_clip_quantile == "auto":
            return self.rules.get("cmz_clip_quantile", {}).get("value")
        return self.cmz_clip_quantile  # type: ignore[return-value]

    def _make_rule(self) -> RewardRule:
        return reward_rule(self.reward, self.alpha, self.ema, self.u0, self.dril_threshold, self.cmz_u_max)

    def _pretrain_summary(self, info: dict[str, float]) -> str:
        """The verbose line of :meth:`pretrain`: what ran, and what was kept as loaded."""
        bc = self._cloning_summary(info) if "bc_seconds" in info else "policy kept as loaded"
        if "ensemble_loss" in info:
            fit = f"ensemble loss {info['ensemble_loss']:.4g} ({info['ensemble_seconds']:.1f}s)"
        else:
            fit = "ensemble kept as loaded"
        threshold = f"; DRIL threshold {self.dril_threshold:.4g}" if self.dril_threshold is not None else ""
        if self.cmz_u_max is not None:
            threshold += f"; CMZ reward clips u at {self.cmz_u_max:.4g}"
        return f"{self.learner_name} pretraining: {bc}; {fit}{threshold}"

    # -- learning ------------------------------------------------------------------------------
    def learn(
        self: SelfImitationLearner,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 100,
        tb_log_name: str = "run",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfImitationLearner:
        """The RL algorithm's ``learn``, after pretraining if the model is not :attr:`pretrained` yet."""
        # Rollouts step MuJoCo: its warnings (e.g. unstable simulation) go to stderr, not MUJOCO_LOG.TXT.
        with mujoco_warnings_routed():
            self.pretrain(progress_bar=progress_bar)
            return super().learn(  # type: ignore[safe-super]  # the learner's algorithm's
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
        self._prepare_learning(progress_bar)
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        # learn()'s logger (TensorBoard included) exists only from here: pretraining ran before it.
        if self._pretrain_log_pending:
            for key, value in self.pretrain_info.items():
                self.logger.record(f"pretrain/{key}", value)
            self._pretrain_log_pending = False
        return result

    def _prepare_learning(self, progress_bar: bool) -> None:
        """What ``learn()`` needs before the RL algorithm sets up (a caller driving the algorithm
        after ``_setup_learn`` itself, as SB3's own tests do, gets it as well): the reward rule and the
        way its rewards reach the algorithm."""
        raise NotImplementedError

    def _absorbing_applies(self) -> bool:
        """``absorbing`` resolved: ``"auto"`` is the ``"cmz"`` reward where the expert never terminates
        (the decision and its reason go to :attr:`rules`)."""
        if self.absorbing != "auto":
            return bool(self.absorbing)
        if self.reward != "cmz" or self.demonstrations is None or self.env is None:
            return False
        on = expert_never_terminates(self.demonstrations, self.env)
        limit = time_limit(self.env)
        lengths = self.demonstrations.episode_lengths
        if on:
            reason = (f"every demonstration lasts the env's time limit ({limit} steps): an episode that ends "
                      "earlier is one the expert never had")
        elif limit is None:
            reason = "the env has no time limit in its spec, so an early end cannot be told from the expert's"
        else:
            reason = (f"{int(np.sum(lengths < limit))} of {len(lengths)} demonstrations end before the env's "
                      f"time limit ({limit} steps): the expert ends its own episodes")
            if self.clone_ends is not None:
                clone, shortest = self.clone_ends
                on = falls_early(clone, shortest)
                if not np.isfinite(clone):
                    reason += "; the env ends none of the clone's episodes, so none of them is a fall"
                else:
                    reason += (f"; the env ends the clone's after {clone:.0f} steps on average, "
                               + (f"under {EARLY_END_FRACTION:g} times the shortest demonstration's {shortest}: the "
                                  "clone falls" if on else f"at least {EARLY_END_FRACTION:g} times the shortest "
                                  f"demonstration's {shortest}: as the expert ends them"))
        self._record_rule("absorbing", on, reason)
        return on

    def _record_rule(self, name: str, value: Any, reason: str) -> None:
        """Keep a setting an ``"auto"`` rule decided, with why, in :attr:`rules`, and say it once in a log
        line (the command line prints it; a run's records keep :attr:`rules`)."""
        decided = {"value": value, "reason": reason}
        if self.rules.get(name) != decided:
            self.rules[name] = decided
            logger.info("%s %s: %s", name, _describe(value), reason)

    def _record_disagreement_rule(self) -> None:
        """:attr:`rules`' entry for ``disagreement="auto"`` once the ensemble has chosen its form."""
        if self.ensemble.requested_disagreement != "auto" or self.demonstrations is None:
            return
        share = share_on_bound(self.demonstrations.actions, self.action_space)
        self._record_rule("disagreement", self.ensemble.disagreement_form,
                          f"{share:.1%} of the demonstrations' action entries sit on a bound of the action space "
                          f"({'at least' if share >= AUTO_UNCLIPPED_SHARE else 'under'} "
                          f"{AUTO_UNCLIPPED_SHARE:.0%})")

    def _log_reward_state(self, absorbing: bool) -> None:
        """Log the reward rule's mean per-env state and, where terminations are scored as an absorbing
        state (``absorbing``), the absorbing state's u."""
        state = self.reward_rule.get_state() if self.reward_rule is not None else np.zeros(0)
        if state.size:
            self.logger.record("rollout/ubar_mean", float(state.mean()))
        if absorbing:
            # How much a termination costs depends on it: the run's highest u so far.
            self.logger.record("rollout/absorbing_u", self.absorbing_u)

    # -- saving and loading --------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        return super()._excluded_save_params() + [
            "demonstrations", "reward_rule", "ensemble", "bc", "_pretrain_log_pending"
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return state_dicts + ["ensemble", "bc.optimizer"], variables + list(SAVED_TENSORS)

    def save(self, path: Any, exclude: Any | None = None, include: Any | None = None) -> None:
        """Save as the RL algorithm does, plus the ensemble, the BC optimiser, the demonstrations and the
        reward rule's state (:mod:`sb3_cmzdril.common.saving`)."""
        demos = self.demonstrations
        if demos is not None:
            self._saved_demo_obs, self._demo_obs_layout = pack_observations(demos.observations)
            for key, tensor in demo_tensors(demos).items():
                setattr(self, f"_saved_demo_{key}", tensor)
        if self.reward_rule is not None:
            self._saved_reward_state = th.as_tensor(self.reward_rule.get_state())
            self._saved_absorbing_u = th.tensor([self.reward_rule.absorbing_u], dtype=th.float64)
        super().save(path, exclude=exclude, include=include)

    @classmethod
    def load(
        cls: type[SelfImitationLearner],
        path: Any,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        demonstrations: DemosLike = None,
        **kwargs: Any,
    ) -> SelfImitationLearner:
        """Load a saved model of this learner, as its RL algorithm's ``load`` does (CMZDRIL also loads a
        plain PPO zip).

        ``demonstrations`` replaces the ones saved with the model. Where they hold other steps than
        those and the model was saved pretrained, its ensemble is fitted again on them at the next
        ``learn()``, and with it DRIL's threshold, the CMZ reward's clip and a fresh reward state (the
        EMA of the old ensemble's u means nothing to the new one), so that the reward measures the
        distance to the demonstrations the BC steps pull toward; a line is logged. The policy keeps
        its weights, and with them the input standardisation they were trained with (refitting it
        would change what the trained policy does); set ``pretrained = False`` after loading to
        clone the new demonstrations afresh as well. The saved demonstrations handed again change
        nothing. A model saved by another learner is refused in one line.
        """
        check_saved_learner(path, cls.learner_name, off_policy=cls.off_policy, plain_sb3=cls.loads_plain_sb3)
        with restoring_saved_model(), warnings.catch_warnings():
            # A zip names the classes it pickled by the paths they had (e.g. sb3_cmzdril.demo_replay's
            # buffer): their deprecation is for imports a user writes, not for the zip's.
            warnings.filterwarnings("ignore", message=r"sb3_cmzdril\.\w+ moved to ", category=FutureWarning)
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
        if weights_brought_by_user():
            self._policy_pretrained = self._policy_pretrained or "policy" in params
            if "ensemble" in params:
                self._imitation_ready = False  # the rule and its bounds belong to the ensemble it replaced

    def _saved_demonstrations(self) -> Demonstrations | None:
        """The demonstrations the zip holds (None: none)."""
        if not self._saved_demo_obs.numel():
            return None
        observations = unpack_observations(self._saved_demo_obs.cpu().numpy(), self._demo_obs_layout)
        tensors = {key: getattr(self, f"_saved_demo_{key}") for key in ("actions", "lengths", "rewards", "seeds")}
        return demos_from_tensors(observations, tensors)

    def _restore_saved_state(self, demonstrations: Demonstrations | None) -> None:
        """After SB3's ``load()``: the demonstrations to go on with (``demonstrations``, else the saved
        ones) and the reward rule with its saved state, for a model saved with its rule made."""
        # Zips of earlier versions: a CMZDRIL one kept the absorbing state's u as a plain attribute and
        # may lack _policy_pretrained (it was pretrained when its rule was ready); a CMZDRILSAC one may
        # keep the flag as a plain `pretrained`, and none kept _imitation_ready (its rule was made
        # whenever it was pretrained). SB3's load() put their keys into __dict__, beside the properties.
        legacy_absorbing_u = self.__dict__.pop("absorbing_u", None)
        legacy_pretrained = self.__dict__.pop("pretrained", None)
        if legacy_pretrained is not None:
            self._policy_pretrained = bool(legacy_pretrained)
        if self._imitation_ready is None:
            self._imitation_ready = self.pretrained
        self._policy_pretrained = self._policy_pretrained or self._imitation_ready
        saved = self._saved_demonstrations()
        checked, refit = demonstrations_to_go_on(
            saved, demonstrations, self.observation_space, self.action_space, self.ensemble.is_fitted,
            self.learner_name,
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
                    stacklevel=3,
                )
            self.reward_rule.set_state(state)
            if self._saved_absorbing_u.numel():
                self.reward_rule.absorbing_u = float(self._saved_absorbing_u.item())
            elif legacy_absorbing_u is not None:
                self.reward_rule.absorbing_u = float(legacy_absorbing_u)



def _describe(value: Any) -> str:
    """How a rule's log line says what it decided: "on"/"off" for a switch, the value otherwise."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return repr(value)


__all__ = ["DemosLike", "ImitationLearner", "arguments_for", "buffer_actions",
           "disagreement_where_ended", "made_env", "reward_rule", "rule_bounds"]
