"""Table I and what sits beside it, computed from a grid's per-epoch records.

* :func:`table_one` — per env and method: mean (std over trials) of each run's evaluation return,
  Fréchet distance and action MSE averaged over its last 100 epochs (all of them if fewer; BC has
  one evaluation, at epoch 0). The std is the population std (numpy's ddof=0) over trials.
* :func:`gap_closed` — (cmz - zero) / (env - zero) per env and metric: how much of the gap between
  "no reward" and the true env reward CMZ-DRIL closes (the paper: about 50% for the reward).
* :func:`expert_returns` — per env, the true return of the expert's held-out episodes that each
  trial was evaluated against (from the demo pool named in the run's config.json): the scale.
* :func:`reward_signal` — per env and method, what the runs' SB3 progress logs say about the shaped
  reward: mean disagreement u over the first and last epochs, shaped reward and EMA, episode length.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cmzdril_lab.report.records import POLICIES, RunRecord, group, progress_rows
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.io import PathLike
from sb3_cmzdril.training.run_folder import TABLE_WINDOW, window_means

#: Table metrics: (key in window_means, column header, eval.csv column).
METRICS: tuple[tuple[str, str, str], ...] = (
    ("return", "Return", "return_mean"),
    ("frechet", "Fréchet distance", "frechet_mean"),
    ("action_mse", "Action MSE", "action_mse"),
)
#: the metrics of :data:`METRICS` where lower is better
LOWER_IS_BETTER = frozenset({"frechet", "action_mse"})


@dataclasses.dataclass
class TableRow:
    """One (env, method) cell group of Table I."""

    env: str
    method: str
    runs: list[RunRecord]
    per_run: dict[str, list[float]]  #: metric -> each run's window mean, in run order
    window: int

    @property
    def n_trials(self) -> int:
        return len(self.runs)

    def mean(self, metric: str) -> float:
        return float(np.mean(self.per_run[metric]))

    def std(self, metric: str) -> float:
        return float(np.std(self.per_run[metric]))  # population std over trials (ddof=0)


def table_one(records: Sequence[RunRecord], window: int = TABLE_WINDOW) -> list[TableRow]:
    """Table I rows, one per (env, method) present, in the report's order."""
    rows = []
    for (env, method), runs in group(records).items():
        means = [window_means(r.columns, window) for r in runs]
        per_run = {key: [m[key] for m in means] for key, _, _ in METRICS}
        rows.append(TableRow(env, method, runs, per_run, window))
    return rows


GAP_METHODS: tuple[str, ...] = ("cmz", "zero", "env")


def gap_trials(rows: Sequence[TableRow]) -> dict[str, list[int]]:
    """env -> the trials that CMZ-DRIL, no reward and env reward all have (the gap compares them paired)."""
    by = {(r.env, r.method): r for r in rows}
    result: dict[str, list[int]] = {}
    for env in dict.fromkeys(r.env for r in rows):
        sets = [{run.trial for run in by[(env, m)].runs} if (env, m) in by else set() for m in GAP_METHODS]
        result[env] = sorted(set.intersection(*sets))
    return result


def gap_closed(rows: Sequence[TableRow]) -> dict[str, dict[str, float | None]]:
    """env -> metric -> (cmz - zero) / (env - zero) over the trials all three have (:func:`gap_trials`):
    a grid still running must not divide one trial's env reward into five trials' means. None where no
    trial has all three or the env reward does no better than no reward (no gap to close: the ratio would
    divide by a difference of noise, or turn a gain into a loss)."""
    by = {(r.env, r.method): r for r in rows}
    result: dict[str, dict[str, float | None]] = {}
    for env, trials in gap_trials(rows).items():
        result[env] = {}
        for key, _, _ in METRICS:
            if not trials:
                result[env][key] = None
                continue
            cmz, zero, true = (_mean_over(by[(env, m)], key, trials) for m in GAP_METHODS)
            better = zero - true if key in LOWER_IS_BETTER else true - zero
            result[env][key] = (cmz - zero) / (true - zero) if better > 0 else None
    return result


def _mean_over(row: TableRow, metric: str, trials: Sequence[int]) -> float:
    """The row's metric averaged over the runs of the given trials."""
    return float(np.mean([v for run, v in zip(row.runs, row.per_run[metric], strict=True) if run.trial in trials]))


def table_csv(rows: Sequence[TableRow], runs_dir: Path) -> str:
    """Table I as CSV, full precision, with each number's run folders (relative to ``runs_dir``)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = ["env", "method", "n_trials", "window_epochs"]
    for key, _, _ in METRICS:
        header += [f"{key}_mean", f"{key}_std"]
    writer.writerow(header + ["run_dirs"])
    for r in rows:
        values: list[Any] = [r.env, r.method, r.n_trials, r.window]
        for key, _, _ in METRICS:
            values += [repr(r.mean(key)), repr(r.std(key))]
        writer.writerow(values + [";".join(run.relative(runs_dir) for run in r.runs)])
    return out.getvalue()


def per_run_csv(rows: Sequence[TableRow], runs_dir: Path) -> str:
    """One row per run behind Table I: its folder (relative to ``runs_dir``), status, the epochs it
    reached, its own Table I return (its window mean) and each final-evaluation policy's mean return
    with its number of held-out episodes (empty where it has none)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = ["env", "method", "trial", "run_dir", "status", "first_epoch", "last_epoch", "table1_return"]
    for policy in POLICIES:
        header += [f"{policy}_return", f"{policy}_episodes"]
    writer.writerow(header)
    for r in rows:
        for run, value in zip(r.runs, r.per_run["return"], strict=True):
            values: list[Any] = [r.env, r.method, run.trial, run.relative(runs_dir), run.status,
                                 int(run.columns["epoch"][0]), int(run.columns["epoch"][-1]), repr(value)]
            for policy in POLICIES:
                final = run.final.get(policy)
                values += ["", ""] if final is None else [repr(float(np.mean(final["return"]))), final["episode"].size]
            writer.writerow(values)
    return out.getvalue()


