"""train-expert (tiny SAC on Pendulum: files, resume, interruption) and collect-demos."""
import json
import logging
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from helpers import SHORT_EPISODES, TINY_SAC, zoo_yaml
from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.experts import (
    SCRIPTED_EXPERTS,
    collect_demos,
    load_expert_model,
    pool_provenance,
    register_scripted_expert,
    run_episode,
    train_expert,
)
from sb3_cmzdril.io import LOCK_FILE

ENV = "Pendulum-v1"
# Tiny SAC, 50-step episodes: a few hundred steps train in a couple of seconds.
TINY_YAML = zoo_yaml(ENV, TINY_SAC, n_timesteps=20000, learning_rate=1e-3, env_kwargs=SHORT_EPISODES)
FAST = dict(eval_freq=100, n_eval_episodes=1, checkpoint_freq=100, final_eval_episodes=2, progress_bar=False)


@pytest.fixture(scope="module")
def tiny_yaml(tmp_path_factory):
    p = tmp_path_factory.mktemp("hp") / "sac.yml"
    p.write_text(TINY_YAML)
    return p


@pytest.fixture(scope="module")
def trained(tiny_yaml, tmp_path_factory):
    """One tiny expert trained through the CLI entry point (200 steps)."""
    out = tmp_path_factory.mktemp("expert") / "Pendulum-v1"
    rc = main([
        "train-expert", "--env", ENV, "--timesteps", "200", "--seed", "3", "--hyperparams", str(tiny_yaml),
        "-o", str(out), "--eval-freq", "100", "--eval-episodes", "1", "--checkpoint-freq", "100",
        "--final-eval-episodes", "2", "--no-progress",
    ])
    assert rc == 0
    return out


def _state(out: Path) -> dict:
    return json.loads((out / "checkpoints" / "state.json").read_text())


def _buffer(out: Path):
    model = SAC.load(out / "checkpoints" / _state(out)["model_file"], device="cpu")
    model.load_replay_buffer(out / "checkpoints" / _state(out)["replay_buffer_file"])
    return model


@pytest.mark.slow
def test_train_expert_writes_model_and_metadata(trained):
    assert sorted(p.name for p in trained.iterdir()) == ["checkpoints", "metadata.json", "model.zip"]
    model = SAC.load(trained / "model.zip", device="cpu")
    assert model.policy.actor.latent_pi[0].out_features == 16  # the YAML's net_arch was used
    meta = json.loads((trained / "metadata.json").read_text())
    assert meta["env_id"] == ENV and meta["algo"] == "sac" and meta["seed"] == 3
    assert meta["total_timesteps"] == 200
    assert meta["model_timesteps"] in (100, 200)
    assert meta["eval"]["n_episodes"] == 2 and len(meta["eval"]["episode_returns"]) == 2
    assert np.isfinite(meta["eval"]["mean_reward"]) and meta["eval"]["deterministic"] is True
    assert meta["hyperparams"]["values"]["policy_kwargs"] == "dict(net_arch=[16, 16])"
    assert meta["hyperparams"]["key"] == ENV
    for pkg in ("stable_baselines3", "gymnasium", "mujoco", "torch", "python"):
        assert meta["versions"][pkg]
    assert "train-expert" in meta["command"] or meta["command"]  # sys.argv of the process
    assert meta["wall_time_s"] >= 0 and [e["timesteps"] for e in meta["evaluations"]] == [100, 200]
    # no temporary files left behind
    assert not [p for p in trained.rglob(".*") if p.is_file() and p.name != LOCK_FILE]  # the lock's file stays


