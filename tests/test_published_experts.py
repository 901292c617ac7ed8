"""Published experts as users bring them: old SB3 zips pickling gym, sb3-contrib's TQC, and the RL
Zoo's folder layout with VecNormalize statistics. Every model is built here (tiny, untrained); no network."""
import base64
import json
import sys
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from helpers import TINY_SAC
from sb3_cmzdril.cli import main
from sb3_cmzdril.experts import collect_demos, load_expert_model
from sb3_cmzdril.experts.adapters import PaddedObservationExpert
from sb3_cmzdril.experts.loading import NormalizedObservationExpert, resolve_expert
from sb3_cmzdril.extras import MissingExtraError

ENV = "Pendulum-v1"
TINY = dict(TINY_SAC, device="cpu", seed=0)
#: A pickle of ``gym.spaces.box.Box()``: what an SB3 1.x zip holds, naming a module not installed here.
GYM_PICKLE = base64.b64encode(b"\x80\x02cgym.spaces.box\nBox\n)\x81}b.").decode()
OBSERVATIONS = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -3.0], [-0.6, 0.8, 7.0]], dtype=np.float32)


def _actions(model, observations=OBSERVATIONS) -> np.ndarray:
    return np.stack([model.predict(o, deterministic=True)[0] for o in observations])


