"""Studies beside the main grid: variants of a setting (ablations) and sweeps of one setting across
runs folders, compared trial by trial, and what the agent does in training (rollout quantities).

A study page (docs/new_tasks.md) is written by a script under ``benchmarks/studies/`` that names its
runs folders (:class:`Variant`, :class:`Sweep`, :class:`RolloutTable`) and hands them to
:func:`render`. Variants of an env share trials: trial t has the same seed, demo split and held-out
episodes in every folder, so two variants are compared on the trials both have. Per variant: the
final policy's % of the expert's return on the held-out episodes (mean over trials [bootstrap CI],
and trial by trial), the lowest-u policy's, the Table I window's return, the CPU minutes a run took
(where its records kept them), and in how many shared
trials the final policy beats the env's reference variant (the first listed). The numbers come from
the runs' final_eval.csv and done.json (:mod:`.final_eval`, :mod:`.records`); the hand-written reading,
``docs/new_tasks_discussion.md``, is linked when it exists. :class:`AcrossTasks` compares
learners over several tasks at once, with the report's rliable aggregates (:mod:`.aggregate`), so
a learner outside the grid (the off-policy one) meets the grid's methods on one scale.
"""
from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from cmzdril_lab.records_store import materialize_all
from cmzdril_lab.report.aggregate import (
    LeftOut,
    Scores,
    aggregate,
    aggregate_markdown,
    normalised_score,
    plot_aggregate,
)
from cmzdril_lab.report.figures import COLORS, SMOOTHING_SIGMA, new_figure, save_png, smoothed_band
from cmzdril_lab.report.final_eval import FinalRow, expert_by_env, final_table, find, mean_ci
from cmzdril_lab.report.formatting import fmt, fmt_ci, md_table
from cmzdril_lab.report.records import (
    METHOD_LABELS,
    METHOD_ORDER,
    POLICIES,
    RunRecord,
    Skipped,
    load_runs,
    progress_rows,
    relative,
    result_policy,
)

#: the published grid: the BC and DRIL runs every ablation is paired with
GRID = "results/runs"


@dataclasses.dataclass(frozen=True)
class Variant:
    """One configuration of one env and method, and where its runs are."""

    env: str
    method: str
    label: str
    runs: str  #: runs folder, relative to the repository
    made_by: str  #: the command (and commit) that made the runs
    #: only these trials of the folder (None: all), so tuning trials and confirmation trials get a row each
    trials: tuple[int, ...] | None = None
    #: the policy an ablation row shows as its final one ("averaged": the same runs' averaged policy)
    policy: str = "final"
    #: more trials of the env's reference (its first variant), e.g. the confirmation trials 5-9: every
    #: other row of the env is paired with the reference's runs on the trials it has, these included
    extends_reference: bool = False



@dataclasses.dataclass(frozen=True)
class RolloutTable:
    """One training-rollout quantity compared by method, first epochs against last, in some envs."""

    key: str  #: SB3 logger key in each run's logs/progress_0.csv
    title: str
    envs: tuple[str, ...]
    runs: str = "results/runs"
    final_column: str | None = None  #: final_eval.csv column for the final policy's value, if any



@dataclasses.dataclass(frozen=True)
class Sweep:
    """Runs of one env in several folders that differ in one setting of their config.json."""

    env: str
    methods: tuple[str, ...]
    setting: str  #: the config.json key that varies between the folders
    title: str  #: what the setting is, for headers and axes
    folders: tuple[str, ...]  #: runs folders, relative to the repository
    figure: str  #: file name of the figure under docs/figures
    made_by: str  #: the commands that made the runs
    fixed: str = ""  #: what the folders share that is not the package defaults, for the heading



@dataclasses.dataclass(frozen=True)
class CostCurves:
    """Variants of one env whose evaluations are drawn against the CPU time their runs spent, so
    learners of different cost per step (PPO with several envs, SAC) meet on one axis."""

    env: str
    title: str
    figure: str  #: file name of the figure under docs/figures
    variants: tuple[Variant, ...]


@dataclasses.dataclass(frozen=True)
class AcrossTasks:
    """Methods compared across tasks with rliable's aggregates (:mod:`.aggregate`) on the same trials:
    each method is a key, its label and one variant (runs folder) per task."""

    title: str
    trials: tuple[int, ...]
    methods: tuple[tuple[str, str, tuple[Variant, ...]], ...]
    pairs: tuple[tuple[str, str], ...]  #: (method, baseline) keys for the probability of improvement
    figure: str  #: file name of the figure under docs/figures
    intro: str = ""  #: what the comparison is for, before its tables


#: points of the common CPU-time axis the runs' curves are interpolated onto
COST_GRID_POINTS = 60


#: Epochs (PPO rollouts) averaged at each end of training.
EDGE_EPOCHS = 10


def rollout_edges(run: Path, key: str) -> tuple[float, float]:
    """Mean of a logged rollout quantity over the first and the last :data:`EDGE_EPOCHS` epochs of a
    run (every segment of a resumed one); NaN when its progress log has none."""
    values = [float(r[key]) for r in progress_rows(run) if r.get(key)]
    if not values:
        return math.nan, math.nan
    first, last = values[:EDGE_EPOCHS], values[-EDGE_EPOCHS:]
    return sum(first) / len(first), sum(last) / len(last)


