"""The watchdog that ends a local Ray instance with the process that started it (grid.py's Ray
backend), on stand-in processes: fast, no Ray. tests/test_ray_cluster.py kills a real benchmark's Ray."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import pytest

from cmzdril_lab.run._ray_watchdog import descendants

pytestmark = [pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="the watchdog reads /proc (Linux)"),
              pytest.mark.xdist_group("ray")]  # one worker for every Ray test (tests/test_ray_cluster.py)

#: A stand-in driver: starts the watchdog, then a child and a grandchild that, like Ray's agents,
#: is left to PID 1 once its parent exits; with argument "stop" it stops the watchdog as the backend's
#: close() does.
DRIVER = textwrap.dedent(
    """
    import subprocess, sys, time
    from cmzdril_lab.run.grid import start_ray_watchdog, stop_ray_watchdog

    watchdog = start_ray_watchdog()
    child = subprocess.Popen(["sleep", "300"])
    # sh starts sleep in the background and exits two seconds later: the grandchild's parent is gone
    # before the driver, as the raylet is (killed with its parent) before Ray's agents are.
    subprocess.Popen(["sh", "-c", "sleep 301 > /dev/null 2>&1 & sleep 2"])
    time.sleep(4)  # the watchdog records every second
    if sys.argv[1] == "stop":
        stop_ray_watchdog(watchdog)
    print("READY", flush=True)
    time.sleep(600)
    """
)


#: The environment variable that marks one driver's processes: a suite running beside this one (another
#: checkout's CI) starts sleepers of its own, with their own mark.
MARK = "SB3_CMZDRIL_WATCHDOG_TEST"


def _sleepers(mark: str) -> dict[int, int]:
    """Running ``sleep 300`` / ``sleep 301`` processes started by the driver marked ``mark``: pid -> start time."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
            environ = Path(f"/proc/{entry}/environ").read_bytes().split(b"\0")
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        if cmdline[:2] in ([b"sleep", b"300"], [b"sleep", b"301"]) and f"{MARK}={mark}".encode() in environ:
            found[int(entry)] = int(stat[stat.rfind(")") + 2:].split()[19])
    return found


def _alive(processes: dict[int, int]) -> list[int]:
    alive = []
    for pid, started in processes.items():
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()
        if int(fields[19]) == started and fields[0] != "Z":
            alive.append(pid)
    return alive


def _start_driver(mode: str) -> tuple[subprocess.Popen[str], dict[int, int]]:
    mark = uuid.uuid4().hex
    driver = subprocess.Popen([sys.executable, "-c", DRIVER, mode], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), MARK: mark})
    assert driver.stdout is not None and driver.stdout.readline().strip() == "READY"
    ours = _sleepers(mark)
    assert len(ours) == 2
    return driver, ours


def _kill(driver: subprocess.Popen[str], processes: dict[int, int]) -> None:
    for pid in _alive(processes):
        os.kill(pid, signal.SIGKILL)
    driver.kill()
    driver.wait()


def test_a_killed_driver_takes_its_descendants_with_it():
    driver, ours = _start_driver("run")
    try:
        assert set(ours) <= set(descendants(driver.pid)) | set(_alive(ours))
        driver.send_signal(signal.SIGKILL)
        driver.wait()
        deadline = time.monotonic() + 10
        while _alive(ours) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _alive(ours) == []
    finally:
        _kill(driver, ours)


def test_a_stopped_watchdog_ends_nothing():
    # The backend shut Ray down itself and said stop: what the driver runs afterwards is its own.
    driver, ours = _start_driver("stop")
    try:
        driver.send_signal(signal.SIGKILL)
        driver.wait()
        time.sleep(2)
        assert sorted(_alive(ours)) == sorted(ours)
    finally:
        _kill(driver, ours)


def _command(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
    except OSError:
        return ""


# Here rather than beside the cluster tests: a local Ray instance another test still runs would be found by
# ray.init() and joined instead of started.
@pytest.mark.slow
def test_a_killed_benchmark_leaves_no_ray_process():
    """``kill -9`` of a process running the Ray backend on a local instance: every process of that
    instance is gone within seconds (Ray alone leaves its DashboardAgent and RuntimeEnvAgent for a
    minute). About 30 s on a loaded 2-core machine, most of it Ray starting."""
    import os
    import signal
    import subprocess
    import sys

    from cmzdril_lab.run._ray_watchdog import descendants

    pytest.importorskip("ray", reason="the Ray backend is in the 'ray' and 'test' extras")
    if not Path("/proc/self/stat").is_file():
        pytest.skip("the watchdog reads /proc (Linux)")
    script = (
        "import time\n"
        "from cmzdril_lab.run.grid import _RayBackend\n"
        "backend = _RayBackend(1, None)\n"
        "print('UP', flush=True)\n"
        "time.sleep(600)\n"
    )
    driver = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                              # A cluster another test of this module started exports RAY_ADDRESS: this driver must
                              # start its own local instance, as a plain benchmark does.
                              env={**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"},
                                   "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
                              start_new_session=True)
    started: dict[int, int] = {}
    try:
        assert driver.stdout is not None and driver.stdout.readline().strip() == "UP"
        deadline = time.monotonic() + 30
        names: set[str] = set()
        # The raylet starts its agents a moment after ray.init returns.
        while not {"ray::DashboardAgent", "ray::RuntimeEnvAgent"} <= names and time.monotonic() < deadline:
            time.sleep(0.5)
            started = descendants(driver.pid)
            names = {_command(pid) for pid in started}
        assert {"ray::DashboardAgent", "ray::RuntimeEnvAgent"} <= names, names
        time.sleep(1.5)  # the watchdog records every second
        driver.send_signal(signal.SIGKILL)
        driver.wait()
        deadline = time.monotonic() + 15
        while _alive(started) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert {_command(pid) for pid in _alive(started)} == set()
    finally:
        for pid in _alive(started):
            os.kill(pid, signal.SIGKILL)
        driver.kill()
        driver.wait()