@pytest.mark.slow
def test_resume_continues_to_total(tiny_yaml, tmp_path):
    out = tmp_path / "run"
    train_expert(ENV, timesteps=200, seed=0, hyperparams_path=tiny_yaml, output_dir=out, **FAST)
    first = _buffer(out)
    assert first.num_timesteps == 200 and first.replay_buffer.size() == 200
    obs_first = first.replay_buffer.observations[:200].copy()

    # A finished expert is trained further only when asked to (--force): it may replace model.zip.
    before = {p.name: p.stat().st_mtime_ns for p in out.rglob("*")}
    with pytest.raises(
        FileExistsError, match="finished expert trained for 200 steps, fewer than the 300 asked; pass --force"
    ):
        train_expert(ENV, timesteps=300, seed=0, hyperparams_path=tiny_yaml, output_dir=out, **FAST)
    assert {p.name: p.stat().st_mtime_ns for p in out.rglob("*")} == before
    train_expert(ENV, timesteps=300, seed=0, hyperparams_path=tiny_yaml, output_dir=out, force=True, **FAST)
    state = _state(out)
    assert state["num_timesteps"] == 300 and state["resumes"] == 1
    second = _buffer(out)
    # continued from the checkpoint: 300 in total (not 200 + 300), and the first 200 transitions kept
    assert second.num_timesteps == 300 and second.replay_buffer.size() == 300
    np.testing.assert_array_equal(second.replay_buffer.observations[:200], obs_first)
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["total_timesteps"] == 300 and meta["resumes"] == 1
    assert [e["timesteps"] for e in meta["evaluations"]] == [100, 200, 300]
    # only the latest checkpoint is kept
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        LOCK_FILE,
        "best.json",
        "model_300_steps.zip",
        "replay_buffer_300_steps.pkl",
        "state.json",
    ]

    # asking for fewer steps than done trains nothing more and rewrites nothing
    before = {p.name: p.stat().st_mtime_ns for p in out.rglob("*")}
    train_expert(ENV, timesteps=250, seed=0, hyperparams_path=tiny_yaml, output_dir=out, **FAST)
    assert _state(out)["num_timesteps"] == 300
    assert {p.name: p.stat().st_mtime_ns for p in out.rglob("*")} == before


class _Crash(BaseCallback):
    def __init__(self, at: int):
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.at:
            raise KeyboardInterrupt("simulated interruption")
        return True


@pytest.mark.slow
def test_interruption_leaves_resumable_checkpoint_and_keeps_best(tiny_yaml, tmp_path):
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train_expert(
            ENV, timesteps=400, seed=1, hyperparams_path=tiny_yaml, output_dir=out, _callback=_Crash(250), **FAST
        )
    assert not (out / "metadata.json").exists()
    assert _state(out)["num_timesteps"] == 200
    SAC.load(out / "model.zip", device="cpu")  # the best-so-far model is complete and loadable
    assert not [p for p in out.rglob(".*") if p.is_file() and p.name != LOCK_FILE]  # no temporary files left
    # a hard kill (SIGKILL) mid-write would leave a temporary file: the next run removes it
    stale = out / "checkpoints" / ".replay_buffer_300_steps.pkl.abc123.tmp.pkl"
    stale.write_bytes(b"half written")

    # pretend an earlier evaluation scored very high: a resumed run must not overwrite model.zip
    best = json.loads((out / "checkpoints" / "best.json").read_text())
    best["mean_reward"] = 1e9
    (out / "checkpoints" / "best.json").write_text(json.dumps(best))
    before = (out / "model.zip").read_bytes()

    train_expert(ENV, timesteps=400, seed=1, hyperparams_path=tiny_yaml, output_dir=out, **FAST)
    assert _state(out)["num_timesteps"] == 400 and _state(out)["resumes"] == 1
    assert (out / "model.zip").read_bytes() == before
    assert not stale.exists()
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["total_timesteps"] == 400 and meta["best_periodic_eval"]["mean_reward"] == 1e9


def test_train_expert_rejects_unsupported_keys_and_other_runs(tmp_path, tiny_yaml):
    p = tmp_path / "norm.yml"
    p.write_text("Pendulum-v1:\n  normalize: true\n  n_timesteps: 100\n")
    with pytest.raises(ValueError, match="normalize"):
        train_expert(ENV, hyperparams_path=p, output_dir=tmp_path / "x", **FAST)
    out = tmp_path / "other"
    (out / "checkpoints").mkdir(parents=True)
    (out / "checkpoints" / "state.json").write_text(json.dumps({"env_id": "Hopper-v5", "algo": "sac"}))
    with pytest.raises(ValueError, match="Hopper-v5"):
        train_expert(ENV, timesteps=100, hyperparams_path=tiny_yaml, output_dir=out, **FAST)


