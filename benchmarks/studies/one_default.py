"""The tables of docs/one_default.md and the README's headline: the default against the tuned entries.

CMZ-DRIL's final policy per task, % of the expert (the return on Pendulum-v1, whose returns are
negative), mean over trials 0-4 / 5-9 (/ 10-14 where run): the published grid's tuned entries (on the
untuned tasks, the shipped default; on another expert's pools, the task's entry run on them), the sixth
candidate's runs (``results/tuning/D6-*``), the thirteenth's and the fourteenth's, the fourteenth's paired
difference to the entry over the trials both have, and BC on the candidates' inputs. A rule's column takes,
per trial, the run of the candidate that decides as the rule does there (a seeded run goes on as the
decided value runs it), then the rule's own runs. The README's table: BC, DRIL and CMZ-DRIL on the
default (D14) beside CMZ-DRIL's tuned entries on the six tasks. ``--check`` fails (exit 1) when a table is
not what the records give.

    python benchmarks/studies/one_default.py           # rewrite the tables (docs/one_default.md, README.md)
    python benchmarks/studies/one_default.py --check
    python benchmarks/studies/one_default.py --grid results/default_grid  # the default's grid, for the report
"""
from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import gymnasium as gym
import numpy as np

import sb3_cmzdril  # noqa: F401  (registers WaypointNav-v0)
from cmzdril_lab.records_store import NOT_RECORDS, materialize_all
from cmzdril_lab.report.aggregate import Scores, aggregate
from cmzdril_lab.report.final_eval import FinalRow, final_table, find
from cmzdril_lab.report.records import load_runs
from sb3_cmzdril.common.bc import AUTO_EPOCHS_NLL, nll_per_action_entry

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "one_default.md"
BEGIN, END = "<!-- one default table: written by benchmarks/studies/one_default.py -->", "<!-- end of table -->"
README = ROOT / "README.md"
README_BEGIN = "<!-- default table: written by benchmarks/studies/one_default.py, do not edit by hand -->"
README_END = "<!-- end of default table -->"
#: the six tasks of the issue's across-task target (IQM over them, trials 0-4)
SIX = ("Walker2d-v5", "Hopper-v5", "HalfCheetah-v5", "Swimmer-v5", "WaypointNav-v0", "LunarLander-v3")

