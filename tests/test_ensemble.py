"""BCEnsemble: bootstrap members, disagreement forms, persistence, input errors."""
from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.ensemble import BCEnsemble, quantile_of_disagreement, share_on_bound

OBS = spaces.Box(-np.inf, np.inf, (3,), np.float32)
# Wide bounds: clipping would flatten members' predictions far from the data and hide disagreement.
WIDE = spaces.Box(-100.0, 100.0, (2,), np.float32)


@pytest.fixture(scope="module")
def linear_demos() -> Demonstrations:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(400, 3)).astype(np.float32)
    act = np.stack([obs[:, 0] - obs[:, 1], 0.5 * obs[:, 2]], axis=1)
    return Demonstrations(obs, act, [200, 200])


@pytest.fixture(scope="module")
def fitted(linear_demos) -> BCEnsemble:
    return BCEnsemble(OBS, WIDE, n_members=5, hidden_sizes=(32, 32), seed=0).fit(linear_demos, n_epochs=60)


def test_shapes_and_fit_quality(fitted, linear_demos):
    obs = linear_demos.observations[:7]
    assert fitted.member_outputs(obs).shape == (5, 7, 2)
    assert fitted.predict(obs).shape == (7, 2)
    assert fitted.disagreement(obs).shape == (7,)
    assert fitted.disagreement(obs[0]).shape == (1,)  # a single observation is a batch of one
    assert np.all(fitted.train_loss_ < 0.05)
    assert np.mean((fitted.predict(linear_demos.observations) - linear_demos.actions) ** 2) < 0.05


def test_members_differ_through_bootstrap_and_init(fitted, linear_demos):
    out = fitted.member_outputs(linear_demos.observations[:50]).copy()
    for i in range(1, 5):
        assert not np.allclose(out[0], out[i])


def test_same_seed_same_ensemble(linear_demos):
    a = BCEnsemble(OBS, WIDE, 3, (8,), seed=4).fit(linear_demos, n_epochs=3)
    b = BCEnsemble(OBS, WIDE, 3, (8,), seed=4).fit(linear_demos, n_epochs=3)
    c = BCEnsemble(OBS, WIDE, 3, (8,), seed=5).fit(linear_demos, n_epochs=3)
    obs = linear_demos.observations[:20]
    assert np.array_equal(a.member_outputs(obs), b.member_outputs(obs))
    assert not np.allclose(a.member_outputs(obs), c.member_outputs(obs))


def test_identical_members_do_not_disagree(fitted, linear_demos):
    clone = BCEnsemble(OBS, WIDE, 5, (32, 32), seed=0)
    clone.load_state_dict(fitted.state_dict())
    with th.no_grad():
        for p in list(clone.weights) + list(clone.biases):
            p[:] = p[0]
    far = linear_demos.observations[:10] * 50
    assert np.all(clone.disagreement(far) == 0.0)
    assert np.all(clone.disagreement(far, actions=np.ones((10, 2))) == 0.0)


def test_disagreement_grows_away_from_the_demos(fitted, linear_demos):
    near = fitted.disagreement(linear_demos.observations).mean()
    far = fitted.disagreement(linear_demos.observations + 6.0).mean()
    farther = fitted.disagreement(linear_demos.observations + 20.0).mean()
    assert near < far < farther
    assert far > 5 * near


NARROW = spaces.Box(-1.0, 1.0, (2,), np.float32)


@pytest.mark.parametrize("batch", [8, 100])  # numpy's path and torch's
def test_members_past_a_bound_agree_when_clipped_and_not_unclipped(linear_demos, batch):
    # An expert often on a bound (two thirds of these actions are): off its states, members extrapolate past it.
    saturated = Demonstrations(linear_demos.observations, np.clip(3.0 * linear_demos.actions, -1.0, 1.0), [200, 200])
    clipped, unclipped = (BCEnsemble(OBS, NARROW, 4, (16,), disagreement=form, seed=2).fit(saturated, n_epochs=20)
                          for form in ("std", "std_unclipped"))
    far = np.tile(np.array([[30.0, -30.0, 30.0]], np.float32), (batch, 1))
    assert np.all(clipped.disagreement(far) == 0.0)  # every member on the same bound
    raw = unclipped.member_outputs(far, clip=False).copy()
    assert np.all(np.abs(raw) > 1.0)
    np.testing.assert_allclose(unclipped.disagreement(far), raw.std(axis=0).mean(axis=1), rtol=1e-4)
    assert np.all(unclipped.disagreement(far) > 0.1)


