"""Runs of the grid on Ray workers that share no filesystem with the driver (ray up, KubeRay).

A task carries everything its run reads, and its run folder comes back to the driver:

* the driver packs a :class:`RunPackage` (the :class:`~sb3_cmzdril.training.spec.RunSpec`,
  the hyperparameter YAML's text and the run folder's current files, so that a partial run continues
  from its checkpoint as on the local backend); the demo pool's bytes go to Ray's object store once
  per pool file and reach every task of that env from there;
* the worker writes them into a temporary directory of its own, points the spec there
  (:func:`relocate`) and calls :func:`~cmzdril_lab.run.worker.execute_run`, as the local backend does;
* after every checkpoint the worker sends the run folder's changed files to a small actor on the
  driver's node (:class:`FolderSink`), so that checkpoints outlive a lost worker or an interrupted
  driver; at the end the task returns the files changed since it started (:class:`RunResult`), and
  the driver writes them atomically into its runs folder. (A driver on Ray Client, ``ray://``, gets
  no such sink: its checkpoints come back with the finished run only.)

The driver holds the run folder's lock while its run is away, so a second grid (any backend) cannot
work in the same folder meanwhile. config.json, done.json, state.json and the outcome name the
driver's paths, not the worker's temporary ones; log.txt and error.txt keep the worker's (they
tell where the run actually ran).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import shlex
import tempfile
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import Any

from cmzdril_lab.run.worker import RunOutcome, RunStatus, execute_run
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import (
    LOCK_FILE,
    OutputLock,
    PathLike,
    atomic_path,
    lock_output,
    portable_path,
    unlock_output,
)
from sb3_cmzdril.training.run_folder import CHECKPOINT_KEY, STATE_FILE
from sb3_cmzdril.training.spec import RunSpec, file_mtime_ns

logger = logging.getLogger(__name__)

#: Seconds between the worker's looks at state.json, which a checkpoint writes last.
SNAPSHOT_INTERVAL_S = 1.0
#: Files of a run folder that hold paths of the spec (rewritten from the worker's to the driver's).
_JSON_SUFFIX = ".json"

#: ``{relative POSIX path: (mtime_ns, size)}``: what a folder held at one moment.
Listing = dict[str, tuple[int, int]]


@dataclasses.dataclass(frozen=True)
class RunPackage:
    """What a worker needs besides the demo pool: the driver's spec, the hyperparameter file's text,
    the run folder's files (relative POSIX paths; empty for a new run) and the driver's current folder,
    which the records' paths are relative to."""

    spec: RunSpec
    hyperparams_text: str
    files: Mapping[str, bytes]
    cwd: str = "."


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What a task returns: the outcome as the local backend reports it (driver paths), the run
    folder's files written or changed by the task, and those it deleted."""

    outcome: RunOutcome
    files: Mapping[str, bytes]
    removed: Sequence[str]


# -- the spec's paths ----------------------------------------------------------------------------------
def relocate(spec: RunSpec, root: Path) -> RunSpec:
    """``spec`` with its demo pool, hyperparameter file and run folder under ``root``.

    The only place that knows which RunSpec fields are paths; the files keep their names, so that a
    run's records and messages still name the pool and the YAML the user chose.
    """
    return dataclasses.replace(
        spec,
        demos=str(root / "demos" / Path(spec.demos).name),
        hyperparams=str(root / "hyperparams" / Path(spec.hyperparams).name),
        output_dir=str(root / "run"),
    )


def _moved_paths(original: RunSpec, relocated: RunSpec, driver_cwd: str) -> list[tuple[str, str]]:
    """``(worker path, driver path)`` of every field :func:`relocate` changed, longest first: each as the
    spec gives it, and each as the records write it (:func:`~sb3_cmzdril.io.portable_path`, relative to
    the worker's current folder and to the driver's ``driver_cwd``)."""
    pairs = {}
    for f in dataclasses.fields(original):
        worker, driver = str(getattr(relocated, f.name)), str(getattr(original, f.name))
        if worker != driver:
            pairs[portable_path(worker)] = portable_path(driver, driver_cwd)
            pairs[worker] = driver
    return sorted(pairs.items(), key=lambda pair: len(pair[0]), reverse=True)