def _as_old_sb3_zip(source: Path, target: Path, shape=(3,)) -> None:
    """Copy an SB3 zip, its spaces and schedule replaced by pickles naming the ``gym`` package (as an
    SB3 1.x zip has them), with the plain-JSON shape SB3 1.x wrote beside them."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            payload = zin.read(item.filename)
            if item.filename == "data":
                data = json.loads(payload)
                for key in ("observation_space", "action_space"):
                    data[key] = {":type:": "<class 'gym.spaces.box.Box'>", ":serialized:": GYM_PICKLE,
                                 "shape": list(shape if key == "observation_space" else (1,))}
                data["lr_schedule"] = {":type:": "<class 'function'>", ":serialized:": GYM_PICKLE}
                payload = json.dumps(data).encode()
            zout.writestr(item, payload)


@pytest.fixture(scope="module")
def sac(tmp_path_factory):
    path = tmp_path_factory.mktemp("sac") / "sac.zip"
    model = SAC("MlpPolicy", ENV, **TINY)
    model.save(path)
    return model, path


def test_old_zip_pickling_gym_loads_with_the_envs_spaces(sac, tmp_path):
    model, path = sac
    old = tmp_path / "old.zip"
    _as_old_sb3_zip(path, old)
    with pytest.raises(ModuleNotFoundError, match="gym"):  # what the user saw before
        SAC.load(old, device="cpu")
    env = gym.make(ENV)
    loaded = load_expert_model(old, env=env)
    assert isinstance(loaded, SAC) and loaded.observation_space == env.observation_space
    np.testing.assert_allclose(_actions(loaded), _actions(model), rtol=1e-6)
    with pytest.raises(ValueError, match=r"old.zip pickles its observation_space .*\(env=\.\.\.\)"):
        load_expert_model(old)
    _as_old_sb3_zip(path, old, shape=(5,))
    with pytest.raises(ValueError, match=r"observation_space of shape \(5,\), the env has \(3,\)"):
        load_expert_model(old, env=env)


def test_tqc_is_recognised_from_the_zip_not_its_name(tmp_path, monkeypatch):
    from sb3_contrib import TQC

    model = TQC("MlpPolicy", ENV, **TINY)
    path = tmp_path / "expert.zip"
    model.save(path)
    loaded = load_expert_model(path)
    assert isinstance(loaded, TQC)
    np.testing.assert_allclose(_actions(loaded), _actions(model), rtol=1e-6)
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # as if sb3-contrib were not installed
    with pytest.raises(MissingExtraError, match=r"expert.zip \(an sb3-contrib model\) needs the 'contrib' extra"):
        load_expert_model(path)


def _zoo_folder(root: Path, model, env_name="Pendulum-v0", config="- - - normalize\n    - true\n",
                mean=(0.5, -0.5, 1.0), var=(4.0, 0.25, 9.0)) -> Path:
    """The zoo's layout: ``<algo>/<Env>_1/<Env>.zip`` and ``<Env>/{config,args}.yml, vecnormalize.pkl``
    (its statistics ``mean`` and ``var``)."""
    folder = root / "sac" / f"{env_name}_1"
    (folder / env_name).mkdir(parents=True)
    model.save(folder / f"{env_name}.zip")
    header = "!!python/object/apply:collections.OrderedDict\n"
    (folder / env_name / "config.yml").write_text(header + config + "  - - policy\n    - MlpPolicy\n")
    (folder / env_name / "args.yml").write_text(header + f"- - - algo\n    - sac\n  - - env\n    - {env_name}\n")
    stats = VecNormalize(DummyVecEnv([lambda: gym.make(ENV)]), norm_reward=False)
    stats.obs_rms = RunningMeanStd(shape=(len(mean),))
    stats.obs_rms.mean, stats.obs_rms.var = np.array(mean, dtype=np.float64), np.array(var, dtype=np.float64)
    stats.save(folder / env_name / "vecnormalize.pkl")
    return folder


def test_zoo_folder_expert_sees_normalised_observations_and_the_pool_records_raw_ones(sac, tmp_path):
    model, _ = sac
    folder = _zoo_folder(tmp_path, model)
    with pytest.warns(UserWarning, match="trained on Pendulum-v0 and is used on Pendulum-v1"):
        demos = collect_demos(folder, ENV, n_episodes=1, seed=3, verbose=False)
    env = gym.make(ENV)
    obs, _ = env.reset(seed=3)
    raw = [obs]
    for action in demos.actions[:-1]:
        raw.append(env.step(action)[0])
    np.testing.assert_allclose(demos.observations, np.array(raw), rtol=1e-6)  # the env's raw observations
    normalised = np.clip((demos.observations - [0.5, -0.5, 1.0]) / np.sqrt(np.array([4.0, 0.25, 9.0]) + 1e-8), -10, 10)
    np.testing.assert_allclose(demos.actions, _actions(model, normalised), rtol=1e-5)
    assert not np.allclose(demos.actions, _actions(model, demos.observations))  # normalising mattered


def test_zoo_vecnormalize_pickling_gym_spaces_loads(sac, tmp_path, monkeypatch):
    model, _ = sac
    folder = _zoo_folder(tmp_path, model, env_name=ENV)
    pkl = folder / ENV / "vecnormalize.pkl"
    # The pickle's spaces renamed into the gym package (same length, so the pickle's framing holds).
    original = pkl.read_bytes()
    assert b"gymnasium.spaces.box" in original
    pkl.write_bytes(original.replace(b"gymnasium.spaces.box", b"gym.spaces.old_boxes"))
    with pytest.raises(ModuleNotFoundError):
        VecNormalize.load(str(pkl), DummyVecEnv([lambda: gym.make(ENV)]))
    expert = load_expert_model(folder / f"{ENV}.zip", env=gym.make(ENV))
    assert isinstance(expert, NormalizedObservationExpert)
    np.testing.assert_allclose(expert.stats.obs_rms.var, [4.0, 0.25, 9.0])


def test_zoo_settings_we_do_not_reproduce_and_non_models_are_one_line_errors(sac, tmp_path, capsys):
    model, _ = sac
    wrapper = "sb3_contrib.common.wrappers.TimeFeatureWrapper"
    wrapped = _zoo_folder(tmp_path / "w", model, config=f"- - - env_wrapper\n    - {wrapper}\n")
    with pytest.raises(ValueError, match=f"config.yml sets env_wrapper: '{wrapper}', which changes the observations"):
        load_expert_model(wrapped)
    (wrapped / "Pendulum-v0" / "config.yml").write_text("normalize: true\n")
    (wrapped / "Pendulum-v0" / "vecnormalize.pkl").write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"vecnormalize.pkl is not a readable VecNormalize pickle"):
        load_expert_model(wrapped)
    no_zip = tmp_path / "plain.zip"
    with zipfile.ZipFile(no_zip, "w") as zf:
        zf.writestr("readme.txt", "hello")
    not_zip = tmp_path / "model.zip"
    not_zip.write_bytes(b"not a zip")
    for path, problem in [(no_zip, "is a zip but not an SB3 model"), (not_zip, "is not a zip file")]:
        with pytest.raises(ValueError, match=problem):
            load_expert_model(path)
        out = tmp_path / "d.npz"
        assert main(["collect-demos", "--expert", str(path), "--env", ENV, "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err and problem in err
        assert not out.exists()


class _AntV3Spaces(gym.Env):
    """Only the spaces of gym's Ant-v3 (111 observations, 8 torques): what the zoo's Ant agents were built on."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (111,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (8,), np.float32)


@pytest.fixture(scope="module")
def ant_v3_agent():
    return SAC("MlpPolicy", _AntV3Spaces(), **TINY)


