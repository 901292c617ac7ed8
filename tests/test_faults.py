"""Faults: a run killed (SIGKILL, SIGINT, SIGTERM) at several points and resumed ends exactly where
the same run stopped cleanly at the same checkpoints ends; a killed benchmark leaves no process
behind; a run another benchmark holds is skipped, not failed.

Why not bit-identical to a run never stopped: a resumed segment reseeds with seed + its first step
and its env starts a new episode (runs.py), so a clean stop at the same checkpoint is the reference.

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

from cmzdril_lab.run import grid, worker
from helpers import ENV, TINY, Interrupt, pendulum_expert
from sb3_cmzdril import io
from sb3_cmzdril.cli import main
from sb3_cmzdril.training.runs import latest_epoch, plan_run, run_experiment

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and process groups")

EPOCH = 64  # n_steps of TINY_YAML, one env
CHECKPOINT_EVERY = 2
TIMESTEPS = 8 * EPOCH
REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def tiny(request, tmp_path_factory) -> dict[str, Path]:
    """The tiny experiment's demo pool (<demos_dir>/<EnvName>/demos.npz) and hyperparameters, with an
    averaged policy over the last 3/4 of each run, so that a killed run resumes its running average too."""
    paths = dict(request.getfixturevalue("tiny_experiment"))
    hp = tmp_path_factory.mktemp("hp") / "cmzdril.yml"
    hp.write_text(paths["hp"].read_text() + "  average_from: 0.25\n")
    return {**paths, "hp": hp}


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))


def _run_options(paths: dict[str, Path]) -> list[str]:
    return ["--env", ENV, "--hyperparams", str(paths["hp"]), "--eval-episodes", "1", "--timesteps", str(TIMESTEPS),
            "--checkpoint-every", str(CHECKPOINT_EVERY), "--no-progress"]


def _train(paths: dict[str, Path], out: Path) -> subprocess.Popen:
    """`sb3-cmzdril train` of the tiny run into ``out``, started as under a non-interactive runner:
    with SIGINT ignored (inherited SIG_IGN)."""
    command = [sys.executable, "-m", "sb3_cmzdril", "train", *_run_options(paths), "--reward", "cmz", "--seed", "0",
               "--demos", str(paths["pool"]), "-o", str(out)]

    def ignore() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            preexec_fn=ignore)


def _benchmark(paths: dict[str, Path], runs: Path) -> subprocess.Popen:
    """`sb3-cmzdril benchmark` of the same run (cmz, trial 0) into ``runs``, one worker, in a session of
    its own: it, its worker and multiprocessing's helpers share its process group."""
    command = [sys.executable, "-m", "sb3_cmzdril", "benchmark", *_run_options(paths), "--methods", "cmz",
               "--trials", "1", "--workers", "1", "--demos-dir", str(paths["demos_dir"]), "-o", str(runs)]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            start_new_session=True)


def _kill_benchmark(child: subprocess.Popen, sig: signal.Signals) -> str:
    """Send ``sig`` to the benchmark alone; check that its whole process group is gone soon after;
    return its stderr."""
    assert len(_process_group(child.pid)) >= 2  # the benchmark and its worker at least
    try:
        os.kill(child.pid, sig)
        _, err = child.communicate(timeout=60)
        deadline = time.time() + 30
        while _process_group(child.pid) and time.time() < deadline:
            time.sleep(0.05)
        assert _process_group(child.pid) == set(), "the benchmark left processes behind"
    finally:
        for pid in _process_group(child.pid):  # only after a failure: leave nothing running either way
            os.kill(pid, signal.SIGKILL)
    return err


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


