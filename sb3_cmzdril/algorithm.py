"""CMZDRIL: SB3's PPO with CMZ-DRIL's imitation machinery (paper, Algorithm 1).

On the first ``learn()`` (or an explicit :meth:`CMZDRIL.pretrain`) the model checks the demonstrations
against the env, pretrains the policy by NLL behaviour cloning, fits the bootstrap ensemble, and puts
the :class:`~sb3_cmzdril.rewards.DisagreementReward` wrapper into the training VecEnv (just above the
base VecEnv, so below VecNormalize: the ensemble sees raw observations and the Monitor below reports
the true return). Every PPO update is followed by ``bc_epochs_per_update`` NLL epochs on the demos.

``reward`` picks the rule, everything else is shared: ``"cmz"`` (the paper), ``"dril"`` (+1/-1 by the
q-quantile threshold), ``"zero"`` (PPO + BC epochs only), ``"env"`` (the true reward). Plain BC is
the pretrained policy (``model.pretrain()`` without ``learn``).

Saving: the zip holds the policy, the ensemble, the BC optimiser, the demonstrations (observations,
actions, episode lengths, seeds) and the reward rule's per-env state, so ``CMZDRIL.load(path,
env=env)`` can go on learning without being handed the demos again; ``load(...,
demonstrations=...)`` replaces them.
"""
from __future__ import annotations

import time
import warnings
from typing import Any, Dict, Optional, Sequence, Tuple, Type, TypeVar, Union

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_cmzdril.bc import BehaviourCloner
from sb3_cmzdril.demos import Demonstrations, as_demonstrations
from sb3_cmzdril.ensemble import BCEnsemble, quantile_of_disagreement
from sb3_cmzdril.rewards import DisagreementReward, RewardRule, make_rule

REWARD_MODES = ("cmz", "dril", "zero", "env")
SelfCMZDRIL = TypeVar("SelfCMZDRIL", bound="CMZDRIL")
DemosLike = Union[Demonstrations, str, list, None]

# Tensors that travel in the zip next to the state dicts (SB3 loads them with weights_only=True).
_SAVED_TENSORS = ("_saved_demo_obs", "_saved_demo_actions", "_saved_demo_lengths", "_saved_demo_seeds", "_saved_reward_state")


