"""A run folder's files: their names, how they are read, and the checks that keep one run per folder.

:func:`~sb3_cmzdril.training.runs.run_experiment` writes into the run's own folder::

    DIR/config.json        everything needed to reproduce it: env, method, seeds, the train/eval
                           episode indices of the demo pool (and its sha256), hyperparameters,
                           versions, the creating command and the equivalent `sb3-cmzdril train` line
    DIR/eval.csv           one row per evaluation against the held-out expert episodes
                           (ExpertEvalCallback: epoch, timesteps, return, Fréchet, action MSE, ...)
    DIR/model.zip          the latest checkpoint (written atomically every few PPO updates and at
                           the end; after done.json it is the final model; for bc the BC policy)
    DIR/vecnormalize.pkl   VecNormalize statistics beside model.zip, when the hyperparameters
                           ask for ``normalize``
    DIR/state.json         step count, wall and CPU time and the segments (start, resumes) of the run,
                           each with the machine and device it ran on (CPU model, logical CPUs, torch's
                           threads, OS); written last by each checkpoint, with the checkpoint's step count
                           and the sha256 of each of its files: a resume refuses a checkpoint whose files
                           are not those (a process killed while it wrote them)
    DIR/pretrain.csv       the NLL curve of behaviour-cloning pretraining (training and held-out steps)
    DIR/lowest_u.pt        the policy whose own training rollout had the lowest ensemble disagreement
                           (reward-free selection, sb3_cmzdril.selection), saved with each checkpoint;
                           an off-policy run (cmz-sac) keeps longest.pt instead, the policy whose
                           deterministic episodes from fixed starts lasted longest
    DIR/averaged.pt        with ``average_from`` in the hyperparameters (PPO methods): the running
                           average of the policy's weights over the run's last updates, saved with
                           each checkpoint
    DIR/replay_buffer.pkl  an off-policy run's replay buffer, with each checkpoint; removed when the
                           run is done
    DIR/final_eval.csv     the final evaluation: every pool episode not used for training, replayed by
                           the final policy ("final"), by the kept one ("lowest_u" or "longest") and by
                           the averaged one ("averaged"), one row per (policy, episode)
    DIR/logs/progress_<T>.csv  SB3's training log of the segment that started at step T
    DIR/done.json          written last: the final summary (with what each "auto" rule decided, and why);
                           its presence means "finished"

Here: :class:`RunFolder`, through which a run writes every one of those files; the file names,
eval.csv as columns and its Table I window (:func:`read_eval_csv`, :func:`window_means`), moving
evaluation rows written after a checkpoint aside (:func:`discard_rows_after`), config.json and the
checks that keep a run out of a folder that is not its own: someone else's files
(:func:`check_run_folder`) or a different run (:meth:`RunFolder.open`,
:func:`check_finished`); state.json (:class:`RunState`), the folder's lock, and what a folder holds
(:func:`run_status`, :func:`latest_epoch`).
"""
from __future__ import annotations

import collections
import contextlib
import csv
import functools
import math
import os
import re
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_cmzdril.errors import UserError
from sb3_cmzdril.experts import env_name
from sb3_cmzdril.io import (
    LOCK_FILE,
    PathLike,
    atomic_path,
    atomic_write_text,
    deferred_signals,
    file_sha256,
    is_temporary,
    jsonable,
    lock_output,
    machine,
    portable_path,
    read_json,
    read_json_or_empty,
    remove_stale_temporaries,
    unlock_output,
    versions,
    write_json,
)
from sb3_cmzdril.training.methods import METHOD_REGISTRY, Method
from sb3_cmzdril.training.spec import (
    ResolvedRun,
    RunSpec,
    effective_values,
    record_made,
    record_version,
    resolve_run,
    train_command,
)

#: Table I averages each run over its last this-many epochs (paper, Table I caption).
TABLE_WINDOW = 100

CONFIG_FILE = "config.json"
DONE_FILE = "done.json"
STATE_FILE = "state.json"
MODEL_FILE = "model.zip"
VECNORMALIZE_FILE = "vecnormalize.pkl"
EVAL_CSV = "eval.csv"
FINAL_EVAL_CSV = "final_eval.csv"
FINAL_EVAL_COLUMNS = ("policy", "episode", "seed", "return", "length", "frechet", "action_mse", "expert_return")
PRETRAIN_CSV = "pretrain.csv"
LOWEST_U_FILE = "lowest_u.pt"
LOWEST_U_MODEL = "model_lowest_u.zip"
LONGEST_FILE = "longest.pt"
LONGEST_MODEL = "model_longest.zip"
AVERAGED_FILE = "averaged.pt"
AVERAGED_MODEL = "model_averaged.zip"
REPLAY_BUFFER_FILE = "replay_buffer.pkl"
#: final_eval.csv's names of the policies a run keeps beside its last weights (:mod:`sb3_cmzdril.selection`),
#: with the files of each and of its model: the reward-free choice ("lowest_u" for CMZDRIL, "longest" for
#: CMZDRILSAC) and, where asked, the averaged policy
SELECTIONS: dict[str, tuple[str, str]] = {"lowest_u": (LOWEST_U_FILE, LOWEST_U_MODEL),
                                          "longest": (LONGEST_FILE, LONGEST_MODEL),
                                          "averaged": (AVERAGED_FILE, AVERAGED_MODEL)}
