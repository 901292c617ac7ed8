"""CMZDRIL as a drop-in for PPO across the spaces and policies PPO takes (issue 22).

Every observation space (Box of any shape and dtype, Discrete, MultiDiscrete, MultiBinary, Dict,
images), every action space (Box, Box (2, 2), Discrete, Discrete with a start, MultiDiscrete,
MultiBinary), CnnPolicy, MultiInputPolicy, a user's features extractor, VecNormalize on Dict
observations, SubprocVecEnv, set_parameters, collect_rollouts right after _setup_learn, and batch norm
in train/eval mode. Demonstrations are recorded in the test from a tiny env.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, CombinedExtractor, NatureCNN
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

from helpers import TINY
from sb3_cmzdril import CMZDRIL, BCEnsemble, Demonstrations
from sb3_cmzdril.common.imitation import buffer_actions
from sb3_cmzdril.data.spaces import ObsEncoder, reshape_rows
from sb3_cmzdril.policies import DemoStandardizer, observation_statistics

VEC = spaces.Box(-1.0, 1.0, (4,), np.float32)

ACTION_SPACES: dict[str, spaces.Space] = {
    "box": spaces.Box(-1.0, 1.0, (2,), np.float32),
    "box2x2": spaces.Box(-1.0, 1.0, (2, 2), np.float32),
    "discrete": spaces.Discrete(3),
    "discrete_start1": spaces.Discrete(3, start=1),
    "multidiscrete": spaces.MultiDiscrete([2, 3]),
    "multibinary": spaces.MultiBinary(3),
}

OBS_SPACES: dict[str, spaces.Space] = {
    "box_float64": spaces.Box(-1.0, 1.0, (3,), np.float64),
    "box_2d": spaces.Box(-1.0, 1.0, (2, 3), np.float32),
    "discrete": spaces.Discrete(5),
    "multidiscrete": spaces.MultiDiscrete([3, 2]),
    "multibinary": spaces.MultiBinary(4),
    "dict": spaces.Dict({"pos": spaces.Box(-1.0, 1.0, (2,), np.float32), "mode": spaces.Discrete(3)}),
}

# 36 pixels: the smallest NatureCNN (CnnPolicy's extractor) takes.
IMAGE = spaces.Box(0, 255, (36, 36, 1), np.uint8)



class SpacesEnv(gym.Env):
    """Observations drawn from the space, reward 0, episodes of ``length`` steps."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, length: int = 16) -> None:
        self.observation_space = observation_space
        self.action_space = action_space
        self.length = length
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self.observation_space.seed(int(self.np_random.integers(2**31)))
        self._t = 0
        return self.observation_space.sample(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._t += 1
        return self.observation_space.sample(), 0.0, False, self._t >= self.length, {}


def expert_for(space: spaces.Space) -> Callable[[np.ndarray], Any]:
    """A deterministic expert on VEC observations, for each action space."""

    def act(obs: np.ndarray) -> Any:
        if isinstance(space, spaces.Box):
            return np.tanh(obs[: int(np.prod(space.shape))] * 2).reshape(space.shape).astype(np.float32)
        if isinstance(space, spaces.Discrete):
            return int(space.start) + int(np.digitize(obs[0], [-0.33, 0.33]))
        if isinstance(space, spaces.MultiDiscrete):
            return np.array([int(obs[0] > 0), int(np.digitize(obs[1], [-0.33, 0.33]))])
        return (obs[:3] > 0).astype(np.int8)

    return act


def record(env: gym.Env, policy: Callable[[Any], Any] | None = None, n_episodes: int = 4) -> Demonstrations:
    episodes = []
    env.action_space.seed(0)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=i)
        o, a = [], []
        done = False
        while not done:
            act = policy(obs) if policy is not None else env.action_space.sample()
            o.append(obs)
            a.append(act)
            obs, _, terminated, truncated, _ = env.step(act)
            done = terminated or truncated
        obs_arr: Any = {k: np.stack([x[k] for x in o]) for k in o[0]} if isinstance(o[0], dict) else np.stack(o)
        episodes.append({"observations": obs_arr, "actions": np.stack([np.asarray(x) for x in a])})
    return Demonstrations.from_episodes(episodes)


def rollout_u(model: CMZDRIL) -> float:
    """The rollout's mean disagreement recomputed from the buffer, independently of the scorer."""
    buf = model.rollout_buffer
    rows = buf.buffer_size * buf.n_envs
    obs = reshape_rows(buf.observations, (rows,), model.observation_space)
    actions = buffer_actions(buf.actions.reshape(rows, -1), model.action_space)
    return float(model.ensemble.disagreement(obs, actions).mean())


