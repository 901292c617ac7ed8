"""Do two runs folders of one learner evaluate alike wherever both have a checkpoint?

    python benchmarks/studies/same_checkpoints.py results/offpolicy/H-sac-64-clip98-abs \
        results/offpolicy/H-sac-64-clip98-abs-longest

For every trial folder (``<Env>/<method>/trial<k>``) present in both, it compares eval.csv's
``return_mean`` at the timesteps both runs evaluated and prints how many they share, whether all are
equal to the last digit, and where each run stopped. A choice made beside training (a callback with
its own env) must leave these equal; only the run's end may move.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path


def returns_by_step(path: Path) -> dict[str, str]:
    """eval.csv's return_mean by timesteps, as written (text: equal means equal to the last digit)."""
    with open(path, newline="", encoding="utf-8") as f:
        return {row["timesteps"]: row["return_mean"] for row in csv.DictReader(f)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("first", type=Path)
    parser.add_argument("second", type=Path)
    args = parser.parse_args(argv)
    for folder in (args.first, args.second):
        if not folder.is_dir():
            parser.error(f"no such runs folder: {folder}")
    trials = sorted(p.parent.relative_to(args.first) for p in args.first.rglob("eval.csv")
                    if (args.second / p.parent.relative_to(args.first) / "eval.csv").is_file())
    if not trials:
        parser.error("the two folders share no trial with an eval.csv")
    for trial in trials:
        a, b = (returns_by_step(root / trial / "eval.csv") for root in (args.first, args.second))
        shared = set(a) & set(b)
        same = all(a[step] == b[step] for step in shared)
        print(f"{trial}: {len(shared)} shared checkpoints, {'all equal' if same else 'NOT all equal'}; "
              f"last steps {max(map(int, a))} and {max(map(int, b))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
