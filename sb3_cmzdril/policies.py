"""Observation standardisation with fixed statistics of the demonstrations.

SB3's ``MlpPolicy`` feeds raw observations to tanh units. On MuJoCo the velocities reach magnitudes of
~10, the units saturate, and behaviour cloning from one episode fits badly (HalfCheetah-v5, one demo:
BC returns 188-736 on raw inputs against 3,380-4,760 with standardised inputs, as we measured). The
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
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, CombinedExtractor, FlattenExtractor, NatureCNN

from sb3_cmzdril.errors import UserError

#: Floor of the per-dimension std: a demo dimension that never varies (a constant sensor, a one-hot
#: that the expert never switched) would otherwise be divided by ~0 and blow up off the demos.
MIN_OBS_STD = 1e-2


def observation_statistics(observations: np.ndarray, min_std: float = MIN_OBS_STD) -> tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean and std (population, floored at ``min_std``) of flattened observations.

    The one place the standardisation statistics are computed, so the policy and the ensemble agree.
    """
    obs = np.asarray(observations, dtype=np.float64)
    if len(obs) == 0:
        raise UserError("cannot compute observation statistics of zero observations")
    obs = obs.reshape(len(obs), int(np.prod(obs.shape[1:])))
    mean = obs.mean(axis=0)
    std = np.maximum(obs.std(axis=0), float(min_std))
    return mean.astype(np.float32), std.astype(np.float32)


