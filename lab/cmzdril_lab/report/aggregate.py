"""One number across tasks: rliable's aggregates of the final evaluation, over every task and trial.

Per-task tables say how a method does on each env; a reader comparing methods across envs needs one
number with an honest interval. Following Agarwal et al. (NeurIPS 2021, the ``rliable`` library):

* a run's **normalised score** is its mean return over its held-out pool episodes divided by the
  expert's mean return over the same episodes (1 = the expert), so envs of different return scales
  pool together (:func:`score_matrix`);
* the **interquartile mean** (IQM) of the scores over all tasks and trials, beside the mean and the
  median of the per-task means, each with a stratified bootstrap confidence interval (runs resampled
  within each task);
* the **probability of improvement** of one method over another: the chance that a run of the first
  scores above a run of the second on a task picked at random (ties count half), with its interval;
* **performance profiles**: the share of runs whose score exceeds each threshold.

A method enters an aggregate only on the tasks where it has runs; a comparison between two methods
uses the tasks both have. Trials are matched by index (the grids' trials 0..n-1), so every task
contributes the same number of runs, as rliable's stratified bootstrap needs.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from cmzdril_lab.report.final_eval import FinalRow, expert_percent
from cmzdril_lab.report.formatting import md_table
from cmzdril_lab.report.records import METHOD_LABELS, METHOD_ORDER, result_policy
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import PathLike, atomic_write_text

#: Seed of every bootstrap here: the same runs give the same intervals on every report.
SEED = 0
#: Bootstrap replications (rliable's default is 50,000; 2,000 keeps a report within seconds and
#: moves the interval ends by well under a percentage point on 30 runs).
REPS = 2000
CONFIDENCE = 0.95
#: Thresholds of the performance profiles, in normalised score (0 to 1.25 times the expert).
PROFILE_TAUS = np.linspace(0.0, 1.25, 51)
#: Pairs whose probability of improvement the report gives: (method, baseline).
#: A pair is given only where both methods have tasks in common (cmz-sac's runs need not cover every task).
IMPROVEMENT_PAIRS: tuple[tuple[str, str], ...] = (
    ("cmz", "bc"), ("cmz", "dril"), ("cmz", "zero"), ("dril", "bc"),
    ("cmz-sac", "bc"), ("cmz-sac", "dril"), ("cmz-sac", "cmz"), ("cmz-sac", "dril-sac"), ("cmz-sac", "zero-sac"),
)
FIGURE = "fig4_across_tasks.png"
CSV = "across_tasks.csv"


def normalised_score(columns: dict[str, np.ndarray]) -> float:
    """A run's mean return over the expert's mean return on the same held-out episodes (the per-task
    tables' "% of expert" over 100); nan when the expert's mean is not positive (no scale to divide by)."""
    return expert_percent(columns) / 100


class LeftOut(NamedTuple):
    """A task a method has runs of that its aggregate leaves out, and why."""

    task: str
    label: str  #: the method, as tables name it
    reason: str


def left_out_text(left_out: Sequence[LeftOut]) -> str:
    """``left_out`` in a sentence, one clause per task and reason: "Pendulum-v1 (BC, CMZ-DRIL): no positive
    expert mean; ..." rather than the task and reason again for each method."""
    labels: dict[tuple[str, str], list[str]] = {}
    for task, label, reason in left_out:
        labels.setdefault((task, reason), []).append(label)
    return "; ".join(f"{task} ({', '.join(names)}): {reason}" for (task, reason), names in labels.items())


@dataclasses.dataclass(frozen=True)
class Scores:
    """Normalised scores of the final policies: ``by_method[m]`` is (len(trials[m]), len(tasks[m]))."""

    trials: dict[str, tuple[int, ...]]
    tasks: dict[str, tuple[str, ...]]
    by_method: dict[str, np.ndarray]
    left_out: tuple[LeftOut, ...] = ()  #: (task, method)s not aggregated, each with the reason
    #: how tables and figures name each method (a study may compare methods the grid does not have)
    labels: dict[str, str] = dataclasses.field(default_factory=lambda: dict(METHOD_LABELS))

    def on(self, method: str, tasks: Sequence[str]) -> np.ndarray:
        """``method``'s (trials, len(tasks)) scores restricted to ``tasks``."""
        columns = [self.tasks[method].index(t) for t in tasks]
        return self.by_method[method][:, columns]

    def shared_tasks(self, a: str, b: str) -> tuple[str, ...]:
        return tuple(t for t in self.tasks[a] if t in self.tasks[b])


def _runs_kept(trials: tuple[int, ...], scored: Mapping[str, Mapping[int, float]]) -> tuple[int, int]:
    """(runs, tasks) that scoring on ``trials`` keeps: the tasks with all of them."""
    tasks = sum(set(trials) <= set(by_trial) for by_trial in scored.values())
    return tasks * len(trials), tasks


def score_matrix(rows: Sequence[FinalRow]) -> Scores | None:
    """The normalised scores of each method's result (:func:`result_policy`: the final
    policy, or the longest-episodes one for ``cmz-sac``) on its tasks, over the trials its tasks share.

    rliable's stratified bootstrap resamples the runs within each task and wants as many on each, so a
    method is scored on the set of trials one of its tasks has that keeps the most runs (tasks with
    all of them times their number; on a tie, the more tasks): ten trials on one task do not crowd out
    the five of three others. A task of that method without all of them (a grid still running) is left
    out with a note, as is a task whose expert mean is not positive. None when nothing is left; a
    UserError when an (env, method) comes twice (from two grids: which one counts is the caller's
    choice, not ours).
    """
    chosen = [r for r in rows if r.policy == result_policy(r.method)]
    seen: set[tuple[str, str]] = set()
    for row in chosen:
        if (row.env, row.method) in seen:
            raise UserError(f"{row.env} {METHOD_LABELS[row.method]} is in two grids: aggregate each task once")
        seen.add((row.env, row.method))
    trials: dict[str, tuple[int, ...]] = {}
    tasks: dict[str, list[str]] = {}
    columns: dict[str, list[list[float]]] = {}
    left_out = []
    for method in METHOD_ORDER:
        mine = [r for r in chosen if r.method == method]
        if not mine:
            continue
        scored = {}
        for row in mine:
            by_trial = {run.trial: normalised_score(run.final[row.policy]) for run in row.runs}
            if np.isfinite(list(by_trial.values())).all():
                scored[row.env] = by_trial
            else:
                left_out.append(LeftOut(row.env, METHOD_LABELS[method], "no positive expert mean"))
        if not scored:
            continue
        # Only a task that can be scored sets the trials: one without a scale must not crowd out the rest.
        wanted = max((tuple(sorted(by_trial)) for by_trial in scored.values()), key=lambda w: _runs_kept(w, scored))
        for env, by_trial in scored.items():
            if not set(wanted) <= set(by_trial):
                left_out.append(LeftOut(env, METHOD_LABELS[method],
                                        f"{len(set(by_trial) & set(wanted))} of the {len(wanted)} trials"))
                continue
            values = [by_trial[t] for t in wanted]
            trials[method] = wanted
            tasks.setdefault(method, []).append(env)
            columns.setdefault(method, []).append(values)
    if not columns:
        return None
    methods = [m for m in METHOD_ORDER if m in columns]
    return Scores(
        trials={m: trials[m] for m in methods},
        tasks={m: tuple(tasks[m]) for m in methods},
        by_method={m: np.asarray(columns[m], dtype=np.float64).T for m in methods},
        left_out=tuple(left_out),
    )


def stratified_bootstrap(
    samples: Sequence[np.ndarray],
    point_func: Callable[..., np.ndarray | float],
    batch_func: Callable[..., np.ndarray],
    reps: int = REPS,
    seed: int = SEED,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point, low, high): ``point_func(*samples)`` and a percentile interval from a stratified bootstrap.

    Each sample is a (runs, tasks) matrix; every replication resamples the runs of each task with
    replacement, each sample independently: rliable's ``StratifiedBootstrap`` for one sample and
    ``StratifiedIndependentBootstrap`` for two. Done here in numpy because rliable's bootstrap module
    imports ``arch``, whose releases that rliable admits (< 8) fail to import beside pandas 3; and
    batched (``batch_func`` takes (reps, runs, tasks) arrays and returns (reps, ...)), because a
    Python loop of 2,000 Mann-Whitney tests per task and pair takes minutes.
    """
    rng = np.random.default_rng(seed)
    point = np.atleast_1d(np.asarray(point_func(*samples), dtype=np.float64))
    resampled = []
    for x in samples:
        rows = rng.integers(0, x.shape[0], size=(reps, *x.shape))  # per task (column), runs with replacement
        resampled.append(np.take_along_axis(np.broadcast_to(x, (reps, *x.shape)), rows, axis=1))
    draws = np.asarray(batch_func(*resampled), dtype=np.float64).reshape(reps, -1)
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(draws, [tail, 100 - tail], axis=0)
    return point, low, high


def batch_statistics(x: np.ndarray) -> np.ndarray:
    """(reps, 3): IQM, mean and median of each (runs, tasks) matrix of ``x``, as rliable's
    ``aggregate_iqm``, ``aggregate_mean`` and ``aggregate_median`` compute them."""
    from scipy.stats import trim_mean

    flat = x.reshape(x.shape[0], -1)
    per_task = x.mean(axis=1)
    return np.stack([trim_mean(flat, 0.25, axis=1), per_task.mean(axis=1), np.median(per_task, axis=1)], axis=1)


def batch_profile(x: np.ndarray) -> np.ndarray:
    """(reps, len(PROFILE_TAUS)): the share of runs above each threshold (rliable's score distribution)."""
    flat = x.reshape(x.shape[0], -1)
    return (flat[:, :, None] > PROFILE_TAUS[None, None, :]).mean(axis=1)


def batch_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(reps,): rliable's ``probability_of_improvement`` (Mann-Whitney U / (n m) per task, ties half,
    averaged over tasks) of each pair of (runs, tasks) matrices."""
    above = (x[:, :, None, :] > y[:, None, :, :]).mean(axis=(1, 2))
    ties = (x[:, :, None, :] == y[:, None, :, :]).mean(axis=(1, 2))
    return (above + 0.5 * ties).mean(axis=1)


Interval = tuple[float, float, float]  #: (point, low, high)


@dataclasses.dataclass(frozen=True)
class Improvement:
    """A (method, baseline) pair on the tasks both have: the probability of improvement, and each one's
    IQM on those tasks alone, since the summary's IQMs may pool different tasks and not compare."""

    probability: Interval
    tasks: tuple[str, ...]
    iqm: Interval
    baseline_iqm: Interval


@dataclasses.dataclass(frozen=True)
class Aggregates:
    """IQM, mean and median per method (point, low, high), and the probabilities of improvement."""

    scores: Scores
    summary: dict[str, dict[str, Interval]]  #: method -> statistic -> (point, low, high)
    improvement: dict[tuple[str, str], Improvement]
    profiles: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]  #: method -> (profile, low, high)


