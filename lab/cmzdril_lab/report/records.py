"""What the report reads from a runs folder: each run's records, named and ordered for tables.

A grid's runs live in ``<RUNS_DIR>/<EnvName>/<method>/trial<t>/`` (see :mod:`sb3_cmzdril.training.run_folder`).
:func:`load_runs` reads, per run: eval.csv (the per-epoch evaluation), final_eval.csv when the run has
one (the final evaluation on every held-out pool episode; grids made before it existed have none),
config.json and done.json. A run is known by its config.json (env, method, trial seed), not by its
folder's name, so a copied folder is not another trial; whatever is left out is listed with the
reason (:class:`Skipped`), never dropped silently. :class:`Grid` is one runs folder with its label,
so that a report can set two grids side by side; :func:`setting_differences` says, from the runs'
config.json, how two grids' settings differ.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cmzdril_lab.records_store import materialize
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.experts import env_name
from sb3_cmzdril.io import PathLike, read_json, read_json_or_empty
from sb3_cmzdril.shipped import constraints_advice, published_differences
from sb3_cmzdril.training.run_folder import (
    CONFIG_FILE,
    DONE_FILE,
    EVAL_CSV,
    FINAL_EVAL_COLUMNS,
    FINAL_EVAL_CSV,
    read_eval_csv,
    run_status,
)
from sb3_cmzdril.training.spec import METHODS, effective_values, learner_defaults, record_made, result_policy

logger = logging.getLogger(__name__)

#: How methods are named in tables and legends (the paper's names).
METHOD_LABELS: dict[str, str] = {
    "bc": "BC",
    "dril": "DRIL",
    "cmz": "CMZ-DRIL",
    "zero": "No reward",
    "env": "Env. reward",
    "cmz-sac": "CMZ-DRIL (SAC)",
    "dril-sac": "DRIL (SAC)",
    "zero-sac": "No reward (SAC)",
    "env-sac": "Env. reward (SAC)",
}
#: Row order of the tables: the paper's Table I first, then Fig. 2's extra methods, then the off-policy learner.
METHOD_ORDER: tuple[str, ...] = ("bc", "dril", "cmz", "zero", "env", "cmz-sac", "dril-sac", "zero-sac", "env-sac")
#: Column order of envs: the paper's (PyUXV, Half Cheetah, Hopper); others follow alphabetically.
ENV_ORDER: tuple[str, ...] = ("WaypointNav-v0", "HalfCheetah-v5", "Hopper-v5")
#: The policies of a final evaluation: the one at the end of training, and the reward-free choice of
#: the RL methods: CMZDRIL's policy whose own training rollout had the lowest ensemble disagreement,
#: CMZDRILSAC's whose deterministic episodes from fixed starts lasted longest; and, for PPO runs whose
#: hyperparameters name ``average_from``, the average of the policy's weights over the last updates.
POLICIES: tuple[str, ...] = ("final", "lowest_u", "longest", "averaged")
#: How a table names a policy, after its method's label (none for the method's result,
#: :func:`~sb3_cmzdril.training.spec.result_policy`).
POLICY_SUFFIXES: dict[str, str] = {"final": " (last weights)", "lowest_u": " (lowest u)",
                                   "longest": " (longest episodes)", "averaged": " (averaged)"}
#: Numeric columns of final_eval.csv that the report averages (per run, over its episodes).
FINAL_VALUES: tuple[str, ...] = ("return", "length", "frechet", "action_mse", "expert_return")


@dataclasses.dataclass
class RunRecord:
    """One run's evaluation history and where it came from."""

    env: str  #: env name without module prefix
    method: str
    trial: int
    path: Path  #: the run folder
    columns: dict[str, np.ndarray]  #: eval.csv as columns, sorted by epoch
    status: str  #: done / partial / failed / new (see runs.run_status)
    config: dict[str, Any]
    #: final_eval.csv: policy -> column -> one value per held-out episode ({} without the file)
    final: dict[str, dict[str, np.ndarray]] = dataclasses.field(default_factory=dict)
    summary: dict[str, Any] = dataclasses.field(default_factory=dict)  #: done.json ({} if unfinished)

    def relative(self, root: Path) -> str:
        return relative(self.path, root)


