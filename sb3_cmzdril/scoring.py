"""Scoring a collected rollout from what the rollout buffer holds (CMZDRIL's default path).

The rollout buffer stores exactly the steps PPO trains on: the observation each env acted on and the
action it took. Scoring them there, once per rollout, costs one batched ensemble forward (3-20 ms for
2,048 steps) instead of one forward per env step, and nothing that happens outside
``collect_rollouts`` (an ``evaluate_policy`` on the training env between two ``learn()`` calls, a
reset by the user) can misalign steps and scores: there is no side queue to fall out of step.

The env stack is left alone: every Monitor and VecMonitor sees the true reward, and so do callbacks
during the rollout. At the end of the rollout :class:`RolloutScorer` (the first callback, so user
callbacks' ``on_rollout_end`` already see the final rewards) replaces each step's env reward by the
rule's reward, keeping SB3's bootstrap ``gamma * V(s_T)`` that ``collect_rollouts`` adds at time-limit
truncations, and recomputes returns and advantages.

Two cases score step by step instead, with :class:`~sb3_cmzdril.rewards.DisagreementReward` in the
env stack: a reward-normalising VecNormalize (it must see the shaped reward as it happens) and
``CMZDRIL(batch_scoring=False)``. The scorer then only collects the wrapper's statistics.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback

from sb3_cmzdril.rewards import terminations, with_absorbing_state
from sb3_cmzdril.spaces import concatenate, indices_as_actions, reshape_rows

if TYPE_CHECKING:
    from sb3_cmzdril.algorithm import CMZDRIL


class RolloutScorer(BaseCallback):
    """Rescore each finished rollout in the buffer and log the disagreement statistics.

    :param rescore: replace the buffer's rewards (False: a per-step wrapper already did).
    """

    def __init__(self, rescore: bool) -> None:
        super().__init__()
        self.rescore = bool(rescore)
        self._env_rewards: np.ndarray | None = None
        self._terminated: np.ndarray | None = None
        self._raw_obs: list[Any] | None = None
        self._vec_normalize: Any = None
        self._t = 0

    @property
    def cmz(self) -> CMZDRIL:
        # Only CMZDRIL._init_callback installs the scorer, so its model is always a CMZDRIL.
        return cast("CMZDRIL", self.model)

    def _on_rollout_start(self) -> None:
        self._t = 0
        if not self.rescore:
            return
        buffer = self.cmz.rollout_buffer
        self._env_rewards = np.zeros((buffer.buffer_size, buffer.n_envs), np.float32)
        self._terminated = np.zeros((buffer.buffer_size, buffer.n_envs), bool)
        vec_normalize = self.model.get_vec_normalize_env()
        # The buffer holds what the policy saw; the ensemble needs raw observations.
        self._vec_normalize = vec_normalize if vec_normalize is not None and vec_normalize.norm_obs else None
        self._raw_obs = [_copy(self._vec_normalize.get_original_obs())] if self._vec_normalize is not None else None

    def _on_step(self) -> bool:
        if self.rescore:
            t = self._t
            assert self._env_rewards is not None
            # A copy: collect_rollouts adds the truncation bootstrap to this array in place afterwards.
            self._env_rewards[t] = self.locals["rewards"]
            assert self._terminated is not None
            self._terminated[t] = terminations(self.locals["dones"], self.locals["infos"])
            if self._raw_obs is not None and t + 1 < self.cmz.rollout_buffer.buffer_size:
                # What VecNormalize returned last is the raw form of the next observation acted on.
                self._raw_obs.append(_copy(self._vec_normalize.get_original_obs()))
        self._t += 1
        return True

    def _on_rollout_end(self) -> None:
        model = self.cmz
        if not self.rescore:
            wrapper = model.reward_wrapper()
            stats = wrapper.pop_stats() if wrapper is not None else {}
        else:
            stats = self._rescore(model.rollout_buffer)
        for key, value in stats.items():
            model.logger.record(f"rollout/{key}", value)
        model.rollout_disagreement = stats.get("disagreement_mean")
        state = model.reward_rule.get_state() if model.reward_rule is not None else np.zeros(0)
        if state.size:
            model.logger.record("rollout/ubar_mean", float(state.mean()))

    def _rescore(self, buffer: Any) -> dict:
        model = self.cmz
        steps, n_envs = buffer.buffer_size, buffer.n_envs
        obs = buffer.observations if self._raw_obs is None else concatenate([_row(o) for o in self._raw_obs])
        flat_obs = reshape_rows(obs, (steps * n_envs,), model.observation_space)
        actions = None
        if getattr(model.ensemble, "needs_actions", True):
            actions = buffer_actions(buffer.actions.reshape(steps * n_envs, -1), model.action_space)
        u = model.ensemble.disagreement(flat_obs, actions).reshape(steps, n_envs)
        env_rewards = self._env_rewards
        assert env_rewards is not None and model.reward_rule is not None
        shaped = model.reward_rule.sequence(u, env_rewards)
        if model.reward != "env" and model.absorbing_active:
            assert self._terminated is not None
            # The highest u seen up to each step, this step's envs included (as the per-step wrapper sees it).
            seen = np.maximum.accumulate(np.maximum(u.max(axis=1), model.absorbing_u))
            model.absorbing_u = float(seen[-1])
            shaped = with_absorbing_state(model.reward_rule, shaped, u, self._terminated, seen[:, None], model.gamma)
        if model.reward != "env":
            # Swap the env reward for the rule's; the truncation bootstrap in the buffer stays.
            buffer.rewards += shaped - env_rewards
            buffer.compute_returns_and_advantage(last_values=self.locals["values"], dones=self.locals["dones"])
        self._env_rewards = self._raw_obs = self._terminated = None
        return {"disagreement_mean": float(u.mean()), "shaped_reward_mean": float(shaped.mean())}


def buffer_actions(actions: np.ndarray, space: spaces.Space) -> np.ndarray:
    """The rollout buffer's actions (what the policy output, flattened) as the space's actions:
    Box clipped to its bounds as SB3 clips them before the env sees them; Discrete and MultiDiscrete
    indices shifted by the space's ``start``."""
    if isinstance(space, spaces.Box):
        return np.clip(actions, space.low.reshape(-1), space.high.reshape(-1))
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        return indices_as_actions(actions, space)
    return actions


def _copy(obs: Any) -> Any:
    return {k: np.array(v) for k, v in obs.items()} if isinstance(obs, dict) else np.array(obs)


def _row(obs: Any) -> Any:
    # One step of every env as a batch of one step: (1, n_envs, ...).
    return {k: v[None] for k, v in obs.items()} if isinstance(obs, dict) else obs[None]


__all__ = ["RolloutScorer", "buffer_actions"]
