"""Demonstrations from imitation-style trajectories and from Minari datasets (built locally)."""
from __future__ import annotations

import dataclasses
import sys
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from helpers import cartpole_expert, pendulum_expert
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.extras import MissingExtraError

FIELDS = ("observations", "actions", "rewards", "episode_lengths", "seeds")


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """The shape of imitation.data.types.TrajectoryWithRew (imitation itself pins an older SB3)."""

    obs: np.ndarray
    acts: np.ndarray
    infos: np.ndarray | None
    terminal: bool
    rews: np.ndarray


def play(env: gym.Env, policy, seeds: list[int | None], max_steps: int = 60) -> list[dict[str, Any]]:
    """Roll the scripted expert; each episode with T + 1 observations, as imitation and Minari store them."""
    episodes = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        o, a, r, terminal = [obs], [], [], False
        for _ in range(max_steps):
            act = policy(obs)[0]
            obs, rew, terminal, truncated, _ = env.step(act)
            o.append(obs)
            a.append(act)
            r.append(rew)
            if terminal or truncated:
                break
        episodes.append(
            {"obs": np.array(o), "acts": np.array(a), "rews": np.array(r), "terminal": terminal, "seed": seed}
        )
    return episodes


def npz_reference(episodes: list[dict[str, Any]], tmp_path, with_seeds: bool) -> Demonstrations:
    """The same episodes through our own format: from_episodes, save, load."""
    ours = Demonstrations.from_episodes(
        [{"observations": ep["obs"][:-1], "actions": ep["acts"], "rewards": ep["rews"],
          "seed": ep["seed"] if with_seeds else None} for ep in episodes]
    )
    ours.save(tmp_path / "ref.npz")
    return Demonstrations.load(tmp_path / "ref.npz")


def assert_same(demos: Demonstrations, reference: Demonstrations) -> None:
    for name in FIELDS:
        got, want = getattr(demos, name), getattr(reference, name)
        assert got.dtype == want.dtype and np.array_equal(got, want), name


@pytest.mark.parametrize("env_id, policy", [("Pendulum-v1", pendulum_expert), ("CartPole-v1", cartpole_expert)])
def test_trajectories_round_trip_to_our_npz(env_id, policy, tmp_path):
    episodes = play(gym.make(env_id), policy, seeds=[3, 4, 5], max_steps=40)
    trajectories = [Trajectory(ep["obs"], ep["acts"], np.array([{}] * len(ep["acts"])), ep["terminal"], ep["rews"])
                    for ep in episodes]
    demos = Demonstrations.from_trajectories(trajectories)
    assert_same(demos, npz_reference(episodes, tmp_path, with_seeds=False))
    assert demos.seeds.tolist() == [-1, -1, -1]  # imitation records no reset seeds
    as_dicts = Demonstrations.from_trajectories([{k: ep[k] for k in ("obs", "acts", "rews")} for ep in episodes])
    assert_same(as_dicts, demos)


def test_trajectories_without_rewards():
    demos = Demonstrations.from_trajectories([{"obs": np.zeros((4, 2)), "acts": np.ones((3, 1))}])
    assert demos.rewards is None and len(demos) == 3 and demos.observations.shape == (3, 2)


@pytest.mark.parametrize(
    "trajectories, message",
    [
        ([], "got no trajectories"),
        ({"obs": np.zeros((3, 2)), "acts": np.zeros((2, 1))}, "not a single trajectory"),
        ([{"obs": np.zeros((3, 2))}], r"lacks \['acts'\]"),
        ([{"obs": np.zeros((3, 2)), "acts": np.zeros((3, 1))}], "3 observations for 3 actions.*final one"),
        ([{"obs": np.zeros((1, 2)), "acts": np.zeros((0, 1))}], "has no actions"),
        ([{"obs": np.zeros((3, 2)), "acts": np.zeros((2, 1)), "rews": np.zeros(3)}], "3 rewards for 2 actions"),
        ([{"obs": {"a": np.zeros((3, 2))}, "acts": np.zeros((2, 1))}], "Dict or Tuple space"),
        ([{"obs": np.zeros((3, 2)), "acts": np.zeros((2, 1)), "rews": np.zeros(2)},
          {"obs": np.zeros((3, 2)), "acts": np.zeros((2, 1))}], "every episode or for none"),
    ],
)
def test_trajectory_errors(trajectories, message):
    with pytest.raises(ValueError, match=message):
        Demonstrations.from_trajectories(trajectories)


