"""The policy's observation standardisation from demo statistics (sb3_cmzdril.policies)."""
from __future__ import annotations

import logging
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from helpers import TINY
from sb3_cmzdril import CMZDRIL
from sb3_cmzdril.policies import MIN_OBS_STD, DemoStandardizer, observation_statistics


def test_statistics_are_the_demos_with_a_floored_std():
    obs = np.array([[0.0, 5.0, 1.0], [2.0, 5.0, 3.0]], np.float32)
    mean, std = observation_statistics(obs)
    np.testing.assert_allclose(mean, [1.0, 5.0, 2.0])
    np.testing.assert_allclose(std, [1.0, MIN_OBS_STD, 1.0])  # the constant dimension is floored
    with pytest.raises(ValueError, match="zero observations"):
        observation_statistics(np.zeros((0, 3)))


def test_standardizer_forward_and_bad_statistics():
    ext = DemoStandardizer(gym.spaces.Box(-1, 1, (2,), np.float32))
    x = th.tensor([[1.0, 2.0]])
    assert th.equal(ext(x), x)  # identity until set
    ext.set_statistics(np.array([1.0, 0.0]), np.array([2.0, 4.0]))
    np.testing.assert_allclose(ext(x).cpu().numpy(), [[0.0, 0.5]])
    with pytest.raises(ValueError, match="positive std"):
        ext.set_statistics(np.zeros(2), np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="2 observation dimensions"):
        ext.set_statistics(np.zeros(3), np.ones(3))


def test_policy_sees_demo_standardised_inputs_that_survive_save_load(pendulum_demos, tmp_path):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, standardize_observations=True, **TINY)
    model.pretrain()
    ext = model.policy.features_extractor
    assert isinstance(ext, DemoStandardizer)
    mean, std = observation_statistics(pendulum_demos.observations)
    np.testing.assert_allclose(ext.obs_mean.cpu().numpy(), mean, rtol=1e-6)
    np.testing.assert_allclose(ext.obs_std.cpu().numpy(), std, rtol=1e-6)
    # the ensemble standardises with the very same statistics
    np.testing.assert_allclose(model.ensemble.obs_mean.cpu().numpy(), mean, rtol=1e-6)
    np.testing.assert_allclose(model.ensemble.obs_std.cpu().numpy(), std, rtol=1e-6)
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip")
    np.testing.assert_array_equal(loaded.policy.features_extractor.obs_mean.cpu().numpy(), ext.obs_mean.cpu().numpy())
    obs = pendulum_demos.observations[:50] * 1.1
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


def test_switched_off_the_policy_sees_raw_observations(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, standardize_observations=False, **TINY)
    model.pretrain()
    assert type(model.policy.features_extractor) is FlattenExtractor
    obs = th.as_tensor(pendulum_demos.observations[:5], device=model.device)
    assert th.equal(model.policy.extract_features(obs, model.policy.features_extractor), obs)


def test_a_users_extractor_is_composed_and_vecnormalize_wins(pendulum_demos, caplog):
    kwargs = {**TINY, "policy_kwargs": {"features_extractor_class": FlattenExtractor, "net_arch": [8]}}
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **kwargs)
    ext = model.policy.features_extractor
    assert isinstance(ext, DemoStandardizer) and type(ext.extractor) is FlattenExtractor
    assert not caplog.records  # flattening is what MlpPolicy does anyway: nothing to note
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]), norm_reward=False)
    model = CMZDRIL("MlpPolicy", venv, demonstrations=pendulum_demos, standardize_observations=True, **TINY)
    with pytest.warns(UserWarning, match="VecNormalize normalises the observations already"):
        model.pretrain()
    assert float(model.policy.features_extractor.obs_std.min()) == 1.0  # left as the identity
    # the default's rule decides the same without a warning, and says why
    model = CMZDRIL("MlpPolicy", venv, demonstrations=pendulum_demos, **TINY)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.pretrain()
    assert model.rules["standardize_observations"] == {
        "value": False, "reason": "a VecNormalize normalises the observations already: the policy sees its inputs"}
    assert float(model.policy.features_extractor.obs_std.min()) == 1.0


def test_statistics_of_every_standardizer_when_actor_and_critic_do_not_share(pendulum_demos):
    kwargs = {**TINY, "standardize_observations": True,
              "policy_kwargs": {"share_features_extractor": False, "net_arch": [8]}}
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **kwargs)
    model.pretrain()
    mean, _ = observation_statistics(pendulum_demos.observations)
    for ext in (model.policy.pi_features_extractor, model.policy.vf_features_extractor):
        np.testing.assert_allclose(ext.obs_mean.cpu().numpy(), mean, rtol=1e-6)