# -- the ensemble on its own ------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(ACTION_SPACES))
def test_ensemble_clones_an_expert_in_every_action_space(name):
    space = ACTION_SPACES[name]
    env = SpacesEnv(VEC, space, length=50)
    demos = record(env, expert_for(space), n_episodes=6)
    ens = BCEnsemble(VEC, space, n_members=3, hidden_sizes=(32,), seed=0).fit(demos, n_epochs=60, learning_rate=3e-3)
    pred = ens.predict(demos.observations)
    assert pred.shape == demos.actions.shape
    if isinstance(space, spaces.Box):
        assert np.mean((pred - demos.actions) ** 2) < 0.05
    else:
        assert np.mean(pred == demos.actions) > 0.85  # the start of Discrete(3, start=1) included
    u = ens.disagreement(demos.observations, demos.actions)
    assert u.shape == (len(demos),) and np.all(u >= 0)
    # one observation, the per-step path, gives the same u as the batch
    np.testing.assert_allclose(ens.disagreement(demos.observations[3], demos.actions[3:4]), u[3:4], rtol=1e-4)


def test_multidiscrete_and_multibinary_disagreement_is_the_sum_over_components():
    obs = np.random.default_rng(0).uniform(-1, 1, (64, 4)).astype(np.float32)
    md = ACTION_SPACES["multidiscrete"]
    ens = BCEnsemble(VEC, md, 4, (8,), seed=1).fit(Demonstrations(obs, np.tile([1, 2], (64, 1)), [64]), n_epochs=2)
    probs = ens.member_outputs(obs[:5]).copy()  # (E, 5, 2 + 3)
    acts = np.array([[0, 1], [1, 2], [0, 0], [1, 1], [0, 2]])
    expected = probs[:, np.arange(5), acts[:, 0]].std(0) + probs[:, np.arange(5), 2 + acts[:, 1]].std(0)
    np.testing.assert_allclose(ens.disagreement(obs[:5], acts), expected, rtol=1e-5)
    mb = ACTION_SPACES["multibinary"]
    ens = BCEnsemble(VEC, mb, 4, (8,), seed=1).fit(Demonstrations(obs, np.ones((64, 3), np.int8), [64]), n_epochs=2)
    probs = ens.member_outputs(obs[:5]).copy()
    assert not ens.needs_actions
    np.testing.assert_allclose(ens.disagreement(obs[:5]), probs.std(0).sum(1), rtol=1e-5)


@pytest.mark.parametrize("name", [*OBS_SPACES, "image"])
def test_the_ensemble_encodes_observations_as_sb3_preprocesses_them(name):
    space = IMAGE if name == "image" else OBS_SPACES[name]
    encoder = ObsEncoder(space)
    space.seed(0)
    batch = [space.sample() for _ in range(6)]
    dict_space = isinstance(space, spaces.Dict)
    obs: Any = {k: np.stack([b[k] for b in batch]) for k in batch[0]} if dict_space else np.stack(batch)
    tensors: Any = {k: th.as_tensor(v) for k, v in obs.items()} if isinstance(obs, dict) else th.as_tensor(obs)
    sb3 = preprocess_obs(tensors, space)
    if name == "image":
        np.testing.assert_allclose(encoder.images(obs)[0], sb3.permute(0, 3, 1, 2).cpu().numpy(), rtol=1e-6)
        return
    parts = [sb3[k] for k in space.spaces] if isinstance(sb3, dict) else [sb3]
    expected = np.concatenate([p.reshape(6, -1).cpu().numpy() for p in parts], axis=1)
    np.testing.assert_allclose(encoder.flat(obs), expected, rtol=1e-6)


# -- CMZDRIL, every action space -------------------------------------------------------------------
@pytest.mark.parametrize("name", list(ACTION_SPACES))
def test_cmzdril_learns_and_scores_in_every_action_space(name):
    space = ACTION_SPACES[name]
    env = SpacesEnv(VEC, space)
    demos = record(env, expert_for(space))
    model = CMZDRIL("MlpPolicy", env, demonstrations=demos, **TINY)
    model.learn(64)
    assert model.rollout_disagreement == pytest.approx(rollout_u(model), rel=1e-5)
    assert np.isfinite(model.rollout_buffer.rewards).all()
    assert not np.all(model.rollout_buffer.rewards == 0)  # the shaped reward, not the env's 0
    action, _ = model.predict(demos.observations[:3], deterministic=True)
    assert action.shape[1:] == (space.shape if not isinstance(space, spaces.Discrete) else ())


