"""The reactive expert for WaypointNav-v0: head for the goal, slide along obstacle tangents.

It is a function of the observation alone (an imitator sees only observations, so an expert that
peeked at the simulator state would be impossible to imitate exactly):

1. Every lidar beam that returns a hit gives a point on an obstacle or wall in the body frame. Each
   point is inflated to a disc of radius ``safety_radius`` (vehicle radius plus a margin that also
   covers the gaps between neighbouring beams).
2. Candidate headings are the goal bearing plus offsets 0, +d, -d, +2d, -2d, ... (d = 360 /
   ``n_headings`` degrees). A candidate is blocked when its ray, up to ``min(goal distance,
   lookahead)``, passes within ``safety_radius`` of a hit point ahead of the vehicle.
3. Of the free candidates it takes the one minimising ``|offset| + turn_weight * |turn needed|``:
   the goal itself when the way is clear, otherwise the tangent to the inflated obstacle's edge on
   the side nearer the goal. Following it makes the vehicle slide along the obstacle's tangent line
   until the goal comes free again (the paper's "follows a tangent line to the obstacle"). The turn
   term (< 1, so the goal still wins whenever it is free) makes the vehicle keep to the side it is
   already turning towards: without it, which of two nearly equal ways round looked better
   flickered as the beams swept over the obstacle, and the vehicle dithered on the spot.
4. Turn: proportional, saturating, reaching the chosen heading in one step when the turn rate
   allows. Throttle: ``cos`` of the heading error (clipped at 0), so it slows for sharp turns and
   turns on the spot when the chosen heading is behind it.

If every candidate is blocked it turns toward the longest lidar return at low speed.
"""
from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_cmzdril.envs.waypoint import OBS_TAIL, WaypointNavEnv
from sb3_cmzdril.errors import UserError


