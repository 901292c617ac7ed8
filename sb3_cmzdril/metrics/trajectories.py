"""Which features of the observations make the path that the Fréchet distance compares."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

TrajectoryFn = Callable[[np.ndarray], np.ndarray]


def full_observation(obs: np.ndarray) -> np.ndarray:
    """Default trajectory feature: the whole (flattened) observation, (T, obs_dim)."""
    obs = np.asarray(obs)
    return obs.reshape(len(obs), -1)


def waypoint_position(obs: np.ndarray) -> np.ndarray:
    """WaypointNav-v0: the vehicle's (x, y), the last two observation entries (normalised by the arena half-size)."""
    return np.asarray(obs)[..., -2:]


#: Env id (without ``module:`` prefix) -> function mapping observations (T, d) to path points (T, k).
TRAJECTORY_FEATURES: dict[str, TrajectoryFn] = {
    "WaypointNav-v0": waypoint_position,
}


def _strip_module(env_id: str) -> str:
    return env_id.split(":", 1)[-1]


def trajectory_features(env_id: str | None) -> TrajectoryFn:
    """The trajectory feature function for an env id (``module:`` prefix allowed); full observation by default."""
    if env_id is None:
        return full_observation
    return TRAJECTORY_FEATURES.get(_strip_module(env_id), full_observation)
