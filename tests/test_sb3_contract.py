"""CMZDRIL keeps PPO's promises to an SB3 user: evaluate_policy on the training env between learns,
VecMonitor, set_env, SubprocVecEnv, callbacks (early stop, final rewards at rollout end), save with
exclude/include, seeding and device placement."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

from helpers import TINY
from sb3_cmzdril import CMZDRIL


def _pendulums(n: int = 2) -> DummyVecEnv:
    return DummyVecEnv([lambda: gym.make("Pendulum-v1")] * n)


def _expected_rollout_u(model: CMZDRIL) -> float:
    buf = model.rollout_buffer
    return float(model.ensemble.disagreement(buf.observations.reshape(-1, *buf.obs_shape)).mean())


def test_evaluate_policy_on_the_training_env_between_learns(pendulum_demos):
    model = CMZDRIL("MlpPolicy", VecMonitor(_pendulums()), demonstrations=pendulum_demos, **TINY)
    model.learn(128)
    mean, _ = evaluate_policy(model, model.get_env(), n_eval_episodes=2)
    assert mean < -100  # Pendulum's true return, not a shaped one
    model.learn(256, reset_num_timesteps=False)  # used to fail: the extra steps misaligned a side queue
    assert model.num_timesteps == 128 + 256
    assert model.rollout_disagreement == pytest.approx(_expected_rollout_u(model), rel=1e-5)


@pytest.mark.parametrize("batch_scoring", [True, False])
def test_vecmonitor_and_ep_info_see_the_true_return(pendulum_demos, batch_scoring):
    model = CMZDRIL("MlpPolicy", VecMonitor(_pendulums()), demonstrations=pendulum_demos, batch_scoring=batch_scoring,
                    **{**TINY, "n_steps": 200, "batch_size": 100})
    model.learn(400)
    returns = [info["r"] for info in model.ep_info_buffer]
    assert len(returns) == 2
    # Pendulum pays -16..0 per step: 200 true rewards sum to well below zero; the shaped reward
    # (alpha * (u - ubar), mean zero) or the reward 0 of a batch-scored step would not.
    assert all(r < -100 for r in returns)


def test_callbacks_see_final_rewards_at_rollout_end_and_can_stop(pendulum_demos):
    seen = {}

    class Watch(BaseCallback):
        def _on_step(self) -> bool:
            seen.setdefault("step_reward", float(self.locals["rewards"][0]))
            return True

        def _on_rollout_end(self) -> None:
            seen["rollout_end"] = self.model.rollout_buffer.rewards.copy()

    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    model.learn(64, callback=Watch())
    np.testing.assert_array_equal(seen["rollout_end"], model.rollout_buffer.rewards)
    assert seen["step_reward"] < -0.5  # during the rollout, a step callback sees the env's reward
    assert np.abs(seen["rollout_end"]).max() < 5  # at its end, the shaped one (10 * |u - ubar|, u < 0.5)

    class StopAt(BaseCallback):
        def _on_step(self) -> bool:
            return self.n_calls < 10

    model.learn(640, callback=StopAt(), reset_num_timesteps=False)
    assert model.num_timesteps == 64 + 10
    model.learn(64, reset_num_timesteps=False)  # a stopped rollout leaves nothing behind
    assert model.rollout_disagreement == pytest.approx(_expected_rollout_u(model), rel=1e-5)


@pytest.mark.slow
def test_set_env_and_subprocvecenv(pendulum_demos):
    model = CMZDRIL("MlpPolicy", _pendulums(), demonstrations=pendulum_demos, **TINY)
    model.learn(128)
    venv = SubprocVecEnv([lambda: gym.make("Pendulum-v1")] * 2)
    try:
        model.set_env(venv)
        model.learn(256, reset_num_timesteps=False)
        assert model.num_timesteps == 128 + 256
        assert model.rollout_disagreement == pytest.approx(_expected_rollout_u(model), rel=1e-5)
    finally:
        venv.close()


def test_save_with_exclude_and_include(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, alpha=3.0, **TINY)
    model.learn(64)
    model.save(tmp_path / "a.zip", exclude=["alpha"], include=["rollout_disagreement"])
    loaded = CMZDRIL.load(tmp_path / "a.zip", env=gym.make("Pendulum-v1"))
    assert loaded.alpha == 10.0  # excluded: the constructor's default
    assert loaded.rollout_disagreement == model.rollout_disagreement
    obs = pendulum_demos.observations[:10]
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    loaded.learn(64, reset_num_timesteps=False)


def test_seed_none_draws_from_the_global_rng(pendulum_demos):
    def ensemble_weights(global_seed: int) -> np.ndarray:
        np.random.seed(global_seed)
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "seed": None})
        return model.ensemble.weights[0].detach().cpu().numpy().copy()

    assert np.array_equal(ensemble_weights(1), ensemble_weights(1))
    assert not np.array_equal(ensemble_weights(1), ensemble_weights(2))  # not a fixed seed 0


def test_everything_lives_on_the_model_device(pendulum_demos):
    devices = ["cpu"] + (["cuda"] if th.cuda.is_available() else [])
    for device in devices:
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "device": device})
        model.learn(64)
        assert {p.device.type for p in model.ensemble.parameters()} == {model.device.type}
        assert {b.device.type for b in model.ensemble.buffers()} == {model.device.type}
        assert model.ensemble.disagreement(pendulum_demos.observations[:100]).shape == (100,)  # the torch path
