"""Top-view ``rgb_array`` frames of WaypointNav, drawn with plain numpy.

Plain numpy keeps rendering free of display back-ends and of matplotlib (an extra; its pictures for
docs and reports are in :mod:`sb3_cmzdril.envs.plotting`). The static part of a frame (obstacles,
goal, start, walls) depends only on the field, so :func:`draw_background` is drawn once per field
and :func:`draw_frame` copies it and adds the path, lidar hits and vehicle.
"""
from __future__ import annotations

import math

import numpy as np

from sb3_cmzdril.envs.waypoint_field import WaypointField

#: Render size in pixels (square).
RENDER_SIZE = 400

_OBSTACLE = (110, 110, 110)
_GOAL = (40, 170, 60)
_PATH = (40, 80, 220)           # the start ring too: the path begins there
_LIDAR_HIT = (255, 140, 0)
_VEHICLE = (220, 30, 30)
_HEADING = (120, 0, 0)


def _grid(arena_size: float) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(pixels per metre, half side, xs (1, W), ys (H, 1)): the world coordinates of pixel centres."""
    size = RENDER_SIZE
    half = 0.5 * arena_size
    scale = size / arena_size
    coords = (np.arange(size) + 0.5) / scale - half
    return scale, half, coords[None, :], coords[::-1, None]   # image row 0 is the top (+y)


def draw_background(field: WaypointField, arena_size: float, goal_radius: float) -> np.ndarray:
    """(H, W, 3) uint8 picture of the scene alone: obstacles grey, goal green, start ring blue, walls black."""
    size = RENDER_SIZE
    _, _, xs, ys = _grid(arena_size)
    img = np.full((size, size, 3), 255, dtype=np.uint8)
    for (cx, cy), r in zip(field.centres, field.radii, strict=True):
        img[(xs - cx) ** 2 + (ys - cy) ** 2 <= r * r] = _OBSTACLE
    gx, gy = field.goal
    img[(xs - gx) ** 2 + (ys - gy) ** 2 <= goal_radius ** 2] = _GOAL
    sx, sy = field.start
    ring = (xs - sx) ** 2 + (ys - sy) ** 2
    img[(ring <= 0.3 ** 2) & (ring >= 0.18 ** 2)] = _PATH
    img[[0, -1], :] = 0
    img[:, [0, -1]] = 0
    return img


def draw_frame(
    background: np.ndarray,
    arena_size: float,
    trail: np.ndarray,
    pose: tuple[float, float, float],
    vehicle_radius: float,
    hit_points: np.ndarray,
) -> np.ndarray:
    """A new (H, W, 3) uint8 frame: ``background`` (left unchanged) with the path ``trail`` ((T + 1, 2)
    metres) in blue, the lidar ``hit_points`` ((M, 2) metres) in orange and the vehicle at ``pose``
    (x, y, heading) in red with a dark line for its heading."""
    size = RENDER_SIZE
    scale, half, xs, ys = _grid(arena_size)
    img = background.copy()

    def pixel(px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        col = np.clip(((px + half) * scale).astype(int), 0, size - 1)
        row = np.clip(((half - py) * scale).astype(int), 0, size - 1)
        return row, col

    if len(trail) > 1:
        # Dense samples along each segment give a continuous line without a drawing library.
        s = np.linspace(0.0, 1.0, 8)[:, None, None]
        pts = (trail[:-1][None] * (1 - s) + trail[1:][None] * s).reshape(-1, 2)
        img[pixel(pts[:, 0], pts[:, 1])] = _PATH
    if len(hit_points):
        r, c = pixel(hit_points[:, 0], hit_points[:, 1])
        # A 3 x 3 dot per hit: one pixel is hard to see.
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                img[np.clip(r + dr, 0, size - 1), np.clip(c + dc, 0, size - 1)] = _LIDAR_HIT
    x, y, heading = pose
    img[(xs - x) ** 2 + (ys - y) ** 2 <= vehicle_radius ** 2] = _VEHICLE
    s = np.linspace(0.0, 2.5 * vehicle_radius, 20)
    img[pixel(x + s * math.cos(heading), y + s * math.sin(heading))] = _HEADING
    return img
