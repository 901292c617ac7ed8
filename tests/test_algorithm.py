"""CMZDRIL end to end: pretraining, wrapping, BC epochs, logging, save/load, Discrete, errors."""
from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from helpers import PAPER, TINY
from sb3_cmzdril import CMZDRIL, CMZReward, DisagreementReward, DRILReward
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.hyperparams import LinearSchedule


@pytest.mark.slow
@pytest.mark.parametrize("reward", ["cmz", "dril", "zero", "env"])
def test_every_reward_mode_learns_and_logs(reward, pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, reward=reward, **TINY)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(192)
    assert model.num_timesteps == 192
    with open(tmp_path / "progress.csv") as f:
        rows = list(csv.DictReader(f))
    assert {"rollout/disagreement_mean", "rollout/shaped_reward_mean", "train/bc_nll"} <= set(rows[0])
    assert any(r["train/bc_nll"] for r in rows)
    rule = model.reward_rule
    assert model.reward_wrapper() is None  # rollouts are scored from the buffer; the env stack is untouched
    assert {"cmz": CMZReward, "dril": DRILReward}.get(reward, type(rule)) is type(rule)
    if reward == "dril":
        assert model.dril_threshold is not None and model.dril_threshold > 0


@pytest.mark.slow
def test_pretraining_lowers_the_nll_of_expert_actions(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "bc_pretrain_epochs": 30})
    info = model.pretrain()
    assert info["bc_nll_after"] < info["bc_nll_before"] - 0.3
    assert model.pretrain() is info  # pretraining happens once


def test_bc_epoch_after_each_update_and_disabled(pendulum_demos):
    calls = []
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=2, **TINY)
    original = model.bc.epoch
    model.bc.epoch = lambda *a, **k: calls.append(1) or original(*a, **k)
    model.learn(128)  # pretraining epochs, then 2 updates x 2 epochs
    assert len(calls) == TINY["bc_pretrain_epochs"] + 4
    off = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=0, **TINY)
    off.pretrain()
    before = [p.detach().clone() for p in off.policy.parameters()]
    off.bc.epoch = lambda *a, **k: pytest.fail("no BC epoch expected")
    off.learn(64)
    assert any(
        not np.allclose(b.cpu(), p.detach().cpu()) for b, p in zip(before, off.policy.parameters(), strict=True)
    )  # PPO still updated


@pytest.mark.parametrize("update_std", [True, False])
def test_bc_epochs_fit_the_log_std_only_when_asked(update_std, pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_update_std=update_std, **TINY)
    model.pretrain()
    moved = []
    original = model.bc.epoch

    def epoch(*args, **kwargs):
        before = {k: v.clone() for k, v in model.policy.state_dict().items()}
        result = original(*args, **kwargs)
        moved.append(_changed(before, model))
        return result

    model.bc.epoch = epoch
    model.learn(128)  # two PPO updates, each followed by one NLL epoch
    assert len(moved) == 2
    for changed in moved:
        assert {"action_net.weight", "mlp_extractor.policy_net.0.weight"} <= changed
        assert ("log_std" in changed) is update_std
    assert all(p.requires_grad for p in model.policy.parameters())  # PPO's next update moves it again


def test_a_bc_learning_rate_schedule_sets_each_nll_epochs_step_size(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_learning_rate="lin_1e-3", **TINY)
    rates = []
    original = model.bc.epoch

    def epoch(*args, **kwargs):
        rates.append(model.bc.optimizer.param_groups[0]["lr"])
        return original(*args, **kwargs)

    model.bc.epoch = epoch
    model.learn(128)  # pretraining, then PPO updates after 64 and 128 of 128 steps (progress remaining 0.5, 0)
    pretraining, after_updates = rates[:-2], rates[-2:]
    assert pretraining and pretraining == pytest.approx([1e-3] * len(pretraining))  # the start value
    assert after_updates == pytest.approx([5e-4, 0.0])
    model.save(tmp_path / "scheduled.zip")
    assert CMZDRIL.load(tmp_path / "scheduled.zip").bc_learning_rate == LinearSchedule(1e-3)


