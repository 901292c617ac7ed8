"""Demonstrations: construction, persistence, selection and validation errors."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from gymnasium import spaces

from sb3_cmzdril.data.demos import FORMAT_VERSION, Demonstrations, as_demonstrations

OBS_SPACE = spaces.Box(-np.inf, np.inf, (3,), np.float32)
ACT_SPACE = spaces.Box(-1.0, 1.0, (2,), np.float32)


def make(lengths=(3, 2), seeds=(7, 8)) -> Demonstrations:
    n = sum(lengths)
    obs = np.arange(n * 3, dtype=np.float32).reshape(n, 3)
    act = np.linspace(-0.9, 0.9, n * 2, dtype=np.float32).reshape(n, 2)
    return Demonstrations(obs, act, lengths, rewards=np.ones(n), seeds=seeds)


def test_views_and_episode_boundaries():
    d = make()
    assert len(d) == 5 and d.n_episodes == 2
    assert d.episode_starts.tolist() == [0, 3]
    assert d.episode_returns.tolist() == [3.0, 2.0]
    ep = d.episode(1)
    assert ep["seed"] == 8 and np.array_equal(ep["observations"], d.observations[3:])


def test_save_load_roundtrip_is_exact(tmp_path):
    d = make()
    d.save(tmp_path / "d.npz")
    back = Demonstrations.load(tmp_path / "d.npz")
    for name in ("observations", "actions", "rewards", "episode_lengths", "seeds"):
        assert np.array_equal(getattr(back, name), getattr(d, name)), name
    assert [p.name for p in tmp_path.iterdir()] == ["d.npz"]  # no temporary file left behind


def test_save_without_rewards_and_unknown_seeds(tmp_path):
    d = Demonstrations(np.zeros((4, 3)), np.zeros((4, 2)), [4])
    d.save(tmp_path / "d.npz")
    back = Demonstrations.load(tmp_path / "d.npz")
    assert back.rewards is None and back.seeds.tolist() == [-1]


def test_select_keeps_order_and_seeds():
    d = make()
    s = d.select([1, 0])
    assert s.seeds.tolist() == [8, 7]
    assert np.array_equal(s.observations[:2], d.observations[3:])
    with pytest.raises(IndexError, match="out of range"):
        d.select([2])
    with pytest.raises(ValueError, match="at least one"):
        d.select([])


def test_from_episodes_and_as_demonstrations(tmp_path):
    eps = [{"observations": np.zeros((2, 3)), "actions": np.zeros((2, 2)), "seed": 3}]
    d = Demonstrations.from_episodes(eps)
    assert d.seeds.tolist() == [3] and d.rewards is None
    d.save(tmp_path / "x.npz")
    assert len(as_demonstrations(str(tmp_path / "x.npz"))) == 2
    assert len(as_demonstrations(eps)) == 2
    with pytest.raises(TypeError, match="expected Demonstrations"):
        as_demonstrations(42)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(observations=np.zeros((0, 3)), actions=np.zeros((0, 2)), episode_lengths=[]), "empty"),
        (dict(observations=np.zeros((3, 3)), actions=np.zeros((2, 2)), episode_lengths=[3]), "differ in length"),
        (dict(observations=np.zeros((3, 3)), actions=np.zeros((3, 2)), episode_lengths=[2]), "sum to 2"),
        (dict(observations=np.zeros((3, 3)), actions=np.zeros((3, 2)), episode_lengths=[3, 0]), "at least one step"),
        (
            dict(observations=np.array([[0, np.nan, 0]] * 3), actions=np.zeros((3, 2)), episode_lengths=[3]),
            "observations contains NaN",
        ),
        (
            dict(observations=np.zeros((3, 3)), actions=np.array([[0, np.inf]] * 3), episode_lengths=[3]),
            "actions contains NaN or inf",
        ),
        (
            dict(observations=np.zeros((3, 3)), actions=np.zeros((3, 2)), episode_lengths=[3], rewards=np.zeros(2)),
            "rewards have 2",
        ),
        (
            dict(observations=np.zeros((3, 3)), actions=np.zeros((3, 2)), episode_lengths=[3], seeds=[1, 2]),
            "2 seeds given for 1",
        ),
        (dict(observations=np.zeros(()), actions=np.zeros(3), episode_lengths=[3]), "n_steps, \\*obs_shape"),
    ],
)
def test_bad_arrays_raise_clear_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Demonstrations(**kwargs)


def test_final_observation_hint():
    with pytest.raises(ValueError, match="final observation"):
        Demonstrations(np.zeros((4, 3)), np.zeros((3, 2)), [3])


def test_from_episodes_errors():
    with pytest.raises(ValueError, match="no episodes"):
        Demonstrations.from_episodes([])
    with pytest.raises(ValueError, match="lacks"):
        Demonstrations.from_episodes([{"observations": np.zeros((2, 3))}])
    with pytest.raises(ValueError, match="2 observations but 1 actions"):
        Demonstrations.from_episodes([{"observations": np.zeros((2, 3)), "actions": np.zeros((1, 2))}])
    with pytest.raises(ValueError, match="every episode or for none"):
        Demonstrations.from_episodes(
            [
                {"observations": np.zeros((1, 3)), "actions": np.zeros((1, 2)), "rewards": np.zeros(1)},
                {"observations": np.zeros((1, 3)), "actions": np.zeros((1, 2))},
            ]
        )


def test_check_spaces_shapes():
    d = make()
    assert d.check_spaces(OBS_SPACE, ACT_SPACE) is d
    with pytest.raises(ValueError, match=r"observation shape \(3,\).*\(4,\)"):
        d.check_spaces(spaces.Box(-1, 1, (4,)), ACT_SPACE)
    with pytest.raises(ValueError, match=r"action shape \(2,\).*\(3,\)"):
        d.check_spaces(OBS_SPACE, spaces.Box(-1, 1, (3,)))
    with pytest.raises(ValueError, match="unsupported observation space Tuple"):
        d.check_spaces(spaces.Tuple([OBS_SPACE]), ACT_SPACE)
    with pytest.raises(ValueError, match="unsupported action space Tuple"):
        d.check_spaces(OBS_SPACE, spaces.Tuple([ACT_SPACE]))


def test_out_of_bounds_box_actions_are_clipped_with_a_warning():
    d = Demonstrations(np.zeros((3, 3)), np.array([[0.0, 0.5], [2.0, -3.0], [0.1, 0.1]]), [3])
    with pytest.warns(UserWarning, match="1 of 3 demonstration actions lie outside.*largest excess 2"):
        clipped = d.check_spaces(OBS_SPACE, ACT_SPACE)
    assert clipped.actions.tolist()[1] == [1.0, -1.0]
    assert d.actions[1, 0] == 2.0  # the original is untouched
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clipped.check_spaces(OBS_SPACE, ACT_SPACE)


def test_discrete_actions_checked():
    obs = np.zeros((3, 3))
    space = spaces.Discrete(2)
    ok = Demonstrations(obs, np.array([0.0, 1.0, 1.0]), [3]).check_spaces(OBS_SPACE, space)
    assert ok.actions.dtype == np.int64 and ok.actions.shape == (3,)
    with pytest.raises(ValueError, match=r"span \[0, 2\].*allows \[0, 1\]"):
        Demonstrations(obs, np.array([0, 1, 2]), [3]).check_spaces(OBS_SPACE, space)
    with pytest.raises(ValueError, match="integer actions"):
        Demonstrations(obs, np.array([0.0, 0.5, 1.0]), [3]).check_spaces(OBS_SPACE, space)


def test_load_errors_name_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        Demonstrations.load(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="bad.npz is corrupt"):
        Demonstrations.load(bad)
    partial = tmp_path / "partial.npz"
    np.savez(partial, observations=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"partial.npz lacks arrays \['actions', 'episode_lengths'\]"):
        Demonstrations.load(partial)


def test_a_newer_format_version_is_refused(tmp_path):
    demos = Demonstrations(np.zeros((3, 2)), np.zeros((3, 1)), [3])
    arrays = {"observations": demos.observations, "actions": demos.actions, "episode_lengths": demos.episode_lengths}
    np.savez(tmp_path / "future.npz", format_version=np.asarray(FORMAT_VERSION + 1), **arrays)
    with pytest.raises(ValueError, match=rf"future.npz has format_version {FORMAT_VERSION + 1}, newer"):
        Demonstrations.load(tmp_path / "future.npz")
    np.savez(tmp_path / "odd.npz", format_version=np.asarray("x"), **arrays)
    with pytest.raises(ValueError, match="odd.npz has an unreadable format_version"):
        Demonstrations.load(tmp_path / "odd.npz")
    np.savez(tmp_path / "old.npz", **arrays)  # files from before the version existed still load
    assert Demonstrations.load(tmp_path / "old.npz").n_episodes == 1
    demos.save(tmp_path / "now.npz")
    assert Demonstrations.load(tmp_path / "now.npz").n_episodes == 1
