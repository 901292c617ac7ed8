"""WaypointNav-v0: drive a vehicle to a waypoint through a random field of circular obstacles.

Our public stand-in for the paper's PyUXV (not public): "a waypoint-navigation and obstacle-avoidance
environment [whose] observation space includes lidar readings as well as position and goal
information. The agent uses continuous heading and throttle control to navigate in a 2D plane to
the waypoint while avoiding a randomly-initialized field of obstacles."

Kinematics (unicycle, one step = ``dt`` seconds, default 0.1 s), action ``a`` in [-1, 1]^2 (clipped)::

    turn rate  w = a[0] * max_turn_rate          (rad/s, positive = counter-clockwise)
    speed      v = (a[1] + 1) / 2 * max_speed    (m/s, throttle sets the speed directly, 0 .. max)
    heading   th <- wrap(th + w * dt)            (turn first, then move: semi-implicit Euler)
    position   p <- p + v * dt * (cos th, sin th)

Observation (float32, length ``n_beams + 8``), the layout other modules rely on::

    [0 : n_beams]   lidar ranges / lidar_range, in [0, 1]; beam j points at body angle
                    2*pi*j/n_beams (counter-clockwise, beam 0 straight ahead); 1 = nothing in range
    [n_beams]       distance to goal / arena diagonal, in [0, 1]
    [n_beams + 1]   sin(goal bearing in the body frame)
    [n_beams + 2]   cos(goal bearing in the body frame)
    [n_beams + 3]   sin(heading)           (world frame)
    [n_beams + 4]   cos(heading)
    [n_beams + 5]   speed / max_speed, in [0, 1]
    [-2:]           x, y position / (arena_size / 2), in [-1, 1] (clipped at the walls)

``obs[..., -2:]`` (:data:`POSITION_SLICE`) is the vehicle's normalised position: the evaluation code
computes the Fréchet distance between expert and imitator paths on it.

The step limit is the env's own ``max_steps`` option (``truncated=True`` when reached), not a
``TimeLimit`` wrapper: it is then settable through ``gym.make(..., max_steps=N)``, has one source of
truth, and holds for ``env.unwrapped`` too. See ``docs/waypoint.md`` for reward and design notes.

This module is the gymnasium Env (spaces, dynamics, reward, episode logic). Its parts live apart:
scenes (:class:`WaypointField`, random generation, checks) in :mod:`.waypoint_field`, the lidar's
ray casting in :mod:`.waypoint_lidar`, ``rgb_array`` drawing in :mod:`.waypoint_render`.
"""
from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

# WaypointField is imported from here too (where it was first defined): keep it in this import.
from sb3_cmzdril.envs.waypoint_field import (
    WaypointField,
    as_field,
    random_field,
    validate_field,
    wrap_angle,
)
from sb3_cmzdril.envs.waypoint_lidar import Lidar
from sb3_cmzdril.envs.waypoint_render import draw_background, draw_frame
from sb3_cmzdril.errors import UserError

#: Observation entries after the lidar block (their order is fixed; see the module docstring).
OBS_TAIL = ("goal_distance", "goal_bearing_sin", "goal_bearing_cos", "heading_sin", "heading_cos",
            "speed", "x", "y")
#: ``obs[..., POSITION_SLICE]`` is the vehicle position normalised by the arena half-size; the
#: Fréchet distance of the evaluation is computed on it.
POSITION_SLICE = slice(-2, None)


def obs_dim(n_beams: int) -> int:
    """Length of the observation vector for ``n_beams`` lidar beams."""
    return int(n_beams) + len(OBS_TAIL)


def obs_index(n_beams: int) -> dict[str, int | slice]:
    """Named positions in the observation: ``{"lidar": slice, "goal_distance": int, ..., "y": int}``."""
    index: dict[str, int | slice] = {"lidar": slice(0, int(n_beams))}
    for i, name in enumerate(OBS_TAIL):
        index[name] = int(n_beams) + i
    return index