STATISTICS: tuple[str, ...] = ("IQM", "Mean", "Median")


def aggregate(scores: Scores, pairs: Sequence[tuple[str, str]] = IMPROVEMENT_PAIRS) -> Aggregates:
    """Every aggregate of ``scores``: rliable's statistics (the ``experiments`` extra), bootstrapped, and the
    probability of improvement of each (method, baseline) of ``pairs`` that both have tasks in common."""
    from sb3_cmzdril.extras import require_extra

    metrics = require_extra("rliable.metrics", "experiments", "the across-task aggregate (rliable)")

    def stats(x: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(x), metrics.aggregate_mean(x), metrics.aggregate_median(x)])

    def profile(x: np.ndarray) -> np.ndarray:
        return batch_profile(x[None])[0]

    def summarise(matrix: np.ndarray) -> dict[str, Interval]:
        point, low, high = stratified_bootstrap([matrix], stats, batch_statistics)
        return {st: (float(point[i]), float(low[i]), float(high[i])) for i, st in enumerate(STATISTICS)}

    summary, profiles = {}, {}
    for m, matrix in scores.by_method.items():
        summary[m] = summarise(matrix)
        profiles[m] = stratified_bootstrap([matrix], profile, batch_profile)
    def iqm_on(method: str, tasks: tuple[str, ...]) -> Interval:
        # A pair over all of a method's tasks has the summary's IQM: no second bootstrap of the same runs.
        if tasks == scores.tasks[method]:
            return summary[method]["IQM"]
        return summarise(scores.on(method, tasks))["IQM"]

    improvement = {}
    for a, b in pairs:
        shared = scores.shared_tasks(a, b) if a in scores.tasks and b in scores.tasks else ()
        if shared:
            point, low, high = stratified_bootstrap(
                [scores.on(a, shared), scores.on(b, shared)], metrics.probability_of_improvement, batch_improvement
            )
            improvement[(a, b)] = Improvement(
                probability=(float(point[0]), float(low[0]), float(high[0])), tasks=shared,
                iqm=iqm_on(a, shared), baseline_iqm=iqm_on(b, shared),
            )
    return Aggregates(scores, summary, improvement, profiles)