DISCARDED_CSV = "eval.discarded.csv"
ERROR_FILE = "error.txt"
LOG_FILE = "log.txt"

#: config.json's word on resumed runs: train_command alone reproduces a run never interrupted, not
#: one resumed from a checkpoint (SB3 saves no random-number state, and the env's episode in progress
#: is lost), so the record says what a resume does and state.json lists each segment's seed.
RESUME_NOTE = (
    "a run resumed from a checkpoint reseeds the networks and the envs with seed + the step it resumes from "
    "and starts new episodes there, so after that step it differs from the same run never interrupted; "
    "state.json lists each segment's start and seed"
)
#: config.json entries that must agree before a run folder is resumed (the rest may change, e.g.
#: the requested number of steps or how often to evaluate).
_IDENTITY_KEYS = ("env_id", "method", "seed", "train_episodes", "eval_episodes", "demos_sha256", "hyperparams_values")
#: config.json entries a resume may change.
_SETTING_KEYS = ("timesteps", "eval_every", "checkpoint_every", "train_command", "resume", "device")
#: state.json's record of the last checkpoint: its step count and the sha256 of each of its files.
CHECKPOINT_KEY = "checkpoint"
#: done.json's repeat of the identity, for a folder of ours whose config.json went missing.
_DONE_IDENTITY_KEYS = ("env_id", "method", "seed", "train_episodes", "eval_episodes")


# -- eval.csv ------------------------------------------------------------------------------------
def read_eval_csv(path: PathLike, dropped: list[str] | None = None) -> dict[str, np.ndarray]:
    """eval.csv as columns (float arrays, rows sorted by epoch; first row per epoch kept).

    Rows cut short by a killed process (wrong field count, unparsable numbers) and rows holding a NaN
    or an infinite value are left out, each kind counted in ``dropped`` when it is given ("1 row(s)
    with NaN or infinite values"). A file that is no eval.csv (not UTF-8 text, or without its
    columns) is a ValueError naming it.
    """
    from sb3_cmzdril.metrics import ExpertEvalCallback

    columns = ExpertEvalCallback.CSV_COLUMNS
    rows: dict[int, list[float]] = {}
    left_out: collections.Counter = collections.Counter()
    path = Path(path)
    if path.is_file():
        try:
            with open(path, newline="", encoding="utf-8") as f:
                reader = csv.DictReader(f)
                missing = [c for c in columns if c not in (reader.fieldnames or columns)]  # empty file: no rows
                if missing:
                    raise UserError(f"{path} is not an eval.csv: it has no column {', '.join(missing)}")
                for row in reader:
                    try:
                        values = [float(row[c]) for c in columns]
                    except (TypeError, ValueError, KeyError):
                        left_out["cut short or unreadable"] += 1
                        continue
                    if not all(map(math.isfinite, values)):
                        left_out["with NaN or infinite values"] += 1
                        continue
                    rows.setdefault(int(values[0]), values)
        except UnicodeDecodeError as e:
            raise UserError(f"{path} is not an eval.csv: not UTF-8 text ({e.reason} at byte {e.start})") from None
    if dropped is not None:
        dropped += [f"{n} row(s) {kind}" for kind, n in left_out.items()]
    ordered = [rows[e] for e in sorted(rows)]
    table = np.asarray(ordered, dtype=np.float64).reshape(len(ordered), len(columns))
    return {c: table[:, i] for i, c in enumerate(columns)}


def window_means(columns: Mapping[str, np.ndarray], window: int = TABLE_WINDOW) -> dict[str, float]:
    """Each metric averaged over the evaluations of the last ``window`` epochs (all, if fewer).

    "Last 100 epochs" counts epochs, not rows: rows with ``epoch > last_epoch - window``.
    """
    epochs = columns["epoch"]
    if epochs.size == 0:
        return {"return": float("nan"), "frechet": float("nan"), "action_mse": float("nan"), "n_rows": 0,
                "first_epoch": -1, "last_epoch": -1}
    keep = epochs > epochs[-1] - window
    return {
        "return": float(np.mean(columns["return_mean"][keep])),
        "frechet": float(np.mean(columns["frechet_mean"][keep])),
        "action_mse": float(np.mean(columns["action_mse"][keep])),
        "n_rows": int(keep.sum()),
        "first_epoch": int(epochs[keep][0]),
        "last_epoch": int(epochs[-1]),
    }


