"""The final-evaluation table: every run's policy replayed on all its held-out pool episodes.

Five evaluation episodes per epoch cannot tell methods apart on HalfCheetah (one BC policy scored 188
on one machine and 242 on another), so each run ends with an evaluation on every pool episode not
used for training (final_eval.csv, written by :mod:`sb3_cmzdril.training.runs`). Here:

* :func:`final_table` — per env, method and policy ("final", or "lowest_u": the policy whose own
  training rollout had the lowest ensemble disagreement), the mean over trials of each run's mean
  over its held-out episodes, with a bootstrap confidence interval over trials (:func:`mean_ci`).
* the share of held-out episodes a policy completes at expert level (:data:`EXPERT_LEVEL`): on
  HalfCheetah-v5 an episode either runs near the expert's return or fails outright (the cheetah
  flips), so a run's mean return mostly says how often it fails, and this column says it directly.
* "% of expert" (:func:`expert_percent`): a run's mean return as a percentage of the expert's mean
  return on the same held-out episodes, so that envs with returns of different scales compare.
* :func:`paired` — a method against a baseline trial by trial (same seed, so the same demo split and
  the same held-out episodes): in how many trials it is higher, and the mean difference with its CI.
"""
from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cmzdril_lab.report.formatting import fmt_ci, md_table
from cmzdril_lab.report.records import METHOD_ORDER, POLICIES, RunRecord, env_key, group, label, result_policy
from sb3_cmzdril.training.methods import METHOD_REGISTRY

#: Final-evaluation metrics: (final_eval.csv column, table header).
FINAL_METRICS: tuple[tuple[str, str], ...] = (
    ("return", "Return"),
    ("pct_of_expert", "% of expert"),
    ("frechet", "Fréchet distance"),
    ("action_mse", "Action MSE"),
    ("expert_level", "Episodes at expert level"),
)
#: An episode is "at expert level" when its return is at least this fraction of the expert's return on
#: the same episode (same reset seed). Undefined (nan) for a run whose expert returns are not all
#: positive: a fraction of a negative return does not order episodes.
EXPERT_LEVEL = 0.5
CONFIDENCE = 0.95
#: The bootstrap's seed: the same runs give the same intervals on every report.
BOOTSTRAP_SEED = 0
BOOTSTRAP_RESAMPLES = 9999
#: Percentile rather than BCa: BCa's acceleration estimate is unstable with 5 values and undefined
#: when they are all equal (scipy returns nan); the percentile interval is neither.
BOOTSTRAP_METHOD = "percentile"
#: Fewer trials than this: the mean and no interval (2 values give a bootstrap of 3 distinct means).
MIN_TRIALS_FOR_CI = 3


def mean_ci(values: Sequence[float]) -> tuple[float, float, float]:
    """(mean, low, high): the mean of ``values`` and its :data:`CONFIDENCE` bootstrap interval
    (``scipy.stats.bootstrap``, :data:`BOOTSTRAP_METHOD`, seeded with :data:`BOOTSTRAP_SEED`);
    low and high are nan with fewer than :data:`MIN_TRIALS_FOR_CI` values or a non-finite one."""
    array = np.asarray(values, dtype=np.float64)
    mean = float(np.mean(array)) if array.size else math.nan
    if array.size < MIN_TRIALS_FOR_CI or not np.isfinite(array).all():
        return mean, math.nan, math.nan
    from scipy.stats import bootstrap

    result = bootstrap((array,), np.mean, confidence_level=CONFIDENCE, n_resamples=BOOTSTRAP_RESAMPLES,
                       method=BOOTSTRAP_METHOD, random_state=BOOTSTRAP_SEED)
    return mean, float(result.confidence_interval.low), float(result.confidence_interval.high)


