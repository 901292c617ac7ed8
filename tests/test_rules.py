"""Settings an ``"auto"`` rule decides from the demonstrations and the env: each decision is kept with
its reason in ``model.rules`` and said once in a log line."""
from __future__ import annotations

import logging

import gymnasium as gym
import numpy as np
import pytest

from helpers import PAPER, TINY, TINY_SAC
from sb3_cmzdril import CMZDRIL, CMZDRILSAC, Demonstrations


def _pendulum(limit: int):
    return gym.make("Pendulum-v1", max_episode_steps=limit)


@pytest.mark.parametrize("learner", [CMZDRIL, CMZDRILSAC])
def test_the_absorbing_rule_says_what_it_decided_and_why(pendulum_demos, learner, caplog):
    # The fixture's two episodes last 100 steps: the time limit of the env they are held to decides.
    kwargs = dict(TINY_SAC, ensemble_hidden=(16, 16), ensemble_epochs=5, bc_pretrain_epochs=5, seed=0) \
        if learner is CMZDRILSAC else dict(TINY)
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        model = learner("MlpPolicy", _pendulum(100), demonstrations=pendulum_demos, absorbing="auto", **kwargs)
        model.learn(64 if learner is CMZDRIL else 20)
    assert model.rules["absorbing"] == {
        "value": True,
        "reason": "every demonstration lasts the env's time limit (100 steps): an episode that ends earlier is "
                  "one the expert never had",
    }
    assert "absorbing on: every demonstration lasts the env's time limit (100 steps)" in caplog.text

    shorter = learner("MlpPolicy", _pendulum(150), demonstrations=pendulum_demos, absorbing="auto", **kwargs)
    shorter.learn(64 if learner is CMZDRIL else 20)
    assert shorter.rules["absorbing"]["value"] is False
    assert shorter.rules["absorbing"]["reason"].startswith(
        "2 of 2 demonstrations end before the env's time limit (150 steps)")


def test_the_disagreement_rule_reads_how_many_expert_actions_sit_on_a_bound(pendulum_demos, caplog):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, disagreement="auto", **TINY)
    model.learn(64)
    on_bound = float(np.mean(np.abs(pendulum_demos.actions) == 2.0))
    expected = "std_unclipped" if on_bound >= 0.01 else "std"
    assert model.rules["disagreement"]["value"] == expected
    assert f"{on_bound:.1%} of the demonstrations' action entries sit on a bound" in \
        model.rules["disagreement"]["reason"]
    # Actions clipped to the bound everywhere: the unclipped form.
    clipped = Demonstrations(pendulum_demos.observations, np.sign(pendulum_demos.actions) * 2.0,
                             pendulum_demos.episode_lengths)
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        bound = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=clipped, disagreement="auto", **TINY)
        bound.learn(64)
    assert bound.rules["disagreement"] == {
        "value": "std_unclipped",
        "reason": "100.0% of the demonstrations' action entries sit on a bound of the action space (at least 1%)",
    }
    assert "disagreement 'std_unclipped': 100.0% of the demonstrations' action entries" in caplog.text


def test_settings_given_outright_are_no_rule(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos,
                    **{**TINY, **PAPER, "absorbing": True})
    model.learn(64)
    assert model.rules == {}


def test_a_runs_record_keeps_what_its_rules_decided(tiny_experiment, tmp_path):
    import json

    from helpers import ENV
    from sb3_cmzdril.training.runs import plan_run, run_experiment

    hp = tmp_path / "auto.yml"
    hp.write_text(tiny_experiment["hp"].read_text() + "  bc_epochs_per_update: 1\n")  # the defaults' other rules
    spec = plan_run(ENV, "cmz", 0, demos=tiny_experiment["pool"], n_eval_episodes=1, timesteps=128,
                    hyperparams=hp, output_dir=tmp_path / "run")
    run_experiment(spec)
    rules = json.loads((tmp_path / "run" / "done.json").read_text())["rules"]
    assert set(rules) == {"absorbing", "disagreement", "cmz_clip_quantile", "standardize_observations"}
    assert rules["absorbing"]["value"] is True
    assert rules["absorbing"]["reason"].startswith("every demonstration lasts the env's time limit (50 steps)")
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["rules"] == rules
    # every constructor argument as the run gave it: the YAML's, the run's own, the constructor's defaults
    constructor = config["constructor"]
    assert constructor["absorbing"] == "auto" and constructor["reward"] == "cmz" and constructor["seed"] == 0
    assert constructor["bc_epochs_per_update"] == 1
    assert constructor["alpha"] == 10.0 and constructor["gae_lambda"] == 0.95 and constructor["device"] == "cpu"
    assert not {"env", "demonstrations", "verbose", "self"} & set(constructor)