def _restore_paths(value: Any, moved: Sequence[tuple[str, str]]) -> Any:
    """``value`` (JSON data) with the worker's paths replaced by the driver's.

    A string that is a path (or under one) gets the driver's path as it is; a path inside a longer
    string is an argument of a command line (config.json's train_command) and gets it shell-quoted.
    """
    if isinstance(value, dict):
        return {k: _restore_paths(v, moved) for k, v in value.items()}
    if isinstance(value, list):
        return [_restore_paths(v, moved) for v in value]
    if not isinstance(value, str):
        return value
    for worker, driver in moved:
        if value == worker or value.startswith(worker + "/"):
            return driver + value[len(worker):]
    for worker, driver in moved:
        value = value.replace(worker, shlex.quote(driver))
    return value


# -- a folder's files ----------------------------------------------------------------------------------
def _skipped(rel: PurePosixPath) -> bool:
    """The lock and the temporaries of atomic writes in progress belong to one machine's processes."""
    return rel.name == LOCK_FILE or (rel.name.startswith(".") and ".tmp" in rel.name)


def _listing(folder: Path) -> Listing:
    found: Listing = {}
    if not folder.is_dir():
        return found
    for path in folder.rglob("*"):
        rel = PurePosixPath(path.relative_to(folder).as_posix())
        if _skipped(rel):
            continue
        with contextlib.suppress(FileNotFoundError):  # replaced or removed while we looked
            stat = path.stat()
            if path.is_file():
                found[str(rel)] = (stat.st_mtime_ns, stat.st_size)
    return found


def read_files(folder: Path, names: Sequence[str], moved: Sequence[tuple[str, str]] = (),
               attempts: int = 20) -> dict[str, bytes]:
    """The named files of ``folder`` (relative paths), and every file of the checkpoint state.json
    records; JSON records with the worker's paths restored.

    A consistent copy of the checkpoint: state.json (which a checkpoint writes last) records the
    sha256 of each of the checkpoint's files, and the files are read again, a moment later, until each
    matches that record (a checkpoint written while they were read leaves a newer model beside an older
    record, which a resume would refuse). After ``attempts`` reads the last one is sent as it is; a
    file that vanished meanwhile is left out.
    """
    for attempt in range(attempts):
        files = _read(folder, names)
        record = _checkpoint_record(files)
        files.update(_read(folder, [name for name in record if name not in files]))
        if all(name in files and hashlib.sha256(files[name]).hexdigest() == digest
               for name, digest in record.items()) or attempt == attempts - 1:
            break
        time.sleep(0.05)
    if moved:
        for name in [n for n in files if n.endswith(_JSON_SUFFIX) and "/" not in n]:
            with contextlib.suppress(ValueError):  # a record cut short is sent as it is
                files[name] = (json.dumps(_restore_paths(json.loads(files[name]), moved), indent=2) + "\n").encode()
    return files


def _read(folder: Path, names: Sequence[str]) -> dict[str, bytes]:
    files: dict[str, bytes] = {}
    for name in names:
        with contextlib.suppress(FileNotFoundError):
            files[name] = (folder / name).read_bytes()
    return files


def _checkpoint_record(files: Mapping[str, bytes]) -> dict[str, str]:
    """file name -> sha256 of the checkpoint that the state.json among ``files`` records ({} without one)."""
    try:
        record = json.loads(files[STATE_FILE]).get(CHECKPOINT_KEY) or {}
        return {str(name): str(digest) for name, digest in (record.get("sha256") or {}).items()}
    except (KeyError, ValueError, AttributeError):
        return {}