def test_a_bc_learning_rate_that_is_no_schedule_is_one_line_naming_it(pendulum_demos):
    with pytest.raises(UserError, match="invalid schedule for bc_learning_rate: 'exp_1e-3'"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_learning_rate="exp_1e-3", **TINY)


def _changed(before: dict, model: CMZDRIL) -> set[str]:
    return {k for k, v in model.policy.state_dict().items() if not np.array_equal(before[k].cpu(), v.cpu())}


def test_critic_warmup_fits_the_value_function_alone_and_is_not_repeated_on_resume(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, critic_warmup_updates=2, **TINY)
    model.pretrain()
    model.bc.epoch = lambda *a, **k: pytest.fail("no NLL epoch during the critic's warm-up")
    before = {k: v.clone() for k, v in model.policy.state_dict().items()}
    model.learn(128)  # two updates, both warm-up
    assert model.critic_warmup_done == 2
    assert _changed(before, model) == {
        "mlp_extractor.value_net.0.weight", "mlp_extractor.value_net.0.bias", "mlp_extractor.value_net.2.weight",
        "mlp_extractor.value_net.2.bias", "value_net.weight", "value_net.bias",
    }
    assert all(p.requires_grad for p in model.policy.parameters())  # unfrozen again
    model.save(tmp_path / "warm.zip")
    resumed = CMZDRIL.load(tmp_path / "warm.zip", env=gym.make("Pendulum-v1"))
    assert resumed.critic_warmup_done == 2
    before = {k: v.clone() for k, v in resumed.policy.state_dict().items()}
    resumed.learn(64, reset_num_timesteps=False)  # warm-up over: PPO and the NLL epoch move the actor
    assert {"action_net.weight", "log_std", "mlp_extractor.policy_net.0.weight"} <= _changed(before, resumed)


def test_wrapper_reports_true_return_to_monitor_and_callbacks(pendulum_demos):
    seen = []

    class Grab(BaseCallback):
        def _on_step(self) -> bool:
            seen.append((self.locals["infos"][0], float(self.locals["rewards"][0])))
            return True

    # per-step scoring: the wrapper fills info["disagreement"] as each step happens
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, batch_scoring=False, **TINY)
    model.learn(256, callback=Grab(), progress_bar=True)
    info, shaped = seen[10]
    assert {"env_reward", "disagreement"} <= set(info)
    assert shaped != pytest.approx(info["env_reward"])
    # Pendulum episodes last 200 steps: Monitor's return is the sum of the true rewards, not the shaped ones
    episodes = [i["episode"]["r"] for i, _ in seen if "episode" in i]
    assert len(episodes) == 1
    assert episodes[0] == pytest.approx(sum(i["env_reward"] for i, _ in seen[:200]), rel=1e-5)


def test_save_load_identity_and_continued_learning(pendulum_demos, tmp_path):
    env = DummyVecEnv([lambda: gym.make("Pendulum-v1"), lambda: gym.make("Pendulum-v1")])
    model = CMZDRIL("MlpPolicy", env, demonstrations=pendulum_demos, **TINY)
    model.learn(256)
    model.save(tmp_path / "agent.zip")
    loaded = CMZDRIL.load(tmp_path / "agent.zip", env=DummyVecEnv([lambda: gym.make("Pendulum-v1")] * 2))
    obs = pendulum_demos.observations[:50] + 0.3
    assert np.array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    assert np.array_equal(model.ensemble.member_outputs(obs), loaded.ensemble.member_outputs(obs))
    assert np.array_equal(model.reward_rule.get_state(), loaded.reward_rule.get_state())
    assert loaded.reward_rule.get_state().shape == (2,)
    assert np.array_equal(loaded.demonstrations.observations, pendulum_demos.observations)
    assert np.array_equal(loaded.demonstrations.seeds, pendulum_demos.seeds)
    assert loaded.alpha == 10.0 and loaded.ensemble_hidden == (16, 16)
    bc_state = loaded.bc.optimizer.state_dict()["state"]
    assert bc_state and all(v["step"] > 0 for v in bc_state.values())  # BC optimiser moments restored
    loaded.learn(128, reset_num_timesteps=False)
    assert loaded.num_timesteps == 256 + 128
    assert loaded.reward_rule.get_state().shape == (2,)
    # no env: still predicts
    assert CMZDRIL.load(tmp_path / "agent.zip").predict(obs[:1], deterministic=True)[0].shape == (1, 1)