@dataclasses.dataclass
class FinalRow:
    """One (env, method, policy) of the final-evaluation table."""

    env: str
    method: str
    policy: str  #: "final" or "lowest_u"
    runs: list[RunRecord]  #: the runs whose final_eval.csv has this policy

    @property
    def n_trials(self) -> int:
        return len(self.runs)

    @property
    def label(self) -> str:
        return label(self.method, self.policy)

    def per_run(self, column: str) -> list[float]:
        """Each run's mean of ``column`` over its held-out episodes, in run order; for a name in
        :data:`PER_RUN_METRICS` (``expert_level``, ``pct_of_expert``), its function of the run's episodes."""
        if column in PER_RUN_METRICS:
            return [PER_RUN_METRICS[column](r.final[self.policy]) for r in self.runs]
        return [float(np.mean(r.final[self.policy][column])) for r in self.runs]

    def per_trial(self, column: str = "return") -> dict[int, float]:
        return dict(zip([r.trial for r in self.runs], self.per_run(column), strict=True))

    def episodes(self) -> list[int]:
        """Each run's number of held-out episodes."""
        return [int(r.final[self.policy]["episode"].size) for r in self.runs]

    def stat(self, column: str = "return") -> tuple[float, float, float]:
        """(mean over trials, CI low, CI high) of :meth:`per_run`."""
        return mean_ci(self.per_run(column))

    def selected_epochs(self) -> list[int | None]:
        """The epoch of each run's lowest-u policy (done.json), None where it is not recorded."""
        chosen = [r.summary.get("final_evaluation", {}).get(self.policy, {}).get("epoch") for r in self.runs]
        return [None if e is None else int(e) for e in chosen]