def _on_bound(linear_demos: Demonstrations, n_entries: int) -> Demonstrations:
    """The demos in (-1, 1) with the first ``n_entries`` action entries set to a bound."""
    actions = np.clip(linear_demos.actions, -0.99, 0.99).copy()
    flat = actions.reshape(-1)
    flat[:n_entries] = np.where(np.arange(n_entries) % 2 == 0, 1.0, -1.0)
    return Demonstrations(linear_demos.observations, actions, [200, 200])


@pytest.mark.parametrize("n_entries, form", [(0, "std"), (7, "std"), (8, "std_unclipped"), (800, "std_unclipped")])
def test_auto_leaves_actions_unclipped_from_one_percent_of_entries_on_a_bound(linear_demos, n_entries, form):
    # 400 steps x 2 dimensions: 8 entries are 1%.
    ens = BCEnsemble(OBS, NARROW, 3, (8,), disagreement="auto", seed=0)
    assert ens.disagreement_form == "std"  # before fit() has seen the demonstrations
    ens.fit(_on_bound(linear_demos, n_entries), n_epochs=1)
    assert ens.disagreement_form == form
    assert f"disagreement='auto' (-> '{form}')" in repr(ens)


def test_auto_scores_as_the_form_it_chose_and_keeps_it_through_save_and_load(linear_demos, tmp_path):
    saturated = Demonstrations(linear_demos.observations, np.clip(3.0 * linear_demos.actions, -1.0, 1.0), [200, 200])
    auto, unclipped = (BCEnsemble(OBS, NARROW, 4, (16,), disagreement=form, seed=2).fit(saturated, n_epochs=5)
                       for form in ("auto", "std_unclipped"))
    far = np.tile(np.array([[30.0, -30.0, 30.0]], np.float32), (8, 1))
    np.testing.assert_array_equal(auto.disagreement(far), unclipped.disagreement(far))
    auto.save(tmp_path / "auto.pt")
    back = BCEnsemble.load(tmp_path / "auto.pt")
    assert (back.requested_disagreement, back.disagreement_form) == ("auto", "std_unclipped")
    np.testing.assert_array_equal(back.disagreement(far), unclipped.disagreement(far))
    fresh = BCEnsemble(OBS, NARROW, 4, (16,), disagreement="auto", seed=2)
    fresh.load_state_dict(auto.state_dict())
    assert fresh.disagreement_form == "std_unclipped"


def test_share_on_bound_counts_entries_exactly_on_a_finite_bound():
    half_open = spaces.Box(np.array([-1.0, -np.inf], np.float32), np.array([1.0, 2.0], np.float32))
    actions = np.array([[1.0, 2.0], [-1.0, -5.0], [0.999999, 1e30], [0.0, 2.0 - 1e-6]], np.float32)
    assert share_on_bound(actions, half_open) == 3 / 8  # 0.999999 and 2 - 1e-6 are off it in float32
    assert share_on_bound(actions[:0], half_open) == 0.0
    assert share_on_bound(np.array([0, 2, 2]), spaces.Discrete(3)) == 0.0


def test_auto_is_the_std_form_for_discrete_actions(cartpole_demos):
    # Its actions are 0 and 1, the first and last of the space: "on a bound" means a Box's bounds only.
    ens = BCEnsemble(spaces.Box(-np.inf, np.inf, (4,), np.float32), spaces.Discrete(2), 3, (8,), disagreement="auto")
    assert ens.fit(cartpole_demos, n_epochs=1).disagreement_form == "std"


def test_the_unclipped_form_needs_box_actions():
    with pytest.raises(ValueError, match="disagreement='std_unclipped' needs Box actions"):
        BCEnsemble(OBS, spaces.Discrete(3), disagreement="std_unclipped")


def test_std_form_matches_numpy(fitted, linear_demos):
    obs = linear_demos.observations[:9]
    out = fitted.member_outputs(obs).copy()
    expected = out.std(axis=0, ddof=0).mean(axis=1)
    np.testing.assert_allclose(fitted.disagreement(obs), expected, rtol=1e-5)