#: (row label, env, its tuned entry's folders, the sixth candidate's folder, the eleventh's folders (a later one
#: replaces an earlier one's trials), BC's folder on the same inputs); the twelfth's folder: :data:`QUARTER`
TASKS: tuple[tuple[str, str, tuple[str, ...], str, tuple[str, ...], str], ...] = (
    *((env, env, ("runs", "runs_cmz_trials5-9"), "tuning/D6-norew", d11, "runs")
      for env, d11 in (("Walker2d-v5", ("tuning/D6-norew",)), ("Hopper-v5", ("tuning/D6-norew",)),
                       ("HalfCheetah-v5", ("tuning/D11-epochs",)),
                       ("Swimmer-v5", ("tuning/D9-drift", "tuning/D11-epochs")),
                       ("WaypointNav-v0", ("tuning/D6-norew",)))),
    ("LunarLander-v3", "LunarLander-v3", ("outside_env", "outside_env_trials5-9", "outside_env_trials10-14"),
     "tuning/D6-lunar", ("tuning/D6-lunar",), "tuning/D4-lunar"),
    *((env, env, ("untuned",), "tuning/D6-untuned", d11, bc)
      for env, d11, bc in (("MountainCarContinuous-v0", ("tuning/D11-epochs",), "tuning/D4-untuned"),
                           ("Pendulum-v1", ("tuning/D6-untuned",), "tuning/D4-untuned"),
                           ("Ant-v5", ("tuning/D9-drift",), "untuned"),
                           ("BipedalWalker-v3", ("tuning/D6-untuned",), "tuning/D6-untuned"),
                           ("BipedalWalkerHardcore-v3", ("tuning/D6-untuned", "tuning/D10-untuned"),
                            "tuning/D6-untuned"))),
    *((f"{env}, another expert (TQC)", env, ("tuning/E-tqc",), "tuning/D6-tqc", d11, "tuning/D6-tqc")
      for env, d11 in (("Walker2d-v5", ("tuning/D6-tqc",)), ("Hopper-v5", ("tuning/D6-tqc", "tuning/D10-tqc")),
                       ("HalfCheetah-v5", ("tuning/D11-tqc",)))),
)
#: (row label, env, the runs with one NLL epoch after each update (D6's other settings; a later folder replaces an
#: earlier one's trials), the runs without (D6), what D11's rule decides there and why)
EPOCHS: tuple[tuple[str, str, tuple[str, ...], tuple[str, ...], str], ...] = (
    ("HalfCheetah-v5", "HalfCheetah-v5", ("tuning/D11-epochs",), ("tuning/D6-norew",), "on"),
    ("Swimmer-v5", "Swimmer-v5", ("tuning/D9-drift", "tuning/D11-epochs"), ("tuning/D6-norew",), "on"),
    ("Ant-v5", "Ant-v5", ("tuning/D9-drift",), ("tuning/D6-untuned",), "on"),
    ("MountainCarContinuous-v0", "MountainCarContinuous-v0", ("tuning/D11-epochs",), ("tuning/D6-untuned",), "on"),
    ("HalfCheetah-v5, another expert (TQC)", "HalfCheetah-v5", ("tuning/D11-tqc",), ("tuning/D6-tqc",), "on"),
    ("WaypointNav-v0", "WaypointNav-v0", ("tuning/D11-epochs",), ("tuning/D6-norew",), "off: actions on a bound"),
    ("LunarLander-v3", "LunarLander-v3", ("tuning/D11-lunar", "tuning/D13-lunar-epochs"), ("tuning/D6-lunar",),
     "off: actions on a bound"),
    ("BipedalWalker-v3", "BipedalWalker-v3", ("tuning/D11-epochs",), ("tuning/D6-untuned",),
     "off: actions on a bound"),
    ("BipedalWalkerHardcore-v3", "BipedalWalkerHardcore-v3", ("tuning/D11-epochs",),
     ("tuning/D6-untuned", "tuning/D10-untuned"), "off: actions on a bound"),
    ("Pendulum-v1", "Pendulum-v1", ("tuning/D11-epochs",), ("tuning/D6-untuned",), "off: actions on a bound"),
)
#: the twelfth candidate's runs (D6 with a quarter NLL epoch after each update), by EPOCHS row label
QUARTER = {"Ant-v5": "tuning/D12-quarter", "WaypointNav-v0": "tuning/D12-quarter"}
#: the thirteenth candidate's own runs (``bc_epochs_per_update: auto`` by the clone's held-out NLL), by row label:
#: the trials no earlier candidate's runs stand for
D13_RUNS = {"LunarLander-v3": ("tuning/D13-lunar",)}
#: the fourteenth candidate's (D14's) own runs, on trials no earlier run stands for: D13 where the expert ends its
#: own episodes before the env's time limit keeps the NLL epochs unless the clone falls
D14_RUNS = {"LunarLander-v3": ("tuning/D14-lunar",),
            **{label: ("tuning/D14-untuned",)
               for label in ("MountainCarContinuous-v0", "BipedalWalker-v3", "Pendulum-v1")}}
#: BC's runs on the trials after 0-4 that the fourteenth candidate's confirmation ran, by row label
BC_LATER = {"LunarLander-v3": ("outside_env_trials10-14",), **{label: folders for label, folders in D14_RUNS.items()
                                                                if label != "LunarLander-v3"}}
#: the candidates' folders whose trials after 0-4 are a few runs for another study (docs/new_tasks.md), not a set
TRIALS_0_4_ONLY = ("tuning/D6-tqc", "tuning/D10-tqc")
#: tasks scored by their return: a negative expert return makes no percentage
BY_RETURN = ("Pendulum-v1",)

V = TypeVar("V")


def _row(folder: str, env: str, method: str) -> FinalRow | None:
    return find(final_table([r for r in load_runs(ROOT / "results" / folder) if r.env == env]), env, method)


#: what a table reads of a row's runs, by trial: a metric of the final policy (:func:`_metric`) or the run folder
Pick = Callable[[FinalRow], dict[int, V]]