def test_bc_maps_a_discrete_start_to_the_policys_indices():
    space = ACTION_SPACES["discrete_start1"]
    env = SpacesEnv(VEC, space, length=50)
    demos = record(env, expert_for(space), n_episodes=6)
    model = CMZDRIL("MlpPolicy", env, demonstrations=demos, **{**TINY, "bc_pretrain_epochs": 60})
    model.pretrain()
    index, _ = model.predict(demos.observations, deterministic=True)
    # SB3's policies output 0-based indices (PPO passes them on as they are); index k is action start + k
    assert np.mean(index + 1 == demos.actions) > 0.8


# -- CMZDRIL, every observation space and policy ---------------------------------------------------
@pytest.mark.parametrize("name", list(OBS_SPACES))
def test_cmzdril_learns_saves_and_loads_in_every_observation_space(name, tmp_path):
    space = OBS_SPACES[name]
    env = SpacesEnv(space, ACTION_SPACES["box"])
    demos = record(env)
    policy = "MultiInputPolicy" if isinstance(space, spaces.Dict) else "MlpPolicy"
    model = CMZDRIL(policy, env, demonstrations=demos, **TINY)
    model.learn(64)
    assert model.rollout_disagreement == pytest.approx(rollout_u(model), rel=1e-5)
    model.save(tmp_path / "m.zip")
    loaded = CMZDRIL.load(tmp_path / "m.zip", env=env)
    obs = demos.observations
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    np.testing.assert_array_equal(loaded.ensemble.disagreement(obs), model.ensemble.disagreement(obs))
    assert len(loaded.demonstrations) == len(demos)
    loaded.learn(32, reset_num_timesteps=False)


def test_dict_demonstrations_save_load_and_select(tmp_path):
    demos = record(SpacesEnv(OBS_SPACES["dict"], ACTION_SPACES["multidiscrete"]))
    demos.save(tmp_path / "d.npz")
    back = Demonstrations.load(tmp_path / "d.npz")
    assert set(back.observations) == {"mode", "pos"} and len(back) == len(demos) == 64
    np.testing.assert_array_equal(back.observations["pos"], demos.observations["pos"])
    one = back.select([1])
    np.testing.assert_array_equal(one.observations["mode"], demos.observations["mode"][16:32])
    assert back.check_spaces(OBS_SPACES["dict"], ACTION_SPACES["multidiscrete"]) is back
    with pytest.raises(ValueError, match=r"lack the keys \['x'\]"):
        back.check_spaces(spaces.Dict({"mode": spaces.Discrete(3), "pos": VEC, "x": VEC}), ACTION_SPACES["box"])
    with pytest.raises(ValueError, match="outside the MultiDiscrete"):
        back.check_spaces(OBS_SPACES["dict"], spaces.MultiDiscrete([2, 2]))


def test_dict_observations_standardise_their_box_entries_only():
    space = OBS_SPACES["dict"]
    demos = record(SpacesEnv(space, ACTION_SPACES["box"]))
    model = CMZDRIL("MultiInputPolicy", SpacesEnv(space, ACTION_SPACES["box"]), demonstrations=demos,
                    standardize_observations=True, **TINY)
    model.pretrain()
    ext = model.policy.features_extractor
    assert isinstance(ext, DemoStandardizer) and isinstance(ext.extractor, CombinedExtractor)
    assert ext.keys == ["pos"]
    mean, std = observation_statistics(demos.observations["pos"])
    np.testing.assert_allclose(ext.obs_mean_0.cpu().numpy(), mean, rtol=1e-6)
    # the one-hot of "mode" reaches the CombinedExtractor unchanged
    obs = {"pos": th.as_tensor(mean[None], device=model.device),
           "mode": th.tensor([[0.0, 1.0, 0.0]], device=model.device)}
    np.testing.assert_allclose(ext(obs).cpu().numpy(), [[0.0, 1.0, 0.0, 0.0, 0.0]], atol=1e-6)  # keys sorted


