"""CMZDRILSAC, the off-policy learner: replayed rewards, the demo-mixing buffer, BC of a SAC actor,
save/load, and the refusals."""
from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import DummyVecEnv

from helpers import TINY, TINY_SAC
from sb3_cmzdril import CMZDRIL, CMZReward, Demonstrations, DRILReward, UserError
from sb3_cmzdril.cmzdril_sac.cmzdril_sac import CMZDRILSAC, ScaledActionMSE
from sb3_cmzdril.cmzdril_sac.demo_replay import DemoReplayBuffer, DemoTransitions
from sb3_cmzdril.rewards import EnvReward, ZeroReward
from sb3_cmzdril.selection import LongestEpisodesPolicy, kept_check

#: A CMZDRILSAC whose learn() calls take a second: TINY's networks and fits, TINY_SAC's buffer.
TINY_CMZ_SAC = dict(
    TINY_SAC,
    ensemble_hidden=TINY["ensemble_hidden"],
    ensemble_epochs=TINY["ensemble_epochs"],
    bc_pretrain_epochs=TINY["bc_pretrain_epochs"],
    bc_batch_size=32,
    seed=0,
    device="cpu",
)


def tiny_model(demos: Demonstrations, **kwargs) -> CMZDRILSAC:
    return CMZDRILSAC("MlpPolicy", "Pendulum-v1", demonstrations=demos, **{**TINY_CMZ_SAC, **kwargs})


# -- rewards of replayed transitions ------------------------------------------------------------------
def test_cmz_replayed_reward_is_measured_against_the_mean_ema_and_leaves_it_alone():
    rule = CMZReward(alpha=10.0, ema=0.9)
    rule.set_state(np.array([0.2, 0.4]))
    rewards = rule.replayed(np.array([0.1, 0.5, 0.3]), np.zeros(3))
    np.testing.assert_allclose(rewards, [2.0, -2.0, 0.0], atol=1e-6)  # -10 * (u - 0.3)
    np.testing.assert_array_equal(rule.get_state(), [0.2, 0.4])


def test_cmz_replayed_reward_starts_from_u0_and_clips_like_the_rule():
    rule = CMZReward(alpha=2.0, u0=0.1, u_max=0.5)
    np.testing.assert_allclose(rule.replayed(np.array([0.1, 0.9]), np.zeros(2)), [0.0, -0.8], atol=1e-6)
    assert rule.get_state().size == 0


def test_stateless_rules_replay_as_they_score():
    u, env_rewards = np.array([0.1, 0.3]), np.array([5.0, -1.0])
    np.testing.assert_array_equal(DRILReward(threshold=0.2).replayed(u, env_rewards), [1.0, -1.0])
    np.testing.assert_array_equal(ZeroReward().replayed(u, env_rewards), [0.0, 0.0])
    np.testing.assert_array_equal(EnvReward().replayed(u, env_rewards), [5.0, -1.0])


# -- demonstrations as transitions ----------------------------------------------------------------------
def _two_episodes() -> Demonstrations:
    obs = np.arange(10, dtype=np.float32).reshape(5, 2)
    actions = np.array([[-2.0], [0.0], [1.0], [2.0], [4.0]], dtype=np.float32)
    return Demonstrations(obs, actions, [3, 2], rewards=np.arange(5, dtype=np.float32))


def test_demo_transitions_pair_consecutive_steps_within_an_episode_only():
    demos = DemoTransitions(_two_episodes(), lambda a: a / 2.0)
    # Episode 1 is steps 0-2, episode 2 steps 3-4: last steps 2 and 4 have no next observation.
    np.testing.assert_array_equal(demos.observations, [[0, 1], [2, 3], [6, 7]])
    np.testing.assert_array_equal(demos.next_observations, [[2, 3], [4, 5], [8, 9]])
    np.testing.assert_array_equal(demos.actions, [[-1.0], [0.0], [1.0]])  # scaled, clipped to [-1, 1]
    np.testing.assert_array_equal(demos.rewards, [0.0, 1.0, 3.0])
    assert len(demos) == 3 and demos.has_rewards


def test_demo_transitions_refuse_single_step_episodes():
    demos = Demonstrations(np.zeros((2, 2)), np.zeros((2, 1)), [1, 1])
    with pytest.raises(UserError, match="single step"):
        DemoTransitions(demos, lambda a: a)


# -- the buffer ------------------------------------------------------------------------------------------
def _buffer(n: int = 6) -> DemoReplayBuffer:
    obs_space = gym.spaces.Box(-100, 100, (2,), np.float32)
    act_space = gym.spaces.Box(-1, 1, (1,), np.float32)
    buffer = DemoReplayBuffer(50, obs_space, act_space, device="cpu")
    for i in range(n):
        truncated = i == 4
        buffer.add(
            np.full((1, 2), i, np.float32), np.full((1, 2), i + 1, np.float32), np.array([[0.5]]),
            np.array([float(i)]), np.array([i in (3, 4)]), [{"TimeLimit.truncated": truncated}],
        )
    return buffer