def test_a_seed_beyond_int64_is_a_clear_error():
    with pytest.raises(ValueError, match="seeds must fit in int64"):
        Demonstrations(np.zeros((2, 1)), np.zeros((2, 1)), [2], seeds=[2**64 - 1])


def test_from_minari_names_the_extra_when_minari_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "minari", None)  # as if minari were not installed
    expected = r"from_minari needs the 'minari' extra: pip install 'sb3-cmzdril\[minari\]'"
    with pytest.raises(MissingExtraError, match=expected):
        Demonstrations.from_minari("cartpole/expert-v0")


# -- Minari: datasets recorded here with its DataCollector, in a temporary MINARI_DATASETS_PATH ---------
@pytest.fixture
def minari_home(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari", reason="minari is in the 'minari' and 'test' extras")
    pytest.importorskip("jax", reason="minari's DataCollector needs minari[create] (in the 'test' extra)")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return minari


def collect(minari, env_id: str, policy, seeds: list[int | None], dataset_id: str, max_steps: int = 60):
    """Record episodes with minari's DataCollector; return the dataset and what was played."""
    env = minari.DataCollector(gym.make(env_id))
    played = play(env, policy, seeds, max_steps)
    # Given reference scores, minari does not roll a random policy 100 times to estimate them.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".* is set to None", category=UserWarning)  # author, permalink...
        dataset = env.create_dataset(dataset_id, algorithm_name="scripted", ref_min_score=0.0, ref_max_score=1.0,
                                     description="sb3-cmzdril test")
    env.close()
    return dataset, played


@pytest.mark.slow
@pytest.mark.parametrize("env_id, policy", [("Pendulum-v1", pendulum_expert), ("CartPole-v1", cartpole_expert)])
def test_minari_round_trips_to_our_npz_with_seeds(minari_home, env_id, policy, tmp_path):
    name = env_id.split("-")[0].lower()
    dataset, played = collect(minari_home, env_id, policy, seeds=[11, 12, 13], dataset_id=f"{name}/expert-v0")
    reference = npz_reference(played, tmp_path, with_seeds=True)
    assert_same(Demonstrations.from_minari(dataset), reference)
    # by id, from the local folder only
    assert_same(Demonstrations.from_minari(f"{name}/expert-v0"), reference)
    assert reference.seeds.tolist() == [11, 12, 13]


def test_minari_seed_is_replayable(minari_home):
    dataset, _ = collect(minari_home, "Pendulum-v1", pendulum_expert, seeds=[21, 22], dataset_id="pendulum/replay-v0")
    demos = Demonstrations.from_minari(dataset)
    env = gym.make("Pendulum-v1")
    for i in range(demos.n_episodes):
        obs, _ = env.reset(seed=int(demos.seeds[i]))
        assert np.array_equal(obs, demos.episode(i)["observations"][0])


def test_minari_filtered_dataset_and_oversized_seed(minari_home):
    big = 2**63 + 5  # Minari's own seeds are 64-bit unsigned; ours are int64
    dataset, played = collect(minari_home, "CartPole-v1", cartpole_expert, [1, big, 2], dataset_id="cartpole/mixed-v0")
    with pytest.warns(UserWarning, match=r"1 of 3 episodes .* outside \[0, 2\*\*63\)"):
        demos = Demonstrations.from_minari(dataset)
    assert demos.seeds.tolist() == [1, -1, 2]
    assert demos.episode_lengths.tolist() == [len(ep["acts"]) for ep in played]
    subset = dataset.filter_episodes(lambda episode: episode.id != 1)
    assert Demonstrations.from_minari(subset).seeds.tolist() == [1, 2]


def test_minari_errors(minari_home):
    with pytest.raises(FileNotFoundError, match="not found locally"):
        Demonstrations.from_minari("cartpole/absent-v0")
    with pytest.raises(TypeError, match="MinariDataset or a dataset id"):
        Demonstrations.from_minari(42)
