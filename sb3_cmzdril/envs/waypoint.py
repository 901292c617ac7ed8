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
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Tuple, Union

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: Observation entries after the lidar block (their order is fixed; see the module docstring).
OBS_TAIL = ("goal_distance", "goal_bearing_sin", "goal_bearing_cos", "heading_sin", "heading_cos",
            "speed", "x", "y")
#: ``obs[..., POSITION_SLICE]`` is the vehicle position normalised by the arena half-size; the
#: Fréchet distance of the evaluation is computed on it.
POSITION_SLICE = slice(-2, None)


def obs_dim(n_beams: int) -> int:
    """Length of the observation vector for ``n_beams`` lidar beams."""
    return int(n_beams) + len(OBS_TAIL)


def obs_index(n_beams: int) -> Dict[str, Union[int, slice]]:
    """Named positions in the observation: ``{"lidar": slice, "goal_distance": int, ..., "y": int}``."""
    index: Dict[str, Union[int, slice]] = {"lidar": slice(0, int(n_beams))}
    for i, name in enumerate(OBS_TAIL):
        index[name] = int(n_beams) + i
    return index


@dataclass(frozen=True, eq=False)
class WaypointField:
    """One episode's scene, in metres and radians (world frame, arena centred on the origin).

    ``env.unwrapped.field`` is the current one; pass one back with ``env.reset(options={"field": f})``
    to replay a scene exactly or to build one by hand (tests, figures). A mapping with the same keys
    is accepted there too.

    :param centres: (K, 2) obstacle centres.
    :param radii: (K,) obstacle radii (> 0).
    :param start: (2,) start position of the vehicle.
    :param goal: (2,) waypoint.
    :param start_heading: initial heading (rad, 0 = +x, counter-clockwise).
    :param arena_size: side length of the square arena; ``None`` means "the env's own".
    """

    centres: np.ndarray
    radii: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    start_heading: float = 0.0
    arena_size: Optional[float] = None

    @property
    def n_obstacles(self) -> int:
        return int(len(self.radii))