def test_buffer_mixes_the_demo_share_into_each_batch_and_relabels_raw_transitions():
    buffer = _buffer()
    seen = {}

    def relabel(obs, actions, env_rewards, terminated, next_obs, scored):
        seen.update(obs=obs, terminated=terminated, env_rewards=env_rewards, next_obs=next_obs)
        return obs[:, 0] * 10.0

    demos = DemoTransitions(_two_episodes(), lambda a: a / 2.0)
    buffer.set_demonstrations(demos, 0.25, relabel)
    np.random.seed(0)
    batch = buffer.sample(8)
    assert batch.observations.shape == (8, 2) and batch.rewards.shape == (8, 1) and batch.dones.shape == (8, 1)
    demo_rows = seen["obs"][6:]  # the last round(0.25 * 8) = 2 rows are the expert's
    assert all(row.tolist() in demos.observations.tolist() for row in demo_rows)
    assert all(row[0] == row[1] and row[0] < 6 for row in seen["obs"][:6])  # the agent's stored steps
    np.testing.assert_array_equal(seen["next_obs"][:6], seen["obs"][:6] + 1)  # raw, each its own step's
    np.testing.assert_allclose(batch.rewards[:, 0].numpy(), seen["obs"][:, 0] * 10.0)
    # Step 3 terminated, step 4 was cut by the time limit: only the termination is a done.
    agent = seen["obs"][:6, 0]
    np.testing.assert_array_equal(seen["terminated"][:6], agent == 3)
    assert not seen["terminated"][6:].any()
    np.testing.assert_array_equal(batch.dones[:, 0].numpy(), (seen["obs"][:, 0] == 3) & (np.arange(8) < 6))


def test_buffer_hands_relabel_the_disagreement_each_step_was_stored_with():
    buffer = _buffer(3)  # three steps stored without one
    for i in range(3, 6):
        buffer.add(np.full((1, 2), i, np.float32), np.full((1, 2), i + 1, np.float32), np.array([[0.5]]),
                   np.array([0.0]), np.array([False]), [{"disagreement": i / 10}])
    demos = DemoTransitions(_two_episodes(), lambda a: a / 2.0)
    demos.disagreements = np.array([7.0, 8.0, 9.0])  # as a learner sets them, one per transition
    seen = {}

    def relabel(obs, actions, env_rewards, terminated, next_obs, scored):
        seen.update(obs=obs, scored=scored)
        return np.zeros(len(obs))

    buffer.set_demonstrations(demos, 0.25, relabel)
    np.random.seed(1)
    buffer.sample(40)
    step, scored = seen["obs"][:30, 0], seen["scored"][:30]
    assert np.isnan(scored[step < 3]).all() and (step < 3).any()
    np.testing.assert_allclose(scored[step >= 3], step[step >= 3] / 10)
    rows = [demos.observations.tolist().index(row) for row in seen["obs"][30:].tolist()]
    np.testing.assert_array_equal(seen["scored"][30:], demos.disagreements[rows])


def test_buffer_without_demos_or_relabel_samples_the_stored_rewards():
    buffer = _buffer()
    buffer.set_demonstrations(None, 0.5, None)
    batch = buffer.sample(16)
    np.testing.assert_array_equal(batch.rewards[:, 0].numpy(), batch.observations[:, 0].numpy())
    assert isinstance(buffer, ReplayBuffer)


def test_buffer_refuses_a_share_of_one_or_more():
    with pytest.raises(UserError, match="demo_fraction"):
        _buffer().set_demonstrations(None, 1.0, None)


# -- BC of a SAC actor ----------------------------------------------------------------------------------
def test_scaled_action_mse_compares_in_the_squashed_scale():
    space = gym.spaces.Box(np.array([-2.0, 0.0], np.float32), np.array([2.0, 4.0], np.float32))
    loss = ScaledActionMSE(space, th.device("cpu"))

    def actor(obs, deterministic):
        assert deterministic
        return th.tensor([[0.5, -1.0]])

    # Expert (1, 4) scales to (0.5, 1.0); (3, 5) clips to (1, 1).
    assert loss(actor, th.zeros(1, 3), th.tensor([[1.0, 4.0]])).item() == pytest.approx(4.0)
    assert loss(actor, th.zeros(1, 3), th.tensor([[3.0, 5.0]])).item() == pytest.approx(0.25 + 4.0)


def test_pretraining_clones_the_demos_into_the_actor(pendulum_demos):
    model = tiny_model(pendulum_demos, bc_pretrain_epochs=200, bc_patience=200, log_std_init=-1.5)
    model.bc.set_demonstrations(pendulum_demos)
    before = model.bc.nll()
    info = model.pretrain()
    assert model.pretrained and model.reward_rule is not None
    assert info["bc_loss"] < 0.5 * before
    # The log-std head outputs the constant it was given, whatever the observation.
    obs = th.as_tensor(pendulum_demos.observations[:5])
    features = model.actor.extract_features(obs, model.actor.features_extractor)
    _, log_std, _ = model.actor.get_action_dist_params(features)
    np.testing.assert_allclose(log_std.detach().numpy(), -1.5)


# -- training --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("reward", ["cmz", "dril", "zero", "env"])
def test_every_reward_learns_logs_and_advances_its_rule(reward, pendulum_demos, tmp_path):
    model = tiny_model(pendulum_demos, reward=reward)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(300, log_interval=1)
    assert model.num_timesteps == 300
    if reward == "cmz":
        state = model.reward_rule.get_state()
        assert state.shape == (1,) and 0 < state[0] < model.absorbing_u
    assert model.absorbing_u > 0
    model.logger.dump(model.num_timesteps)
    with open(tmp_path / "progress.csv") as f:
        rows = list(csv.DictReader(f))
    assert {"train/bc_loss", "rollout/disagreement_mean", "train/critic_loss"} <= set(rows[-1])