@pytest.mark.parametrize("vector", [False, True], ids=["CnnPolicy", "MultiInputPolicy"])
def test_images_through_a_cnn_trunk(vector, caplog):
    space: spaces.Space = spaces.Dict({"img": IMAGE, "vec": VEC}) if vector else IMAGE
    env = SpacesEnv(space, ACTION_SPACES["discrete"])
    demos = record(env, n_episodes=2)  # channel-last, as the env gives them
    policy = "MultiInputPolicy" if vector else "CnnPolicy"
    with caplog.at_level(logging.INFO, logger="sb3_cmzdril"):
        extractor_kwargs = dict(cnn_output_dim=8) if vector else dict(features_dim=8)
        policy_kwargs = dict(net_arch=[8], features_extractor_kwargs=extractor_kwargs)
        model = CMZDRIL(policy, env, demonstrations=demos, **{**TINY, "policy_kwargs": policy_kwargs})
    assert "standardize_observations" in caplog.text  # one note: skipped (images) or composed (Dict)
    assert isinstance(model.policy.features_extractor, DemoStandardizer if vector else NatureCNN)
    model.learn(64)  # SB3 transposes the env's images to channel-first; the demos follow
    assert len(model.ensemble.trunks) == 1
    assert model.rollout_disagreement == pytest.approx(rollout_u(model), rel=1e-4)


# -- PPO's other promises ------------------------------------------------------------------------
@pytest.mark.slow
def test_vecnormalize_on_dict_observations_and_subprocvecenv():
    space = OBS_SPACES["dict"]
    make = [lambda: SpacesEnv(space, ACTION_SPACES["box"])] * 2
    demos = record(make[0]())
    venv = VecNormalize(DummyVecEnv(make), norm_obs_keys=["pos"])
    model = CMZDRIL("MultiInputPolicy", venv, demonstrations=demos, **{**TINY, "standardize_observations": False})
    model.learn(64)  # the reward-normalising VecNormalize gets the per-step wrapper, below it
    assert np.isfinite(model.rollout_disagreement)
    venv = VecNormalize(DummyVecEnv(make), norm_obs_keys=["pos"], norm_reward=False)
    model = CMZDRIL("MultiInputPolicy", venv, demonstrations=demos, **{**TINY, "standardize_observations": False})
    model.learn(64)  # scored from the buffer, on the raw observations VecNormalize kept
    assert np.isfinite(model.rollout_disagreement)
    subproc = SubprocVecEnv(make)
    try:
        model = CMZDRIL("MultiInputPolicy", subproc, demonstrations=demos, **TINY)
        model.learn(64)
        assert model.rollout_disagreement == pytest.approx(rollout_u(model), rel=1e-5)
    finally:
        subproc.close()


def test_set_parameters_with_random_values_and_collect_rollouts_after_setup_learn(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **TINY)
    # SB3's own tests drive collect_rollouts themselves after _setup_learn, without learn()
    _, callback = model._setup_learn(32)
    assert model.ensemble.is_fitted
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=32)
    assert model.rollout_disagreement == pytest.approx(rollout_u(model), rel=1e-5)
    params = model.get_parameters()
    assert all(t.dtype != th.bool for state in params.values() for t in state.values() if isinstance(t, th.Tensor))
    randomised = {
        name: state if "optim" in name else {k: th.rand_like(v) for k, v in state.items()}
        for name, state in params.items()
    }
    before = model.ensemble.disagreement(pendulum_demos.observations[:5])
    model.set_parameters(randomised, exact_match=True)
    assert model.ensemble.is_fitted
    assert model.action_space == gym.make("Pendulum-v1").action_space  # the bounds are the ensemble's copies
    assert not np.allclose(model.ensemble.disagreement(pendulum_demos.observations[:5]), before)
    model.learn(32, reset_num_timesteps=False)


class BatchNormExtractor(BaseFeaturesExtractor):
    def __init__(self, observation_space: spaces.Box) -> None:
        super().__init__(observation_space, features_dim=4)
        self.net = th.nn.Sequential(th.nn.Flatten(), th.nn.Linear(int(np.prod(observation_space.shape)), 4),
                                    th.nn.BatchNorm1d(4))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations)


def test_batch_norm_is_in_eval_mode_except_while_training(pendulum_demos):
    kwargs = {**TINY, "policy_kwargs": dict(net_arch=[8], features_extractor_class=BatchNormExtractor)}
    # without NLL epochs too: the last update, not the last epoch, leaves the policy in eval mode
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_epochs_per_update=0, **kwargs)
    ext = model.policy.features_extractor
    assert isinstance(ext, DemoStandardizer) and isinstance(ext.extractor, BatchNormExtractor)  # composed
    model.learn(64)
    bn = ext.net[2]  # the wrapped extractor's attributes are reachable on the wrapper
    assert not model.policy.training
    stats = bn.running_mean.clone()
    model.predict(pendulum_demos.observations[:10])
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, n_rollout_steps=32)
    assert th.equal(bn.running_mean, stats)  # acting never updates batch-norm statistics
    model.bc.epoch()
    assert not th.equal(bn.running_mean, stats) and not model.policy.training  # BC trains, then back to eval
