"""The table of docs/one_default.md: the leading candidate for one default against the tuned entries.

CMZ-DRIL's final policy per task, % of the expert (the return on Pendulum-v1, whose returns are
negative), mean over trials 0-4 / 5-9: the published grid's tuned entries (on the untuned tasks, the
shipped default; on another expert's pools, the task's entry run on them), the candidate's runs
(``results/tuning/D6-*``), their paired difference over the trials both have, and BC on the candidate's
inputs. ``--check`` fails (exit 1) when the page's table is not what the records give.

    python benchmarks/studies/one_default.py           # rewrite the table in docs/one_default.md
    python benchmarks/studies/one_default.py --check
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cmzdril_lab.records_store import materialize_all
from cmzdril_lab.report.final_eval import FinalRow, final_table, find
from cmzdril_lab.report.records import load_runs

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "one_default.md"
BEGIN, END = "<!-- one default table: written by benchmarks/studies/one_default.py -->", "<!-- end of table -->"

#: (row label, env, its tuned entry's folders, the candidate's folder, BC's folder on the same inputs)
TASKS: tuple[tuple[str, str, tuple[str, ...], str, str], ...] = (
    *((env, env, ("runs", "runs_cmz_trials5-9"), "tuning/D6-norew", "runs")
      for env in ("Walker2d-v5", "Hopper-v5", "HalfCheetah-v5", "Swimmer-v5", "WaypointNav-v0")),
    ("LunarLander-v3", "LunarLander-v3", ("outside_env",), "tuning/D6-lunar", "tuning/D4-lunar"),
    *((env, env, ("untuned",), "tuning/D6-untuned", bc)
      for env, bc in (("MountainCarContinuous-v0", "tuning/D4-untuned"), ("Pendulum-v1", "tuning/D4-untuned"),
                      ("Ant-v5", "untuned"), ("BipedalWalker-v3", "tuning/D6-untuned"),
                      ("BipedalWalkerHardcore-v3", "tuning/D6-untuned"))),
    *((f"{env}, another expert (TQC)", env, ("tuning/E-tqc",), "tuning/D6-tqc", "tuning/D6-tqc")
      for env in ("Walker2d-v5", "Hopper-v5", "HalfCheetah-v5")),
)
#: the candidate's folders whose trials after 0-4 are a few runs for another study (docs/new_tasks.md), not a set
TRIALS_0_4_ONLY = ("tuning/D6-tqc",)
#: tasks scored by their return: a negative expert return makes no percentage
BY_RETURN = ("Pendulum-v1",)


def _row(folder: str, env: str, method: str) -> FinalRow | None:
    return find(final_table([r for r in load_runs(ROOT / "results" / folder) if r.env == env]), env, method)


def _per_trial(folders: tuple[str, ...], env: str, method: str, column: str) -> dict[int, float]:
    """Trial -> the final policy's value of ``column``, over ``folders`` (a later folder adds trials)."""
    values: dict[int, float] = {}
    for folder in folders:
        row = _row(folder, env, method)
        if row is not None:
            values.update(row.per_trial(column))
    return values


def _means(values: dict[int, float]) -> str:
    """'mean of trials 0-4 / mean of trials 5-9', each only where it has trials."""
    parts = [np.mean([v for t, v in values.items() if t in trials]) if set(values) & set(trials) else None
             for trials in (range(5), range(5, 10))]
    return " / ".join(f"{p:.1f}" if abs(p) < 1000 else f"{p:.0f}" for p in parts if p is not None)


def table() -> str:
    """The page's table, from the records."""
    materialize_all(ROOT / "results")
    lines = ["| Task | tuned entry | **D6** | paired, D6 - entry | BC |", "|---|---|---|---|---|"]
    for label, env, entry_folders, default_folder, bc_folder in TASKS:
        column = "return" if env in BY_RETURN else "pct_of_expert"
        entry = _per_trial(entry_folders, env, "cmz", column)
        default = {t: v for t, v in _per_trial((default_folder,), env, "cmz", column).items()
                   if t < 5 or default_folder not in TRIALS_0_4_ONLY}
        bc = {t: v for t, v in _per_trial((bc_folder,), env, "bc", column).items() if t < 5}
        shared = sorted(set(entry) & set(default))
        diffs = np.array([default[t] - entry[t] for t in shared])
        se = diffs.std(ddof=1) / np.sqrt(len(diffs)) if len(diffs) > 1 else float("nan")
        paired = (f"{diffs.mean():+.1f} (se {se:.1f}), higher in {int((diffs > 0).sum())} of {len(diffs)}"
                  if len(diffs) else "")
        name = f"{label} (return)" if env in BY_RETURN else label
        lines.append(f"| {name} | {_means(entry) or '—'} | **{_means(default)}** | {paired} | {_means(bc)} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail when the page's table is out of date")
    args = parser.parse_args(argv)
    text = PAGE.read_text(encoding="utf-8")
    head, rest = text.split(BEGIN + "\n")
    _, tail = rest.split(END)
    new = f"{head}{BEGIN}\n{table()}\n{END}{tail}"
    if args.check:
        if new != text:
            print(f"{PAGE} is out of date: run python benchmarks/studies/one_default.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(new, encoding="utf-8")
    print(PAGE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
