"""rl-zoo-style hyperparameter loading: lookup/fallback, special keys, safe policy_kwargs, schedules."""
from pathlib import Path

import pytest
import torch.nn as nn
import torch.optim

from sb3_cmzdril.hyperparams import (
    LinearSchedule,
    default_hyperparams_path,
    load_hyperparams,
    parse_schedule,
    safe_eval,
    split_hyperparams,
)

YAML = """
Pendulum-v1:
  n_timesteps: 20000
  policy: 'MlpPolicy'
  learning_rate: !!float 1e-3
WaypointNav-v0:
  n_timesteps: !!float 1e5
  policy: 'MlpPolicy'
  n_envs: 4
  learning_rate: lin_3e-4
  clip_range: lin_0.2
  train_freq: [1, "episode"]
  env_kwargs: "dict(n_waypoints=3)"
  policy_kwargs: "dict(log_std_init=-3, net_arch=[400, 300], activation_fn=nn.ReLU)"
default:
  n_timesteps: !!float 1e6
  policy: 'MlpPolicy'
  gamma: 0.98
"""


@pytest.fixture
def yml(tmp_path):
    p = tmp_path / "algo.yml"
    p.write_text(YAML)
    return p


def test_exact_id(yml):
    hp = load_hyperparams(yml, "Pendulum-v1")
    assert hp.key == "Pendulum-v1"
    assert hp.n_timesteps == 20000 and hp.policy == "MlpPolicy"
    assert hp.algo_kwargs == {"learning_rate": 1e-3}
    assert hp.model_kwargs() == {"learning_rate": 1e-3}
    assert hp.raw == {"n_timesteps": 20000, "policy": "MlpPolicy", "learning_rate": 1e-3}


def test_prefixed_id_falls_back_to_plain_id(yml):
    hp = load_hyperparams(yml, "sb3_cmzdril:WaypointNav-v0")
    assert hp.key == "WaypointNav-v0"
    assert hp.n_timesteps == 100_000 and hp.n_envs == 4
    assert hp.env_kwargs == {"n_waypoints": 3}
    assert hp.policy_kwargs == {"log_std_init": -3, "net_arch": [400, 300], "activation_fn": nn.ReLU}
    # special keys are split off; the rest goes to the constructor (schedules parsed, train_freq a tuple)
    assert set(hp.algo_kwargs) == {"learning_rate", "clip_range", "train_freq"}
    assert hp.algo_kwargs["learning_rate"] == LinearSchedule(3e-4)
    assert hp.algo_kwargs["train_freq"] == (1, "episode")
    assert hp.model_kwargs()["policy_kwargs"]["activation_fn"] is nn.ReLU
    # the raw entry is kept as written (for metadata)
    assert hp.raw["policy_kwargs"].startswith("dict(")


def test_default_fallback(yml):
    hp = load_hyperparams(yml, "HalfCheetah-v5")
    assert hp.key == "default" and hp.env_id == "HalfCheetah-v5"
    assert hp.algo_kwargs == {"gamma": 0.98} and hp.n_timesteps == 1_000_000


def test_missing_entry_lists_keys(tmp_path):
    p = tmp_path / "x.yml"
    p.write_text("Pendulum-v1:\n  n_timesteps: 10\nCartPole-v1:\n  n_timesteps: 10\n")
    with pytest.raises(ValueError, match=r"HalfCheetah-v5.*available: \['CartPole-v1', 'Pendulum-v1'\]"):
        load_hyperparams(p, "HalfCheetah-v5")


def test_missing_or_bad_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yml"):
        load_hyperparams(tmp_path / "nope.yml", "Pendulum-v1")
    bad = tmp_path / "bad.yml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ValueError, match="bad.yml"):
        load_hyperparams(bad, "a")