def test_quadratic_form_is_action_covariance_action(linear_demos):
    ens = BCEnsemble(OBS, WIDE, 4, (16,), disagreement="quadratic", seed=1).fit(linear_demos, n_epochs=5)
    obs = linear_demos.observations[:6] + 3.0
    acts = np.random.default_rng(1).normal(size=(6, 2)).astype(np.float32)
    out = ens.member_outputs(obs).copy()
    expected = [a @ np.cov(out[:, b, :].T, bias=True) @ a for b, a in enumerate(acts)]
    np.testing.assert_allclose(ens.disagreement(obs, acts), expected, rtol=1e-4)
    with pytest.raises(ValueError, match="needs the agent's actions"):
        ens.disagreement(obs)


def test_predictions_are_clipped_to_the_bounds(linear_demos):
    tight = spaces.Box(-0.5, 0.5, (2,), np.float32)
    with pytest.warns(UserWarning, match="clipping"):
        ens = BCEnsemble(OBS, tight, 3, (8,), seed=0).fit(linear_demos, n_epochs=3)
    out = ens.member_outputs(linear_demos.observations * 100)
    assert out.min() >= -0.5 and out.max() <= 0.5


def test_discrete_disagreement_uses_the_agents_action(cartpole_demos):
    space = spaces.Box(-np.inf, np.inf, (4,), np.float32)
    ens = BCEnsemble(space, spaces.Discrete(2), 5, (16,), seed=0).fit(cartpole_demos, n_epochs=100, learning_rate=1e-2)
    obs = cartpole_demos.observations[:8]
    probs = ens.member_outputs(obs).copy()
    np.testing.assert_allclose(probs.sum(axis=2), 1.0, rtol=1e-5)
    acts = cartpole_demos.actions[:8]
    expected = probs[:, np.arange(8), acts].std(axis=0)
    np.testing.assert_allclose(ens.disagreement(obs, acts), expected, rtol=1e-5)
    # agreement on the expert's own action is high where the expert was seen
    assert np.mean(ens.predict(cartpole_demos.observations) == cartpole_demos.actions) > 0.9
    with pytest.raises(ValueError, match=r"must lie in \[0, 1\]"):
        ens.disagreement(obs, np.full(8, 2))


def test_quantile_threshold(fitted, linear_demos):
    u = fitted.disagreement(linear_demos.observations)
    assert quantile_of_disagreement(fitted, linear_demos, 0.98) == pytest.approx(np.quantile(u, 0.98))
    assert np.mean(u <= quantile_of_disagreement(fitted, linear_demos, 0.5)) == pytest.approx(0.5, abs=0.01)
    with pytest.raises(ValueError, match="quantile q"):
        quantile_of_disagreement(fitted, linear_demos, 1.5)


def test_save_load_identity(fitted, linear_demos, tmp_path):
    fitted.save(tmp_path / "ens.pt")
    back = BCEnsemble.load(tmp_path / "ens.pt")
    obs = linear_demos.observations[:30] + 2.0
    assert np.array_equal(back.member_outputs(obs), fitted.member_outputs(obs))
    assert back.hidden_sizes == (32, 32) and back.n_members == 5
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        BCEnsemble.load(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.pt is corrupt"):
        BCEnsemble.load(tmp_path / "junk.pt")


def test_input_errors(fitted):
    with pytest.raises(RuntimeError, match="not fitted"):
        BCEnsemble(OBS, WIDE, 2, (4,)).disagreement(np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"shape \(4,\) do not match the observation space's \(3,\)"):
        fitted.disagreement(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="NaN or inf"):
        fitted.disagreement(np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="at least 2 members"):
        BCEnsemble(OBS, WIDE, n_members=1)
    with pytest.raises(ValueError, match="disagreement must be one of"):
        BCEnsemble(OBS, WIDE, disagreement="entropy")
    with pytest.raises(ValueError, match="unsupported observation space Tuple"):
        BCEnsemble(spaces.Tuple([OBS]), WIDE)
    with pytest.raises(ValueError, match="unsupported action space Tuple"):
        BCEnsemble(OBS, spaces.Tuple([WIDE]))