def rollout_markdown(root: Path, skipped: list[Skipped], tables: tuple[RolloutTable, ...] = ()) -> str:
    """Per table and env, per method: the quantity in the first and last training epochs (and the final
    policy's, where the table has a final_eval.csv column), mean over trials [CI]."""
    parts = []
    for table in tables:
        folder = root / table.runs
        if not folder.is_dir():
            skipped.append(Skipped(folder, "no such runs folder"))
            continue
        rows = final_table(load_runs(folder, skipped))
        for env in table.envs:
            body = []
            for row in rows:
                if row.env != env or row.policy != "final":
                    continue
                edges = [rollout_edges(r.path, table.key) for r in row.runs]
                cells = [
                    "—" if all(math.isnan(e[i]) for e in edges) else fmt_ci(*mean_ci([e[i] for e in edges]))
                    for i in (0, 1)
                ]
                if table.final_column:
                    cells.append(fmt_ci(*row.stat(table.final_column)))
                elif cells == ["—", "—"]:
                    continue  # BC: no training rollouts, and nothing else in this table
                body.append([METHOD_LABELS[row.method], str(row.n_trials), *cells])
            if not body:
                continue
            header = ["Method", "Trials", f"Training rollouts, first {EDGE_EPOCHS} epochs",
                      f"Training rollouts, last {EDGE_EPOCHS} epochs"]
            if table.final_column:
                header.append("Final policy, held-out episodes")
            parts.append(f"### {env}: {table.title} (`{table.runs}`)\n\n" + md_table(header, body))
    return "\n\n".join(parts)


def variant_rows(variant: Variant, root: Path, skipped: list[Skipped],
                 loaded: dict[Path, list[FinalRow]] | None = None) -> dict[str, FinalRow | None]:
    """The variant's final row and its reward-free choice's, lowest u or longest episodes (None where
    its folder has no such finished runs); ``loaded`` keeps each folder's rows for the next variant of
    the same folder."""
    folder = root / variant.runs
    if not folder.is_dir():
        skipped.append(Skipped(folder, "no such runs folder"))
        return dict.fromkeys(POLICIES)
    rows = None if loaded is None else loaded.get(folder)
    if rows is None:
        rows = final_table(load_runs(folder, skipped))
        if loaded is not None:
            loaded[folder] = rows
    found = {policy: find(rows, variant.env, variant.method, policy) for policy in POLICIES}
    if variant.trials is None:
        return found
    kept = {policy: None if row is None else dataclasses.replace(
        row, runs=[r for r in row.runs if r.trial in variant.trials]) for policy, row in found.items()}
    return {policy: row if row is not None and row.runs else None for policy, row in kept.items()}


def window_return(row: FinalRow) -> float:
    """Mean over the row's runs of done.json's Table I window return."""
    values = [r.summary.get("final_window", {}).get("return", math.nan) for r in row.runs]
    return mean_ci(values)[0]


def cpu_and_steps(run: RunRecord) -> tuple[float, float] | None:
    """done.json's ``cpu_time_s`` and ``num_timesteps`` (both positive), None where either is
    missing (runs made before the records kept CPU time)."""
    cpu, steps = run.summary.get("cpu_time_s"), run.summary.get("num_timesteps")
    if not isinstance(cpu, (int, float)) or not isinstance(steps, (int, float)) or cpu <= 0 or steps <= 0:
        return None
    return float(cpu), float(steps)


def cpu_minutes(row: FinalRow) -> str:
    """Median CPU minutes per run (done.json's ``cpu_time_s``: pretraining, training and evaluations),
    "—" where no run recorded it (runs made before the records kept CPU time), naming the CPU models
    when the runs recorded more than one (done.json's ``cpus``)."""
    values = [r.summary["cpu_time_s"] for r in row.runs if isinstance(r.summary.get("cpu_time_s"), (int, float))]
    if not values:
        return "—"
    note = "" if len(values) == len(row.runs) else f" ({len(values)} of {len(row.runs)} runs)"
    cpus = sorted({str(cpu) for r in row.runs for cpu in r.summary.get("cpus", [])})
    if len(cpus) > 1:  # CPU seconds of different processors do not compare
        note += f" (on {len(cpus)} CPU models: {', '.join(cpus)})"
    return f"{np.median(values) / 60:.1f}{note}"


def above_reference(row: FinalRow, reference: FinalRow) -> str:
    """"k of n": in how many trials both have, the row's final return is above the reference's."""
    mine, theirs = row.per_trial("return"), reference.per_trial("return")
    shared = sorted(set(mine) & set(theirs))
    return f"{sum(mine[t] > theirs[t] for t in shared)} of {len(shared)}"


def paired_cell(row: FinalRow, reference: FinalRow | None, is_reference: bool) -> str:
    """A variant's paired count against its env's reference: "reference" for the reference's own rows."""
    if is_reference:
        return "reference"
    return "no reference runs" if reference is None else above_reference(row, reference)


def merged_row(env: str, method: str, parts: list[FinalRow | None]) -> FinalRow | None:
    """The runs of ``parts`` as one final row, merged by trial: a trial comes from the first part that has it."""
    runs: dict[int, RunRecord] = {}
    for part in parts:
        for run in [] if part is None else part.runs:
            runs.setdefault(run.trial, run)
    return FinalRow(env, method, "final", [runs[t] for t in sorted(runs)]) if runs else None