def test_safe_eval_accepts_zoo_strings():
    assert safe_eval("dict(log_std_init=-3.67, net_arch=[64, 64])") == {"log_std_init": -3.67, "net_arch": [64, 64]}
    assert safe_eval("dict(net_arch=dict(pi=[64], vf=[64]), ortho_init=False, activation_fn=th.nn.Tanh)") == {
        "net_arch": {"pi": [64], "vf": [64]},
        "ortho_init": False,
        "activation_fn": nn.Tanh,
    }
    assert safe_eval("{'norm_obs': True, 'norm_reward': False}") == {"norm_obs": True, "norm_reward": False}
    assert safe_eval("dict(optimizer_class=torch.optim.Adam, x=(1, 'a', None))") == {
        "optimizer_class": torch.optim.Adam,
        "x": (1, "a", None),
    }


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os').system('x')",
        "dict(a=__import__('os').system('x'))",
        "dict(net_arch=[64]*2)",
        "nn.Module.__subclasses__()",
        "nn.functional",
        "nn.init.zeros_",
        "os.system",
        "dict(**kw)",
        "print",
        "lambda: 0",
        "[x for x in range(3)]",
        "dict(1, a=2)",
        "nn.ReLU()",
    ],
)
def test_safe_eval_rejects(text):
    with pytest.raises(ValueError) as info:
        safe_eval(text)
    assert repr(text) in str(info.value) or text in str(info.value)


def test_malicious_policy_kwargs_in_yaml_rejected(tmp_path):
    p = tmp_path / "evil.yml"
    p.write_text("Pendulum-v1:\n  policy_kwargs: \"__import__('os').system('touch pwned')\"\n")
    with pytest.raises(ValueError, match=r"policy_kwargs.*__import__"):
        load_hyperparams(p, "Pendulum-v1")
    assert not Path("pwned").exists() and not (tmp_path / "pwned").exists()


def test_lin_schedule():
    sched = parse_schedule("lin_7.3e-4")
    assert isinstance(sched, LinearSchedule)
    assert sched(1.0) == pytest.approx(7.3e-4)
    assert sched(0.5) == pytest.approx(3.65e-4)
    assert sched(0.0) == 0.0
    assert repr(sched) == "lin_0.00073"
    assert parse_schedule(3e-4) == 3e-4
    for bad in ("lin_abc", "exp_0.1", "0.001x"):
        with pytest.raises(ValueError, match="schedule"):
            parse_schedule(bad)


def test_bad_schedule_in_yaml_names_key(tmp_path):
    p = tmp_path / "s.yml"
    p.write_text("default:\n  learning_rate: cos_1e-3\n")
    with pytest.raises(ValueError, match="learning_rate"):
        load_hyperparams(p, "X-v0")


def test_check_supported_rejects_unimplemented_special_keys():
    hp = split_hyperparams({"normalize": True, "n_timesteps": 10}, env_id="X-v0", key="X-v0", path="f.yml")
    with pytest.raises(ValueError, match=r"normalize.*train-expert"):
        hp.check_supported(what="train-expert")
    hp = split_hyperparams({"frame_stack": 4, "env_wrapper": ["a.B"]}, key="k")
    with pytest.raises(ValueError, match=r"env_wrapper.*frame_stack"):
        hp.check_supported()
    split_hyperparams({"normalize": False}, key="k").check_supported()  # false is the same as absent
    hp = split_hyperparams({"normalize": "dict(norm_obs=True, norm_reward=False)"}, key="k")
    assert hp.normalize == {"norm_obs": True, "norm_reward": False}
    hp.check_supported(unsupported=("frame_stack",))  # callers that implement normalize may allow it


def test_policy_must_be_a_name():
    with pytest.raises(ValueError, match="policy"):
        split_hyperparams({"policy": "os.system"}, key="k")


