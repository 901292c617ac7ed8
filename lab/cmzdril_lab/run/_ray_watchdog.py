"""Ends the processes of a local Ray instance when the process that started it dies (Linux).

Run as a script, ``python _ray_watchdog.py PID``, by the grid's Ray backend (``_RayBackend`` in
:mod:`.grid`), with the read end of a pipe as its standard input; the backend holds the write end.

Why: ``ray.init()`` without an address starts GCS, raylet and helpers that die with the driver, but
the raylet's DashboardAgent and RuntimeEnvAgent, on finding the raylet gone, report it to the GCS,
which is gone too, and wait out Ray's GCS reconnect timeout (about 60 s) under PID 1 before they exit.
Nothing of Ray's ends them sooner without shortening that timeout for the driver as well.

How: every second it records the descendants of ``PID`` (with their start times, so a reused pid is
never mistaken for one of them). End of file on standard input means ``PID`` is gone however it ended
(SIGKILL included): it sends SIGKILL to every recorded descendant still running and exits. A line
``stop`` means the backend shut Ray down itself: it exits without touching anything.

Standalone on purpose: it imports no part of sb3_cmzdril (whose ``__init__`` imports torch), so it
starts in milliseconds and costs a few MB. Only the standard library and ``/proc``.
"""
from __future__ import annotations

import os
import select
import signal
import sys
from pathlib import Path

#: Seconds between two recordings of the descendants.
INTERVAL_S = 1.0


def _stat(pid: int) -> tuple[int, int] | None:
    """``(parent pid, start time in clock ticks)`` of a running process, or None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) is in parentheses and may hold spaces: fields are counted after it.
    fields = text[text.rfind(")") + 2:].split()
    return int(fields[1]), int(fields[19])


def descendants(root: int) -> dict[int, int]:
    """The running descendants of ``root``: pid -> start time."""
    parents: dict[int, list[int]] = {}
    started: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            stat = _stat(int(entry))
            if stat is not None:
                parents.setdefault(stat[0], []).append(int(entry))
                started[int(entry)] = stat[1]
    found: dict[int, int] = {}
    stack = [root]
    while stack:
        for child in parents.get(stack.pop(), []):
            if child not in found and child in started:
                found[child] = started[child]
                stack.append(child)
    return found


def kill_recorded(recorded: dict[int, int]) -> None:
    """SIGKILL every recorded process that still runs with the start time it was recorded with."""
    for pid, started in recorded.items():
        stat = _stat(pid)
        if pid != os.getpid() and stat is not None and stat[1] == started:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:  # it exited in between
                pass


def watch(root: int) -> None:
    """Record ``root``'s descendants until standard input ends (kill them) or says ``stop``."""
    recorded: dict[int, int] = {}
    stdin = sys.stdin.fileno()
    while True:
        # Processes found once are kept: Ray's agents are reparented to PID 1 when the raylet dies.
        recorded.update(descendants(root))
        ready, _, _ = select.select([stdin], [], [], INTERVAL_S)
        if not ready:
            continue
        line = os.read(stdin, 64)
        if line.strip() == b"stop":
            return
        if not line:
            kill_recorded(recorded)
            return


def main(argv: list[str]) -> int:
    if len(argv) != 2 or not argv[1].isdigit():
        print("usage: _ray_watchdog.py PID (standard input: the pipe whose end means PID is gone)", file=sys.stderr)
        return 2
    # Ctrl-C in the terminal reaches the whole foreground group: the driver handles it and says stop.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch(int(argv[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
