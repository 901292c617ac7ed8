"""The grid on a two-node Ray cluster whose worker node cannot read the driver's files.

The head node (the driver's) has no CPUs, so every run goes to the second node; every process of
that node refuses to open, list or write anything under the driver's folder (an audit hook installed
in each of its workers), as if it were another machine. The same grid, with one run resumed from a
checkpoint, on the local backend gives the numbers the Ray grid must reproduce. Tiny settings of
test_experiments.py (Pendulum-v1, 16x16 networks, 64-step rollouts).
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import threading
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from cmzdril_lab import report
from cmzdril_lab.run import remote
from cmzdril_lab.run.grid import held_elsewhere, plan_grid, run_grid
from helpers import ENV, POOL_EPISODES, Interrupt, pendulum_expert, record
from helpers import TINY_PPO_YAML as TINY_YAML
from sb3_cmzdril.io import portable_path
from sb3_cmzdril.training.runs import run_experiment, train_command

ray = pytest.importorskip("ray")
# Every test starts or uses a two-node Ray cluster. The "ray" group keeps every Ray test of the suite on
# one worker under pytest-xdist: a ray.init() finds a local instance another test is running and joins it.
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray")]

#: Set on the worker node only: the folder its processes must not touch.
DENIED = "SB3_CMZDRIL_TEST_DENIED_ROOT"
RUN_FILES = ("eval.csv", "final_eval.csv", "pretrain.csv", "eval.discarded.csv")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    from ray.cluster_utils import Cluster

    driver = tmp_path_factory.mktemp("driver")
    nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
    nodes.add_node(num_cpus=1, env_vars={DENIED: str(driver)})

    # Defined here so that Ray pickles it by value: the worker node cannot import this test module.
    def deny_driver_files() -> None:
        import os
        import sys

        root = os.environ.get("SB3_CMZDRIL_TEST_DENIED_ROOT")
        if not root:
            return
        events = {"open", "os.listdir", "os.scandir", "os.mkdir", "os.rename", "os.remove", "os.rmdir",
                  "os.chmod", "os.utime", "os.truncate", "shutil.copyfile", "shutil.rmtree"}

        def audit(event: str, args: tuple) -> None:
            if event in events and args and isinstance(args[0], (str, bytes, os.PathLike)):
                path = os.path.abspath(os.fsdecode(args[0]))
                if path == root or path.startswith(root + os.sep):
                    raise PermissionError(f"{path}: the driver's files are not on this node")

        sys.addaudithook(audit)

    ray.init(address=nodes.address, runtime_env={"worker_process_setup_hook": deny_driver_files},
             log_to_driver=False)
    try:
        yield driver
    finally:
        ray.shutdown()
        nodes.shutdown()


def test_the_worker_node_cannot_read_the_driver_folder(cluster):
    (cluster / "probe.txt").write_text("driver only")

    @ray.remote(num_cpus=1)
    def probe(path: str) -> tuple[str, str]:
        try:
            Path(path).read_text()
            outcome = "read"
        except PermissionError:
            outcome = "denied"
        return outcome, ray.get_runtime_context().get_node_id()

    outcome, node = ray.get(probe.remote(str(cluster / "probe.txt")))
    assert outcome == "denied"
    assert node != ray.get_runtime_context().get_node_id()


@pytest.fixture(scope="module")
def grids(cluster):
    """cmz trials 0 and 1 on both backends; trial 1 interrupted after its first checkpoint beforehand."""
    pool = cluster / "experts" / ENV / "demos.npz"
    pool.parent.mkdir(parents=True)
    record(ENV, pendulum_expert, n_episodes=POOL_EPISODES, max_steps=50, seed=100).save(pool)
    hp = cluster / "cmzdril.yml"
    hp.write_text(TINY_YAML)
    specs = {
        backend: plan_grid(ENV, "cmz", 2, cluster / backend, demos_dir=cluster / "experts", hyperparams=hp,
                           timesteps=128, n_eval_episodes=2, checkpoint_every=1, command="pytest cluster")
        for backend in ("local", "ray")
    }
    with pytest.raises(KeyboardInterrupt):
        run_experiment(specs["local"][1], callbacks=[Interrupt(at=64)])
    shutil.copytree(specs["local"][1].output_dir, specs["ray"][1].output_dir)
    bad_hp = cluster / "bad.yml"
    bad_hp.write_text(TINY_YAML.replace("n_demos: 1", "n_demos: 1\n  ensemble_size: 1"))  # fails in the worker
    for backend, grid in specs.items():
        grid.append(dataclasses.replace(grid[0], method="zero", hyperparams=str(bad_hp),
                                        output_dir=str(cluster / backend / "broken" / "zero" / "trial0")))
    # One local worker: a second one would only add a process start-up on this small machine.
    outcomes = {backend: run_grid(specs[backend], workers=1 if backend == "local" else 2, backend=backend,
                                  progress=False)
                for backend in ("local", "ray")}
    return {"specs": specs, "outcomes": outcomes}


def _read(run_dir: str, name: str) -> bytes | None:
    path = Path(run_dir) / name
    return path.read_bytes() if path.is_file() else None


def test_ray_grid_equals_the_local_grid(grids):
    specs, outcomes = grids["specs"], grids["outcomes"]
    for backend in ("local", "ray"):
        assert [o.status for o in outcomes[backend]] == ["done", "done", "failed"], outcomes[backend]
        assert [o.run_dir for o in outcomes[backend]] == [s.output_dir for s in specs[backend]]
    for local, ray_spec in zip(specs["local"][:2], specs["ray"][:2], strict=True):
        for name in RUN_FILES:
            assert _read(ray_spec.output_dir, name) == _read(local.output_dir, name), name
        done = {b: json.loads(_read(s.output_dir, "done.json")) for b, s in (("local", local), ("ray", ray_spec))}
        assert done["ray"]["final_evaluation"] == done["local"]["final_evaluation"]
        assert done["ray"]["run_dir"] == portable_path(ray_spec.output_dir)  # as a local run records it
        assert not held_elsewhere(ray_spec.output_dir)  # the driver's lock on the run released


def test_worker_errors_come_back_as_on_the_local_backend(grids):
    (_, _, local), (_, _, on_ray) = grids["outcomes"]["local"], grids["outcomes"]["ray"]
    assert on_ray.error == local.error and "at least 2 members" in local.error
    text = (Path(on_ray.run_dir) / "error.txt").read_text()
    # error.txt says where the run ran: the worker's copy of the YAML, so compare what follows the path.
    assert local.error.split("bad.yml", 1)[1] in text
    assert not held_elsewhere(on_ray.run_dir)


def test_interrupted_run_resumed_on_the_worker(grids):
    resumed = Path(grids["specs"]["ray"][1].output_dir)
    state = json.loads((resumed / "state.json").read_text())
    assert [s["from_timesteps"] for s in state["segments"]] == [0, 64] and state["num_timesteps"] == 128
    assert sorted(p.name for p in (resumed / "logs").iterdir()) == ["progress_0.csv", "progress_64.csv"]
    assert json.loads((resumed / "done.json").read_text())["segments"] == 2


def test_lost_worker_leaves_its_last_checkpoint_on_the_driver(cluster, grids, monkeypatch):
    """A worker killed mid-run: its run fails as on the local backend, its last checkpoint that reached
    the driver stays, and the next grid continues from it."""
    [spec] = plan_grid(ENV, "zero", [0], cluster / "lost", demos_dir=cluster / "experts",
                       hyperparams=cluster / "cmzdril.yml", timesteps=64 * 200, n_eval_episodes=2, checkpoint_every=1)
    # Long enough that the cancel lands mid-run: at 20 epochs a loaded CI machine once finished the run
    # before the first checkpoint reached the driver.
    handles = []
    submit = remote.RemoteRuns.submit
    monkeypatch.setattr(remote.RemoteRuns, "submit", lambda self, s: handles.append(submit(self, s)) or handles[-1])
    state = Path(spec.output_dir) / "state.json"

    def kill_after_the_first_checkpoint() -> None:
        deadline = time.time() + 120
        while not (handles and state.exists()) and time.time() < deadline:
            time.sleep(0.05)
        ray.cancel(handles[0], force=True)

    killer = threading.Thread(target=kill_after_the_first_checkpoint)
    killer.start()
    [outcome] = run_grid([spec], workers=1, backend="ray", progress=False)
    killer.join()
    assert outcome.status == "failed" and (Path(spec.output_dir) / "error.txt").is_file()
    # The model may be a checkpoint newer than state.json (it is read after it), never older.
    with zipfile.ZipFile(Path(spec.output_dir) / "model.zip") as model:
        reached = json.loads(model.read("data"))["num_timesteps"]
    assert 0 < json.loads(state.read_text())["num_timesteps"] <= reached < spec.timesteps

    [outcome] = run_grid([dataclasses.replace(spec, timesteps=reached + 64)], backend="ray", progress=False)
    assert outcome.status == "done"
    resumed = json.loads(state.read_text())
    assert [s["from_timesteps"] for s in resumed["segments"]] == [0, reached]
    assert resumed["num_timesteps"] == reached + 64


def test_records_name_the_driver_paths(grids):
    for spec in grids["specs"]["ray"][:2]:
        config = json.loads(_read(spec.output_dir, "config.json"))
        paths = (portable_path(spec.demos), portable_path(spec.hyperparams))  # as a local run records them
        assert (config["demos"], config["hyperparams_file"]) == paths
        assert config["train_command"] == train_command(spec)
        for name in ("config.json", "done.json", "state.json"):
            assert b"sb3-cmzdril-run-" not in _read(spec.output_dir, name), name


def test_ray_report_equals_local_report(grids, tmp_path):
    tables = {}
    for backend in ("local", "ray"):
        runs_dir = Path(grids["specs"][backend][0].output_dir).parents[2]
        out = tmp_path / backend
        report.write_report(runs_dir, out, references=(), figures=False)
        tables[backend] = [(out / name).read_text() for name in ("table1.csv", "final_table.csv")]
    assert tables["ray"] == tables["local"]


def test_checkpoints_reach_the_driver_while_the_run_goes_on(cluster, tmp_path, monkeypatch):
    """A worker's snapshot thread sends what a checkpoint changed (state.json last written) to the sink."""
    monkeypatch.setattr(remote, "SNAPSHOT_INTERVAL_S", 0.05)
    # The actor's method, called in this process (an actor would cost a worker start-up).
    sink = SimpleNamespace(store=SimpleNamespace(
        remote=lambda *args: (remote.FolderSink().store(*args), ray.put(None))[1]
    ))
    worker, driver = tmp_path / "worker", tmp_path / "driver"
    (worker / "logs").mkdir(parents=True)
    for folder in (worker, driver):  # a file the driver shipped, which the run then deletes
        folder.mkdir(exist_ok=True)
        (folder / "old.txt").write_text("shipped")
    baseline = remote._listing(worker)
    moved = [(str(worker), str(driver))]
    with remote._Snapshots(worker, str(driver), moved, sink, baseline):
        (worker / "model.zip").write_bytes(b"weights")
        (worker / "logs" / "progress_0.csv").write_text("a,b\n")
        (worker / "old.txt").unlink()
        (worker / "state.json").write_text(json.dumps({"run_dir": str(worker / "x"), "num_timesteps": 64}))
        deadline = time.time() + 30
        while not (driver / "state.json").exists() and time.time() < deadline:
            time.sleep(0.05)
    assert (driver / "model.zip").read_bytes() == b"weights"
    assert (driver / "logs" / "progress_0.csv").read_text() == "a,b\n"
    assert json.loads((driver / "state.json").read_text()) == {"run_dir": str(driver / "x"), "num_timesteps": 64}
    assert not (driver / "old.txt").exists()


def test_files_from_a_worker_stay_inside_the_run_folder(tmp_path):
    with pytest.raises(ValueError, match="not a path inside the run folder"):
        remote.write_files(tmp_path, {"../escaped.txt": b"x"})
    assert not (tmp_path.parent / "escaped.txt").exists()
