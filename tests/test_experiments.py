"""The experiment grid, one run, resuming, the report and the CLI commands train/evaluate/benchmark/report.

Everything runs on Pendulum-v1 cut to 50-step episodes with tiny networks (16x16), 64-step rollouts
and 1-2 evaluation episodes, so a run takes about a second plus process start-up.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch as th

from cmzdril_lab import report
from cmzdril_lab.run import grid
from cmzdril_lab.run.grid import plan_grid, run_grid
from helpers import ENV, POOL_EPISODES, Interrupt, with_entry
from helpers import TINY_PPO_YAML as TINY_YAML
from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.io import cpu_model
from sb3_cmzdril.training import runs
from sb3_cmzdril.training.run_folder import RunState, check_finished
from sb3_cmzdril.training.runs import plan_run, run_experiment, split_episodes
from sb3_cmzdril.training.spec import RunSpec

GRID = dict(timesteps=256, n_eval_episodes=2, eval_every=1, checkpoint_every=2)


def _rows(path: Path) -> list:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _config(run_dir) -> dict:
    return json.loads((Path(run_dir) / "config.json").read_text())


# -- the data split ---------------------------------------------------------------------------------
def test_split_is_disjoint_seeded_and_checked():
    for trial in range(5):
        train, held_out = split_episodes(10, 3, 5, trial)
        order = np.random.default_rng(trial).permutation(10)
        assert train == order[:3].tolist() and held_out == order[3:8].tolist()
        assert not set(train) & set(held_out)
        assert split_episodes(10, 3, 5, trial) == (train, held_out)
    with pytest.raises(ValueError, match="6 episodes but 5 training \\+ 2 evaluation"):
        split_episodes(6, 5, 2, 0)


def test_run_state_adds_cpu_time_across_segments(tmp_path):
    """state.json's CPU seconds are this process's since the segment started, plus the earlier
    segments' (a resumed run's cost is the sum); a state.json from before they were kept counts 0."""
    spec = RunSpec(ENV, "cmz", "pool.npz", 0, 1, 1, 100, str(tmp_path), "hp.yml")
    first = RunState(tmp_path, spec, 0)
    t = time.process_time()
    while time.process_time() - t < 0.05:
        pass
    first.write(64)
    written = json.loads((tmp_path / "state.json").read_text())["cpu_time_s"]
    assert 0.05 <= written <= first.cpu_time()
    second = RunState(tmp_path, spec, 64)
    assert written <= second.cpu_time() < written + 0.05
    legacy = json.loads((tmp_path / "state.json").read_text())
    del legacy["cpu_time_s"]
    (tmp_path / "state.json").write_text(json.dumps(legacy))
    assert RunState(tmp_path, spec, 64).cpu_time() < 0.05


def test_each_segment_of_state_json_names_the_machine_it_ran_on(tmp_path):
    """CPU seconds are only comparable on one machine: every segment, a resume's too, records the CPU
    model, the instruction set of torch's kernels, the logical CPUs and torch's threads it ran with."""
    spec = RunSpec(ENV, "cmz", "pool.npz", 0, 1, 1, 100, str(tmp_path), "hp.yml")
    RunState(tmp_path, spec, 0).write(64)
    RunState(tmp_path, spec, 64).write(128)
    segments = json.loads((tmp_path / "state.json").read_text())["segments"]
    assert len(segments) == 2
    for segment in segments:
        found = segment["machine"]
        assert isinstance(found["cpu"], str) and found["cpu"]
        assert found["logical_cpus"] == os.cpu_count()
        assert found["torch_threads"] == th.get_num_threads()
        # torch 2.0 (the floor) has no torch.backends.cpu: the record says it does not know
        backend = getattr(th.backends, "cpu", None)
        assert found["cpu_capability"] == (backend.get_cpu_capability() if backend else "unknown (torch < 2.1)")


def test_rows_after_the_checkpoint_and_cut_short_rows_move_aside(tmp_path):
    path = tmp_path / "eval.csv"
    header = "epoch,timesteps,return_mean,return_std,frechet_mean,frechet_std,action_mse,length_mean,n_episodes"
    rows = [f"{e},{64 * e},-1.5,0,2,0,0.25,50,1" for e in range(4)]
    path.write_text("\n".join([header, *rows, "4,25"]))  # a process killed while writing epoch 4's row
    assert runs._discard_rows_after(path, 128) == 2
    assert path.read_text().splitlines() == [header, *rows[:3]]
    assert (tmp_path / "eval.discarded.csv").read_text().splitlines() == [header, rows[3], "4,25"]
    columns = runs.read_eval_csv(path)
    assert columns["epoch"].tolist() == [0, 1, 2] and columns["action_mse"].tolist() == [0.25] * 3


# -- the grid: local processes, interruption, resume, failure ------------------------------------------
@pytest.fixture(scope="module")
def grid_runs(tiny_experiment):
    """2 methods x 2 trials on the local process pool, one run interrupted first, one run failing."""
    runs_dir = tiny_experiment["root"] / "runs"
    specs = plan_grid(ENV, "bc,cmz", 2, runs_dir, demos_dir=tiny_experiment["demos_dir"],
                      hyperparams=tiny_experiment["hp"], command="pytest grid", **GRID)
    interrupted = next(s for s in specs if s.method == "cmz" and s.seed == 1)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(interrupted, callbacks=[Interrupt(at=192)])
    before = (Path(interrupted.output_dir) / "eval.csv").read_text()

    bad_hp = tiny_experiment["root"] / "bad.yml"
    bad_hp.write_text(TINY_YAML.replace("n_demos: 1", "n_demos: 1\n  ensemble_size: 1"))  # fails in the worker
    failing = dataclasses.replace(specs[0], method="zero", hyperparams=str(bad_hp),
                                  output_dir=str(runs_dir / "broken" / "zero" / "trial0"))
    outcomes = run_grid([*specs, failing], workers=2, backend="local", progress=True)
    return {"runs_dir": runs_dir, "specs": specs, "outcomes": outcomes, "interrupted": interrupted,
            "before": before, "failing": failing}


@pytest.mark.slow
def test_grid_runs_every_spec_and_reports_the_failure(grid_runs):
    statuses = [o.status for o in grid_runs["outcomes"]]
    assert statuses == ["done"] * 4 + ["failed"]
    error = Path(grid_runs["failing"].output_dir) / "error.txt"
    assert "Traceback" in error.read_text() and "at least 2 members" in error.read_text()
    assert "at least 2 members" in grid_runs["outcomes"][-1].error
    for spec in grid_runs["specs"]:
        out = Path(spec.output_dir)
        assert out == grid_runs["runs_dir"] / ENV / spec.method / f"trial{spec.seed}"
        expected = {"config.json", "eval.csv", "done.json", "model.zip", "state.json", "log.txt"}
        assert expected <= {p.name for p in out.iterdir()}
        epochs = [int(r["epoch"]) for r in _rows(out / "eval.csv")]
        assert epochs == ([0] if spec.method == "bc" else [0, 1, 2, 3, 4])


@pytest.mark.slow
def test_every_method_of_a_trial_uses_the_same_data(grid_runs):
    by_trial = {}
    for spec in grid_runs["specs"]:
        config = _config(spec.output_dir)
        assert config["seed"] == config["network_seed"] == config["env_seed"] == spec.seed
        assert not set(config["train_episodes"]) & set(config["eval_episodes"])
        assert len(config["train_episodes"]) == 1 and len(config["eval_episodes"]) == 2
        assert (config["train_episodes"], config["eval_episodes"]) == split_episodes(POOL_EPISODES, 1, 2, spec.seed)
        first_row = _rows(Path(spec.output_dir) / "eval.csv")[0]
        by_trial.setdefault(spec.seed, []).append(
            (config["train_episodes"], config["eval_episodes"], config["demos_sha256"], first_row)
        )
    for entries in by_trial.values():
        assert len(entries) == 2
        (train_a, eval_a, sha_a, row_a), (train_b, eval_b, sha_b, row_b) = entries
        assert (train_a, eval_a, sha_a) == (train_b, eval_b, sha_b)
        # Same data and seeds: BC and CMZ-DRIL start from the same pretrained policy (epoch 0).
        assert row_a == row_b


@pytest.mark.slow
def test_interrupted_run_continued_from_its_checkpoint(grid_runs):
    out = Path(grid_runs["interrupted"].output_dir)
    state = json.loads((out / "state.json").read_text())
    assert [s["from_timesteps"] for s in state["segments"]] == [0, 128]
    assert state["segments"][1]["discarded_eval_rows"] == 1 and state["num_timesteps"] == 256
    # Rows up to the checkpoint are kept as they were; the row evaluated after it moved aside.
    before = grid_runs["before"].splitlines()
    after = (out / "eval.csv").read_text().splitlines()
    assert after[:4] == before[:4]  # header + epochs 0, 1, 2 (checkpoint at epoch 2 = 128 steps)
    assert (out / "eval.discarded.csv").read_text().splitlines()[1:] == before[4:]
    assert [int(r["epoch"]) for r in _rows(out / "eval.csv")] == [0, 1, 2, 3, 4]
    assert sorted(p.name for p in (out / "logs").iterdir()) == ["progress_0.csv", "progress_128.csv"]
    done = json.loads((out / "done.json").read_text())
    assert done["num_timesteps"] == 256 and done["segments"] == 2
    assert 0 < state["cpu_time_s"] <= done["cpu_time_s"]
    assert done["cpus"] == [cpu_model()]  # both segments ran here: one CPU model


@pytest.mark.slow
def test_final_evaluation_on_every_held_out_episode_and_lowest_u_choice(grid_runs):
    for spec in grid_runs["specs"]:
        out = Path(spec.output_dir)
        config, done = _config(out), json.loads((out / "done.json").read_text())
        held_out = [i for i in range(POOL_EPISODES) if i not in config["train_episodes"]]
        policies = ["final"] if spec.method == "bc" else ["final", "lowest_u"]
        rows = _rows(out / "final_eval.csv")
        assert [(r["policy"], int(r["episode"])) for r in rows] == [(p, i) for p in policies for i in held_out]
        final = done["final_evaluation"]
        assert final["episodes"] == held_out
        for policy in policies:
            returns = [float(r["return"]) for r in rows if r["policy"] == policy]
            assert final[policy]["return_mean"] == pytest.approx(np.mean(returns), rel=1e-5)
            assert final[policy]["n_episodes"] == len(held_out)
        if spec.method == "bc":
            assert not (out / "model_lowest_u.zip").exists()
            assert len(_rows(out / "pretrain.csv")) == done["pretrain"]["bc_epochs"] + 1
            continue
        assert (out / "model_lowest_u.zip").is_file() and (out / "lowest_u.pt").is_file()
        if spec.seed == 0:  # one segment: the choice is the argmin of the logged rollout disagreement
            log = _rows(out / "logs" / "progress_0.csv")
            u = {
                int(r["time/total_timesteps"]) // 64 - 1: float(r["rollout/disagreement_mean"])
                for r in log
                if r.get("rollout/disagreement_mean")
            }
            assert final["lowest_u"]["epoch"] == min(u, key=u.get)
            assert final["lowest_u"]["rollout_u"] == pytest.approx(min(u.values()), rel=1e-5)


@pytest.mark.slow
def test_finished_runs_are_skipped(grid_runs):
    done = {s.output_dir: (Path(s.output_dir) / "done.json").stat().st_mtime_ns for s in grid_runs["specs"]}
    csvs = {s.output_dir: (Path(s.output_dir) / "eval.csv").read_bytes() for s in grid_runs["specs"]}
    outcomes = run_grid(grid_runs["specs"], workers=2, progress=False)
    assert [o.status for o in outcomes] == ["skipped"] * 4
    for spec in grid_runs["specs"]:
        assert (Path(spec.output_dir) / "done.json").stat().st_mtime_ns == done[spec.output_dir]
        assert (Path(spec.output_dir) / "eval.csv").read_bytes() == csvs[spec.output_dir]


# -- report ----------------------------------------------------------------------------------------
def _by_hand(run_dir: Path, window: int) -> dict:
    rows = _rows(run_dir / "eval.csv")
    last = int(rows[-1]["epoch"])
    kept = [r for r in rows if int(r["epoch"]) > last - window]
    return {
        k: sum(float(r[c]) for r in kept) / len(kept)
        for k, c in (("return", "return_mean"), ("frechet", "frechet_mean"), ("action_mse", "action_mse"))
    }


@pytest.mark.slow
@pytest.mark.parametrize("window", [100, 2])
def test_report_numbers_equal_hand_computed_means(grid_runs, tmp_path, window):
    runs_dir = grid_runs["runs_dir"]
    rc = main(["report", str(runs_dir), "-o", str(tmp_path), "--window", str(window)])
    assert rc == 0
    text = (tmp_path / "results.md").read_text()
    table = {(r["env"], r["method"]): r for r in _rows(tmp_path / "table1.csv")}
    assert set(table) == {(ENV, "bc"), (ENV, "cmz")}  # the failed run has no evaluations
    for method in ("bc", "cmz"):
        per_trial = [_by_hand(runs_dir / ENV / method / f"trial{t}", window) for t in (0, 1)]
        row = table[(ENV, method)]
        assert row["run_dirs"] == f"{ENV}/{method}/trial0;{ENV}/{method}/trial1"
        cells = []
        for key in ("return", "frechet", "action_mse"):
            values = [p[key] for p in per_trial]
            mean = sum(values) / 2
            std = math.sqrt(sum((v - mean) ** 2 for v in values) / 2)
            assert float(row[f"{key}_mean"]) == pytest.approx(mean, rel=1e-12)
            assert float(row[f"{key}_std"]) == pytest.approx(std, rel=1e-9, abs=1e-12)
            cells.append(report.fmt_mean_std(mean, std))
        # Table I on the page: the return, in the paper's layout (one env: one column); the rest in table1.csv
        assert f"| {report.METHOD_LABELS[method]} | {cells[0]} |" in text
    for png in ("fig1_bc_dril_cmz.png", "fig2_cmz_env_zero.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({png})" in text
    assert "pytest grid" in text  # the command that produced the runs, from config.json
    assert "This report:" in text
    assert "failed without any evaluation" in text and "`broken/zero/trial0`" in text
    assert "paper's Table I" in text and "1690 (360)" in text  # the labelled reference table
    # The final evaluation: each run's final_eval.csv averaged by hand; two trials give no interval.
    final = {(r["method"], r["policy"]): r for r in _rows(tmp_path / "final_table.csv")}
    assert set(final) == {("bc", "final"), ("cmz", "final"), ("cmz", "lowest_u")}
    for (method, policy), row in final.items():
        per_run = [
            np.mean(
                [
                    float(r["return"])
                    for r in _rows(runs_dir / ENV / method / f"trial{t}" / "final_eval.csv")
                    if r["policy"] == policy
                ]
            )
            for t in (0, 1)
        ]
        assert float(row["return_mean"]) == pytest.approx(np.mean(per_run), rel=1e-5)
        assert math.isnan(float(row["return_ci_low"])) and row["n_trials"] == "2"
    assert (tmp_path / "fig3_final_eval.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_report_expert_scale_comes_from_the_held_out_episodes(grid_runs, tiny_experiment, tmp_path):
    records = report.load_runs(grid_runs["runs_dir"])
    pool = Demonstrations.load(tiny_experiment["pool"])
    per_trial = []
    for trial in (0, 1):
        held_out = _config(grid_runs["runs_dir"] / ENV / "cmz" / f"trial{trial}")["eval_episodes"]
        per_trial.append(np.mean([pool.episode(i)["rewards"].sum() for i in held_out]))
    mean, std, n = report.expert_returns(records, grid_runs["runs_dir"])[ENV]
    assert (mean, std, n) == (pytest.approx(np.mean(per_trial)), pytest.approx(np.std(per_trial)), 2)
    text = report.write_report(grid_runs["runs_dir"], tmp_path, references=(), figures=False).read_text()
    assert "| Expert (held-out demos) | " + report.fmt_mean_std(mean, std) + " |" in text


@pytest.mark.slow
def test_report_expert_scale_skips_a_pool_that_changed(grid_runs, tmp_path):
    records = report.load_runs(grid_runs["runs_dir"])
    for r in records:
        r.config = {**r.config, "demos_sha256": "0" * 64}
    assert report.expert_returns(records, tmp_path) == {}


# -- Ray backend ------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.xdist_group("ray")  # one worker for every Ray test (tests/test_ray_cluster.py)
def test_ray_backend_runs_the_grid(tiny_experiment, tmp_path):
    ray = pytest.importorskip("ray")
    specs = plan_grid(
        ENV,
        "bc,cmz",
        2,
        tmp_path / "runs",
        demos_dir=tiny_experiment["demos_dir"],
        hyperparams=tiny_experiment["hp"],
        **{**GRID, "timesteps": 128},
    )
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        outcomes = run_grid(specs, workers=2, backend="ray", progress=False)
    finally:
        ray.shutdown()
    assert [o.status for o in outcomes] == ["done"] * 4
    for spec in specs:
        assert json.loads((Path(spec.output_dir) / "done.json").read_text())["num_timesteps"] == (
            0 if spec.method == "bc" else 128
        )


# -- the train / evaluate CLI ---------------------------------------------------------------------------------
@pytest.mark.slow
def test_train_cli_end_to_end_then_evaluate(tiny_experiment, tmp_path, capsys):
    out = tmp_path / "cmz"
    args = [
        "train",
        "--env",
        ENV,
        "--reward",
        "cmz",
        "--demos",
        str(tiny_experiment["pool"]),
        "--n-demos",
        "2",
        "--eval-episodes",
        "1",
        "--seed",
        "3",
        "--timesteps",
        "128",
        "--hyperparams",
        str(tiny_experiment["hp"]),
        "-o",
        str(out),
        "--no-progress",
    ]
    assert main(args) == 0
    config = _config(out)
    assert config["method"] == "cmz" and config["seed"] == 3 and config["timesteps"] == 128
    assert (config["train_episodes"], config["eval_episodes"]) == split_episodes(POOL_EPISODES, 2, 1, 3)
    assert config["hyperparams_values"]["n_steps"] == 64 and config["versions"]["stable_baselines3"]
    assert "train --env Pendulum-v1 --reward cmz" in config["train_command"]
    assert [int(r["epoch"]) for r in _rows(out / "eval.csv")] == [0, 1, 2]
    assert json.loads((out / "done.json").read_text())["status"] == "done"
    assert main(args) == 0 and "already finished" in capsys.readouterr().out

    episodes = ",".join(map(str, config["eval_episodes"]))
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(out / "model.zip"),
                "--env",
                ENV,
                "--demos",
                str(tiny_experiment["pool"]),
                "--episodes",
                episodes,
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "mean" in printed and "Fréchet" in printed
    # The evaluate command and the run's last evaluation agree (same episodes, same env_kwargs).
    last = _rows(out / "eval.csv")[-1]
    assert f"{float(last['return_mean']):.2f}" in printed


@pytest.mark.slow
def test_train_cli_bc_and_normalize(tiny_experiment, tmp_path):
    bc = tmp_path / "bc"
    assert (
        main(
            [
                "train",
                "--env",
                ENV,
                "--reward",
                "bc",
                "--demos",
                str(tiny_experiment["pool"]),
                "--eval-episodes",
                "1",
                "--hyperparams",
                str(tiny_experiment["hp"]),
                "-o",
                str(bc),
                "--no-progress",
            ]
        )
        == 0
    )
    assert [int(r["epoch"]) for r in _rows(bc / "eval.csv")] == [0]
    assert _config(bc)["timesteps"] == 0

    hp = tmp_path / "norm.yml"
    hp.write_text(TINY_YAML + '  normalize: "dict(norm_obs=True, norm_reward=False)"\n')
    spec = plan_run(
        ENV,
        "env",
        0,
        demos=tiny_experiment["pool"],
        n_eval_episodes=1,
        timesteps=192,
        hyperparams=hp,
        output_dir=tmp_path / "norm",
        checkpoint_every=1,
    )
    with pytest.raises(KeyboardInterrupt):
        run_experiment(spec, callbacks=[Interrupt(at=128)])
    assert (tmp_path / "norm" / "vecnormalize.pkl").is_file()
    longer = dataclasses.replace(spec, timesteps=256)  # a resume may also extend the run
    assert run_experiment(longer)["num_timesteps"] == 256
    assert (
        _config(tmp_path / "norm")["timesteps"] == 256
        and "--timesteps 256" in _config(tmp_path / "norm")["train_command"]
    )
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    stats = VecNormalize.load(str(tmp_path / "norm" / "vecnormalize.pkl"), DummyVecEnv([lambda: gym.make(ENV)]))
    assert stats.obs_rms.count > 250  # statistics carried across the resume (128 fresh steps would not)
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(tmp_path / "norm" / "model.zip"),
                "--env",
                ENV,
                "--demos",
                str(tiny_experiment["pool"]),
                "--episodes",
                "0",
            ]
        )
        == 0
    )


# -- clear errors -------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "extra, message",
    [
        (["--methods", "bc,magic"], "unknown method 'magic'"),
        (["--env", "NoSuchEnv-v0"], "unknown environment 'NoSuchEnv-v0'"),
        (["--demos-dir", "/nonexistent"], "demo pool not found"),
        (["--n-demos", "5"], "6 episodes but 5 training \\+ 2 evaluation"),
        (["--backend", "carrier-pigeon"], "unknown backend"),
        (["--hyperparams", "TYPO"], "\\['n_step'\\] are not CMZDRIL/PPO arguments"),
    ],
)
def test_benchmark_errors(tiny_experiment, tmp_path, capsys, extra, message):
    args = [
        "benchmark",
        "--env",
        ENV,
        "--methods",
        "bc",
        "--trials",
        "1",
        "--eval-episodes",
        "2",
        "--demos-dir",
        str(tiny_experiment["demos_dir"]),
        "--hyperparams",
        str(tiny_experiment["hp"]),
        "-o",
        str(tmp_path / "r"),
    ]
    if extra == ["--hyperparams", "TYPO"]:
        typo = tmp_path / "typo.yml"
        typo.write_text(TINY_YAML + "  n_step: 32\n")
        extra = ["--hyperparams", str(typo)]
    args += extra  # later options win in argparse
    assert main(args) == 2
    import re

    assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "r" / ENV).exists()  # nothing started


def test_ray_missing_and_train_errors(tiny_experiment, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    assert (
        main(
            [
                "benchmark",
                "--env",
                ENV,
                "--methods",
                "bc",
                "--trials",
                "1",
                "--eval-episodes",
                "2",
                "--demos-dir",
                str(tiny_experiment["demos_dir"]),
                "--hyperparams",
                str(tiny_experiment["hp"]),
                "-o",
                str(tmp_path / "r"),
                "--backend",
                "ray",
            ]
        )
        == 2
    )
    assert "pip install 'sb3-cmzdril[ray]'" in capsys.readouterr().err

    base = [
        "train",
        "--env",
        ENV,
        "--demos",
        str(tiny_experiment["pool"]),
        "--hyperparams",
        str(tiny_experiment["hp"]),
        "--eval-episodes",
        "1",
    ]
    assert main([*base, "--reward", "gail", "-o", str(tmp_path / "x")]) == 2
    assert "unknown method 'gail'" in capsys.readouterr().err
    nope = ["train", "--env", "sb3_cmzdril:Nope-v0", "--reward", "cmz", "--demos", str(tiny_experiment["pool"])]
    assert main(nope) == 2
    assert "unknown environment" in capsys.readouterr().err
    # A folder holding another run is not silently mixed with a new one.
    out = tmp_path / "bc"
    assert main([*base, "--reward", "bc", "-o", str(out), "--seed", "0"]) == 0
    (out / "done.json").unlink()
    assert main([*base, "--reward", "bc", "-o", str(out), "--seed", "1"]) == 2
    assert "holds a different run" in capsys.readouterr().err


def test_run_experiment_checks_a_spec_made_by_hand_before_writing(tiny_experiment, tmp_path):
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=1, timesteps=128,
                    hyperparams=tiny_experiment["hp"], output_dir=tmp_path / "run")
    bad = tmp_path / "bad.yml"
    bad.write_text(with_entry(TINY_YAML, "  n_epochs: 0\n"))
    with pytest.raises(ValueError, match="n_epochs must be >= 1, got 0"):
        run_experiment(dataclasses.replace(spec, hyperparams=str(bad)))
    assert not (tmp_path / "run").exists()


def test_a_pool_is_held_to_the_env_kwargs_it_was_recorded_with(tiny_experiment, tmp_path):
    # The tiny YAML makes Pendulum-v1 with max_episode_steps=50 and nothing else.
    pool = tmp_path / "pool.npz"
    pool.write_bytes(tiny_experiment["pool"].read_bytes())
    plan = dict(demos=pool, n_eval_episodes=1, timesteps=128, hyperparams=tiny_experiment["hp"])
    record = tmp_path / "pool.json"
    # Another time limit wraps the same env: a quick run on a pool of longer episodes is allowed.
    record.write_text(json.dumps({"demos": {"env_id": ENV, "env_kwargs": {"max_episode_steps": 200}}}))
    plan_run(ENV, "cmz", 0, output_dir=tmp_path / "same", **plan)
    record.write_text(json.dumps({"demos": {"env_id": ENV, "env_kwargs": {"g": 9.0}}}))
    with pytest.raises(ValueError, match=r"recorded with env_kwargs \{'g': 9.0\}, .* make the env with \{\}"):
        plan_run(ENV, "cmz", 0, output_dir=tmp_path / "other", **plan)
    assert not (tmp_path / "same").exists() and not (tmp_path / "other").exists()


def test_a_published_run_folder_is_still_the_same_run():
    """A run folder written before the run half was restructured (results/runs) is recognised as the
    finished run of the same spec: config.json's identity is what it was."""
    from cmzdril_lab.records_store import materialize

    repo = Path(__file__).resolve().parent.parent
    out = materialize(repo / "results" / "runs" / "Hopper-v5" / "cmz" / "trial0")  # unpacked from runs.tar.xz
    config = _config(out)
    spec = RunSpec(
        env_id=config["env_id"], method=config["method"], demos=str(repo / "experts" / "Hopper-v5" / "demos.npz"),
        seed=config["seed"], n_demos=config["n_demos"], n_eval_episodes=config["n_eval_episodes"],
        timesteps=config["timesteps"], output_dir=str(out), hyperparams=str(repo / "hyperparams" / "cmzdril-tuned.yml"),
    )
    assert check_finished(spec) == json.loads((out / "done.json").read_text())
    with pytest.raises(ValueError, match="holds a different, finished run \\(seed: 0 there, 1 now"):
        check_finished(dataclasses.replace(spec, seed=1))


