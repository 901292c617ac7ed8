"""The report's figures (PNG, matplotlib's Agg canvas: no display needed).

* :func:`plot_figure` — the paper's Fig. 1/2 layout: one row per env, one column per metric (reward,
  Fréchet distance, action MSE) against the epoch; each trial's curve smoothed with a Gaussian filter
  (sigma 2 evaluations, ``scipy.ndimage.gaussian_filter1d``, as the paper), then the mean over trials
  with a ±1 std band. BC, evaluated once, is a horizontal line (mean over trials, ±1 std band).
* :func:`plot_final` — the final evaluation's return per env and method: each trial's point, the mean
  over trials with its bootstrap CI, BC's mean and the expert's as horizontal lines, and under each
  method in how many trials it beat BC: whether CMZ-DRIL beats BC, at a glance.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cmzdril_lab.report.final_eval import (
    CONFIDENCE,
    FinalRow,
    baselines,
    expert_by_env,
    find,
    paired,
    trials_text,
)
from cmzdril_lab.report.records import (
    METHOD_LABELS,
    METHOD_ORDER,
    RunRecord,
    env_key,
    group,
    result_policy,
)
from cmzdril_lab.report.tables import METRICS
from sb3_cmzdril.io import PathLike, atomic_path

#: The paper's figures: which methods each compares.
FIGURES: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("fig1_bc_dril_cmz.png", "Fig. 1: CMZ-DRIL, BC and DRIL", ("bc", "dril", "cmz")),
    ("fig2_cmz_env_zero.png", "Fig. 2: CMZ-DRIL, env. reward and no reward", ("cmz", "env", "zero")),
)
#: The final-evaluation figure of the main grid (and of a reference grid that has final evaluations).
FINAL_FIGURE = "fig3_final_eval.png"
FINAL_FIGURE_REFERENCE = "fig3_final_eval_reference.png"
SMOOTHING_SIGMA = 2.0
COLORS = {"bc": "tab:gray", "dril": "tab:orange", "cmz": "tab:blue", "zero": "tab:red", "env": "tab:green",
          "cmz-sac": "tab:purple", "dril-sac": "tab:brown", "zero-sac": "tab:pink", "env-sac": "tab:olive"}


def new_figure(width: float, height: float):
    """A matplotlib Figure on the Agg canvas (no display, no pyplot state), constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig, path: PathLike) -> Path:
    """Write ``fig`` to ``path`` as PNG, atomically."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path


def smoothed_band(runs: Sequence[RunRecord], column: str, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(epochs, mean, std) over trials of each trial's smoothed curve; epochs not reached by every
    trial use the trials that reached them (an unfinished trial shortens nothing)."""
    from scipy.ndimage import gaussian_filter1d

    epochs = np.unique(np.concatenate([r.columns["epoch"] for r in runs]))
    grid = np.full((len(runs), len(epochs)), np.nan)
    for i, r in enumerate(runs):
        values = r.columns[column]
        smooth = gaussian_filter1d(values, sigma, mode="nearest") if sigma > 0 and len(values) > 1 else values
        grid[i, np.searchsorted(epochs, r.columns["epoch"])] = smooth
    return epochs, np.nanmean(grid, axis=0), np.nanstd(grid, axis=0)  # every column has a trial


