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

import inspect
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor

#: Floor of the per-dimension std: a demo dimension that never varies (a constant sensor, a one-hot
#: that the expert never switched) would otherwise be divided by ~0 and blow up off the demos.
MIN_OBS_STD = 1e-2


def observation_statistics(observations: np.ndarray, min_std: float = MIN_OBS_STD) -> tuple[np.ndarray, np.ndarray]:
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
            raise ValueError(
                f"statistics of shape {mean.shape}/{std.shape} for {self.obs_mean.shape[0]} observation dimensions"
            )
        if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
            raise ValueError("observation statistics must be finite with a positive std")
        with th.no_grad():
            self.obs_mean.copy_(th.as_tensor(mean))
            self.obs_std.copy_(th.as_tensor(std))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return (self.flatten(observations) - self.obs_mean) / self.obs_std


def standardizing_policy_kwargs(policy_class: type, policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """``policy_kwargs`` with :class:`DemoStandardizer` as the features extractor.

    Refuses (ValueError) a features extractor of the user's, and a policy whose default extractor is
    not the flat one (e.g. ``CnnPolicy``): standardisation replaces the extractor, which would
    silently drop theirs.
    """
    kwargs = dict(policy_kwargs or {})
    current = kwargs.get("features_extractor_class")
    if current not in (None, DemoStandardizer):
        raise ValueError(
            f"standardize_observations=True puts DemoStandardizer in place of the features extractor, but "
            f"policy_kwargs asks for {getattr(current, '__name__', current)}; "
            f"pass standardize_observations=False to keep yours"
        )
    default = inspect.signature(policy_class.__init__).parameters.get("features_extractor_class")
    if current is None and (default is None or default.default is not FlattenExtractor):
        raise ValueError(
            f"standardize_observations=True needs a flat-input policy (MlpPolicy); {policy_class.__name__} "
            "has its own features extractor: pass standardize_observations=False"
        )
    kwargs["features_extractor_class"] = DemoStandardizer
    return kwargs


def _gaussian_log_std(policy: Any) -> th.Tensor | None:
    # A state-independent Gaussian has a log_std parameter; gSDE's log_std means something else.
    log_std = getattr(policy, "log_std", None)
    return log_std if isinstance(log_std, th.Tensor) and not getattr(policy, "use_sde", False) else None


def mean_log_std(policy: Any) -> float:
    """Mean log-std of a Gaussian policy's actions (NaN for other distributions)."""
    log_std = _gaussian_log_std(policy)
    return float(log_std.detach().mean()) if log_std is not None else float("nan")


def floor_log_std(policy: Any, floor: float) -> None:
    """Raise a Gaussian policy's log-std to at least ``floor`` (other distributions: no-op)."""
    log_std = _gaussian_log_std(policy)
    if log_std is not None:
        with th.no_grad():
            log_std.clamp_(min=float(floor))


__all__ = [
    "DemoStandardizer",
    "mean_log_std",
    "floor_log_std",
    "observation_statistics",
    "standardizing_policy_kwargs",
    "MIN_OBS_STD",
]