class WaypointReactiveExpert:
    """SB3-style ``predict`` for WaypointNav-v0 observations (one (D,) or a batch (n, D)).

    The defaults match ``WaypointNavEnv()``'s; build it with :func:`make_waypoint_expert` (or
    :meth:`from_env`) to follow an env's options.

    :param n_beams: lidar beams in the observation.
    :param lidar_range: metres that a lidar value of 1 stands for.
    :param arena_size: arena side in metres (goal distance is normalised by its diagonal).
    :param max_turn_rate: rad/s at full heading command.
    :param dt: seconds per step.
    :param safety_radius: metres kept between the vehicle centre and any lidar hit point.
    :param lookahead: metres along a candidate heading that must be free.
    :param n_headings: candidate headings over 360 degrees.
    :param turn_weight: weight in [0, 1) of the turn needed in the choice of heading.

    It needs at least 16 beams: with 8 (45 degrees apart) the free headings it sees jump too much from
    step to step, and it dithers (no collisions, but time-outs in a quarter of episodes).
    """

    def __init__(
        self,
        n_beams: int = 32,
        lidar_range: float = 8.0,
        arena_size: float = 20.0,
        max_turn_rate: float = math.pi / 2,
        dt: float = 0.1,
        safety_radius: float = 0.7,
        lookahead: float = 2.5,
        n_headings: int = 72,
        turn_weight: float = 0.5,
        observation_space: gym.spaces.Space | None = None,
        action_space: gym.spaces.Space | None = None,
    ) -> None:
        if int(n_beams) < 1:
            raise UserError(f"n_beams must be >= 1, got {n_beams}")
        if int(n_headings) < 4:
            raise UserError(f"n_headings must be >= 4, got {n_headings}")
        for name, v in (("lidar_range", lidar_range), ("arena_size", arena_size),
                        ("max_turn_rate", max_turn_rate), ("dt", dt), ("safety_radius", safety_radius),
                        ("lookahead", lookahead)):
            if not (math.isfinite(float(v)) and float(v) > 0):
                raise UserError(f"{name} must be a positive number, got {v!r}")
        self.n_beams = int(n_beams)
        self.obs_dim = self.n_beams + len(OBS_TAIL)
        self.lidar_range = float(lidar_range)
        self.diagonal = math.sqrt(2.0) * float(arena_size)
        self.max_turn = float(max_turn_rate) * float(dt)      # rad per step at |a0| = 1
        self.safety_radius = float(safety_radius)
        self.lookahead = float(lookahead)
        if not 0.0 <= float(turn_weight) < 1.0:
            raise UserError(f"turn_weight must be in [0, 1), got {turn_weight!r}")
        self.turn_weight = float(turn_weight)
        self.observation_space = observation_space
        self.action_space = action_space

        angles = 2.0 * np.pi * np.arange(self.n_beams) / self.n_beams
        self.beam_angles = np.where(angles > np.pi, angles - 2.0 * np.pi, angles)
        step = 2.0 * np.pi / int(n_headings)
        k = np.arange(1, int(n_headings) // 2 + 1)
        # 0, +d, -d, +2d, -2d, ...: argmax over "free" then returns the free offset of least size,
        # ties going to the left (a fixed rule, so the expert is deterministic).
        self.offsets = np.concatenate([[0.0], np.stack([k * step, -k * step], axis=1).reshape(-1)])
        self.offsets = self.offsets[np.abs(self.offsets) <= np.pi + 1e-9]

    @classmethod
    def from_env(cls, env: gym.Env, **kwargs: Any) -> WaypointReactiveExpert:
        """An expert configured from ``env``'s options (wrappers are looked through)."""
        base = env.unwrapped
        if not isinstance(base, WaypointNavEnv):
            raise ValueError(f"the waypoint expert needs a WaypointNav env, got {type(base).__name__}")
        config: dict[str, Any] = dict(
            n_beams=base.n_beams, lidar_range=base.lidar_range, arena_size=base.arena_size,
            max_turn_rate=base.max_turn_rate, dt=base.dt,
            observation_space=base.observation_space, action_space=base.action_space,
        )
        config.update(kwargs)
        return cls(**config)

    def predict(
        self,
        observation: np.ndarray,
        state: Any | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """Actions (2,) for one observation, (n, 2) for a batch; float32 in [-1, 1]."""
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        if single:
            obs = obs[None]
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise ValueError(
                f"expected observations of shape ({self.obs_dim},) or (n, {self.obs_dim}) for "
                f"{self.n_beams} beams, got {np.shape(observation)}")
        if not np.all(np.isfinite(obs)):
            raise ValueError("observation contains NaN or inf")
        n = len(obs)
        j = self.n_beams
        lidar = obs[:, :j]
        ranges = lidar * self.lidar_range
        hit = lidar < 1.0 - 1e-6
        goal_dist = obs[:, j] * self.diagonal
        bearing = np.arctan2(obs[:, j + 1], obs[:, j + 2])

        headings = bearing[:, None] + self.offsets[None, :]                        # (n, M)
        rel = headings[:, :, None] - self.beam_angles[None, None, :]              # (n, M, J)
        along = ranges[:, None, :] * np.cos(rel)
        perp = ranges[:, None, :] * np.sin(rel)
        reach = np.minimum(goal_dist, self.lookahead)[:, None, None]
        # Only points ahead along the candidate count, so a vehicle already inside a point's safety
        # disc can still move away from it.
        rs = self.safety_radius
        blocked = (hit[:, None, :] & (along > 0.0) & (np.abs(perp) < rs)
                   & (along - np.sqrt(np.maximum(rs * rs - perp * perp, 0.0)) < reach))
        free = ~blocked.any(axis=2)                                                # (n, M)
        body = (headings + np.pi) % (2.0 * np.pi) - np.pi                          # turn needed
        cost = np.where(free, np.abs(self.offsets)[None, :] + self.turn_weight * np.abs(body), np.inf)
        best = np.argmin(cost, axis=1)
        error = body[np.arange(n), best]
        stuck = ~free.any(axis=1)
        if stuck.any():
            error = np.where(stuck, self.beam_angles[np.argmax(ranges, axis=1)], error)

        actions = np.empty((n, 2), dtype=np.float32)
        actions[:, 0] = np.clip(error / self.max_turn, -1.0, 1.0)
        speed = np.clip(np.cos(error), 0.0, 1.0)
        speed = np.where(stuck, np.minimum(speed, 0.2), speed)
        actions[:, 1] = 2.0 * speed - 1.0
        return (actions[0] if single else actions), None


def make_waypoint_expert(env: gym.Env) -> WaypointReactiveExpert:
    """Factory registered as the scripted expert ``"waypoint-reactive"``."""
    return WaypointReactiveExpert.from_env(env)