def test_load_with_other_n_envs(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    model.learn(64)
    model.save(tmp_path / "a.zip")
    with pytest.warns(UserWarning, match="reward state is for 1 envs but the model now has 3"):
        loaded = CMZDRIL.load(tmp_path / "a.zip", env=DummyVecEnv([lambda: gym.make("Pendulum-v1")] * 3))
    assert np.allclose(loaded.reward_rule.get_state(), model.reward_rule.get_state()[0])
    loaded.learn(192, reset_num_timesteps=False)


def _rollout_of(env_fn, pendulum_demos, **kwargs) -> CMZDRIL:
    model = CMZDRIL(
        "MlpPolicy", env_fn(), demonstrations=pendulum_demos,
        **{**TINY, **PAPER, "n_steps": 160, "batch_size": 80, **kwargs}
    )
    model.learn(2 * 160 * model.n_envs)
    return model


def _assert_same_rollouts(a: CMZDRIL, b: CMZDRIL) -> None:
    for name in ("rewards", "returns", "advantages", "values"):
        np.testing.assert_allclose(
            getattr(a.rollout_buffer, name), getattr(b.rollout_buffer, name), rtol=1e-5, atol=1e-5, err_msg=name
        )
    # u differs in the last float32 bits between the batched (torch) and per-step (numpy) forward
    np.testing.assert_allclose(a.reward_rule.get_state(), b.reward_rule.get_state(), rtol=1e-6)


def test_vecnormalize_the_ensemble_scores_raw_observations(pendulum_demos):
    # Per-step scoring puts the wrapper below VecNormalize, where it sees raw observations; the
    # buffer path must score the same raw observations although the buffer holds normalised ones.
    def env():
        return VecNormalize(DummyVecEnv([lambda: Monitor(gym.make("Pendulum-v1"))] * 2), norm_reward=False)

    batch, step = _rollout_of(env, pendulum_demos), _rollout_of(env, pendulum_demos, batch_scoring=False)
    assert batch.reward_wrapper() is None
    assert isinstance(step.env, VecNormalize) and isinstance(step.env.venv, DisagreementReward)
    raw = step.reward_wrapper()._last_obs
    assert np.allclose(np.linalg.norm(raw[:, :2], axis=1), 1.0, atol=1e-5)  # cos/sin: raw, not normalised
    _assert_same_rollouts(batch, step)
    assert batch._demo_obs_transform() == batch.env.normalize_obs


def test_discrete_cartpole_end_to_end(cartpole_demos, tmp_path):
    for reward in ("cmz", "dril"):
        model = CMZDRIL("MlpPolicy", "CartPole-v1", demonstrations=cartpole_demos, reward=reward, **TINY)
        model.learn(128)
        assert model.ensemble.discrete
        model.save(tmp_path / f"{reward}.zip")
        loaded = CMZDRIL.load(tmp_path / f"{reward}.zip", env=gym.make("CartPole-v1"))
        obs = cartpole_demos.observations[:20]
        assert np.array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
        loaded.learn(64, reset_num_timesteps=False)


def test_demonstrations_from_a_path(pendulum_demos, tmp_path):
    pendulum_demos.save(tmp_path / "demos.npz")
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=str(tmp_path / "demos.npz"), **TINY)
    assert isinstance(model.demonstrations, Demonstrations) and len(model.demonstrations) == len(pendulum_demos)


def test_a_fraction_of_an_nll_epoch_after_each_update(pendulum_demos):
    # 0.25: a quarter of the demo steps, each drawn once, after each of the 2 updates
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=0.25, **TINY)
    model.pretrain()
    steps: list[np.ndarray] = []
    original = model.bc._update
    model.bc._update = lambda obs, idx: steps.append(idx.cpu().numpy()) or original(obs, idx)
    model.learn(128)
    per_update = np.concatenate(steps).reshape(2, -1)
    assert per_update.shape[1] == 50  # 200 demo steps
    assert all(len(set(rows)) == 50 for rows in per_update)
    assert model.bc_epochs_per_update == 0.25
    assert CMZDRIL("MlpPolicy", "Pendulum-v1", bc_epochs_per_update=2.0).bc_epochs_per_update == 2