def test_repo_sac_yml_has_zoo_values():
    path = default_hyperparams_path("sac")
    assert path.name == "sac.yml" and path.parent.name == "hyperparams"
    for env_id in ("HalfCheetah-v5", "Hopper-v5"):
        hp = load_hyperparams(path, env_id)
        assert hp.key == env_id
        assert hp.n_timesteps == 1_000_000 and hp.policy == "MlpPolicy"
        assert hp.algo_kwargs == {"learning_starts": 10000} and hp.policy_kwargs == {}
    hp = load_hyperparams(path, "Pendulum-v1")
    assert hp.n_timesteps == 20000 and hp.algo_kwargs == {"learning_rate": 1e-3}
    assert load_hyperparams(path, "Unknown-v0").key == "default"


def test_missing_default_file_is_explained():
    with pytest.raises(FileNotFoundError, match="--hyperparams"):
        default_hyperparams_path("no-such-algo")


# -- constructor arguments: names and types checked before anything is built ----------------------------
@pytest.mark.parametrize(
    "annotation, expected",
    [
        (int, ["int"]),
        ("Optional[Dict[str, Any]]", ["Dict", "None"]),
        ("Union[None, float, Schedule]", ["None", "float", "Schedule"]),
        ("int | tuple[int, str]", ["int", "tuple"]),
        ("torch.device | str", ["device", "str"]),
    ],
)
def test_annotation_alternatives(annotation, expected):
    from sb3_cmzdril.hyperparams import annotation_alternatives

    assert annotation_alternatives(annotation) == expected


def test_check_constructor_kwargs_accepts_the_shipped_files_and_zoo_forms():
    from stable_baselines3 import PPO, SAC

    from sb3_cmzdril.cmzdril import CMZDRIL
    from sb3_cmzdril.cmzdril_sac import CMZDRILSAC
    from sb3_cmzdril.hyperparams import check_constructor_kwargs, read_hyperparams_file
    from sb3_cmzdril.training.runs import load_run_hyperparams
    from sb3_cmzdril.training.spec import FALLBACK_N_DEMOS, PAPER_METHODS

    sac = default_hyperparams_path("sac")
    for key in read_hyperparams_file(sac):
        check_constructor_kwargs(load_hyperparams(sac, key), [SAC])
    cmzdril = default_hyperparams_path("cmzdril")
    for key in read_hyperparams_file(cmzdril):
        for method in PAPER_METHODS:  # an entry's per_method settings are constructor arguments too
            check_constructor_kwargs(load_run_hyperparams(cmzdril, key, method)[0], [CMZDRIL, PPO])
    cmzdril_sac = default_hyperparams_path("cmzdril_sac")
    for key in read_hyperparams_file(cmzdril_sac):
        hp, settings = load_run_hyperparams(cmzdril_sac, key, "cmz-sac")
        check_constructor_kwargs(hp, [CMZDRILSAC, SAC])
        # the grid's split: as many training episodes for both learners
        assert (settings.get("n_demos", FALLBACK_N_DEMOS)
                == load_run_hyperparams(cmzdril, key)[1].get("n_demos", FALLBACK_N_DEMOS))
    # schedules, [n, "episode"] train_freq, ent_coef as a number or "auto", an int where a float is due
    zoo = {
        "learning_rate": "lin_7.3e-4",
        "train_freq": [1, "episode"],
        "ent_coef": 0.1,
        "target_entropy": "auto",
        "tau": 1,
    }
    check_constructor_kwargs(split_hyperparams(zoo, "Pendulum-v1", "Pendulum-v1"), [SAC])


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"n_steps": "lots"}, "hyperparameters 'k' in f.yml: n_steps must be int, got 'lots' \\(str\\)"),
        ({"n_steps": 2.5}, "n_steps must be int, got 2.5 \\(float\\)"),
        ({"gamma": True}, "gamma must be float, got True \\(bool\\)"),
        ({"clip_range": "x"}, "invalid schedule for clip_range"),
        ({"target_kl": "0.01"}, "target_kl must be float or None, got '0.01' \\(str\\)"),
        ({"ensemble_hidden": 64}, "ensemble_hidden must be list, got 64 \\(int\\)"),
        ({"n_step": 3}, "\\['n_step'\\] are not CMZDRIL/PPO arguments"),
    ],
)
def test_check_constructor_kwargs_names_the_key(entry, message):
    from stable_baselines3 import PPO

    from sb3_cmzdril.cmzdril import CMZDRIL
    from sb3_cmzdril.hyperparams import check_constructor_kwargs

    with pytest.raises(ValueError, match=message):
        check_constructor_kwargs(split_hyperparams(entry, "Pendulum-v1", "k", path="f.yml"), [CMZDRIL, PPO])