def test_second_process_on_same_folder_is_refused(tmp_path, tiny_yaml):
    from sb3_cmzdril.io import lock_output, unlock_output

    ckpt = tmp_path / "run" / "checkpoints"
    ckpt.mkdir(parents=True)
    held = lock_output(ckpt)  # as if another train-expert were running there
    try:
        with pytest.raises(ValueError, match="already running"):
            train_expert(ENV, timesteps=100, hyperparams_path=tiny_yaml, output_dir=tmp_path / "run", **FAST)
    finally:
        unlock_output(ckpt, held)


# -- collect-demos -------------------------------------------------------------------------------
def test_collect_demos_round_trip_and_seeds(trained, tmp_path, capsys):
    path = tmp_path / "demos.npz"
    rc = main(
        ["collect-demos", "--expert", str(trained), "--env", ENV, "--episodes", "2", "--seed", "7", "-o", str(path)]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "mean" in printed and "200" in printed
    demos = Demonstrations.load(path)
    assert demos.n_episodes == 2 and list(demos.seeds) == [7, 8]
    assert list(demos.episode_lengths) == [200, 200] and demos.rewards is not None
    assert demos.observations.shape == (400, 3) and demos.actions.shape == (400, 1)

    # replaying a recorded seed with the same expert reproduces the episode exactly
    expert = load_expert_model(trained / "model.zip")
    env = gym.make(ENV)
    for i in range(2):
        ep = run_episode(expert, env, int(demos.seeds[i]))
        rec = demos.episode(i)
        np.testing.assert_array_equal(ep["observations"].astype(np.float32), rec["observations"])
        np.testing.assert_array_equal(ep["actions"].astype(np.float32), rec["actions"])
        np.testing.assert_allclose(ep["rewards"], rec["rewards"], rtol=1e-6)


def test_collect_demos_zip_without_metadata(trained, tmp_path):
    """A bare zip elsewhere: the algorithm is inferred from the zip itself."""
    zip_path = tmp_path / "bare.zip"
    shutil.copy(trained / "model.zip", zip_path)
    demos = collect_demos(zip_path, ENV, n_episodes=1, seed=0, verbose=False)
    assert demos.n_episodes == 1 and list(demos.seeds) == [0]


@pytest.mark.slow
def test_demos_beside_the_expert_keep_their_record_when_it_trains_further(trained, tmp_path, tiny_yaml):
    out = tmp_path / "expert"
    shutil.copytree(trained, out)
    # The expert's own folder: the pool's record names the step count of the expert that made it.
    collect_demos(out, ENV, n_episodes=1, output=out / "demos.npz", verbose=False)
    assert pool_provenance(out / "demos.npz")["expert_total_timesteps"] == 200
    train_expert(ENV, timesteps=300, seed=3, hyperparams_path=tiny_yaml, output_dir=out, force=True, **FAST)
    assert json.loads((out / "metadata.json").read_text())["total_timesteps"] == 300
    # still there, and still saying the pool came from the 200-step expert
    record = pool_provenance(out / "demos.npz")
    assert record["file"] == "demos.npz" and record["expert_total_timesteps"] == 200
    # A pool recorded in the earlier layout (its record in the expert's metadata.json) keeps it too.
    (out / "demos.json").unlink()
    meta = json.loads((out / "metadata.json").read_text())
    (out / "metadata.json").write_text(json.dumps({**meta, "demos": record}))
    train_expert(ENV, timesteps=400, seed=3, hyperparams_path=tiny_yaml, output_dir=out, force=True, **FAST)
    assert pool_provenance(out / "demos.npz")["expert_total_timesteps"] == 200


class _PendulumPD:
    """Swing-free PD controller around the upright position (a scripted expert for the tests)."""

    def __init__(self, env):
        self.high = float(env.action_space.high[0])

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs, dtype=np.float64)
        theta = np.arctan2(obs[..., 1], obs[..., 0])
        torque = np.clip(-10.0 * theta - 2.0 * obs[..., 2], -self.high, self.high)
        return torque[..., None].astype(np.float32), None