def _auto_epochs(env, demos, **kwargs):
    return CMZDRIL("MlpPolicy", env, demonstrations=demos,
                   **{**TINY, **PAPER, "bc_epochs_per_update": "auto", **kwargs})


def _inside(demos: Demonstrations) -> Demonstrations:
    """The demonstrations with every action moved off Pendulum-v1's bounds (+-2)."""
    return Demonstrations(demos.observations, np.clip(demos.actions, -1.9, 1.9), demos.episode_lengths)


@pytest.fixture
def close_clones(monkeypatch):
    """Every clone reads as close by its held-out NLL, so that the NLL epochs rule asks whether it falls."""
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    monkeypatch.setattr(cmzdril_module, "AUTO_EPOCHS_NLL", float("inf"))


def test_the_held_out_nll_per_action_entry_is_in_units_of_half_the_bounds_range():
    from gymnasium import spaces

    from sb3_cmzdril.common.bc import nll_per_action_entry

    # Pendulum-v1's torque in [-2, 2]: half its range is 2, so the NLL per entry falls by log 2.
    assert nll_per_action_entry(1.0, spaces.Box(-2, 2, (1,))) == pytest.approx(1.0 - np.log(2.0))
    assert nll_per_action_entry(-3.0, spaces.Box(-1, 1, (3,))) == pytest.approx(-1.0)
    # each entry by its own bounds; an unbounded entry as it is
    box = spaces.Box(np.array([-1, -4, -np.inf], np.float32), np.array([1, 4, np.inf], np.float32))
    assert nll_per_action_entry(3.0, box) == pytest.approx(1.0 - np.log(4.0) / 3)
    assert nll_per_action_entry(float("nan"), spaces.Box(-1, 1, (2,))) is None
    assert nll_per_action_entry(1.0, spaces.Discrete(3)) is None


@pytest.mark.parametrize("per_entry", [0.5, -1.0])
def test_the_nll_epochs_rule_drops_them_where_the_clone_predicts_the_held_out_steps_loosely(
        pendulum_demos, monkeypatch, caplog, per_entry):
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    # Decided from the pretraining alone: the clone is not played for it.
    monkeypatch.setattr(cmzdril_module, "clone_drift", lambda *a, **k: pytest.fail("probed"))
    model = _auto_epochs(_pendulum(40), pendulum_demos)
    model.pretrain()
    model.pretrain_info["bc_validation_nll"] = per_entry + np.log(2.0)  # one entry, bounds +-2
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        model.learn(64)
    assert model.rules["bc_epochs_per_update"] == {
        "value": 0,
        "reason": f"the clone's NLL on the held-out demo steps is {per_entry:.2f} per action entry (in units of "
                  "half its bounds' range), at least -1: it predicts the expert's actions loosely, and no NLL epoch "
                  "pulls the policy toward it",
    }
    assert model.bc_epochs_active == 0 and "train/bc_nll" not in model.logger.name_to_value
    assert f"bc_epochs_per_update 0: the clone's NLL on the held-out demo steps is {per_entry:.2f}" in caplog.text


def test_a_close_clone_that_does_not_fall_keeps_the_nll_epochs(pendulum_demos):
    model = _auto_epochs(_pendulum(40), _inside(pendulum_demos))
    model.pretrain()
    model.pretrain_info["bc_validation_nll"] = -2.5 + np.log(2.0)
    model.learn(64)
    decided = model.rules["bc_epochs_per_update"]
    assert decided["value"] == 1 and "train/bc_nll" in model.logger.name_to_value
    assert "and its held-out NLL is -2.50 per action entry, under -1: the clone does not fall" in decided["reason"]