@dataclasses.dataclass(frozen=True)
class Skipped:
    """What a report leaves out of a runs folder, and why: a run folder, or rows of its eval.csv."""

    path: Path  #: the run folder, or the eval.csv whose rows were left out
    reason: str

    def text(self, root: Path) -> str:
        return f"{relative(self.path, root)}: {self.reason}"


def label(method: str, policy: str = "final") -> str:
    """The method's name for its result (:func:`result_policy`), with a suffix for another of its
    policies: ``CMZ-DRIL`` and ``CMZ-DRIL (lowest u)``, ``CMZ-DRIL (SAC)`` (its longest-episodes policy)
    and ``CMZ-DRIL (SAC) (last weights)``."""
    return METHOD_LABELS[method] + ("" if policy == result_policy(method) else POLICY_SUFFIXES[policy])


def relative(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` where it lies below it, else as it is."""
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def read_final_eval(path: PathLike) -> dict[str, dict[str, np.ndarray]]:
    """final_eval.csv as ``policy -> column -> values`` (episode order kept); {} when there is none.

    The file is written atomically at the end of a run, so a malformed one is an error, not a run in
    progress: ValueError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            missing = [c for c in FINAL_EVAL_COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise UserError(f"{path}: missing column(s) {', '.join(missing)}")
            rows = list(reader)
    except UnicodeDecodeError as e:
        raise UserError(f"{path} is not a final_eval.csv: not UTF-8 text ({e.reason} at byte {e.start})") from None
    result: dict[str, dict[str, np.ndarray]] = {}
    try:
        for policy in dict.fromkeys(row["policy"] for row in rows):
            mine = [row for row in rows if row["policy"] == policy]
            columns = {c: np.array([float(row[c]) for row in mine]) for c in FINAL_VALUES}
            columns["episode"] = np.array([int(row["episode"]) for row in mine])
            result[policy] = columns
    except (TypeError, ValueError) as e:
        raise UserError(f"{path}: unreadable row ({e})") from None
    return result


def progress_rows(run_dir: Path) -> list[dict[str, str]]:
    """A run's SB3 progress CSVs (one per segment, ``logs/progress_<start step>.csv``) joined in step
    order; a resumed segment replaces the rows its predecessor logged after the checkpoint it resumed
    from. [] without logs."""
    segments = []
    for path in (run_dir / "logs").glob("progress_*.csv"):
        suffix = path.stem.split("_")[-1]
        if suffix.isdigit():
            segments.append((int(suffix), path))
    rows: list[dict[str, str]] = []
    for start, path in sorted(segments):
        rows = [row for row in rows if float(row["time/total_timesteps"]) <= start]
        with open(path, newline="", encoding="utf-8") as f:
            rows += [row for row in csv.DictReader(f) if row.get("time/total_timesteps")]
    return rows


def run_identity(folder: Path) -> tuple[tuple[str, str, int], dict[str, Any]] | str:
    """``((env, method, trial), config)`` from the folder's config.json, or why it names no run
    the report knows (no or a corrupt config.json, an unknown method, no trial seed)."""
    path = folder / CONFIG_FILE
    if not path.is_file():
        return f"no {CONFIG_FILE}, so not known which run it is"
    try:
        config = read_json(path)
    except ValueError as e:  # corrupt, or not a JSON object: the reason, with the file named as in the list
        return str(e).replace(str(path), CONFIG_FILE)
    env = config.get("env_name") or (env_name(config["env_id"]) if isinstance(config.get("env_id"), str) else None)
    method, seed = config.get("method"), config.get("seed")
    if not isinstance(env, str) or not env:
        return f"{CONFIG_FILE} names no env (env_name, env_id)"
    if method not in METHODS:
        return f"method {method!r} in {CONFIG_FILE} is none of {', '.join(METHODS)}"
    if not isinstance(seed, int) or isinstance(seed, bool):
        return f"{CONFIG_FILE} has no trial seed (seed: {seed!r})"
    return (env, method, seed), config


def _done_summary(path: Path, notes: list[Skipped]) -> dict[str, Any]:
    """done.json ({} when absent or unreadable), with a ``final_evaluation`` the tables can read.

    The tables read ``final_evaluation[policy]["epoch"]`` (the lowest-u policy's epoch); a hand-edited
    entry of another shape is left out with a note, so the rest of the run still counts.
    """
    summary = read_json_or_empty(path)
    final = summary.get("final_evaluation")
    if final is None:
        return summary
    # Only the policies' entries are read; a run also records other keys there (its "episodes").
    valid = isinstance(final, dict) and all(
        isinstance(entry, dict) and (entry.get("epoch") is None or _is_int(entry["epoch"]))
        for policy, entry in final.items()
        if policy in POLICIES
    )
    if not valid:
        notes.append(Skipped(path, f"its final_evaluation {final!r:.60} (an object of policies with integer epochs "
                                   "was expected): the selected epochs are not shown; its other numbers count"))
        summary = {k: v for k, v in summary.items() if k != "final_evaluation"}
    return summary


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _preference(record: RunRecord) -> tuple[bool, int]:
    """Which of several folders of one trial a report counts: a finished one, else the furthest."""
    return record.status == "done", int(record.columns["epoch"].size)


#: config.json fields that fix which episodes of which pool a run trains and is evaluated on.
SPLIT_FIELDS: tuple[str, ...] = ("demos_sha256", "train_episodes", "eval_episodes")
#: ... and, with those, what makes two folders of one trial the same run (a copy) rather than another run.
RUN_FIELDS: tuple[str, ...] = (*SPLIT_FIELDS, "timesteps", "eval_every", "hyperparams_values")


def _differing(configs: Sequence[dict[str, Any]], fields: Sequence[str]) -> list[str]:
    return [f for f in fields if len({json.dumps(c.get(f), sort_keys=True) for c in configs}) > 1]


def _check_same_run(copies: Sequence[RunRecord], root: Path) -> None:
    """Folders of one env, method and trial count once only when they are copies of one run: a run with
    another split or other settings is refused, naming both, never pooled into the same cell."""
    differ = _differing([r.config for r in copies], RUN_FIELDS)
    if differ:
        first, other = copies[0], next(r for r in copies[1:] if _differing([copies[0].config, r.config], differ))
        raise UserError(f"{relative(first.path, root)} and {relative(other.path, root)} are both {first.env} "
                        f"{METHOD_LABELS[first.method]} trial {first.trial} but differ in {', '.join(differ)}: "
                        "report them from separate runs folders, or remove one")


def _check_shared_splits(records: Sequence[RunRecord], root: Path) -> None:
    """A trial's methods are paired only when they trained and were evaluated on the same episodes of
    the same pool; a trial whose methods differ there is refused, naming the runs."""
    trials: dict[tuple[str, int], list[RunRecord]] = {}
    for record in records:
        trials.setdefault((record.env, record.trial), []).append(record)
    for (env, trial), runs in trials.items():
        differ = _differing([r.config for r in runs], SPLIT_FIELDS)
        if differ:
            splits = "; ".join(f"{relative(r.path, root)}: " + ", ".join(f"{f} {r.config.get(f)}" for f in differ)
                               for r in runs)
            raise UserError(f"{env} trial {trial}: its methods' runs differ in {', '.join(differ)}, so they cannot "
                            f"be paired ({splits}); rerun them on one split")


def note_versions(records: Sequence[RunRecord], root: Path) -> list[str]:
    """Log (and return) a line for the runs on a shipped demo pool that were made with other versions of
    the packages than the published records (``constraints/published.txt``): their numbers need not
    repeat the published ones."""
    by_difference: dict[str, int] = {}
    for record in records:
        config = record.config
        differ = ", ".join(published_differences(config.get("demos_sha256"), config.get("versions") or {}))
        if differ:
            by_difference[differ] = by_difference.get(differ, 0) + 1
    lines = [f"{root}: {n} of {len(records)} runs were made with {differ}; their numbers may differ from the "
             f"published records' ({constraints_advice()})" for differ, n in by_difference.items()]
    for line in lines:
        logger.warning("%s", line)
    return lines


def load_runs(runs_dir: PathLike, skipped: list[Skipped] | None = None) -> list[RunRecord]:
    """Every run below ``runs_dir`` with at least one evaluation row, sorted by env, method, trial.

    Each trial counts once: of several folders whose config.json name the same env, method and
    trial (a copy such as ``trial0.bak``), the finished one, else the one with the most evaluations,
    else the first by path; folders of one trial that are not copies of one run (another split or other
    settings), and a trial whose methods trained on different splits, are refused. Appended to
    ``skipped``: those other folders, folders whose config.json
    names no run the report knows (:func:`run_identity`), runs without an evaluation yet, and the
    rows of an eval.csv left out (NaN, cut short: the run's other rows count).

    :raises ValueError: an eval.csv or final_eval.csv that is no such file, naming it.
    """
    root = materialize(runs_dir)
    if not root.is_dir():
        raise MissingFileError(f"runs folder not found: {root}")
    notes: list[Skipped] = []
    by_trial: dict[tuple[str, str, int], list[RunRecord]] = {}
    for csv_path in sorted(root.rglob(EVAL_CSV)):
        folder = csv_path.parent
        identity = run_identity(folder)
        if isinstance(identity, str):
            notes.append(Skipped(folder, identity))
            continue
        (env, method, trial), config = identity
        dropped: list[str] = []
        columns = read_eval_csv(csv_path, dropped)
        if dropped:
            notes.append(Skipped(csv_path, f"{', '.join(dropped)} left out; its other rows count"))
        if columns["epoch"].size == 0:
            notes.append(Skipped(folder, "no evaluation yet"))
            continue
        by_trial.setdefault((env, method, trial), []).append(
            RunRecord(env, method, trial, folder, columns, run_status(folder), config,
                      read_final_eval(folder / FINAL_EVAL_CSV), _done_summary(folder / DONE_FILE, notes)))
    records = []
    for (env, method, trial), copies in by_trial.items():
        _check_same_run(copies, root)
        kept = max(copies, key=_preference)  # max keeps the first of equals: the first by path
        records.append(kept)
        notes += [Skipped(other.path, f"another folder of {env} {METHOD_LABELS[method]} trial {trial} "
                          f"(config.json), counted once, from {relative(kept.path, root)}")
                  for other in copies if other is not kept]
    _check_shared_splits(records, root)
    note_versions(records, root)
    for note in notes:
        logger.warning("%s: left out %s", root, note.text(root))
    if skipped is not None:
        skipped += notes
    return sorted(records, key=lambda r: (env_key(r.env), METHOD_ORDER.index(r.method), r.trial))


def env_key(env: str) -> tuple[int, str]:
    """Sort key: the paper's envs in its order, then the others alphabetically."""
    return (ENV_ORDER.index(env), env) if env in ENV_ORDER else (len(ENV_ORDER), env)


def group(records: Iterable[RunRecord]) -> dict[tuple[str, str], list[RunRecord]]:
    """(env, method) -> its runs, in the order given."""
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.env, r.method), []).append(r)
    return groups


@dataclasses.dataclass
class Grid:
    """One runs folder, as a report shows it."""

    label: str  #: how tables and headings name it
    root: Path
    records: list[RunRecord]
    skipped: list[Skipped] = dataclasses.field(default_factory=list)  #: what load_runs left out, and why

    @property
    def has_final(self) -> bool:
        return any(r.final for r in self.records)


def load_grid(runs_dir: PathLike, label: str | None = None) -> Grid:
    """The runs of ``runs_dir`` (ValueError when it has none), labelled by ``label`` or its path."""
    root = Path(runs_dir)
    skipped: list[Skipped] = []
    records = load_runs(root, skipped)
    if not records:
        why = f"; left out: {'; '.join(s.text(root) for s in skipped)}" if skipped else ""
        raise UserError(
            f"no runs with evaluations under {root} (expected <EnvName>/<method>/trial<t>/{EVAL_CSV}){why}"
        )
    return Grid(label or str(runs_dir), root, records, skipped)


#: Top-level config.json settings compared by :func:`setting_differences` (beside hyperparams_values).
COMPARED_SETTINGS: tuple[str, ...] = ("timesteps", "n_demos", "n_eval_episodes", "eval_every")
NOT_SET = "not set"


def _hyperparams(config: dict[str, Any]) -> dict[str, Any]:
    """config.json's hyperparameters without those at a default (a record that states one and one that
    does not are the same run)."""
    values = config.get("hyperparams_values", {})
    if config.get("method") not in METHODS:
        return values
    return effective_values(values, config["method"], **record_made(config))


def _run_settings(records: Sequence[RunRecord], env: str) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Per run of ``env``: (the settings its config.json states, its learner's defaults)."""
    configs = [r.config for r in records if r.env == env and r.config]
    return [({**{k: c[k] for k in COMPARED_SETTINGS if k in c}, **_hyperparams(c)},
             learner_defaults(c["method"]) if c.get("method") in METHODS else {}) for c in configs]


def _values(runs: list[tuple[dict[str, Any], dict[str, Any]]], key: str) -> set[str]:
    """The values (as JSON text) ``runs`` have for ``key``: a run that leaves it out counts at its
    learner's default, or NOT_SET where there is none."""
    return {json.dumps(s[key] if key in s else d[key], sort_keys=True) if key in s or key in d else NOT_SET
            for s, d in runs}


def setting_differences(a: Sequence[RunRecord], b: Sequence[RunRecord]) -> dict[str, list[tuple[str, str, str]]]:
    """env -> [(setting, a's value(s), b's value(s))] for the settings whose values differ between the
    two grids' runs of that env (config.json: :data:`COMPARED_SETTINGS` and hyperparams_values).
    Only the methods both grids ran on an env are compared: a method one grid alone has (another
    learner, with its own settings) is no difference between the grids."""
    result: dict[str, list[tuple[str, str, str]]] = {}
    envs_b = {r.env for r in b}
    for env in sorted({r.env for r in a} & envs_b, key=env_key):
        shared = {r.method for r in a if r.env == env} & {r.method for r in b if r.env == env}
        ra = _run_settings([r for r in a if r.method in shared], env)
        rb = _run_settings([r for r in b if r.method in shared], env)
        diffs = []
        for key in dict.fromkeys(k for s, _ in [*ra, *rb] for k in s):
            va, vb = _values(ra, key), _values(rb, key)
            if va != vb:
                diffs.append((key, " or ".join(sorted(va)), " or ".join(sorted(vb))))
        if diffs:
            result[env] = diffs
    return result


__all__ = [
    "METHOD_LABELS",
    "METHOD_ORDER",
    "ENV_ORDER",
    "POLICIES",
    "result_policy",
    "RunRecord",
    "Skipped",
    "Grid",
    "label",
    "load_runs",
    "load_grid",
    "run_identity",
    "read_final_eval",
    "setting_differences",
    "env_key",
    "group",
]
