"""Files that run code when loaded: model zips (SB3 pickles parts of their ``data``), pickles
(``vecnormalize.pkl``) and Hugging Face Hub downloads. Inspecting a zip before SB3's own load must
run none of its pickles, and loading such files says once per process that they can run code."""
from __future__ import annotations

import base64
import json
import logging
import os
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import pytest
from stable_baselines3 import PPO

from sb3_cmzdril.cli import main
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.experts import collect_demos, loading
from sb3_cmzdril.experts.loading import inference_custom_objects, read_model_data

ENV = "Pendulum-v1"
SHORT = "dict(max_episode_steps=5)"


@pytest.fixture(scope="module")
def model_zip(tmp_path_factory) -> Path:
    """A tiny untrained PPO expert for Pendulum."""
    path = tmp_path_factory.mktemp("model") / "ppo.zip"
    PPO("MlpPolicy", ENV, n_steps=64, batch_size=32, policy_kwargs=dict(net_arch=[8]), device="cpu", seed=0).save(path)
    return path


def _mkdir_pickle(marker: Path) -> bytes:
    """Pickle opcodes that call ``os.mkdir(marker)`` when unpickled (the payload), its result dropped."""
    name = pickle.dumps(str(marker), protocol=2)[2:-1]  # the string's opcodes, without PROTO and STOP
    return b"\x80\x02" + f"c{os.mkdir.__module__}\nmkdir\n".encode() + name + b"\x85R0"


#: An SB3 1.x ``gym.spaces.box.Box()``, a module not installed here: the space does not unpickle.
OLD_GYM_BOX = b"cgym.spaces.box\nBox\n)\x81}b."


def _with_data(source: Path, target: Path, **entries: bytes | dict) -> Path:
    """A copy of a model zip whose ``data`` has ``entries`` (pickles as SB3 serialises them)."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            payload = zin.read(item.filename)
            if item.filename == "data":
                data = json.loads(payload)
                for key, value in entries.items():
                    if isinstance(value, bytes):
                        value = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(value).decode()}
                    data[key] = value
                payload = json.dumps(data).encode()
            zout.writestr(item, payload)
    return target


def test_inspecting_a_zip_unpickles_nothing(model_zip, tmp_path):
    """3a: the package read a zip's ``data`` and unpickled each ``:serialized:`` entry to see whether it
    loads; a payload in the zip ran then, before SB3's own load was ever asked for."""
    marker = tmp_path / "ran"
    evil = _with_data(model_zip, tmp_path / "evil.zip", _last_obs=_mkdir_pickle(marker) + b"N.")
    data = read_model_data(evil)
    custom = inference_custom_objects(evil, data, gym.make(ENV))
    assert not marker.exists()
    assert "_last_obs" not in custom  # it names only installed code: SB3's load decides


def test_collect_demos_runs_no_pickle_of_a_space_the_env_replaces(model_zip, tmp_path, capsys):
    """3a through the command: an old zip's observation space that names ``gym`` (not installed) is
    replaced by the env's without being unpickled, so the payload before it never runs."""
    marker = tmp_path / "ran"
    space = {":type:": "<class 'gym.spaces.box.Box'>", "shape": [3],
             ":serialized:": base64.b64encode(_mkdir_pickle(marker) + OLD_GYM_BOX).decode()}
    evil = _with_data(model_zip, tmp_path / "old.zip", observation_space=space)
    out = tmp_path / "d.npz"
    assert main(["collect-demos", "--expert", str(evil), "--env", ENV, "--env-kwargs", SHORT, "-o", str(out)]) == 0
    assert not marker.exists()
    assert Demonstrations.load(out).n_episodes == 1


def _code_notes(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "run code" in r.getMessage()]


def test_loading_model_files_says_once_that_they_can_run_code(model_zip, tmp_path, caplog, capsys, monkeypatch):
    """3b: loading a model zip, a pickle or a Hub download says once per process, not once per file,
    that such files run code when loaded; a scripted expert loads no file and says nothing."""
    loading.note_code_on_load.cache_clear()
    caplog.set_level(logging.INFO, logger="sb3_cmzdril")
    collect_demos("waypoint-reactive", "sb3_cmzdril:WaypointNav-v0", n_episodes=1, verbose=False)
    assert _code_notes(caplog) == []
    for _ in range(2):
        collect_demos(model_zip, ENV, n_episodes=1, env_kwargs={"max_episode_steps": 5}, verbose=False)
    (note,) = _code_notes(caplog)
    assert "only" in note and "trust" in note

    loading.note_code_on_load.cache_clear()  # a new process: the command line prints it, once
    capsys.readouterr()
    assert main(["collect-demos", "--expert", str(model_zip), "--env", ENV, "--env-kwargs", SHORT,
                 "-o", str(tmp_path / "d.npz")]) == 0
    out, err = capsys.readouterr()
    assert out.count("run code") == 1 and err == ""


def test_a_pickle_naming_a_submodule_this_install_lacks_counts_as_not_loading():
    # numpy 2's pickles name numpy._core, which numpy 1 lacks: such an entry is replaced, not unpickled
    # (the floors job loads the shipped SAC expert, pickled under numpy 2, with numpy 1.24).
    payload = b"\x80\x02cjson.no_such_submodule\nThing\n."  # a pickle of the global json.no_such_submodule.Thing
    error = loading._unresolvable({":serialized:": base64.b64encode(payload).decode()})
    assert isinstance(error, ModuleNotFoundError) and "json.no_such_submodule" in str(error)
    whole = pickle.dumps(json.JSONDecoder, protocol=4)
    assert loading._unresolvable({":serialized:": base64.b64encode(whole).decode()}) is None
