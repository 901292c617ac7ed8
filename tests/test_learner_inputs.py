"""What the learners are given: hyperparameter files, constructor settings, saved models, demo seeds.

Each refusal is a UserError of one line naming the problem (the command line prints it and exits 2);
each case here was accepted without a word before, or failed with an unrelated traceback.
"""
from __future__ import annotations

import logging
import re

import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO, SAC

from helpers import ENV, TINY, TINY_SAC
from sb3_cmzdril import CMZDRIL, CMZDRILSAC
from sb3_cmzdril.data.demos import FORMAT_VERSION, Demonstrations
from sb3_cmzdril.ensemble import quantile_of_disagreement
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.hyperparams import load_hyperparams

#: CMZDRILSAC's imitation part as small as CMZDRIL's in TINY.
TINY_CMZ_SAC = dict(TINY_SAC, ensemble_hidden=(16, 16), ensemble_epochs=5, bc_pretrain_epochs=5, seed=0)


def one_line_error(call, *args, **kwargs) -> str:
    """The message of the UserError ``call`` raises, checked to be one line."""
    with pytest.raises(UserError) as raised:
        call(*args, **kwargs)
    message = str(raised.value)
    assert "\n" not in message, message
    return message


# -- 1. hyperparameter files ---------------------------------------------------------------------
DUPLICATE_EPOCHS = """\
Pendulum-v1:
  n_timesteps: 1000
  n_epochs: 3
  policy: 'MlpPolicy'
  n_epochs: 5
"""
DUPLICATE_PER_METHOD = """\
Pendulum-v1:
  n_timesteps: 1000
  per_method:
    cmz: {bc_epochs_per_update: 0}
  per_method:
    dril: {bc_epochs_per_update: 2}
"""


@pytest.mark.parametrize("text, key, line, first", [
    (DUPLICATE_EPOCHS, "n_epochs", 5, 3),
    (DUPLICATE_PER_METHOD, "per_method", 5, 3),
    ("Pendulum-v1: {n_epochs: 3}\nPendulum-v1: {n_epochs: 5}\n", "Pendulum-v1", 2, 1),
])
def test_a_key_written_twice_in_a_hyperparameter_file_is_refused(text, key, line, first, tmp_path):
    """The last value won without a word: a second n_epochs or per_method block replaced the first."""
    path = tmp_path / "hp.yml"
    path.write_text(text)
    message = one_line_error(load_hyperparams, path, ENV, method="cmz")
    assert message == (f"hyperparameter file {path}: duplicate key {key!r} at line {line} (first at line {first}); "
                       "each key may appear once in a mapping")


def test_merged_keys_may_still_be_overridden(tmp_path):
    path = tmp_path / "hp.yml"
    path.write_text("base: &base {n_epochs: 3, gamma: 0.9}\nPendulum-v1:\n  <<: *base\n  n_epochs: 5\n")
    assert load_hyperparams(path, ENV).algo_kwargs == {"n_epochs": 5, "gamma": 0.9}


