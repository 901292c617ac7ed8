"""Faults: a run killed (SIGKILL, SIGINT, SIGTERM) at several points and resumed ends exactly where
the same run stopped cleanly at the same checkpoints ends; a killed benchmark leaves no process
behind; a run another benchmark holds is skipped, not failed.

The runs are test_experiments' tiny Pendulum runs; the killed ones are real `sb3-cmzdril` processes.
"""
from __future__ import annotations

import io as text_io
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from test_experiments import ENV, Interrupt
from test_experiments import setup as _tiny_paths  # noqa: F401  (registers that module's fixture here)

from sb3_cmzdril import io
from sb3_cmzdril.cli import main
from sb3_cmzdril.experiments import grid
from sb3_cmzdril.experiments.runs import latest_epoch, plan_run, run_experiment

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and process groups")

EPOCH = 64  # n_steps of TINY_YAML, one env
CHECKPOINT_EVERY = 2
TIMESTEPS = 12 * EPOCH
REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def tiny(request) -> dict[str, Path]:
    """test_experiments' demo pool (<demos_dir>/<EnvName>/demos.npz) and tiny hyperparameters."""
    return request.getfixturevalue("_tiny_paths")


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))


def _start(paths: dict[str, Path], out: Path, ignore_sigint: bool = False) -> subprocess.Popen:
    """`sb3-cmzdril train` of the tiny run into ``out``; with ``ignore_sigint`` it starts as under a
    non-interactive runner, with SIGINT ignored (inherited SIG_IGN)."""
    command = [sys.executable, "-m", "sb3_cmzdril", "train", "--env", ENV, "--reward", "cmz", "--seed", "0",
               "--demos", str(paths["pool"]), "--hyperparams", str(paths["hp"]), "--eval-episodes", "1",
               "--timesteps", str(TIMESTEPS), "--checkpoint-every", str(CHECKPOINT_EVERY), "--no-progress",
               "-o", str(out)]

    def ignore() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            preexec_fn=ignore if ignore_sigint else None)


def _wait_for(condition: Callable[[], bool], child: subprocess.Popen, timeout: float = 120.0) -> None:
    deadline = time.time() + timeout
    while not condition():
        assert child.poll() is None, f"the process ended first: {child.communicate()[1][-2000:]}"
        assert time.time() < deadline, "timed out"
        time.sleep(0.02)


def _checkpoint(out: Path) -> int:
    """The step count of the run's last checkpoint (state.json), 0 before the first."""
    try:
        return int(json.loads((out / "state.json").read_text())["num_timesteps"])
    except (OSError, ValueError, KeyError):
        return 0


def _spec(paths: dict[str, Path], out: Path):
    return plan_run(ENV, "cmz", 0, demos=str(paths["pool"]), n_eval_episodes=1, timesteps=TIMESTEPS,
                    output_dir=str(out), hyperparams=str(paths["hp"]), checkpoint_every=CHECKPOINT_EVERY)


def _tensors(path: Path) -> dict[str, torch.Tensor]:
    """Every tensor of a model zip's (or a .pt file's) torch files, by file and key."""
    if path.suffix == ".pt":
        return _flatten(path.name, torch.load(path, map_location="cpu", weights_only=True))
    found: dict[str, torch.Tensor] = {}
    with zipfile.ZipFile(path) as archive:
        for name in archive.namelist():
            if name.endswith(".pth"):
                blob = torch.load(text_io.BytesIO(archive.read(name)), map_location="cpu", weights_only=True)
                found.update(_flatten(name, blob))
    return found


def _flatten(prefix: str, value) -> dict[str, torch.Tensor]:
    if isinstance(value, torch.Tensor):
        return {prefix: value}
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in _flatten(f"{prefix}/{key}", item).items()}
    if isinstance(value, (list, tuple)):
        return {k: v for i, item in enumerate(value) for k, v in _flatten(f"{prefix}/{i}", item).items()}
    return {prefix: torch.tensor(float(value))} if isinstance(value, (int, float)) else {}


