"""Tests of sb3_cmzdril.metrics: Fréchet distance, action MSE, evaluation against expert episodes, callback."""
from __future__ import annotations

import csv
import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from scipy.spatial.distance import cdist
from stable_baselines3 import PPO
from stable_baselines3.common.logger import KVWriter, Logger

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.metrics import (
    TRAJECTORY_FEATURES,
    ExpertEvalCallback,
    ExpertEvaluation,
    action_mse,
    evaluate_against_expert,
    frechet_distance,
    trajectory_features,
)
from sb3_cmzdril.metrics import frechet as frechet_module
from sb3_cmzdril.selection import LowestDisagreementPolicy

EPISODE_STEPS = 40  # short Pendulum episodes keep the file fast
PENDULUM_KWARGS = {"max_episode_steps": EPISODE_STEPS}


# ---------------------------------------------------------------------------------------------
# Fréchet distance
# ---------------------------------------------------------------------------------------------
def reference_frechet(P: np.ndarray, Q: np.ndarray, dist: np.ndarray | None = None) -> float:
    """Textbook O(n*m) double loop (Eiter & Mannila); distances pair by pair unless ``dist`` is given."""
    P = np.asarray(P, dtype=float).reshape(len(P), -1)
    Q = np.asarray(Q, dtype=float).reshape(len(Q), -1)
    n, m = len(P), len(Q)
    ca = np.full((n, m), np.inf)
    for i in range(n):
        for j in range(m):
            d = math.sqrt(sum((a - b) ** 2 for a, b in zip(P[i], Q[j], strict=True))) if dist is None else dist[i, j]
            if i == 0 and j == 0:
                ca[i, j] = d
            elif i == 0:
                ca[i, j] = max(ca[i, j - 1], d)
            elif j == 0:
                ca[i, j] = max(ca[i - 1, j], d)
            else:
                ca[i, j] = max(min(ca[i - 1, j], ca[i - 1, j - 1], ca[i, j - 1]), d)
    return float(ca[-1, -1])


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("dim", [1, 2, 5])
def test_frechet_matches_reference_dp(seed: int, dim: int) -> None:
    rng = np.random.default_rng(1000 * dim + seed)
    for _ in range(6):
        n, m = rng.integers(1, 40, size=2)
        P = np.cumsum(rng.normal(size=(n, dim)), axis=0)
        Q = np.cumsum(rng.normal(size=(m, dim)), axis=0) + rng.normal(size=dim)
        # The DP only selects among pairwise distances: bit-identical given the same distances...
        assert frechet_distance(P, Q) == reference_frechet(P, Q, dist=cdist(P, Q))
        # ...and within the last bit of a differently rounded distance formula.
        assert frechet_distance(P, Q) == pytest.approx(reference_frechet(P, Q), rel=1e-12, abs=1e-12)