# -- 2. settings that disable learning -----------------------------------------------------------
@pytest.mark.parametrize("option, value, message", [
    ("gradient_steps", 0, "gradient_steps must be a whole number >= 1, or -1 for as many as the env steps collected"),
    ("gradient_steps", -3, "gradient_steps must be a whole number >= 1, or -1"),
    ("buffer_size", 0, "buffer_size must be >= 1, got 0"),
    ("batch_size", 0, "batch_size must be >= 1, got 0"),
    ("learning_starts", -1, "learning_starts must be >= 0, got -1"),
    ("train_freq", 0, "train_freq must be >= 1, got 0"),
    ("train_freq", (0, "episode"), "train_freq must be >= 1, got 0"),
    ("train_freq", (1, "epoch"), "train_freq's unit must be 'step' or 'episode', got 'epoch'"),
    ("target_update_interval", 0, "target_update_interval must be >= 1, got 0"),
    ("tau", 2.0, r"tau must be in \(0, 1\], got 2.0"),
    ("tau", 0.0, r"tau must be in \(0, 1\], got 0.0"),
    ("gamma", 1.5, r"gamma must be in \[0, 1\], got 1.5"),
    ("learning_rate", 0.0, "learning_rate must be finite and > 0, got 0.0"),
    ("ent_coef", "auto_0", "ent_coef must be a number >= 0, 'auto' or 'auto_<initial value > 0>', got 'auto_0'"),
    ("ent_coef", -0.1, "ent_coef must be finite and >= 0, got -0.1"),
    ("target_entropy", "low", "target_entropy must be a number or 'auto', got 'low'"),
    ("ensemble_epochs", 0, "ensemble_epochs must be >= 1, got 0"),
])
def test_sac_settings_that_cannot_learn_are_refused(option, value, message, pendulum_demos):
    """SAC took each of them: gradient_steps=0 reported the clone as the result, buffer_size=0 made a
    buffer of one transition, tau=2 overshot the target critics; others failed mid-training."""
    got = one_line_error(CMZDRILSAC, "MlpPolicy", ENV, demonstrations=pendulum_demos,
                         **{**TINY_CMZ_SAC, option: value})
    assert re.match(message, got), got


def test_sac_keeps_gradient_steps_minus_one_and_train_freq_in_episodes(pendulum_demos):
    model = CMZDRILSAC("MlpPolicy", ENV, demonstrations=pendulum_demos,
                       **{**TINY_CMZ_SAC, "gradient_steps": -1, "train_freq": (1, "episode"), "ent_coef": "auto"})
    assert model.gradient_steps == -1


@pytest.mark.parametrize("option, value, message", [
    ("n_epochs", 0, "n_epochs must be >= 1, got 0"),
    ("n_steps", 0, "n_steps must be >= 1, got 0"),
    ("n_steps", 1, r"`n_steps \* n_envs` must be greater than 1 with normalize_advantage=True, got n_steps=1 and"),
    ("batch_size", 0, "`batch_size` must be greater than 1 with normalize_advantage=True, got 0"),
    ("batch_size", 1, "`batch_size` must be greater than 1 with normalize_advantage=True, got 1"),
    ("batch_size", 1.5, "batch_size must be a whole number >= 1, got 1.5"),
    ("gamma", 1.5, r"gamma must be in \[0, 1\], got 1.5"),
    ("gae_lambda", -0.1, r"gae_lambda must be in \[0, 1\], got -0.1"),
    ("clip_range", 0, "clip_range must be finite and > 0, got 0.0"),
    ("clip_range_vf", 0.0, "clip_range_vf must be finite and > 0, got 0.0"),
    ("learning_rate", 0.0, "learning_rate must be finite and > 0, got 0.0"),
    ("ensemble_batch_size", 0, "ensemble_batch_size must be >= 1, got 0"),
])
def test_ppo_settings_that_cannot_learn_are_refused(option, value, message, pendulum_demos):
    """PPO took n_epochs=0 (an UnboundLocalError inside train()) and ensemble_batch_size=0 (refused only
    once learn() ran); its own checks of batch_size, n_steps and clip_range_vf are assertions."""
    got = one_line_error(CMZDRIL, "MlpPolicy", ENV, demonstrations=pendulum_demos, **{**TINY, option: value})
    assert re.match(message, got), got


@pytest.mark.parametrize("option, value", [("n_steps", 1), ("batch_size", 1), ("clip_range_vf", -0.2)])
def test_what_ppo_asserts_is_still_an_assertion_error(option, value, pendulum_demos):
    # code written for SB3's PPO catches AssertionError here (SB3's own tests do)
    with pytest.raises(AssertionError, match="must be"):
        CMZDRIL("MlpPolicy", ENV, demonstrations=pendulum_demos, **{**TINY, option: value})


def test_ppo_takes_minibatches_of_one_without_advantage_normalisation(pendulum_demos):
    model = CMZDRIL("MlpPolicy", ENV, demonstrations=pendulum_demos,
                    **{**TINY, "batch_size": 1, "normalize_advantage": False})
    assert model.batch_size == 1