# -- the expert's scale -----------------------------------------------------------------------------------
def _demo_pool_candidates(record: RunRecord, runs_dir: Path) -> list[Path]:
    """Where a run's demo pool may be: the path it recorded, else experts/<EnvName>/demos.npz beside
    the working directory or the repository holding ``runs_dir`` (a fresh clone moves the path)."""
    tail = Path("experts") / record.env / "demos.npz"
    found = [Path(record.config["demos"])] if record.config.get("demos") else []
    return found + [Path.cwd() / tail] + [parent / tail for parent in runs_dir.resolve().parents]


def expert_returns(records: Sequence[RunRecord], runs_dir: PathLike) -> dict[str, tuple[float, float, int]]:
    """env -> (mean, std over trials, trials) of the mean true return of each trial's held-out expert
    episodes: the episodes its evaluations replay. Trials whose pool cannot be found, whose pool's
    sha256 differs from the one recorded, or whose pool has no rewards are left out."""
    root = Path(runs_dir)
    per_env: dict[str, dict[int, float]] = {}
    pools: dict[Path, tuple[str, Any]] = {}
    for r in records:
        episodes = r.config.get("eval_episodes")
        if not episodes or r.trial in per_env.get(r.env, {}):
            continue
        for candidate in _demo_pool_candidates(r, root):
            if not candidate.is_file():
                continue
            if candidate not in pools:
                digest = hashlib.sha256(candidate.read_bytes()).hexdigest()
                pools[candidate] = (digest, Demonstrations.load(candidate))
            digest, pool = pools[candidate]
            if r.config.get("demos_sha256") not in (None, digest) or pool.episode_returns is None:
                continue
            per_env.setdefault(r.env, {})[r.trial] = float(np.mean(pool.episode_returns[list(episodes)]))
            break
    return {env: (float(np.mean(list(v.values()))), float(np.std(list(v.values()))), len(v))
            for env, v in per_env.items()}


# -- the reward signal ------------------------------------------------------------------------------------
#: Columns of SB3's progress CSV that :func:`reward_signal` summarises.
SIGNAL_COLUMNS: tuple[tuple[str, str], ...] = (
    ("u", "rollout/disagreement_mean"),
    ("shaped", "rollout/shaped_reward_mean"),
    ("ubar", "rollout/ubar_mean"),
    ("ep_len", "rollout/ep_len_mean"),
)
#: Epochs averaged at the start and at the end of a run in :func:`reward_signal`.
SIGNAL_EPOCHS = 10


def _progress_log(record: RunRecord) -> dict[str, np.ndarray]:
    """The :data:`SIGNAL_COLUMNS` of the run's progress logs, every segment joined; {} without logs."""
    rows = progress_rows(record.path)
    columns: dict[str, np.ndarray] = {}
    for key, column in SIGNAL_COLUMNS:
        values = [float(row[column]) if row.get(column) else np.nan for row in rows]
        columns[key] = np.asarray(values, dtype=np.float64)
    return columns


def reward_signal(records: Sequence[RunRecord],
                  epochs: int = SIGNAL_EPOCHS) -> dict[tuple[str, str], dict[str, tuple[float, float]]]:
    """(env, method) -> {"u": (first, last), "shaped": (first, last), "ubar": ..., "ep_len": ...}: the
    mean over trials of each run's rollout statistics averaged over its first and last ``epochs``
    PPO updates. Runs without progress logs are left out; so is BC (it has no rollouts)."""
    result: dict[tuple[str, str], dict[str, tuple[float, float]]] = {}
    for (env, method), runs in group(r for r in records if r.method != "bc").items():
        logs = [log for log in map(_progress_log, runs) if log and log["u"].size]
        if not logs:
            continue
        cell: dict[str, tuple[float, float]] = {}
        for key, _ in SIGNAL_COLUMNS:
            first = [np.nanmean(log[key][:epochs]) for log in logs if np.isfinite(log[key][:epochs]).any()]
            last = [np.nanmean(log[key][-epochs:]) for log in logs if np.isfinite(log[key][-epochs:]).any()]
            cell[key] = (float(np.mean(first)) if first else math.nan, float(np.mean(last)) if last else math.nan)
        cell["trials"] = (float(len(logs)), float(len(logs)))
        result[(env, method)] = cell
    return result


__all__ = [
    "METRICS",
    "TableRow",
    "table_one",
    "gap_closed",
    "gap_trials",
    "table_csv",
    "per_run_csv",
    "expert_returns",
    "reward_signal",
    "SIGNAL_EPOCHS",
]