@pytest.mark.parametrize("falls", [True, False])
def test_the_nll_epochs_rule_drops_them_where_the_clone_falls(pendulum_demos, close_clones, falls):
    # The demonstrations last the env's time limit (40 of their 100 steps); wrapped, the env ends an episode
    # once the pole hangs below the horizontal, which the expert never met.
    env = _Falls(_pendulum(40)) if falls else _pendulum(40)
    model = _auto_epochs(env, _inside(pendulum_demos))
    model.learn(64)
    decided = model.rules["bc_epochs_per_update"]
    assert decided["value"] == (0 if falls else 1) and model.bc_epochs_active == decided["value"]
    # The NLL epochs ran after the update only where the rule kept them.
    assert ("train/bc_nll" in model.logger.name_to_value) is not falls
    assert decided["reason"].startswith("the env terminated ")
    assert "episodes, where every demonstration lasts the time limit (40 steps) (its path scores u " in \
        decided["reason"]
    assert decided["reason"].endswith(
        "the clone falls, so no NLL epoch pulls the policy back to it" if falls
        else "the clone does not fall, and one NLL epoch after each update holds the policy on the demonstrations")
    if not falls:
        assert decided["reason"].startswith("the env terminated 0 of the clone's 5 episodes")
    assert model.bc_epochs_per_update == "auto"


@pytest.mark.parametrize("reward", ["dril", "env"])
def test_the_baselines_keep_their_nll_epoch_where_the_rule_would_drop_it(pendulum_demos, monkeypatch, reward):
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    # A clone that falls would lose its epochs under the 'cmz' reward; DRIL keeps its BC step, unprobed.
    monkeypatch.setattr(cmzdril_module, "clone_drift", lambda *a, **k: pytest.fail("probed"))
    model = _auto_epochs(_Falls(_pendulum(40)), _inside(pendulum_demos), reward=reward)
    model.learn(64)
    assert model.rules["bc_epochs_per_update"] == {
        "value": 1,
        "reason": f"the {reward!r} reward keeps the paper's NLL epoch after each update, as its method defines "
                  "it; the rule decides only for the 'cmz' reward",
    }
    assert model.bc_epochs_active == 1 and "train/bc_nll" in model.logger.name_to_value


def test_where_the_expert_ends_its_episodes_the_nll_epochs_rule_asks_how_soon_the_clone_ends(
        pendulum_demos, close_clones):
    # The demonstrations end at 100 steps, the env's limit is 150: the clone falls where the env ends its
    # episodes before 50 steps on average.
    model = _auto_epochs(_Falls(_pendulum(150)), _inside(pendulum_demos))
    model.learn(64)
    decided = model.rules["bc_epochs_per_update"]
    assert decided["value"] == 0
    assert "steps on average: under 0.5 times the shortest demonstration's 100 (its path scores u " in \
        decided["reason"]


@pytest.mark.parametrize("falls", [True, False])
def test_where_the_expert_ends_its_episodes_a_loose_clone_keeps_the_nll_epochs_unless_it_falls(
        pendulum_demos, falls):
    # The demonstrations end at 100 steps, before the env's limit of 150: the expert ends its own episodes, and
    # the held-out NLL is not asked; whether the clone falls decides.
    model = _auto_epochs(_Falls(_pendulum(150)) if falls else _pendulum(150), _inside(pendulum_demos))
    model.pretrain()
    model.pretrain_info["bc_validation_nll"] = 0.5 + np.log(2.0)  # loose: 0.50 per action entry
    model.learn(64)
    decided = model.rules["bc_epochs_per_update"]
    assert decided["value"] == (0 if falls else 1) and model.bc_epochs_active == decided["value"]
    assert ("train/bc_nll" in model.logger.name_to_value) is not falls
    if falls:
        assert decided["reason"].endswith("the clone falls, so no NLL epoch pulls the policy back to it")
    else:
        assert decided["reason"].startswith("the env terminated 0 of the clone's 5 episodes (its path scores u ")
        assert decided["reason"].endswith(
            "and the expert ends its own episodes, an end the disagreement reward does not ask for (its held-out "
            "NLL, 0.50 per action entry, is not asked): the clone does not fall, and one NLL epoch after each "
            "update holds the policy on the demonstrations")