def chosen_against(chosen: FinalRow, baselines: dict[str, FinalRow | None]) -> str:
    """" (above BC k of n, DRIL k of n)": the reward-free choice's paired counts, which the targets ask of
    a method whose result is that choice (`cmz-sac`'s longest-episodes policy); "" without baselines."""
    counts = [f"{METHOD_LABELS[m]} {above_reference(chosen, b)}" for m, b in baselines.items()
              if b is not None and m != chosen.method]
    return f" (above {', '.join(counts)})" if counts else ""


def baseline_row(env: str, method: str, folders: tuple[str, ...], root: Path) -> FinalRow | None:
    """The final rows of ``method`` in ``folders``, merged by trial: a trial comes from the first
    folder that has it (the published grid first; later folders add trials it lacks)."""
    return merged_row(env, method, [variant_rows(Variant(env, method, method, folder, ""), root, [])["final"]
                                    for folder in folders])


def ablation_markdown(
    root: Path, skipped: list[Skipped], ablations: tuple[Variant, ...] = (), grid: tuple[str, ...] = (GRID,)
) -> str:
    """One table per env: each variant's numbers, its paired count against the env's first variant
    and against BC and DRIL of the published grid (``grid``: its folder first, then folders adding
    trials it lacks): the issue's targets are paired ones."""
    parts = []
    where = " + ".join(f"`{folder}`" for folder in grid)
    for env in dict.fromkeys(v.env for v in ablations):
        variants = [v for v in ablations if v.env == env]
        rows = [variant_rows(v, root, skipped) for v in variants]
        is_reference = [i == 0 or v.extends_reference for i, v in enumerate(variants)]
        # The reference: the first variant's runs, with the trials of the variants that extend it.
        reference = merged_row(env, variants[0].method, [row[v.policy] for v, row, ref
                                                         in zip(variants, rows, is_reference, strict=True) if ref])
        baselines = {m: baseline_row(env, m, grid, root) for m in ("bc", "dril")}
        body = []
        for variant, row, own in zip(variants, rows, is_reference, strict=True):
            final, lowest = row[variant.policy], row["lowest_u"] or row["longest"]
            if final is None:
                body.append([variant.label, "0", "no finished runs"] + [""] * 8)
                continue
            against = ["—" if m == variant.method or b is None else above_reference(final, b)
                       for m, b in baselines.items()]
            per_trial = ", ".join(f"{t}: {fmt(v)}" for t, v in sorted(final.per_trial("return").items()))
            body.append([
                variant.label,
                str(final.n_trials),
                fmt_ci(*final.stat("pct_of_expert")),
                fmt_ci(*final.stat("return")),
                per_trial,
                "—" if lowest is None else fmt_ci(*lowest.stat("pct_of_expert")) + chosen_against(lowest, baselines),
                fmt(window_return(final)),
                cpu_minutes(final),
                paired_cell(final, reference, own),
                *against,
            ])
        parts.append(f"### {env}, {METHOD_LABELS[variants[0].method]}\n\n" + md_table(
            ["Variant", "Trials", "Final policy: % of expert [95% CI]", "Final policy: return [95% CI]",
             "Final policy: return by trial",
             "Lowest-u (or longest-episodes) policy: % of expert (above BC, DRIL: trials)", "Table I window return",
             "CPU minutes per run (median)",
             "Final above the reference (trials)",
             f"Final above BC of {where} (trials)", f"Final above DRIL of {where} (trials)"],
            body,
        ))
        parts.append(runs_sentence(variant_groups(variants)))
    return "\n\n".join(parts)


def trial_span(trials: tuple[int, ...] | None) -> str:
    """e.g. "trials 0-4" or "trials 1, 3"; "" for every trial of a folder."""
    if not trials:
        return ""
    ordered = sorted(trials)
    if ordered == list(range(ordered[0], ordered[-1] + 1)) and len(ordered) > 1:
        return f"trials {ordered[0]}-{ordered[-1]}"
    return "trials " + ", ".join(map(str, ordered))


def variant_groups(variants: Sequence[Variant]) -> dict[tuple[str, str], list[str]]:
    """(folder, command) -> each method it holds, with its trials ("CMZ-DRIL: trials 0-4, 5-9"), so a
    command shared by several rows is written once."""
    by_method: dict[tuple[str, str], dict[str, dict[str, None]]] = {}
    for v in variants:
        spans = by_method.setdefault((v.runs, v.made_by), {}).setdefault(METHOD_LABELS[v.method], {})
        spans[trial_span(v.trials).removeprefix("trials ")] = None
    return {key: [method + (f": trials {', '.join(s for s in spans if s)}" if any(spans) else "")
                  for method, spans in methods.items()]
            for key, methods in by_method.items()}


def runs_sentence(groups: dict[tuple[str, str], list[str]]) -> str:
    """"Runs: `folder` (what it holds), made by `command`; ..." with each folder and command once."""
    return "Runs: " + "; ".join(f"`{folder}` ({'; '.join(what)})" + (f", made by `{made_by}`" if made_by else "")
                                for (folder, made_by), what in groups.items()) + "."