class WaypointNavEnv(gym.Env):
    """Waypoint navigation with lidar through random circular obstacles (see the module docstring).

    Reward per step: ``-time_penalty + progress_weight * (previous goal distance - goal distance)``,
    plus ``goal_bonus`` on reaching the goal and minus ``crash_penalty`` on hitting an obstacle or a
    wall. The progress term is potential-based shaping (it telescopes to the net distance gained),
    so it gives a dense signal without changing which paths are best; the time penalty prefers
    short paths; ``crash_penalty > time_penalty * max_steps`` with the defaults, so crashing is
    never cheaper than idling until the step limit.

    Episodes terminate on reaching the goal (distance <= ``goal_radius``), on a collision (vehicle
    disc overlapping an obstacle) and on leaving the arena (vehicle disc crossing a wall); they are
    truncated after ``max_steps`` steps. ``info`` holds ``is_success``, ``collision`` (obstacle or
    wall), ``out_of_bounds`` (wall), ``position`` (x, y in metres) and ``goal_distance`` (metres).

    Random fields (``reset`` without a ``field`` option), drawn from ``self.np_random`` so the reset
    seed fixes them: start and goal uniform at least ``wall_margin`` from the walls and at least
    ``0.6 * (arena_size - 2 * wall_margin)`` apart; random heading; ``n_obstacles`` discs with radii
    in ``obstacle_radius``; the first one sits on the start-goal segment (so every episode needs
    avoiding), the rest uniformly; all obstacles keep ``min_gap`` between their surfaces and from
    the walls (so every gap is wide enough to pass and no obstacle forms a pocket with a wall) and
    ``endpoint_clearance`` from start and goal.

    :param n_obstacles: number of obstacles (>= 0).
    :param n_beams: number of lidar beams (>= 1), evenly spaced over 360 degrees.
    :param arena_size: side of the square arena in metres (>= 10).
    :param max_steps: step limit (truncation), >= 1.
    :param lidar_range: lidar maximum range in metres.
    :param max_speed: m/s at full throttle.
    :param max_turn_rate: rad/s at full heading command.
    :param dt: seconds per step.
    :param render_mode: ``None`` or ``"rgb_array"``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    vehicle_radius = 0.25
    goal_radius = 0.5
    wall_margin = 2.0
    endpoint_clearance = 1.5
    min_gap = 2.0
    obstacle_radius = (0.5, 1.5)
    time_penalty = 0.05
    progress_weight = 1.0
    goal_bonus = 10.0
    crash_penalty = 20.0

    def __init__(
        self,
        n_obstacles: int = 10,
        n_beams: int = 32,
        arena_size: float = 20.0,
        max_steps: int = 300,
        lidar_range: float = 8.0,
        max_speed: float = 2.5,
        max_turn_rate: float = math.pi / 2,
        dt: float = 0.1,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        self.n_obstacles = _check_int("n_obstacles", n_obstacles, 0)
        self.n_beams = _check_int("n_beams", n_beams, 1)
        self.max_steps = _check_int("max_steps", max_steps, 1)
        self.arena_size = _check_float("arena_size", arena_size, 10.0)
        self.lidar_range = _check_float("lidar_range", lidar_range, 1e-6)
        self.max_speed = _check_float("max_speed", max_speed, 1e-6)
        self.max_turn_rate = _check_float("max_turn_rate", max_turn_rate, 1e-6)
        self.dt = _check_float("dt", dt, 1e-6)
        if self.max_speed * self.dt > self.vehicle_radius + self.obstacle_radius[0]:
            # Collisions are checked at the end of each step; a longer stride could jump an obstacle.
            raise UserError(
                f"max_speed * dt = {self.max_speed * self.dt:g} m per step is more than "
                f"{self.vehicle_radius + self.obstacle_radius[0]:g} m: the vehicle could pass through obstacles")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode

        self.half = 0.5 * self.arena_size
        self.diagonal = math.sqrt(2.0) * self.arena_size
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        n = self.n_beams
        low = np.concatenate([np.zeros(n), [0.0, -1, -1, -1, -1, 0.0, -1, -1]]).astype(np.float32)
        high = np.ones(n + len(OBS_TAIL), dtype=np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self._lidar = Lidar(n, self.lidar_range, self.half)
        # A public copy: changing it must not steer the sensor.
        self.beam_angles = self._lidar.beam_angles
        # The lidar's own arrays, written in place by every sense(): aliases, not copies.
        self._ranges = self._lidar.ranges

        self._field: WaypointField | None = None
        self._state_ready = False
        self._done = False
        self._background: np.ndarray | None = None
        self._set_field(self._demo_field())

    # -- scene ------------------------------------------------------------------------------------
    @property
    def field(self) -> WaypointField:
        """The current scene (obstacles, start, goal, start heading, arena size)."""
        assert self._field is not None
        return self._field

    @property
    def trajectory(self) -> np.ndarray:
        """(T + 1, 2) positions in metres since the last reset, the start included."""
        return np.asarray(self._trail, dtype=np.float64).reshape(-1, 2)

    def _demo_field(self) -> WaypointField:
        h = self.half - self.wall_margin
        return WaypointField(np.zeros((0, 2)), np.zeros(0), np.array([-h, -h]), np.array([h, h]),
                             0.0, self.arena_size)

    def _set_field(self, f: WaypointField) -> None:
        for arr in (f.centres, f.radii, f.start, f.goal):
            arr.setflags(write=False)  # the field is frozen, its arrays too
        self._field = f
        self._goal = (float(f.goal[0]), float(f.goal[1]))
        self._background = None
        self._lidar.set_obstacles(f.centres, f.radii, self.vehicle_radius)

    def _random_field(self) -> WaypointField:
        # The class attributes are read now, so a subclass or an instance can change them.
        return random_field(self.np_random, self.n_obstacles, self.arena_size, self.wall_margin, self.min_gap,
                            self.endpoint_clearance, self.obstacle_radius)

    # -- gym API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode on a new random field, or on ``options["field"]`` (a :class:`WaypointField`)."""
        super().reset(seed=seed)
        options = dict(options or {})
        given = options.pop("field", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; the only option is 'field'")
        if given is not None:
            f = validate_field(as_field(given), self.arena_size, self.vehicle_radius)
        else:
            f = self._random_field()
        self._set_field(f)
        self._x, self._y = float(f.start[0]), float(f.start[1])
        self._heading = float(f.start_heading)
        self._speed = 0.0
        self._steps = 0
        self._done = False
        self._state_ready = True
        self._trail = [(self._x, self._y)]
        self._dist = math.hypot(self._goal[0] - self._x, self._goal[1] - self._y)
        collided = self._lidar.sense(self._x, self._y, self._heading)
        obs = self._observation()
        return obs, self._info(False, collided, False)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._state_ready:
            raise RuntimeError("call reset() before step()")
        if self._done:
            raise RuntimeError("the episode has ended (terminated or truncated); call reset() first")
        shape = getattr(action, "shape", None)
        if shape is None:
            action = np.asarray(action, dtype=np.float64)
            shape = action.shape
        if shape != (2,):
            raise ValueError(f"action must have shape (2,) (turn, throttle), got shape {shape}")
        a0, a1 = float(action[0]), float(action[1])
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise ValueError(f"action contains NaN or inf: {[a0, a1]}")
        a0 = -1.0 if a0 < -1.0 else (1.0 if a0 > 1.0 else a0)
        a1 = -1.0 if a1 < -1.0 else (1.0 if a1 > 1.0 else a1)

        self._heading = wrap_angle(self._heading + a0 * self.max_turn_rate * self.dt)
        self._speed = 0.5 * (a1 + 1.0) * self.max_speed
        step = self._speed * self.dt
        self._x += step * math.cos(self._heading)
        self._y += step * math.sin(self._heading)
        self._steps += 1
        self._trail.append((self._x, self._y))

        prev = self._dist
        self._dist = dist = math.hypot(self._goal[0] - self._x, self._goal[1] - self._y)
        limit = self.half - self.vehicle_radius
        out = abs(self._x) > limit or abs(self._y) > limit
        collision = self._lidar.sense(self._x, self._y, self._heading) or out
        if collision:
            # From inside an obstacle or beyond a wall some beams meet a surface behind the sensor
            # (negative range); the terminal observation still has to lie in the observation space.
            np.maximum(self._ranges, 0.0, out=self._ranges)
        success = (not collision) and dist <= self.goal_radius
        reward = self.progress_weight * (prev - dist) - self.time_penalty
        if collision:
            reward -= self.crash_penalty
        elif success:
            reward += self.goal_bonus
        terminated = collision or success
        truncated = (not terminated) and self._steps >= self.max_steps
        self._done = terminated or truncated
        return self._observation(), reward, terminated, truncated, self._info(success, collision, out)

    def _observation(self) -> np.ndarray:
        n = self.n_beams
        obs = np.empty(n + 8, dtype=np.float32)
        obs[:n] = self._ranges
        dx, dy = self._goal[0] - self._x, self._goal[1] - self._y
        dist = self._dist
        ch, sh = math.cos(self._heading), math.sin(self._heading)
        if dist > 1e-9:
            cb, sb = (dx * ch + dy * sh) / dist, (dy * ch - dx * sh) / dist
        else:
            cb, sb = 1.0, 0.0
        g = dist / self.diagonal
        x, y = self._x / self.half, self._y / self.half
        # Scalar stores: cheaper than building a tuple or array for eight values.
        obs[n] = g if g < 1.0 else 1.0
        obs[n + 1] = sb
        obs[n + 2] = cb
        obs[n + 3] = sh
        obs[n + 4] = ch
        obs[n + 5] = self._speed / self.max_speed
        obs[n + 6] = -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)
        obs[n + 7] = -1.0 if y < -1.0 else (1.0 if y > 1.0 else y)
        return obs

    def _info(self, success: bool, collision: bool, out: bool) -> dict[str, Any]:
        return {"is_success": success, "collision": collision, "out_of_bounds": out,
                "position": np.array((self._x, self._y)), "goal_distance": self._dist}

    # -- rendering --------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """``rgb_array``: an (H, W, 3) uint8 top view (obstacles grey, goal green, path blue,
        vehicle red with its heading, lidar hits orange)."""
        if self.render_mode is None:
            gym.logger.warn("render() called with render_mode=None; pass render_mode='rgb_array' to gym.make")
            return None
        if not self._state_ready:
            raise RuntimeError("call reset() before render()")
        if self._background is None:
            # The scene changes only on reset (_set_field clears this): draw it once per field.
            self._background = draw_background(self.field, self.arena_size, self.goal_radius)
        return draw_frame(self._background, self.arena_size, self.trajectory, (self._x, self._y, self._heading),
                          self.vehicle_radius, self._lidar.hit_points(self._x, self._y))

    def close(self) -> None:
        self._background = None


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise UserError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise UserError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def _check_float(name: str, value: Any, minimum: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < minimum:
        raise UserError(f"{name} must be a finite number >= {minimum:g}, got {value!r}")
    return v