def test_frechet_low_memory_path_matches(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(7)
    cases = [
        (rng.normal(size=(n, d)), rng.normal(size=(m, d)))
        for n, m, d in [(1, 1, 2), (1, 9, 3), (13, 5, 2), (30, 31, 4)]
    ]
    expected = [frechet_distance(P, Q) for P, Q in cases]
    monkeypatch.setattr(frechet_module, "_MAX_MATRIX_ELEMENTS", 0)
    for (P, Q), want in zip(cases, expected, strict=True):
        assert frechet_distance(P, Q) == pytest.approx(want, rel=1e-12, abs=1e-12)
        assert frechet_distance(P, Q) == pytest.approx(reference_frechet(P, Q), rel=1e-12, abs=1e-12)


def test_frechet_textbook_cases() -> None:
    rng = np.random.default_rng(0)
    curve = rng.normal(size=(25, 3))
    assert frechet_distance(curve, curve) == 0.0
    # A single point against a curve: every coupling pairs the point with every vertex.
    point = np.array([[0.5, -1.0, 2.0]])
    assert frechet_distance(point, curve) == pytest.approx(np.max(np.linalg.norm(curve - point, axis=1)))
    # Parallel lines offset by c (same sampling): distance c.
    x = np.linspace(0.0, 10.0, 50)
    assert frechet_distance(np.c_[x, 0 * x], np.c_[x, 0 * x + 3.0]) == pytest.approx(3.0)
    # Worked by hand (1-D): P = 0, 2, 0 and Q = 0, 0, 2, 2, 0.
    # Couplings must visit P's 2 while Q is at 2 and P's 0s with Q's 0s: all pairs can be matched
    # exactly, e.g. (0,0)(0,0)(2,2)(2,2)(0,0), so the distance is 0 despite different lengths.
    assert frechet_distance([0.0, 2.0, 0.0], [0.0, 0.0, 2.0, 2.0, 0.0]) == 0.0
    # P = 0, 2, 0 and Q = 0, 1, 0: the middle must pair 2 with 1 (or with a 0): best is 1.
    assert frechet_distance([0.0, 2.0, 0.0], [0.0, 1.0, 0.0]) == 1.0
    # P = (0,0),(1,0),(2,0) and Q = (0,1),(2,1): Q's first vertex must cover P's (1,0) or its last
    # must: sqrt(1 + 1) = sqrt(2) either way, larger than the endpoint distances of 1.
    assert frechet_distance([[0, 0], [1, 0], [2, 0]], [[0, 1], [2, 1]]) == pytest.approx(math.sqrt(2.0))
    # Lower bound by the endpoints.
    P, Q = rng.normal(size=(10, 2)), rng.normal(size=(17, 2))
    assert frechet_distance(P, Q) >= max(np.linalg.norm(P[0] - Q[0]), np.linalg.norm(P[-1] - Q[-1]))


def test_frechet_symmetry_and_input_forms() -> None:
    rng = np.random.default_rng(3)
    P, Q = rng.normal(size=(12, 2)), rng.normal(size=(31, 2))
    assert frechet_distance(P, Q) == frechet_distance(Q, P)
    assert frechet_distance(P.tolist(), Q) == frechet_distance(P, Q)
    x, y = rng.normal(size=8), rng.normal(size=5)
    assert frechet_distance(x, y) == frechet_distance(x[:, None], y[:, None])
    assert isinstance(frechet_distance(np.arange(3), np.arange(4)), float)  # integer input is fine


@pytest.mark.parametrize(
    "P, Q, match",
    [
        (np.zeros((0, 2)), np.zeros((3, 2)), "empty"),
        (np.zeros((3, 2)), [], "empty"),
        (np.zeros((3, 0)), np.zeros((3, 0)), "empty"),
        (np.zeros((3, 2)), np.zeros((3, 3)), "dimension"),
        (np.zeros((3, 2, 2)), np.zeros((3, 2)), "shape"),
        (np.float64(1.0), np.zeros((3, 1)), "shape"),
        (np.array([[0.0, np.nan]]), np.zeros((3, 2)), "NaN"),
        (np.zeros((3, 2)), np.array([[0.0, 0.0], [np.inf, 0.0]]), "NaN or inf"),
        (["a", "b"], [1.0, 2.0], "numeric"),
    ],
)
def test_frechet_errors(P: Any, Q: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        frechet_distance(P, Q)


# ---------------------------------------------------------------------------------------------
# A deterministic scripted expert on Pendulum-v1, and its demonstrations
# ---------------------------------------------------------------------------------------------
class PendulumRule:
    """PD-like rule; its raw output often exceeds the [-2, 2] torque bounds (so clipping is exercised)."""

    action_space = spaces.Box(-2.0, 2.0, (1,), np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.atleast_2d(np.asarray(obs, dtype=np.float64))
        theta = np.arctan2(obs[:, 1], obs[:, 0])
        return (-(1.0 * theta + 0.3 * obs[:, 2]))[:, None]

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ):
        observation = np.asarray(observation)
        actions = self(observation)
        return (actions if observation.ndim == 2 else actions[0]), state


class NoSpaceRule(PendulumRule):
    """The same rule without an action_space attribute (a minimal scripted expert)."""

    action_space = None


def record_demos(rule: PendulumRule, seeds: list[int], env_kwargs: dict[str, Any] = PENDULUM_KWARGS) -> Demonstrations:
    env = gym.make("Pendulum-v1", **env_kwargs)
    episodes = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        observations, actions, rewards = [], [], []
        done = False
        while not done:
            action = rule(obs)[0]
            observations.append(obs)
            actions.append(action)  # raw, possibly out of bounds: demos keep what the expert chose
            obs, reward, terminated, truncated, _ = env.step(np.clip(action, -2.0, 2.0).astype(np.float32))
            rewards.append(reward)
            done = terminated or truncated
        episodes.append(
            {
                "observations": np.array(observations),
                "actions": np.array(actions),
                "rewards": np.array(rewards),
                "seed": seed,
            }
        )
    env.close()
    return Demonstrations.from_episodes(episodes)


@pytest.fixture(scope="module")
def expert() -> PendulumRule:
    return PendulumRule()


@pytest.fixture(scope="module")
def demos(expert: PendulumRule) -> Demonstrations:
    d = record_demos(expert, seeds=[11, 12, 13])
    out_of_bounds = np.abs(d.actions) > 2.0
    assert out_of_bounds.any() and not out_of_bounds.all(), "want actions both inside and outside the bounds"
    return d


class ConstantPolicy:
    def __init__(self, value: Any, action_space: spaces.Space) -> None:
        self.value = np.asarray(value, dtype=np.float64)
        self.action_space = action_space

    def predict(self, observation: np.ndarray, deterministic: bool = True):
        observation = np.asarray(observation)
        return np.broadcast_to(self.value, (len(observation), *self.value.shape)).copy(), None


# ---------------------------------------------------------------------------------------------
# Action MSE
# ---------------------------------------------------------------------------------------------
def test_action_mse_zero_for_expert(expert: PendulumRule, demos: Demonstrations) -> None:
    assert action_mse(expert, demos) == 0.0
    assert action_mse(NoSpaceRule(), demos, action_space=expert.action_space) == 0.0
    with pytest.raises(ValueError, match="action space"):
        action_mse(NoSpaceRule(), demos)


def test_action_mse_constant_policy_hand_computed() -> None:
    box = spaces.Box(-2.0, 2.0, (2,), np.float32)
    d = Demonstrations(
        observations=np.zeros((3, 4), np.float32),
        actions=np.array([[1.0, 0.0], [3.0, -2.0], [-1.0, 0.5]], np.float32),
        episode_lengths=[3],
    )
    # Expert clipped: (1, 0), (2, -2), (-1, 0.5); policy (0.5, 0.5):
    # squared errors 0.25 + 0.25, 2.25 + 6.25, 2.25 + 0 -> 11.25 over 6 entries.
    assert action_mse(ConstantPolicy([0.5, 0.5], box), d) == pytest.approx(11.25 / 6)
    # Out-of-bounds predictions are clipped too: (5, -9) acts as (2, -2).
    # Errors: (1, 4), (0, 0), (9, 6.25) -> 20.25 / 6.
    assert action_mse(ConstantPolicy([5.0, -9.0], box), d) == pytest.approx(20.25 / 6)


def test_action_mse_constant_policy_on_pendulum(demos: Demonstrations) -> None:
    box = PendulumRule.action_space
    expected = np.mean((0.5 - np.clip(demos.actions.astype(np.float64), -2.0, 2.0)) ** 2)
    assert action_mse(ConstantPolicy([0.5], box), demos) == pytest.approx(expected, rel=1e-6)


def test_action_mse_discrete() -> None:
    d = Demonstrations(
        observations=np.arange(5, dtype=np.float32)[:, None],
        actions=np.array([0, 1, 2, 1, 0]),
        episode_lengths=[2, 3],
    )

    class ParityPolicy:
        action_space = spaces.Discrete(3)

        def predict(self, observation: np.ndarray, deterministic: bool = True):
            return (np.asarray(observation)[:, 0].astype(int) % 2), None

    # Predictions 0, 1, 0, 1, 0 vs expert 0, 1, 2, 1, 0: one disagreement in five.
    assert action_mse(ParityPolicy(), d) == pytest.approx(0.2)
    assert action_mse(ConstantPolicy(1, spaces.Discrete(3)), d) == pytest.approx(3 / 5)


def test_action_mse_uses_vec_normalize_and_obs_transform() -> None:
    box = spaces.Box(-10.0, 10.0, (1,), np.float32)
    d = Demonstrations(np.array([[1.0], [2.0]], np.float32), np.array([[1.0], [2.0]], np.float32), [2])

    class Normaliser:
        def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
            return obs * 2.0

    class Model:
        action_space = box

        def __init__(self, vec_normalize: Any) -> None:
            self._vn = vec_normalize

        def get_vec_normalize_env(self) -> Any:
            return self._vn

        def predict(self, observation: np.ndarray, deterministic: bool = True):
            return np.asarray(observation, dtype=np.float64), None  # echoes what it sees

    assert action_mse(Model(None), d) == 0.0
    assert action_mse(Model(Normaliser()), d) == pytest.approx((1 + 4) / 2)  # it saw 2x the observations
    assert action_mse(Model(Normaliser()), d, obs_transform=lambda o: o) == 0.0


def test_action_mse_sb3_model_and_policy(demos: Demonstrations) -> None:
    model = PPO(
        "MlpPolicy", "Pendulum-v1", n_steps=64, batch_size=64, policy_kwargs={"net_arch": [8]}, seed=0, device="cpu"
    )
    predicted, _ = model.predict(demos.observations, deterministic=True)
    expected = np.mean((np.clip(predicted, -2, 2) - np.clip(demos.actions, -2, 2)) ** 2)
    assert action_mse(model, demos) == pytest.approx(expected, rel=1e-6)
    assert action_mse(model.policy, demos) == pytest.approx(expected, rel=1e-6)


# ---------------------------------------------------------------------------------------------
# Evaluation against the expert
# ---------------------------------------------------------------------------------------------
def test_evaluate_expert_replays_itself(expert: PendulumRule, demos: Demonstrations) -> None:
    result = evaluate_against_expert(expert, "Pendulum-v1", demos, env_kwargs=PENDULUM_KWARGS)
    assert isinstance(result, ExpertEvaluation)
    assert result.n_episodes == 3
    np.testing.assert_array_equal(result.frechet, 0.0)
    assert result.action_mse == 0.0 and result.mean_frechet == 0.0
    np.testing.assert_allclose(result.returns, demos.episode_returns, rtol=1e-5)
    np.testing.assert_array_equal(result.lengths, demos.episode_lengths)
    assert result.start_matches.all()
    for i, obs in enumerate(result.agent_observations):
        np.testing.assert_array_equal(obs, demos.episode(i)["observations"])
    summary = result.summary()
    assert summary["return_mean"] == pytest.approx(float(np.mean(demos.episode_returns)), rel=1e-5)
    # A scripted expert without action_space uses the env's; a gym.Env instance works as well.
    env = gym.make("Pendulum-v1", **PENDULUM_KWARGS)
    again = evaluate_against_expert(NoSpaceRule(), env, demos)
    np.testing.assert_array_equal(again.returns, result.returns)
    env.close()


def test_evaluate_other_policy_and_per_episode_mse(demos: Demonstrations) -> None:
    policy = ConstantPolicy([0.5], PendulumRule.action_space)
    result = evaluate_against_expert(policy, "Pendulum-v1", demos, env_kwargs=PENDULUM_KWARGS)
    assert np.all(result.frechet > 0)
    assert result.action_mse == pytest.approx(action_mse(policy, demos))
    for i in range(demos.n_episodes):
        assert result.episode_action_mse[i] == pytest.approx(action_mse(policy, demos.select([i])))
    # The trajectory function decides what the distance is measured on.
    angle_only = evaluate_against_expert(
        policy, "Pendulum-v1", demos, trajectory_fn=lambda o: o[:, :2], env_kwargs=PENDULUM_KWARGS
    )
    assert np.all(angle_only.frechet <= result.frechet + 1e-12)


def test_evaluate_discrete_expert_replays_itself() -> None:
    class CartPoleRule:
        action_space = spaces.Discrete(2)

        def predict(self, observation: np.ndarray, deterministic: bool = True):
            obs = np.atleast_2d(observation)
            return (obs[:, 2] + 0.5 * obs[:, 3] > 0).astype(np.int64), None

    rule = CartPoleRule()
    env = gym.make("CartPole-v1", max_episode_steps=30)
    episodes = []
    for seed in (3, 4):
        obs, _ = env.reset(seed=seed)
        observations, actions, done = [], [], False
        while not done:
            action = int(rule.predict(obs)[0][0])
            observations.append(obs)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        episodes.append({"observations": np.array(observations), "actions": np.array(actions), "seed": seed})
    d = Demonstrations.from_episodes(episodes)
    result = evaluate_against_expert(rule, env, d)
    env.close()
    np.testing.assert_array_equal(result.frechet, 0.0)
    assert result.action_mse == 0.0
    np.testing.assert_array_equal(result.returns, d.episode_lengths)  # +1 per step
    assert np.isnan(result.expert_returns).all()  # these demos carry no rewards


def test_evaluate_requires_known_seeds(expert: PendulumRule, demos: Demonstrations) -> None:
    unknown = Demonstrations(
        demos.observations, demos.actions, demos.episode_lengths, demos.rewards, seeds=[11, -1, 13]
    )
    with pytest.raises(ValueError, match=r"episodes \[1\].*seed"):
        evaluate_against_expert(expert, "Pendulum-v1", unknown, env_kwargs=PENDULUM_KWARGS)
    with pytest.raises(ValueError, match="seed"):
        ExpertEvalCallback("Pendulum-v1", unknown)


def test_evaluate_flags_a_start_that_the_seed_does_not_reproduce(expert: PendulumRule, demos: Demonstrations) -> None:
    wrong = Demonstrations(demos.observations, demos.actions, demos.episode_lengths, demos.rewards, seeds=[99, 12, 13])
    with pytest.warns(UserWarning, match="episode 0.*does not reproduce"):
        result = evaluate_against_expert(expert, "Pendulum-v1", wrong, env_kwargs=PENDULUM_KWARGS)
    assert result.start_matches.tolist() == [False, True, True]
    with pytest.raises(ValueError, match="does not reproduce"):
        evaluate_against_expert(expert, "Pendulum-v1", wrong, env_kwargs=PENDULUM_KWARGS, start_mismatch="raise")


def test_evaluate_checks_spaces(expert: PendulumRule) -> None:
    cartpole_like = Demonstrations(np.zeros((3, 4), np.float32), np.zeros((3, 1), np.float32), [3], seeds=[0])
    with pytest.raises(ValueError, match="observation shape"):
        evaluate_against_expert(expert, "Pendulum-v1", cartpole_like)


def test_trajectory_features() -> None:
    obs = np.arange(24, dtype=np.float32).reshape(4, 6)
    np.testing.assert_array_equal(TRAJECTORY_FEATURES["WaypointNav-v0"](obs), obs[:, -2:])
    assert trajectory_features("sb3_cmzdril:WaypointNav-v0") is TRAJECTORY_FEATURES["WaypointNav-v0"]
    np.testing.assert_array_equal(trajectory_features("Hopper-v5")(obs), obs)
    np.testing.assert_array_equal(trajectory_features(None)(obs), obs)


# ---------------------------------------------------------------------------------------------
# Callback
# ---------------------------------------------------------------------------------------------
class RecordingWriter(KVWriter):
    def __init__(self) -> None:
        self.dumps: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        self.dumps.append(dict(key_values))

    def close(self) -> None:
        pass


def tiny_ppo(seed: int = 0) -> PPO:
    env = gym.make("Pendulum-v1", **PENDULUM_KWARGS)
    return PPO(
        "MlpPolicy",
        env,
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        policy_kwargs={"net_arch": [8]},
        seed=seed,
        device="cpu",
    )


def read_csv(path: Any) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_callback_writes_csv_and_logs(tmp_path: Any, demos: Demonstrations) -> None:
    model = tiny_ppo()
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    path = tmp_path / "sub" / "eval.csv"
    held_out = demos.select([0, 1])
    callback = ExpertEvalCallback("Pendulum-v1", held_out, eval_every=1, csv_path=path, env_kwargs=PENDULUM_KWARGS)
    model.learn(64 * 3, callback=callback)

    rows = read_csv(path)
    assert tuple(rows[0]) == ExpertEvalCallback.CSV_COLUMNS
    # Epoch 0 is the policy before any update; the last update is evaluated at the end of training.
    assert [int(r["epoch"]) for r in rows] == [0, 1, 2, 3]
    assert [int(r["timesteps"]) for r in rows] == [0, 64, 128, 192]
    assert all(int(r["n_episodes"]) == 2 for r in rows)
    assert all(float(r["frechet_mean"]) > 0 and float(r["action_mse"]) > 0 for r in rows)
    # The row matches a direct evaluation of the final model.
    final = evaluate_against_expert(model, "Pendulum-v1", held_out, env_kwargs=PENDULUM_KWARGS)
    assert float(rows[-1]["return_mean"]) == pytest.approx(final.mean_return)
    assert float(rows[-1]["frechet_mean"]) == pytest.approx(final.mean_frechet)
    assert float(rows[-1]["action_mse"]) == pytest.approx(final.action_mse)
    assert callback.history[-1]["epoch"] == 3

    logged = [d for d in writer.dumps if "eval/mean_reward" in d]
    assert len(logged) == 4
    for key in ("eval/mean_reward", "eval/std_reward", "eval/mean_ep_length", "eval/frechet", "eval/action_mse"):
        assert all(key in d for d in logged)
    assert logged[-1]["eval/mean_reward"] == pytest.approx(final.mean_return)

    # Resumed run with a new callback: rows are kept, the restart epoch is not logged twice.
    resumed = ExpertEvalCallback("Pendulum-v1", held_out, eval_every=2, csv_path=path, env_kwargs=PENDULUM_KWARGS)
    model.learn(64 * 3, callback=resumed, reset_num_timesteps=False)
    rows = read_csv(path)
    assert [int(r["epoch"]) for r in rows] == [0, 1, 2, 3, 4, 6]
    assert path.read_text().count("epoch,timesteps") == 1


def test_callback_eval_every_and_vec_normalize(tmp_path: Any, demos: Demonstrations) -> None:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=0, env_kwargs=PENDULUM_KWARGS))
    model = PPO(
        "MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, policy_kwargs={"net_arch": [8]}, seed=0, device="cpu"
    )
    path = tmp_path / "eval.csv"
    callback = ExpertEvalCallback(
        "Pendulum-v1", demos.select([2]), eval_every=2, csv_path=path, env_kwargs=PENDULUM_KWARGS
    )
    model.learn(64 * 3, callback=callback)
    rows = read_csv(path)
    assert [int(r["epoch"]) for r in rows] == [0, 2, 3]  # n_steps * n_envs = 64 steps per update
    # The policy saw normalised observations, so the metric must normalise the demos the same way.
    vn = model.get_vec_normalize_env()
    assert float(rows[-1]["action_mse"]) == pytest.approx(action_mse(model, demos.select([2])))
    assert action_mse(model, demos.select([2])) == pytest.approx(
        action_mse(model, demos.select([2]), obs_transform=vn.normalize_obs)
    )
    assert action_mse(model, demos.select([2])) != pytest.approx(
        action_mse(model, demos.select([2]), obs_transform=lambda o: o)
    )


