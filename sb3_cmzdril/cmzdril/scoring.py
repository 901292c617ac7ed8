"""Scoring a collected rollout from what the rollout buffer holds (CMZDRIL's default path; CMZDRILSAC
scores the transitions it samples from its replay buffer instead).

The rollout buffer stores exactly the steps PPO trains on: the observation each env acted on and the
action it took. Scoring them there, once per rollout, costs one batched ensemble forward (3-20 ms for
2,048 steps) instead of one forward per env step, and nothing that happens outside
``collect_rollouts`` (an ``evaluate_policy`` on the training env between two ``learn()`` calls, a
reset by the user) can misalign steps and scores: there is no side queue to fall out of step.

The env stack is left alone: every Monitor and VecMonitor sees the true reward, and so do callbacks
during the rollout. While the rollout runs, a :class:`RolloutRecord` keeps what the buffer lacks
(each step's env reward before SB3 adds its truncation bootstrap, which envs terminated, the raw
observations under VecNormalize); at its end :func:`score_rollout`, a function of the rollout, the
ensemble and the reward rule, gives each step's disagreement and the rule's reward. The model owns
the buffer and applies the rewards itself (keeping SB3's bootstrap ``gamma * V(s_T)`` at time-limit
truncations); this module writes nothing onto it.

Two cases score step by step instead, with :class:`~sb3_cmzdril.rewards.DisagreementReward` in the
env stack: a reward-normalising VecNormalize (it must see the shaped reward as it happens) and
``CMZDRIL(batch_scoring=False)``.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecNormalize

from sb3_cmzdril.common.imitation import buffer_actions
from sb3_cmzdril.data.spaces import concatenate, reshape_rows
from sb3_cmzdril.ensemble import BCEnsemble
from sb3_cmzdril.rewards import RewardRule, terminations, with_absorbing_state


class RolloutRecord:
    """What scoring a rollout needs that the rollout buffer does not keep, step by step.

    :param n_steps: steps per env in the rollout (the buffer's ``buffer_size``).
    :param n_envs: envs of the training VecEnv.
    :param vec_normalize: the training env's VecNormalize when it normalises observations (the
        buffer then holds normalised ones, and the ensemble needs raw ones), else None.
    :param keep_terminal: also keep the observation each terminated episode ended in, raw (for an
        absorbing state scored there).
    """

    def __init__(
        self, n_steps: int, n_envs: int, vec_normalize: VecNormalize | None = None, keep_terminal: bool = False
    ) -> None:
        self.n_steps = int(n_steps)
        #: each step's env reward, copied before collect_rollouts adds the truncation bootstrap in place
        self.env_rewards = np.zeros((n_steps, n_envs), np.float32)
        #: which envs' episodes terminated (not truncated) at each step
        self.terminated = np.zeros((n_steps, n_envs), bool)
        #: which envs' episodes ended at each step, terminated or truncated
        self.dones = np.zeros((n_steps, n_envs), bool)
        self._vec_normalize = vec_normalize
        self._raw_obs: list[Any] | None = None
        if vec_normalize is not None:
            self._raw_obs = [_copy(vec_normalize.get_original_obs())]
        self._keep_terminal = keep_terminal
        #: (step, env, raw observation) of each terminated episode, in order
        self.ended_in: list[tuple[int, int, Any]] = []
        self._t = 0

    def record(self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict]) -> None:
        """One step of every env, as ``collect_rollouts`` hands it to the callbacks."""
        t = self._t
        self.env_rewards[t] = rewards
        self.terminated[t] = terminations(dones, infos)
        self.dones[t] = dones
        if self._keep_terminal:
            for i in np.flatnonzero(self.terminated[t]):
                obs = infos[i]["terminal_observation"]
                if self._vec_normalize is not None:
                    # VecNormalize normalised it in the infos; undone, it is raw up to its clip_obs.
                    obs = self._vec_normalize.unnormalize_obs(obs)
                self.ended_in.append((t, int(i), _copy(obs)))
        if self._vec_normalize is not None and self._raw_obs is not None and t + 1 < self.n_steps:
            # What VecNormalize returned last is the raw form of the next observation acted on.
            self._raw_obs.append(_copy(self._vec_normalize.get_original_obs()))
        self._t += 1

    def observations(self, buffer: RolloutBuffer) -> Any:
        """The observations the envs acted on, raw: (n_steps, n_envs, ...) or a dict of such."""
        if self._raw_obs is None:
            return buffer.observations
        return concatenate([_row(o) for o in self._raw_obs])


@dataclasses.dataclass(frozen=True)
class RolloutScores:
    """Each step's disagreement ``u`` and the rule's reward for it, both (n_steps, n_envs)."""

    u: np.ndarray
    rewards: np.ndarray

    def stats(self) -> dict[str, float]:
        """What the model logs per rollout."""
        return {"disagreement_mean": float(self.u.mean()), "shaped_reward_mean": float(self.rewards.mean())}


def score_rollout(
    record: RolloutRecord,
    buffer: RolloutBuffer,
    ensemble: BCEnsemble,
    rule: RewardRule,
    observation_space: spaces.Space,
    action_space: spaces.Space,
    absorbing_gamma: float | None = None,
    terminal_disagreement: Callable[[Any], np.ndarray] | None = None,
) -> RolloutScores:
    """Score a finished rollout in one ensemble forward: ``u`` on the observation each env acted on,
    then the rule's rewards (its state advances over the rollout, step by step as the per-step wrapper
    would advance it). ``absorbing_gamma``: score terminations as entering an absorbing state at the
    highest u seen so far, with this discount (:func:`~sb3_cmzdril.rewards.with_absorbing_state`);
    with ``terminal_disagreement``, at that function's u of the observations the episodes ended in
    (a batch of the record's ``ended_in``, which it must keep) instead."""
    steps, n_envs = buffer.buffer_size, buffer.n_envs
    flat_obs = reshape_rows(record.observations(buffer), (steps * n_envs,), observation_space)
    actions = None
    if getattr(ensemble, "needs_actions", True):
        actions = buffer_actions(buffer.actions.reshape(steps * n_envs, -1), action_space)
    u = ensemble.disagreement(flat_obs, actions).reshape(steps, n_envs)
    rewards = rule.sequence(u, record.env_rewards)
    if absorbing_gamma is not None:
        u_absorbing = np.repeat(rule.highest_u_so_far(u)[:, None], n_envs, axis=1)
        if terminal_disagreement is not None and record.ended_in:
            steps_ended, envs_ended, ended_in = zip(*record.ended_in, strict=True)
            u_absorbing[list(steps_ended), list(envs_ended)] = terminal_disagreement(
                concatenate([_row(o) for o in ended_in])
            )
        rewards = with_absorbing_state(rule, rewards, u, record.terminated, u_absorbing, absorbing_gamma)
    return RolloutScores(u, rewards)


class ReturnScale:
    """Rewards divided by the running standard deviation of their discounted return, as SB3's
    ``VecNormalize(norm_obs=False, norm_reward=True)`` divides the rewards it passes on, step by step:
    the return of each env is discounted by ``gamma`` and restarts where its episode ended, the
    statistics take every step's returns before that step's rewards are divided, and the result is
    clipped to ``[-clip, clip]``. What the learner sees is then about the same size on every task."""

    def __init__(self, gamma: float, epsilon: float = 1e-8, clip: float = 10.0) -> None:
        self.gamma = float(gamma)
        self.epsilon = float(epsilon)
        self.clip = float(clip)
        self.rms = RunningMeanStd(shape=())
        self.returns = np.zeros(0)

    def apply(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        """``rewards`` and ``dones`` of a rollout, (n_steps, n_envs): the scaled rewards, float32."""
        if self.returns.shape != rewards.shape[1:]:
            self.returns = np.zeros(rewards.shape[1:])  # the first rollout, or another number of envs
        out = np.empty(rewards.shape, np.float64)
        for t in range(len(rewards)):
            self.returns = self.returns * self.gamma + rewards[t]
            self.rms.update(self.returns)
            out[t] = np.clip(rewards[t] / np.sqrt(self.rms.var + self.epsilon), -self.clip, self.clip)
            self.returns[dones[t]] = 0.0
        return out.astype(np.float32)

    @property
    def scale(self) -> float:
        """What a reward is divided by now."""
        return float(np.sqrt(self.rms.var + self.epsilon))


def _copy(obs: Any) -> Any:
    return {k: np.array(v) for k, v in obs.items()} if isinstance(obs, dict) else np.array(obs)


def _row(obs: Any) -> Any:
    # One step of every env as a batch of one step: (1, n_envs, ...).
    return {k: v[None] for k, v in obs.items()} if isinstance(obs, dict) else obs[None]


__all__ = ["ReturnScale", "RolloutRecord", "RolloutScores", "score_rollout"]