def _pct(point: float, low: float, high: float) -> str:
    return f"{100 * point:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def _improvement_row(labels: Mapping[str, str], a: str, b: str, pair: Improvement) -> list[str]:
    p, low, high = pair.probability
    return [labels[a], labels[b], f"{p:.2f} [{low:.2f}, {high:.2f}]", _pct(*pair.iqm), _pct(*pair.baseline_iqm),
            ", ".join(pair.tasks)]


def per_task_markdown(scores: Scores, short: bool = False) -> str:
    """Each task's mean score (% of expert) per method over its trials, the numbers the aggregates pool;
    "—" where a method has no runs of the task. ``short``: the methods' names alone as column heads."""
    methods = list(scores.by_method)
    tasks = list(dict.fromkeys(t for m in methods for t in scores.tasks[m]))

    def cell(method: str, task: str) -> str:
        if task not in scores.tasks[method]:
            return "—"
        return f"{100 * scores.on(method, [task]).mean():.1f}"

    heads = [scores.labels[m] if short else f"{scores.labels[m]}, mean % of expert" for m in methods]
    return md_table(["Task", *heads], [[task, *(cell(m, task) for m in methods)] for task in tasks])


def _summary_table(agg: Aggregates, short: bool = False) -> str:
    s = agg.scores
    heads = [f"{st} [CI]" if short else f"{st}, % of expert [CI]" for st in STATISTICS]
    return md_table(["Method", "Tasks", *heads],
                    [[s.labels[m], ", ".join(s.tasks[m]), *(_pct(*agg.summary[m][st]) for st in STATISTICS)]
                     for m in s.by_method])