def test_callback_validates_arguments(tmp_path: Any, demos: Demonstrations) -> None:
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="eval_every"):
            ExpertEvalCallback("Pendulum-v1", demos, eval_every=bad)
    path = tmp_path / "other.csv"
    path.write_text("a,b\n1,2\n")
    model = tiny_ppo()
    callback = ExpertEvalCallback("Pendulum-v1", demos.select([0]), csv_path=path, env_kwargs=PENDULUM_KWARGS)
    with pytest.raises(ValueError, match="columns"):
        model.learn(64, callback=callback)


def test_lowest_u_choice_round_trips_and_a_damaged_file_is_named(tmp_path):
    kept = LowestDisagreementPolicy()
    kept.best_state, kept.best_epoch, kept.best_u = {"w": th.arange(4.0)}, 3, 0.25
    path = tmp_path / "lowest_u.pt"
    kept.save(path)
    back = LowestDisagreementPolicy()
    assert back.load(path) and back.best_epoch == 3 and back.best_u == 0.25
    assert th.equal(back.best_state["w"], th.arange(4.0))
    assert not LowestDisagreementPolicy().load(tmp_path / "absent.pt")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"lowest_u.pt is truncated or not a lowest-u policy file"):
        LowestDisagreementPolicy().load(path)


def test_make_env_names_the_env_and_the_kwargs_it_refuses():
    from sb3_cmzdril.metrics.evaluation import make_env

    with pytest.raises(ValueError, match=r"cannot make Pendulum-v1 with env_kwargs \{'nonsense': 1\}: TypeError"):
        make_env("Pendulum-v1", {"nonsense": 1})
    env = make_env("Pendulum-v1", {"max_episode_steps": 7})
    assert env.spec.max_episode_steps == 7
    env.close()