def discard_rows_after(csv_path: Path, timesteps: int) -> int:
    """Move eval rows with ``timesteps`` beyond the checkpoint to eval.discarded.csv; returns how many.

    They were evaluated by a process that died after the checkpoint: the policy they describe is
    gone, and the resumed run evaluates those epochs again.
    """
    if not csv_path.is_file():
        return 0
    lines = csv_path.read_text().splitlines()
    if not lines:
        return 0
    header, keep = lines[0], [lines[0]]
    moved: list[str] = []
    n_fields = len(header.split(","))
    for line in lines[1:]:
        fields = line.split(",")
        try:
            later = len(fields) != n_fields or int(fields[1]) > timesteps
        except ValueError:
            later = True
        # A row cut short by the kill counts as later: it is moved out of the way with its text kept.
        (moved if later else keep).append(line)
    if not moved:
        return 0
    discarded = csv_path.with_name(DISCARDED_CSV)
    with open(discarded, "a") as f:
        if discarded.stat().st_size == 0:
            f.write(header + "\n")
        f.write("".join(f"{line}\n" for line in moved))
        f.flush()
        os.fsync(f.fileno())  # the rows are safe in the discard file before they leave eval.csv
    with atomic_path(csv_path) as tmp:
        tmp.write_text("".join(f"{line}\n" for line in keep))
    return len(moved)



def pretrain_csv_text(history: Mapping[str, Sequence[float]]) -> str:
    """pretrain.csv's text: epoch, training NLL, held-out NLL (epoch 0: before training, held-out only)."""
    train, validation = list(history.get("train_nll", [])), list(history.get("validation_nll", []))
    n = max(len(train) + (1 if validation else 0), len(validation))
    lines = ["epoch,train_nll,validation_nll"]
    offset = 1 if validation else 0  # validation_nll[0] is measured before the first epoch
    for epoch in range(n):
        t = train[epoch - offset] if 0 <= epoch - offset < len(train) else float("nan")
        v = validation[epoch] if epoch < len(validation) else float("nan")
        lines.append(f"{epoch + 1 - offset},{t:.6g},{v:.6g}")
    return "\n".join(lines) + "\n"


# -- config.json, state.json, the lock -----------------------------------------------------------
class RunState:
    """state.json: step count, wall and CPU time across segments, and how each segment started and
    on which machine (CPU model, logical CPUs, torch's threads, OS).

    CPU time is this process's (``time.process_time``, every thread of it) from the segment's start.
    Another process waiting for the core does not add to it as it adds to wall time, but a loaded
    machine still slows each step (shared caches and cores): compare runs made under similar load.
    A state.json from before it was recorded counts from 0."""

    def __init__(self, out: Path, spec: RunSpec, start_steps: int, device: str | None = None) -> None:
        self.path = out / STATE_FILE
        self.data: dict[str, Any] = {"num_timesteps": 0, "wall_time_s": 0.0, "cpu_time_s": 0.0, "segments": []}
        if self.path.is_file() and start_steps > 0:
            self.data.update(_read_record(self.path))
        self._base_wall = float(self.data.get("wall_time_s", 0.0))
        self._base_cpu = float(self.data.get("cpu_time_s", 0.0))
        self._t0 = time.time()
        self._cpu0 = time.process_time()
        self.data["segments"].append({
            "started_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "from_timesteps": int(start_steps),
            "seed": spec.seed + int(start_steps),  # what the segment reseeded with (config.json's "resume")
            "command": spec.command,
            "machine": machine(),
            **({"device": device} if device is not None else {}),
        })

    def wall_time(self) -> float:
        return self._base_wall + (time.time() - self._t0)

    def cpu_time(self) -> float:
        return self._base_cpu + (time.process_time() - self._cpu0)

    def write(self, num_timesteps: int, checkpoint: Mapping[str, str] | None = None) -> None:
        """state.json; with ``checkpoint`` (file name -> sha256 of each file of the checkpoint just
        written at ``num_timesteps``), the record a resume checks the checkpoint's files against."""
        if checkpoint is not None:
            self.data[CHECKPOINT_KEY] = {"timesteps": int(num_timesteps), "sha256": dict(checkpoint)}
        self.data.update(num_timesteps=int(num_timesteps), wall_time_s=round(self.wall_time(), 2),
                         cpu_time_s=round(self.cpu_time(), 2))
        write_json(self.path, self.data)