def plot_figure(
    records: Sequence[RunRecord],
    methods: Sequence[str],
    path: PathLike,
    title: str = "",
    sigma: float = SMOOTHING_SIGMA,
) -> Path | None:
    """The paper's Fig. 1/2 layout for ``methods``; None (nothing written) when none of them ran."""
    groups = group(r for r in records if r.method in methods)
    if not groups:
        return None
    envs = sorted({env for env, _ in groups}, key=env_key)
    fig = new_figure(13, 3.2 * len(envs) + 0.8)
    axes = fig.subplots(len(envs), len(METRICS), squeeze=False)
    for row, env in enumerate(envs):
        xmax = max((r.columns["epoch"][-1] for (e, m), runs in groups.items() if e == env and m != "bc" for r in runs),
                   default=1)
        for col, (_, label, column) in enumerate(METRICS):
            ax = axes[row, col]
            for method in methods:
                runs = groups.get((env, method))
                if not runs:
                    continue
                name = f"{METHOD_LABELS[method]} (n={len(runs)})"
                color = COLORS[method]
                if method == "bc":
                    # BC is evaluated once (epoch 0): a horizontal line over the training epochs.
                    values = np.array([r.columns[column][0] for r in runs])
                    mean, std = float(values.mean()), float(values.std())
                    ax.axhline(mean, color=color, linestyle="--", label=name)
                    ax.axhspan(mean - std, mean + std, color=color, alpha=0.12, linewidth=0)
                    continue
                epochs, band_mean, band_std = smoothed_band(runs, column, sigma)
                ax.plot(epochs, band_mean, color=color, label=name)
                ax.fill_between(epochs, band_mean - band_std, band_mean + band_std, color=color, alpha=0.2, linewidth=0)
            ax.set_xlim(0, max(1, xmax))
            ax.set_xlabel("epoch (PPO update)")
            ax.set_title(f"{env}: {label}", fontsize=10)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.legend(fontsize=8, loc="best")
    fig.suptitle(
        (title + "\n" if title else "")
        + f"mean over trials, band ±1 std; curves Gaussian-smoothed (sigma {sigma:g} evaluations)",
        fontsize=11,
    )
    return save_png(fig, path)


#: Horizontal offset of the final policy's, the reward-free choice's and the averaged policy's points
#: around a method's tick (a method has one kind of choice: lowest u for CMZDRIL, longest episodes for
#: CMZDRILSAC).
_POLICY_OFFSET = {"final": -0.17, "lowest_u": 0.17, "longest": 0.17, "averaged": 0.0}


def _tick_label(rows: Sequence[FinalRow], env: str, method: str) -> str:
    """The method's name and, for RL methods, in how many trials each policy (final | its reward-free
    choice) beat BC."""
    wins = []
    for policy in _POLICY_OFFSET:
        row = find(rows, env, method, policy)
        comparison = paired(row, baselines(rows, row)[0]) if row is not None else None
        if comparison is not None and comparison.trials:
            wins.append(f"{comparison.wins}/{len(comparison.trials)}")
    # Two-word names on two lines: six methods side by side stay legible at page width.
    name = METHOD_LABELS[method].replace(" (", "\n(").replace(". ", ".\n").replace("No reward", "No\nreward")
    return "\n".join([name, *([" | ".join(wins)] if wins else [])])


#: The final evaluation's figure: panels per row (a page's width holds two legibly), inches per panel,
#: and font sizes in points (the figure is read scaled down to a page's width).
FINAL_COLUMNS = 2
FINAL_PANEL = (5.6, 4.4)
FINAL_FONTS = {"tick": 10, "title": 13, "label": 11, "legend": 10.5, "suptitle": 13}


