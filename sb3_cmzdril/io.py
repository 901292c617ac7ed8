"""Shared file utilities: atomic writes, JSON records, folder locks and provenance.

Every module that writes results (experts, demo pools, runs, reports) uses these, so that a reader
never sees a half-written file, JSON records look the same everywhere, and one process at a time
works in a folder.

Atomic writes go to a temporary file in the destination folder (same filesystem, so the final
``os.replace`` is atomic), are flushed to disk, then renamed over the destination. A hard kill can
leave such a temporary behind; its name carries the id of the process that wrote it, and
:func:`remove_stale_temporaries` clears those of processes that have ended once the folder's lock is
held. SIGINT and SIGTERM that arrive during an atomic write are delivered when it ends
(:func:`deferred_signals`), so Ctrl-C never cuts a write in the middle.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import logging
import math
import os
import platform
import re
import shlex
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Union

import filelock
import numpy as np

from sb3_cmzdril.errors import UserError

PathLike = Union[str, "os.PathLike[str]"]

logger = logging.getLogger(__name__)

#: Name of the lock file :func:`lock_output` holds in a folder.
LOCK_FILE = ".lock"

_PROC_STATUS = Path("/proc/self/status")


# -- signals ---------------------------------------------------------------------------------------
#: Signals that :func:`deferred_signals` holds back: Ctrl-C and a polite kill.
DEFERRED_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def deferred_signals() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back until the block ends, then deliver them to the handlers they had.

    torch.save and zipfile write through Python callbacks: a KeyboardInterrupt raised in one of them
    comes out of torch as a RuntimeError, with a traceback instead of the command line's one line.
    Deferring the signal lets a write finish (or fail) on its own; the interruption follows at once.
    Signal handlers belong to the main thread: in any other thread the block runs as it is. Blocks
    nest (an inner one hands what it held to the outer one's handler). A signal that is ignored
    stays ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        pending.append(signum)

    previous: dict[signal.Signals, Any] = {}
    for sig in DEFERRED_SIGNALS:
        handler = signal.getsignal(sig)
        if handler is signal.SIG_IGN or handler is None:  # None: a handler not set from Python
            continue
        previous[sig] = handler
        signal.signal(sig, hold)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for signum in dict.fromkeys(pending):
            signal.raise_signal(signum)


# -- atomic writes ---------------------------------------------------------------------------------
def current_umask() -> int:
    """The process's file-creation mask, read without changing it.

    Linux reports it in ``/proc/self/status`` (``Umask:`` line). Elsewhere the only way is to set a
    mask and put the old one back, which for that instant changes the mask of every thread of the
    process; that is done once and remembered.
    """
    try:
        for line in _PROC_STATUS.read_text(encoding="ascii").splitlines():
            if line.startswith("Umask:"):
                return int(line.split(":", 1)[1].strip(), 8)
    except (OSError, ValueError):
        pass
    return _umask_by_setting()


@functools.lru_cache(maxsize=1)
def _umask_by_setting() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path to write to; on success it replaces ``path`` atomically.

    ``suffix`` is appended to the temporary name so that writers which insist on an extension
    (``np.savez`` adds ``.npz``, SB3 adds ``.zip`` when there is none) keep the name we chose.
    The name also carries this process's id (:data:`_TEMPORARY`), so that a temporary which a hard
    kill leaves behind is known for one (:func:`remove_stale_temporaries`).
    On any exception the temporary file is removed and ``path`` is left untouched. SIGINT and
    SIGTERM wait until the write is over (:func:`deferred_signals`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with deferred_signals():
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}-",
                                        suffix=f".tmp{suffix}")
        os.close(fd)
        tmp = Path(tmp_name)
        # mkstemp makes 0600 files; results should be readable like any other file the process writes.
        os.chmod(tmp, 0o666 & ~current_umask())
        try:
            yield tmp
            with open(tmp, "rb") as f:
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            raise


def atomic_write_text(path: PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


#: An :func:`atomic_path` temporary: ``.<name>.<pid>-<mkstemp's random part>.tmp<suffix>``, where the
#: suffix is none or the extension of ``<name>`` (``.d.npz.4242-k3x9_q2a.tmp.npz``). Earlier releases
#: wrote no ``<pid>-``; those names still count.
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?:(?P<pid>[0-9]+)-)?[A-Za-z0-9_]+\.tmp(?P<suffix>.*)$")


def is_temporary(name: str) -> bool:
    """Whether a file name is one of :func:`atomic_path`'s temporaries.

    Exactly that form, not any hidden file with ".tmp" in its name: a user's ``.draft.tmp.md`` in an
    output folder is theirs, and neither counts as the command's own nor is removed.
    """
    match = _TEMPORARY.match(name)
    return match is not None and match["suffix"] in ("", Path(match["name"]).suffix)


def process_alive(pid: int) -> bool | None:
    """Whether process ``pid`` of this machine is running (this process included); None where that cannot
    be asked without harm: on a system without POSIX signals ``os.kill(pid, 0)`` would end the process."""
    if os.name != "posix":
        return None
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: the process exists, under another user
        return True
    return True


def _writer_alive(name: str) -> bool:
    """Whether the process a temporary's name says wrote it may still be writing it.

    A name without a process id (an older release's) and a process that has ended count as not, and so
    does any where :func:`process_alive` cannot tell: the folder's lock alone decides there, as it did
    before names carried ids.
    """
    match = _TEMPORARY.match(name)
    return match is not None and match["pid"] is not None and bool(process_alive(int(match["pid"])))


def remove_stale_temporaries(*folders: Path) -> list[Path]:
    """Remove the temporaries of atomic writes cut short by a hard kill (:func:`is_temporary`), and
    log one line naming them; return them.

    Only those whose writer has ended (:func:`_writer_alive`) go: a process that writes in the folder
    without its lock (a user's script saving a pool there) keeps its temporary. Call it only while
    holding the folder's lock, which keeps the commands' own writers out: a process id says nothing
    of the processes of another machine sharing the folder, and ids are reused.
    """
    removed = []
    for folder in folders:
        for p in sorted(Path(folder).glob(".*.tmp*")):
            if p.is_file() and is_temporary(p.name) and not _writer_alive(p.name):
                with contextlib.suppress(OSError):
                    p.unlink()
                    removed.append(p)
    if removed:
        logger.info("removed %d temporary %s that a write cut short left behind: %s", len(removed),
                    "file" if len(removed) == 1 else "files", ", ".join(str(p) for p in removed))
    return removed


def file_sha256(path: PathLike) -> str:
    """The file's sha256 (hex): a run's fingerprint of its demo pool, a checkpoint's of its files."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# -- JSON ------------------------------------------------------------------------------------------
def _public_name(cls: type) -> str:
    """``module.Class`` by the public module that exports the class: Python 3.13 defines
    ``pathlib.Path`` in ``pathlib._local``, and a record must not depend on the Python that wrote it."""
    parts = cls.__module__.split(".")
    while len(parts) > 1 and parts[-1].startswith("_"):
        parent = sys.modules.get(".".join(parts[:-1]))
        if getattr(parent, cls.__qualname__, None) is not cls:
            break
        parts.pop()
    return f"{'.'.join(parts)}.{cls.__qualname__}"


def jsonable(value: Any) -> Any:
    """``value`` as JSON data: classes by qualified name, numpy scalars as Python numbers,
    non-finite floats as strings, anything else unknown (schedules, callables) by its repr."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, type):
        return _public_name(value)
    return repr(value)


def write_json(path: PathLike, data: dict[str, Any]) -> None:
    """Write ``data`` (made :func:`jsonable`) to ``path`` atomically, indented, keys in order."""
    atomic_write_text(path, json.dumps(jsonable(data), indent=2, sort_keys=False) + "\n")


def read_json(path: PathLike) -> dict[str, Any]:
    """The JSON object in ``path``; a ValueError naming the file when it is unreadable, corrupt, or
    holds something else than an object (a hand-edited list or null would fail later, unnamed)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise UserError(f"{path} is unreadable or corrupt: {e}") from e
    if not isinstance(data, dict):
        kind = "null" if data is None else {list: "array", str: "string", bool: "boolean"}.get(type(data), "number")
        raise UserError(f"{path} is not what sb3-cmzdril wrote: it holds a JSON {kind}, not an object")
    return data


def read_json_or_empty(path: PathLike) -> dict[str, Any]:
    """A JSON object file, or {} when it is missing, unreadable or not an object."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


# -- locks -----------------------------------------------------------------------------------------
#: What :func:`lock_output` returns and :func:`unlock_output` takes.
OutputLock = filelock.BaseFileLock


class LockHeld(UserError):
    """Another process holds the folder's lock (:func:`lock_output`)."""


def lock_output(folder: PathLike, message: str | None = None, name: str = LOCK_FILE) -> OutputLock:
    """Hold an exclusive lock on ``folder`` (its file ``name``, :data:`LOCK_FILE` by default) until
    :func:`unlock_output`; fail at once, never wait, when another process holds it.

    The lock is filelock's: the operating system's (``flock`` on POSIX, ``LockFileEx`` on Windows),
    so it ends with the process, however it ends. On POSIX the lock file stays after the release:
    removing a locked path lets a waiter that opened it lock the removed file while a newcomer locks
    a new one, and both would believe they hold the folder.

    Keep the returned lock referenced until :func:`unlock_output`: filelock releases a lock that is
    garbage-collected.

    :param message: the :class:`LockHeld` error's text when another process holds the lock.
    :raises LockHeld: another process holds it.
    """
    path = Path(folder) / name
    # thread_local=False: the grid may take a run's lock in one thread and let it go in another.
    lock = filelock.FileLock(str(path), timeout=0, thread_local=False)
    try:
        lock.acquire()
    except filelock.Timeout:
        raise LockHeld(message or f"another process is already running in {folder} (lock {path})") from None
    return lock


def unlock_output(folder: PathLike, handle: OutputLock | None) -> None:
    """Release a lock of :func:`lock_output` (None, a lock never taken: nothing to do)."""
    if handle is not None:
        handle.release()


# -- provenance ------------------------------------------------------------------------------------
def versions() -> dict[str, str]:
    """Versions of Python and of the packages that decide a result, for metadata records."""
    import gymnasium as gym
    import stable_baselines3
    import torch

    from sb3_cmzdril._version import __version__

    found = {
        "python": platform.python_version(),
        "sb3_cmzdril": __version__,
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gym.__version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
    }
    try:
        import mujoco

        found["mujoco"] = mujoco.__version__
    except ImportError:  # the mujoco extra is optional (classic control, WaypointNav)
        found["mujoco"] = "not installed"
    return found


def cpu_model() -> str:
    """The processor's model name (Linux: /proc/cpuinfo's ``model name``), or the architecture where
    the system does not say."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                key, sep, value = line.partition(":")
                if sep and key.strip() == "model name" and value.strip():
                    return value.strip()
    except OSError:  # not Linux
        pass
    return platform.processor() or platform.machine() or "unknown"


def cpu_capability() -> str:
    """The instruction set torch dispatches its CPU kernels for ("AVX2", "AVX512", "DEFAULT"...); torch
    before 2.1 does not say."""
    import torch

    backend = getattr(torch.backends, "cpu", None)
    return str(backend.get_cpu_capability()) if backend is not None else "unknown (torch < 2.1)"


def machine() -> dict[str, Any]:
    """The machine a run segment ran on, for its CPU time to be read against: the same steps took
    twice the CPU time on one day's machine as on another's, and rounded differently. Two machines
    with the same model name can still differ in the instruction set torch dispatches its CPU kernels
    for (``cpu_capability``: AVX2, AVX512...), and with it in how a kernel rounds."""
    import torch

    return {
        "cpu": cpu_model(),
        "cpu_capability": cpu_capability(),
        "logical_cpus": os.cpu_count() or 0,
        "torch_threads": torch.get_num_threads(),
        "os": f"{platform.system()} {platform.release()}",
    }


def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether two paths name one file: the same path once links are followed, or (both existing)
    the same file under two names (a hard link, a case-insensitive filesystem)."""
    if Path(a).resolve() == Path(b).resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist
        return False


def portable_path(path: PathLike, cwd: PathLike | None = None) -> str:
    """``path`` as a record stores it: relative to the current folder (or ``cwd``) when it lies below it.

    Run records are committed and shared, so they must not carry the absolute paths of the machine
    that made them; a path outside that folder has no portable form and stays as it is.
    """
    base = Path(os.path.abspath(cwd if cwd is not None else Path.cwd()))
    absolute = Path(os.path.abspath(base / path))
    try:
        return absolute.relative_to(base).as_posix() or "."
    except ValueError:
        return str(path)


def command_line(argv: Sequence[str] | None = None) -> str:
    """The command line as typed (``sys.argv`` by default), shell-quoted, in portable form.

    The program is named as a user types it (``sb3-cmzdril``, not the interpreter's absolute path
    to the console script or to the ``__main__.py`` of ``python -m sb3_cmzdril`` or ``python -m
    sb3_cmzdril.cli``), and absolute arguments below the current folder become relative
    (:func:`portable_path`).
    """
    args = list(sys.argv if argv is None else argv)
    if args:
        program = Path(args[0])
        if program.name == "sb3-cmzdril" or program.parts[-2:] == ("sb3_cmzdril", "__main__.py") \
                or program.parts[-3:] == ("sb3_cmzdril", "cli", "__main__.py"):
            args[0] = "sb3-cmzdril"
    return shlex.join([portable_path(a) if os.path.isabs(a) else a for a in args])