def sweep_rows(sweep: Sweep, root: Path, skipped: list[Skipped]) -> dict[tuple[str, int], FinalRow]:
    """The final policy's row per (method, value of the swept setting), over all the sweep's folders.

    The value comes from each run's config.json, not from the folder's name; a trial met twice with the
    same value counts once (the first folder's) and the other is listed as left out."""
    runs: dict[tuple[str, int], dict[int, RunRecord]] = {}
    for folder in sweep.folders:
        path = root / folder
        if not path.is_dir():
            skipped.append(Skipped(path, "no such runs folder"))
            continue
        for row in final_table(load_runs(path, skipped)):
            if row.env != sweep.env or row.method not in sweep.methods or row.policy != "final":
                continue
            for record in row.runs:
                if sweep.setting not in record.config:
                    skipped.append(Skipped(record.path, f"config.json has no {sweep.setting}"))
                    continue
                trials = runs.setdefault((row.method, int(record.config[sweep.setting])), {})
                if record.trial in trials:
                    skipped.append(Skipped(record.path, f"trial {record.trial} is already counted from "
                                                        f"{relative(trials[record.trial].path, root)}"))
                else:
                    trials[record.trial] = record
    return {key: FinalRow(sweep.env, key[0], "final", [trials[t] for t in sorted(trials)])
            for key, trials in sorted(runs.items(), key=lambda item: (METHOD_ORDER.index(item[0][0]), item[0][1]))}


def sweep_markdown(sweep: Sweep, rows: dict[tuple[str, int], FinalRow]) -> str:
    """Per method and value: the final policy's % of the expert, its returns by trial, the lowest-u
    policy's % of the expert and the Table I window return (methods with an RL phase), and paired
    counts of the final policy against BC at the same value and against the method's previous value."""
    body = []
    for method in sweep.methods:
        previous = None
        for (m, value), row in rows.items():
            if m != method:
                continue
            bc = rows.get(("bc", value))
            per_trial = ", ".join(f"{t}: {fmt(v)}" for t, v in sorted(row.per_trial("return").items()))
            lowest = FinalRow(row.env, method, "lowest_u", [r for r in row.runs if "lowest_u" in r.final])
            body.append([
                METHOD_LABELS[method], f"{value:,}", str(row.n_trials),
                "/".join(str(n) for n in sorted(set(row.episodes()))),
                fmt_ci(*row.stat("pct_of_expert")), per_trial,
                fmt_ci(*lowest.stat("pct_of_expert")) if lowest.runs else "—",
                "—" if method == "bc" else fmt(window_return(row)),
                "—" if bc is None or method == "bc" else above_reference(row, bc),
                "—" if previous is None else above_reference(row, previous),
            ])
            previous = row
    return md_table(
        ["Method", sweep.title[:1].upper() + sweep.title[1:], "Trials", "Held-out episodes per trial",
         "Final policy: % of expert [95% CI]", "Final policy: return by trial",
         "Lowest-u policy: % of expert [95% CI]", "Table I window return",
         "Above BC, same setting (trials)", "Above the previous row (trials)"],
        body,
    )