def run_config(run: ResolvedRun) -> dict[str, Any]:
    """config.json's content for ``run``: what it is (env, method, seeds, split, demo pool), the
    hyperparameters as written and every constructor argument as the run gives it
    (:meth:`~sb3_cmzdril.training.spec.ResolvedRun.constructor_arguments`), the device the model runs
    on (which ``model_kwargs``, as the YAML asks, need not say) and how to run it again. The learner's
    ``"auto"`` rules join it as ``rules`` once they are decided (:meth:`RunFolder.checkpoint`)."""
    spec, hp, pool = run.spec, run.hp, run.pool
    train_idx, eval_idx = list(run.train_idx), list(run.eval_idx)
    return {
        "env_id": spec.env_id,
        "env_name": env_name(spec.env_id),
        "method": spec.method,
        "reward": Method.of(spec.method).recorded_reward,
        "seed": spec.seed,
        "network_seed": spec.seed,
        "env_seed": spec.seed,
        "demos": portable_path(spec.demos),
        "demos_sha256": file_sha256(spec.demos),
        "pool_episodes": int(pool.n_episodes),
        "split": "numpy.random.default_rng(seed).permutation(pool_episodes): first n_demos train, "
        "next n_eval_episodes evaluate",
        "n_demos": spec.n_demos,
        "n_eval_episodes": spec.n_eval_episodes,
        "train_episodes": train_idx,
        "eval_episodes": eval_idx,
        "train_episode_seeds": [int(pool.seeds[i]) for i in train_idx],
        "eval_episode_seeds": [int(pool.seeds[i]) for i in eval_idx],
        "timesteps": spec.timesteps,
        "eval_every": spec.eval_every,
        "checkpoint_every": spec.checkpoint_every,
        "hyperparams_file": portable_path(spec.hyperparams),
        "hyperparams_key": hp.key,
        "hyperparams_values": hp.raw,
        "model_kwargs": hp.model_kwargs(),
        "constructor": run.constructor_arguments(),
        "device": run.device,
        "env_kwargs": hp.env_kwargs,
        "versions": versions(),
        "command": spec.command,
        "train_command": train_command(spec),
        "resume": RESUME_NOTE,
        "created_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def as_stored(config: Mapping[str, Any]) -> dict[str, Any]:
    """``config`` as config.json stores it, to compare like with like."""
    import json

    return json.loads(json.dumps(jsonable(dict(config))))


def _identity_value(key: str, config: Mapping[str, Any], method: Any) -> Any:
    """config.json's ``key`` as two runs compare it: an env id by its name, hyperparameters by what they
    change (:func:`~sb3_cmzdril.training.spec.effective_values`, a default read as the version that made
    the run had it when it made it)."""
    value = config.get(key)
    if key == "env_id" and isinstance(value, str):
        return env_name(value)
    if key == "hyperparams_values" and isinstance(value, dict) and method in METHOD_REGISTRY:
        return effective_values(value, method, **record_made(config))
    return value


def _difference(key: str, saved: Mapping[str, Any], fresh: Mapping[str, Any], method: Any) -> str:
    """How the folder's run and the asked one differ in ``key``: for the hyperparameters, each setting
    that differs as it is compared (a default by its value at the version that made the run)."""
    there, now = _identity_value(key, saved, method), _identity_value(key, fresh, method)
    if not (isinstance(there, dict) and isinstance(now, dict)):
        return f"{key}: {saved.get(key)!r} there, {fresh.get(key)!r} now"

    def shown(values: dict[str, Any], name: str) -> str:
        return repr(values[name]) if name in values else "the default"

    settings = "; ".join(f"{name} {shown(there, name)} there, {shown(now, name)} now"
                         for name in sorted({*there, *now}) if shown(there, name) != shown(now, name))
    made_by = record_version(saved)
    if made_by is not None and made_by != record_version(fresh):
        settings += f" (the folder's run was made by sb3-cmzdril {made_by})"
    return f"{key}: {settings}"


def check_same_run(
    out: Path, saved: Mapping[str, Any], fresh: Mapping[str, Any], what: str = "a different run"
) -> None:
    """ValueError naming each identity entry in which the folder's run and the asked one differ.

    An env id is compared without its ``module:`` prefix: gymnasium's ``module:Env-v0`` imports the module
    and makes ``Env-v0``, the same env as ``Env-v0`` made after that import. Hyperparameters are compared
    without the values that restate a default: a run made when the YAML stated them is the same run, and
    one made by an earlier version that left out a default since changed is not.
    """
    method = fresh.get("method")
    differing = [k for k in _IDENTITY_KEYS if k in saved and _identity_value(k, saved, method)
                 != _identity_value(k, fresh, method)]
    if differing:
        diffs = ", ".join(_difference(k, saved, fresh, method) for k in differing)
        raise UserError(
            f"{out} holds {what} ({diffs}); "
            "use another output folder or delete that one"
        )


@contextlib.contextmanager
def locked(out: Path) -> Iterator[None]:
    """One process per run folder: a second one fails at once instead of corrupting the first."""
    lock = lock_output(out)  # LockHeld (a ValueError) names the folder; the grid tells it from a failure
    try:
        yield
    finally:
        unlock_output(out, lock)


def check_run_folder(out: Path) -> None:
    """ValueError unless ``out`` is absent, empty or a run folder of ours: one whose config.json (or,
    should that have gone missing, done.json) is a run's, or that holds only what a run of ours leaves
    before writing config.json. Someone's config.json is never replaced, and an expert's folder never
    receives a run's files."""
    if not out.exists():
        return
    if not out.is_dir():
        raise UserError(f"{out} is a file, not a run folder; use another output folder")
    config, done = (_read_record(out / name, strict=False) for name in (CONFIG_FILE, DONE_FILE))
    # What a run of ours leaves before config.json: the lock, an atomic write's temporary, or an
    # error.txt / log.txt as the grid writes them (those by their first line, :func:`_written_by_the_grid`).
    found = sorted(out.iterdir())
    ours = {p.name for p in found
            if p.is_file() and (p.name == LOCK_FILE or is_temporary(p.name)) or _written_by_the_grid(p)}
    if (out / CONFIG_FILE).is_file():
        if all(k in config for k in _IDENTITY_KEYS):
            return
        raise UserError(
            f"{out / CONFIG_FILE} is not the config.json of an sb3-cmzdril run, and it is not ours to replace; "
            "use another output folder"
        )
    if all(k in done for k in _DONE_IDENTITY_KEYS):
        return
    foreign = [p.name for p in found if p.name not in ours]
    if foreign:
        shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
        raise UserError(
            f"{out} holds files that are not an sb3-cmzdril run's ({shown}); train into a new or empty folder"
        )


#: The first line of the error.txt a failed attempt leaves (grid's ``_write_error``): time, label, "failed".
_ERROR_HEADER = re.compile(r"^\d{4}-\d{2}-\d{2}T\S+ \S+ failed$")
#: The first line the grid writes to a run's log.txt, before anything else.
_LOG_HEADER = "=== "


def _read_record(path: Path, strict: bool = True) -> dict[str, Any]:
    """A run folder's JSON record (config.json, done.json, state.json). ``strict``: a UserError naming one
    that is damaged or not an object; else ``{}`` for one missing or damaged (to tell whose folder it is)."""
    return read_json(path) if strict else read_json_or_empty(path)


def _first_line(path: Path) -> str | None:
    """The file's first line (at most 1 KiB of it), None when it cannot be read as text."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline(1024).rstrip("\n")
    except (OSError, UnicodeDecodeError):
        return None


def _written_by_the_grid(path: Path) -> bool:
    """Whether ``path`` is an error.txt or log.txt as the grid writes them into a run's folder.

    By name alone, a user's own error.txt or log.txt would pass for the run's, and the run would delete
    or append to it; the first line tells them apart.
    """
    if path.name == ERROR_FILE:
        first = _first_line(path)
        return first is not None and _ERROR_HEADER.match(first) is not None
    if path.name == LOG_FILE:
        first = _first_line(path)
        return first is not None and (first == "" or first.startswith(_LOG_HEADER))
    return False


def check_finished(spec: RunSpec, run: ResolvedRun | None = None) -> dict[str, Any] | None:
    """done.json's summary when ``spec.output_dir`` holds this run finished, None when it is not finished.

    :param run: ``spec`` resolved, when the caller has it (else it is resolved here, if done.json is there).
    :raises ValueError: the folder is not a run folder of ours (:func:`check_run_folder`); or it holds
        a finished run of something else (another method, seed, split, demo pool or hyperparameters),
        whose numbers must not pass for this run's; or this run, finished with fewer steps than
        ``spec.timesteps`` asks for.
    """
    done_path = _done_path(Path(spec.output_dir))
    if done_path is None:
        return None
    run = run if run is not None else resolve_run(spec, check=False)  # finished: nothing left to check
    return RunFolder(run).finished_at(done_path)


def _done_path(out: Path) -> Path | None:
    """The done.json of ``out``, a run folder of ours (:func:`check_run_folder`); None where it has none."""
    check_run_folder(out)
    done_path = out / DONE_FILE
    return done_path if done_path.is_file() else None


class RunFolder:
    """The folder of one resolved run, through which the run reads and writes every file of it."""

    def __init__(self, run: ResolvedRun) -> None:
        self.run = run
        self.path = Path(run.spec.output_dir)
        self.model = self.path / MODEL_FILE
        self.vecnormalize = self.path / VECNORMALIZE_FILE
        self.eval_csv = self.path / EVAL_CSV
        self.replay_buffer = self.path / REPLAY_BUFFER_FILE
        self.config: dict[str, Any] = {}  #: config.json's content, once :meth:`open` has written or read it

    @functools.cached_property
    def fresh_config(self) -> dict[str, Any]:
        """config.json's content for this run (:func:`run_config`), made once."""
        return run_config(self.run)

    def finished(self) -> dict[str, Any] | None:
        """done.json's summary of this very run, or None (:func:`check_finished`)."""
        done_path = _done_path(self.path)
        return None if done_path is None else self.finished_at(done_path)

    def finished_at(self, done_path: Path) -> dict[str, Any]:
        """done.json's summary (at ``done_path``), once it is this very run's (:func:`check_finished`)."""
        spec = self.run.spec
        done = _read_record(done_path)
        # done.json repeats the first identity entries, for a folder whose config.json went missing.
        saved = _read_record(self.path / CONFIG_FILE) if (self.path / CONFIG_FILE).is_file() else done
        check_same_run(self.path, saved, as_stored(self.fresh_config), "a different, finished run")
        steps = done.get("num_timesteps", 0)
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
            raise UserError(
                f"{done_path} is not what sb3-cmzdril wrote: num_timesteps is {steps!r}, not a number of steps; "
                "delete it to let the run finish again, or use another output folder"
            )
        if spec.timesteps > steps:
            if self.run.method.off_policy:
                # Its replay buffer went when it finished (finish()): without it no resume is the same run.
                raise UserError(
                    f"{self.path} is finished at {steps} steps (done.json), fewer than the {spec.timesteps} asked; a "
                    f"finished {spec.method} run cannot train further (its {REPLAY_BUFFER_FILE}, which resuming needs, "
                    f"is removed when it finishes): train {spec.timesteps} steps into another output folder"
                )
            raise UserError(
                f"{self.path} is finished at {steps} steps (done.json), fewer than the {spec.timesteps} asked; to "
                f"train it further, delete {done_path} and run the command again (it continues from {MODEL_FILE}), "
                "or use another output folder"
            )
        return done

    @contextlib.contextmanager
    def open(self) -> Iterator[RunFolder]:
        """The folder created (or checked to be ours) and locked, with config.json written or matched."""
        check_run_folder(self.path)
        self.path.mkdir(parents=True, exist_ok=True)
        with locked(self.path):
            remove_stale_temporaries(self.path)
            self.config = self._check_or_write_config()
            yield self

    def _check_or_write_config(self) -> dict[str, Any]:
        """Write config.json for a new run; for an existing one, refuse to mix two different runs.

        A config.json with nothing trained beside it (an attempt that failed or was stopped before its
        first checkpoint) is replaced: it must not block the corrected command.
        """
        path = self.path / CONFIG_FILE
        trained = self.model.is_file() or (self.path / DONE_FILE).is_file()
        if not path.is_file() or not trained:
            self._write(path, self.fresh_config)
            return self.fresh_config
        saved = _read_record(path)
        fresh = as_stored(self.fresh_config)
        check_same_run(self.path, saved, fresh)
        # A resume may ask for more steps or another cadence: config.json follows, so that its
        # train_command reproduces what the run became (state.json keeps each segment's command).
        changed = {k: fresh[k] for k in _SETTING_KEYS if saved.get(k) != fresh.get(k)}
        if changed:
            saved.update(changed)
            self._write(path, saved)
        return saved

    def _write(self, path: Path, content: Mapping[str, Any] | str | Callable[[Path], Any], suffix: str = "") -> Path:
        """Write one file of the folder whole or not at all, and return its path: a JSON record (config.json,
        done.json), a text (a CSV), or what ``content(tmp)`` saves into a temporary beside ``path`` (a model,
        statistics, a replay buffer) with the file's ``suffix``, which SB3's savers append when it is missing."""
        if isinstance(content, Mapping):
            write_json(path, dict(content))
        elif isinstance(content, str):
            atomic_write_text(path, content)
        else:
            with atomic_path(path, suffix=suffix) as tmp:
                content(tmp)
        return path

    @property
    def resumable(self) -> bool:
        """Whether the run continues from a checkpoint (BC has none to continue from: it is retrained)."""
        return not self.run.method.pretrain_only and self.model.is_file()

    def check_resumable(self) -> None:
        """UserError, naming the file, unless the checkpoint is one whole that the run can go on from.

        Each checkpoint writes state.json last, with its step count and the sha256 of every file of it
        (:meth:`checkpoint`); each must be there as written. A process killed while it wrote a checkpoint
        leaves some files newer than the others (model.zip at one step, the replay buffer and the kept
        policy's search at an earlier one), and a file missing would let the run go on as another run,
        silently. A state.json written before checkpoints were recorded holds their step count only:
        model.zip must be at it, and an off-policy run needs its replay buffer.
        """
        if not self.resumable:
            return
        state_path = self.path / STATE_FILE
        restart = f"delete {self.path} (or train into another output folder) to start the run again"
        if not state_path.is_file():
            raise UserError(f"{self.path} holds {MODEL_FILE} but not {STATE_FILE}, which records its checkpoint; "
                            f"{restart}")
        state = _read_record(state_path)
        record = state.get(CHECKPOINT_KEY)
        if record is None:
            self._check_unrecorded_checkpoint(state, restart)
            return
        try:
            steps, digests = int(record["timesteps"]), dict(record["sha256"])
            if not all(isinstance(d, str) for d in digests.values()):
                raise TypeError("a digest is not a string")
        except (TypeError, ValueError, KeyError):
            raise UserError(f"{state_path} is not what sb3-cmzdril wrote: its checkpoint record is {record!r}; "
                            f"{restart}") from None
        foreign = sorted(set(digests) - set(_CHECKPOINT_FILES))
        if foreign:
            raise UserError(f"{state_path} is not what sb3-cmzdril wrote: its checkpoint names {foreign}, no files "
                            f"of a checkpoint; {restart}")
        for name in [*self._needed_files(), *digests]:
            if name not in digests or not (self.path / name).is_file():
                raise UserError(f"{self.path} holds {MODEL_FILE} but not {name}, which its checkpoint at {steps} "
                                f"steps needs to resume; {restart}")
        for name, digest in digests.items():
            if file_sha256(self.path / name) != digest:
                raise UserError(
                    f"{self.path / name} is truncated, damaged or from another checkpoint than the one at {steps} "
                    f"steps that {STATE_FILE} records (a process killed while it wrote a checkpoint leaves its files "
                    f"so); {restart}"
                )

    def _needed_files(self) -> list[str]:
        """The files every checkpoint of this run holds: model.zip, an off-policy learner's replay buffer,
        the VecNormalize statistics where the hyperparameters normalise."""
        return [MODEL_FILE, *([REPLAY_BUFFER_FILE] if self.run.method.off_policy else []),
                *([VECNORMALIZE_FILE] if self.run.hp.normalize not in (None, False) else [])]

    def _check_unrecorded_checkpoint(self, state: Mapping[str, Any], restart: str) -> None:
        """A state.json without a checkpoint record (written before they were kept): its step count must
        be model.zip's, and an off-policy run needs its replay buffer."""
        if self.run.method.off_policy and not self.replay_buffer.is_file():
            raise UserError(
                f"{self.path} holds {MODEL_FILE} but not {REPLAY_BUFFER_FILE}, which an off-policy run needs to "
                f"resume; {restart}"
            )
        steps, saved = state.get("num_timesteps"), _model_timesteps(self.model)
        if saved is not None and steps != saved:
            raise UserError(
                f"{self.model} is at {saved} steps, but {STATE_FILE}, which each checkpoint writes last, at {steps!r}: "
                f"a process killed while it wrote a checkpoint leaves its files so; {restart}"
            )

    def segment_logger(self, start: int, verbose: int, tensorboard: Path | None = None):
        """SB3 logger writing the progress CSV of the segment that starts at step ``start`` (a resumed
        run must not overwrite the last one's) and, with ``tensorboard`` (:meth:`tensorboard_dir`),
        TensorBoard's event files into that folder."""
        import sys

        from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, Logger, TensorBoardOutputFormat

        (self.path / "logs").mkdir(exist_ok=True)
        formats: list[Any] = [CSVOutputFormat(str(self.path / "logs" / f"progress_{start}.csv"))]
        if verbose >= 1:
            formats.append(HumanOutputFormat(sys.stdout))
        if tensorboard is not None:
            formats.append(TensorBoardOutputFormat(str(tensorboard)))
        return Logger(folder=None, output_formats=formats)

    def tensorboard_dir(self, state: RunState) -> Path | None:
        """Where the run writes TensorBoard's events, None unless its hyperparameters set ``tensorboard_log``:
        SB3's ``<tensorboard_log>/<name>_<n>``, the run's label as the name and ``n`` one more than the
        last such folder there; a resumed run continues the folder its earlier segments wrote to
        (state.json's segments name it), as SB3's ``learn(reset_num_timesteps=False)`` does."""
        root = self.run.model_kwargs().get("tensorboard_log")
        if root is None:
            return None
        from stable_baselines3.common.utils import get_latest_run_id

        earlier = [seg["tensorboard"] for seg in state.data["segments"][:-1] if isinstance(seg.get("tensorboard"), str)]
        if earlier:
            return Path(earlier[-1])
        name = self.run.spec.label.replace("/", "_")
        return Path(root).resolve() / f"{name}_{get_latest_run_id(str(root), name) + 1}"

    def kept_file(self, name: str) -> Path:
        """Where the kept policy ``name`` (a key of :data:`SELECTIONS`) and what led to it are saved."""
        return self.path / SELECTIONS[name][0]

    def checkpoint(self, model: Any, kept: Mapping[str, Any], state: RunState) -> None:
        """model.zip, the VecNormalize statistics beside it, an off-policy learner's replay buffer, the
        kept policies so far (name -> selector, :mod:`sb3_cmzdril.selection`) and, last, state.json with
        the step count and the sha256 of each of those files (what :meth:`check_resumable` checks)."""
        written: list[Path] = []
        # The checkpoint's files belong together: Ctrl-C or SIGTERM waits until all are written.
        with deferred_signals():
            vec_normalize = model.get_vec_normalize_env()
            if vec_normalize is not None:
                written.append(self._write(self.vecnormalize, lambda tmp: vec_normalize.save(str(tmp)), ".pkl"))
            written.append(self._write(self.model, model.save, ".zip"))
            if self.run.method.off_policy:
                written.append(self._write(self.replay_buffer, model.save_replay_buffer, ".pkl"))
            for name, selector in kept.items():  # with the checkpoint, so a resume continues the same search
                if selector.best_state is not None:  # nothing is written before a choice exists
                    selector.save(self.kept_file(name))
                    written.append(self.kept_file(name))
            state.write(model.num_timesteps, {path.name: file_sha256(path) for path in written})
        self.record_rules(model.rules)

    def record_rules(self, rules: Mapping[str, Any]) -> None:
        """config.json's ``rules``: what each of the learner's ``"auto"`` settings was decided to be, and
        why, written when they are first decided (or change)."""
        if rules and self.config.get("rules") != rules:
            self.config = {**self.config, "rules": dict(rules)}
            self._write(self.path / CONFIG_FILE, self.config)

    def has_pretrain(self) -> bool:
        """Whether pretrain.csv is there."""
        return (self.path / PRETRAIN_CSV).is_file()

    def write_pretrain(self, history: Mapping[str, Sequence[float]]) -> None:
        self._write(self.path / PRETRAIN_CSV, pretrain_csv_text(history))

    def write_final_evaluation(self, rows: Sequence[str]) -> None:
        self._write(self.path / FINAL_EVAL_CSV, "\n".join([",".join(FINAL_EVAL_COLUMNS), *rows]) + "\n")

    def save_kept_model(self, model: Any, name: str) -> None:
        """The model holding the kept policy ``name``, beside model.zip."""
        self._write(self.path / SELECTIONS[name][1], model.save, ".zip")

    def finish(self, summary: dict[str, Any]) -> dict[str, Any]:
        """done.json, written last: from now on the folder holds a finished run (whose replay buffer,
        hundreds of MB and of no use once nothing resumes, is removed)."""
        self._write(self.path / DONE_FILE, summary)
        self.replay_buffer.unlink(missing_ok=True)
        error = self.path / ERROR_FILE
        if _written_by_the_grid(error):  # an earlier attempt's failure is history once the run is done
            with contextlib.suppress(FileNotFoundError):
                error.unlink()
        return summary


#: The files a checkpoint may hold (state.json's record names no others).
_CHECKPOINT_FILES = (MODEL_FILE, VECNORMALIZE_FILE, REPLAY_BUFFER_FILE, *(files for files, _ in SELECTIONS.values()))


def _model_timesteps(path: Path) -> int | None:
    """The step count an SB3 zip records (its ``data``), None where it cannot be read (loading it says why)."""
    import json
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            steps = json.loads(archive.read("data"))["num_timesteps"]
    except Exception:  # a damaged or foreign zip: the resume's load names it
        return None
    return steps if isinstance(steps, int) and not isinstance(steps, bool) else None


# -- what a folder holds ---------------------------------------------------------------------------
def run_status(output_dir: PathLike) -> str:
    """``"done"``, ``"failed"`` (error.txt, no done.json), ``"partial"`` (a checkpoint) or ``"new"``."""
    out = Path(output_dir)
    if (out / DONE_FILE).is_file():
        return "done"
    if (out / ERROR_FILE).is_file():
        return "failed"
    if (out / MODEL_FILE).is_file():
        return "partial"
    return "new"


def latest_epoch(output_dir: PathLike) -> int | None:
    """The epoch of the last row of a run's eval.csv (cheap: reads the file's tail), or None."""
    path = Path(output_dir) / EVAL_CSV
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 1024))
            tail = f.read().decode("utf-8", "replace").strip().splitlines()
        return int(tail[-1].split(",")[0]) if tail else None
    except (OSError, ValueError, IndexError):
        return None


__all__ = [
    "AVERAGED_FILE",
    "AVERAGED_MODEL",
    "CHECKPOINT_KEY",
    "CONFIG_FILE",
    "DISCARDED_CSV",
    "DONE_FILE",
    "ERROR_FILE",
    "EVAL_CSV",
    "FINAL_EVAL_COLUMNS",
    "FINAL_EVAL_CSV",
    "LOG_FILE",
    "LONGEST_FILE",
    "LONGEST_MODEL",
    "LOWEST_U_FILE",
    "LOWEST_U_MODEL",
    "MODEL_FILE",
    "PRETRAIN_CSV",
    "REPLAY_BUFFER_FILE",
    "RESUME_NOTE",
    "SELECTIONS",
    "STATE_FILE",
    "TABLE_WINDOW",
    "VECNORMALIZE_FILE",
    "RunFolder",
    "RunState",
    "as_stored",
    "check_finished",
    "check_run_folder",
    "check_same_run",
    "discard_rows_after",
    "file_sha256",
    "latest_epoch",
    "locked",
    "read_eval_csv",
    "run_config",
    "run_status",
    "window_means",
    "pretrain_csv_text",
]