def test_scripted_expert_via_cli(tmp_path):
    register_scripted_expert("test-pendulum-pd", _PendulumPD)
    assert "test-pendulum-pd" in SCRIPTED_EXPERTS
    path = tmp_path / "pd.npz"
    assert (
        main(
            [
                "collect-demos",
                "--expert",
                "test-pendulum-pd",
                "--env",
                ENV,
                "--episodes",
                "2",
                "--seed",
                "0",
                "-o",
                str(path),
            ]
        )
        == 0
    )
    demos = Demonstrations.load(path)
    assert demos.n_episodes == 2 and list(demos.seeds) == [0, 1]
    again = collect_demos("test-pendulum-pd", ENV, n_episodes=2, seed=0, verbose=False)
    np.testing.assert_array_equal(again.observations, demos.observations)


def test_library_logs_its_notes_and_the_cli_prints_them(tmp_path, capsys, caplog):
    # Called as a library: nothing on stdout, the notes go to the package's loggers.
    register_scripted_expert("test-pendulum-pd", _PendulumPD)
    caplog.set_level(logging.INFO, logger="sb3_cmzdril")
    path = tmp_path / "lib" / "pd.npz"
    collect_demos("test-pendulum-pd", ENV, n_episodes=2, seed=0, output=path)
    assert capsys.readouterr().out == ""
    messages = [r.getMessage() for r in caplog.records if r.name == "sb3_cmzdril.experts.collect"]
    assert messages[0].startswith("scripted:test-pendulum-pd on Pendulum-v1: 2 episodes, 400 steps\n")
    assert messages[0].splitlines()[-1].startswith("    mean")  # the plain table, for any log handler
    assert messages[1] == f"saved {path} (provenance in {path.with_suffix('.json')})"

    # Through the CLI: the same notes on stdout, the table drawn by rich, no prefixes.
    library_logger = logging.getLogger("sb3_cmzdril")
    handlers, level = list(library_logger.handlers), library_logger.level
    path = tmp_path / "cli" / "pd.npz"
    assert (
        main(["collect-demos", "--expert", "test-pendulum-pd", "--env", ENV, "--episodes", "2", "-o", str(path)]) == 0
    )
    printed = capsys.readouterr().out
    assert "┃ episode ┃" in printed and "+/-" in printed
    assert printed.endswith(f"saved {path} (provenance in {path.with_suffix('.json')})\n")
    assert (library_logger.handlers, library_logger.level) == (handlers, level)  # main restored them


def test_cli_says_a_finished_expert_needs_nothing(trained, tiny_yaml, capsys):
    capsys.readouterr()
    assert (
        main(
            [
                "train-expert",
                "--env",
                ENV,
                "--timesteps",
                "200",
                "--hyperparams",
                str(tiny_yaml),
                "-o",
                str(trained),
                "--no-progress",
            ]
        )
        == 0
    )
    assert capsys.readouterr().out.splitlines() == [
        f"{trained} holds a finished sac expert on {ENV} (200 >= 200 steps, metadata.json); nothing to do",
        str(trained / "model.zip"),
    ]


def test_clear_errors_for_bad_experts(tmp_path, capsys):
    missing = tmp_path / "missing" / "model.zip"
    with pytest.raises(FileNotFoundError, match=str(missing)):
        collect_demos(missing, ENV, n_episodes=1, verbose=False)
    empty_dir = tmp_path / "empty"
    empty_dir.mkdir()
    with pytest.raises(FileNotFoundError, match="has no model.zip"):
        collect_demos(empty_dir, ENV, n_episodes=1, verbose=False)
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"this is not a zip file")
    with pytest.raises(ValueError, match=str(corrupt)):
        collect_demos(corrupt, ENV, n_episodes=1, verbose=False)
    register_scripted_expert("test-pendulum-pd", _PendulumPD)
    with pytest.raises(ValueError, match=r"no-such-expert.*test-pendulum-pd"):
        collect_demos("no-such-expert", ENV, n_episodes=1, verbose=False)
    # the CLI reports them as errors (exit status 2) naming the path
    assert main(["collect-demos", "--expert", str(corrupt), "--env", ENV, "-o", str(tmp_path / "d.npz")]) == 2
    assert str(corrupt) in capsys.readouterr().err
    assert not (tmp_path / "d.npz").exists()


