"""Reward rules against hand-computed values, and the DisagreementReward wrapper."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from sb3_cmzdril import CMZReward, DisagreementReward, DRILReward
from sb3_cmzdril.rewards import EnvReward, ZeroReward, make_rule, terminations, with_absorbing_state


class ScriptedEnv(gym.Env):
    """Observation = the next value of a script; an episode ends after ``episode_len`` steps.

    The observation returned with ``done`` is 99: if the wrapper scored that terminal observation
    instead of the one the agent acted on, u = 99 would show up in the rewards."""

    observation_space = spaces.Box(-np.inf, np.inf, (1,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, script: list[float], episode_len: int) -> None:
        self.script = list(script)
        self.episode_len = episode_len
        self.t = 0

    def _next(self) -> np.ndarray:
        return np.array([self.script.pop(0)], dtype=np.float32)

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._next(), {}

    def step(self, action):
        self.t += 1
        if self.t == self.episode_len:
            return np.array([99.0], np.float32), 5.0, True, False, {}
        return self._next(), 5.0, False, False, {}


class ObsIsU:
    """A disagreement model whose u is the observation itself."""

    needs_actions = False

    def disagreement(self, obs: np.ndarray, actions=None) -> np.ndarray:
        return np.asarray(obs, dtype=np.float64)[:, 0]


def test_cmz_reward_hand_computed_two_envs_with_an_episode_end():
    # env 0 acts on 0.2, 0.4, then its episode ends and it acts on the new episode's 0.1;
    # env 1 acts on 1.0, 0.0, 0.5 without an episode end.
    venv = DummyVecEnv([lambda: ScriptedEnv([0.2, 0.4, 0.1, 0.0], 2), lambda: ScriptedEnv([1.0, 0.0, 0.5, 0.0], 10)])
    env = DisagreementReward(venv, ObsIsU(), CMZReward(alpha=10.0, ema=0.99, u0=0.0))
    env.reset()
    actions = np.zeros((2, 1), np.float32)
    # step 1: ubar = [0, 0]                 -> r = -10 * ([0.2, 1.0] - 0)
    # step 2: ubar = [0.002, 0.01]          -> r = -10 * ([0.4, 0.0] - ubar)
    # step 3: ubar = [0.00598, 0.0099]      -> r = -10 * ([0.1, 0.5] - ubar)   (no reset of ubar)
    expected = [[-2.0, -10.0], [-3.98, 0.1], [-0.9402, -4.901]]
    expected_ubar = [[0.002, 0.01], [0.00598, 0.0099], [0.00598 * 0.99 + 0.001, 0.0099 * 0.99 + 0.005]]
    dones_seen = []
    for step in range(3):
        obs, rewards, dones, infos = env.step(actions)
        np.testing.assert_allclose(rewards, expected[step], rtol=1e-6)
        np.testing.assert_allclose(env.rule.get_state(), expected_ubar[step], rtol=1e-6)  # obs are float32
        assert [i["env_reward"] for i in infos] == [5.0, 5.0]
        dones_seen.append(dones.tolist())
    assert dones_seen[1] == [True, False]
    assert infos[0]["disagreement"] == pytest.approx(0.1)


def test_cmz_reward_has_zero_mean_in_steady_state():
    rule = CMZReward(alpha=10.0, ema=0.99)
    rng = np.random.default_rng(0)
    rewards = [rule(rng.uniform(0.5, 1.5, size=4), np.zeros(4)) for _ in range(5000)]
    assert abs(np.mean(rewards[2000:])) < 0.05  # the EMA has caught up: mean reward ~ 0
    assert np.mean(rewards[:50]) < -5  # early on ubar ~ 0 and every step is penalised


def test_cmz_state_roundtrip_and_validation():
    rule = CMZReward(u0=0.3)
    rule(np.array([1.0, 2.0]), np.zeros(2))
    state = rule.get_state()
    np.testing.assert_allclose(state, [0.3 * 0.99 + 0.01, 0.3 * 0.99 + 0.02])
    other = CMZReward(u0=0.3)
    other.set_state(state)
    u = np.array([0.5, 0.7])
    assert np.array_equal(other(u, np.zeros(2)), rule(u, np.zeros(2)))
    with pytest.raises(ValueError, match="EMA state for 2 envs but got 3"):
        rule(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="alpha must be > 0"):
        CMZReward(alpha=0)
    with pytest.raises(ValueError, match=r"ema must lie in \(0, 1\)"):
        CMZReward(ema=1.0)


def test_cmz_reward_clips_u_before_the_reward_and_the_ema():
    # u_max 0.5: u = 0.2, 2.0, 0.4 reads as 0.2, 0.5, 0.4.
    # r_1 = -10 * 0.2 = -2; ubar = 0.002; r_2 = -10 * (0.5 - 0.002) = -4.98; ubar = 0.00698;
    # r_3 = -10 * (0.4 - 0.00698) = -3.9302.
    rule = CMZReward(u_max=0.5)
    u = np.array([[0.2], [2.0], [0.4]])
    expected = [-2.0, -4.98, -3.9302]
    np.testing.assert_allclose(rule.sequence(u, np.zeros_like(u))[:, 0], expected, rtol=1e-6)
    stepwise = CMZReward(u_max=0.5)
    np.testing.assert_allclose([stepwise(row, np.zeros(1))[0] for row in u], expected, rtol=1e-6)
    np.testing.assert_allclose(rule.get_state(), stepwise.get_state())
    np.testing.assert_allclose(rule.get_state(), [0.00698 * 0.99 + 0.004])
    # Every u beyond the clip costs the same; below it the reward is the paper's.
    far = CMZReward(u_max=0.5)
    assert far(np.array([0.6, 5.0]), np.zeros(2)).tolist() == [-5.0, -5.0]
    # The absorbing state's u is clipped too: at most as bad as a step at u_max.
    rewards = CMZReward(u_max=0.5).sequence(np.array([[0.1]]), np.zeros((1, 1)))
    np.testing.assert_allclose(rule.absorbing(np.array(3.0), np.array([[0.1]]), rewards), [[-5.0]], rtol=1e-6)
    assert "u_max=0.5" in repr(rule) and "u_max" not in repr(CMZReward())
    for bad in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match="u_max must be finite and > 0, or None"):
            CMZReward(u_max=bad)


def test_dril_reward_and_threshold_from_quantile(pendulum_demos):
    rule = DRILReward(threshold=0.5)
    assert rule(np.array([0.4, 0.5, 0.6]), np.zeros(3)).tolist() == [1.0, 1.0, -1.0]

    class Constant:
        needs_actions = True

        def disagreement(self, obs, actions):
            return np.linspace(0.0, 1.0, len(obs))

    q = DRILReward.from_quantile(Constant(), pendulum_demos, q=0.98).threshold
    assert q == pytest.approx(np.quantile(np.linspace(0, 1, len(pendulum_demos)), 0.98))
    with pytest.raises(ValueError, match="threshold must be finite"):
        DRILReward(np.nan)


def test_zero_env_rules_and_make_rule():
    u, r = np.array([0.1, 2.0]), np.array([3.0, -1.0])
    assert ZeroReward()(u, r).tolist() == [0.0, 0.0]
    assert EnvReward()(u, r).tolist() == [3.0, -1.0]
    assert isinstance(make_rule("cmz", alpha=2.0), CMZReward)
    with pytest.raises(ValueError, match="unknown reward 'gail'"):
        make_rule("gail")


def _pendulum_rollout(venv_cls, n_envs: int, steps: int = 30):
    from sb3_cmzdril.ensemble import BCEnsemble

    make = [lambda: gym.make("Pendulum-v1") for _ in range(n_envs)]
    venv = venv_cls(make)
    venv.seed(3)
    ens = BCEnsemble(venv.observation_space, venv.action_space, 3, (8,), seed=0)
    rng = np.random.default_rng(0)
    from sb3_cmzdril.data.demos import Demonstrations

    ens.fit(Demonstrations(rng.normal(size=(50, 3)), rng.uniform(-2, 2, size=(50, 1)), [50]), n_epochs=2)
    env = DisagreementReward(venv, ens, CMZReward())
    obs = env.reset()
    reference = [gym.make("Pendulum-v1") for _ in range(n_envs)]
    for i, ref in enumerate(reference):
        ref.reset(seed=3 + i)
    for _ in range(steps):
        acts = rng.uniform(-2, 2, size=(n_envs, 1)).astype(np.float32)
        acted_on = obs.copy()
        obs, rewards, dones, infos = env.step(acts)
        ref_rewards = [ref.step(a)[1] for ref, a in zip(reference, acts, strict=True)]
        np.testing.assert_allclose([i["env_reward"] for i in infos], ref_rewards, rtol=1e-6)
        np.testing.assert_allclose([i["disagreement"] for i in infos], ens.disagreement(acted_on), rtol=1e-9)
        assert rewards.shape == (n_envs,) and rewards.dtype == np.float32
    stats = env.pop_stats()
    assert set(stats) == {"disagreement_mean", "shaped_reward_mean"} and env.pop_stats() == {}
    env.close()


def test_wrapper_keeps_true_reward_in_info_dummy_vec_env():
    _pendulum_rollout(DummyVecEnv, n_envs=3)


def test_wrapper_works_with_subproc_vec_env():
    _pendulum_rollout(lambda fns: SubprocVecEnv(fns, start_method="fork"), n_envs=2, steps=10)


def test_wrapper_errors():
    venv = DummyVecEnv([lambda: gym.make("Pendulum-v1")])
    with pytest.raises(TypeError, match="disagreement"):
        DisagreementReward(venv, object(), CMZReward())
    with pytest.raises(TypeError, match="RewardRule"):
        DisagreementReward(venv, ObsIsU(), lambda u, r: u)
    env = DisagreementReward(venv, ObsIsU(), CMZReward())
    env.step_async(np.zeros((1, 1), np.float32))
    with pytest.raises(RuntimeError, match="before reset"):
        env.step_wait()


def test_absorbing_state_hand_computed():
    # CMZ (alpha 10, g 0.99, ubar_0 0): u = 0.1 then 0.3 -> r = -1, -10 (0.3 - 0.001) = -2.99.
    # The second step terminates into an absorbing state at u = 0.5: each of its steps is worth
    # -10 (0.5 - 0.001) = -4.99, and it starts one step later: + 0.99 / 0.01 * -4.99 = -494.01.
    rule = CMZReward()
    u = np.array([[0.1], [0.3]])
    rewards = rule.sequence(u, np.zeros_like(u))
    np.testing.assert_allclose(rewards[:, 0], [-1.0, -2.99], rtol=1e-6)
    terminated = np.array([[False], [True]])
    out = with_absorbing_state(rule, rewards, u, terminated, np.array(0.5), gamma=0.99)
    np.testing.assert_allclose(out[:, 0], [-1.0, -2.99 - 494.01], rtol=1e-5)
    assert out is not rewards and rewards[1, 0] == pytest.approx(-2.99)  # the input is left alone
    # DRIL: the absorbing state lies above the threshold, so -1 forever: -99 on top of the step's reward.
    dril = DRILReward(threshold=0.2)
    np.testing.assert_allclose(
        with_absorbing_state(dril, dril(u, u), u, terminated, np.array(0.5), 0.99)[:, 0], [1.0, -1.0 - 99.0]
    )
    assert with_absorbing_state(ZeroReward(), np.zeros((2, 1)), u, terminated, np.array(0.5), 0.99).tolist() == [
        [0.0],
        [0.0],
    ]
    assert with_absorbing_state(rule, rewards, u, ~terminated & False, np.array(0.5), 0.99) is rewards


def test_terminations_leave_out_time_limit_truncations():
    infos = [{"TimeLimit.truncated": True}, {}, {"TimeLimit.truncated": False}, {}]
    assert terminations(np.array([True, True, True, False]), infos).tolist() == [False, True, True, False]
    # a VecEnv that gives no info dicts (PPO takes one): every done is a termination
    assert terminations(np.array([True, False]), []).tolist() == [True, False]


def test_wrapper_scores_terminations_as_the_absorbing_state():
    # CartPole pushed one way falls within tens of steps; u is the observation's first entry.
    def wrapped(absorbing_gamma):
        venv = DummyVecEnv([lambda: gym.make("CartPole-v1")])
        venv.seed(0)
        env = DisagreementReward(venv, ObsIsU(), CMZReward(), absorbing_gamma=absorbing_gamma)
        env.reset()
        return env

    plain, absorbing = wrapped(None), wrapped(0.9)
    for _ in range(200):
        _, r_abs, done, info = absorbing.step(np.array([1]))
        _, r_plain, _, _ = plain.step(np.array([1]))
        if done[0]:
            break
        assert r_abs[0] == r_plain[0]
    assert done[0] and not info[0].get("TimeLimit.truncated")
    # 0.9 / 0.1 = 9 steps' worth of the CMZ reward at the highest u seen instead of this step's u.
    at_absorbing = r_plain[0] - 10.0 * (absorbing.absorbing_u - info[0]["disagreement"])
    assert r_abs[0] == pytest.approx(r_plain[0] + 9.0 * at_absorbing, rel=1e-5)
    assert absorbing.absorbing_u > 0 and r_abs[0] < r_plain[0]


def test_wrapper_can_score_a_termination_at_the_u_of_the_observation_it_ended_in():
    # As above, with the absorbing state's u taken on the terminal observation (its first entry doubled).
    ended_in = []

    def doubled_first_entry(obs: np.ndarray) -> np.ndarray:
        ended_in.append(obs.copy())
        return 2.0 * obs[:, 0]

    def wrapped(absorbing_gamma, terminal_disagreement=None):
        venv = DummyVecEnv([lambda: gym.make("CartPole-v1")])
        venv.seed(0)
        env = DisagreementReward(venv, ObsIsU(), CMZReward(), absorbing_gamma=absorbing_gamma,
                                 terminal_disagreement=terminal_disagreement)
        env.reset()
        return env

    plain, terminal = wrapped(None), wrapped(0.9, doubled_first_entry)
    for _ in range(200):
        _, r_terminal, done, info = terminal.step(np.array([1]))
        _, r_plain, _, _ = plain.step(np.array([1]))
        if done[0]:
            break
        assert r_terminal[0] == r_plain[0] and not ended_in  # called for terminations only
    assert done[0] and len(ended_in) == 1
    np.testing.assert_array_equal(ended_in[0], info[0]["terminal_observation"][None])
    # 9 steps' worth of the CMZ reward at the terminal observation's u instead of this step's u.
    u_end = 2.0 * float(info[0]["terminal_observation"][0])
    at_absorbing = r_plain[0] - 10.0 * (u_end - info[0]["disagreement"])
    assert r_terminal[0] == pytest.approx(r_plain[0] + 9.0 * at_absorbing, rel=1e-5)
    assert u_end != pytest.approx(terminal.absorbing_u)  # the highest-u rule would have scored it otherwise
