"""Matplotlib pictures of WaypointNav fields and paths (for docs and reports)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sb3_cmzdril.envs.waypoint import WaypointField, WaypointNavEnv


def _field_of(env_or_field: Any) -> WaypointField:
    if isinstance(env_or_field, WaypointField):
        return env_or_field
    base = getattr(env_or_field, "unwrapped", None)
    if isinstance(base, WaypointNavEnv):
        return base.field
    raise ValueError(f"expected a WaypointNav env or a WaypointField, got {type(env_or_field).__name__}")


def plot_trajectories(
    env_or_field: WaypointNavEnv | WaypointField | Any,
    trajectories: Mapping[str, np.ndarray] | None = None,
    ax: Any | None = None,
    title: str | None = None,
    normalised: bool = False,
    colors: Sequence[str] | None = None,
    legend: bool = True,
) -> Any:
    """Draw the obstacle field, start, goal and paths; returns the matplotlib Axes.

    :param env_or_field: a WaypointNav env (wrapped or not; its current ``field`` is drawn) or a
        :class:`~sb3_cmzdril.envs.waypoint.WaypointField`.
    :param trajectories: label -> (T, 2) xy path, e.g. ``{"expert": P, "agent": Q}``.
    :param ax: Axes to draw on (a new figure when ``None``).
    :param normalised: the paths are ``obs[:, -2:]`` (divided by the arena half-size) rather than
        metres; they are scaled back.
    :param colors: one matplotlib colour per path (defaults to the colour cycle).
    :param legend: add a legend when there are labelled paths.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    f = _field_of(env_or_field)
    if f.arena_size is None:
        raise ValueError("the field has no arena_size; take it from env.unwrapped.field")
    half = 0.5 * float(f.arena_size)
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 5))
    ax.add_patch(Rectangle((-half, -half), 2 * half, 2 * half, fill=False, lw=1.5, color="black"))
    for (cx, cy), r in zip(np.asarray(f.centres).reshape(-1, 2), np.asarray(f.radii), strict=True):
        ax.add_patch(Circle((cx, cy), r, color="0.45", zorder=1))
    ax.add_patch(Circle(tuple(f.goal), WaypointNavEnv.goal_radius, color="tab:green", alpha=0.8, zorder=2))
    ax.plot(*f.start, marker="o", ms=7, mfc="white", mec="tab:blue", mew=2, zorder=4, ls="none", label="start")
    ax.plot(*f.goal, marker="*", ms=12, color="darkgreen", zorder=4, ls="none", label="goal")
    for i, (label, path) in enumerate((trajectories or {}).items()):
        xy = np.asarray(path, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"trajectory {label!r} must have shape (T, 2), got {xy.shape}")
        if normalised:
            xy = xy * half
        kw: dict[str, Any] = {"color": colors[i]} if colors is not None and i < len(colors) else {}
        ax.plot(xy[:, 0], xy[:, 1], lw=2, zorder=3, label=label, **kw)
    ax.set_xlim(-half, half)
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title, fontsize=9)
    if legend and trajectories:
        ax.legend(loc="upper right", fontsize=7)
    return ax