def plot_sweep(sweep: Sweep, rows: dict[tuple[str, int], FinalRow], path: Path) -> Path:
    """% of expert against the swept setting (each trial a point, the mean with its CI); for a sweep of
    the training budget, beside it the per-epoch evaluation return against timesteps. ``rows`` is not
    empty."""
    values = sorted({value for _, value in rows})
    curves = sweep.setting == "timesteps"
    fig = new_figure(12.0 if curves else 6.5, 4.8)
    axes = fig.subplots(1, 2 if curves else 1, squeeze=False)[0]
    ax = axes[0]
    for k, method in enumerate(sweep.methods):
        points = [(value, rows[(method, value)]) for value in values if (method, value) in rows]
        if not points:
            continue
        # Methods side by side on a log axis: a constant factor apart, the same on every report.
        shift = 1.06 ** (k - (len(sweep.methods) - 1) / 2)
        xs = [value * shift for value, _ in points]
        stats = [row.stat("pct_of_expert") for _, row in points]
        for x, (_, row) in zip(xs, points, strict=True):
            pct = row.per_run("pct_of_expert")
            ax.scatter([x] * len(pct), pct, s=14, color=COLORS[method], alpha=0.45, linewidth=0)
        means = [m for m, _, _ in stats]
        errors = [[m - lo if math.isfinite(lo) else 0.0 for m, lo, _ in stats],
                  [hi - m if math.isfinite(hi) else 0.0 for m, _, hi in stats]]
        ax.errorbar(xs, means, yerr=errors, color=COLORS[method], marker="o", capsize=4,
                    label=f"{METHOD_LABELS[method]} (trials: {', '.join(str(r.n_trials) for _, r in points)})")
    ax.axhline(100, color="black", linestyle=":", linewidth=1.2, label="expert")
    ax.set_xscale("log")
    ax.set_xticks(values, [f"{v:,}" for v in values])
    ax.minorticks_off()
    ax.set_xlabel(sweep.title)
    ax.set_ylabel("final policy: % of the expert's return\non the same held-out episodes")
    fixed = f"{sweep.fixed}\n" if sweep.fixed else ""
    ax.set_title(f"{fixed}{sweep.env}: mean over trials, bar: 95% bootstrap CI; dots: trials", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    if curves:
        _plot_budget_curves(axes[1], sweep, rows)
    return save_png(fig, path)


def _plot_budget_curves(ax, sweep: Sweep, rows: dict[tuple[str, int], FinalRow]) -> None:
    styles = ("--", "-", "-.", ":")
    values = sorted({value for _, value in rows})
    for (method, value), row in rows.items():
        epochs, mean, std = smoothed_band(row.runs, "return_mean", SMOOTHING_SIGMA)
        steps = {int(e): int(t) for r in row.runs
                 for e, t in zip(r.columns["epoch"], r.columns["timesteps"], strict=True)}
        x = np.array([steps[int(e)] for e in epochs])
        style = styles[values.index(value) % len(styles)]
        ax.plot(x, mean, color=COLORS[method], linestyle=style,
                label=f"{METHOD_LABELS[method]}, {value:,} steps (n={row.n_trials})")
        ax.fill_between(x, mean - std, mean + std, color=COLORS[method], alpha=0.12, linewidth=0)
    expert = expert_by_env(list(rows.values()))[sweep.env][0]
    ax.axhline(expert, color="black", linestyle=":", linewidth=1.2, label="expert (held-out mean)")
    ax.set_xlabel("PPO timesteps")
    episodes = sorted({int(n) for row in rows.values() for r in row.runs for n in r.columns["n_episodes"]})
    ax.set_ylabel(f"evaluation return ({'/'.join(map(str, episodes))} held-out episodes)")
    ax.set_title(f"{sweep.env}: per-epoch evaluation, mean over trials ±1 std (smoothed)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")


def sweeps_markdown(root: Path, skipped: list[Skipped], figures: Path | None,
                    sweeps: tuple[Sweep, ...] = ()) -> str:
    """A section per sweep: its table and, when ``figures`` is given, its figure written there."""
    parts = []
    for sweep in sweeps:
        rows = sweep_rows(sweep, root, skipped)
        text = [f"### {sweep.env}: {sweep.title}" + (f", {sweep.fixed}" if sweep.fixed else "")]
        if not rows:
            text.append("No finished runs yet.")
        else:
            text.append(sweep_markdown(sweep, rows))
            if figures is not None:
                plot_sweep(sweep, rows, figures / sweep.figure)
                text.append(f"![{sweep.title}](figures/{sweep.figure})")
        text.append(f"Runs: `{'`, `'.join(sweep.folders)}`, made by {sweep.made_by}.")
        parts.append("\n\n".join(text))
    return "\n\n".join(parts)


def cpu_minutes_axis(run: RunRecord) -> np.ndarray | None:
    """Each evaluation's CPU minutes into ``run``: done.json's ``cpu_time_s`` (pretraining, training
    and evaluations) spread over its steps in proportion, so pretraining is smeared over the run
    rather than charged before step 0; None where done.json kept no CPU time."""
    cost = cpu_and_steps(run)
    if cost is None:
        return None
    cpu, steps = cost
    return np.asarray(run.columns["timesteps"], dtype=np.float64) / steps * cpu / 60.0


def cost_band(runs: list[RunRecord]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(CPU minutes, mean, std, runs used) of the runs' evaluation returns, each run interpolated onto
    a common axis. The axis ends where the first run ended: past it the mean would be that of the
    runs that went on, a different set of trials at every point."""
    curves = [(x, np.asarray(r.columns["return_mean"], dtype=np.float64))
              for r in runs if (x := cpu_minutes_axis(r)) is not None and len(x)]
    if not curves:
        return np.empty(0), np.empty(0), np.empty(0), 0
    axis = np.linspace(0.0, min(float(x[-1]) for x, _ in curves), COST_GRID_POINTS)
    grid = np.array([np.interp(axis, x, y) for x, y in curves])
    return axis, grid.mean(axis=0), grid.std(axis=0), len(curves)


def steps_per_cpu_second(row: FinalRow) -> str:
    """Median over runs of done.json's ``num_timesteps / cpu_time_s``; "—" where none kept CPU time."""
    values = [steps / cpu for r in row.runs if (cost := cpu_and_steps(r)) is not None for cpu, steps in [cost]]
    return fmt(float(np.median(values))) if values else "—"


def plot_cost_curves(curves: CostCurves, rows: list[tuple[Variant, FinalRow]], bc: FinalRow | None,
                     path: Path) -> Path:
    """Evaluation return against CPU minutes, mean over trials ±1 std, per variant (up to where its
    first run ended); the expert's and BC's final returns as lines. ``rows`` is not empty."""
    fig = new_figure(8.5, 5.0)
    ax = fig.subplots()
    palette = ("tab:purple", "tab:blue", "tab:orange", "tab:green", "tab:brown", "tab:pink")
    for k, (variant, row) in enumerate(rows):
        axis, mean, std, n = cost_band(row.runs)
        if not n:
            continue
        color = palette[k % len(palette)]
        ax.plot(axis, mean, color=color, label=f"{variant.label} (n={n})")
        ax.fill_between(axis, mean - std, mean + std, color=color, alpha=0.12, linewidth=0)
    expert = expert_by_env([row for _, row in rows])[curves.env][0]
    ax.axhline(expert, color="black", linestyle=":", linewidth=1.2, label="expert (held-out mean)")
    if bc is not None:
        ax.axhline(bc.stat("return")[0], color=COLORS["bc"], linestyle="--", linewidth=1.2,
                   label=f"BC, final policy (mean of {bc.n_trials} trials)")
    ax.set_xlabel("CPU minutes into the run (pretraining and evaluations included, spread over its steps)")
    episodes = sorted({int(n) for _, row in rows for r in row.runs for n in r.columns["n_episodes"]})
    ax.set_ylabel(f"evaluation return ({'/'.join(map(str, episodes))} held-out episodes)")
    ax.set_title(f"{curves.env}: {curves.title}; mean over trials ±1 std, up to where a variant's first run "
                 "ended", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    return save_png(fig, path)


def cost_markdown(root: Path, skipped: list[Skipped], figures: Path | None,
                  cost_curves: tuple[CostCurves, ...] = (), grid: tuple[str, ...] = (GRID,)) -> str:
    """A section per :class:`CostCurves`: steps per CPU second and the final policy per variant, and
    the figure (written to ``figures`` when given)."""
    parts = []
    for curves in cost_curves:
        found = [(v, variant_rows(v, root, skipped)["final"]) for v in curves.variants]
        rows = [(v, row) for v, row in found if row is not None]
        text = [f"### {curves.env}: {curves.title}"]
        if not rows:
            parts.append("\n\n".join([*text, "No finished runs yet."]))
            continue
        text.append(md_table(
            ["Variant", "Trials", "Steps per CPU second (median)", "CPU minutes per run (median)",
             "Final policy: % of expert [95% CI]"],
            [[v.label, str(row.n_trials), steps_per_cpu_second(row), cpu_minutes(row),
              fmt_ci(*row.stat("pct_of_expert"))] for v, row in rows],
        ))
        if figures is not None:
            plot_cost_curves(curves, rows, baseline_row(curves.env, "bc", grid, root), figures / curves.figure)
            text.append(f"![{curves.title}](figures/{curves.figure})")
        text.append("Runs: " + "; ".join(f"{v.label}: `{v.runs}`" for v, _ in rows)
                    + " (the commands: the ablation rows of the same folders).")
        parts.append("\n\n".join(text))
    return "\n\n".join(parts)


def kept_and_last(variant: Variant, root: Path, skipped: list[Skipped]) -> tuple[FinalRow, FinalRow] | None:
    """The variant's runs that kept a policy by a reward-free choice, as the kept row and the last
    weights' row over the same runs; None when it has none. Two layouts: the off-policy study's (done.json
    ``selection``; final_eval.csv's kept policy is "final", the last weights "last") and the package's
    ``cmz-sac`` runs (final_eval.csv's kept policy is "longest", the last weights "final")."""
    rows = variant_rows(variant, root, skipped)
    final = rows["final"]
    study = [r for r in ([] if final is None else final.runs)
             if "last" in r.final and isinstance(r.summary.get("selection"), dict)]
    if study:
        return (FinalRow(variant.env, variant.method, "final", study),
                FinalRow(variant.env, variant.method, "last", study))
    longest = rows["longest"]
    if longest is None:
        return None
    return longest, dataclasses.replace(longest, policy="final")


def _kept_check(run: RunRecord) -> dict[str, Any]:
    """Where a run's kept policy was found: its check's steps, mean episode length and mean u (NaN
    where not recorded), and the checks' count and env steps (None where not recorded)."""
    selection = run.summary.get("selection")
    if isinstance(selection, dict):  # the off-policy study's runs
        return {"checks": len(selection.get("checks", [])), "env_steps": selection.get("env_steps"),
                "timesteps": selection.get("kept_timesteps"), "length": selection.get("kept_mean_length", math.nan),
                "u": math.nan}
    kept = run.summary.get("final_evaluation", {}).get("longest", {})
    return {"checks": None, "env_steps": kept.get("env_steps"), "timesteps": kept.get("timesteps"),
            "length": kept.get("mean_length", math.nan), "u": kept.get("mean_u", math.nan)}


def selection_markdown(root: Path, skipped: list[Skipped], variants: tuple[Variant, ...] = ()) -> str:
    """A table per variant whose runs chose their final policy reward-free: per trial, where the kept
    policy was found and what it and the last weights return on the same held-out episodes."""
    parts = []
    for variant in variants:
        found = kept_and_last(variant, root, skipped)
        text = [f"### {variant.env}: {variant.label}"]
        if found is None:
            parts.append("\n\n".join([*text, "No finished runs yet."]))
            continue
        kept, last = found
        kept_pct, last_pct = kept.per_trial("pct_of_expert"), last.per_trial("pct_of_expert")
        body = []
        checks = {run.trial: _kept_check(run) for run in kept.runs}
        for run in kept.runs:
            check = checks[run.trial]
            count = "" if check["checks"] is None else f"{check['checks']} "
            body.append([
                str(run.trial), f"{count}({check['env_steps']})",
                f"{check['timesteps']} of {run.summary.get('num_timesteps')}",
                fmt(float(check["length"])), fmt(float(check["u"])),
                fmt(last_pct[run.trial]), fmt(kept_pct[run.trial]),
            ])
        body.append(["mean [95% CI]", "", "", "", "", fmt_ci(*last.stat("pct_of_expert")),
                     fmt_ci(*kept.stat("pct_of_expert"))])
        text.append(md_table(
            ["Trial", "Checks (their env steps)", "Kept: at step (of the run's)",
             "Kept: mean episode length at its check", "Kept: mean u at its check", "Last weights: % of expert",
             "Kept policy: % of expert"], body))
        earlier = [r.trial for r in kept.runs if checks[r.trial]["timesteps"] != r.summary.get("num_timesteps")]
        above = sum(kept_pct[t] > last_pct[t] for t in earlier)
        text.append(f"The kept policy is the last one in {len(kept.runs) - len(earlier)} of {len(kept.runs)} trials; "
                    f"where it is an earlier one, it is above the last weights in {above} of {len(earlier)}. "
                    f"Runs: `{variant.runs}`, made by `{variant.made_by}`.")
        parts.append("\n\n".join(text))
    return "\n\n".join(parts)


def across_scores(study: AcrossTasks, root: Path, skipped: list[Skipped]) -> Scores | None:
    """The normalised final scores (:func:`.aggregate.normalised_score`) of each method's result
    (:func:`result_policy`) on the study's trials; a task where a method lacks one of them is
    left out of that method with a note."""
    tasks: dict[str, list[str]] = {}
    columns: dict[str, list[list[float]]] = {}
    left_out = []
    loaded: dict[Path, list[FinalRow]] = {}  # the grid's folder serves every grid method on every task
    for key, label, variants in study.methods:
        for variant in variants:
            policy = result_policy(variant.method)
            row = variant_rows(dataclasses.replace(variant, trials=study.trials), root, skipped, loaded)[policy]
            by_trial = {} if row is None else {run.trial: normalised_score(run.final[policy]) for run in row.runs}
            missing = [t for t in study.trials if t not in by_trial]
            if missing:
                left_out.append(LeftOut(variant.env, label, f"no finished trial {', '.join(map(str, missing))}"))
                continue
            values = [by_trial[t] for t in study.trials]
            if not np.isfinite(values).all():
                left_out.append(LeftOut(variant.env, label, "no positive expert mean"))
                continue
            tasks.setdefault(key, []).append(variant.env)
            columns.setdefault(key, []).append(values)
    if not columns:
        return None
    keys = [key for key, _, _ in study.methods if key in columns]
    return Scores(
        trials={k: study.trials for k in keys},
        tasks={k: tuple(tasks[k]) for k in keys},
        by_method={k: np.asarray(columns[k], dtype=np.float64).T for k in keys},
        left_out=tuple(left_out),
        labels={key: label for key, label, _ in study.methods},
    )


def across_markdown(root: Path, skipped: list[Skipped], figures: Path | None,
                    studies: tuple[AcrossTasks, ...] = ()) -> str:
    """Per study: its aggregates (IQM, mean, median, probability of improvement), the performance
    profiles' figure in ``figures`` (none without it), and the runs each method's tasks came from."""
    parts = []
    for study in studies:
        text = [f"### {study.title}", *([study.intro] if study.intro else [])]
        scores = across_scores(study, root, skipped)
        if scores is None:
            parts.append("\n\n".join([*text, "No finished runs yet."]))
            continue
        result = aggregate(scores, study.pairs)
        if figures is not None:
            plot_aggregate(result, figures / study.figure)
        section = aggregate_markdown(result, None if figures is None else f"figures/{study.figure}")
        folders: dict[tuple[str, str], tuple[dict[str, None], dict[str, None]]] = {}
        for _, label, variants in study.methods:
            for v in variants:
                labels, envs = folders.setdefault((v.runs, v.made_by), ({}, {}))
                labels[label], envs[v.env] = None, None
        groups = {key: [f"{', '.join(labels)} on {', '.join(envs)}"] for key, (labels, envs) in folders.items()}
        parts.append("\n\n".join([*text, section.strip(), runs_sentence(groups)]))
    return "\n\n".join(parts)


def render(
    root: Path,
    ablations: tuple[Variant, ...] = (),
    rollouts: tuple[RolloutTable, ...] = (),
    sweeps: tuple[Sweep, ...] = (),
    figures: Path | None = None,
    command: str = "",
    grid: tuple[str, ...] = (GRID,),
    cost_curves: tuple[CostCurves, ...] = (),
    selections: tuple[Variant, ...] = (),
    across: tuple[AcrossTasks, ...] = (),
) -> str:
    """The page's text (docs/new_tasks.md), from the runs below ``root``; the sweeps' figures go to
    ``figures`` (none are drawn without it). ``command`` is what the page says wrote it; ``grid``
    the published grid every ablation is paired with (then folders adding trials it lacks);
    ``cost_curves`` the variants drawn against CPU time; ``selections`` the variants whose runs
    chose their final policy reward-free (:func:`selection_markdown`); ``across`` the comparisons
    across tasks (:func:`across_markdown`)."""
    materialize_all(root / "results")
    skipped: list[Skipped] = []
    sweep_tables = sweeps_markdown(root, skipped, figures, sweeps)
    tables = ablation_markdown(root, skipped, ablations, grid)
    cost = cost_markdown(root, skipped, figures, cost_curves, grid)
    kept = selection_markdown(root, skipped, selections)
    across_tables = across_markdown(root, skipped, figures, across)
    rollout_tables = rollout_markdown(root, skipped, rollouts)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    text = [
        "# Beyond the three tuned tasks: demonstrations, budget and ablations",
        f"Written by `{command}` on {stamp} from the runs named under each table; no number is typed in. "
        "The published grid (Walker2d-v5 and Swimmer-v5 beside the paper's envs, tuned entries) is in "
        "[its report](tuned/results.md), the methods on the default in [results.md](results.md).",
        "Versions: most of these runs were made before 0.3.0 (each config.json names its version), and "
        "\"package defaults\" there means the settings of then: the task's entry in `hyperparams/cmzdril.yml` "
        "or `cmzdril_sac.yml` (now `cmzdril-tuned.yml`, `cmzdril_sac-tuned.yml`: a command here that names "
        "the former makes its runs with these) or, for a task with none, the paper's. From 0.3.0 every task "
        "gets the rules of [one default](one_default.md) instead; a command here that runs a task with no "
        "entry without naming `absorbing`, `cmz_clip_quantile`, `disagreement`, `standardize_observations` "
        "and `bc_epochs_per_update` makes its runs at commit a7b611ab (the untuned tasks' scripts and the "
        "outside-env study name the YAML that pins them), and its run folder refuses to resume under 0.3.0.",
        "Each run's final evaluation replays every demo-pool episode not used for training from the expert's "
        "start state. % of expert: 100 x the run's mean return / the expert's mean return on the same "
        "episodes; a cell is the mean over trials [95% bootstrap CI over trials, n/a under 3 trials]. "
        "Lowest-u policy: the policy whose own training rollout had the lowest ensemble disagreement; for "
        "the method `cmz-sac`, the longest-episodes policy: the one whose deterministic episodes from fixed "
        "starts lasted longest (neither reads the env reward). Table I window: the per-epoch evaluation (5 "
        "held-out episodes) averaged over the last 100 epochs. Trials: a trial is a seed, demo split and set "
        "of held-out episodes, the same in every variant; the paired count is over the trials both variants "
        "have.",
        "## How many demonstrations, how many steps\n\nThe package defaults with more training "
        "demonstrations (the first N of the trial's permutation of the pool, so a trial's 1 demo is among "
        "its 3 and its 3 among its 10; the rest of the 30-episode pool is held out) and with a longer "
        "training budget. The paired counts compare the same trials.",
        sweep_tables,
        "## Ablations",
        tables,
        *(["## Against CPU time\n\nLearners differ in CPU per step (PPO with one or several envs per process, "
           "SAC with a gradient step per env step), so the evaluations are drawn against the CPU time a run had "
           "spent when it made them.", cost] if cost_curves else []),
        *(["## Keeping the policy that lasts longest\n\nThe off-policy learner reaches the expert's level and "
           "loses it again. These runs check the policy at the start, every evaluation interval and at the end, "
           "playing it deterministically for 5 episodes from fixed starts (no pool episode's), and keep the one "
           "whose episodes lasted longest, the latest on a tie: a choice that reads termination, never reward. "
           "The kept policy is the run's final policy in the ablation tables (for the package's `cmz-sac` runs, "
           "its second policy; with `longest_tie_break: lowest_u` a tie goes to the check whose states the "
           "ensemble disagrees on least, its mean u; for PPO runs with `keep_longest: true`, its second row); here "
           "it is beside the last weights of the same runs, both on every held-out episode.", kept]
          if selections else []),
        *(["## Across tasks", across_tables] if across else []),
        "## What the agent does in training\n\nMean over trials [95% CI] of what each run logged per "
        "training rollout, early and late. Episode length: steps per episode (time limit 1,000); shorter "
        "ended in a fall, and a reward that favours staying alive lengthens it. u: the ensemble's disagreement "
        "on the agent's own states, the quantity DRIL's and CMZ-DRIL's rewards push down (no reward: what "
        "PPO's updates and the BC epochs alone do to it).",
        rollout_tables,
    ]
    if skipped:
        # Folders shared by several tables are loaded once per table: list what each leaves out once.
        text.append("Left out: " + "; ".join(dict.fromkeys(s.text(root) for s in skipped)))
    discussion = root / "docs" / "new_tasks_discussion.md"
    if discussion.is_file():  # linked, not copied: the hand-written text lives in one place
        where = os.path.relpath(discussion, figures.parent) if figures is not None else discussion.name
        text.append(f"## Reading\n\nWhat these tables mean, written by hand: [the reading]({Path(where).as_posix()}).")
    return "\n\n".join(text) + "\n"


__all__ = [
    "AcrossTasks",
    "COST_GRID_POINTS",
    "CostCurves",
    "EDGE_EPOCHS",
    "GRID",
    "RolloutTable",
    "Sweep",
    "Variant",
    "ablation_markdown",
    "across_markdown",
    "across_scores",
    "cost_band",
    "cost_markdown",
    "cpu_and_steps",
    "cpu_minutes_axis",
    "kept_and_last",
    "render",
    "rollout_edges",
    "rollout_markdown",
    "selection_markdown",
    "steps_per_cpu_second",
    "sweep_markdown",
    "sweep_rows",
    "sweeps_markdown",
]