# -- 3. a zip of the other learner -----------------------------------------------------------------
@pytest.fixture(scope="module")
def zips(tmp_path_factory, pendulum_demos) -> dict[str, object]:
    folder = tmp_path_factory.mktemp("zips")
    CMZDRIL("MlpPolicy", ENV, demonstrations=pendulum_demos, **TINY).save(folder / "cmz.zip")
    CMZDRILSAC("MlpPolicy", ENV, demonstrations=pendulum_demos, **TINY_CMZ_SAC).save(folder / "cmzsac.zip")
    PPO("MlpPolicy", ENV, n_steps=64, batch_size=32).save(folder / "ppo.zip")
    SAC("MlpPolicy", ENV, **TINY_SAC).save(folder / "sac.zip")
    return {name: folder / f"{name}.zip" for name in ("cmz", "cmzsac", "ppo", "sac")}


@pytest.mark.parametrize("learner, saved, holds", [
    (CMZDRIL, "cmzsac", "CMZDRILSAC"),
    (CMZDRIL, "sac", "SAC"),
    (CMZDRILSAC, "cmz", "CMZDRIL"),
    (CMZDRILSAC, "ppo", "PPO"),
    (CMZDRILSAC, "sac", "SAC"),
])
def test_loading_another_learners_zip_names_what_it_holds(learner, saved, holds, zips):
    """A TypeError (SACPolicy got multiple values for 'use_sde'), an AttributeError
    ('ActorCriticPolicy' object has no attribute 'actor') or a RuntimeError of missing state-dict keys."""
    path = zips[saved]
    expected = f"{path} holds a {holds} model, not a {learner.__name__} one; load it with {holds}.load"
    assert one_line_error(learner.load, path, device="cpu") == expected
    assert one_line_error(learner.load, str(path)[: -len(".zip")], device="cpu") == expected  # SB3 adds .zip
    with open(path, "rb") as stream:
        assert one_line_error(learner.load, stream, device="cpu") == expected


def test_each_learner_still_loads_its_own_zips(zips):
    with open(zips["cmzsac"], "rb") as stream:  # read for the check, then left where it was for SB3
        assert isinstance(CMZDRILSAC.load(stream, device="cpu"), CMZDRILSAC)
    assert isinstance(CMZDRIL.load(zips["cmz"], device="cpu"), CMZDRIL)
    assert isinstance(CMZDRIL.load(zips["ppo"], device="cpu"), CMZDRIL)  # a PPO agent to go on from


# -- 4. other demonstrations at load() -------------------------------------------------------------
@pytest.mark.parametrize("learner, kwargs", [(CMZDRIL, TINY), (CMZDRILSAC, TINY_CMZ_SAC)])
def test_load_with_other_demonstrations_refits_the_ensemble_on_them(learner, kwargs, pendulum_demos, tmp_path,
                                                                     caplog):
    """The ensemble, DRIL threshold and reward state stayed the old demos' while only the BC steps used
    the new ones: the reward measured the distance to demonstrations the model no longer imitated."""
    model = learner("MlpPolicy", ENV, demonstrations=pendulum_demos, reward="dril", **kwargs)
    model.pretrain()
    model.save(tmp_path / "m.zip")
    policy = {k: v.clone() for k, v in model.policy.state_dict().items()}
    ensemble = {k: v.clone() for k, v in model.ensemble.state_dict().items()}

    again = learner.load(tmp_path / "m.zip", demonstrations=pendulum_demos, device="cpu")  # the saved ones
    assert again.pretrained and again.dril_threshold == model.dril_threshold

    other = pendulum_demos.select([1])
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        loaded = learner.load(tmp_path / "m.zip", demonstrations=other, device="cpu")
    loaded.pretrain()
    assert loaded.dril_threshold == pytest.approx(quantile_of_disagreement(loaded.ensemble, other, 0.98))
    assert any(not th.equal(ensemble[k], v) for k, v in loaded.ensemble.state_dict().items() if k in ensemble)
    # the policy (and with it its input standardisation) is the one saved
    assert all(th.equal(policy[k], v) for k, v in loaded.policy.state_dict().items())
    assert f"{learner.__name__}.load: the demonstrations given (1 episodes, 100 steps) differ" in caplog.text