def test_the_clones_probe_leaves_the_run_as_the_decided_value_would_have_run_it(pendulum_demos, close_clones):
    pendulum_demos = _inside(pendulum_demos)
    auto = _auto_epochs(_pendulum(40), pendulum_demos, seed=3)
    auto.learn(128)
    decided = auto.rules["bc_epochs_per_update"]["value"]
    given = CMZDRIL("MlpPolicy", _pendulum(40), demonstrations=pendulum_demos,
                    **{**TINY, **PAPER, "seed": 3, "bc_epochs_per_update": decided})
    given.learn(128)
    for (name, a), (_, b) in zip(auto.policy.state_dict().items(), given.policy.state_dict().items(), strict=True):
        assert np.array_equal(a.cpu().numpy(), b.cpu().numpy()), name
    assert auto.num_timesteps == given.num_timesteps == 128


def test_a_loaded_model_keeps_its_decision_without_a_new_probe(pendulum_demos, tmp_path, monkeypatch, close_clones):
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    model = _auto_epochs(_pendulum(40), pendulum_demos)
    model.learn(64)
    model.save(tmp_path / "model.zip")

    def no_probe(*args, **kwargs):
        raise AssertionError("a decided rule probes again")

    monkeypatch.setattr(cmzdril_module, "clone_drift", no_probe)
    loaded = CMZDRIL.load(tmp_path / "model.zip", env=_pendulum(40))
    assert loaded.rules["bc_epochs_per_update"] == model.rules["bc_epochs_per_update"]
    loaded.learn(64, reset_num_timesteps=False)
    assert loaded.bc_epochs_active == model.bc_epochs_active


def test_the_nll_epochs_take_a_number_or_auto(pendulum_demos):
    from sb3_cmzdril.errors import UserError

    with pytest.raises(UserError, match=r"bc_epochs_per_update must be a number >= 0 or 'auto', got 'yes'"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update="yes")
    with pytest.raises(UserError, match="bc_epochs_per_update must be finite and >= 0, got -1"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=-1)


