"""The WaypointNav lidar: ray casting against circular obstacles and the square arena's walls.

Pure geometry with preallocated buffers: :meth:`Lidar.sense` runs once per env step, so it makes
no arrays of its own (every numpy call writes into a buffer made by the constructor or by
:meth:`Lidar.set_obstacles`). Everything is in units of the lidar range, so the column-wise minimum
over obstacles, walls and the range limit is the observation's lidar block as it is.
"""
from __future__ import annotations

import numpy as np


class Lidar:
    """``n_beams`` rays, evenly spaced over 360 degrees, from the vehicle in a square arena of half
    side ``half`` (metres) with the arena centred on the origin.

    Beam ``j`` points at body angle ``2*pi*j/n_beams`` (counter-clockwise, beam 0 straight ahead).
    After :meth:`sense`, :attr:`ranges` holds distance / ``lidar_range`` for each beam, 1 where
    nothing is in range, and :attr:`directions` the beams' (2, n_beams) world-frame unit vectors.
    From inside an obstacle or beyond a wall a beam can meet a surface behind the sensor: its
    range is then negative (the env clamps it on the terminal step).

    :param n_beams: number of beams (>= 1).
    :param lidar_range: maximum range in metres (> 0).
    :param half: half the arena's side in metres.
    """

    def __init__(self, n_beams: int, lidar_range: float, half: float) -> None:
        n = n_beams
        angles = 2.0 * np.pi * np.arange(n) / n
        angles[angles > np.pi] -= 2.0 * np.pi
        self._beam_angles = angles
        self._beam_angles_s = angles - 0.5 * np.pi
        self.n_beams = n
        self.ranges = np.empty(n)
        self.directions = np.empty((2, n))
        self._angle = np.empty(n)
        self._pos = np.zeros(2)
        self._pos_col = self._pos[:, None]
        self._inv = np.empty((2, n))
        self._tmp2 = np.empty((2, n))
        self.lidar_range = lidar_range
        self._inv_range = 1.0 / lidar_range
        self._half_n = half / lidar_range
        self.set_obstacles(np.zeros((0, 2)), np.zeros(0), 0.0)

    @property
    def beam_angles(self) -> np.ndarray:
        """(n_beams,) body-frame beam angles in radians, wrapped into (-pi, pi] (a copy)."""
        return self._beam_angles.copy()

    def set_obstacles(self, centres: np.ndarray, radii: np.ndarray, vehicle_radius: float) -> None:
        """Sense these obstacle discs from now on: (K, 2) centres and (K,) radii in metres;
        :meth:`sense` reports contact where the vehicle disc of ``vehicle_radius`` overlaps one."""
        k, n = len(radii), self.n_beams
        self._n_obst = k
        scale = self._inv_range
        self._centres = np.array(centres, dtype=np.float64).reshape(k, 2) * scale
        self._r2 = (radii * scale) ** 2
        self._contact_dist = (radii + vehicle_radius) * scale
        # Rows of the table are the obstacles, then the two wall axes, then a constant row of 1 (the
        # range limit): one column-wise minimum gives the clipped ranges. (Rows-by-beams rather than
        # beams-by-rows because numpy reduces over the leading axis of a small array several times
        # faster.)
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

    def sense(self, x: float, y: float, heading: float) -> bool:
        """Cast every beam from (``x``, ``y``) at ``heading`` into :attr:`ranges`; returns whether the
        vehicle disc touches an obstacle (walls are the caller's: it knows the vehicle's bounds).

        All beams against all obstacles and the walls at once, in units of the lidar range.
        """
        pos = self._pos
        pos[0] = x * self._inv_range
        pos[1] = y * self._inv_range
        u = self.directions                                # (2, J) world-frame beam directions
        # sin(a) is taken as cos(a - pi/2): the cosine of a float is never exactly 0 (no float is an
        # odd multiple of pi/2), whereas sin(0.0) is, and 1/u below must stay finite.
        np.cos(np.add(self._beam_angles, heading, out=self._angle), out=u[0])
        np.cos(np.add(self._beam_angles_s, heading, out=self._angle), out=u[1])
        # Walls: along an axis the wall ahead is at (half - p*sign(u)) / |u| = half*|1/u| - p/u.
        inv = np.divide(1.0, u, out=self._inv)
        walls = np.abs(inv, out=self._walls)
        walls *= self._half_n
        walls -= np.multiply(inv, self._pos_col, out=self._tmp2)
        contact = False
        if self._n_obst:
            w = np.subtract(self._centres, pos, out=self._w)   # (K, 2) vehicle -> centre
            dist = np.hypot(self._wx, self._wy, out=self._dist_k)
            contact = bool(np.count_nonzero(np.less(dist, self._contact_dist, out=self._contact)))
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
        np.minimum.reduce(self._table, axis=0, out=self.ranges)
        return contact

    def hit_points(self, x: float, y: float) -> np.ndarray:
        """(M, 2) world points, in metres, where the beams of the last :meth:`sense`, cast from
        (``x``, ``y``), met something within range (for drawing)."""
        hits = self.ranges < 1.0
        return np.array([x, y]) + self.lidar_range * self.ranges[hits, None] * self.directions.T[hits]