def test_replayed_rewards_of_terminations_carry_the_absorbing_value(pendulum_demos):
    model = tiny_model(pendulum_demos, absorbing=True, gamma=0.9, cmz_clip_quantile=None)  # u as it is
    model.learn(60)
    assert model.absorbing_active
    rule = model.reward_rule
    obs = pendulum_demos.observations[:2]
    actions = np.zeros((2, 1), np.float32)
    u = model.ensemble.disagreement(obs)
    rewards = model._replay_rewards(obs, actions, np.zeros(2), np.array([False, True]), obs)
    plain = rule.replayed(u, np.zeros(2))
    assert rewards[0] == pytest.approx(plain[0])
    # The terminating step also earns gamma / (1 - gamma) = 9 times the reward at the highest u seen.
    absorbing = -model.alpha * (model.absorbing_u - float(rule.get_state().mean()))
    assert rewards[1] == pytest.approx(plain[1] + 9.0 * absorbing, rel=1e-5)


@pytest.mark.parametrize("disagreement", ["std", "quadratic"])
def test_a_termination_can_be_scored_at_the_u_of_the_state_it_ended_in(pendulum_demos, disagreement):
    model = tiny_model(pendulum_demos, absorbing=True, absorbing_score="terminal", gamma=0.9,
                       disagreement=disagreement)
    model.learn(60)
    rule = model.reward_rule
    obs, ended_in = pendulum_demos.observations[:2], pendulum_demos.observations[5:7]
    buffer_actions = np.array([[0.5], [-0.5]], np.float32)
    rewards = model._replay_rewards(obs, buffer_actions, np.zeros(2), np.array([False, True]), ended_in)
    actions = model.policy.unscale_action(buffer_actions)
    u = model.ensemble.disagreement(obs, actions if model.ensemble.needs_actions else None)
    plain = rule.replayed(u, np.zeros(2))
    assert rewards[0] == pytest.approx(plain[0])  # no termination: the absorbing state plays no part
    # The actor's action where the episode ended, for a disagreement that needs one.
    there, _ = model.policy.predict(ended_in[1:], deterministic=True)
    u_end = model.ensemble.disagreement(ended_in[1:], there if model.ensemble.needs_actions else None)[0]
    assert u_end != pytest.approx(model.absorbing_u)  # the case differs from the highest-u rule's
    absorbing = -model.alpha * (u_end - float(rule.get_state().mean()))
    assert rewards[1] == pytest.approx(plain[1] + 9.0 * absorbing, rel=1e-5)


def _parameters(module: th.nn.Module) -> list[th.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def _same(a: list[th.Tensor], b: list[th.Tensor]) -> bool:
    return all(th.equal(x, y) for x, y in zip(a, b, strict=True))


def test_the_critics_warm_up_alone_then_the_actor_and_temperature_learn(pendulum_demos, tmp_path):
    model = tiny_model(pendulum_demos, learning_starts=10, critic_warmup_steps=40)
    model.pretrain()
    actor, critic, temperature = _parameters(model.actor), _parameters(model.critic), model.log_ent_coef.item()
    model.learn(40)  # 30 updates, all inside the warm-up
    assert model._n_updates == 30
    assert _same(_parameters(model.actor), actor) and model.log_ent_coef.item() == temperature
    assert not _same(_parameters(model.critic), critic)
    # The count survives save/load: the next 10 updates finish the warm-up, the ones after move the actor.
    model.save(tmp_path / "m.zip")
    model = CMZDRILSAC.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), device="cpu")
    model.learn(10, reset_num_timesteps=False)
    assert model._n_updates == 40 and _same(_parameters(model.actor), actor)
    model.learn(5, reset_num_timesteps=False)
    assert not _same(_parameters(model.actor), actor) and model.log_ent_coef.item() != temperature


def test_the_clone_collects_from_the_first_step(pendulum_demos):
    # With a log-std of -20 the actor's samples are its deterministic action: no uniform warm-up.
    model = tiny_model(pendulum_demos, learning_starts=1000, log_std_init=-20.0)
    model.pretrain()
    model._setup_learn(10)
    for _ in range(5):
        action, buffer_action = model._sample_action(1000)
        expected, _ = model.predict(model._last_obs, deterministic=True)
        np.testing.assert_allclose(action, expected, atol=1e-4)
        np.testing.assert_allclose(buffer_action, model.policy.scale_action(expected), atol=1e-4)


def test_gsde_draws_new_exploration_weights_for_every_gradient_step(pendulum_demos):
    # As SAC does: the weights drawn for one step hang on a graph of log_std that its actor step frees.
    model = tiny_model(pendulum_demos, use_sde=True, gradient_steps=2, learning_starts=20)
    model.learn(60)
    assert model._n_updates == 2 * 40


