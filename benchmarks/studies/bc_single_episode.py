"""Behaviour cloning from one episode: holding out a fifth of it against refitting on all of it.

    python benchmarks/studies/bc_single_episode.py [--output docs/bc_single_episode.md] [--force]

BC pretraining early-stops on a random fifth of the demo steps and keeps the best held-out epoch's
weights. From a single demonstration those held-out steps are neighbours of training steps on the
same trajectory, and they are a fifth of the only episode. ``CMZDRIL(bc_refit=True)`` keeps the
split to choose the number of epochs, then trains that many epochs afresh on every step. This script
pairs the two, trial by trial (same seed: same demo episode, same held-out episodes), from the BC
runs of ``benchmarks/studies/tune.py`` named in :data:`PAIRS`, and writes a markdown page: each
run's final-evaluation return over its held-out pool episodes, % of the expert on those episodes,
and the paired difference with its bootstrap interval. Nothing is trained here.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from cmzdril_lab.report.final_eval import final_table, find, mean_ci, paired
from cmzdril_lab.report.formatting import fmt, fmt_ci, md_table
from cmzdril_lab.report.records import load_runs
from sb3_cmzdril.io import atomic_write_text

ROOT = Path(__file__).resolve().parents[2]
TUNE = "python benchmarks/studies/tune.py"
#: (what, env, refit runs, reference runs, the commands that made them)
PAIRS: tuple[tuple[str, str, str, str, tuple[str, ...]], ...] = (
    (
        "Walker2d-v5, a pool of the RL Zoo's TQC agent (results/pools/tqc)",
        "Walker2d-v5",
        "results/tuning/W-tqc-bc-refit",
        "results/tuning/W-tqc-bc",
        (
            f"{TUNE} W-tqc-bc -- --env Walker2d-v5 --demos results/pools/tqc --methods bc --trials 10 --workers 2",
            f"{TUNE} W-tqc-bc-refit --set bc_refit=true -- --env Walker2d-v5 --demos results/pools/tqc "
            "--methods bc --trials 10 --workers 2",
        ),
    ),
    (
        "Walker2d-v5, the shipped pool (the RL Zoo's SAC agent)",
        "Walker2d-v5",
        "results/tuning/W-bc-refit",
        "results/runs",
        (f"{TUNE} W-bc-refit --set bc_refit=true -- --env Walker2d-v5 --methods bc --trials 5 --workers 2",
         "the published grid (results/runs)"),
    ),
    (
        "HalfCheetah-v5, the shipped pool",
        "HalfCheetah-v5",
        "results/tuning/HC-Hopper-bc-refit",
        "results/runs",
        (f"{TUNE} HC-Hopper-bc-refit --set bc_refit=true -- --env HalfCheetah-v5,Hopper-v5 --methods bc "
         "--trials 5 --workers 2", "the published grid (results/runs)"),
    ),
    (
        "Hopper-v5, the shipped pool",
        "Hopper-v5",
        "results/tuning/HC-Hopper-bc-refit",
        "results/runs",
        (f"{TUNE} HC-Hopper-bc-refit (above)", "the published grid (results/runs)"),
    ),
)


def section(what: str, env: str, refit_dir: str, reference_dir: str, commands: tuple[str, ...]) -> list[str]:
    if not (ROOT / refit_dir).is_dir() or not (ROOT / reference_dir).is_dir():
        return [f"## {what}", "", f"Not run yet: {' ; '.join(commands)}", ""]
    refit = find(final_table(load_runs(ROOT / refit_dir)), env, "bc")
    reference = find(final_table(load_runs(ROOT / reference_dir)), env, "bc")
    if refit is None or reference is None:
        return [f"## {what}", "", f"Not run yet: {' ; '.join(commands)}", ""]
    pair = paired(refit, reference)
    assert pair is not None
    ours, theirs = refit.per_trial("return"), reference.per_trial("return")
    pct_ours, pct_theirs = refit.per_trial("pct_of_expert"), reference.per_trial("pct_of_expert")
    rows = [[str(t), fmt(theirs[t]), fmt(ours[t]), fmt(pct_theirs[t]), fmt(pct_ours[t])] for t in pair.trials]
    parts = [
        f"## {what}",
        "",
        md_table(["Trial", "Hold-out (defaults)", "Refit", "% of expert, hold-out", "% of expert, refit"], rows),
        "",
        f"Refit above the hold-out in {pair.wins_text()} trials; refit minus hold-out, mean [95% CI]: "
        f"{fmt_ci(*mean_ci(pair.diffs))}. Mean return over those trials: hold-out "
        f"{fmt(sum(theirs[t] for t in pair.trials) / len(pair.trials))}, refit "
        f"{fmt(sum(ours[t] for t in pair.trials) / len(pair.trials))}.",
        "",
        f"Runs: `{refit_dir}` (refit) and `{reference_dir}` (hold-out). Made by:",
        "",
        *(f"    {c}" for c in commands),
        "",
    ]
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "bc_single_episode.md")
    parser.add_argument("--force", action="store_true", help="replace an existing output")
    args = parser.parse_args()
    if args.output.exists() and not args.force:
        parser.error(f"{args.output} exists; pass --force to replace it")
    text = [
        "# Behaviour cloning from one episode",
        "",
        f"Written by `python benchmarks/studies/bc_single_episode.py --force` on {time.strftime('%Y-%m-%d %H:%M %Z')} "
        "from the runs named under each table; no number is typed in.",
        "",
        "BC pretraining holds out a random fifth of the demo steps, stops when their NLL has not improved for 20 "
        "epochs and keeps the best epoch's weights (the defaults). With `bc_refit=True` the same split only "
        "chooses the number of epochs; the policy then learns that many epochs afresh on every step. Each row "
        "is one trial: the same demonstration episode and the same held-out pool episodes for both; the "
        "return is the final evaluation's mean over every held-out pool episode.",
        "",
    ]
    for pair in PAIRS:
        text += section(*pair)
    atomic_write_text(args.output, "\n".join(text))
    print(args.output)


if __name__ == "__main__":
    main()