def _plot_env(ax, rows: Sequence[FinalRow], env: str) -> None:
    methods = [m for m in METHOD_ORDER if any(find(rows, env, m, policy) is not None for policy in _POLICY_OFFSET)]
    for x, method in enumerate(methods):
        for policy, offset in _POLICY_OFFSET.items():
            row = find(rows, env, method, policy)
            if row is None:
                continue
            values = row.per_run("return")
            # Trials side by side (not random jitter): the figure is the same on every report.
            spread = np.linspace(-0.06, 0.06, len(values)) if len(values) > 1 else np.zeros(1)
            face = COLORS[method] if policy == result_policy(method) else "none"
            ax.scatter(x + offset + spread, values, s=30, facecolors=face, edgecolors=COLORS[method], zorder=3)
            mean, low, high = row.stat("return")
            if np.isfinite(low):
                ax.errorbar(x + offset, mean, yerr=[[mean - low], [high - mean]], color="black", capsize=5,
                            linewidth=1.4, zorder=4)
            ax.plot([x + offset - 0.12, x + offset + 0.12], [mean, mean], color="black", linewidth=2.2, zorder=4)
    bc = find(rows, env, "bc")
    if bc is not None:
        ax.axhline(bc.stat("return")[0], color=COLORS["bc"], linestyle="--", linewidth=1.2)
    ax.axhline(expert_by_env(rows)[env][0], color="black", linestyle=":", linewidth=1.2)
    ax.set_xticks(range(len(methods)), [_tick_label(rows, env, m) for m in methods], fontsize=FINAL_FONTS["tick"])
    ax.tick_params(axis="y", labelsize=FINAL_FONTS["tick"])
    ax.set_xlim(-0.6, len(methods) - 0.4)
    ax.set_title(f"{env} ({trials_text([r for r in rows if r.env == env])} trials)", fontsize=FINAL_FONTS["title"])
    ax.set_ylabel("return", fontsize=FINAL_FONTS["label"])
    ax.grid(axis="y", alpha=0.3)


def plot_final(rows: Sequence[FinalRow], path: PathLike, title: str = "") -> Path | None:
    """The final evaluation's returns, one panel per env, :data:`FINAL_COLUMNS` panels a row (the legend
    in the last row's empty panel, or under the panels); None (nothing written) without rows."""
    if not rows:
        return None
    from matplotlib.lines import Line2D

    envs = sorted({r.env for r in rows}, key=env_key)
    columns = min(FINAL_COLUMNS, len(envs))
    panels = -(-len(envs) // columns)
    spare = panels * columns > len(envs)  # an empty panel holds the legend
    width, height = FINAL_PANEL
    fig = new_figure(max(width * columns, 9.0), height * (panels + (0 if spare else 0.6)) + 1.0)
    axes = fig.subplots(panels, columns, squeeze=False).ravel()
    for ax, env in zip(axes, envs, strict=False):
        _plot_env(ax, rows, env)
    handles = [
        Line2D([], [], marker="o", linestyle="", color="tab:gray",
               label="the method's result (last weights;\nCMZ-DRIL (SAC): longest episodes), a point per trial"),
        Line2D([], [], marker="o", linestyle="", markerfacecolor="none", color="tab:gray",
               label="its other policy (CMZ-DRIL: lowest u;\nCMZ-DRIL (SAC): last weights), a point per trial"),
        Line2D([], [], color="black", marker="_", markersize=12,
               label=f"mean over trials, bar: {100 * CONFIDENCE:g}% bootstrap CI"),
        Line2D([], [], color=COLORS["bc"], linestyle="--", label="BC mean"),
        Line2D([], [], color="black", linestyle=":", label="expert on the same episodes"),
        Line2D([], [], linestyle="", label="under each method: trials above BC,\nlast weights | reward-free choice"),
    ]
    if spare:
        for ax in axes[len(envs):]:
            ax.axis("off")
        axes[len(envs)].legend(handles=handles, loc="center", fontsize=FINAL_FONTS["legend"], frameon=False)
    else:
        fig.legend(handles=handles, loc="outside lower center", ncols=2, fontsize=FINAL_FONTS["legend"])
    fig.suptitle((title + "\n" if title else "") + "each trial's return averaged over its held-out pool episodes "
                 "(final_eval.csv)", fontsize=FINAL_FONTS["suptitle"])
    return save_png(fig, path)


__all__ = [
    "COLORS",
    "FIGURES",
    "FINAL_FIGURE",
    "FINAL_FIGURE_REFERENCE",
    "SMOOTHING_SIGMA",
    "new_figure",
    "plot_figure",
    "plot_final",
    "save_png",
    "smoothed_band",
]