class _MatrixActions(gym.Env):
    """Actions are 2x2 matrices; the episode checks that each one arrives in its shape."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    action_space = gym.spaces.Box(-2.0, 2.0, (2, 2), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.uniform(-1, 1, 3).astype(np.float32), {}

    def step(self, action):
        assert np.shape(action) == (2, 2)
        self.t += 1
        return self.np_random.uniform(-1, 1, 3).astype(np.float32), 0.0, False, self.t >= 20, {}


def test_box_actions_of_any_shape_are_cloned_and_mixed_into_batches_flat():
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (40, 3)).astype(np.float32)
    actions = np.stack([np.outer(o[:2], [1.0, -1.0]) for o in obs]).astype(np.float32)  # a function of obs
    demos = Demonstrations.from_episodes([{"observations": obs[:20], "actions": actions[:20]},
                                          {"observations": obs[20:], "actions": actions[20:]}])
    model = CMZDRILSAC("MlpPolicy", _MatrixActions(), demonstrations=demos,
                       **{**TINY_CMZ_SAC, "bc_pretrain_epochs": 300, "learning_starts": 10})
    model.pretrain()
    cloned = model.predict(obs, deterministic=True)[0]
    assert cloned.shape == (40, 2, 2) and np.abs(cloned - actions).mean() < 0.2 * np.abs(actions).mean()
    model.learn(40)  # batches of the agent's flat actions and the demos' (2, 2) ones
    assert model.replay_buffer.sample(16).actions.shape == (16, 4)


class _BatchNormExtractor(BaseFeaturesExtractor):
    """Flatten, then batch norm: its running statistics move whenever it runs in training mode."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        super().__init__(observation_space, int(np.prod(observation_space.shape)))
        self.norm = th.nn.BatchNorm1d(self.features_dim)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.norm(th.flatten(observations, start_dim=1))


def test_collecting_leaves_batch_norm_alone_after_the_clone(pendulum_demos):
    model = tiny_model(pendulum_demos, learning_starts=10_000,
                       policy_kwargs=dict(net_arch=[16, 16], features_extractor_class=_BatchNormExtractor))
    norm = model.actor.features_extractor.norm
    before = norm.running_mean.clone()
    model.pretrain()  # cloning trains the actor, batch norm included
    cloned = norm.running_mean.clone()
    assert not th.equal(before, cloned)
    model.learn(100)  # collecting only: SAC takes no gradient step
    assert th.equal(norm.running_mean, cloned)


def test_save_and_load_keep_policy_ensemble_demos_and_reward_state(pendulum_demos, tmp_path):
    model = tiny_model(pendulum_demos)
    model.learn(200)
    model.save(tmp_path / "m.zip")
    loaded = CMZDRILSAC.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), device="cpu")
    obs = pendulum_demos.observations[:10]
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    np.testing.assert_allclose(loaded.ensemble.disagreement(obs), model.ensemble.disagreement(obs))
    np.testing.assert_array_equal(loaded.reward_rule.get_state(), model.reward_rule.get_state())
    assert loaded.absorbing_u == model.absorbing_u and loaded.pretrained
    np.testing.assert_array_equal(loaded.demonstrations.actions, pendulum_demos.actions)
    np.testing.assert_array_equal(loaded.demonstrations.rewards, pendulum_demos.rewards)
    loaded.learn(100, reset_num_timesteps=False)  # goes on learning, without pretraining again
    assert loaded.num_timesteps == 300


def test_a_saved_replay_buffer_holds_the_agents_transitions_and_resumes_with_the_demos_mixed_in_again(
    pendulum_demos, tmp_path
):
    model = tiny_model(pendulum_demos)
    model.learn(120)
    model.save(tmp_path / "m.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    # The buffer's relabelling function is a method of the learner: pickled with the buffer, it would
    # take the whole model (and its env) into the file.
    assert b"CMZDRILSAC" not in (tmp_path / "buffer.pkl").read_bytes()
    loaded = CMZDRILSAC.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), device="cpu")
    loaded.load_replay_buffer(tmp_path / "buffer.pkl")
    buffer = loaded.replay_buffer
    assert isinstance(buffer, DemoReplayBuffer) and buffer.pos == 120 and buffer.demos is None
    np.testing.assert_array_equal(buffer.observations[:120], model.replay_buffer.observations[:120])
    loaded.learn(30, reset_num_timesteps=False)
    assert buffer.demos is not None and buffer.relabel is not None and buffer.pos == 150


def test_replayed_rewards_use_the_u_stored_at_collection_and_equal_a_fresh_scoring(pendulum_demos):
    model = tiny_model(pendulum_demos, cmz_clip_quantile=0.98, absorbing=True)
    seen = []
    model.learn(150, callback=_InfoSpy(seen))
    # Each step's info dict carries its u once the step is stored (after the callbacks' on_step).
    assert len(seen) == 150 and all("disagreement" in info for infos in seen for info in infos)
    buffer = model.replay_buffer
    assert isinstance(buffer, DemoReplayBuffer) and buffer.demos is not None
    obs, actions = buffer.observations[:150, 0], buffer.actions[:150, 0]
    fresh = model.ensemble.disagreement(obs, model.policy.unscale_action(actions))
    np.testing.assert_allclose(buffer.disagreements[:150, 0], fresh, rtol=1e-5, atol=1e-7)
    demo_fresh = model.ensemble.disagreement(buffer.demos.observations, None)
    np.testing.assert_allclose(buffer.demos.disagreements, demo_fresh, rtol=1e-5, atol=1e-7)
    # The rewards of a batch from stored u are those of u scored now, and a step without a stored u
    # (a buffer saved before steps kept theirs) is scored when sampled.
    env_rewards, terminated = np.zeros(150), buffer.dones[:150, 0].astype(bool)
    from_stored = model._replay_rewards(obs, actions, env_rewards, terminated, obs, buffer.disagreements[:150, 0])
    rescored = model._replay_rewards(obs, actions, env_rewards, terminated, obs, np.full(150, np.nan))
    np.testing.assert_allclose(from_stored, rescored, rtol=1e-5, atol=1e-6)
    del buffer.disagreements
    batch = buffer.sample(16)
    assert np.isfinite(batch.rewards.numpy()).all()