def test_errors(pendulum_demos, cartpole_demos, tmp_path):
    with pytest.raises(ValueError, match="reward must be one of"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, reward="gail")
    with pytest.raises(ValueError, match="alpha must be > 0"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, alpha=-1.0)
    with pytest.raises(ValueError, match="dril_quantile"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, dril_quantile=0.0)
    with pytest.raises(ValueError, match="bc_epochs_per_update must be finite and >= 0"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=-1)
    with pytest.raises(ValueError, match="critic_warmup_updates must be >= 0"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, critic_warmup_updates=-1)
    with pytest.raises(ValueError, match="CMZDRIL needs demonstrations"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", **TINY).learn(64)
    with pytest.raises(ValueError, match=r"observation shape \(4,\).*\(3,\)"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=cartpole_demos, **TINY).learn(64)
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=str(tmp_path / "missing.npz"))


def test_tensorboard_logging(pendulum_demos, tmp_path):
    pytest.importorskip("tensorboard", reason="tensorboard is in the test extra")
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, tensorboard_log=str(tmp_path), **TINY)
    model.learn(128, tb_log_name="run")
    events = list(tmp_path.glob("run_1/events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("reward", ["cmz", "dril", "env"])
def test_batch_scoring_gives_the_same_rollout_as_per_step_scoring(reward, pendulum_demos):
    # Pendulum truncates at 200 steps: the rollout includes SB3's time-limit bootstrap, which the
    # batch correction must keep. Two envs, rollouts of 160 steps.
    def env():
        return DummyVecEnv([lambda: gym.make("Pendulum-v1")] * 2)

    batch = _rollout_of(env, pendulum_demos, reward=reward)
    step = _rollout_of(env, pendulum_demos, reward=reward, batch_scoring=False)
    assert batch.reward_wrapper() is None and step.reward_wrapper() is not None
    _assert_same_rollouts(batch, step)
    obs = pendulum_demos.observations[:20]
    np.testing.assert_allclose(
        batch.predict(obs, deterministic=True)[0], step.predict(obs, deterministic=True)[0], rtol=1e-5, atol=1e-6
    )


def test_reward_normalising_vecnormalize_scores_per_step(pendulum_demos):
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]), norm_reward=True)
    model = CMZDRIL("MlpPolicy", venv, demonstrations=pendulum_demos, **TINY)
    model.learn(64)
    assert model.env is venv and isinstance(venv.venv, DisagreementReward)


@pytest.mark.parametrize("reward", ["cmz", "env"])
def test_normalize_reward_scales_the_rollout_as_a_reward_normalising_vecnormalize(reward, pendulum_demos):
    # Two rollouts of 160 steps in two envs, with Pendulum's time-limit truncation inside: the option,
    # applied to the scored buffer, gives the rollout a VecNormalize(norm_reward=True) gives step by step.
    def plain():
        return DummyVecEnv([lambda: gym.make("Pendulum-v1")] * 2)

    def normalising():
        return VecNormalize(plain(), norm_obs=False, norm_reward=True, gamma=0.99)

    option = _rollout_of(plain, pendulum_demos, reward=reward, normalize_reward=True)
    wrapper = _rollout_of(normalising, pendulum_demos, reward=reward)
    _assert_same_rollouts(option, wrapper)
    vec_normalize = wrapper.get_vec_normalize_env()
    assert option.return_scale.rms.count == pytest.approx(vec_normalize.ret_rms.count)
    np.testing.assert_allclose(option.return_scale.rms.var, vec_normalize.ret_rms.var, rtol=1e-5)