def _metric(column: str) -> Pick[float]:
    """Trial -> the final policy's value of ``column``."""
    return lambda row: row.per_trial(column)


def _run_folder(row: FinalRow) -> dict[int, Path]:
    """Trial -> the run's folder."""
    return {run.trial: run.path for run in row.runs}


def _values(folders: tuple[str, ...], env: str, method: str, pick: Pick[V]) -> dict[int, V]:
    """Trial -> what ``pick`` reads, over ``folders`` (a later folder adds trials)."""
    values: dict[int, V] = {}
    for folder in folders:
        row = _row(folder, env, method)
        if row is not None:
            values.update(pick(row))
    return values


def _per_trial(folders: tuple[str, ...], env: str, method: str, column: str) -> dict[int, float]:
    """Trial -> the final policy's value of ``column``, over ``folders`` (a later folder adds trials)."""
    return _values(folders, env, method, _metric(column))


def _means(values: dict[int, float]) -> str:
    """'mean of trials 0-4 / mean of trials 5-9 / mean of trials 10-14', each only where it has trials."""
    parts = [np.mean([v for t, v in values.items() if t in trials]) if set(values) & set(trials) else None
             for trials in (range(5), range(5, 10), range(10, 15))]
    return " / ".join(f"{p:.1f}" if abs(p) < 1000 else f"{p:.0f}" for p in parts if p is not None)


def _candidate(folders: tuple[str, ...], env: str, pick: Pick[V]) -> dict[int, V]:
    """Trial -> what ``pick`` reads of CMZ-DRIL's runs over a candidate's ``folders`` (a few-runs folder: trials
    0-4 only)."""
    values: dict[int, V] = {}
    for folder in folders:
        values.update({t: v for t, v in _values((folder,), env, "cmz", pick).items()
                       if t < 5 or folder not in TRIALS_0_4_ONLY})
    return values


def table() -> str:
    """The page's table and the six tasks' aggregate under it, from the records."""
    materialize_all(ROOT / "results")
    lines = ["| Task | tuned entry | D6 | D13 | **D14** | paired, D14 - entry | BC |", "|---|---|---|---|---|---|---|"]
    six: dict[str, list[list[float]]] = {"entry": [], "D6": [], "D13": [], "D14": [], "BC": []}
    for label, env, entry_folders, d6_folder, d11_folders, bc_folder in TASKS:
        column = "return" if env in BY_RETURN else "pct_of_expert"
        entry, pick = _per_trial(entry_folders, env, "cmz", column), _metric(column)
        d6 = _candidate((d6_folder,), env, pick)
        d13, d14 = _d13(label, env, pick, d11_folders), _d14(label, env, pick, d11_folders)
        bc = {t: v for t, v in _per_trial((bc_folder,), env, "bc", column).items() if t < 5}
        bc.update({t: v for t, v in _per_trial(BC_LATER.get(label, ()), env, "bc", column).items() if t >= 5})
        shared = sorted(set(entry) & set(d14))
        diffs = np.array([d14[t] - entry[t] for t in shared])
        se = diffs.std(ddof=1) / np.sqrt(len(diffs)) if len(diffs) > 1 else float("nan")
        paired = (f"{diffs.mean():+.1f} (se {se:.1f}), higher in {int((diffs > 0).sum())} of {len(diffs)}"
                  if len(diffs) else "")
        name = f"{label} (return)" if env in BY_RETURN else label
        lines.append(f"| {name} | {_means(entry) or '—'} | {_means(d6)} | {_means(d13)} | "
                     f"**{_means(d14)}** | {paired} | {_means(bc)} |")
        if label in SIX:
            for key, values in (("entry", entry), ("D6", d6), ("D13", d13), ("D14", d14), ("BC", bc)):
                six[key].append([values.get(t, float("nan")) / 100 for t in range(5)])
    return ("\n".join(lines) + "\n\n" + _six_tasks(six) + "\n\n" + _over_bc() + "\n\n" + _dril() + "\n\n" +
            _epochs())