def _inside(folder: Path, name: str) -> Path:
    rel = PurePosixPath(name)
    if rel.is_absolute() or not rel.parts or ".." in rel.parts:
        raise UserError(f"refusing to write {name!r}: not a path inside the run folder")
    return folder.joinpath(*rel.parts)


def write_files(folder: PathLike, files: Mapping[str, bytes], removed: Sequence[str] = ()) -> None:
    """Write ``files`` (relative paths) into ``folder``, each atomically, and delete ``removed``.

    state.json goes last, as a checkpoint writes it: the model beside it is never older than it says.
    """
    folder = Path(folder)
    for name, data in sorted(files.items(), key=lambda item: item[0] == STATE_FILE):
        with atomic_path(_inside(folder, name)) as tmp:
            tmp.write_bytes(data)
    for name in removed:
        with contextlib.suppress(FileNotFoundError):
            _inside(folder, name).unlink()


# -- the worker side -------------------------------------------------------------------------------------
class FolderSink:
    """A Ray actor on the driver's node that writes the checkpoints workers send into its runs folder."""

    def store(self, folder: str, files: Mapping[str, bytes], removed: Sequence[str]) -> None:
        write_files(folder, files, removed)

    def flush(self) -> None:
        """Returns once the stores this actor received before it are written (it runs one call at a time)."""


class _Snapshots:
    """Sends the run folder's changed files to a :class:`FolderSink` whenever state.json changes
    (a checkpoint was written), from a thread beside the training; waits for the last send on exit."""

    def __init__(
        self, folder: Path, driver_folder: str, moved: Sequence[tuple[str, str]], sink: Any, baseline: Listing
    ) -> None:
        self.folder, self.driver_folder, self.moved, self.sink = folder, driver_folder, moved, sink
        self.sent = dict(baseline)
        self.stop = threading.Event()
        self.pending: Any = None
        self.thread = threading.Thread(target=self._watch, name="run-folder-snapshots", daemon=True)

    def __enter__(self) -> _Snapshots:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()
        if self.pending is not None:
            import ray

            try:
                ray.get(self.pending, timeout=60)
            except Exception as e:  # the driver went away: the task's own result still carries the run
                logger.warning("could not send a checkpoint of %s to the driver: %s", self.driver_folder, e)

    def _watch(self) -> None:
        while not self.stop.wait(SNAPSHOT_INTERVAL_S):
            now = _listing(self.folder)
            if now.get(STATE_FILE) == self.sent.get(STATE_FILE):
                continue
            try:
                self._send(now)
            except Exception as e:  # the sink is gone: the run goes on, its result still comes back
                logger.warning("stopped sending checkpoints of %s to the driver: %s", self.driver_folder, e)
                return

    def _send(self, now: Listing) -> None:
        changed = [name for name, stamp in now.items() if self.sent.get(name) != stamp]
        removed = [name for name in self.sent if name not in now]
        files = read_files(self.folder, changed, self.moved)
        self.pending = self.sink.store.remote(self.driver_folder, files, removed)
        self.sent = {name: stamp for name, stamp in now.items() if name in files or name not in changed}


def run_shipped(package: RunPackage, pool: bytes, sink: Any = None) -> RunResult:
    """The Ray task: one run in a temporary directory of this worker, nothing read from the driver's disk."""
    driver_spec = package.spec
    with tempfile.TemporaryDirectory(prefix="sb3-cmzdril-run-") as tmp:
        spec = relocate(driver_spec, Path(tmp))
        out = Path(spec.output_dir)
        write_files(Path(spec.demos).parent, {Path(spec.demos).name: pool})
        write_files(Path(spec.hyperparams).parent, {Path(spec.hyperparams).name: package.hyperparams_text.encode()})
        write_files(out, package.files)
        moved = _moved_paths(driver_spec, spec, package.cwd)
        shipped = _listing(out)
        snapshots: contextlib.AbstractContextManager[Any] = contextlib.nullcontext()
        if sink is not None:
            snapshots = _Snapshots(out, driver_spec.output_dir, moved, sink, shipped)
        with snapshots:
            outcome = execute_run(spec)
        now = _listing(out)
        changed = [name for name, stamp in now.items() if shipped.get(name) != stamp]
        return RunResult(
            outcome=RunOutcome.from_dict(_restore_paths(outcome.as_dict(), moved)),
            files=read_files(out, changed, moved),
            removed=sorted(name for name in shipped if name not in now),
        )