class CMZDRIL(PPO):
    """PPO trained on CMZ-DRIL's disagreement reward plus NLL behaviour-cloning epochs.

    Takes every argument of :class:`stable_baselines3.PPO`, and:

    :param demonstrations: a :class:`~sb3_cmzdril.demos.Demonstrations`, a path to a saved one, or a
        list of episode dicts. Required before the first ``learn()``.
    :param reward: ``"cmz"``, ``"dril"``, ``"zero"`` or ``"env"``.
    :param alpha: CMZ reward scale (paper: 10).
    :param ema: CMZ EMA factor g (paper: 0.99).
    :param u0: initial EMA value (paper: 0).
    :param dril_quantile: DRIL threshold quantile of u on the demos (DRIL: 0.98).
    :param disagreement: ``"std"`` or ``"quadratic"`` (see :mod:`sb3_cmzdril.ensemble`).
    :param ensemble_size: number of ensemble members (paper/DRIL: 5).
    :param ensemble_hidden: hidden layer widths of each member.
    :param ensemble_epochs: epochs of ensemble fitting.
    :param ensemble_batch_size: minibatch size of ensemble fitting.
    :param ensemble_learning_rate: Adam step size of ensemble fitting.
    :param bc_pretrain_epochs: NLL epochs before RL.
    :param bc_epochs_per_update: NLL epochs after each PPO update (paper: 1; 0 disables).
    :param bc_batch_size: minibatch size of the NLL epochs.
    :param bc_learning_rate: Adam step size of the NLL epochs.
    :param batch_scoring: score each rollout's steps in one ensemble forward after collecting it
        (and correct the rollout buffer) instead of one forward per env step: the same rewards at a
        fraction of the cost. Per-step scoring is used anyway under a reward-normalising
        VecNormalize, which must see the shaped reward at step time. With batch scoring, step
        ``infos`` carry ``"env_reward"`` but not ``"disagreement"`` and callbacks see reward 0 during
        the rollout; the logger gets the rollout's mean u and reward.
    """

    def __init__(
        self,
        policy: Union[str, Type[ActorCriticPolicy]],
        env: Union[GymEnv, str],
        demonstrations: DemosLike = None,
        reward: str = "cmz",
        alpha: float = 10.0,
        ema: float = 0.99,
        u0: float = 0.0,
        dril_quantile: float = 0.98,
        disagreement: str = "std",
        ensemble_size: int = 5,
        ensemble_hidden: Sequence[int] = (64, 64),
        ensemble_epochs: int = 200,
        ensemble_batch_size: int = 64,
        ensemble_learning_rate: float = 1e-3,
        bc_pretrain_epochs: int = 100,
        bc_epochs_per_update: int = 1,
        bc_batch_size: int = 64,
        bc_learning_rate: float = 1e-3,
        batch_scoring: bool = True,
        _init_setup_model: bool = True,
        **ppo_kwargs: Any,
    ) -> None:
        if reward not in REWARD_MODES:
            raise ValueError(f"reward must be one of {REWARD_MODES}, got {reward!r}")
        if reward == "cmz":
            make_rule("cmz", alpha=alpha, ema=ema, u0=u0)  # validates alpha, ema, u0 now, not at learn()
        if not 0.0 < dril_quantile <= 1.0:
            raise ValueError(f"dril_quantile must lie in (0, 1], got {dril_quantile}")
        for name, value in (("bc_pretrain_epochs", bc_pretrain_epochs), ("bc_epochs_per_update", bc_epochs_per_update)):
            if int(value) < 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        self.demonstrations: Optional[Demonstrations] = None if demonstrations is None else as_demonstrations(demonstrations)
        self.reward = reward
        self.alpha = float(alpha)
        self.ema = float(ema)
        self.u0 = float(u0)
        self.dril_quantile = float(dril_quantile)
        self.dril_threshold: Optional[float] = None
        self.disagreement = disagreement
        self.ensemble_size = int(ensemble_size)
        self.ensemble_hidden = tuple(int(h) for h in ensemble_hidden)
        self.ensemble_epochs = int(ensemble_epochs)
        self.ensemble_batch_size = int(ensemble_batch_size)
        self.ensemble_learning_rate = float(ensemble_learning_rate)
        self.bc_pretrain_epochs = int(bc_pretrain_epochs)
        self.bc_epochs_per_update = int(bc_epochs_per_update)
        self.bc_batch_size = int(bc_batch_size)
        self.bc_learning_rate = float(bc_learning_rate)
        self.batch_scoring = bool(batch_scoring)
        self.pretrain_info: Dict[str, float] = {}
        self._imitation_ready = False
        super().__init__(policy, env, _init_setup_model=False, **ppo_kwargs)
        if _init_setup_model:
            self._setup_model()

    # -- model construction and persistence --------------------------------------------------
    def _setup_model(self) -> None:
        super()._setup_model()
        if not isinstance(self.action_space, (spaces.Box, spaces.Discrete)):
            raise ValueError(f"CMZDRIL supports Box and Discrete action spaces, got {self.action_space}")
        seed = 0 if self.seed is None else int(self.seed)
        self.ensemble_hidden = tuple(self.ensemble_hidden)  # a loaded model gets a JSON list back
        self.ensemble = BCEnsemble(
            self.observation_space, self.action_space, self.ensemble_size, self.ensemble_hidden, self.disagreement, seed
        ).to(self.device)
        self.bc = BehaviourCloner(self.policy, self.bc_batch_size, self.bc_learning_rate, self.max_grad_norm, seed=seed)
        self.reward_rule: Optional[RewardRule] = None
        for name in _SAVED_TENSORS:
            setattr(self, name, th.zeros(0))

    def _excluded_save_params(self) -> list:
        return super()._excluded_save_params() + ["demonstrations", "reward_rule", "ensemble", "bc"]

    def _get_torch_save_params(self) -> Tuple[list, list]:
        state_dicts, variables = super()._get_torch_save_params()
        return state_dicts + ["ensemble", "bc.optimizer"], variables + list(_SAVED_TENSORS)

    def save(self, path: Any, exclude: Optional[Any] = None, include: Optional[Any] = None) -> None:
        """Save like PPO, plus ensemble, BC optimiser, demonstrations and reward-rule state."""
        demos = self.demonstrations
        if demos is not None:
            self._saved_demo_obs = th.as_tensor(demos.observations)
            self._saved_demo_actions = th.as_tensor(demos.actions)
            self._saved_demo_lengths = th.as_tensor(demos.episode_lengths)
            self._saved_demo_seeds = th.as_tensor(demos.seeds)
        if self.reward_rule is not None:
            self._saved_reward_state = th.as_tensor(self.reward_rule.get_state())
        super().save(path, exclude=exclude, include=include)

    @classmethod
    def load(  # type: ignore[override]
        cls: Type[SelfCMZDRIL],
        path: Any,
        env: Optional[GymEnv] = None,
        device: Union[th.device, str] = "auto",
        custom_objects: Optional[Dict[str, Any]] = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        demonstrations: DemosLike = None,
        **kwargs: Any,
    ) -> SelfCMZDRIL:
        """Load a saved model; ``demonstrations`` replaces the ones saved with it."""
        model = super().load(
            path, env=env, device=device, custom_objects=custom_objects,
            print_system_info=print_system_info, force_reset=force_reset, **kwargs,
        )
        model._restore_saved_state(None if demonstrations is None else as_demonstrations(demonstrations))
        return model

    def _restore_saved_state(self, demonstrations: Optional[Demonstrations]) -> None:
        if demonstrations is not None:
            self.demonstrations = demonstrations
        elif self._saved_demo_obs.numel():
            self.demonstrations = Demonstrations(
                self._saved_demo_obs.cpu().numpy(),
                self._saved_demo_actions.cpu().numpy(),
                self._saved_demo_lengths.cpu().numpy(),
                seeds=self._saved_demo_seeds.cpu().numpy(),
            )
        if self.demonstrations is not None:
            self.bc.set_demonstrations(self.demonstrations.check_spaces(self.observation_space, self.action_space))
        if self._imitation_ready:
            self.reward_rule = self._make_rule()
            state = self._saved_reward_state.cpu().numpy().astype(np.float64)
            if state.size and state.size != self.n_envs:
                warnings.warn(
                    f"the saved reward state is for {state.size} envs but the model now has {self.n_envs}; "
                    "starting every env's EMA from the saved mean",
                    UserWarning,
                )
                state = np.full(self.n_envs, state.mean())
            self.reward_rule.set_state(state)

    # -- imitation set-up ------------------------------------------------------------------------
    def _make_rule(self) -> RewardRule:
        if self.reward == "cmz":
            return make_rule("cmz", alpha=self.alpha, ema=self.ema, u0=self.u0)
        if self.reward == "dril":
            assert self.dril_threshold is not None, "the DRIL threshold is computed by pretrain()"
            return make_rule("dril", threshold=self.dril_threshold)
        return make_rule(self.reward)

    def _demo_obs_transform(self) -> Any:
        vec_normalize = self.get_vec_normalize_env()
        if vec_normalize is not None and vec_normalize.norm_obs:
            return vec_normalize.normalize_obs
        return None

    def pretrain(self, progress_bar: bool = False) -> Dict[str, float]:
        """Check the demos, pretrain the policy by NLL and fit the ensemble (once; later calls only
        re-check the demos). Returns NLL before/after pretraining and timings."""
        if self.demonstrations is None:
            raise ValueError(
                "CMZDRIL needs demonstrations: pass demonstrations=... (a Demonstrations, a path to a "
                "demos.npz, or a list of episode dicts) to the constructor or to load()"
            )
        self.demonstrations = self.demonstrations.check_spaces(self.observation_space, self.action_space)
        self.bc.set_demonstrations(self.demonstrations)
        if self._imitation_ready:
            return self.pretrain_info
        transform = self._demo_obs_transform()
        start = time.perf_counter()
        nll_before = self.bc.nll(transform)
        self.bc.train(self.bc_pretrain_epochs, transform, progress_bar=progress_bar)
        nll_after = self.bc.nll(transform)
        bc_seconds = time.perf_counter() - start
        start = time.perf_counter()
        self.ensemble.fit(
            self.demonstrations, self.ensemble_epochs, self.ensemble_batch_size, self.ensemble_learning_rate, progress_bar
        )
        if self.reward == "dril":
            self.dril_threshold = quantile_of_disagreement(self.ensemble, self.demonstrations, self.dril_quantile)
        self.reward_rule = self._make_rule()
        self._imitation_ready = True
        self.pretrain_info = {
            "bc_nll_before": nll_before,
            "bc_nll_after": nll_after,
            "bc_seconds": bc_seconds,
            "ensemble_loss": float(np.mean(self.ensemble.train_loss_)),
            "ensemble_seconds": time.perf_counter() - start,
        }
        if self.verbose >= 1:
            info = self.pretrain_info
            print(
                f"CMZDRIL pretraining: BC NLL {nll_before:.3f} -> {nll_after:.3f} ({self.bc_pretrain_epochs} epochs, "
                f"{info['bc_seconds']:.1f}s); ensemble loss {info['ensemble_loss']:.4g} ({info['ensemble_seconds']:.1f}s)"
                + (f"; DRIL threshold {self.dril_threshold:.4g}" if self.dril_threshold is not None else "")
            )
        return self.pretrain_info

    def reward_wrapper(self) -> Optional[DisagreementReward]:
        """The DisagreementReward in the training env, or None before the first learn()."""
        env = self.env
        while isinstance(env, VecEnvWrapper):
            if isinstance(env, DisagreementReward):
                return env
            env = env.venv
        return None

    def _wrap_training_env(self) -> None:
        if self.env is None:
            raise ValueError("CMZDRIL.learn() needs an environment: pass env= to the constructor or to load()")
        assert self.reward_rule is not None
        vec_normalize = self.get_vec_normalize_env()
        batch = self.batch_scoring and not (vec_normalize is not None and vec_normalize.norm_reward)
        wrapper = self.reward_wrapper()
        if wrapper is not None:
            wrapper.ensemble, wrapper.rule, wrapper.batch = self.ensemble, self.reward_rule, batch
            return
        lowest: Optional[VecEnvWrapper] = None
        base: VecEnv = self.env
        while isinstance(base, VecEnvWrapper):
            lowest, base = base, base.venv
        wrapper = DisagreementReward(base, self.ensemble, self.reward_rule, batch=batch)
        if lowest is None:
            self.env = wrapper
        else:
            lowest.venv = wrapper
        self._last_obs = None  # the next learn() resets through the wrapper so it sees the first obs

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
        self.pretrain(progress_bar=progress_bar)
        self._wrap_training_env()
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        keep_going = super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        wrapper = self.reward_wrapper()
        if wrapper is not None and wrapper.batch:
            if keep_going:
                self._apply_batch_rewards(wrapper, rollout_buffer)
            else:
                wrapper.discard_pending()  # aborted by a callback: the buffer will not be trained on
        if wrapper is not None:
            for key, value in wrapper.pop_stats().items():
                self.logger.record(f"rollout/{key}", value)
            state = wrapper.rule.get_state()
            if state.size:
                self.logger.record("rollout/ubar_mean", float(state.mean()))
        return keep_going

    def _apply_batch_rewards(self, wrapper: DisagreementReward, rollout_buffer: RolloutBuffer) -> None:
        _, shaped = wrapper.score_pending()
        # The buffer holds reward 0 per step plus SB3's bootstrap gamma*V(s_T) at time-limit
        # truncations; adding the shaped rewards keeps that bootstrap.
        rollout_buffer.rewards += shaped
        with th.no_grad():
            last_values = self.policy.predict_values(obs_as_tensor(self._last_obs, self.device))
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=self._last_episode_starts)

    def train(self) -> None:
        super().train()
        if self.bc_epochs_per_update and self.demonstrations is not None:
            transform = self._demo_obs_transform()
            for _ in range(self.bc_epochs_per_update):
                nll = self.bc.epoch(transform)
            self.logger.record("train/bc_nll", nll)