def bounded_statistics(
    space: spaces.Box, mean: np.ndarray, std: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """``mean`` and ``std`` with every entry that ``space`` bounds on both sides left as the env gives it
    (mean 0, std 1: the env has scaled it already), and how many entries that is."""
    low = np.asarray(space.low, np.float64).reshape(-1)
    high = np.asarray(space.high, np.float64).reshape(-1)
    bounded = np.isfinite(low) & np.isfinite(high)
    return (np.where(bounded, 0.0, mean).astype(np.float32), np.where(bounded, 1.0, std).astype(np.float32),
            int(bounded.sum()))


def standardized_keys(observation_space: spaces.Space) -> list[str | None]:
    """The parts of an observation worth standardising: a non-image Box (``[None]``), or the
    non-image Box entries of a Dict (their keys). Images are scaled by SB3 and discrete parts are
    one-hot or binary, so they are left alone."""
    if isinstance(observation_space, spaces.Dict):
        return [k for k, sub in observation_space.spaces.items() if _standardizable(sub)]
    return [None] if _standardizable(observation_space) else []


def _standardizable(space: spaces.Space) -> bool:
    return isinstance(space, spaces.Box) and not is_image_space(space, check_channels=False)


class DemoStandardizer(BaseFeaturesExtractor):
    """``(obs - mean) / std`` on the Box parts of the observation with fixed statistics (identity
    until they are set), then the features extractor it wraps: SB3's FlattenExtractor by default,
    or the policy's own (CombinedExtractor for Dict observations, a user's extractor). Image and
    discrete parts pass through unchanged. Attributes of the wrapped extractor are reachable on the
    wrapper (``policy.features_extractor.batch_norm``).

    :param observation_space: the policy's observation space.
    :param features_extractor_class: the extractor that gets the standardised observations.
    :param features_extractor_kwargs: its keyword arguments.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
    ) -> None:
        keys = standardized_keys(observation_space)
        if not keys:
            raise UserError(f"DemoStandardizer needs a Box part in the observation space, got {observation_space}")
        inner = features_extractor_class(observation_space, **(features_extractor_kwargs or {}))
        super().__init__(observation_space, features_dim=inner.features_dim)
        self.extractor = inner
        self.keys = keys
        for i, key in enumerate(keys):
            sub = observation_space if key is None else observation_space[key]  # type: ignore[index]
            n = int(np.prod(sub.shape or ()))
            self.register_buffer(self._buffer("obs_mean", i), th.zeros(n))
            self.register_buffer(self._buffer("obs_std", i), th.ones(n))

    def __getattr__(self, name: str) -> Any:
        # The wrapped extractor's attributes stay reachable where users look for them
        # (policy.features_extractor.<their layer>).
        try:
            return super().__getattr__(name)
        except AttributeError:
            if name == "extractor":
                raise
            return getattr(super().__getattr__("extractor"), name)

    def _buffer(self, name: str, i: int) -> str:
        # A plain Box keeps the names models saved before Dict support used.
        return name if self.keys == [None] else f"{name}_{i}"

    def set_statistics(self, mean: np.ndarray, std: np.ndarray, key: str | None = None) -> None:
        """Set the statistics of one part (``key``: a Dict entry; None for a Box space), in place."""
        if key not in self.keys:
            raise ValueError(f"no standardised observation part {key!r}; the parts are {self.keys}")
        i = self.keys.index(key)
        obs_mean, obs_std = getattr(self, self._buffer("obs_mean", i)), getattr(self, self._buffer("obs_std", i))
        mean = np.asarray(mean, dtype=np.float32).reshape(-1)
        std = np.asarray(std, dtype=np.float32).reshape(-1)
        if mean.shape != obs_mean.shape or std.shape != obs_std.shape:
            raise ValueError(
                f"statistics of shape {mean.shape}/{std.shape} for {obs_mean.shape[0]} observation dimensions"
            )
        if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
            raise ValueError("observation statistics must be finite with a positive std")
        with th.no_grad():
            obs_mean.copy_(th.as_tensor(mean))
            obs_std.copy_(th.as_tensor(std))

    def fit(self, observations: np.ndarray | dict[str, np.ndarray], by_bounds: bool = False) -> tuple[int, int]:
        """Set every part's statistics from demonstration observations (an array, or a dict).
        ``by_bounds``: an entry the observation space bounds on both sides is left as the env gives it
        instead (:func:`bounded_statistics`). Returns (entries left so, entries)."""
        bounded = total = 0
        for key in self.keys:
            part = observations[key] if isinstance(observations, dict) and key is not None else observations
            mean, std = observation_statistics(np.asarray(part))
            if by_bounds:
                space = self._observation_space if key is None else self._observation_space[key]  # type: ignore[index]
                assert isinstance(space, spaces.Box)  # standardized_keys keeps Box parts only
                mean, std, n = bounded_statistics(space, mean, std)
                bounded += n
            total += len(mean)
            self.set_statistics(mean, std, key=key)
        return bounded, total

    def forward(self, observations: Any) -> th.Tensor:
        if self.keys == [None]:
            observations = self._standardize(observations, 0)
        else:
            observations = dict(observations)
            for i, key in enumerate(self.keys):
                observations[key] = self._standardize(observations[key], i)
        return self.extractor(observations)

    def _standardize(self, x: th.Tensor, i: int) -> th.Tensor:
        flat = x.reshape(len(x), -1)
        out = (flat - getattr(self, self._buffer("obs_mean", i))) / getattr(self, self._buffer("obs_std", i))
        return out.reshape(x.shape)


def standardizing_policy_kwargs(
    policy_class: type, policy_kwargs: dict[str, Any] | None, observation_space: spaces.Space
) -> tuple[dict[str, Any], str | None]:
    """``policy_kwargs`` with :class:`DemoStandardizer` wrapping the policy's features extractor,
    and a note for the log when that is not plain flattening (or nothing is standardised).

    The wrapped extractor is the user's ``features_extractor_class`` if given, else the policy's
    default (FlattenExtractor for MlpPolicy, CombinedExtractor for MultiInputPolicy). An observation
    without a non-image Box part (images, discrete) is left as it is.
    """
    kwargs = dict(policy_kwargs or {})
    inner = kwargs.get("features_extractor_class")
    if inner is DemoStandardizer:  # already set up (a loaded model)
        return kwargs, None
    if inner is None:
        default = inspect.signature(policy_class).parameters.get("features_extractor_class")
        inner = default.default if default is not None else FlattenExtractor
    if isinstance(inner, type) and issubclass(inner, NatureCNN):
        return kwargs, (
            f"standardize_observations: {inner.__name__} takes the observation for an image (SB3 scales "
            "images, or they come normalised); the policy sees it unchanged"
        )
    if not standardized_keys(observation_space):
        return kwargs, (
            f"standardize_observations: the observation space {observation_space} has no Box part to "
            "standardise (SB3 scales images and one-hot encodes discrete parts); the policy sees them unchanged"
        )
    inner_kwargs = dict(kwargs.pop("features_extractor_kwargs", None) or {})
    if kwargs.get("normalize_images") is False and isinstance(inner, type) and issubclass(inner, CombinedExtractor):
        # What SB3's policy does for its own CombinedExtractor, which it no longer sees behind the wrapper.
        inner_kwargs["normalized_image"] = True
    kwargs["features_extractor_class"] = DemoStandardizer
    kwargs["features_extractor_kwargs"] = {"features_extractor_class": inner, "features_extractor_kwargs": inner_kwargs}
    note = None
    if inner is not FlattenExtractor:
        keys = [str(k) for k in standardized_keys(observation_space) if k is not None]
        parts = ", ".join(keys) or "the Box observation"
        note = (
            f"standardize_observations: {parts} standardised with the demonstrations' statistics before "
            f"{getattr(inner, '__name__', inner)}; other parts pass unchanged"
        )
    return kwargs, note


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
    "standardized_keys",
    "standardizing_policy_kwargs",
    "MIN_OBS_STD",
]