def _as_field(value: Any) -> WaypointField:
    if isinstance(value, WaypointField):
        return value
    if isinstance(value, Mapping):
        unknown = set(value) - {"centres", "radii", "start", "goal", "start_heading", "arena_size"}
        if unknown:
            raise ValueError(f"unknown field keys {sorted(unknown)}")
        missing = {"start", "goal"} - set(value)
        if missing:
            raise ValueError(f"a field needs {sorted(missing)}")
        return WaypointField(
            centres=value.get("centres", np.zeros((0, 2))), radii=value.get("radii", np.zeros(0)),
            start=value["start"], goal=value["goal"],
            start_heading=float(value.get("start_heading", 0.0)), arena_size=value.get("arena_size"))
    raise ValueError(f"options['field'] must be a WaypointField or a mapping, got {type(value).__name__}")


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


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
        render_mode: Optional[str] = None,
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
            raise ValueError(
                f"max_speed * dt = {self.max_speed * self.dt:g} m per step is more than "
                f"{self.vehicle_radius + self.obstacle_radius[0]:g} m: the vehicle could pass through obstacles")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode

        self.half = 0.5 * self.arena_size
        self.diagonal = math.sqrt(2.0) * self.arena_size
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        n = self.n_beams
        low = np.concatenate([np.zeros(n), [0.0, -1, -1, -1, -1, 0.0, -1, -1]]).astype(np.float32)
        high = np.ones(n + len(OBS_TAIL), dtype=np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self.beam_angles = 2.0 * np.pi * np.arange(n) / n
        self.beam_angles[self.beam_angles > np.pi] -= 2.0 * np.pi
        self._beam_angles = self.beam_angles.copy()  # the step path's private copies
        self._beam_angles_s = self.beam_angles - 0.5 * np.pi
        # Per-step work buffers (no allocations for the (beams x obstacles) intersection in step();
        # the obstacle-sized ones are made in _set_field).
        self._u = np.empty((2, n))
        self._angle = np.empty(n)
        self._pos = np.zeros(2)
        self._pos_col = self._pos[:, None]
        self._inv = np.empty((2, n))
        self._tmp2 = np.empty((2, n))
        self._ranges = np.empty(n)
        self._inv_range = 1.0 / self.lidar_range
        self._half_n = self.half / self.lidar_range

        self._field: Optional[WaypointField] = None
        self._state_ready = False
        self._done = False
        self._background: Optional[np.ndarray] = None
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

    def _validate_field(self, f: WaypointField) -> WaypointField:
        # Copies: the caller may go on changing its arrays; the env's field must not change with them.
        centres = np.array(f.centres, dtype=np.float64).reshape(-1, 2) if np.size(f.centres) else np.zeros((0, 2))
        radii = np.array(f.radii, dtype=np.float64).reshape(-1)
        start = np.array(f.start, dtype=np.float64).reshape(-1)
        goal = np.array(f.goal, dtype=np.float64).reshape(-1)
        if f.arena_size is not None and float(f.arena_size) != self.arena_size:
            raise ValueError(f"field.arena_size {f.arena_size} differs from the env's arena_size {self.arena_size}")
        if len(centres) != len(radii):
            raise ValueError(f"field has {len(centres)} centres but {len(radii)} radii")
        if start.shape != (2,) or goal.shape != (2,):
            raise ValueError(f"field start and goal must be (x, y) pairs, got shapes {start.shape} and {goal.shape}")
        for name, arr in (("centres", centres), ("radii", radii), ("start", start), ("goal", goal)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"field {name} contains NaN or inf")
        if np.any(radii <= 0):
            raise ValueError("field radii must be > 0")
        limit = self.half - self.vehicle_radius
        for name, p in (("start", start), ("goal", goal)):
            if np.any(np.abs(p) >= limit):
                raise ValueError(f"field {name} {tuple(p)} is not inside the arena (|x|, |y| < {limit:g})")
        if len(radii) and np.any(np.hypot(*(centres - start).T) < radii + self.vehicle_radius):
            raise ValueError("field start overlaps an obstacle")
        heading = float(f.start_heading)
        if not math.isfinite(heading):
            raise ValueError("field start_heading must be finite")
        return WaypointField(centres, radii, start, goal, _wrap(heading), self.arena_size)

    def _set_field(self, f: WaypointField) -> None:
        for arr in (f.centres, f.radii, f.start, f.goal):
            arr.setflags(write=False)  # the field is frozen, its arrays too
        self._field = f
        k, n = len(f.radii), self.n_beams
        self._n_obst = k
        # _sense works in units of the lidar range, so its minimum is the observation directly.
        scale = 1.0 / self.lidar_range
        self._centres = np.array(f.centres, dtype=np.float64).reshape(k, 2) * scale
        self._r2 = (f.radii * scale) ** 2
        self._contact_dist = (f.radii + self.vehicle_radius) * scale
        self._goal = (float(f.goal[0]), float(f.goal[1]))
        self._background = None
        self._table = np.empty((k + 3, n))
        self._table[-1] = 1.0
        self._table_obst = self._table[:k]
        self._walls = self._table[k:k + 2]
        self._w = np.empty((k, 2))
        self._wx, self._wy = self._w[:, 0], self._w[:, 1]
        self._dist_k = np.empty(k)
        self._contact = np.empty(k, dtype=bool)
        self._b = np.empty((k, n))
        self._q = np.empty((k, n))
        self._c = np.empty(k)
        self._c_col = self._c[:, None]
        self._miss = np.empty((k, n), dtype=bool)

    def _random_field(self) -> WaypointField:
        rng = self.np_random
        h = self.half - self.wall_margin
        min_sep = 0.6 * 2.0 * h
        for _ in range(100):
            pts = rng.uniform(-h, h, size=(16, 2, 2))
            ok = np.hypot(*(pts[:, 0] - pts[:, 1]).T) >= min_sep
            if not ok.any():
                continue
            start, goal = pts[int(np.argmax(ok))]
            heading = float(rng.uniform(-math.pi, math.pi))
            obstacles = self._place_obstacles(start, goal)
            if obstacles is not None:
                return WaypointField(obstacles[:, :2].copy(), obstacles[:, 2].copy(), start.copy(), goal.copy(),
                                     heading, self.arena_size)
        raise RuntimeError(
            f"could not place {self.n_obstacles} obstacles in a {self.arena_size:g} m arena with "
            f"{self.min_gap:g} m gaps; use fewer obstacles or a larger arena")

    def _place_obstacles(self, start: np.ndarray, goal: np.ndarray) -> Optional[np.ndarray]:
        """(n_obstacles, 3) rows (x, y, r), or ``None`` when this start/goal left too little room.

        Random sequential placement: candidates are tested in the order drawn, each accepted when it
        keeps its distances to the walls, start, goal and the obstacles accepted so far. Candidates
        come in chunks; accepting one drops every later candidate of its chunk that is too close to
        it in one vectorised step, so the next survivor is the next accepted obstacle (the same
        result as testing them one by one, with a few numpy calls per obstacle, not per candidate).
        """
        n = self.n_obstacles
        if n == 0:
            return np.zeros((0, 3))
        rng = self.np_random
        r_lo, r_hi = self.obstacle_radius
        gap, clear = self.min_gap, self.endpoint_clearance
        bound = self.half - gap

        def admissible(cand: np.ndarray) -> np.ndarray:
            x, y, r = cand.T
            ok = (np.abs(x) <= bound - r) & (np.abs(y) <= bound - r)
            ok &= np.hypot(x - start[0], y - start[1]) - r >= clear
            ok &= np.hypot(x - goal[0], y - goal[1]) - r >= clear
            return ok

        # The first obstacle goes on the start-goal segment so that no episode is a straight run; if
        # no segment candidate fits (a segment hugging a wall leaves no room) all are uniform.
        seg = np.empty((16, 3))
        seg[:, 2] = rng.uniform(r_lo, r_hi, size=16)
        seg[:, :2] = start + rng.uniform(0.35, 0.65, size=(16, 1)) * (goal - start) + rng.normal(0.0, 0.3, size=(16, 2))
        ok = np.flatnonzero(admissible(seg))
        placed = seg[ok[:1]]
        chunk, max_chunks = 64, 2 + (5 * n) // 8
        for _ in range(max_chunks):
            if len(placed) == n:
                break
            pool = np.empty((chunk, 3))
            pool[:, 2] = rng.uniform(r_lo, r_hi, size=chunk)
            pool[:, :2] = rng.uniform(-1.0, 1.0, size=(chunk, 2)) * (bound - pool[:, 2:])
            pool = pool[admissible(pool)]
            if len(placed) and len(pool):
                d = np.hypot(pool[:, None, 0] - placed[None, :, 0], pool[:, None, 1] - placed[None, :, 1])
                pool = pool[(d - pool[:, 2:] - placed[None, :, 2] >= gap).all(axis=1)]
            accepted = []
            while len(pool) and len(placed) + len(accepted) < n:
                first = pool[0]
                accepted.append(first)
                rest = pool[1:]
                pool = rest[np.hypot(rest[:, 0] - first[0], rest[:, 1] - first[1]) - rest[:, 2] - first[2] >= gap]
            if accepted:
                placed = np.concatenate([placed, np.array(accepted)])
        return placed if len(placed) == n else None

    # -- gym API ----------------------------------------------------------------------------------
    def reset(self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
              ) -> Tuple[np.ndarray, Dict[str, Any]]:
        """Start an episode on a new random field, or on ``options["field"]`` (a :class:`WaypointField`)."""
        super().reset(seed=seed)
        options = dict(options or {})
        given = options.pop("field", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; the only option is 'field'")
        f = self._validate_field(_as_field(given)) if given is not None else self._random_field()
        self._set_field(f)
        self._x, self._y = float(f.start[0]), float(f.start[1])
        self._heading = float(f.start_heading)
        self._speed = 0.0
        self._steps = 0
        self._done = False
        self._state_ready = True
        self._trail = [(self._x, self._y)]
        self._dist = math.hypot(self._goal[0] - self._x, self._goal[1] - self._y)
        collided = self._sense()
        obs = self._observation()
        return obs, self._info(False, collided, False)

    def step(self, action: Any) -> Tuple[np.ndarray, float, bool, bool, Dict[str, Any]]:
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

        self._heading = _wrap(self._heading + a0 * self.max_turn_rate * self.dt)
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
        collision = self._sense() or out
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

    def _sense(self) -> bool:
        """Lidar ranges / lidar_range (into ``self._ranges``) at the current pose; returns obstacle contact.

        All beams against all obstacles and the walls at once, in units of the lidar range. Rows of
        ``self._table`` are obstacles, then the two wall axes, then a constant row of 1 (the range
        limit): one column-wise minimum gives the clipped ranges. (Rows-by-beams rather than
        beams-by-rows because numpy reduces over the leading axis of a small array several times
        faster.)
        """
        pos = self._pos
        pos[0] = self._x * self._inv_range
        pos[1] = self._y * self._inv_range
        u = self._u                                        # (2, J) world-frame beam directions
        # sin(a) is taken as cos(a - pi/2): the cosine of a float is never exactly 0 (no float is an
        # odd multiple of pi/2), whereas sin(0.0) is, and 1/u below must stay finite.
        np.cos(np.add(self._beam_angles, self._heading, out=self._angle), out=u[0])
        np.cos(np.add(self._beam_angles_s, self._heading, out=self._angle), out=u[1])
        # Walls: along an axis the wall ahead is at (half - p*sign(u)) / |u| = half*|1/u| - p/u.
        inv = np.divide(1.0, u, out=self._inv)
        walls = np.abs(inv, out=self._walls)
        walls *= self._half_n
        walls -= np.multiply(inv, self._pos_col, out=self._tmp2)
        contact = False
        if self._n_obst:
            w = np.subtract(self._centres, pos, out=self._w)   # (K, 2) vehicle -> centre
            dist = np.hypot(self._wx, self._wy, out=self._dist_k)
            contact = np.count_nonzero(np.less(dist, self._contact_dist, out=self._contact)) > 0
            b = np.matmul(w, u, out=self._b)                  # (K, J) centre projected on each beam
            c = np.multiply(dist, dist, out=self._c)
            c -= self._r2                                      # |w|^2 - r^2 > 0 outside the disc
            # Ray p + t*u meets |x - c| = r at t = b - sqrt(b^2 - c). Outside the disc a hit ahead
            # needs b > 0 and b^2 >= c, i.e. q = b*|b| - c >= 0 (q < 0 also when b <= 0).
            q = np.abs(b, out=self._q)
            q *= b
            q -= self._c_col
            miss = np.less(q, 0.0, out=self._miss)
            np.maximum(q, 0.0, out=q)
            np.sqrt(q, out=q)
            np.subtract(b, q, out=self._table_obst)
            np.putmask(self._table_obst, miss, np.inf)
        np.minimum.reduce(self._table, axis=0, out=self._ranges)
        return bool(contact)

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

    def _info(self, success: bool, collision: bool, out: bool) -> Dict[str, Any]:
        return {"is_success": success, "collision": collision, "out_of_bounds": out,
                "position": np.array((self._x, self._y)), "goal_distance": self._dist}

    # -- rendering --------------------------------------------------------------------------------
    def render(self) -> Optional[np.ndarray]:
        """``rgb_array``: an (H, W, 3) uint8 top view (obstacles grey, goal green, path blue,
        vehicle red with its heading, lidar hits orange)."""
        if self.render_mode is None:
            gym.logger.warn("render() called with render_mode=None; pass render_mode='rgb_array' to gym.make")
            return None
        if not self._state_ready:
            raise RuntimeError("call reset() before render()")
        return _render(self)

    def close(self) -> None:
        self._background = None


# Render size in pixels (square); plain numpy drawing keeps rendering free of display back-ends.
RENDER_SIZE = 400


def _render(env: WaypointNavEnv) -> np.ndarray:
    size = RENDER_SIZE
    scale = size / env.arena_size                       # pixels per metre
    coords = (np.arange(size) + 0.5) / scale - env.half
    xs, ys = coords[None, :], coords[::-1, None]        # image row 0 is the top (+y)
    if env._background is None:
        img = np.full((size, size, 3), 255, dtype=np.uint8)
        f = env.field
        for (cx, cy), r in zip(f.centres, f.radii):
            img[(xs - cx) ** 2 + (ys - cy) ** 2 <= r * r] = (110, 110, 110)
        gx, gy = f.goal
        img[(xs - gx) ** 2 + (ys - gy) ** 2 <= env.goal_radius ** 2] = (40, 170, 60)
        sx, sy = f.start
        ring = (xs - sx) ** 2 + (ys - sy) ** 2
        img[(ring <= 0.3 ** 2) & (ring >= 0.18 ** 2)] = (40, 80, 220)
        img[[0, -1], :] = 0
        img[:, [0, -1]] = 0
        env._background = img
    img = env._background.copy()

    def pixel(px: np.ndarray, py: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        col = np.clip(((px + env.half) * scale).astype(int), 0, size - 1)
        row = np.clip(((env.half - py) * scale).astype(int), 0, size - 1)
        return row, col

    trail = env.trajectory
    if len(trail) > 1:
        # Dense samples along each segment give a continuous line without a drawing library.
        s = np.linspace(0.0, 1.0, 8)[:, None, None]
        pts = (trail[:-1][None] * (1 - s) + trail[1:][None] * s).reshape(-1, 2)
        img[pixel(pts[:, 0], pts[:, 1])] = (40, 80, 220)
    hits = env._ranges < 1.0
    if hits.any():
        hp = np.array([env._x, env._y]) + env.lidar_range * env._ranges[hits, None] * env._u.T[hits]
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = pixel(hp[:, 0], hp[:, 1])
                img[np.clip(r + dr, 0, size - 1), np.clip(c + dc, 0, size - 1)] = (255, 140, 0)
    img[(xs - env._x) ** 2 + (ys - env._y) ** 2 <= env.vehicle_radius ** 2] = (220, 30, 30)
    s = np.linspace(0.0, 2.5 * env.vehicle_radius, 20)
    img[pixel(env._x + s * math.cos(env._heading), env._y + s * math.sin(env._heading))] = (120, 0, 0)
    return img


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def _check_float(name: str, value: Any, minimum: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < minimum:
        raise ValueError(f"{name} must be a finite number >= {minimum:g}, got {value!r}")
    return v