PER_METHOD_YAML = """
default:
  n_timesteps: 1000
  bc_epochs_per_update: 1
  gamma: 0.99
  per_method:
    cmz: {bc_epochs_per_update: 0, ent_coef: 0.01}
    env: {bc_epochs_per_update: 2}
"""


def test_a_per_method_block_lays_one_methods_settings_over_the_entry(tmp_path):
    path = tmp_path / "cmzdril.yml"
    path.write_text(PER_METHOD_YAML)
    cmz = load_hyperparams(path, "X-v0", "cmz")
    assert cmz.algo_kwargs == {"bc_epochs_per_update": 0, "gamma": 0.99, "ent_coef": 0.01}
    # the record of a run holds what that run used, never the other methods' settings
    assert cmz.raw == {"n_timesteps": 1000, "bc_epochs_per_update": 0, "gamma": 0.99, "ent_coef": 0.01}
    assert load_hyperparams(path, "X-v0", "env").algo_kwargs == {"bc_epochs_per_update": 2, "gamma": 0.99}
    for method in ("dril", None):  # a method the block does not name, or none, gets the entry alone
        hp = load_hyperparams(path, "X-v0", method)
        assert hp.raw == {"n_timesteps": 1000, "bc_epochs_per_update": 1, "gamma": 0.99}
        assert hp.per_method_names == ("cmz", "env")


@pytest.mark.parametrize("block", ["[cmz]", "{cmz: 0}", "{cmz: {per_method: {}}}"])
def test_a_malformed_per_method_block_is_one_line_naming_it(tmp_path, block):
    from sb3_cmzdril.errors import UserError

    path = tmp_path / "cmzdril.yml"
    path.write_text(f"default:\n  gamma: 0.99\n  per_method: {block}\n")
    with pytest.raises(UserError, match="per_method") as info:
        load_hyperparams(path, "X-v0", "cmz")
    assert "\n" not in str(info.value)


def test_a_run_refuses_a_per_method_block_naming_an_unknown_method(tmp_path):
    from sb3_cmzdril.errors import UserError
    from sb3_cmzdril.training.spec import load_run_hyperparams

    path = tmp_path / "cmzdril.yml"
    path.write_text("default:\n  gamma: 0.99\n  per_method: {cmzz: {gamma: 0.9}}\n")
    with pytest.raises(UserError, match=r"unknown methods \['cmzz'\]"):
        load_run_hyperparams(path, "X-v0", "cmz")


def test_tune_sets_a_value_for_every_method_over_the_per_method_blocks(monkeypatch):
    import importlib

    import yaml

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "benchmarks" / "studies"))
    tune = importlib.import_module("tune")
    base = yaml.safe_load(PER_METHOD_YAML)
    base["Y-v0"] = {"gamma": 0.9}
    tune.apply_sets(base, {"bc_epochs_per_update": 3})
    assert base["default"]["per_method"] == {"cmz": {"ent_coef": 0.01}}  # env's only setting was overridden
    assert base["default"]["bc_epochs_per_update"] == 3 and base["Y-v0"] == {"gamma": 0.9, "bc_epochs_per_update": 3}
    tune.apply_sets(base, {"ent_coef": 0.0})
    assert "per_method" not in base["default"]