def test_corrupt_checkpoint_is_reported(trained, tmp_path, tiny_yaml):
    out = tmp_path / "run"
    shutil.copytree(trained, out)
    ckpt = out / "checkpoints" / _state(out)["model_file"]
    ckpt.write_bytes(b"garbage")
    with pytest.raises(ValueError, match=str(ckpt)):
        train_expert(ENV, timesteps=300, seed=3, hyperparams_path=tiny_yaml, output_dir=out, force=True, **FAST)


def test_collect_demos_records_provenance_beside_the_file(tmp_path):
    out = tmp_path / "pool" / "demos.npz"
    demos = collect_demos(
        "waypoint-reactive", "sb3_cmzdril:WaypointNav-v0", n_episodes=2, seed=5, output=out, verbose=False
    )
    # The folder lock (filelock keeps its file after release) is the only other entry.
    assert sorted(p.name for p in out.parent.iterdir()) == [".lock", "demos.json", "demos.npz"]
    rec = json.loads(out.with_suffix(".json").read_text())["demos"]
    assert rec["expert"] == "scripted:waypoint-reactive" and rec == pool_provenance(out)
    assert rec["episodes"] == 2 and rec["seeds"] == [5, 6] and rec["steps"] == len(demos)
    assert rec["mean_return"] == pytest.approx(float(np.mean(demos.episode_returns)))