def _segments(out: Path) -> list[int]:
    """The step each recorded segment of the run started from (state.json), [] before the first checkpoint."""
    try:
        return [int(s["from_timesteps"]) for s in json.loads((out / "state.json").read_text())["segments"]]
    except (OSError, ValueError, KeyError):
        return []


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


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc")
def test_killed_benchmark_and_train_leave_nothing_behind_and_resume_to_clean_stops(tiny, tmp_path):
    """One run killed three times (a benchmark's worker with its benchmark, the train command), then
    finished; it must end exactly as the same run stopped cleanly at the checkpoints it resumed from."""
    runs = tmp_path / "runs"
    out = runs / ENV / "cmz" / "trial0"  # the benchmark's folder of the run; train -o uses it too
    # SIGKILL to a benchmark whose worker is pretraining (config.json is there, nothing trained yet):
    # the worker dies with it, the rerun starts afresh.
    child = _benchmark(tiny, runs)
    _wait_for(lambda: (out / "config.json").is_file(), child)
    _kill_benchmark(child, signal.SIGKILL)
    assert not grid.held_elsewhere(out)  # nobody left holding the run
    # SIGINT to train once a checkpoint is written: SIGINT works though the process started with it ignored.
    child = _train(tiny, out)
    _wait_for(lambda: _checkpoint(out) >= CHECKPOINT_EVERY * EPOCH, child)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == "sb3-cmzdril train: interrupted; rerun the same command to resume"
    # SIGTERM to a benchmark whose worker is between two checkpoints: resumed (its first checkpoint, at
    # the step it resumed from, is in state.json), then evaluated one epoch further.
    resumed_from, segments = _checkpoint(out), len(_segments(out))
    assert 0 < resumed_from < TIMESTEPS - CHECKPOINT_EVERY * EPOCH
    child = _benchmark(tiny, runs)
    _wait_for(lambda: len(_segments(out)) > segments and EPOCH * (latest_epoch(out) or 0) > resumed_from, child)
    err = _kill_benchmark(child, signal.SIGTERM)
    assert child.returncode == 143, err[-2000:]
    assert err.strip().splitlines()[-1] == (
        "sb3-cmzdril benchmark: terminated (SIGTERM); rerun the same command to resume"
    )
    assert not grid.held_elsewhere(out) and not (out / "error.txt").exists()  # a rerun resumes it, not "failed"
    assert not any(p.name.endswith(".tmp") or ".tmp." in p.name for p in out.iterdir())  # no write cut short
    run_experiment(_spec(tiny, out))  # the rest of the run

    # The same run, stopped cleanly at each checkpoint the killed one resumed from.
    starts = _segments(out)
    assert starts[0] == 0 and len(starts) >= 3 and starts == sorted(starts), starts
    reference = tmp_path / "reference"
    for at in starts[1:]:
        with pytest.raises(KeyboardInterrupt):
            run_experiment(_spec(tiny, reference), callbacks=[Interrupt(at=at)])
    run_experiment(_spec(tiny, reference))
    assert _segments(reference) == starts

    for name in ("eval.csv", "final_eval.csv"):
        assert (out / name).read_text() == (reference / name).read_text(), name
    rows = (out / "eval.csv").read_text().splitlines()
    assert int(rows[-1].split(",")[1]) == TIMESTEPS
    for name in ("model.zip", "lowest_u.pt", "averaged.pt"):
        killed, clean = _tensors(out / name), _tensors(reference / name)
        assert set(killed) == set(clean) and len(killed) > 5, name
        for key, value in clean.items():
            assert torch.equal(killed[key], value), (name, key)
    assert json.loads((out / "done.json").read_text())["num_timesteps"] == TIMESTEPS


def test_an_interrupted_local_pool_is_wound_down_before_the_command_returns():
    """Closed after an interruption, the local backend's pool has ended its workers and its manager
    thread, and closed the pipe that wakes that thread: Python's exit writes to that pipe of every pool
    still running, and a close racing that write ended a SIGTERM'd benchmark with "Bad file descriptor"
    after its last line."""
    backend = grid._LocalBackend(1)
    job = backend.pool.submit(time.sleep, 60)
    deadline = time.time() + 60
    while not job.running():
        assert time.time() < deadline, "the worker never started"
        time.sleep(0.05)
    processes = list(backend.pool._processes.values())
    manager = backend.pool._executor_manager_thread
    wakeup = backend.pool._executor_manager_thread_wakeup
    backend.close(interrupted=True)
    assert not any(p.is_alive() for p in processes)
    assert not manager.is_alive()
    assert wakeup._closed


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
        assert worker.execute_run(spec).status is worker.RunStatus.BUSY
        assert not (run / "error.txt").exists()
    finally:
        io.unlock_output(run, held)