def test_return_scale_against_hand_computed_values():
    from sb3_cmzdril.cmzdril.scoring import ReturnScale

    scale = ReturnScale(gamma=0.5, clip=100.0)
    scale.rms.var, scale.rms.count = np.float64(3.0), 1.0  # statistics carried from earlier rollouts
    rewards = np.array([[2.0], [4.0], [1.0]], np.float32)
    dones = np.array([[False], [True], [False]])
    out = scale.apply(rewards, dones)
    # Returns 2, then 0.5 * 2 + 4 = 5; the episode ended, so the third starts again at 1.
    mean, var, count = 0.0, 3.0, 1.0
    expected = []
    for r, ret in zip((2.0, 4.0, 1.0), (2.0, 5.0, 1.0), strict=True):
        delta, total = ret - mean, count + 1
        mean, var, count = mean + delta / total, (var * count + delta**2 * count / total) / total, total
        expected.append(r / np.sqrt(var + 1e-8))
    np.testing.assert_allclose(out[:, 0], expected, rtol=1e-6)
    np.testing.assert_array_equal(scale.returns, [1.0])
    assert out.dtype == np.float32


def test_normalize_reward_refuses_what_would_divide_twice_or_step_by_step(pendulum_demos):
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]), norm_reward=True)
    # At construction, before a run writes anything; set_env then learn() meets the same check.
    with pytest.raises(UserError, match="normalize_reward=True and a VecNormalize that normalises rewards would "
                                        "divide the reward twice"):
        CMZDRIL("MlpPolicy", venv, demonstrations=pendulum_demos, normalize_reward=True, **TINY)
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, normalize_reward=True, **TINY)
    model.set_env(venv)
    with pytest.raises(UserError, match="normalize_reward=True and a VecNormalize that normalises rewards would "
                                        "divide the reward twice"):
        model.learn(64)
    with pytest.raises(UserError, match=r"normalize_reward=True needs batch_scoring=True"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, normalize_reward=True,
                batch_scoring=False, **TINY)


def test_normalize_reward_keeps_its_statistics_through_save_and_load(pendulum_demos, tmp_path):
    from stable_baselines3.common.logger import configure

    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, normalize_reward=True, **TINY)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(64)
    logged = np.genfromtxt(tmp_path / "progress.csv", delimiter=",", names=True)
    assert float(np.atleast_1d(logged["rolloutreward_scale"])[-1]) == pytest.approx(model.return_scale.scale, rel=1e-5)
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"))
    assert loaded.normalize_reward is True
    assert loaded.return_scale.rms.count == model.return_scale.rms.count
    np.testing.assert_array_equal(loaded.return_scale.returns, model.return_scale.returns)


def _forbid(model: CMZDRIL, *, clone: bool = False, fit: bool = False) -> None:
    """Make the model's BC pretraining and/or ensemble fit fail the test if they run."""
    if clone:
        model.bc.train_early_stopping = lambda *a, **k: pytest.fail("the policy was pretrained again")
    if fit:
        model.ensemble.fit = lambda *a, **k: pytest.fail("the ensemble was refitted")


@pytest.mark.parametrize("reward", ["cmz", "dril"])
def test_set_parameters_then_learn_keeps_the_loaded_weights(reward, pendulum_demos, tmp_path):
    trained = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, reward=reward, **TINY)
    trained.learn(64)
    trained.save(tmp_path / "a.zip")
    fresh = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, reward=reward, **{**TINY, "seed": 7})
    assert not fresh.pretrained
    fresh.set_parameters(str(tmp_path / "a.zip"))
    assert fresh.pretrained
    obs = pendulum_demos.observations[:30]
    assert np.array_equal(fresh.predict(obs, deterministic=True)[0], trained.predict(obs, deterministic=True)[0])
    _forbid(fresh, clone=True, fit=True)
    fresh.learn(64)
    assert np.array_equal(fresh.ensemble.member_outputs(obs), trained.ensemble.member_outputs(obs))
    if reward == "dril":  # the threshold belongs to the loaded ensemble, on the same demos
        assert fresh.dril_threshold == pytest.approx(trained.dril_threshold)


