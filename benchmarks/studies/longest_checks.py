"""Which policy would each finished off-policy run have kept with the other tie break, or by another length?

    python benchmarks/studies/longest_checks.py FOLDER [FOLDER ...] [-o OUT]

The off-policy runs (`cmz-sac` and its comparisons) keep, as their result, the policy whose checks'
deterministic episodes lasted longest (``LongestEpisodesPolicy``); where checks tie in length, the
latest (``longest_tie_break: latest``, the default) or the one whose checks' states the ensemble
disagrees on least (``lowest_u``). Where the expert ends its episodes itself, runs with ``lowest_u`` keep
the check whose episodes last as long as the training demonstrations' on average (``episode_length:
expert``, the default with ``lowest_u``; done.json's ``target_length``); runs made at commit d75d34b4
kept the lowest u alone there (done.json's ``length_compared: false``). Every check's length and mean u
are in the run's done.json (in
its longest.pt, which the repository does not keep, for runs made before done.json had them), so
the choice either rule makes is known without training again (``selection.kept_check``, the rule the
runs apply). Its return is not: only the kept policy and the last weights get the final evaluation
on every held-out episode. This script reads the per-epoch evaluation instead (eval.csv: the policy
at the same step on the run's ``--eval-episodes`` held-out episodes, 5 in the grid), so its returns
for a policy the run did not keep are estimates on few episodes.

For every finished run folder under the FOLDERs with a longest-episodes choice: the checks (steps,
mean length, mean u, eval.csv's return at that step), the check each rule keeps (each tie break with
the longest episodes, the lowest u with no length compared, and the run's own rule where it aimed at
the expert's length), and the final evaluation's returns.
Then, per env and method, the runs where the two rules keep different policies. A run whose
recorded choice differs from the replayed one is an error (the replay would not be the runs' rule).

The repository's outputs, Pendulum-v1's off-policy runs with the package's `default` entry and with the entry
before it (docs/untuned/discussion.md):

    python benchmarks/studies/longest_checks.py results/untuned/Pendulum-v1 \\
        -o results/tuning/longest_checks_pendulum_auto_tie_u.txt
    python benchmarks/studies/longest_checks.py results/tuning/P-sac-default-before/Pendulum-v1 \\
        -o results/tuning/longest_checks_pendulum.txt

and the tasks nobody here tuned for whose expert ends its episodes, where the runs aim at its length:

    python benchmarks/studies/longest_checks.py results/untuned/BipedalWalker-v3 \\
        results/untuned/MountainCarContinuous-v0 results/tuning/BW-sac-auto-tie-u \\
        results/tuning/goal-tasks-u-alone -o results/tuning/longest_checks_goal_tasks.txt
"""
from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from sb3_cmzdril.io import read_json
from sb3_cmzdril.selection import TIE_BREAKS, LongestEpisodesPolicy, kept_check
from sb3_cmzdril.training.run_folder import DONE_FILE, LONGEST_FILE

#: The replayed rule that compares no lengths: the lowest u over every check.
U_ALONE = "u alone"
#: The rule of a run that kept the check closest to the expert's mean episode length (then the lowest u).
EXPERT_LENGTH = "expert length"


def recorded_checks(run: Path, config: dict, kept: dict) -> list[tuple[int, float, float]] | None:
    """The run's checks: from done.json's record of its choice (``kept``), or from its longest.pt where
    that record predates them; None where neither has them (the repository keeps no longest.pt)."""
    if "checks" in kept:  # written by jsonable: a NaN u as the string "nan"
        return [(int(steps), float(length), float(u)) for steps, length, u in kept["checks"]]
    env = gym.make(config["env_id"], **config.get("env_kwargs", {}))
    try:
        selector = LongestEpisodesPolicy(env)
        if not selector.load(run / LONGEST_FILE):
            return None
    finally:
        env.close()
    return selector.history