def _held_out(folders: tuple[str, ...], env: str) -> dict[int, float]:
    """Trial -> the clone's NLL on the held-out demo steps per action entry (:func:`nll_per_action_entry`), as
    the first row of a run's log gives it (every run of a trial pretrains alike)."""
    values: dict[int, float] = {}
    for folder in folders:
        for run in sorted((ROOT / "results" / folder / env / "cmz").glob("trial*")):
            config = json.loads((run / "config.json").read_text(encoding="utf-8"))
            space = gym.make(env, **config.get("env_kwargs") or {}).action_space
            with (run / "logs" / "progress_0.csv").open(encoding="utf-8") as log:
                nll = nll_per_action_entry(float(next(csv.DictReader(log))["pretrain/bc_validation_nll"]), space)
            if nll is not None:
                values[int(run.name.removeprefix("trial"))] = nll
    return values


def _d13(label: str, env: str, pick: Pick[V], d11_folders: tuple[str, ...]) -> dict[int, V]:
    """Trial -> the thirteenth candidate's final policy. Where the clone falls (the tasks without an
    :data:`EPOCHS` row), no epochs: D11's runs. Elsewhere each trial's run with the epochs where the clone's
    held-out NLL per action entry is under :data:`AUTO_EPOCHS_NLL`, without them where it is not (the clones
    that fall there, BipedalWalkerHardcore-v3's trials 3-4, read as loose too); then :data:`D13_RUNS`, the
    rule's own runs."""
    row = next(((on, off) for name, _, on, off, _ in EPOCHS if name == label), None)
    if row is None:
        values = _candidate(d11_folders, env, pick)
    else:
        (on_folders, off_folders), values = row, {}
        on, off = _candidate(on_folders, env, pick), _candidate(off_folders, env, pick)
        for trial, nll in _held_out(on_folders + off_folders, env).items():
            runs = on if nll < AUTO_EPOCHS_NLL else off
            if trial in runs:
                values[trial] = runs[trial]
    values.update(_candidate(D13_RUNS.get(label, ()), env, pick))
    return values


def _ends(folders: tuple[str, ...], env: str) -> dict[int, bool]:
    """Trial -> whether the clone falls, on the trials where the expert ends its own episodes before the env's
    time limit, as the absorbing rule of a run of the trial recorded it (every run of a trial probes alike)."""
    ends: dict[int, bool] = {}
    for folder in folders:
        for run in sorted((ROOT / "results" / folder / env / "cmz").glob("trial*")):
            reason = json.loads((run / "config.json").read_text(encoding="utf-8")).get("rules", {}).get(
                "absorbing", {}).get("reason", "")
            if "demonstrations end before the env's time limit" in reason and "the env ends the clone's" in reason:
                ends[int(run.name.removeprefix("trial"))] = reason.endswith("the clone falls")
    return ends


def _decided(folder: str, env: str) -> dict[int, float]:
    """Trial -> the NLL epochs ``bc_epochs_per_update="auto"`` decided in the run's record."""
    decided: dict[int, float] = {}
    for run in sorted((ROOT / "results" / folder / env / "cmz").glob("trial*")):
        rule = json.loads((run / "config.json").read_text(encoding="utf-8")).get("rules", {}).get(
            "bc_epochs_per_update")
        if rule is not None:
            decided[int(run.name.removeprefix("trial"))] = rule["value"]
    return decided


def _d14(label: str, env: str, pick: Pick[V], d11_folders: tuple[str, ...]) -> dict[int, V]:
    """Trial -> the fourteenth candidate's final policy: D13's, but where the expert ends its own episodes
    before the env's time limit, the run with the NLL epochs unless the clone falls (D13's own runs count as
    runs with the epochs they decided); then :data:`D14_RUNS`, the rule's own runs."""
    values = _d13(label, env, pick, d11_folders)
    row = next(((on, off) for name, _, on, off, _ in EPOCHS if name == label), None)
    if row is not None:
        on_folders, off_folders = row
        on, off = _candidate(on_folders, env, pick), _candidate(off_folders, env, pick)
        for folder in D13_RUNS.get(label, ()):
            decided, runs = _decided(folder, env), _candidate((folder,), env, pick)
            for trial, value in runs.items():
                (on if decided.get(trial) else off).setdefault(trial, value)
        for trial, falls in _ends(on_folders + off_folders + D13_RUNS.get(label, ()), env).items():
            runs = off if falls else on
            if trial in runs:
                values[trial] = runs[trial]
    values.update(_candidate(D14_RUNS.get(label, ()), env, pick))
    return values