def test_auto_standardisation_leaves_bounded_entries_as_the_env_gives_them(pendulum_demos, caplog):
    from sb3_cmzdril.policies import DemoStandardizer

    # Pendulum-v1 bounds every entry: cos and sin in [-1, 1], the angular velocity in [-8, 8].
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, standardize_observations="auto",
                        **TINY)
        model.pretrain()
    standardizer = next(m for m in model.policy.modules() if isinstance(m, DemoStandardizer))
    np.testing.assert_array_equal(standardizer.obs_mean.cpu().numpy(), [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(standardizer.obs_std.cpu().numpy(), [1.0, 1.0, 1.0])
    assert model.rules["standardize_observations"] == {
        "value": False,
        "reason": "3 of 3 observation entries have finite bounds in the observation space: the env scales those, "
                  "every other one is standardised by the demonstrations",
    }
    assert "standardize_observations off: 3 of 3 observation entries" in caplog.text


def test_auto_standardisation_standardises_the_unbounded_entries(pendulum_demos):
    from sb3_cmzdril.policies import DemoStandardizer, observation_statistics

    unbounded = gym.spaces.Box(np.array([-1.0, -np.inf, -8.0], np.float32), np.array([1.0, np.inf, 8.0], np.float32))
    env = gym.wrappers.TransformObservation(gym.make("Pendulum-v1"), lambda o: o, unbounded)
    model = CMZDRIL("MlpPolicy", env, demonstrations=pendulum_demos, standardize_observations="auto", **TINY)
    model.pretrain()
    standardizer = next(m for m in model.policy.modules() if isinstance(m, DemoStandardizer))
    mean, std = observation_statistics(pendulum_demos.observations)
    np.testing.assert_allclose(standardizer.obs_mean.cpu().numpy(), [0.0, mean[1], 0.0])
    np.testing.assert_allclose(standardizer.obs_std.cpu().numpy(), [1.0, std[1], 1.0])
    assert model.rules["standardize_observations"]["value"] == "unbounded entries"
    assert model.rules["standardize_observations"]["reason"].startswith("2 of 3 observation entries")


def test_standardisation_takes_true_false_or_auto(pendulum_demos):
    from sb3_cmzdril.errors import UserError

    with pytest.raises(UserError, match="standardize_observations must be True, False or 'auto', got 'bounds'"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, standardize_observations="bounds")


@pytest.mark.parametrize("falls", [True, False])
def test_the_clip_rule_clips_u_where_the_clone_falls(pendulum_demos, falls):
    from sb3_cmzdril.ensemble import quantile_of_disagreement

    # Pendulum-v1 never terminates; wrapped, it ends an episode once the pole hangs below the horizontal.
    env = _Falls(_pendulum(40)) if falls else _pendulum(40)
    model = CMZDRIL("MlpPolicy", env, demonstrations=pendulum_demos, absorbing=True, cmz_clip_quantile="auto", **TINY)
    model.learn(64)
    decided = model.rules["cmz_clip_quantile"]
    if falls:
        assert decided["value"] == 0.98 and model.clip_quantile == 0.98
        assert decided["reason"].startswith("the env terminated ")
        assert decided["reason"].endswith("where no demonstration ends early: u is clipped, so a fall costs at most "
                                          "the clip's reward")
        assert model.cmz_u_max == pytest.approx(quantile_of_disagreement(model.ensemble, pendulum_demos, 0.98))
        assert model.reward_rule.u_max == pytest.approx(model.cmz_u_max)
    else:
        assert decided == {"value": None, "reason": "the env terminated 0 of the clone's 5 episodes: the clone "
                                                    "does not fall, u is left unclipped"}
        assert model.cmz_u_max is None and model.clip_quantile is None


class _Falls(gym.Wrapper):
    """Pendulum-v1 whose episode terminates once the pole hangs below the horizontal."""

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated or bool(obs[0] < 0.0), truncated, info


@pytest.mark.parametrize("falls", [True, False])
def test_where_the_expert_ends_its_episodes_the_absorbing_rule_asks_whether_the_clone_falls(
        pendulum_demos, falls, tmp_path, monkeypatch):
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    # The fixture's episodes last 100 steps and the env's limit is 150: the expert ends its own episodes.
    env = _Falls(_pendulum(150)) if falls else _pendulum(150)
    model = CMZDRIL("MlpPolicy", env, demonstrations=pendulum_demos, absorbing="auto", **TINY)
    model.learn(64)
    decided = model.rules["absorbing"]
    assert decided["value"] is falls and model.absorbing_active is falls
    assert decided["reason"].startswith("2 of 2 demonstrations end before the env's time limit (150 steps): the "
                                        "expert ends its own episodes; the env ends ")
    if falls:
        clone = model.clone_ends[0]
        assert model.clone_ends == [clone, 100] and clone < 50
        assert decided["reason"].endswith(f"the clone's after {clone:.0f} steps on average, under 0.5 times the "
                                          "shortest demonstration's 100: the clone falls")
    else:
        assert model.clone_ends == [float("inf"), 100]
        assert decided["reason"].endswith("none of the clone's episodes, so none of them is a fall")
    # Decided once: a loaded model keeps it without playing the clone again.
    model.save(tmp_path / "m.zip")
    monkeypatch.setattr(cmzdril_module, "clone_drift", lambda *a, **k: pytest.fail("probed"))
    loaded = CMZDRIL.load(tmp_path / "m.zip", env=env)
    loaded.learn(64)
    assert loaded.clone_ends == model.clone_ends and loaded.rules["absorbing"] == decided


def test_no_absorbing_state_leaves_u_unclipped_without_a_probe(pendulum_demos, monkeypatch):
    import sb3_cmzdril.cmzdril.cmzdril as cmzdril_module

    monkeypatch.setattr(cmzdril_module, "clone_drift", lambda *a, **k: pytest.fail("probed"))
    model = CMZDRIL("MlpPolicy", _pendulum(40), demonstrations=pendulum_demos,
                    **{**TINY, **PAPER, "cmz_clip_quantile": "auto"})
    model.learn(64)
    assert model.rules["cmz_clip_quantile"] == {
        "value": None, "reason": "no absorbing state: an episode's end costs nothing to clip"}


def test_the_clip_takes_a_quantile_none_or_auto(pendulum_demos):
    from sb3_cmzdril.errors import UserError

    with pytest.raises(UserError, match=r"cmz_clip_quantile must lie in \(0, 1\], be None or 'auto', got 'yes'"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, cmz_clip_quantile="yes")
    with pytest.raises(UserError, match="CMZDRILSAC's cmz_clip_quantile is a quantile in"):
        CMZDRILSAC("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, cmz_clip_quantile="auto")