def replay(run: Path, record: dict) -> dict | None:
    """One run's checks, the check each tie break keeps, and its evaluations; None where its checks
    are not recorded. ``record``: done.json's entry of the run's longest-episodes choice."""
    config = read_json(run / "config.json")
    recorded = config["hyperparams_values"].get("longest_tie_break", "latest")
    checks = recorded_checks(run, config, record)
    if checks is None:
        return None
    kept = {rule: kept_check(checks, rule) for rule in TIE_BREAKS}
    # Every check as long as the others: the tie break alone chooses.
    kept[U_ALONE] = kept_check([(steps, 0.0, u) for steps, _, u in checks], "lowest_u")
    if record.get("length_compared") is False:  # commit d75d34b4's rule where the expert ends its episodes
        recorded = U_ALONE if recorded == "lowest_u" else recorded
    target = record.get("target_length")  # recorded since episode_length exists; None: the longest
    if target is not None:
        if recorded != "lowest_u":
            raise RuntimeError(f"{run}: aimed at the expert's length with the tie break {recorded!r}, which this "
                               "replays only with lowest_u")
        recorded = EXPERT_LENGTH
        kept[recorded] = kept_check(checks, "lowest_u", target_length=float(target))
    kept_steps = record["timesteps"]
    if checks[kept[recorded]][0] != kept_steps:
        raise RuntimeError(f"{run}: the run kept the check at {kept_steps} steps, the replay of {recorded!r} "
                           f"the one at {checks[kept[recorded]][0]}")
    evaluation = pd.read_csv(run / "eval.csv").set_index("timesteps")["return_mean"]
    final = pd.read_csv(run / "final_eval.csv").groupby("policy")["return"].mean()
    return {"env": config["env_id"], "method": config["method"], "trial": config["seed"],
            "runs_dir": str(run.parents[2]), "recorded": recorded,
            "checks": [(steps, length, u, float(evaluation.get(steps, np.nan))) for steps, length, u in checks],
            "kept": kept, "final": final.to_dict(), "episodes": int(config["n_eval_episodes"])}


def describe(run: Path, r: dict) -> list[str]:
    """The lines of one run."""
    checks = ", ".join(f"{steps}: {length:g} / {u:.3f} / {ret:.0f}" for steps, length, u, ret in r["checks"])
    lines = [f"{run} (trial {r['trial']}; the run's tie break: {r['recorded']})",
             f"  checks (steps: mean length / mean u / eval.csv return over {r['episodes']} episodes): {checks}"]
    for rule, index in r["kept"].items():
        steps, length, u, ret = r["checks"][index]
        lines.append(f"  {rule:>8}: keeps the check at {steps} steps (length {length:g}, u {u:.3f}, "
                     f"eval.csv {ret:.0f})")
    final = ", ".join(f"{name} {value:.0f}" for name, value in sorted(r["final"].items()))
    lines.append(f"  final evaluation (every held-out episode): {final}")
    return lines


def _trial_name(r: dict, with_folder: bool) -> str:
    return f"{r['trial']} in {r['runs_dir']}" if with_folder else str(r["trial"])


def summary(replays: list[dict]) -> list[str]:
    """Per env and method: the runs where two rules keep different policies (the two tie breaks with
    the longest episodes; the lowest u with the longest episodes and with u alone; and with the expert's
    length, for the runs that aimed at it)."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in replays:
        groups[(r["env"], r["method"])].append(r)
    lines = []
    for first, second in (("latest", "lowest_u"), ("lowest_u", U_ALONE), ("lowest_u", EXPERT_LENGTH)):
        lines += ["", f"Per env and method: runs, those whose two rules keep different checks, and there eval.csv's "
                      f"return of the check each keeps ({first} -> {second})"]
        for (env, method), runs in sorted(groups.items()):
            runs = sorted(runs, key=lambda r: r["trial"])
            runs = [r for r in runs if second in r["kept"]]
            if not runs:
                continue
            differ = [r for r in runs if r["kept"][first] != r["kept"][second]]
            # A group can pool runs of several folders (a task's runs and a study's): name the folder then.
            several = len({r["runs_dir"] for r in runs}) > 1
            returns = [(_trial_name(r, several), *(r["checks"][r["kept"][rule]][3] for rule in (first, second)))
                       for r in differ]
            detail = "; ".join(f"trial {name}: {one:.0f} -> {other:.0f}" for name, one, other in returns)
            trials = ", ".join(_trial_name(r, several) for r in runs)
            lines.append(f"{env} {method}: {len(runs)} runs (trials {trials}), {len(differ)} differ"
                         + (f": {detail}" if detail else ""))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path, help="folders searched for finished runs")
    parser.add_argument("-o", "--output", type=Path, help="also write the lines here")
    args = parser.parse_args(argv)
    records = {p.parent: read_json(p).get("final_evaluation", {}).get("longest")
               for folder in args.folders for p in folder.rglob(DONE_FILE)}
    runs = sorted(run for run, record in records.items() if record is not None)
    if not runs:
        parser.error(f"no finished run with a longest-episodes choice under {', '.join(map(str, args.folders))}")
    found = [(run, replay(run, records[run])) for run in runs]
    replays = [(run, r) for run, r in found if r is not None]
    unrecorded = [str(run) for run, r in found if r is None]
    lines = [line for run, r in replays for line in describe(run, r)] + summary([r for _, r in replays])
    if unrecorded:
        lines.append(f"Not recorded (made before done.json listed the checks, and no {LONGEST_FILE} here): "
                     + ", ".join(unrecorded))
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