def _improvement_table(agg: Aggregates, short: bool = False) -> str:
    iqm = ["IQM [CI]", "Baseline's IQM [CI]"] if short else ["Method's IQM, % [CI]", "Baseline's IQM, % [CI]"]
    return md_table(["Method", "Over", "P(improvement) [CI]", *iqm, "Tasks"],
                    [_improvement_row(agg.scores.labels, a, b, pair) for (a, b), pair in agg.improvement.items()])


def _spans_tasks(s: Scores) -> bool:
    """Whether the methods are scored on different tasks (then their rows do not compare)."""
    return len(set(s.tasks.values())) > 1


def method_text(agg: Aggregates) -> str:
    """How the aggregates are made, in words."""
    s = agg.scores
    counts = sorted({len(t) for t in s.trials.values()})
    trials = " or ".join(str(n) for n in counts)
    return (
        "One number across tasks, as Agarwal et al. (NeurIPS 2021) recommend, with `rliable`'s statistics: each "
        "run's final policy scores its mean return over its held-out pool episodes divided by the expert's mean "
        "return on the same episodes (100% = the expert). The interquartile mean (IQM) and the mean pool every "
        f"task and trial ({trials} trials a task); the median is that of the per-task means, as rliable's. Intervals: "
        f"{CONFIDENCE:.0%} percentile intervals of a stratified bootstrap ({REPS} resamples of the runs within "
        f"each task, seed {SEED}). A method counts on the tasks where it has runs"
        + (f"; left out: {left_out_text(s.left_out)}." if s.left_out else ".")
        + (" The methods span different tasks (the Tasks column), so the rows do not compare with one another: "
           "the pairs below score two methods on the tasks both have." if _spans_tasks(s) else "")
    )


#: What the probability of improvement is, in words.
IMPROVEMENT_TEXT = ("the chance that a run of the first method scores above a run of the second on a task picked at "
                    "random (0.5: neither is better), over the tasks both have, with each method's IQM on those "
                    "tasks alone")
#: What the performance profiles' figure shows, in words.
PROFILES_TEXT = ("the share of runs (all tasks and trials) whose score exceeds each fraction of the expert, with its "
                 "bootstrap band; a curve above another is better everywhere. Right: the IQM with its interval")


def aggregate_markdown(agg: Aggregates, figure: str | None = None) -> str:
    """The "Across tasks" section of a study page: the method, the tables and the figure (``figure``: its
    link from the page)."""
    parts = [
        method_text(agg),
        "",
        _summary_table(agg),
        "",
        f"**Probability of improvement**: {IMPROVEMENT_TEXT}.",
        "",
        _improvement_table(agg),
        "",
        "**Per task**: the mean over trials of the scores pooled above.",
        "",
        per_task_markdown(agg.scores),
        "",
    ]
    if figure is not None:
        parts += [f"**Performance profiles** (left): {PROFILES_TEXT}.", "", f"![Across tasks]({figure})", ""]
    return "\n".join(parts)