def test_set_parameters_of_the_policy_only_fits_only_the_ensemble(pendulum_demos):
    trained = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    trained.pretrain()
    fresh = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "seed": 7})
    fresh.set_parameters({"policy": trained.policy.state_dict()}, exact_match=False)
    assert not fresh.pretrained  # the ensemble is not fitted yet
    obs = pendulum_demos.observations[:30]
    expected = trained.predict(obs, deterministic=True)[0]
    _forbid(fresh, clone=True)
    info = fresh.pretrain()
    assert "ensemble_loss" in info and "bc_nll_after" not in info
    assert fresh.pretrained
    assert np.array_equal(fresh.predict(obs, deterministic=True)[0], expected)


def test_pretrained_is_settable_and_saved(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    model.learn(64)
    assert model.pretrained
    model.save(tmp_path / "a.zip")
    loaded = CMZDRIL.load(tmp_path / "a.zip", env=gym.make("Pendulum-v1"))
    assert loaded.pretrained
    _forbid(loaded, clone=True, fit=True)
    loaded.learn(64, reset_num_timesteps=False)
    # weights put in by hand: the user says they are pretrained
    by_hand = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "seed": 3})
    by_hand.policy.load_state_dict(model.policy.state_dict())
    by_hand.ensemble.load_state_dict(model.ensemble.state_dict())
    by_hand.pretrained = True
    _forbid(by_hand, clone=True, fit=True)
    by_hand.learn(64)
    # False: the next learn pretrains and refits from the start
    model.pretrained = False
    assert not model.pretrained
    calls = []
    fit = model.ensemble.fit
    model.ensemble.fit = lambda *a, **k: calls.append(1) or fit(*a, **k)
    info = model.pretrain()
    assert calls == [1] and "bc_nll_after" in info and model.pretrained