def _epochs() -> str:
    """No NLL epoch after each PPO update, a quarter of one (D12) and one, D6's other settings alike, what D13
    decides by the clone's held-out NLL and what D14 decides, trials 0-4 (over the trials the first and the third
    have)."""
    rows = ["| NLL epochs, trials 0-4 | none (D6) | a quarter (D12) | one | held-out NLL per action entry: "
            "D13's epochs | D13 | **D14** | D14 - the better of none and one, paired |",
            "|---|---|---|---|---|---|---|---|"]
    for label, env, on_folders, off_folders, _ in EPOCHS:
        column = "return" if env in BY_RETURN else "pct_of_expert"
        pick = _metric(column)
        on, off = (_candidate(folders, env, pick) for folders in (on_folders, off_folders))
        quarter = _candidate((QUARTER[label],), env, pick) if label in QUARTER else {}
        shared = [t for t in range(5) if t in on and t in off]
        nll = _held_out(on_folders + off_folders, env)
        d13, d14 = _d13(label, env, pick, ()), _d14(label, env, pick, ())
        better = on if np.mean([on[t] for t in shared]) > np.mean([off[t] for t in shared]) else off
        diffs = np.array([d14[t] - better[t] for t in shared])
        kept = sum(nll[t] < AUTO_EPOCHS_NLL for t in shared)
        name = f"{label} (return)" if env in BY_RETURN else label
        rows.append(
            f"| {name} | {_means({t: off[t] for t in shared})} | "
            f"{_means({t: quarter[t] for t in shared if t in quarter}) or '—'} | "
            f"{_means({t: on[t] for t in shared})} | "
            f"{min(nll[t] for t in shared):.2f} to {max(nll[t] for t in shared):.2f}: "
            f"{'on' if kept == len(shared) else 'off' if not kept else f'on in {kept} of {len(shared)}'} | "
            f"{_means({t: d13[t] for t in shared})} | **{_means({t: d14[t] for t in shared})}** | "
            f"{diffs.mean():+.1f} (se "
            f"{diffs.std(ddof=1) / np.sqrt(len(diffs)):.1f}) against {'one' if better is on else 'none'} |")
    return "\n".join(rows)


def _six_tasks(six: dict[str, list[list[float]]]) -> str:
    """IQM over :data:`SIX` (trials 0-4) of each column with every run in, and the lead candidate's (D14)
    probability of improvement over each other column."""
    matrices = {key: np.array(rows).T for key, rows in six.items()}  # (trials, tasks)
    missing = [k for k, m in matrices.items() if np.isnan(m).any()]
    matrices = {k: m for k, m in matrices.items() if k not in missing}
    lead = "D14"
    scores = Scores(trials={k: tuple(range(5)) for k in matrices}, tasks={k: SIX for k in matrices},
                    by_method=matrices, labels={k: k for k in matrices})
    agg = aggregate(scores, pairs=[(lead, k) for k in matrices if k != lead])
    keys = [k for k in ("entry", "D6", "D13", "D14", "BC") if k in matrices]
    names = {"entry": "tuned entry"}
    rows = ["| Across the six tasks (trials 0-4) | " + " | ".join(
        f"**{k}**" if k == lead else names.get(k, k) for k in keys) + " |", "|---" * (len(keys) + 1) + "|"]
    iqm = {k: agg.summary[k]["IQM"] for k in matrices}
    rows.append("| IQM, % of the expert [95% CI] | " + " | ".join(
        f"{'**' if k == lead else ''}{100 * p:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]{'**' if k == lead else ''}"
        for k, (p, lo, hi) in ((k, iqm[k]) for k in keys)) + " |")
    rows.append(f"| P({lead} > it) [95% CI] | " + " | ".join(
        "—" if k == lead else "{:.2f} [{:.2f}, {:.2f}]".format(*agg.improvement[(lead, k)].probability)
        for k in keys) + " |")
    if missing:
        rows.append(f"\n{', '.join(missing)}: not every run on the six tasks is in yet.")
    return "\n".join(rows)