# -- 5. reset seeds ------------------------------------------------------------------------------
def test_fractional_seeds_are_refused_not_truncated(pendulum_demos, tmp_path):
    """Seed 1.7 became seed 1 without a word, so an evaluation 'from the expert's seeds' started elsewhere."""
    d = pendulum_demos
    assert one_line_error(Demonstrations, d.observations, d.actions, d.episode_lengths, seeds=[1.7, 2]) == (
        "reset seeds must be whole numbers (-1 for unknown); episodes [0] have [1.7]"
    )
    episodes = [dict(d.episode(0), seed=3.5), d.episode(1)]
    assert "episodes [0] have [3.5]" in one_line_error(Demonstrations.from_episodes, episodes)
    np.savez(tmp_path / "d.npz", format_version=np.asarray(FORMAT_VERSION), observations=d.observations,
             actions=d.actions, episode_lengths=d.episode_lengths, seeds=np.asarray([4.0, np.nan]))
    assert one_line_error(Demonstrations.load, tmp_path / "d.npz") == (
        f"demonstrations file {tmp_path / 'd.npz'}: reset seeds must be whole numbers (-1 for unknown); "
        "episodes [1] have [nan]"
    )
    assert Demonstrations(d.observations, d.actions, d.episode_lengths, seeds=[4.0, -1.0]).seeds.tolist() == [4, -1]


@pytest.mark.parametrize("learner, file", [("CMZDRIL", "cmzdril.yml"), ("CMZDRILSAC", "cmzdril_sac.yml")])
def test_the_shipped_default_entry_runs_the_constructors_defaults(learner, file):
    # `sb3-cmzdril train` on a task with no entry and the learner built in Python run the same method.
    import inspect

    import yaml

    import sb3_cmzdril
    from sb3_cmzdril.cmzdril_sac.cmzdril_sac import DEFAULT_POLICY_KWARGS
    from sb3_cmzdril.hyperparams import safe_eval
    from sb3_cmzdril.shipped import shipped_file

    cls = getattr(sb3_cmzdril, learner)
    defaults = {name: p.default for name, p in inspect.signature(cls.__init__).parameters.items()}
    if learner == "CMZDRILSAC":
        defaults["policy_kwargs"] = DEFAULT_POLICY_KWARGS
        assert cls.default_policy_kwargs == DEFAULT_POLICY_KWARGS
    entry = yaml.safe_load(shipped_file("hyperparams", file).read_text())["default"]
    differ = {}
    for key, value in entry.items():
        if key not in defaults or key == "policy":
            continue
        value = safe_eval(value) if key == "policy_kwargs" else value
        default = list(defaults[key]) if isinstance(defaults[key], tuple) else defaults[key]
        if value != default:
            differ[key] = (value, default)
    assert differ == {}
    # and states none of them again: the constructor is the one place of each default
    assert [key for key in entry if key in defaults or key in ("policy", "n_demos")] == []


@pytest.mark.parametrize("file", ["cmzdril.yml", "cmzdril_sac.yml"])
def test_the_shipped_entries_hold_only_what_their_task_defines(file):
    # Every setting is the default's (the constructor's rules read the task's data); an entry says what its
    # task is: its budget, its demonstrations, how its env is made.
    import yaml

    from sb3_cmzdril.shipped import shipped_file

    entries = yaml.safe_load(shipped_file("hyperparams", file).read_text())
    default = entries.pop("default")
    beyond = {name: sorted(k for k, v in entry.items() if default.get(k, object()) != v and
                           k not in ("n_demos", "env_kwargs", "n_timesteps"))
              for name, entry in entries.items()}
    assert entries and beyond == {name: [] for name in entries}