# -- the driver side -------------------------------------------------------------------------------------
def pack_run(spec: RunSpec) -> RunPackage:
    """The driver's files of ``spec`` that a worker needs, except the demo pool (see :class:`RemoteRuns`)."""
    out = Path(spec.output_dir)
    return RunPackage(
        spec=spec,
        hyperparams_text=Path(spec.hyperparams).read_text(encoding="utf-8"),
        files=read_files(out, list(_listing(out))),
        cwd=os.getcwd(),
    )


def _ray_client(ray: Any) -> bool:
    """Whether this driver reaches the cluster through Ray Client (``ray://``), from another machine."""
    try:
        from ray.util.client import ray as client
    except ImportError:
        return False
    return bool(client.is_connected())


class RemoteRuns:
    """Submits runs as Ray tasks with one CPU each and writes their results into the driver's folders."""

    def __init__(self, ray: Any) -> None:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        self.ray = ray
        # max_retries=0: a run that crashed its worker is reported, not silently restarted.
        self.task = ray.remote(num_cpus=1, max_retries=0)(run_shipped)
        self.sink: Any = None
        if not _ray_client(ray):  # a Ray Client driver's node is the head, not this machine
            here = NodeAffinitySchedulingStrategy(node_id=ray.get_runtime_context().get_node_id(), soft=False)
            self.sink = ray.remote(num_cpus=0)(FolderSink).options(scheduling_strategy=here).remote()
        self.pools: dict[tuple[str, int], Any] = {}
        self.in_flight: dict[Any, tuple[RunSpec, OutputLock | None]] = {}

    def _pool(self, path: str) -> Any:
        """The pool's bytes in the object store, put there once per version of the file."""
        key = (path, file_mtime_ns(path))
        if key not in self.pools:
            self.pools[key] = self.ray.put(Path(path).read_bytes())
        return self.pools[key]

    def submit(self, spec: RunSpec) -> Any:
        """Start ``spec``'s run on some worker; returns the handle for :meth:`result`."""
        out = Path(spec.output_dir)
        out.mkdir(parents=True, exist_ok=True)
        try:
            lock = lock_output(out)
        except ValueError as e:  # as the local backend reports it, from run_experiment's own lock
            handle = self.ray.put(RunResult(RunOutcome.of(spec, RunStatus.FAILED, 0.0, f"ValueError: {e}"), {}, []))
            self.in_flight[handle] = (spec, None)
            return handle
        try:
            handle = self.task.remote(pack_run(spec), self._pool(spec.demos), self.sink)
        except BaseException:
            unlock_output(out, lock)
            raise
        self.in_flight[handle] = (spec, lock)
        return handle

    def result(self, handle: Any) -> RunOutcome:
        """The run's outcome, once its files are in the driver's run folder; raises what the task raised."""
        spec, lock = self.in_flight.pop(handle)
        out = Path(spec.output_dir)
        try:
            try:
                result: RunResult = self.ray.get(handle)
            except BaseException:
                # A killed worker's last checkpoint may still be on its way: let it land before the
                # folder is unlocked, so that nothing writes into it once another run may own it.
                if self.sink is not None:
                    with contextlib.suppress(Exception):
                        self.ray.get(self.sink.flush.remote(), timeout=60)
                raise
            write_files(out, result.files, result.removed)
            return result.outcome
        finally:
            unlock_output(out, lock)


__all__ = ["FolderSink", "RemoteRuns", "RunPackage", "RunResult", "pack_run", "read_files", "relocate",
           "run_shipped", "write_files"]
