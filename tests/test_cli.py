"""The command line's contract: every mistake is one line on stderr and exit code 2 with nothing
written or replaced; Ctrl-C is one line and exit code 130; no silent wrong answer.

Everything runs on Pendulum-v1 cut to 50-step episodes with tiny networks, as in test_experiments.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from helpers import ENV, POOL_EPISODES, pendulum_expert, record, with_entry
from helpers import TINY_PPO_YAML as TINY_PPO
from helpers import TINY_SAC_YAML as TINY_SAC
from helpers import write_run as _fake_run
from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.io import write_json

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def setup(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cli")
    pool = root / "experts" / ENV / "demos.npz"
    pool.parent.mkdir(parents=True)
    record(ENV, pendulum_expert, n_episodes=POOL_EPISODES, max_steps=50, seed=100).save(pool)
    ppo, sac = root / "cmzdril.yml", root / "sac.yml"
    ppo.write_text(TINY_PPO)
    sac.write_text(TINY_SAC)
    return {"root": root, "pool": pool, "ppo": ppo, "sac": sac}


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """Every path below ``folder`` with its size and modification time: 'nothing written or replaced'."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(folder.rglob("*"))}


def error_line(capsys, command: str) -> str:
    """stderr, checked to be exactly one error line of ``command``."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sb3-cmzdril {command}: error: "), err
    return lines[0]


def train_args(setup, *extra: str, reward: str = "bc") -> list[str]:
    return [
        "train",
        "--env",
        ENV,
        "--reward",
        reward,
        "--demos",
        str(setup["pool"]),
        "--hyperparams",
        str(setup["ppo"]),
        "--eval-episodes",
        "1",
        "--no-progress",
        *extra,
    ]


def sac_args(setup, *extra: str) -> list[str]:
    return [
        "train-expert",
        "--env",
        ENV,
        "--hyperparams",
        str(setup["sac"]),
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--checkpoint-freq",
        "100",
        "--final-eval-episodes",
        "1",
        "--no-progress",
        *extra,
    ]


# -- mistakes: exit 2, one line, nothing written ------------------------------------------------------------
def test_unknown_env_id_writes_nothing(setup, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # train-expert without -o would create experts/NoSuchEnv-v0/ here
    assert main(["train-expert", "--env", "NoSuchEnv-v0", "--timesteps", "100"]) == 2
    assert "unknown environment 'NoSuchEnv-v0'" in error_line(capsys, "train-expert")
    assert main(["collect-demos", "--expert", "test-anything", "--env", "NoSuchEnv-v0", "-o", "d.npz"]) == 2
    assert "unknown environment 'NoSuchEnv-v0'" in error_line(capsys, "collect-demos")
    assert main(["evaluate", "--model", "m.zip", "--env", "NoSuchEnv-v0", "--demos", str(setup["pool"])]) == 2
    assert "unknown environment 'NoSuchEnv-v0'" in error_line(capsys, "evaluate")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["train-expert", "collect-demos"])
def test_negative_seed(setup, tmp_path, capsys, command):
    if command == "train-expert":
        args = sac_args(setup, "--seed", "-1", "-o", str(tmp_path / "expert"))
    else:
        args = [
            "collect-demos",
            "--expert",
            str(tmp_path / "x.zip"),
            "--env",
            ENV,
            "--seed",
            "-1",
            "-o",
            str(tmp_path / "d.npz"),
        ]
    assert main(args) == 2
    assert "seed must be an integer in [0, 2**32), got -1" in error_line(capsys, command)
    assert list(tmp_path.iterdir()) == []


def test_zero_threads(setup, tmp_path, capsys):
    assert main(sac_args(setup, "--threads", "0", "-o", str(tmp_path / "expert"))) == 2
    assert "threads must be >= 1, got 0" in error_line(capsys, "train-expert")
    assert main(train_args(setup, "--threads", "0", "-o", str(tmp_path / "run"))) == 2
    assert "threads must be >= 1, got 0" in error_line(capsys, "train")
    assert list(tmp_path.iterdir()) == []


def _corrupt_deflate(src: Path, dst: Path) -> None:
    """A copy of an npz whose first compressed member has a damaged deflate stream (CRC intact)."""
    shutil.copy(src, dst)
    with zipfile.ZipFile(dst) as zf:
        info = next(i for i in zf.infolist() if i.compress_type == zipfile.ZIP_DEFLATED and i.compress_size > 8)
    with open(dst, "r+b") as f:
        f.seek(info.header_offset + 26)
        name_len, extra_len = int.from_bytes(f.read(2), "little"), int.from_bytes(f.read(2), "little")
        f.seek(info.header_offset + 30 + name_len + extra_len)
        f.write(b"\xff" * 8)  # a final block of the reserved type 3: zlib fails before any CRC check


def test_corrupt_compressed_demo_file(setup, tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    _corrupt_deflate(setup["pool"], bad)
    before = snapshot(tmp_path)
    assert main(train_args(setup, "--demos", str(bad), "-o", str(tmp_path / "run"))) == 2
    line = error_line(capsys, "train")
    assert f"demo file {bad} is corrupt: Error -3 while decompressing data" in line
    assert main(["evaluate", "--model", str(bad), "--env", ENV, "--demos", str(bad)]) == 2
    assert "is corrupt" in error_line(capsys, "evaluate")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize(
    "command, entry, message",
    [
        ("train", '  n_steps: "lots"\n', "n_steps must be int, got 'lots' \\(str\\)"),
        ("train", "  n_steps: 1\n", "`n_steps \\* n_envs` must be greater than 1"),
        ("train", "  alpha: [1, 2]\n", "alpha must be float, got \\[1, 2\\] \\(list\\)"),
        # Values the constructors accept but training cannot use: refused before the run folder exists.
        ("train", "  n_epochs: 0\n", "n_epochs must be >= 1, got 0"),
        ("train", "  ensemble_epochs: 0\n", "ensemble_epochs must be >= 1, got 0"),
        ("train", "  batch_size: 0\n", "`batch_size` must be greater than 1"),
        ("train", "  learning_rate: .nan\n", "learning_rate must be finite, got nan"),
        ("train", "  gamma: .nan\n", "gamma must be finite, got nan"),
        ("train", "  clip_range: -1\n", "clip_range must be finite and > 0, got -1.0"),
        ("train-expert", "  n_step: 3\n", "\\['n_step'\\] are not SAC arguments"),
        ("train-expert", '  batch_size: "big"\n', "batch_size must be int, got 'big'"),
        ("train-expert", '  learning_rate: "fast"\n', "invalid schedule for learning_rate"),
    ],
)
def test_wrong_yaml_values(setup, tmp_path, capsys, command, entry, message):
    import re

    bad, out = tmp_path / "bad.yml", tmp_path / "out"
    if command == "train":
        bad.write_text(with_entry(TINY_PPO, entry))
        args = train_args(setup, "--hyperparams", str(bad), "--timesteps", "128", "-o", str(out), reward="cmz")
    else:
        bad.write_text(with_entry(TINY_SAC, entry))
        args = sac_args(setup, "--hyperparams", str(bad), "-o", str(out))
    assert main(args) == 2
    assert re.search(message, error_line(capsys, command))
    assert not out.exists()


def test_train_demo_pool_message_names_an_option_train_has(setup, tmp_path, capsys):
    assert main(train_args(setup, "--demos", str(tmp_path / "none.npz"), "-o", str(tmp_path / "run"))) == 2
    line = error_line(capsys, "train")
    assert "demo pool not found" in line and "--demos)" in line and "--demos-dir" not in line


def test_demo_pool_of_another_env_is_refused_before_config_json(setup, tmp_path, capsys):
    cartpole = tmp_path / "cartpole.npz"
    from helpers import cartpole_expert

    record("CartPole-v1", cartpole_expert, n_episodes=POOL_EPISODES, max_steps=20).save(cartpole)
    assert main(train_args(setup, "--demos", str(cartpole), "-o", str(tmp_path / "run"))) == 2
    assert "does not fit Pendulum-v1" in error_line(capsys, "train")
    assert not (tmp_path / "run").exists()
    # The corrected command then runs in that folder.
    assert main(train_args(setup, "-o", str(tmp_path / "run"))) == 0


def test_demo_pool_without_reset_seeds_is_refused_before_anything_is_written(setup, tmp_path, capsys):
    pool = Demonstrations.load(setup["pool"])
    unseeded = tmp_path / "unseeded.npz"
    Demonstrations(pool.observations, pool.actions, pool.episode_lengths, pool.rewards).save(unseeded)
    before = snapshot(tmp_path)
    assert main(train_args(setup, "--demos", str(unseeded), "-o", str(tmp_path / "run"))) == 2
    assert "held out for evaluation, have no recorded reset seed" in error_line(capsys, "train")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", ["train", "benchmark"])
@pytest.mark.parametrize(
    "files, message",
    [
        ({"config.json": '{"my": "notes"}'}, "config.json is not the config.json of an sb3-cmzdril run"),
        ({"demos.npz": "", "metadata.json": "{}"}, "files that are not an sb3-cmzdril run's (demos.npz, metadata"),
    ],
    ids=["someone's config.json", "an expert's folder"],
)
def test_a_folder_the_run_did_not_create_is_refused_untouched(setup, tmp_path, capsys, command, files, message):
    out = tmp_path / "runs" / ENV / "bc" / "trial0"  # where benchmark -o tmp_path/runs puts trial 0 of bc
    out.mkdir(parents=True)
    for name, text in files.items():
        (out / name).write_text(text)
    before = snapshot(tmp_path)
    if command == "train":
        args = train_args(setup, "-o", str(out))
    else:
        args = ["benchmark", "--env", ENV, "--methods", "bc", "--trials", "1", "--eval-episodes", "1", "--no-progress",
                "--demos-dir", str(setup["pool"].parent.parent), "--hyperparams", str(setup["ppo"]),
                "-o", str(tmp_path / "runs")]
    assert main(args) == 2
    assert message in error_line(capsys, command)
    assert snapshot(tmp_path) == before


def test_benchmark_runs_the_trials_it_names(setup, tmp_path):
    runs = tmp_path / "runs"
    assert main(["benchmark", "--env", ENV, "--methods", "bc", "--trials", "1,3", "--eval-episodes", "1",
                 "--no-progress", "--demos-dir", str(setup["pool"].parent.parent), "--hyperparams",
                 str(setup["ppo"]), "-o", str(runs)]) == 0
    assert sorted(p.name for p in (runs / ENV / "bc").iterdir()) == ["trial1", "trial3"]
    record = json.loads((runs / "benchmark.jsonl").read_text().splitlines()[-1])
    assert record["trials"] == [1, 3]


def test_failed_attempt_before_any_checkpoint_does_not_block_the_corrected_rerun(setup, tmp_path):
    from sb3_cmzdril.training import runs
    from sb3_cmzdril.training.run_folder import run_config

    out = tmp_path / "run"
    spec = runs.plan_run(ENV, "bc", 0, demos=setup["pool"], n_eval_episodes=1, hyperparams=setup["ppo"], output_dir=out)
    # What an attempt with another split leaves when it dies before its first checkpoint: config.json alone.
    stale = runs.plan_run(
        ENV, "bc", 1, demos=setup["pool"], n_eval_episodes=1, hyperparams=setup["ppo"], output_dir=out
    )
    write_json(out / "config.json", run_config(runs.resolve_run(stale, check=False)))
    assert runs.run_experiment(spec)["status"] == "done"
    assert json.loads((out / "config.json").read_text())["seed"] == 0


# -- evaluate -----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def normalized_run(setup, tmp_path_factory) -> Path:
    """A finished bc run whose hyperparameters normalise observations (vecnormalize.pkl beside model.zip)."""
    hp = setup["root"] / "norm.yml"
    hp.write_text(TINY_PPO + '  normalize: "dict(norm_obs=True, norm_reward=False)"\n')
    out = tmp_path_factory.mktemp("norm") / "run"
    assert main(train_args(setup, "--hyperparams", str(hp), "--eval-episodes", "2", "--seed", "2", "-o", str(out))) == 0
    assert (out / "vecnormalize.pkl").is_file()
    return out


def test_evaluate_defaults_to_the_runs_held_out_episodes(normalized_run, capsys):
    capsys.readouterr()
    held_out = json.loads((normalized_run / "config.json").read_text())["eval_episodes"]
    assert main(["evaluate", "--model", str(normalized_run / "model.zip"), "--env", ENV]) == 0
    out = " ".join(capsys.readouterr().out.split())  # the console wraps lines where tmp_path is long
    assert f"episodes {','.join(map(str, held_out))} of " in out and "the run's held-out episodes" in out
    assert "2 episodes of" in out  # the table's title: the held-out pair, not the pool's 6
    assert f"normalised with {normalized_run / 'vecnormalize.pkl'}, found beside the model" in out


def test_evaluate_says_which_pickle_beside_the_model_it_loads_before_loading_it(normalized_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(normalized_run, run)
    (run / "vecnormalize.pkl").write_bytes(b"not a pickle")  # a pickle the user did not name, damaged
    capsys.readouterr()
    main(["evaluate", "--model", str(run / "model.zip"), "--env", ENV])
    out = " ".join(capsys.readouterr().out.split())
    assert f"normalised with {run / 'vecnormalize.pkl'}, found beside the model" in out


def test_evaluate_all_episodes_of_another_pool(normalized_run, setup, tmp_path, capsys):
    other = tmp_path / "other.npz"
    Demonstrations.load(setup["pool"]).select([0, 1, 2]).save(other)
    capsys.readouterr()
    assert main(["evaluate", "--model", str(normalized_run / "model.zip"), "--env", ENV, "--demos", str(other)]) == 0
    assert "all 3 episodes (not the run's demo pool" in capsys.readouterr().out


def test_evaluate_episode_out_of_range(normalized_run, capsys):
    assert main(["evaluate", "--model", str(normalized_run / "model.zip"), "--env", ENV, "--episodes", "0,99"]) == 2
    assert f"has {POOL_EPISODES} episodes, numbered 0 to {POOL_EPISODES - 1}" in error_line(capsys, "evaluate")


def test_evaluate_refuses_to_run_without_the_statistics(normalized_run, setup, tmp_path, capsys):
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(normalized_run / "model.zip"),
                "--env",
                ENV,
                "--vecnormalize",
                str(tmp_path / "typo.pkl"),
            ]
        )
        == 2
    )
    assert f"VecNormalize statistics not found: {tmp_path / 'typo.pkl'}" in error_line(capsys, "evaluate")
    # The model and its config copied without vecnormalize.pkl.
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("model.zip", "config.json"):
        shutil.copy(normalized_run / name, copy / name)
    assert main(["evaluate", "--model", str(copy / "model.zip"), "--env", ENV]) == 2
    assert "trained on VecNormalize'd observations" in error_line(capsys, "evaluate")
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(copy / "model.zip"),
                "--env",
                ENV,
                "--vecnormalize",
                str(normalized_run / "vecnormalize.pkl"),
            ]
        )
        == 0
    )
    # The model alone, without its config.json: the zip itself says it needs the statistics.
    (copy / "config.json").unlink()
    assert main(["evaluate", "--model", str(copy / "model.zip"), "--env", ENV, "--demos", str(setup["pool"])]) == 2
    assert "was trained on VecNormalize'd observations" in error_line(capsys, "evaluate")
    damaged = tmp_path / "damaged.pkl"
    damaged.write_bytes(b"not a pickle")
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(copy / "model.zip"),
                "--env",
                ENV,
                "--demos",
                str(setup["pool"]),
                "--vecnormalize",
                str(damaged),
            ]
        )
        == 2
    )
    assert "are damaged or not VecNormalize's" in error_line(capsys, "evaluate")


def test_evaluate_refuses_held_out_indices_of_a_changed_pool(normalized_run, setup, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(normalized_run, run)
    pool = tmp_path / "pool.npz"
    shutil.copy(setup["pool"], pool)
    config = json.loads((run / "config.json").read_text())
    config["demos"] = str(pool)
    (run / "config.json").write_text(json.dumps(config))
    Demonstrations.load(setup["pool"]).select([5, 4, 3, 2, 1, 0]).save(pool)  # same size, other order
    assert main(["evaluate", "--model", str(run / "model.zip"), "--env", ENV]) == 2
    assert "changed since the run was trained" in error_line(capsys, "evaluate")


# -- finished runs: no foreign numbers, no silent "nothing to do" -------------------------------------------
def test_finished_run_reused_with_another_method_is_refused(setup, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(train_args(setup, "-o", str(out))) == 0
    before = snapshot(out)
    capsys.readouterr()
    assert main(train_args(setup, "-o", str(out), reward="zero")) == 2
    assert "holds a different, finished run (method: 'bc' there, 'zero' now)" in error_line(capsys, "train")
    assert snapshot(out) == before
    assert main(train_args(setup, "-o", str(out))) == 0  # the same command: skipped, as before
    assert "already finished" in capsys.readouterr().out


@pytest.mark.slow
def test_finished_run_asked_for_more_steps_says_how_to_extend(setup, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(train_args(setup, "--timesteps", "128", "-o", str(out), reward="zero")) == 0
    shown = capsys.readouterr().out  # the final evaluation of both kept policies, with their files
    assert "final evaluation, final policy: return" in shown and str(out / "model.zip") in shown
    assert "final evaluation, lowest-u policy (epoch " in shown and str(out / "model_lowest_u.zip") in shown
    before = snapshot(out)
    assert main(train_args(setup, "--timesteps", "192", "-o", str(out), reward="zero")) == 2
    line = error_line(capsys, "train")
    assert "is finished at 128 steps (done.json), fewer than the 192 asked" in line and "delete" in line
    assert snapshot(out) == before
    (out / "done.json").unlink()  # what the message says to do
    assert main(train_args(setup, "--timesteps", "192", "-o", str(out), reward="zero")) == 0
    assert json.loads((out / "done.json").read_text())["num_timesteps"] == 192


def test_benchmark_refuses_a_finished_run_of_other_settings(setup, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    # trial 0 of bc, finished where the benchmark keeps it (train here: no worker process to start)
    assert main(train_args(setup, "-o", str(runs_dir / ENV / "bc" / "trial0"))) == 0
    before = snapshot(runs_dir)
    capsys.readouterr()
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
                "--no-progress",
                "--demos-dir",
                str(setup["pool"].parent.parent),
                "--hyperparams",
                str(setup["ppo"]),
                "-o",
                str(runs_dir),
            ]
        )
        == 2
    )
    assert "holds a different, finished run (eval_episodes:" in error_line(capsys, "benchmark")
    assert snapshot(runs_dir) == before


# -- existing results are never replaced without --force ----------------------------------------------------
def _pd_expert(env):
    class PD:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return pendulum_expert(obs), None

    return PD()


def test_collect_demos_keeps_an_existing_pool_and_foreign_metadata(tmp_path, capsys):
    from sb3_cmzdril.experts import register_scripted_expert

    register_scripted_expert("test-cli-pd", _pd_expert)
    pool = tmp_path / "demos.npz"
    base = ["collect-demos", "--expert", "test-cli-pd", "--env", ENV, "--episodes", "3", "-o", str(pool)]
    assert main(base) == 0
    before = snapshot(tmp_path)
    assert main(base[:-4] + ["--episodes", "1", "-o", str(pool)]) == 2
    assert f"{pool} already exists (a demo pool of 3 episodes); pass --force" in error_line(capsys, "collect-demos")
    assert snapshot(tmp_path) == before
    assert main(base[:-4] + ["--episodes", "1", "-o", str(pool), "--force"]) == 0
    assert Demonstrations.load(pool).n_episodes == 1
    assert json.loads((tmp_path / "demos.json").read_text())["demos"]["episodes"] == 1


@pytest.mark.slow
def test_report_does_not_replace_results_without_force(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    _fake_run(runs_dir, "bc", 0, [1.0], [1.0], [0.1])
    docs = tmp_path / "docs"
    assert main(["report", str(runs_dir), "-o", str(docs)]) == 0
    before = snapshot(docs)
    capsys.readouterr()
    assert main(["report", str(runs_dir), "-o", str(docs)]) == 2
    assert "already holds results.md, table1.csv" in error_line(capsys, "report")
    assert snapshot(docs) == before
    assert main(["report", str(runs_dir), "-o", str(docs), "--force"]) == 0


def test_train_expert_keeps_an_expert_it_cannot_resume(setup, tmp_path, capsys):
    expert = tmp_path / "expert"
    expert.mkdir()
    (expert / "model.zip").write_bytes(b"a shipped expert, no checkpoints")
    before = snapshot(expert)
    assert main(sac_args(setup, "--timesteps", "100", "-o", str(expert))) == 2
    assert "already holds model.zip but no checkpoint to resume from; pass --force" in error_line(
        capsys, "train-expert"
    )
    assert snapshot(expert) == before


# -- Ctrl-C --------------------------------------------------------------------------------------------------
def test_keyboard_interrupt_is_one_line_and_130(setup, tmp_path, capsys, monkeypatch):
    from sb3_cmzdril.training import runs

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runs, "execute_run", interrupted)
    assert main(train_args(setup, "-o", str(tmp_path / "run"))) == 130
    assert capsys.readouterr().err == "sb3-cmzdril train: interrupted; rerun the same command to resume\n"


@pytest.mark.slow
def test_sigint_during_training_is_one_line_and_leaves_a_checkpoint(setup, tmp_path):
    """A real Ctrl-C (SIGINT) in the middle of PPO training, in a child process."""
    out = tmp_path / "run"
    command = [
        sys.executable,
        "-m",
        "sb3_cmzdril",
        *train_args(setup, "--timesteps", "100000", "--checkpoint-every", "1", "-o", str(out), reward="zero"),
    ]
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.time() + 120
    while not (out / "state.json").is_file() and child.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err
    assert err.strip().splitlines()[-1] == "sb3-cmzdril train: interrupted; rerun the same command to resume"
    assert json.loads((out / "state.json").read_text())["num_timesteps"] > 0  # a checkpoint to resume from


# -- MuJoCo's noise ------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_halfcheetah_settotalmass_warning_and_log_file_are_gone(tmp_path):
    pytest.importorskip("mujoco")
    plain, cli = tmp_path / "plain", tmp_path / "cli"
    plain.mkdir()
    cli.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # Without the CLI's handler MuJoCo writes the file (so the check below can fail).
    subprocess.run(
        [sys.executable, "-c", "import gymnasium as gym; gym.make('HalfCheetah-v5').reset(seed=0)"],
        cwd=plain,
        env=env,
        capture_output=True,
        check=True,
    )
    assert (plain / "MUJOCO_LOG.TXT").is_file()
    # The command makes the env, then fails on the expert name: the env was built, nothing else ran.
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sb3_cmzdril",
            "collect-demos",
            "--expert",
            "no-such-expert",
            "--env",
            "HalfCheetah-v5",
            "-o",
            "d.npz",
        ],
        cwd=cli,
        env=env,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and "unknown expert 'no-such-expert'" in result.stderr
    assert "settotalmass" not in result.stderr
    assert list(cli.iterdir()) == []


def test_train_shows_progress_unless_told_not_to(setup, tmp_path, monkeypatch):
    """The progress display (PPO steps; pretraining where the algorithm supports it) is on by default."""
    from sb3_cmzdril.training import runs

    seen = []
    monkeypatch.setattr(
        runs, "execute_run", lambda run, **kwargs: seen.append(kwargs["progress_bar"]) or {"status": "stopped"}
    )
    args = [a for a in train_args(setup, "-o", str(tmp_path / "run")) if a != "--no-progress"]
    main(args)
    main(args + ["--no-progress"])
    assert seen == [True, False]