class _InfoSpy(BaseCallback):
    def __init__(self, seen: list) -> None:
        super().__init__()
        self.seen = seen

    def _on_step(self) -> bool:
        self.seen.append(self.locals["infos"])
        return True


def test_expert_evaluation_epochs_go_on_across_a_resumed_sac_run(pendulum_demos, tmp_path):
    from sb3_cmzdril.metrics import ExpertEvalCallback

    csv_path = tmp_path / "eval.csv"
    model = tiny_model(pendulum_demos)
    model.learn(100, callback=ExpertEvalCallback("Pendulum-v1", pendulum_demos, eval_every=50, csv_path=csv_path))
    model.save(tmp_path / "m.zip")
    loaded = CMZDRILSAC.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), device="cpu")
    loaded.learn(100, callback=ExpertEvalCallback("Pendulum-v1", pendulum_demos, eval_every=50, csv_path=csv_path),
                 reset_num_timesteps=False)
    with open(csv_path, newline="") as f:
        rows = [(int(r["epoch"]), int(r["timesteps"])) for r in csv.DictReader(f)]
    # SAC trains after every step, so an epoch is a step; the second learn() neither restarts at 0 nor
    # evaluates step 100 again.
    assert rows == [(0, 0), (50, 50), (100, 100), (150, 150), (200, 200)]


def test_cmz_clip_bounds_replayed_rewards_at_the_demos_quantile_and_survives_save_load(pendulum_demos, tmp_path):
    model = tiny_model(pendulum_demos, cmz_clip_quantile=0.9)
    model.learn(100)
    u_demos = model.ensemble.disagreement(pendulum_demos.observations, pendulum_demos.actions)
    assert model.cmz_u_max == pytest.approx(np.quantile(u_demos, 0.9), rel=1e-5)
    assert model.reward_rule.u_max == model.cmz_u_max
    # Every u beyond the clip earns the clip's reward: here u of 10 and 100 score alike.
    far = model.reward_rule.replayed(np.array([model.cmz_u_max, 10.0, 100.0]), np.zeros(3))
    assert far[0] == pytest.approx(far[1]) and far[1] == pytest.approx(far[2])
    model.save(tmp_path / "m.zip")
    loaded = CMZDRILSAC.load(tmp_path / "m.zip", device="cpu")
    assert loaded.cmz_clip_quantile == 0.9 and loaded.reward_rule.u_max == model.cmz_u_max


# -- refusals --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(reward="gail"), "reward must be one of"),
        (dict(demo_fraction=1.0), "demo_fraction must lie in"),
        (dict(demo_fraction=float("nan")), "demo_fraction must be finite"),
        (dict(absorbing="yes"), "absorbing must be"),
        (dict(absorbing_score="lowest"), "absorbing_score must be 'highest' or 'terminal', got 'lowest'"),
        (dict(bc_weight=-1.0), "bc_weight must be >= 0"),
        (dict(bc_pretrain_epochs=-1), "bc_pretrain_epochs must be >= 0"),
        (dict(replay_buffer_class=ReplayBuffer), "must be a DemoReplayBuffer"),
        (dict(alpha=0.0), "alpha must be > 0"),
        (dict(cmz_clip_quantile=1.5), r"cmz_clip_quantile must lie in \(0, 1\], be None or 'auto'"),
        (dict(optimize_memory_usage=True), "optimize_memory_usage=True is not supported"),
        (dict(n_steps=3), "n_steps must be 1, got 3"),
        (dict(critic_warmup_steps=-1), "critic_warmup_steps must be a whole number >= 0, got -1"),
        (dict(critic_warmup_steps=2.5), "critic_warmup_steps must be a whole number >= 0, got 2.5"),
        (dict(bc_learning_rate="lin_1e-3"), "CMZDRILSAC's bc_learning_rate is a number .*, got 'lin_1e-3'"),
    ],
)
def test_bad_options_are_refused_naming_them(pendulum_demos, kwargs, message):
    with pytest.raises(UserError, match=message):
        tiny_model(pendulum_demos, **kwargs)


def test_dict_observations_are_refused_with_the_alternative():
    env = gym.make("Pendulum-v1")
    env = gym.wrappers.TransformObservation(
        env, lambda o: {"x": o}, gym.spaces.Dict({"x": env.observation_space})
    )
    with pytest.raises(UserError, match="flat Box observations.*CMZDRIL"):
        CMZDRILSAC("MultiInputPolicy", env)


def test_true_reward_with_demos_that_recorded_none_is_refused_before_training(pendulum_demos):
    demos = Demonstrations(pendulum_demos.observations, pendulum_demos.actions, pendulum_demos.episode_lengths)
    model = tiny_model(demos, reward="env")
    with pytest.raises(UserError, match="demo_fraction=0"):
        model.learn(10)
    assert model.num_timesteps == 0


def test_learning_without_demonstrations_says_what_to_pass():
    model = CMZDRILSAC("MlpPolicy", "Pendulum-v1", **TINY_CMZ_SAC)
    with pytest.raises(UserError, match="needs demonstrations"):
        model.learn(10)