def test_pretrain_keys_reach_tensorboard_on_the_first_learn(pendulum_demos, tmp_path):
    pytest.importorskip("tensorboard", reason="tensorboard is in the test extra")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, tensorboard_log=str(tmp_path), **TINY)
    model.learn(64, tb_log_name="run")
    events = EventAccumulator(str(tmp_path / "run_1"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {"pretrain/bc_nll_after", "pretrain/ensemble_loss"} <= tags
    model.learn(64, tb_log_name="run", reset_num_timesteps=False)  # logged once, not again
    assert model._pretrain_log_pending is False


def test_progress_bar_total_is_the_steps_learn_takes(pendulum_demos, monkeypatch):
    import sb3_cmzdril.cmzdril.cmzdril as algorithm

    bars = []

    class Bar:
        def __init__(self, total):
            self.total, self.n = total, 0
            bars.append(self)

        def update(self, n):
            self.n += n

        def refresh(self):
            pass

        def close(self):
            pass

    monkeypatch.setattr(algorithm, "tqdm", Bar)
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    model.learn(100, progress_bar=True)  # PPO collects whole rollouts of 64 steps: 128
    assert [(b.total, b.n) for b in bars] == [(128, 128)]


def test_mujoco_warnings_are_routed_only_while_the_library_works(pendulum_demos, tmp_path, monkeypatch, capfd):
    mujoco = pytest.importorskip("mujoco")
    monkeypatch.chdir(tmp_path)
    # A CLI test run in this process before may have installed the command line's process-wide
    # handler: start from MuJoCo's default, as a user's program does, and leave theirs as it was.
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(None)
    try:
        _check_mujoco_warnings_routed(mujoco, pendulum_demos, tmp_path, capfd)
    finally:
        mujoco.set_mju_user_warning(previous)


def _check_mujoco_warnings_routed(mujoco, pendulum_demos, tmp_path, capfd) -> None:
    seen = []

    class Handler(BaseCallback):
        def _on_step(self) -> bool:
            seen.append(mujoco.get_mju_user_warning())
            return True

    model = CMZDRIL("MlpPolicy", "HalfCheetah-v5", demonstrations=None, **TINY)  # compiles the model: settotalmass
    assert model.env is not None
    pendulum = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    pendulum.learn(64, callback=Handler())
    assert seen and all(h is not None for h in seen)  # rollouts step with the handler in place
    assert mujoco.get_mju_user_warning() is None  # and MuJoCo's default is back afterwards
    assert "settotalmass" not in capfd.readouterr().err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize(
    ("reward", "limit", "absorbing", "expected"),
    [
        ("cmz", 100, "auto", True),  # every demo lasts the time limit: the expert never terminates
        # the demos are shorter than the limit (the expert may end its own episodes), and the barely trained
        # clone drops the pole long before they end: its ends are falls
        ("cmz", 500, "auto", True),
        ("dril", 100, "auto", False),  # "auto" leaves the baselines as defined
        ("dril", 100, True, True),
        ("cmz", 100, False, False),  # the paper's
    ],
)
def test_absorbing_auto_is_on_where_the_expert_never_terminates(
    cartpole_demos, tmp_path, reward, limit, absorbing, expected
):
    assert np.all(cartpole_demos.episode_lengths == 100)  # the expert holds the pole for all recorded steps
    env = gym.make("CartPole-v1", max_episode_steps=limit)
    model = CMZDRIL("MlpPolicy", env, demonstrations=cartpole_demos,
                    **{**TINY, **PAPER, "reward": reward, "absorbing": absorbing})
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(64)
    assert model.absorbing_active is expected
    assert (model.absorbing_u > 0) is expected
    if limit == 500:
        assert model.clone_ends[0] < 50 and model.rules["absorbing"]["reason"].endswith("the clone falls")
    with open(tmp_path / "progress.csv") as f:
        logged = next(csv.DictReader(f))
    assert ("rollout/absorbing_u" in logged) is expected  # what a fall costs, in the run's logs
    if expected:
        assert float(logged["rollout/absorbing_u"]) == pytest.approx(model.absorbing_u)
    assert bool(model.rollout_buffer.rewards.min() < -5.0) is expected  # a fall within 64 steps costs ~99 steps' reward


@pytest.mark.slow
@pytest.mark.parametrize(
    ("reward", "score", "normalize"),
    [("cmz", "highest", False), ("dril", "highest", False), ("cmz", "terminal", False), ("cmz", "terminal", True)],
)
def test_absorbing_state_is_the_same_scored_per_step_or_from_the_buffer(reward, score, normalize, cartpole_demos):
    # Under VecNormalize the buffer path gets the terminal observation normalised and undoes it; the
    # wrapper below VecNormalize sees it raw.
    def env():
        venv = DummyVecEnv([lambda: gym.make("CartPole-v1", max_episode_steps=100)] * 2)
        return VecNormalize(venv, norm_reward=False) if normalize else venv

    batch = _rollout_of(env, cartpole_demos, reward=reward, absorbing=True, absorbing_score=score)
    step = _rollout_of(env, cartpole_demos, reward=reward, absorbing=True, absorbing_score=score, batch_scoring=False)
    assert batch.absorbing_u == pytest.approx(step.reward_wrapper().absorbing_u, rel=1e-6)
    _assert_same_rollouts(batch, step)
    if score == "terminal":
        highest = _rollout_of(env, cartpole_demos, reward=reward, absorbing=True)
        assert not np.allclose(highest.rollout_buffer.rewards, batch.rollout_buffer.rewards)


def test_a_termination_can_be_scored_at_the_u_of_the_observation_it_ended_in(pendulum_demos):
    # DRIL's quadratic disagreement needs actions: at the observation an episode ended in, the policy's own.
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, absorbing=True,
                    absorbing_score="terminal", disagreement="quadratic", **TINY)
    assert model._terminal_disagreement() is None  # nothing is scored before learn() resolves `absorbing`
    model.learn(64)
    score = model._terminal_disagreement()
    ended_in = pendulum_demos.observations[3:7]
    actions, _ = model.policy.predict(ended_in, deterministic=True)
    np.testing.assert_allclose(score(ended_in), model.ensemble.disagreement(ended_in, actions), rtol=1e-6)
    other = np.clip(actions + 1.0, -2.0, 2.0)
    assert not np.allclose(model.ensemble.disagreement(ended_in, other), score(ended_in))  # the action counts


def test_cmz_clip_quantile_clips_u_at_the_demos_quantile_and_survives_save_load(pendulum_demos, tmp_path):
    with pytest.raises(ValueError, match=r"cmz_clip_quantile must lie in \(0, 1\], be None or 'auto'"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, cmz_clip_quantile=1.5)
    plain = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    plain.pretrain()
    assert plain.cmz_u_max is None and plain.reward_rule.u_max is None
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, cmz_clip_quantile=0.9, **TINY)
    model.learn(64)
    u = model.ensemble.disagreement(pendulum_demos.observations, pendulum_demos.actions)
    assert model.cmz_u_max == pytest.approx(np.quantile(u, 0.9), rel=1e-5)
    assert model.reward_rule.u_max == model.cmz_u_max
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip")
    assert loaded.cmz_clip_quantile == 0.9 and loaded.cmz_u_max == model.cmz_u_max
    assert loaded.reward_rule.u_max == model.cmz_u_max