#: DRIL on D14's settings, by the six tasks' row labels. DRIL keeps its own BC step (one NLL epoch after each
#: update): on Swimmer-v5 and LunarLander-v3 the rule kept it for every method, so trials 0-4 are D13's runs there
#: (the two decide alike), 5-9 D14's; elsewhere the runs made after the rule left DRIL its step
DRIL = {label: ("tuning/D14-lunar",) if label.startswith("Lunar") else
        ("tuning/D13-dril", "tuning/D14-dril") if label == "Swimmer-v5" else ("tuning/D14-dril-bc",) for label in SIX}
#: the same before the rule left DRIL its step: where it dropped the epochs for every method, DRIL ran without them
DRIL_NO_STEP = {label: ("tuning/D14-lunar",) if label.startswith("Lunar") else ("tuning/D13-dril", "tuning/D14-dril")
                for label in SIX}


def _dril() -> str:
    """DRIL against CMZ-DRIL on D14's settings, per task and across the six, trials 0-4 and 5-9 (each on the
    trials DRIL has on every task); then DRIL without its BC step where the rule dropped it."""
    tasks = [task for task in TASKS if task[0] in SIX]
    cmz = {label: _d14(label, env, _metric("pct_of_expert"), d11_folders)
           for label, env, _, _, d11_folders, _ in tasks}
    rows = ["| On D14's settings | trials | " + " | ".join(SIX) + " | IQM [95% CI] | P(CMZ-DRIL > DRIL) [95% CI] |",
            "|---" * (len(SIX) + 4) + "|"]
    for name, folders in (("DRIL", DRIL), ("DRIL, no BC step where the rule drops it", DRIL_NO_STEP)):
        dril = {label: _per_trial(folders[label], env, "dril", "pct_of_expert") for label, env, *_ in tasks}
        for block in (range(5), range(5, 10)):
            trials = tuple(t for t in block if all(t in values for values in dril.values()))
            if len(trials) < 2:
                rows.append(f"| {name} | {block.start}-{block.stop - 1}: not two trials on every task yet |")
                continue
            arrays = {key: np.array([[by_label[label][t] / 100 for label in SIX] for t in trials])
                      for key, by_label in (("CMZ-DRIL", cmz), (name, dril))}
            agg = aggregate(Scores(trials={k: trials for k in arrays}, tasks={k: SIX for k in arrays},
                                   by_method=arrays, labels={k: k for k in arrays}), pairs=[("CMZ-DRIL", name)])
            named = ", ".join(map(str, trials))
            for key, array in arrays.items():
                if key == "CMZ-DRIL" and name != "DRIL":
                    continue  # its row is above
                p, lo, hi = agg.summary[key]["IQM"]
                better = "{:.2f} [{:.2f}, {:.2f}]".format(*agg.improvement[("CMZ-DRIL", name)].probability)
                rows.append(f"| {key} | {named} | " + " | ".join(f"{100 * v:.1f}" for v in array.mean(axis=0)) +
                            f" | {100 * p:.1f} [{100 * lo:.1f}, {100 * hi:.1f}] | " +
                            (f"against DRIL: {better}" if key == "CMZ-DRIL" else
                             "" if name == "DRIL" else f"against it: {better}") + " |")
    return "\n".join(rows)


#: BC's runs of the confirmation trials 5-9 on the six tasks (inputs as D14 gives them)
BC_CONFIRM = {**{label: ("runs_bc_trials10",) for label in SIX if label != "LunarLander-v3"},
              "LunarLander-v3": ("outside_env_trials5-9",)}


def _bc(label: str, env: str, bc_folder: str) -> dict[int, float]:
    """Trial -> BC's final policy, % of the expert, on one of the six tasks: trials 0-4 from the candidates' BC
    folder, 5-9 from :data:`BC_CONFIRM`."""
    bc = {t: v for t, v in _per_trial((bc_folder,), env, "bc", "pct_of_expert").items() if t < 5}
    bc.update(_per_trial(BC_CONFIRM[label], env, "bc", "pct_of_expert"))
    return bc