# -- reward-free selection: the longest episodes -----------------------------------------------------------
class _FallsAfterW(gym.Env):
    """An episode ends (a fall) after round(action) steps, at most 20; the reward punishes standing, so
    a selector that read it would choose otherwise. Each reset draws its start from the env's RNG."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(0.0, 50.0, (1,), np.float32)

    def __init__(self) -> None:
        self.starts: list[float] = []

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        self.starts.append(float(self.np_random.uniform(-1, 1)))
        return np.array([self.starts[-1]], np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(1, np.float32), -float(self.t), self.t >= round(float(action[0])), self.t >= 20, {}


class _ConstantPolicy(th.nn.Module):
    """Acts ``w`` everywhere; ``tag`` changes nothing the env sees, so two ties can be told apart."""

    def __init__(self) -> None:
        super().__init__()
        self.w, self.tag = th.nn.Parameter(th.zeros(())), th.nn.Parameter(th.zeros(()))


class _ConstantModel:
    def __init__(self) -> None:
        self.policy, self.num_timesteps = _ConstantPolicy(), 0

    def predict(self, obs, state=None, episode_start=None, deterministic=False):
        assert deterministic
        return np.full((len(obs), 1), self.policy.w.item()), None


def test_longest_episodes_keeps_the_longest_latest_on_a_tie_from_the_same_starts():
    env = _FallsAfterW()
    selector = LongestEpisodesPolicy(env, check_every=10, n_episodes=3, seed=7)
    model = _ConstantModel()
    selector.init_callback(model)
    # (steps, w, tag): lengths 3, 7, 20 (time limit), 5, 20 again (a tie: the later one is kept), 2.
    for steps, w, tag in [(0, 3, 0), (10, 7, 1), (20, 25, 2), (30, 5, 3), (40, 20, 4), (50, 2, 5)]:
        model.num_timesteps = steps
        with th.no_grad():
            model.policy.w.fill_(w)
            model.policy.tag.fill_(tag)
        selector.on_step()
    assert [(s, length) for s, length, _ in selector.history] == [
        (0, 3.0), (10, 7.0), (20, 20.0), (30, 5.0), (40, 20.0), (50, 2.0)]
    assert all(np.isnan(u) for *_, u in selector.history)  # a model without an ensemble: no u
    assert selector.best_timesteps == 40 and selector.best_length == 20.0
    assert selector.env_steps == 3 * (3 + 7 + 20 + 5 + 20 + 2)
    # The run's record (done.json) lists every check, so the other tie break's choice can be replayed.
    checks = selector.kept()["checks"]
    assert [(s, length) for s, length, _ in checks] == [
        (0, 3.0), (10, 7.0), (20, 20.0), (30, 5.0), (40, 20.0), (50, 2.0)]
    assert kept_check(checks, "latest") == 4
    # Every check starts its three episodes from the same three states: the comparison is paired. (The
    # vectorised env also resets once after a check's last episode: four resets a check.)
    blocks = [env.starts[i:i + 4] for i in range(0, len(env.starts), 4)]
    assert len(blocks) == 6 and all(b == blocks[0] for b in blocks) and len(set(blocks[0][:3])) == 3
    selector.apply(model)
    assert model.policy.w.item() == 20.0 and model.policy.tag.item() == 4.0


def test_longest_episodes_checks_the_clone_every_k_steps_and_the_end_and_keeps_the_last_without_falls(
    pendulum_demos,
):
    model = tiny_model(pendulum_demos)
    selector = LongestEpisodesPolicy("Pendulum-v1", check_every=100, n_episodes=1, seed=3,
                                     env_kwargs={"max_episode_steps": 30})
    model.learn(250, callback=selector)
    # The clone before any SAC step, every 100 steps, and the last policy; Pendulum never terminates.
    assert [steps for steps, *_ in selector.history] == [0, 100, 200, 250]
    assert {length for _, length, _ in selector.history} == {30.0} and selector.env_steps == 4 * 30
    # CMZDRILSAC has an ensemble: each check records the mean u of its states, a positive number.
    assert all(np.isfinite(u) and u > 0 for *_, u in selector.history)
    assert selector.best_timesteps == 250
    final = {k: v.clone() for k, v in model.policy.state_dict().items()}
    selector.apply(model)
    assert all(th.equal(final[k], v) for k, v in model.policy.state_dict().items())
    selector.close()


class _DisagreementOnAction:
    """An ensemble whose u at a state is |action - 22|: ties in length are told apart by the action."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []

    def disagreement(self, obs, actions):
        self.calls.append((np.asarray(obs), np.asarray(actions)))
        return np.abs(np.asarray(actions, np.float64)[:, 0] - 22.0)


@pytest.mark.parametrize(("tie_break", "kept_w"), [("latest", 30.0), ("lowest_u", 20.0)])
def test_longest_episodes_breaks_a_tie_in_length_by_the_lowest_disagreement_when_asked(tie_break, kept_w):
    selector = LongestEpisodesPolicy(_FallsAfterW(), check_every=10, n_episodes=2, seed=7, tie_break=tie_break)
    model = _ConstantModel()
    model.ensemble = _DisagreementOnAction()
    selector.init_callback(model)
    # Lengths 3, then the time limit (20) three times with u = |w - 22| = 3, 2 and 8.
    for steps, w in [(0, 3), (10, 25), (20, 20), (30, 30)]:
        model.num_timesteps = steps
        with th.no_grad():
            model.policy.w.fill_(w)
        selector.on_step()
    assert [(s, length, u) for s, length, u in selector.history] == [
        (0, 3.0, 19.0), (10, 20.0, 3.0), (20, 20.0, 2.0), (30, 20.0, 8.0)]
    # The ensemble scored every state of both episodes, with the action played there.
    obs, actions = model.ensemble.calls[0]
    assert obs.shape == (2 * 3, 1) and actions.shape == (2 * 3, 1) and set(actions[:, 0]) == {3.0}
    assert selector.best_length == 20.0 and selector.kept()["mean_u"] == abs(kept_w - 22)
    selector.apply(model)
    assert model.policy.w.item() == kept_w