# -- issue 30's probe: faults that must not lose data nor pass for the user's mistake ---------------
FAULTY_ENVS = '''
"""Envs with a bug of their own: a KeyError in step(), or in the constructor."""
import gymnasium as gym
from gymnasium.envs.classic_control.pendulum import PendulumEnv


class StepFails(PendulumEnv):
    def step(self, action):
        raise KeyError("velocity_x")


class ConstructorFails(PendulumEnv):
    def __init__(self, **kwargs):
        raise KeyError("velocity_x")


gym.register("StepFails-v0", entry_point=StepFails, max_episode_steps=200)
gym.register("ConstructorFails-v0", entry_point=ConstructorFails, max_episode_steps=200)
'''


@pytest.mark.parametrize("command, env", [("train", "StepFails-v0"), ("train", "ConstructorFails-v0"),
                                          ("evaluate", "ConstructorFails-v0")])
def test_an_envs_own_key_error_keeps_its_traceback_and_is_no_user_error(command, env, tiny, tmp_path):
    """Issue 30, cause 10: a bug in the env (here a KeyError, in step() or in its constructor) is not
    the user's mistake: exit 1 with its traceback, not "error: velocity_x" and exit 2, and never
    blamed on env_kwargs/normalize the YAML holds."""
    from sb3_cmzdril import CMZDRIL, Demonstrations

    (tmp_path / "faulty_envs.py").write_text(FAULTY_ENVS)
    environ = _env()
    environ["PYTHONPATH"] = os.pathsep.join([str(tmp_path), environ["PYTHONPATH"]])
    options = ["--env", f"faulty_envs:{env}", "--demos", str(tiny["pool"])]
    if command == "train":
        options += ["--reward", "cmz", "--hyperparams", str(tiny["hp"]), "--timesteps", str(2 * EPOCH),
                    "--eval-episodes", "1", "--no-progress", "-o", str(tmp_path / "out")]
    else:
        model = tmp_path / "model.zip"
        CMZDRIL("MlpPolicy", ENV, demonstrations=Demonstrations.load(tiny["pool"]), **TINY).save(model)
        options += ["--model", str(model)]
    done = subprocess.run([sys.executable, "-m", "sb3_cmzdril", command, *options], capture_output=True, text=True,
                          env=environ, timeout=300)
    assert done.returncode == 1, done.stderr[-3000:]
    assert "Traceback (most recent call last)" in done.stderr
    assert done.stderr.strip().splitlines()[-1] == "KeyError: 'velocity_x'", done.stderr[-3000:]
    assert not any(line.startswith(f"sb3-cmzdril {command}: error") for line in done.stderr.splitlines())
    assert "cannot make" not in done.stderr  # the old wrapper's "cannot make ... with the env_kwargs/normalize of"


MISSING_DEPENDENCY_ENVS = '''
"""An env registered by its module path, whose module needs a package that is not installed."""
import gymnasium as gym

gym.register("NeedsBox2D-v0", entry_point="needs_box2d:Lander", max_episode_steps=200)
'''
NEEDS_BOX2D = '''
from gymnasium.error import DependencyNotInstalled

raise DependencyNotInstalled('Box2D is not installed, run `pip install "gymnasium[box2d]"`')
'''


@pytest.mark.parametrize("command", ["train", "collect-demos", "evaluate"])
def test_an_env_whose_optional_dependency_is_missing_is_one_line_and_exit_2(command, tiny, tmp_path):
    """A missing optional dependency (gymnasium's Box2D or MuJoCo) is the user's install to fix, not a
    bug: one line naming the env and gymnasium's advice, exit 2, and no folder or file written, where
    gym.make would raise it with a traceback after the command had made its output folder."""
    (tmp_path / "registers.py").write_text(MISSING_DEPENDENCY_ENVS)
    (tmp_path / "needs_box2d.py").write_text(NEEDS_BOX2D)
    environ = _env()
    environ["PYTHONPATH"] = os.pathsep.join([str(tmp_path), environ["PYTHONPATH"]])
    out = tmp_path / "out"
    options = ["--env", "registers:NeedsBox2D-v0"]
    if command == "train":
        options += ["--demos", str(tiny["pool"]), "--reward", "bc", "--hyperparams", str(tiny["hp"]),
                    "--no-progress", "-o", str(out)]
    elif command == "collect-demos":
        options += ["--expert", "pendulum-pd", "--episodes", "1", "-o", str(out / "demos.npz")]
    else:
        options += ["--demos", str(tiny["pool"]), "--model", str(out / "model.zip")]
    done = subprocess.run([sys.executable, "-m", "sb3_cmzdril", command, *options], capture_output=True, text=True,
                          env=environ, timeout=300)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [
        f"sb3-cmzdril {command}: error: cannot make registers:NeedsBox2D-v0: Box2D is not installed, "
        'run `pip install "gymnasium[box2d]"`'], done.stderr
    assert not out.exists()


