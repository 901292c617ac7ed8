"""sb3_cmzdril.io: atomic writes (with the umask's permissions, the umask left alone), JSON records,
folder locks, provenance."""
from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sb3_cmzdril import io


@pytest.mark.slow
def test_import_and_write_leave_the_umask_alone_and_apply_it(tmp_path):
    # A fresh interpreter with a umask of its own, in which os.umask records every call: importing
    # the package and writing a file must not call it (another thread could create a file in that
    # instant with mask 0), and the file gets exactly the umask's permissions.
    script = textwrap.dedent(
        f"""
        import os, stat
        os.umask(0o027)
        calls = []
        real_umask = os.umask
        os.umask = lambda mask: calls.append(mask) or real_umask(mask)
        import sb3_cmzdril
        from sb3_cmzdril.io import atomic_write_text, current_umask
        atomic_write_text({str(tmp_path / "out.txt")!r}, "x")
        print(calls, oct(current_umask()), oct(stat.S_IMODE(os.stat({str(tmp_path / "out.txt")!r}).st_mode)))
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    if not Path("/proc/self/status").is_file():  # pragma: no cover - other systems use the fallback
        pytest.skip("no /proc/self/status: the umask is read by setting it")
    assert result.stdout.split() == ["[]", "0o27", "0o640"]


def test_umask_fallback_where_proc_is_absent(tmp_path, monkeypatch):
    monkeypatch.setattr(io, "_PROC_STATUS", tmp_path / "no-such-file")
    io._umask_by_setting.cache_clear()
    previous = os.umask(0o077)
    try:
        assert io.current_umask() == 0o077
        assert os.umask(0o077) == 0o077  # put back as it was
    finally:
        os.umask(previous)
        io._umask_by_setting.cache_clear()


def test_atomic_write_replaces_whole_or_not_at_all(tmp_path):
    path = tmp_path / "sub" / "result.txt"
    io.atomic_write_text(path, "first")
    with pytest.raises(RuntimeError):
        with io.atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash mid-write")
    assert path.read_text() == "first"
    assert sorted(p.name for p in path.parent.iterdir()) == ["result.txt"]  # no temporary left
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~io.current_umask()


def test_suffix_keeps_the_writers_extension(tmp_path):
    with io.atomic_path(tmp_path / "d.npz", suffix=".npz") as tmp:
        assert tmp.name.endswith(".npz") and tmp.name.startswith(".d.npz.")
        np.savez(tmp, a=np.arange(3))
    with np.load(tmp_path / "d.npz") as data:
        assert list(data["a"]) == [0, 1, 2]


def test_remove_stale_temporaries_removes_only_temporaries(tmp_path):
    (tmp_path / ".model.zip.abc.tmp.zip").write_bytes(b"half")
    (tmp_path / ".eval.csv.k3x9_q2a.tmp").write_bytes(b"half")
    (tmp_path / "model.zip").write_bytes(b"whole")
    (tmp_path / ".lock").write_text("")
    # Issue 30, cause 1: hidden files of the user's with ".tmp" in their names are not ours to remove.
    for name in (".draft.tmp.md", ".notes.x.tmp.md", ".tmp", ".x.tmp"):
        (tmp_path / name).write_text("the user's")
    io.remove_stale_temporaries(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".draft.tmp.md", ".lock", ".notes.x.tmp.md", ".tmp",
                                                          ".x.tmp", "model.zip"]
    with io.atomic_path(tmp_path / "d.npz", suffix=".npz") as tmp:
        assert io.is_temporary(tmp.name)  # what atomic_path makes is what it removes


def _dead_pid() -> int:
    """The id of a process that has ended (and been waited for)."""
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                           check=True)
    return int(child.stdout)


def test_temporaries_name_their_writer_and_only_dead_writers_lose_them(tmp_path, caplog):
    """A hard kill leaves an atomic write's temporary; its name carries the writer's process id, so the
    next run removes those of processes that have ended (saying so) and keeps those of live ones."""
    with io.atomic_path(tmp_path / "d.npz", suffix=".npz") as tmp:
        assert tmp.name.startswith(f".d.npz.{os.getpid()}-") and io.is_temporary(tmp.name)
    dead = tmp_path / f".pool.npz.{_dead_pid()}-k3x9_q2a.tmp.npz"
    live = tmp_path / f".pool.npz.{os.getppid()}-k3x9_q2a.tmp.npz"  # the process that started this one
    legacy = tmp_path / ".model.zip.abc.tmp.zip"  # no id: written before ids, removed under the lock
    for path in (dead, live, legacy):
        path.write_bytes(b"half")
    caplog.set_level("INFO", logger="sb3_cmzdril")
    assert sorted(io.remove_stale_temporaries(tmp_path)) == sorted([dead, legacy])
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, "d.npz"]
    (line,) = [r.getMessage() for r in caplog.records if r.name == "sb3_cmzdril.io"]
    assert "removed 2 temporary files" in line and dead.name in line


def test_jsonable_and_round_trip(tmp_path):
    data = {"a": np.float32(0.5), "b": (1, np.int64(2)), "c": float("inf"), "d": Path, 3: None, "e": [True]}
    expected = {"a": 0.5, "b": [1, 2], "c": "inf", "d": "pathlib.Path", "3": None, "e": [True]}
    assert io.jsonable(data) == expected
    assert io.jsonable(len).startswith("<built-in function len")  # anything else: by its repr
    io.write_json(tmp_path / "r.json", data)
    assert io.read_json(tmp_path / "r.json") == expected
    assert (tmp_path / "r.json").read_text().endswith("}\n")


def test_read_json_names_a_corrupt_file_and_or_empty_forgives(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"a": ')
    with pytest.raises(ValueError, match="bad.json is unreadable or corrupt"):
        io.read_json(bad)
    with pytest.raises(ValueError, match="missing.json is unreadable or corrupt"):
        io.read_json(tmp_path / "missing.json")
    (tmp_path / "list.json").write_text(json.dumps([1, 2]))
    for path in (bad, tmp_path / "missing.json", tmp_path / "list.json"):
        assert io.read_json_or_empty(path) == {}


def test_lock_is_exclusive_and_released(tmp_path):
    held = io.lock_output(tmp_path)
    try:
        with pytest.raises(io.LockHeld, match=r"another process is already running in .* \(lock .*\.lock\)"):
            io.lock_output(tmp_path)
        with pytest.raises(ValueError, match="^busy$"):  # a UserError, so a ValueError to older callers
            io.lock_output(tmp_path, "busy")
    finally:
        io.unlock_output(tmp_path, held)
    io.unlock_output(tmp_path, io.lock_output(tmp_path))  # free again
    io.unlock_output(tmp_path, None)  # a lock never taken: nothing to do


_OTHER_PROCESS = textwrap.dedent("""
    import sys
    from sb3_cmzdril import io
    try:
        io.unlock_output(sys.argv[1], io.lock_output(sys.argv[1]))
    except io.LockHeld as e:
        print(e)
        sys.exit(3)
""")


def _lock_in_another_process(folder: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _OTHER_PROCESS, str(folder)], capture_output=True, text=True,
                          timeout=120)


def test_a_second_process_fails_at_once_naming_the_folder_and_gets_it_once_released(tmp_path):
    held = io.lock_output(tmp_path)
    try:
        other = _lock_in_another_process(tmp_path)
        assert other.returncode == 3, other.stderr
        assert other.stdout.strip() == f"another process is already running in {tmp_path} (lock {tmp_path / '.lock'})"
    finally:
        io.unlock_output(tmp_path, held)
    # The lock file stays (removing a locked path is what lets two processes hold "the same" lock);
    # only the lock counts, and it is free.
    assert (tmp_path / io.LOCK_FILE).is_file()
    other = _lock_in_another_process(tmp_path)
    assert other.returncode == 0, other.stdout + other.stderr


def test_a_lock_dies_with_its_process(tmp_path):
    # A holder killed without any chance to clean up (SIGKILL) leaves no lock behind.
    script = ("import sys, time; from sb3_cmzdril import io; lock = io.lock_output(sys.argv[1]); "
              "print('held', flush=True); time.sleep(600)")  # the lock kept referenced: dropped, it is released
    holder = subprocess.Popen([sys.executable, "-c", script, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        assert _lock_in_another_process(tmp_path).returncode == 3
    finally:
        holder.kill()
        holder.wait(timeout=60)
    assert _lock_in_another_process(tmp_path).returncode == 0


def test_signals_during_an_atomic_write_wait_for_its_end(tmp_path):
    path = tmp_path / "checkpoint.bin"
    io.atomic_write_text(path, "previous")
    # Python raises KeyboardInterrupt on SIGINT only if the process did not start with SIGINT ignored,
    # as a non-interactive runner (a background job, nohup, some CI shells) starts it; there the
    # signal stays ignored, rightly, and nothing would be raised. Ctrl-C as a terminal delivers it:
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with io.atomic_path(path) as tmp:
                signal.raise_signal(signal.SIGINT)  # Ctrl-C in the middle of the write
                tmp.write_text("complete")
        assert path.read_text() == "complete"  # the write finished, then the interruption came
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.bin"]
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_deferred_signals_nest_and_leave_ignored_signals_ignored(tmp_path):
    received: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: received.append(signum))
    try:
        with io.deferred_signals():
            with io.deferred_signals():
                signal.raise_signal(signal.SIGTERM)
                assert received == []
            assert received == []  # the inner block hands it to the outer one
        assert received == [signal.SIGTERM]
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        with io.deferred_signals():
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_provenance():
    assert io.command_line(["sb3-cmzdril", "train", "--env", "a b"]) == "sb3-cmzdril train --env 'a b'"
    found = io.versions()
    for key in ("python", "sb3_cmzdril", "stable_baselines3", "gymnasium", "torch", "numpy", "mujoco"):
        assert found[key]


def test_records_carry_no_absolute_paths_of_the_machine(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert io.portable_path(tmp_path / "runs" / "a") == "runs/a"
    assert io.portable_path(tmp_path) == "."
    assert io.portable_path("/elsewhere/pool.npz") == "/elsewhere/pool.npz"  # no portable form
    # relative to another folder (a Ray worker writes records for a driver whose folder differs)
    assert io.portable_path(tmp_path / "runs" / "a", cwd=tmp_path / "runs") == "a"
    assert io.portable_path("runs/a", cwd="/driver") == "runs/a"
    assert io.portable_path("/driver/runs/a", cwd="/driver") == "runs/a"
    line = io.command_line(["/opt/py/bin/sb3-cmzdril", "train", "-o", str(tmp_path / "out"), "--env", "a b"])
    assert line == "sb3-cmzdril train -o out --env 'a b'"
    assert io.command_line(["/site/sb3_cmzdril/__main__.py", "report"]) == "sb3-cmzdril report"
    assert io.command_line(["/site/sb3_cmzdril/cli/__main__.py", "report"]) == "sb3-cmzdril report"