def _over_bc() -> str:
    """D14's probability of improvement over BC on the six tasks where BC's mean over trials 0-4 stays under 90%
    of the expert, trials 0-4 and 5-9 (each over the trials every such task has)."""
    tasks = [task for task in TASKS if task[0] in SIX]
    cmz = {label: _d14(label, env, _metric("pct_of_expert"), d11_folders) for label, env, _, _, d11_folders, _ in tasks}
    bc = {label: _bc(label, env, bc_folder) for label, env, _, _, _, bc_folder in tasks}
    low = tuple(label for label in SIX if np.mean([v for t, v in bc[label].items() if t < 5]) < 90)
    parts = []
    for block in (range(5), range(5, 10)):
        trials = tuple(t for t in block if all(t in values[label] for values in (cmz, bc) for label in low))
        if len(trials) < 2:
            parts.append("—")
            continue
        arrays = {key: np.array([[values[label][t] / 100 for label in low] for t in trials])
                  for key, values in (("D14", cmz), ("BC", bc))}
        agg = aggregate(Scores(trials={k: trials for k in arrays}, tasks={k: low for k in arrays},
                               by_method=arrays, labels={k: k for k in arrays}), pairs=[("D14", "BC")])
        parts.append("{:.2f} [{:.2f}, {:.2f}]".format(*agg.improvement[("D14", "BC")].probability) +
                     _partial(trials, block))
    return (f"P(D14 > BC) [95% CI] where BC stays under 90% of the expert ({', '.join(low)}), trials 0-4 / 5-9: "
            f"{' / '.join(parts)}.")


def _iqm(by_label: dict[str, dict[int, float]], block: range) -> str:
    """The six tasks' IQM [95% CI] over the trials of ``block`` that every task has (named where not all)."""
    trials = tuple(t for t in block if all(t in by_label[label] for label in SIX))
    if len(trials) < 2:
        return "—"
    array = np.array([[by_label[label][t] / 100 for label in SIX] for t in trials])
    agg = aggregate(Scores(trials={"m": trials}, tasks={"m": SIX}, by_method={"m": array}, labels={"m": "m"}),
                    pairs=[])
    p, lo, hi = agg.summary["m"]["IQM"]
    return f"{100 * p:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]" + _partial(trials, block)


def _partial(trials: tuple[int, ...] | list[int], block: range) -> str:
    """' (trials 0, 1)' where ``trials`` are not all of ``block``, else ''."""
    return "" if len(trials) == len(block) else f" (trials {', '.join(map(str, trials))})"


def _block_means(values: dict[int, float]) -> str:
    """'mean of trials 0-4 / mean of trials 5-9', each only where it has trials, naming them where not all."""
    parts = []
    for block in (range(5), range(5, 10)):
        trials = [t for t in block if t in values]
        if trials:
            parts.append(f"{np.mean([values[t] for t in trials]):.1f}{_partial(trials, block)}")
    return " / ".join(parts) or "—"


def readme_table() -> str:
    """The README's headline: BC, DRIL and CMZ-DRIL on the default (D14) and CMZ-DRIL on its tuned entry, per
    task (mean over trials 0-4 / 5-9) and across the six."""
    columns: dict[str, dict[str, dict[int, float]]] = {"BC": {}, "DRIL": {}, "CMZ-DRIL": {},
                                                       "CMZ-DRIL, tuned entry": {}}
    for label, env, entry_folders, _, d11_folders, bc_folder in (task for task in TASKS if task[0] in SIX):
        columns["BC"][label] = _bc(label, env, bc_folder)
        columns["DRIL"][label] = _per_trial(DRIL[label], env, "dril", "pct_of_expert")
        columns["CMZ-DRIL"][label] = _d14(label, env, _metric("pct_of_expert"), d11_folders)
        columns["CMZ-DRIL, tuned entry"][label] = _per_trial(entry_folders, env, "cmz", "pct_of_expert")
    rows = ["| % of the expert, trials 0-4 / 5-9 | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    rows += [f"| {label} | " + " | ".join(_block_means(by_label[label]) for by_label in columns.values()) + " |"
             for label in SIX]
    rows += [f"| IQM, trials {block.start}-{block.stop - 1} [95% CI] | " +
             " | ".join(_iqm(by_label, block) for by_label in columns.values()) + " |"
             for block in (range(5), range(5, 10))]
    return "\n".join(rows)