class AcrossSection(NamedTuple):
    """The report's "Across tasks" section (short) and how its numbers are made (for "How to read")."""

    body: str
    notes: str


def short_markdown(agg: Aggregates, figure: str | None = None) -> str:
    """The report's "Across tasks" section: the tables with short heads, a sentence under each; how the
    numbers are made is :func:`method_text`."""
    s = agg.scores
    left_out = f" Left out: {left_out_text(s.left_out)}." if s.left_out else ""
    spans = (" The methods span different tasks, so compare them by the pairs, on the tasks both have."
             if _spans_tasks(s) else "")
    parts = [
        _summary_table(agg, short=True),
        "",
        _improvement_table(agg, short=True),
        "",
        f"% of the expert over every task and trial, with {CONFIDENCE:.0%} bootstrap intervals (rliable)."
        + left_out + spans + " P(improvement): the chance that a run of the method scores above a run of the "
        "baseline on a task both have (0.5: neither is better).",
        "",
        per_task_markdown(s, short=True),
        "",
        "Each task's mean % of the expert over its trials: the numbers pooled above.",
        "",
    ]
    if figure is not None:
        parts += [f"![Across tasks]({figure})", "",
                  "Left: the share of runs above each % of the expert (a curve above another is better everywhere); "
                  "right: the IQM with its interval.", ""]
    return "\n".join(parts)


def aggregate_csv(agg: Aggregates) -> str:
    """Every run's normalised score: method, task, trial, score (the figure's and the tables' input)."""
    lines = ["method,task,trial,score"]
    for m, matrix in agg.scores.by_method.items():
        for j, task in enumerate(agg.scores.tasks[m]):
            lines += [f"{m},{task},{t},{matrix[i, j]:.6g}" for i, t in enumerate(agg.scores.trials[m])]
    return "\n".join(lines) + "\n"


def plot_aggregate(agg: Aggregates, path: PathLike) -> Path:
    """Performance profiles and the IQM per method, side by side."""
    from cmzdril_lab.report.figures import COLORS, new_figure, save_png

    fig = new_figure(11.0, 4.0)
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 2]})
    methods = list(agg.scores.by_method)
    # The grid's methods keep their colours; a study's other learners take colours none of them uses.
    spare = iter(c for c in ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "black")
                 if c not in COLORS.values())
    colors = {m: COLORS[m] if m in COLORS else next(spare, None) for m in methods}
    most = max(len(agg.scores.tasks[m]) for m in methods)
    # A method on fewer tasks than the others is not comparable at a glance: its label says so.
    tasks = {m: len(agg.scores.tasks[m]) for m in methods}
    names = {m: agg.scores.labels[m] + ("" if tasks[m] == most else f" ({tasks[m]} tasks)") for m in methods}
    for m in methods:
        profile, low, high = agg.profiles[m]
        left.plot(100 * PROFILE_TAUS, profile, label=names[m], color=colors[m])
        left.fill_between(100 * PROFILE_TAUS, low, high, color=colors[m], alpha=0.2)
    left.set_xlabel("normalised score τ (% of expert)")
    left.set_ylabel("share of runs with score > τ")
    left.set_ylim(0, 1.02)
    left.legend(loc="lower left", fontsize=8)
    for y, m in enumerate(methods):
        iqm, iqm_low, iqm_high = agg.summary[m]["IQM"]
        right.barh(y, 100 * (iqm_high - iqm_low), left=100 * iqm_low, height=0.6, alpha=0.4, color=colors[m])
        right.plot([100 * iqm] * 2, [y - 0.3, y + 0.3], color="black")
    right.set_yticks(range(len(methods)), [names[m] for m in methods])
    right.set_xlabel("IQM, % of expert (95% CI)")
    return save_png(fig, path)


def write_aggregate(rows: Sequence[FinalRow], out: PathLike, figures: bool = True) -> AcrossSection | None:
    """Write :data:`CSV` (and :data:`FIGURE`) into ``out``; returns the report's section and its notes, or
    None when no task has final evaluations on common trials with a positive expert mean (nothing written)."""
    scores = score_matrix(rows)
    if scores is None:
        return None
    agg = aggregate(scores)
    out = Path(out)
    atomic_write_text(out / CSV, aggregate_csv(agg))
    figure = plot_aggregate(agg, out / FIGURE).name if figures else None
    notes = (f"{method_text(agg)} Probability of improvement: {IMPROVEMENT_TEXT}. Performance profiles (the "
             f"figure's left): {PROFILES_TEXT}.")
    return AcrossSection(short_markdown(agg, figure), notes)