#: (steps, mean length, u) of five checks: the longest episodes (200) first at 10, tied at 20, 30 and 40.
_CHECKS = [(0, 50.0, 0.9), (10, 200.0, 0.3), (20, 200.0, 0.1), (30, 200.0, 0.7), (40, 200.0, 0.1)]


@pytest.mark.parametrize(("checks", "tie_break", "kept"), [
    (_CHECKS, "latest", 4),
    (_CHECKS, "lowest_u", 4),  # 20 and 40 tie in u too: the later
    (_CHECKS[:4], "lowest_u", 2),
    (_CHECKS[:4], "latest", 3),
    ([(0, 10.0, 0.1), (10, 9.0, 0.0)], "lowest_u", 0),  # length first: a lower u never outranks it
    ([(0, 5.0, float("nan")), (10, 5.0, float("nan"))], "lowest_u", 1),  # u unknown: the later
])
def test_the_kept_check_is_the_longest_then_the_latest_or_the_lowest_u(checks, tie_break, kept):
    assert kept_check(checks, tie_break) == kept


@pytest.mark.parametrize(("checks", "tie_break", "kept"), [
    ([(0, 100.0, 0.3), (10, 150.0, 0.2), (20, 999.0, 0.1)], "lowest_u", 1),  # 150 is the closest to 160
    ([(0, 100.0, 0.3), (10, 170.0, 0.2), (20, 150.0, 0.1)], "lowest_u", 2),  # 10 from it either side: u
    ([(0, 100.0, 0.3), (10, 170.0, 0.2), (20, 150.0, 0.1)], "latest", 2),
])
def test_with_a_target_length_the_check_closest_to_it_is_kept_then_the_tie_break(checks, tie_break, kept):
    assert kept_check(checks, tie_break, target_length=160.0) == kept


class _DisagreementFromFour(_DisagreementOnAction):
    """u = |action - 4|: the policy that falls soonest is the one the ensemble knows best."""

    def disagreement(self, obs, actions):
        return np.abs(np.asarray(actions, np.float64)[:, 0] - 4.0)


def _demos(lengths: list[int]) -> Demonstrations:
    return Demonstrations(np.zeros((sum(lengths), 1), np.float32), np.zeros((sum(lengths), 1), np.float32), lengths)


@pytest.mark.parametrize(("episode_length", "kept_w"), [("longest", 25.0), ("expert", 4.0), (None, 4.0)])
def test_where_the_expert_ends_its_episodes_the_check_as_long_as_its_is_kept(episode_length, kept_w):
    # _FallsAfterW has no spec, so its time limit is unknown: "expert" (None's meaning with lowest_u)
    # cannot tell that the expert runs to it, and keeps the check closest to the demonstrations' 5 steps.
    selector = LongestEpisodesPolicy(_FallsAfterW(), check_every=10, n_episodes=2, seed=7, tie_break="lowest_u",
                                     episode_length=episode_length)
    model = _ConstantModel()
    model.ensemble, model.demonstrations = _DisagreementFromFour(), _demos([4, 6])
    selector.init_callback(model)
    for steps, w in [(0, 25), (10, 4), (20, 6)]:  # lengths 20 (the time limit), 4 (u 0) and 6 (u 2)
        with th.no_grad():
            model.policy.w.fill_(w)
        model.num_timesteps = steps
        if steps == 0:
            selector.on_training_start({}, {})
        else:
            selector.on_step()
    assert [(length, u) for _, length, u in selector.history] == [(20.0, 21.0), (4.0, 0.0), (6.0, 2.0)]
    assert selector.kept()["target_length"] == (None if episode_length == "longest" else 5.0)
    # 4 and 6 are as close to 5: the tie break keeps the lower u, 4's
    selector.apply(model)
    assert model.policy.w.item() == kept_w


@pytest.mark.parametrize(("lengths", "target"), [([10, 12], None), ([10, 4], 7.0)])
def test_the_expert_length_is_the_demonstrations_mean_unless_every_one_lasts_the_time_limit(lengths, target):
    selector = LongestEpisodesPolicy("Pendulum-v1", n_episodes=1, tie_break="lowest_u",
                                     env_kwargs={"max_episode_steps": 10})
    model = _ConstantModel()
    model.ensemble, model.demonstrations = _DisagreementOnAction(), _demos(lengths)
    selector.init_callback(model)
    selector.on_training_start({}, {})
    assert selector.target_length == target and selector.kept()["target_length"] == target
    selector.close()


def test_the_expert_length_needs_a_model_with_demonstrations():
    selector = LongestEpisodesPolicy(_FallsAfterW(), episode_length="expert")
    selector.init_callback(_ConstantModel())
    with pytest.raises(UserError, match="episode_length='expert' reads the model's demonstrations; _ConstantModel has"):
        selector.on_training_start({}, {})


def test_the_kept_check_refuses_no_checks_and_an_unknown_tie_break():
    with pytest.raises(UserError, match="no checks to choose from"):
        kept_check([])
    with pytest.raises(UserError, match=r"tie_break must be one of \['latest', 'lowest_u'\], got 'first'"):
        kept_check(_CHECKS, "first")


def test_the_lowest_u_tie_break_refuses_a_model_without_an_ensemble():
    selector = LongestEpisodesPolicy(_FallsAfterW(), tie_break="lowest_u")
    selector.init_callback(_ConstantModel())
    with pytest.raises(UserError, match="tie_break='lowest_u' needs a model with an ensemble; _ConstantModel has none"):
        selector.on_training_start({}, {})