def test_an_env_id_with_its_module_prefix_names_the_same_run(tmp_path):
    """gymnasium's ``module:Env-v0`` is ``Env-v0`` once the module is imported: a run asked either way is the
    run in the folder; another env id, or another run's identity, still refuses."""
    from sb3_cmzdril.training.run_folder import check_same_run

    saved = {"env_id": "WaypointNav-v0", "method": "cmz", "seed": 3}
    check_same_run(tmp_path, saved, {**saved, "env_id": "sb3_cmzdril:WaypointNav-v0"})
    check_same_run(tmp_path, {**saved, "env_id": "sb3_cmzdril:WaypointNav-v0"}, saved)
    with pytest.raises(ValueError, match="env_id: 'WaypointNav-v0' there, 'sb3_cmzdril:Other-v0' now"):
        check_same_run(tmp_path, saved, {**saved, "env_id": "sb3_cmzdril:Other-v0"})
    with pytest.raises(ValueError, match="seed: 3 there, 4 now"):
        check_same_run(tmp_path, saved, {**saved, "env_id": "sb3_cmzdril:WaypointNav-v0", "seed": 4})


def test_a_run_folder_of_an_older_version_reads_the_defaults_it_ran_with():
    """A 0.2.0 record that left the five rule settings out ran with the paper's values: the same entry now
    (the rules) is another run, named setting by setting; an entry that states the old values is the same."""
    from helpers import PAPER
    from sb3_cmzdril.training.run_folder import check_same_run

    saved = {"env_id": "Pendulum-v1", "method": "cmz", "seed": 0, "hyperparams_values": {"n_timesteps": 1e6},
             "versions": {"sb3_cmzdril": "0.2.0"}}
    fresh = {**saved, "versions": {"sb3_cmzdril": "0.3.0.dev0"}}
    with pytest.raises(ValueError, match=r"hyperparams_values: absorbing False there, the default now; .*"
                                         r"standardize_observations True there, the default now \(the folder's "
                                         r"run was made by sb3-cmzdril 0\.2\.0\)"):
        check_same_run(Path("out"), saved, fresh)
    check_same_run(Path("out"), saved, {**fresh, "hyperparams_values": {"n_timesteps": 1e6, **PAPER}})


def test_grid_module_names():
    assert runs.METHODS == ("bc", "zero", "env", "dril", "cmz", "cmz-sac", "dril-sac", "zero-sac", "env-sac")
    assert grid.parse_list("cmz, bc,cmz,,") == ["cmz", "bc"]