class _PendulumExpert:
    """The PD expert as an object with ``predict``; ``meanwhile`` runs once, during its first action."""

    def __init__(self, meanwhile: Callable[[], object] | None = None) -> None:
        self.meanwhile = meanwhile

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if self.meanwhile is not None:
            meanwhile, self.meanwhile = self.meanwhile, None
            meanwhile()
        return pendulum_expert(obs)[0], None


def _collect(expert: _PendulumExpert, output: Path, seed: int):
    from sb3_cmzdril.experts import collect_demos

    return collect_demos(expert, ENV, 1, seed=seed, output=output, env_kwargs={"max_episode_steps": 20},
                         verbose=False)


def test_two_collect_demos_to_one_pool_cannot_both_succeed(tmp_path):
    """Issue 30, cause 2: two collect-demos started together to the same -o both printed "saved" and
    the file held only the second pool. The one that saves second must fail, and leave the first's
    pool and its record in place."""
    from sb3_cmzdril.data.demos import Demonstrations
    from sb3_cmzdril.errors import OutputExistsError

    pool = tmp_path / "race" / "pool.npz"
    # The second starts (and passes its checks) while the first is still recording, then saves first.
    second = _PendulumExpert()
    with pytest.raises(OutputExistsError, match="pool.npz already exists"):
        _collect(_PendulumExpert(meanwhile=lambda: _collect(second, pool, seed=1000)), pool, seed=0)
    assert Demonstrations.load(pool).seeds.tolist() == [1000]
    assert json.loads(pool.with_suffix(".json").read_text())["demos"]["seeds"] == [1000, 1000]
    # While the other holds the folder, saving fails at once, naming it; nothing is replaced.
    other = tmp_path / "busy" / "pool.npz"
    other.parent.mkdir()
    held = io.lock_output(other.parent)
    try:
        with pytest.raises(io.LockHeld, match=f"another process is writing demos in {other.parent}"):
            _collect(_PendulumExpert(), other, seed=0)
    finally:
        io.unlock_output(other.parent, held)
    assert not other.exists()


def test_an_interrupted_first_segment_keeps_pretrain_csv_and_the_record_says_a_resume_reseeds(tiny, tmp_path):
    """Issue 30, causes 3 and 18: pretrain.csv was written only when the first segment's learn()
    returned, so a resumed run had none; and config.json did not say that a resume reseeds (its
    train_command does not reproduce a resumed run), nor state.json with which seed."""
    from sb3_cmzdril.training.run_folder import RESUME_NOTE

    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        run_experiment(_spec(tiny, out), callbacks=[Interrupt(at=CHECKPOINT_EVERY * EPOCH)])
    curve = (out / "pretrain.csv").read_text()
    assert curve.startswith("epoch,train_nll,validation_nll\n") and len(curve.splitlines()) > 2
    (out / "pretrain.csv").unlink()  # as a run interrupted by an older version left it
    run_experiment(_spec(tiny, out))
    assert (out / "pretrain.csv").read_text() == curve  # rewritten from the checkpoint's history
    assert json.loads((out / "config.json").read_text())["resume"] == RESUME_NOTE
    segments = json.loads((out / "state.json").read_text())["segments"]
    assert [(s["from_timesteps"], s["seed"]) for s in segments] == [(0, 0), (CHECKPOINT_EVERY * EPOCH,
                                                                            CHECKPOINT_EVERY * EPOCH)]