def test_verbose_keeps_its_place_before_the_tie_break_in_the_constructor():
    # The sixth positional argument was verbose before the tie break came, and still is.
    selector = LongestEpisodesPolicy(_FallsAfterW(), 10, 2, 7, None, 1)
    assert selector.verbose == 1 and selector.tie_break == "latest"


def test_a_longest_episodes_file_written_before_u_was_recorded_resumes_with_u_unknown(tmp_path):
    path = tmp_path / "selection.pt"
    th.save({"state_dict": {"w": th.zeros(())}, "history": th.tensor([[0.0, 3.0], [10.0, 20.0]], dtype=th.float64),
             "best_length": th.tensor(20.0, dtype=th.float64), "best_timesteps": th.tensor(10),
             "env_steps": th.tensor(46)}, path)
    selector = LongestEpisodesPolicy(_FallsAfterW(), tie_break="lowest_u")
    assert selector.load(path)
    assert [(s, length) for s, length, _ in selector.history] == [(0, 3.0), (10, 20.0)]
    assert all(np.isnan(u) for *_, u in selector.history) and np.isnan(selector.best_u)
    assert (selector.best_timesteps, selector.env_steps) == (10, 46)


def test_a_saved_longest_episodes_choice_resumes_without_repeating_or_forgetting_a_check(tmp_path):
    path = tmp_path / "selection.pt"
    first, model = LongestEpisodesPolicy(_FallsAfterW(), check_every=10, n_episodes=2, seed=7), _ConstantModel()
    first.save(path)
    assert not path.exists()  # no check, no choice to keep
    first.init_callback(model)
    for steps, w in [(0, 3), (10, 25), (20, 5)]:
        model.num_timesteps = steps
        with th.no_grad():
            model.policy.w.fill_(w)
        first.on_step()
    first.save(path)

    # A resumed run: the model comes back at step 20 with its last weights (w = 5).
    second = LongestEpisodesPolicy(_FallsAfterW(), check_every=10, n_episodes=2, seed=7)
    assert second.load(path)
    assert [(s, length) for s, length, _ in second.history] == [(0, 3.0), (10, 20.0), (20, 5.0)]
    assert second.env_steps == 2 * (3 + 20 + 5)
    assert (second.best_timesteps, second.best_length) == (10, 20.0)
    second.init_callback(model)
    second.on_training_start({}, {})  # the check at step 20 was made before the checkpoint
    model.num_timesteps = 30
    second.on_step()
    assert [steps for steps, *_ in second.history] == [0, 10, 20, 30]
    second.apply(model)
    assert model.policy.w.item() == 25.0


def test_a_damaged_longest_episodes_file_is_named_and_a_missing_one_is_no_choice(tmp_path):
    selector = LongestEpisodesPolicy(_FallsAfterW())
    assert not selector.load(tmp_path / "none.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a torch file")
    with pytest.raises(UserError, match=r"bad.pt is truncated or not a longest-episodes policy file"):
        selector.load(tmp_path / "bad.pt")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"check_every": 0}, "check_every must be a positive integer, got 0"),
     ({"n_episodes": 2.5}, "n_episodes must be a positive integer, got 2.5"),
     ({"seed": "a"}, "seed must be an integer, got 'a'"),
     ({"tie_break": "earliest"}, r"tie_break must be one of \['latest', 'lowest_u'\], got 'earliest'"),
     ({"episode_length": "shortest"}, r"episode_length must be one of \['longest', 'expert'\], got 'shortest'"),
     ({"env_kwargs": {"g": 9.81}, "eval_env": None}, "env_kwargs applies only to an env id")],
)
def test_longest_episodes_refuses_bad_options_naming_them(kwargs, message):
    env = kwargs.pop("eval_env", "Pendulum-v1") or gym.make("Pendulum-v1")
    with pytest.raises(UserError, match=message):
        LongestEpisodesPolicy(env, **kwargs)


def test_longest_episodes_has_nothing_to_apply_before_a_check():
    with pytest.raises(RuntimeError, match="nothing to select"):
        LongestEpisodesPolicy("Pendulum-v1").apply(_ConstantModel())


def test_longest_episodes_serves_cmzdril_and_the_kept_policy_replays_its_check(cartpole_demos):
    # A large step size moves this tiny PPO's policy between checks: the longest check is not the last.
    model = CMZDRIL("MlpPolicy", "CartPole-v1", demonstrations=cartpole_demos, device="cpu",
                    **{**TINY, "learning_rate": 0.03, "bc_pretrain_epochs": 1})
    selector = LongestEpisodesPolicy("CartPole-v1", check_every=64, n_episodes=2, seed=5)
    model.learn(320, callback=selector)
    steps = [s for s, *_ in selector.history]
    lengths = [length for _, length, _ in selector.history]
    assert steps == [0, 64, 128, 192, 256, 320] and selector.best_length == max(lengths) > lengths[-1]
    assert selector.best_timesteps == max(s for s, length, _ in selector.history if length == max(lengths))
    selector.apply(model)
    # From the same starts, the kept weights last as long as at their check (the last ones would not).
    env = DummyVecEnv([lambda: Monitor(gym.make("CartPole-v1"))])
    env.seed(5)
    _, replayed = evaluate_policy(model, env, n_eval_episodes=2, deterministic=True, return_episode_rewards=True)
    assert float(np.mean(replayed)) == selector.best_length
