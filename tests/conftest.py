"""Shared fixtures: small scripted-expert demonstrations and tiny model settings."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from sb3_cmzdril.demos import Demonstrations

torch.set_num_threads(1)


def pendulum_expert(obs: np.ndarray) -> np.ndarray:
    """A PD controller on the pole angle: deterministic, a function of the observation only."""
    obs = np.atleast_2d(obs)
    theta = np.arctan2(obs[:, 1], obs[:, 0])
    return np.clip(-8.0 * theta - 1.5 * obs[:, 2], -2.0, 2.0).astype(np.float32)[:, None]


def cartpole_expert(obs: np.ndarray) -> np.ndarray:
    """Push toward the side the pole falls to (keeps CartPole up for hundreds of steps)."""
    obs = np.atleast_2d(obs)
    return (obs[:, 2] + 0.5 * obs[:, 3] > 0).astype(np.int64)


def record(
    env_id: str, policy: Callable[[np.ndarray], np.ndarray], n_episodes: int, max_steps: int, seed: int = 0
) -> Demonstrations:
    env = gym.make(env_id)
    episodes = []
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        o, a, r = [], [], []
        for _ in range(max_steps):
            act = policy(obs)[0]
            o.append(obs)
            a.append(act)
            obs, rew, terminated, truncated, _ = env.step(act)
            r.append(rew)
            if terminated or truncated:
                break
        episodes.append({"observations": np.array(o), "actions": np.array(a), "rewards": np.array(r), "seed": seed + i})
    env.close()
    return Demonstrations.from_episodes(episodes)


@pytest.fixture(scope="session")
def pendulum_demos() -> Demonstrations:
    return record("Pendulum-v1", pendulum_expert, n_episodes=2, max_steps=100)


@pytest.fixture(scope="session")
def cartpole_demos() -> Demonstrations:
    return record("CartPole-v1", cartpole_expert, n_episodes=2, max_steps=100)


#: settings that keep a CMZDRIL model tiny and its learn() calls to a fraction of a second
TINY: dict[str, Any] = dict(
    n_steps=64,
    batch_size=32,
    n_epochs=2,
    policy_kwargs=dict(net_arch=[16, 16]),
    ensemble_hidden=(16, 16),
    ensemble_epochs=5,
    bc_pretrain_epochs=5,
    seed=0,
)