def test_killed_run_resumes_to_the_result_of_clean_stops_at_its_checkpoints(tiny, tmp_path):
    out = tmp_path / "killed"
    # SIGKILL during pretraining: config.json is there, nothing trained; the rerun starts afresh.
    child = _start(tiny, out)
    _wait_for(lambda: (out / "config.json").is_file(), child)
    child.kill()
    child.communicate(timeout=60)
    # SIGINT once two checkpoints are written, in a process that started with SIGINT ignored.
    child = _start(tiny, out, ignore_sigint=True)
    _wait_for(lambda: _checkpoint(out) >= 2 * CHECKPOINT_EVERY * EPOCH, child)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == "sb3-cmzdril train: interrupted; rerun the same command to resume"
    # SIGTERM between two checkpoints: an evaluation row past the last checkpoint is written.
    resumed_from = _checkpoint(out)
    assert 0 < resumed_from < TIMESTEPS
    child = _start(tiny, out)
    _wait_for(lambda: EPOCH * (latest_epoch(out) or 0) > resumed_from + EPOCH, child)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 143, err[-2000:]
    assert err.strip().splitlines()[-1] == "sb3-cmzdril train: terminated (SIGTERM); rerun the same command to resume"
    assert not any(p.name.endswith(".tmp") or ".tmp." in p.name for p in out.iterdir())  # no write cut short
    run_experiment(_spec(tiny, out))  # the rest of the run

    # The same run, stopped cleanly at each checkpoint the killed one resumed from.
    starts = [s["from_timesteps"] for s in json.loads((out / "state.json").read_text())["segments"]]
    assert starts[0] == 0 and len(starts) >= 3 and starts == sorted(starts), starts
    reference = tmp_path / "reference"
    for at in starts[1:]:
        with pytest.raises(KeyboardInterrupt):
            run_experiment(_spec(tiny, reference), callbacks=[Interrupt(at=at)])
    run_experiment(_spec(tiny, reference))
    assert [s["from_timesteps"] for s in json.loads((reference / "state.json").read_text())["segments"]] == starts

    for name in ("eval.csv", "final_eval.csv"):
        assert (out / name).read_text() == (reference / name).read_text(), name
    rows = (out / "eval.csv").read_text().splitlines()
    assert int(rows[-1].split(",")[1]) == TIMESTEPS
    for name in ("model.zip", "lowest_u.pt"):
        killed, clean = _tensors(out / name), _tensors(reference / name)
        assert set(killed) == set(clean) and len(killed) > 5, name
        for key, value in clean.items():
            assert torch.equal(killed[key], value), (name, key)
    assert json.loads((out / "done.json").read_text())["num_timesteps"] == TIMESTEPS


def _process_group(pgid: int) -> set[int]:
    """The live (not zombie) processes of process group ``pgid``, from /proc."""
    members = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # it ended while we looked
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.add(int(entry.name))
    return members


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_killed_benchmark_leaves_no_process_behind(tiny, tmp_path, sig):
    runs = tmp_path / "runs"
    command = [sys.executable, "-m", "sb3_cmzdril", "benchmark", "--env", ENV, "--methods", "cmz", "--trials", "1",
               "--workers", "1", "--timesteps", "1000000", "--eval-episodes", "1", "--demos-dir",
               str(tiny["demos_dir"]), "--hyperparams", str(tiny["hp"]), "--no-progress", "-o", str(runs)]
    # Its own session: the benchmark, its workers and multiprocessing's helpers share its process group.
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                             start_new_session=True)
    run = runs / ENV / "cmz" / "trial0"
    try:
        _wait_for(lambda: (run / "config.json").is_file(), child)  # a worker is inside its run
        assert len(_process_group(child.pid)) >= 2
        os.kill(child.pid, sig)
        _, err = child.communicate(timeout=60)
        deadline = time.time() + 30
        while _process_group(child.pid) and time.time() < deadline:
            time.sleep(0.1)
        assert _process_group(child.pid) == set()
    finally:
        with_leftovers = _process_group(child.pid)
        for pid in with_leftovers:  # only if the assertion failed: leave nothing running either way
            os.kill(pid, signal.SIGKILL)
    if sig == signal.SIGTERM:
        assert child.returncode == 143, err[-2000:]
        assert err.strip().splitlines()[-1].startswith("sb3-cmzdril benchmark: terminated (SIGTERM)")
    assert not grid.held_elsewhere(run)  # a rerun can take the run over: not "another process is running"
    assert not (run / "error.txt").exists()


def test_run_held_by_another_process_is_skipped_not_failed(tiny, tmp_path, capsys):
    runs = tmp_path / "runs"
    run = runs / ENV / "cmz" / "trial0"
    run.mkdir(parents=True)
    held = io.lock_output(run)  # as another benchmark working on that run holds it
    try:
        args = ["benchmark", "--env", ENV, "--methods", "cmz", "--trials", "1", "--timesteps", str(TIMESTEPS),
                "--demos-dir", str(tiny["demos_dir"]), "--hyperparams", str(tiny["hp"]), "-o", str(runs)]
        assert main(args) == 0
        out = capsys.readouterr().out
        assert f"] skipped {ENV}/cmz/trial0: another process is running it ({run / '.lock'}) | " in out
        assert out.endswith("1 runs: 1 busy\nbusy (another process is running them; run this again once it ends): "
                            f"{ENV}/cmz/trial0\n")
        assert sorted(p.name for p in run.iterdir()) == [".lock"]  # nothing written into its folder
        # A worker that finds the folder taken after the grid looked: busy too, no error.txt.
        spec = grid.plan_grid(ENV, "cmz", 1, runs, timesteps=TIMESTEPS, demos_dir=tiny["demos_dir"],
                              hyperparams=tiny["hp"])[0]
        assert grid.execute_run(spec)["status"] == grid.BUSY
        assert not (run / "error.txt").exists()
    finally:
        io.unlock_output(run, held)
