"""rl-zoo3 plugin: registration, the shipped YAML as the zoo reads it, training through the zoo's train."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import TINY, zoo_hyperparams
from sb3_cmzdril import CMZDRIL
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.hyperparams import FALLBACK_N_DEMOS, default_hyperparams_path, load_hyperparams
from sb3_cmzdril.training.spec import learner_defaults

rl_zoo3 = pytest.importorskip("rl_zoo3", reason="rl-zoo3 is in the 'zoo' and 'test' extras")
from rl_zoo3.exp_manager import ExperimentManager  # noqa: E402  (needs the importorskip above)

from sb3_cmzdril import zoo  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
#: a zoo YAML for a run of a few seconds: no `demonstrations`, so the pool in ./experts is used
TINY_YAML = {"Pendulum-v1": zoo_hyperparams(TINY, n_timesteps=256, ensemble_size=2, n_demos=1)}


@pytest.fixture
def pool_dir(pendulum_demos, tmp_path, monkeypatch):
    """A working directory with experts/Pendulum-v1/demos.npz (the zoo runs relative to it)."""
    pendulum_demos.save(tmp_path / "experts" / "Pendulum-v1" / "demos.npz")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_register_adds_cmzdril_to_every_algos_table():
    cls = zoo.register()
    import rl_zoo3.exp_manager
    import rl_zoo3.train

    for module in (rl_zoo3, rl_zoo3.train, rl_zoo3.exp_manager):
        assert module.ALGOS["cmzdril"] is cls is zoo.ZooCMZDRIL
    assert issubclass(cls, CMZDRIL) and zoo.register() is cls  # idempotent


def zoo_kwargs(conf: Path, env_id: str) -> tuple:
    """What the zoo hands the constructor for ``env_id``: its own reading and pre-processing of the YAML."""
    import argparse

    manager = ExperimentManager(argparse.Namespace(), "cmzdril", env_id, log_folder="unused", config=str(conf))
    hyperparams, _ = manager.read_hyperparameters()
    kwargs, *_ = manager._preprocess_hyperparams(hyperparams)
    return manager, kwargs


@pytest.mark.parametrize("env_id", ["WaypointNav-v0", "HalfCheetah-v5", "Hopper-v5"])
def test_the_shipped_yaml_builds_the_model_in_the_zoo(env_id):
    if env_id != "WaypointNav-v0":
        pytest.importorskip("mujoco", reason="MuJoCo envs are in the 'mujoco' extra")
    zoo.register()
    manager, kwargs = zoo_kwargs(default_hyperparams_path("cmzdril"), env_id)
    assert "demonstrations" not in kwargs  # as the YAML ships
    env = manager.create_envs(1, no_log=True)
    model = zoo.ZooCMZDRIL(env=env, seed=0, device="cpu", **kwargs)
    pool = Demonstrations.load(REPO / "experts" / env_id / "demos.npz")
    n_demos = kwargs.get("n_demos", FALLBACK_N_DEMOS)  # what `sb3-cmzdril train` takes when the entry is silent
    assert model.demonstrations.n_episodes == n_demos < pool.n_episodes
    assert np.array_equal(model.demonstrations.observations, pool.select(range(n_demos)).observations)
    # the entry's per_method block gives CMZ-DRIL its own settings (the grid's "cmz" method), and no other's
    method = load_hyperparams(default_hyperparams_path("cmzdril"), env_id, "cmz").algo_kwargs
    expected = method.get("bc_epochs_per_update", learner_defaults("cmz")["bc_epochs_per_update"])
    assert model.bc_epochs_per_update == expected
    env.close()


def test_a_per_method_block_gives_the_zoo_cmzdril_its_cmz_settings_and_refuses_a_zoo_key():
    assert zoo.method_settings(None) == {}
    assert zoo.method_settings({"env": {"gamma": 0.9}}) == {}
    settings = zoo.method_settings({"cmz": {"bc_epochs_per_update": 0, "learning_rate": "lin_3e-4"}})
    assert settings["bc_epochs_per_update"] == 0 and settings["learning_rate"](0.5) == pytest.approx(1.5e-4)
    with pytest.raises(UserError, match=r"per_method.cmz sets \['n_envs'\]"):
        zoo.method_settings({"cmz": {"n_envs": 4}})


@pytest.mark.slow
def test_zoo_trains_cmzdril_via_python_m(pool_dir, pendulum_demos):
    conf = pool_dir / "tiny.yml"
    conf.write_text(yaml.safe_dump(TINY_YAML))
    result = subprocess.run(
        [sys.executable, "-m", "sb3_cmzdril.zoo", "--env", "Pendulum-v1", "-conf", str(conf), "--seed", "3",
         "-f", "logs", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu", "--verbose", "0"],
        cwd=pool_dir, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stdout[-1500:] + result.stderr[-3000:]
    run = pool_dir / "logs" / "cmzdril" / "Pendulum-v1_1"
    model = CMZDRIL.load(run / "Pendulum-v1.zip", device="cpu")
    assert model.num_timesteps == 256 and model.n_steps == 64 and model.ensemble_size == 2
    # n_demos: 1 from the YAML selected the pool's first episode
    assert model.demonstrations.n_episodes == 1
    assert np.array_equal(model.demonstrations.actions, pendulum_demos.episode(0)["actions"])
    saved, _ = rl_zoo3.get_saved_hyperparams(str(run / "Pendulum-v1"))  # the zoo's record of the run
    assert saved["n_demos"] == 1 and saved["n_steps"] == 64


def test_explicit_demonstrations_and_n_demos(pendulum_demos, tmp_path):
    path = tmp_path / "d.npz"
    pendulum_demos.save(path)
    model = zoo.ZooCMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=str(path), n_demos=2, **TINY)
    assert model.demonstrations.n_episodes == 2 and model.n_demos == 2
    model.save(tmp_path / "m.zip")
    # the zoo's `-i m.zip` passes the YAML's keys to load(): n_demos applies to given demonstrations
    loaded = zoo.ZooCMZDRIL.load(tmp_path / "m.zip", demonstrations=str(path), n_demos=1, device="cpu")
    assert isinstance(loaded, zoo.ZooCMZDRIL) and loaded.demonstrations.n_episodes == 1
    assert zoo.ZooCMZDRIL.load(tmp_path / "m.zip", device="cpu").demonstrations.n_episodes == 2  # saved ones


def test_missing_pool_and_bad_n_demos_are_clear_errors(pendulum_demos, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"no demo pool at experts/Pendulum-v1/demos.npz or .*collect-demos"):
        zoo.ZooCMZDRIL("MlpPolicy", "Pendulum-v1", **TINY)
    for bad in (0, 3, "1", True):
        with pytest.raises(ValueError, match=r"n_demos must be an integer in \[1, 2\]"):
            zoo.ZooCMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, n_demos=bad, **TINY)


def test_zoo_argv_defaults_algo_and_conf_only_when_absent():
    conf = str(default_hyperparams_path("cmzdril"))
    assert zoo.zoo_argv(["--env", "X-v0"]) == ["--algo", "cmzdril", "--env", "X-v0", "--conf-file", conf]
    assert zoo.zoo_argv(["--algo=cmzdril", "-conf", "c.yml"]) == ["--algo=cmzdril", "-conf", "c.yml"]
    assert zoo.zoo_argv(["--conf", "c.yml"]) == ["--algo", "cmzdril", "--conf", "c.yml"]  # argparse prefix
    assert zoo.zoo_argv(["--algo", "ppo"]) == ["--algo", "ppo"]  # another algo: the zoo's own default file


def test_env_id_of_every_kind_of_env():
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env

    assert zoo.env_id_of("sb3_cmzdril:WaypointNav-v0") == "WaypointNav-v0"
    assert zoo.env_id_of(gym.make("Pendulum-v1")) == "Pendulum-v1"
    assert zoo.env_id_of(make_vec_env("Pendulum-v1", n_envs=2)) == "Pendulum-v1"