def test_auto_disagreement_chooses_from_the_demonstrations_and_survives_save_load(pendulum_demos, tmp_path):
    # A bang-bang expert (every action on a bound) gets u on the members' unclipped actions.
    bang_bang = Demonstrations(pendulum_demos.observations, np.where(pendulum_demos.actions >= 0, 2.0, -2.0),
                               pendulum_demos.episode_lengths)
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=bang_bang, disagreement="auto", **TINY)
    model.pretrain()
    assert model.ensemble.disagreement_form == "std_unclipped"
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip")
    assert loaded.disagreement == "auto" and loaded.ensemble.disagreement_form == "std_unclipped"
    far = pendulum_demos.observations[:4] * 50.0
    np.testing.assert_array_equal(loaded.ensemble.disagreement(far), model.ensemble.disagreement(far))
    # Members' weights loaded by hand, without the flags fit() sets: `pretrained = True` makes the same
    # choice from the demonstrations.
    by_hand = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=bang_bang, disagreement="auto", **TINY)
    weights = {k: v for k, v in model.ensemble.state_dict().items() if k not in ("fitted", "unclipped")}
    by_hand.ensemble.load_state_dict(weights, strict=False)
    assert by_hand.ensemble.disagreement_form == "std"
    by_hand.pretrained = True
    assert by_hand.ensemble.disagreement_form == "std_unclipped"
    np.testing.assert_array_equal(by_hand.ensemble.disagreement(far), model.ensemble.disagreement(far))
    inside = Demonstrations(pendulum_demos.observations, np.clip(pendulum_demos.actions, -1.9, 1.9),
                            pendulum_demos.episode_lengths)
    smooth = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=inside, disagreement="auto", **TINY)
    smooth.pretrain()
    assert smooth.ensemble.disagreement_form == "std"


def test_cmz_clip_at_zero_disagreement_names_the_option(pendulum_demos, monkeypatch):
    # an ensemble agreeing exactly on most demo steps puts the quantile at 0: every state would score alike
    monkeypatch.setattr("sb3_cmzdril.common.imitation.quantile_of_disagreement", lambda *args: 0.0)
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, cmz_clip_quantile=0.5, **TINY)
    with pytest.raises(ValueError, match=r"cmz_clip_quantile=0.5 clips u at 0, .* choose a higher quantile or None"):
        model.pretrain()


def test_absorbing_errors_and_save_load(cartpole_demos, tmp_path):
    with pytest.raises(ValueError, match="absorbing must be True, False or 'auto'"):
        CMZDRIL("MlpPolicy", "CartPole-v1", demonstrations=cartpole_demos, absorbing="yes")
    with pytest.raises(ValueError, match="absorbing_score must be 'highest' or 'terminal', got 'lowest'"):
        CMZDRIL("MlpPolicy", "CartPole-v1", demonstrations=cartpole_demos, absorbing_score="lowest")
    assert CMZDRIL("MlpPolicy", "CartPole-v1", demonstrations=cartpole_demos).absorbing == "auto"  # the default
    env = gym.make("CartPole-v1", max_episode_steps=100)
    model = CMZDRIL("MlpPolicy", env, demonstrations=cartpole_demos, absorbing="auto", absorbing_score="terminal",
                    **TINY)
    model.learn(64)
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip")
    assert loaded.absorbing == "auto" and loaded.absorbing_u == model.absorbing_u > 0
    assert loaded.absorbing_score == "terminal"
