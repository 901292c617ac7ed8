"""WaypointNav scenes: the :class:`WaypointField` record, checking a given one, drawing a random one.

A field is one episode's scene (obstacle discs, start, goal, start heading) in metres and radians,
world frame, arena centred on the origin. This module knows nothing of the env's dynamics or sensor;
the env passes in its arena size and clearances, so a field made here is the one the env would make
from the same random generator state (:meth:`WaypointNavEnv.reset` calls :func:`random_field` with
``self.np_random``, so the reset seed fixes the scene).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Keys a mapping may have where a :class:`WaypointField` is accepted (``reset(options={"field": ...})``).
FIELD_KEYS = ("centres", "radii", "start", "goal", "start_heading", "arena_size")


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
    arena_size: float | None = None

    @property
    def n_obstacles(self) -> int:
        """Number of obstacle discs."""
        return int(len(self.radii))


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def as_field(value: Any) -> WaypointField:
    """``value`` as a :class:`WaypointField`: one is returned as is, a mapping of :data:`FIELD_KEYS`
    (``start`` and ``goal`` required) is converted; anything else is a ``ValueError``."""
    if isinstance(value, WaypointField):
        return value
    if isinstance(value, Mapping):
        unknown = set(value) - set(FIELD_KEYS)
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


def validate_field(f: WaypointField, arena_size: float, vehicle_radius: float) -> WaypointField:
    """A checked float64 copy of ``f`` for an arena of side ``arena_size`` and a vehicle disc of
    ``vehicle_radius``: shapes agree, values are finite, radii positive, start and goal inside the
    arena, the start clear of every obstacle; the heading is wrapped and ``arena_size`` filled in.

    :raises ValueError: naming the first check that fails.
    """
    # Copies: the caller may go on changing its arrays; the env's field must not change with them.
    centres = np.array(f.centres, dtype=np.float64).reshape(-1, 2) if np.size(f.centres) else np.zeros((0, 2))
    radii = np.array(f.radii, dtype=np.float64).reshape(-1)
    start = np.array(f.start, dtype=np.float64).reshape(-1)
    goal = np.array(f.goal, dtype=np.float64).reshape(-1)
    if f.arena_size is not None and float(f.arena_size) != arena_size:
        raise ValueError(f"field.arena_size {f.arena_size} differs from the env's arena_size {arena_size}")
    if len(centres) != len(radii):
        raise ValueError(f"field has {len(centres)} centres but {len(radii)} radii")
    if start.shape != (2,) or goal.shape != (2,):
        raise ValueError(f"field start and goal must be (x, y) pairs, got shapes {start.shape} and {goal.shape}")
    for name, arr in (("centres", centres), ("radii", radii), ("start", start), ("goal", goal)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"field {name} contains NaN or inf")
    if np.any(radii <= 0):
        raise ValueError("field radii must be > 0")
    limit = 0.5 * arena_size - vehicle_radius
    for name, p in (("start", start), ("goal", goal)):
        if np.any(np.abs(p) >= limit):
            raise ValueError(f"field {name} {tuple(p)} is not inside the arena (|x|, |y| < {limit:g})")
    if len(radii) and np.any(np.hypot(*(centres - start).T) < radii + vehicle_radius):
        raise ValueError("field start overlaps an obstacle")
    heading = float(f.start_heading)
    if not math.isfinite(heading):
        raise ValueError("field start_heading must be finite")
    return WaypointField(centres, radii, start, goal, wrap_angle(heading), arena_size)


def random_field(
    rng: np.random.Generator,
    n_obstacles: int,
    arena_size: float,
    wall_margin: float,
    min_gap: float,
    endpoint_clearance: float,
    obstacle_radius: tuple[float, float],
) -> WaypointField:
    """A random scene drawn from ``rng`` (the rules are in :class:`WaypointNavEnv`'s docstring).

    Start and goal are uniform at least ``wall_margin`` from the walls and at least
    ``0.6 * (arena_size - 2 * wall_margin)`` apart, the heading uniform; the obstacles come from
    :func:`place_obstacles`. A start/goal pair that leaves too little room is drawn again.

    :raises RuntimeError: when 100 start/goal draws leave no room for ``n_obstacles`` obstacles.
    """
    half = 0.5 * arena_size
    h = half - wall_margin
    min_sep = 0.6 * 2.0 * h
    for _ in range(100):
        # The order of the draws (pairs, heading, obstacles) is what a reset seed reproduces:
        # changing it changes every seeded scene, the shipped demo pool's included.
        pts = rng.uniform(-h, h, size=(16, 2, 2))
        ok = np.hypot(*(pts[:, 0] - pts[:, 1]).T) >= min_sep
        if not ok.any():
            continue
        start, goal = pts[int(np.argmax(ok))]
        heading = float(rng.uniform(-math.pi, math.pi))
        obstacles = place_obstacles(rng, start, goal, n_obstacles, half, min_gap, endpoint_clearance,
                                    obstacle_radius)
        if obstacles is not None:
            return WaypointField(obstacles[:, :2].copy(), obstacles[:, 2].copy(), start.copy(), goal.copy(),
                                 heading, arena_size)
    raise RuntimeError(
        f"could not place {n_obstacles} obstacles in a {arena_size:g} m arena with "
        f"{min_gap:g} m gaps; use fewer obstacles or a larger arena")


def place_obstacles(
    rng: np.random.Generator,
    start: np.ndarray,
    goal: np.ndarray,
    n: int,
    half: float,
    gap: float,
    clear: float,
    obstacle_radius: tuple[float, float],
) -> np.ndarray | None:
    """(n, 3) rows (x, y, r), or ``None`` when this start/goal left too little room.

    Every obstacle keeps ``gap`` between its surface and the walls (at ``+-half``) and the other
    obstacles, and ``clear`` from ``start`` and ``goal``; radii are uniform in ``obstacle_radius``.

    Random sequential placement: candidates are tested in the order drawn, each accepted when it
    keeps its distances to the walls, start, goal and the obstacles accepted so far. Candidates
    come in chunks; accepting one drops every later candidate of its chunk that is too close to
    it in one vectorised step, so the next survivor is the next accepted obstacle (the same
    result as testing them one by one, with a few numpy calls per obstacle, not per candidate).
    """
    if n == 0:
        return np.zeros((0, 3))
    r_lo, r_hi = obstacle_radius
    bound = half - gap

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
        accepted: list[np.ndarray] = []
        while len(pool) and len(placed) + len(accepted) < n:
            first = pool[0]
            accepted.append(first)
            rest = pool[1:]
            pool = rest[np.hypot(rest[:, 0] - first[0], rest[:, 1] - first[1]) - rest[:, 2] - first[2] >= gap]
        if accepted:
            placed = np.concatenate([placed, np.array(accepted)])
    return placed if len(placed) == n else None
