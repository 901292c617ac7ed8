"""Observation standardisation with fixed statistics of the demonstrations.

SB3's ``MlpPolicy`` feeds raw observations to tanh units. On MuJoCo the velocities reach magnitudes of
~10, the units saturate, and behaviour cloning from one episode fits badly (HalfCheetah-v5, one demo:
BC returns 188-736 on raw inputs against 3,380-4,760 with standardised inputs; DESIGN.md). The
ensemble has always standardised its inputs with the demos' mean and std; :class:`DemoStandardizer`
gives the policy the same inputs.

The statistics are fixed (computed once, from the training demonstrations) rather than running:
behaviour cloning happens before the agent has seen a single state, and running statistics drift
under the agent's own state distribution, which would move the BC policy's inputs away from the
ones it was cloned on. They are buffers of the policy, so they travel with ``model.save()``.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

#: Floor of the per-dimension std: a demo dimension that never varies (a constant sensor, a one-hot
#: that the expert never switched) would otherwise be divided by ~0 and blow up off the demos.
MIN_OBS_STD = 1e-2


def observation_statistics(observations: np.ndarray, min_std: float = MIN_OBS_STD) -> Tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean and std (population, floored at ``min_std``) of flattened observations.

    The one place the standardisation statistics are computed, so the policy and the ensemble agree.
    """
    obs = np.asarray(observations, dtype=np.float64)
    if len(obs) == 0:
        raise ValueError("cannot compute observation statistics of zero observations")
    obs = obs.reshape(len(obs), -1)
    mean = obs.mean(axis=0)
    std = np.maximum(obs.std(axis=0), float(min_std))
    return mean.astype(np.float32), std.astype(np.float32)


class DemoStandardizer(BaseFeaturesExtractor):
    """Flatten, then ``(obs - mean) / std`` with fixed statistics (identity until they are set).

    :param observation_space: a Box observation space.
    """

    def __init__(self, observation_space: spaces.Box) -> None:
        if not isinstance(observation_space, spaces.Box):
            raise ValueError(f"DemoStandardizer needs a Box observation space, got {observation_space}")
        n = int(np.prod(observation_space.shape))
        super().__init__(observation_space, features_dim=n)
        self.flatten = th.nn.Flatten()
        self.register_buffer("obs_mean", th.zeros(n))
        self.register_buffer("obs_std", th.ones(n))

    def set_statistics(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Set the statistics (in place, on the module's device)."""
        mean = np.asarray(mean, dtype=np.float32).reshape(-1)
        std = np.asarray(std, dtype=np.float32).reshape(-1)
        if mean.shape != self.obs_mean.shape or std.shape != self.obs_std.shape:
            raise ValueError(f"statistics of shape {mean.shape}/{std.shape} for {self.obs_mean.shape[0]} observation dimensions")
        if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
            raise ValueError("observation statistics must be finite with a positive std")
        with th.no_grad():
            self.obs_mean.copy_(th.as_tensor(mean))
            self.obs_std.copy_(th.as_tensor(std))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return (self.flatten(observations) - self.obs_mean) / self.obs_std


__all__ = ["DemoStandardizer", "observation_statistics", "MIN_OBS_STD"]
