"""A replay buffer that mixes the demonstrations into every batch and scores rewards when it samples.

Off-policy imitation learners (SQIL, DAC) train their critic on expert transitions as well as the
agent's own: the expert's states are where the reward is highest, and without them in the batch
the critic only learns what the agent's states are worth. :class:`DemoReplayBuffer` is SB3's
``ReplayBuffer`` (same constructor, so ``replay_buffer_class=DemoReplayBuffer`` works with SB3's
SAC, TD3 or DDPG) that

* fills a fixed share of every sampled batch with demonstration transitions
  (:meth:`DemoReplayBuffer.set_demonstrations`), and
* relabels every sampled reward with a function of the raw transitions (``relabel``), so that a
  reward that changes while training (an EMA, a refitted ensemble) applies to old transitions as
  it applies to new ones, and
* keeps the disagreement u that the learner gave each step when it stored it (``infos[i]
  ["disagreement"]``, the key :class:`~sb3_cmzdril.rewards.DisagreementReward` reports u under),
  so that a learner whose ensemble stays fixed does not score the same transition again at every
  sampling.

Transitions come from consecutive demo steps of one episode; an episode's last step, whose next
observation the pool does not keep, is left out. Flat ``Box`` observations only.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError

#: (raw observations, buffer actions (scaled to [-1, 1]), env rewards, terminated, raw next observations,
#: the disagreements recorded with the transitions (NaN where none was)) -> rewards, all (batch,)
Relabel = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class DemoTransitions:
    """The demonstrations as (s, a, r, s') transitions of consecutive steps within an episode.

    :param demos: the demonstrations (flat Box observations).
    :param scale_action: maps the demos' actions to the buffer's (SB3 stores Box actions scaled to
        [-1, 1]; ``policy.scale_action``); the result is clipped to [-1, 1].
    """

    def __init__(self, demos: Demonstrations, scale_action: Callable[[np.ndarray], np.ndarray]) -> None:
        if isinstance(demos.observations, dict):
            raise UserError("demonstration transitions need flat Box observations, got a Dict of observations")
        keep = np.ones(len(demos), dtype=bool)
        keep[demos.episode_starts + demos.episode_lengths - 1] = False  # no next observation recorded
        if not keep.any():
            raise UserError("every demonstration has a single step: no transition (s, a, s') to replay")
        rows = np.flatnonzero(keep)
        obs = np.asarray(demos.observations, dtype=np.float32)
        self.observations = obs[rows]
        self.next_observations = obs[rows + 1]
        # Flat, as the buffer stores the actions of any Box shape.
        actions = np.clip(scale_action(demos.actions[rows]), -1.0, 1.0).astype(np.float32)
        self.actions = actions.reshape(len(rows), -1)
        rewards = demos.rewards if demos.rewards is not None else np.zeros(len(demos), np.float32)
        self.rewards = np.asarray(rewards, dtype=np.float32)[rows]
        #: whether the demos recorded the env's rewards (the true-reward rule needs them)
        self.has_rewards = demos.rewards is not None
        #: each transition's disagreement, where a learner has scored them once (NaN: not scored)
        self.disagreements = np.full(len(rows), np.nan)

    def __len__(self) -> int:
        return len(self.actions)


class DemoReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` whose batches hold a share of demonstration transitions and whose
    rewards are relabelled at sampling time (see the module's docstring). Without demonstrations
    and ``relabel`` it samples exactly as SB3's buffer does."""

    demos: DemoTransitions | None = None
    demo_fraction: float = 0.0
    relabel: Relabel | None = None

    def set_demonstrations(self, demos: DemoTransitions | None, demo_fraction: float, relabel: Relabel | None) -> None:
        """Mix ``round(demo_fraction * batch_size)`` of ``demos`` into each batch and score every
        sampled transition with ``relabel`` (None keeps the stored env rewards)."""
        if not 0.0 <= demo_fraction < 1.0:
            raise UserError(f"demo_fraction must lie in [0, 1), got {demo_fraction}")
        if self.optimize_memory_usage:
            raise UserError("DemoReplayBuffer does not support optimize_memory_usage=True")
        self.demos, self.demo_fraction, self.relabel = demos, float(demo_fraction), relabel

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)
        if not hasattr(self, "disagreements"):  # a buffer pickled before it kept them
            self.disagreements = np.full((self.buffer_size, self.n_envs), np.nan)
        self.disagreements[pos] = [info.get("disagreement", np.nan) for info in infos]

    def __getstate__(self) -> dict[str, Any]:
        # A saved buffer (SB3's save_replay_buffer pickles it) holds the agent's transitions only.
        # relabel is a method of the learner, so pickling it would pickle the whole model with its env;
        # the learner sets both again at every learn().
        state = dict(self.__dict__)
        for name in ("demos", "demo_fraction", "relabel"):
            state.pop(name, None)
        return state

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        n_demo = int(round(batch_size * self.demo_fraction)) if self.demos is not None else 0
        upper = self.buffer_size if self.full else self.pos
        agent = np.random.randint(0, upper, size=batch_size - n_demo)
        return self._get_samples(agent, env=env, n_demo=n_demo)

    def _get_samples(
        self, batch_inds: np.ndarray, env: VecNormalize | None = None, n_demo: int = 0
    ) -> ReplayBufferSamples:
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        obs = self.observations[batch_inds, env_indices, :]
        next_obs = self.next_observations[batch_inds, env_indices, :]
        actions = self.actions[batch_inds, env_indices, :]
        env_rewards = self.rewards[batch_inds, env_indices]
        # A time-limit truncation is no termination: the critic bootstraps through it.
        terminated = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        stored = getattr(self, "disagreements", None)
        if stored is None:
            scored = np.full(len(batch_inds), np.nan)
        else:
            scored = stored[batch_inds, env_indices]
        if n_demo:
            assert self.demos is not None
            rows = np.random.randint(0, len(self.demos), size=n_demo)
            obs = np.concatenate([obs, self.demos.observations[rows]])
            next_obs = np.concatenate([next_obs, self.demos.next_observations[rows]])
            actions = np.concatenate([actions, self.demos.actions[rows]])
            env_rewards = np.concatenate([env_rewards, self.demos.rewards[rows]])
            terminated = np.concatenate([terminated, np.zeros(n_demo, terminated.dtype)])
            scored = np.concatenate([scored, self.demos.disagreements[rows]])
        if self.relabel is not None:
            rewards = np.asarray(
                self.relabel(obs, actions, env_rewards, terminated.astype(bool), next_obs, scored), np.float32
            )
        else:
            rewards = self._normalize_reward(env_rewards, env)
        # Flat Box observations only (set_demonstrations' DemoTransitions refuse dicts): arrays.
        normalized_obs = np.asarray(self._normalize_obs(obs, env))
        normalized_next = np.asarray(self._normalize_obs(next_obs, env))
        return ReplayBufferSamples(
            observations=self.to_torch(normalized_obs),
            actions=self.to_torch(actions),
            next_observations=self.to_torch(normalized_next),
            dones=self.to_torch(terminated.reshape(-1, 1)),
            rewards=self.to_torch(rewards.reshape(-1, 1)),
        )


__all__ = ["DemoReplayBuffer", "DemoTransitions", "Relabel"]