#: A collect-demos killed (SIGKILL) while saving its pool: the atomic write's temporary stays.
_KILLED_WHILE_SAVING = """
import os, signal, sys
from sb3_cmzdril.io import atomic_path
with atomic_path(sys.argv[1], suffix=".npz") as tmp:
    tmp.write_bytes(b"half a pool")
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_collect_demos_removes_the_temporary_a_killed_run_left(tmp_path, capsys):
    """Bug 2: `kill -9` of collect-demos left its `.tmp.npz` for good; the next collect-demos into the
    folder removes it, with a line saying so."""
    import subprocess
    import sys

    out = tmp_path / "cd" / "pool.npz"
    out.parent.mkdir()
    killed = subprocess.run([sys.executable, "-c", _KILLED_WHILE_SAVING, str(out)])
    assert killed.returncode == -9
    (stale,) = [p for p in out.parent.iterdir() if p.name.startswith(".pool.npz.")]
    capsys.readouterr()
    assert main(["collect-demos", "--expert", "waypoint-reactive", "--env", "sb3_cmzdril:WaypointNav-v0",
                 "--env-kwargs", "dict(max_steps=7)", "-o", str(out)]) == 0
    assert sorted(p.name for p in out.parent.iterdir()) == [".lock", "pool.json", "pool.npz"]
    assert f"removed 1 temporary file that a write cut short left behind: {stale}" in capsys.readouterr().out


def test_collect_demos_makes_the_env_with_env_kwargs_and_records_them(tmp_path):
    out = tmp_path / "demos.npz"
    rc = main(["collect-demos", "--expert", "waypoint-reactive", "--env", "sb3_cmzdril:WaypointNav-v0",
               "--episodes", "2", "--env-kwargs", "dict(max_steps=7)", "-o", str(out)])
    assert rc == 0
    # The reactive expert needs far more than 7 steps to reach its goals: the time limit ends both episodes.
    assert list(Demonstrations.load(out).episode_lengths) == [7, 7]
    assert pool_provenance(out)["env_kwargs"] == {"max_steps": 7}


def test_shipped_files_come_from_the_checkout_or_the_installed_copy(tmp_path, monkeypatch):
    from sb3_cmzdril import shipped

    repo = Path(__file__).resolve().parent.parent
    assert shipped.shipped_demos("HalfCheetah-v5") == repo / "experts" / "HalfCheetah-v5" / "demos.npz"
    assert shipped.shipped_demos("sb3_cmzdril:WaypointNav-v0").parent.name == "WaypointNav-v0"
    assert {"HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "WaypointNav-v0"} <= set(shipped.shipped_envs())
    with pytest.raises(FileNotFoundError, match=r"no shipped demo pool for 'Ant-v5'; shipped pools: .*HalfCheetah-v5"):
        shipped.shipped_demos("Ant-v5")
    with pytest.raises(FileNotFoundError, match=r"no shipped hyperparameter file nope.yml \(shipped: .*cmzdril"):
        shipped.shipped_hyperparams("nope")
    # A wheel install: the package's own copy wins over any experts/ folder beside it.
    bundled = tmp_path / "_shipped"
    (bundled / "experts" / "HalfCheetah-v5").mkdir(parents=True)
    (bundled / "hyperparams").mkdir()
    (bundled / "experts" / "HalfCheetah-v5" / "demos.npz").write_bytes(b"x")
    monkeypatch.setattr(shipped, "BUNDLED_DIR", bundled)
    assert shipped.shipped_demos("HalfCheetah-v5") == bundled / "experts" / "HalfCheetah-v5" / "demos.npz"
    # The working directory's own experts/ folder wins over both; a folder the user names never falls back.
    monkeypatch.chdir(tmp_path)
    assert shipped.local_or_shipped_demos("HalfCheetah-v5") == bundled / "experts" / "HalfCheetah-v5" / "demos.npz"
    (tmp_path / "experts" / "HalfCheetah-v5").mkdir(parents=True)
    (tmp_path / "experts" / "HalfCheetah-v5" / "demos.npz").write_bytes(b"y")
    assert shipped.local_or_shipped_demos("HalfCheetah-v5") == Path("experts/HalfCheetah-v5/demos.npz")
    assert shipped.local_or_shipped_demos("HalfCheetah-v5", "mine") == Path("mine/HalfCheetah-v5/demos.npz")


def test_version_flag(capsys):
    from sb3_cmzdril import __version__

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"sb3-cmzdril {__version__}\n"


def _tiny_cmzdril(tmp_path: Path, normalize: bool):
    """A CMZDRIL model trained for one rollout on Pendulum (optionally on VecNormalize'd observations)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from helpers import TINY, pendulum_expert, record
    from sb3_cmzdril import CMZDRIL

    demos = record(ENV, pendulum_expert, n_episodes=2, max_steps=50)
    venv = make_vec_env(ENV, n_envs=1, seed=0)
    if normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    model = CMZDRIL("MlpPolicy", venv, demonstrations=demos, **TINY)
    model.learn(64)
    model.save(tmp_path / "model.zip")
    if normalize:
        venv.save(str(tmp_path / "vecnormalize.pkl"))
    return model


def test_a_cmzdril_model_is_an_expert(tmp_path, capsys):
    # A training run's model.zip is PPO plus an ensemble: PPO.load refuses the extra state, so it
    # must be recognised and loaded as what it is.
    run = tmp_path / "run"
    run.mkdir()
    model = _tiny_cmzdril(run, normalize=False)
    out = tmp_path / "pool.npz"
    assert main(["collect-demos", "--expert", str(run / "model.zip"), "--env", ENV, "--episodes", "2",
                 "-o", str(out)]) == 0
    demos = Demonstrations.load(out)
    assert demos.n_episodes == 2
    # The recorded actions are the model's own deterministic ones.
    first = demos.observations[: demos.episode_lengths[0]]
    expected, _ = model.predict(first, deterministic=True)
    np.testing.assert_allclose(demos.actions[: demos.episode_lengths[0]],
                               np.clip(expected, -2, 2).reshape(demos.actions[: demos.episode_lengths[0]].shape),
                               atol=1e-5)
    # The run folder itself names it too.
    assert main(["collect-demos", "--expert", str(run), "--env", ENV, "-o", str(tmp_path / "again.npz")]) == 0


def test_a_cmzdril_model_on_normalised_observations_needs_its_statistics(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    model = _tiny_cmzdril(run, normalize=True)
    env = gym.make(ENV)
    expert = load_expert_model(run / "model.zip", env=env)
    obs, _ = env.reset(seed=0)
    stats = model.get_vec_normalize_env()
    assert stats is not None
    action, _ = expert.predict(obs, deterministic=True)
    expected, _ = model.predict(stats.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(action, expected, atol=1e-6)
    (run / "vecnormalize.pkl").unlink()
    assert main(["collect-demos", "--expert", str(run / "model.zip"), "--env", ENV,
                 "-o", str(tmp_path / "pool.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trained on VecNormalize'd observations" in err and "vecnormalize.pkl" in err
    assert not (tmp_path / "pool.npz").exists()


def test_several_pools_in_one_folder_each_keep_their_provenance(tmp_path, capsys):
    register_scripted_expert("test-pendulum-pd", _PendulumPD)
    base = ["collect-demos", "--expert", "test-pendulum-pd", "--env", ENV]
    folder = tmp_path / "pools"
    assert main(base + ["--episodes", "1", "--seed", "0", "-o", str(folder / "a.npz")]) == 0
    assert main(base + ["--episodes", "2", "--seed", "100", "-o", str(folder / "b.npz")]) == 0
    assert sorted(p.name for p in folder.iterdir()) == [".lock", "a.json", "a.npz", "b.json", "b.npz"]
    assert pool_provenance(folder / "a.npz")["seeds"] == [0, 0]
    assert pool_provenance(folder / "b.npz")["seeds"] == [100, 101]
    assert pool_provenance(folder / "b.npz")["episodes"] == Demonstrations.load(folder / "b.npz").n_episodes == 2
    capsys.readouterr()

    # A record file with no pool beside it is someone's: not replaced without --force.
    (folder / "c.json").write_text("{}")
    assert main(base + ["-o", str(folder / "c.npz")]) == 2
    assert "c.json already exists" in capsys.readouterr().err
    assert not (folder / "c.npz").exists() and (folder / "c.json").read_text() == "{}"
    # metadata.npz would keep its record in the folder's own metadata.json: refused even with --force.
    assert main(base + ["-o", str(folder / "metadata.npz"), "--force"]) == 2
    assert "choose another name" in capsys.readouterr().err
    assert not (folder / "metadata.npz").exists()


def test_pools_recorded_in_the_earlier_layout_are_read_and_replaced_cleanly(tmp_path):
    register_scripted_expert("test-pendulum-pd", _PendulumPD)
    folder = tmp_path / "Pendulum-v1"
    collect_demos("test-pendulum-pd", ENV, n_episodes=1, output=folder / "demos.npz", verbose=False)
    record = json.loads((folder / "demos.json").read_text())["demos"]
    # The earlier layout: the record as the demos section of metadata.json beside the pool.
    (folder / "demos.json").unlink()
    (folder / "metadata.json").write_text(json.dumps({"env_id": ENV, "demos": record}))
    assert pool_provenance(folder / "demos.npz") == record
    # ... which describes demos.npz only: another pool beside it has no record, and may be recorded.
    assert pool_provenance(folder / "other.npz") == {}
    collect_demos("test-pendulum-pd", ENV, n_episodes=2, seed=7, output=folder / "other.npz", verbose=False)
    assert pool_provenance(folder / "other.npz")["seeds"] == [7, 8]
    assert pool_provenance(folder / "demos.npz") == record
    # Replacing demos.npz moves its record next to it and leaves no stale one in metadata.json.
    collect_demos("test-pendulum-pd", ENV, n_episodes=2, seed=3, output=folder / "demos.npz", verbose=False,
                  force=True)
    assert pool_provenance(folder / "demos.npz")["seeds"] == [3, 4]
    assert json.loads((folder / "metadata.json").read_text()) == {"env_id": ENV}


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Hopper-v5", "Swimmer-v5", "Walker2d-v5", "WaypointNav-v0"])
def test_the_shipped_pools_provenance_is_found(env_id):
    from sb3_cmzdril.shipped import shipped_demos

    pool = shipped_demos(env_id)
    record = pool_provenance(pool)
    assert record["file"] == "demos.npz" and record["episodes"] == Demonstrations.load(pool).n_episodes