def test_a_zoo_ant_v3_agent_acts_on_ant_v5_with_its_zero_contact_inputs(ant_v3_agent, tmp_path):
    """Ant-v3 agents saw 27 body inputs and 84 contact forces that were zeros in their training; on
    Ant-v5 (105 or 27 observations) they get the 27 and 84 zeros, and the pool records the env's own."""
    mean, var = np.r_[np.linspace(-1, 1, 27), np.zeros(84)], np.r_[np.linspace(0.5, 2, 27), np.full(84, 1e-9)]
    folder = _zoo_folder(tmp_path, ant_v3_agent, env_name="Ant-v3", mean=mean, var=var)
    for kwargs, size in [({}, 105), ({"include_cfrc_ext_in_observation": False}, 27)]:
        env = gym.make("Ant-v5", **kwargs)
        with pytest.warns(UserWarning, match=r"it gets the first 27 of the env's observation followed by 84 zeros.*"
                                             r"its saved statistics show they never moved"):
            expert = load_expert_model(folder, env=env)
        assert isinstance(expert, PaddedObservationExpert)
        observations = np.stack([env.reset(seed=seed)[0] for seed in range(3)])
        assert observations.shape == (3, size)
        inputs = np.c_[observations[:, :27], np.zeros((3, 84))]
        normalised = np.clip((inputs - mean) / np.sqrt(var + 1e-8), -10, 10)
        np.testing.assert_allclose(_actions(expert, observations), _actions(ant_v3_agent, normalised), rtol=1e-5)
        np.testing.assert_allclose(expert.predict(observations, deterministic=True)[0],
                                   _actions(ant_v3_agent, normalised), rtol=1e-5)  # a batch as well
    with pytest.warns(UserWarning):
        demos = collect_demos(folder, "Ant-v5", n_episodes=1, seed=0, verbose=False,
                              env_kwargs={"max_episode_steps": 20})
    assert demos.observations.shape[1] == 105


def test_an_ant_v3_agent_whose_contact_inputs_moved_or_another_layout_is_refused(ant_v3_agent, tmp_path):
    moved = _zoo_folder(tmp_path / "moved", ant_v3_agent, env_name="Ant-v3", mean=np.zeros(111), var=np.full(111, 0.3))
    with pytest.raises(ValueError, match=r"its observations 27-110 were not all zeros in training"):
        load_expert_model(moved, env=gym.make("Ant-v5"))
    ant = _zoo_folder(tmp_path / "ant", ant_v3_agent, env_name="Ant-v3", mean=np.zeros(111), var=np.zeros(111))
    with pytest.raises(ValueError, match=r"has observation_space Box.*\(111,\).*the env has Box.*\(107,\)"):
        load_expert_model(ant, env=gym.make("Ant-v5", exclude_current_positions_from_observation=False))
    plain = tmp_path / "plain" / "ant.zip"  # no zoo files: the env it was trained on is unknown
    plain.parent.mkdir()
    ant_v3_agent.save(plain)
    with pytest.raises(ValueError, match=r"has observation_space Box.*\(111,\).*the env has Box.*\(105,\)"):
        load_expert_model(plain, env=gym.make("Ant-v5"))


def test_shipped_experts_by_env_id():
    env = gym.make("HalfCheetah-v5")
    expert, description = resolve_expert("HalfCheetah-v5", env)
    assert isinstance(expert, SAC) and description == "shipped:HalfCheetah-v5"
    with pytest.raises(FileNotFoundError, match="WaypointNav-v0 is not a model file: it is scripted:waypoint-reactive"):
        resolve_expert("WaypointNav-v0", env)
    with pytest.raises(FileNotFoundError, match=r"Walker2d-v5 is not shipped .* get sac/Walker2d-v3_1/ from "
                       r"https://github.com/DLR-RM/rl-trained-agents \(commit [0-9a-f]{40}\)"):
        resolve_expert("Walker2d-v5", env)


#: The commit a test's Hub cache holds (the cache names snapshot folders by commit).
COMMIT = "0123456789abcdef0123456789abcdef01234567"


def _hub_cache(root: Path, model, repo="test-org/sac-Pendulum-v0") -> Path:
    """A Hugging Face Hub cache holding one zoo agent as the Hub keeps it (``<REPO>.zip`` beside
    ``config.yml``, ``args.yml``, ``vec_normalize.pkl``): ``models--ORG--REPO/`` with ``blobs/``, the
    snapshot's files as links into them, and ``refs/main`` naming the snapshot's commit."""
    zoo = _zoo_folder(root / "zoo", model)
    name = repo.split("/")[1]
    env_name = name.split("-", 1)[1]
    sources = {
        f"{name}.zip": zoo / f"{env_name}.zip",
        "config.yml": zoo / env_name / "config.yml",
        "args.yml": zoo / env_name / "args.yml",
        "vec_normalize.pkl": zoo / env_name / "vecnormalize.pkl",
    }
    storage = root / "hub" / ("models--" + repo.replace("/", "--"))
    snapshot = storage / "snapshots" / COMMIT
    (storage / "blobs").mkdir(parents=True)
    snapshot.mkdir(parents=True)
    for i, (name, source) in enumerate(sources.items()):
        blob = storage / "blobs" / f"{i:040x}"
        blob.write_bytes(source.read_bytes())
        (snapshot / name).symlink_to(Path("..", "..", "blobs", blob.name))
    (storage / "refs").mkdir()
    (storage / "refs" / "main").write_text(COMMIT)
    return root / "hub"