def _positive_expert(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """The run's expert returns, or None unless there are some and all are positive: a fraction of
    a negative (or zero) return neither orders episodes nor scales a mean."""
    expert = np.asarray(columns["expert_return"], dtype=np.float64)
    return expert if expert.size and (expert > 0).all() else None


def expert_level_share(columns: dict[str, np.ndarray]) -> float:
    """The share of a run's held-out episodes whose return is at least :data:`EXPERT_LEVEL` times the
    expert's on the same episode; nan unless every expert return is positive."""
    expert = _positive_expert(columns)
    if expert is None:
        return math.nan
    return float(np.mean(np.asarray(columns["return"], dtype=np.float64) >= EXPERT_LEVEL * expert))


def expert_percent(columns: dict[str, np.ndarray]) -> float:
    """100 * the run's mean return / the expert's mean return over the same held-out episodes; nan
    unless the expert's mean is positive.

    A ratio of means, not a mean of per-episode ratios: one failed episode against a small expert
    return must not outweigh the rest, and it is the return table's number on the expert's scale. So
    only the mean sets the scale, and an expert that falls now and then (LunarLander's crashes,
    BipedalWalkerHardcore's falls) still has one; the across-task aggregate scores runs by this number.
    """
    expert = np.asarray(columns["expert_return"], dtype=np.float64)
    if not (expert.size and np.mean(expert) > 0):
        return math.nan
    return float(100 * np.mean(np.asarray(columns["return"], dtype=np.float64)) / np.mean(expert))


#: Final-evaluation metrics computed from a run's episodes as a whole rather than averaged column-wise.
PER_RUN_METRICS: dict[str, Callable[[dict[str, np.ndarray]], float]] = {
    "expert_level": expert_level_share,
    "pct_of_expert": expert_percent,
}


def final_table(records: Sequence[RunRecord]) -> list[FinalRow]:
    """The rows, env by env: every method's final policy, then the lowest-u policies."""
    groups = group(r for r in records if r.final)
    rows = []
    for env in sorted({env for env, _ in groups}, key=env_key):
        for policy in POLICIES:
            for method in METHOD_ORDER:
                runs = [r for r in groups.get((env, method), []) if policy in r.final]
                if runs:
                    rows.append(FinalRow(env, method, policy, runs))
    return rows


def find(rows: Sequence[FinalRow], env: str, method: str, policy: str = "final") -> FinalRow | None:
    return next((r for r in rows if (r.env, r.method, r.policy) == (env, method, policy)), None)


@dataclasses.dataclass
class Paired:
    """``row`` against ``baseline`` on the trials both have: differences of one metric, row minus baseline."""

    trials: list[int]
    diffs: list[float]

    @property
    def wins(self) -> int:
        return int(sum(d > 0 for d in self.diffs))

    def wins_text(self) -> str:
        return f"{self.wins} of {len(self.trials)}" if self.trials else "n/a"


def paired(row: FinalRow, baseline: FinalRow | None, column: str = "return") -> Paired | None:
    """None without a baseline; else the differences of ``column`` (a :meth:`FinalRow.per_run` name;
    mean return by default) on the trials both ran."""
    if baseline is None:
        return None
    mine, theirs = row.per_trial(column), baseline.per_trial(column)
    trials = sorted(set(mine) & set(theirs))
    return Paired(trials, [mine[t] - theirs[t] for t in trials])


#: CMZ-DRIL's methods and their ablations without reward: the same learner, everything but the reward
#: (from the registry of methods: "cmz" -> "zero", "cmz-sac" -> "zero-sac").
NO_REWARD_ABLATION: dict[str, str] = {
    m.name: a.name
    for m in METHOD_REGISTRY.values() if m.reward == "cmz"
    for a in METHOD_REGISTRY.values() if a.learner == m.learner and a.reward == "zero" and not a.pretrain_only
}


def baselines(rows: Sequence[FinalRow], row: FinalRow) -> tuple[FinalRow | None, FinalRow | None]:
    """(BC, no reward) to compare ``row`` with: BC's policy for every RL row; for CMZ-DRIL's methods,
    the same learner with no reward (the same policy choice, so the selection is compared like with like)."""
    bc = find(rows, row.env, "bc") if row.method != "bc" else None
    ablation = NO_REWARD_ABLATION.get(row.method)
    zero = find(rows, row.env, ablation, row.policy) if ablation is not None else None
    return bc, zero


def _diff_cell(p: Paired | None) -> tuple[str, str]:
    if p is None:
        return "—", "—"
    return p.wins_text(), fmt_ci(*mean_ci(p.diffs))


def final_markdown(rows: Sequence[FinalRow]) -> str:
    """The table: mean [CI] over trials of each run's mean over its held-out episodes."""
    body = []
    for r in rows:
        counts = sorted(set(r.episodes()))
        body.append([r.env, r.label, str(r.n_trials), " or ".join(map(str, counts)),
                     *(fmt_ci(*r.stat(c)) for c, _ in FINAL_METRICS), fmt_ci(*r.stat("expert_return"))])
    return md_table(["Env", "Method", "Trials", "Episodes per trial", *(h for _, h in FINAL_METRICS),
                     "Expert return (same episodes)"], body)


def paired_markdown(rows: Sequence[FinalRow]) -> str:
    """Each RL row against BC and (CMZ-DRIL's methods) against no reward, trial by trial."""
    body = []
    for r in rows:
        if r.method == "bc":
            continue
        bc, zero = baselines(rows, r)
        epochs = ", ".join("?" if e is None else str(e) for e in r.selected_epochs()) if r.policy != "final" else "—"
        pct = paired(r, bc, "pct_of_expert")
        body.append([r.env, r.label, *_diff_cell(paired(r, bc)), "—" if pct is None else fmt_ci(*mean_ci(pct.diffs)),
                     *_diff_cell(paired(r, zero)), epochs])
    return md_table(["Env", "Method", "Above BC (trials)", "Return − BC, mean [CI]", "% of expert − BC, mean [CI]",
                     "Above no reward (trials)", "Return − no reward, mean [CI]", "Selected epoch per trial"], body)


def _with_trials(text: str, n: int, varies: bool) -> str:
    """A cell, with its number of trials where the table's cells differ in it."""
    return f"{text}, n={n}" if varies else text


def _row_order(rows: Sequence[FinalRow]) -> list[tuple[str, str]]:
    """(method, policy) of ``rows``, each once: every method's result (:func:`result_policy`) first,
    then its other policies, each group in the methods' order."""
    pairs = {(r.method, r.policy) for r in rows}
    results = [(m, result_policy(m)) for m in METHOD_ORDER if (m, result_policy(m)) in pairs]
    others = [(m, p) for p in POLICIES for m in METHOD_ORDER if (m, p) in pairs and p != result_policy(m)]
    return results + others


def final_wide_markdown(rows: Sequence[FinalRow], column: str = "return") -> str:
    """The final evaluation's ``column`` in the paper's layout: one row per method and policy, one column
    per env, each cell the mean over trials [CI] (with the trials where cells differ in them); then the
    expert's mean return on the same episodes (with ``column`` "return")."""
    envs = sorted({r.env for r in rows}, key=env_key)
    varies = len({r.n_trials for r in rows}) > 1
    body = []
    for method, policy in _row_order(rows):
        cells = []
        for env in envs:
            row = find(rows, env, method, policy)
            cells.append("—" if row is None else _with_trials(fmt_ci(*row.stat(column)), row.n_trials, varies))
        body.append([label(method, policy), *cells])
    if column == "return":
        experts = expert_by_env(rows)
        body.append(["Expert (held-out demos)",
                     *(_with_trials(fmt_ci(*experts[e][:3]), experts[e][3], varies) if e in experts else "—"
                       for e in envs)])
    return md_table(["Method", *envs], body)


def _comparisons(rows: Sequence[FinalRow]) -> list[tuple[FinalRow, FinalRow]]:
    """(row, baseline) of every paired comparison: each RL row against BC, then CMZ-DRIL's methods
    against their learner without reward (:func:`baselines`)."""
    against_bc, against_zero = [], []
    for r in rows:
        if r.method == "bc":
            continue
        bc, zero = baselines(rows, r)
        if bc is not None:
            against_bc.append((r, bc))
        if zero is not None:
            against_zero.append((r, zero))
    return against_bc + against_zero


def headline_policy(method: str, policy: str) -> bool:
    """Whether a policy is one the headline shows: a method's result (:func:`result_policy`) or
    CMZ-DRIL's lowest-u policy."""
    return policy == result_policy(method) or (method, policy) == ("cmz", "lowest_u")


def wins_markdown(rows: Sequence[FinalRow]) -> str:
    """In how many trials each policy the headline shows (:func:`headline_policy`) has a mean return above
    its baseline's, one row per (policy, baseline), one column per env; the other policies' comparisons
    are in :func:`paired_csv`."""
    envs = sorted({r.env for r in rows}, key=env_key)
    cells: dict[tuple[str, str], dict[str, str]] = {}
    for row, base in _comparisons(rows):
        if not headline_policy(row.method, row.policy):
            continue
        comparison = paired(row, base)
        if comparison is not None:
            cells.setdefault((row.label, base.label), {})[row.env] = comparison.wins_text()
    order = {label(m, p): i for i, (m, p) in enumerate(_row_order(rows))}
    keys = sorted(cells, key=lambda k: (k[1] != label("bc"), order[k[0]]))  # against BC first
    return md_table(["Method", "Over", *envs], ([name, over, *(cells[(name, over)].get(e, "—") for e in envs)]
                                               for name, over in keys))


def paired_csv(rows: Sequence[FinalRow]) -> str:
    """Every paired comparison (:func:`wins_markdown`'s and more), full precision: the trials, in how
    many the policy is above its baseline, the mean difference of the return and of the % of the expert
    with their bootstrap CIs, and the epoch each trial's reward-free choice came from."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = ["env", "method", "policy", "baseline", "baseline_policy", "trials", "above"]
    for column in ("return", "pct_of_expert"):
        header += [f"{column}_diff_mean", f"{column}_diff_ci_low", f"{column}_diff_ci_high"]
    writer.writerow(header + ["selected_epochs"])
    for row, base in _comparisons(rows):
        comparison = paired(row, base)
        if comparison is None:
            continue
        values: list[Any] = [row.env, row.method, row.policy, base.method, base.policy,
                             ";".join(map(str, comparison.trials)), comparison.wins]
        for column in ("return", "pct_of_expert"):
            diffs = paired(row, base, column)
            values += [repr(v) for v in mean_ci(diffs.diffs if diffs is not None else [])]
        epochs = "" if row.policy == "final" else ";".join("" if e is None else str(e) for e in row.selected_epochs())
        writer.writerow(values + [epochs])
    return out.getvalue()


def final_csv(rows: Sequence[FinalRow], runs_dir: Path) -> str:
    """The table as CSV, full precision, with each run's own mean return and its folder."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    columns = [c for c, _ in FINAL_METRICS] + ["expert_return"]
    header = ["env", "method", "policy", "n_trials", "episodes_per_run"]
    for c in columns:
        header += [f"{c}_mean", f"{c}_ci_low", f"{c}_ci_high"]
    writer.writerow(header + ["return_per_run", "run_dirs"])
    for r in rows:
        values: list[Any] = [r.env, r.method, r.policy, r.n_trials, ";".join(map(str, r.episodes()))]
        for c in columns:
            values += [repr(v) for v in r.stat(c)]
        writer.writerow(values + [";".join(map(repr, r.per_run("return"))),
                                  ";".join(run.relative(runs_dir) for run in r.runs)])
    return out.getvalue()


def method_text(confidence: float = CONFIDENCE) -> str:
    """How the table's numbers are made, in words (for the report)."""
    return (
        f"Each run's policy replays every pool episode not used for training (the expert's start state; "
        f"final_eval.csv, one row per episode); a run's number is its mean over those episodes; the cell is "
        f"the mean over trials [{100 * confidence:g}% bootstrap confidence interval over trials: "
        f"scipy.stats.bootstrap, {BOOTSTRAP_METHOD}, {BOOTSTRAP_RESAMPLES} resamples, seed {BOOTSTRAP_SEED}; "
        f"n/a with fewer than {MIN_TRIALS_FOR_CI} trials]. \"(lowest u)\" is the policy whose own training "
        "rollout had the lowest ensemble disagreement, \"(longest episodes)\" the off-policy learner's policy "
        "whose deterministic episodes from fixed starts lasted longest (where the expert ends its episodes "
        "itself, as long as its demonstrations): both chosen without the env reward. "
        f"\"Episodes at expert level\": the share of a run's held-out episodes whose return is at least "
        f"{EXPERT_LEVEL:g} times the expert's on the same episode, n/a where the expert's returns are not all "
        "positive. \"% of expert\": 100 times a run's mean return over its mean expert return on the same "
        "episodes, n/a where that mean is not positive."
    )


def trials_text(rows: Sequence[FinalRow]) -> str:
    """e.g. "5" or "2-5": the trials per cell, for a heading."""
    counts = sorted({r.n_trials for r in rows})
    return str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"


def expert_by_env(rows: Sequence[FinalRow]) -> dict[str, tuple[float, float, float, int]]:
    """env -> (mean, CI low, CI high, trials) of each trial's mean expert return on its held-out
    episodes (final_eval.csv's expert_return; the same for every method of a trial: same split)."""
    per_env: dict[str, dict[int, float]] = {}
    for r in rows:
        if r.policy == "final":
            per_env.setdefault(r.env, {}).update(r.per_trial("expert_return"))
    return {env: (*mean_ci(list(v.values())), len(v)) for env, v in per_env.items()}


def fmt_cell(row: FinalRow | None, column: str = "return") -> str:
    """``mean [low, high], n=trials`` of ``column`` for a side-by-side table; ``—`` without the row."""
    return "—" if row is None else f"{fmt_ci(*row.stat(column))}, n={row.n_trials}"


__all__ = [
    "FinalRow",
    "Paired",
    "mean_ci",
    "final_table",
    "expert_level_share",
    "expert_percent",
    "PER_RUN_METRICS",
    "EXPERT_LEVEL",
    "paired",
    "baselines",
    "find",
    "final_markdown",
    "final_wide_markdown",
    "paired_markdown",
    "paired_csv",
    "wins_markdown",
    "headline_policy",
    "final_csv",
    "fmt_cell",
    "expert_by_env",
]