#: PPO on the env's reward and with no reward on D14's settings, by the six tasks' row labels
BASELINES = {label: ("tuning/D14-lunar-baselines",) if label.startswith("Lunar") else ("tuning/D14-baselines",)
             for label in SIX}
#: the default grid's methods
GRID_METHODS = ("bc", "dril", "cmz", "env", "zero")


def grid_runs() -> dict[tuple[str, str, int], Path]:
    """(env, method, trial) -> the run folder of the default's grid on the six tasks, trials 0-4: BC on D14's
    inputs, DRIL (:data:`DRIL`), CMZ-DRIL (the runs D14 stands on, :func:`_d14`), and PPO on the env's reward
    and with no reward (:data:`BASELINES`)."""
    materialize_all(ROOT / "results")
    runs: dict[tuple[str, str, int], Path] = {}
    for label, env, _, _, d11_folders, bc_folder in (task for task in TASKS if task[0] in SIX):
        baselines = tuple(folder for folder in BASELINES[label] if (ROOT / "results" / folder).is_dir())
        by_method: dict[str, dict[int, Path]] = {
            "bc": _values((bc_folder,), env, "bc", _run_folder), "dril": _values(DRIL[label], env, "dril", _run_folder),
            "cmz": _d14(label, env, _run_folder, d11_folders)}
        by_method.update({method: _values(baselines, env, method, _run_folder) for method in ("env", "zero")})
        runs.update({(env, method, trial): folder for method, folders in by_method.items()
                     for trial, folder in folders.items() if trial < 5})
    return runs


def write_grid(out: Path, force: bool) -> int:
    """Copy the records of :func:`grid_runs` to ``out``/<env>/<method>/trial<t> (no models), for
    ``sb3-cmzdril report``. The folder is written whole or not at all; an existing one is replaced only with
    ``force``."""
    if out.exists() and not force:
        print(f"{out} exists; pass --force to replace it", file=sys.stderr)
        return 2
    staging = out.with_name(f".{out.name}.partial")
    shutil.rmtree(staging, ignore_errors=True)
    runs = grid_runs()
    missing = sorted({f"{env} {method}" for label, env, *_ in TASKS if label in SIX
                      for method in GRID_METHODS for trial in range(5)
                      if (env, method, trial) not in runs})
    if missing:
        print(f"not every trial 0-4 has a finished run yet: {', '.join(missing)}", file=sys.stderr)
    for (env, method, trial), folder in sorted(runs.items()):
        shutil.copytree(folder, staging / env / method / f"trial{trial}",
                        ignore=shutil.ignore_patterns(*NOT_RECORDS))
    if out.exists():
        shutil.rmtree(out)
    staging.rename(out)
    print(f"{out}: {len(runs)} runs")
    return 0


def _replace(text: str, begin: str, end: str, block: str) -> str:
    """``text`` with what stands between the lines ``begin`` and ``end`` replaced by ``block``."""
    head, rest = text.split(begin + "\n")
    _, tail = rest.split(end)
    return f"{head}{begin}\n{block}\n{end}{tail}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail when the page's table is out of date")
    parser.add_argument("--grid", type=Path, metavar="DIR",
                        help="instead, copy the default's grid (its runs' records) to DIR for sb3-cmzdril report")
    parser.add_argument("--force", action="store_true", help="with --grid: replace DIR")
    args = parser.parse_args(argv)
    if args.grid is not None:
        return write_grid(args.grid, args.force)
    pages = {PAGE: (BEGIN, END, table()), README: (README_BEGIN, README_END, readme_table())}
    stale = []
    for page, (begin, end, block) in pages.items():
        text = page.read_text(encoding="utf-8")
        new = _replace(text, begin, end, block)
        if new == text:
            continue
        stale.append(page)
        if not args.check:
            page.write_text(new, encoding="utf-8")
            print(page)
    if args.check and stale:
        print(f"{', '.join(map(str, stale))}: out of date; run python benchmarks/studies/one_default.py",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