def test_hub_expert_from_the_local_cache_through_the_cli(sac, tmp_path):
    """``--expert hf://ORG/REPO`` as a user runs it offline: the cache's zoo agent, with its
    normalisation statistics, records a pool of raw observations, and the pool names the commit."""
    import subprocess

    model, _ = sac
    cache = _hub_cache(tmp_path, model)
    env = {**__import__("os").environ, "HF_HUB_OFFLINE": "1", "HF_HUB_CACHE": str(cache),
           "HF_HOME": str(tmp_path / "hf_home"), "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    pool = tmp_path / "pool.npz"
    run = subprocess.run(
        [sys.executable, "-m", "sb3_cmzdril", "collect-demos", "--expert", "hf://test-org/sac-Pendulum-v0",
         "--env", ENV, "--episodes", "1", "--seed", "3", "-o", str(pool)],
        capture_output=True, text=True, timeout=180, env=env, cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "trained on Pendulum-v0 and is used on Pendulum-v1" in run.stderr
    from sb3_cmzdril.data.demos import Demonstrations
    from sb3_cmzdril.experts import pool_provenance

    demos = Demonstrations.load(pool)
    normalised = np.clip((demos.observations - [0.5, -0.5, 1.0]) / np.sqrt(np.array([4.0, 0.25, 9.0]) + 1e-8), -10, 10)
    np.testing.assert_allclose(demos.actions, _actions(model, normalised), rtol=1e-5)
    assert pool_provenance(pool)["expert"] == f"hf://test-org/sac-Pendulum-v0@{COMMIT}"


@pytest.fixture
def offline_hub(monkeypatch, tmp_path):
    """huggingface_hub pointed at an empty cache under tmp_path, offline (no request leaves)."""
    constants = pytest.importorskip("huggingface_hub.constants")
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    return tmp_path / "hub"


def test_hub_experts_in_process_and_their_one_line_errors(sac, tmp_path, offline_hub, capsys):
    model, _ = sac
    assert _hub_cache(tmp_path, model) == offline_hub
    env = gym.make(ENV)
    with pytest.warns(UserWarning, match="trained on Pendulum-v0"):
        expert, description = resolve_expert("hf://test-org/sac-Pendulum-v0", env)
    assert isinstance(expert, NormalizedObservationExpert) and description.endswith(f"@{COMMIT}")
    with pytest.warns(UserWarning, match="trained on Pendulum-v0"):
        _, by_revision = resolve_expert(f"hf://test-org/sac-Pendulum-v0@{COMMIT}", env)
    assert by_revision == description

    cases = [
        ("hf://test-org/not-cached", "cannot get it from the Hugging Face Hub or its cache"),
        ("hf://test-org", "is not a Hugging Face Hub model: write hf://ORG/REPO"),
        ("hf://a/b/c", "is not a Hugging Face Hub model"),
    ]
    for spec, message in cases:
        assert main(["collect-demos", "--expert", spec, "--env", ENV, "-o", str(tmp_path / "x.npz")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and spec in err, err
    assert not (tmp_path / "x.npz").exists()


def test_offline_a_hub_expert_comes_from_the_cache_alone(sac, tmp_path, offline_hub, monkeypatch):
    # Some huggingface_hub releases list the repository online unless told to stay local, and then
    # fail offline on a cached commit: offline, nothing may ask the Hub.
    hub = pytest.importorskip("huggingface_hub")
    _hub_cache(tmp_path, sac[0])
    calls = []
    download = hub.snapshot_download
    monkeypatch.setattr(hub, "snapshot_download", lambda *a, **kw: calls.append(kw) or download(*a, **kw))
    with pytest.warns(UserWarning, match="trained on Pendulum-v0"):
        resolve_expert(f"hf://test-org/sac-Pendulum-v0@{COMMIT}", gym.make(ENV))
    assert [kw.get("local_files_only") for kw in calls] == [True]


def test_hub_expert_names_the_hub_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "huggingface_hub", None)  # as if the hub extra were not installed
    with pytest.raises(MissingExtraError, match=r"needs the 'hub' extra: pip install 'sb3-cmzdril\[hub\]'"):
        resolve_expert("hf://sb3/sac-Walker2d-v3", gym.make(ENV))
