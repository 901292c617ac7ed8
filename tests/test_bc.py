"""NLL behaviour cloning: early stopping on held-out demo steps keeps the best weights."""
from __future__ import annotations

import numpy as np
import pytest
import torch as th

from helpers import TINY
from sb3_cmzdril import CMZDRIL


def _cloner(pendulum_demos, **kwargs):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, **kwargs})
    model.bc.set_demonstrations(pendulum_demos)
    return model.bc


def test_early_stopping_stops_and_restores_the_best_weights(pendulum_demos):
    bc = _cloner(pendulum_demos, bc_learning_rate=3e-2)  # a large step overfits 400 steps quickly
    kept = {}
    original = bc.epoch

    def epoch(*args, **kwargs):
        loss = original(*args, **kwargs)
        kept[len(kept) + 1] = {k: v.clone() for k, v in bc.policy.state_dict().items()}
        return loss

    bc.epoch = epoch
    result = bc.train_early_stopping(max_epochs=300, validation_fraction=0.25, patience=5)
    assert result.epochs < 300  # it stopped
    assert result.epochs - result.best_epoch == 5
    best = int(np.argmin(result.validation_nll))
    assert best == result.best_epoch and result.validation_nll[best] < result.validation_nll[0]
    for key, value in bc.policy.state_dict().items():  # the weights of the best epoch are back
        assert th.equal(value, kept[result.best_epoch][key]), key
    assert not bc.optimizer.state  # fresh Adam moments for the BC epochs that follow


def test_no_validation_trains_every_epoch_on_every_step(pendulum_demos):
    bc = _cloner(pendulum_demos)
    result = bc.train_early_stopping(max_epochs=7, validation_fraction=0.0)
    assert result.epochs == result.best_epoch == 7 and len(result.train_nll) == 7 and not result.validation_nll


def test_bad_arguments(pendulum_demos):
    bc = _cloner(pendulum_demos)
    with pytest.raises(ValueError, match="validation_fraction"):
        bc.train_early_stopping(10, validation_fraction=1.0)
    with pytest.raises(ValueError, match="patience"):
        bc.train_early_stopping(10, patience=0)
    with pytest.raises(ValueError, match="bc_validation_fraction"):
        CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, bc_validation_fraction=-0.1)


def test_pretrain_reports_the_curve_and_the_log_std(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos,
                    **{**TINY, "bc_pretrain_epochs": 40, "log_std_floor": -0.5})
    info = model.pretrain()
    assert len(model.pretrain_history["validation_nll"]) == info["bc_epochs"] + 1
    assert 1 <= info["bc_best_epoch"] <= info["bc_epochs"] <= 40
    assert info["bc_log_std"] >= -0.5 - 1e-6
    assert info["bc_log_std"] == pytest.approx(float(model.policy.log_std.detach().mean()))


def test_refit_learns_the_chosen_number_of_epochs_afresh_on_every_step(pendulum_demos):
    bc = _cloner(pendulum_demos)
    initial = {k: v.clone() for k, v in bc.policy.state_dict().items()}
    chosen = bc.train_early_stopping(max_epochs=12, validation_fraction=0.25, patience=3)
    refitted = _cloner(pendulum_demos)
    refitted.policy.load_state_dict(initial)
    result = refitted.train_early_stopping(max_epochs=12, validation_fraction=0.25, patience=3, refit=True)
    assert result.best_epoch == chosen.best_epoch > 0  # the same split picks the same epoch count
    assert result.refit_epochs == result.best_epoch and len(result.refit_nll) == result.best_epoch
    # From the initial weights, every demo step: the refit's last epoch sees all of them.
    assert result.refit_nll[-1] == pytest.approx(refitted.nll(), rel=0.5)
    assert any(not th.equal(v, bc.policy.state_dict()[k]) for k, v in refitted.policy.state_dict().items())
    assert not refitted.optimizer.state


def test_refit_is_a_constructor_option_reported_by_pretrain(pendulum_demos):
    model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos,
                    **{**TINY, "bc_pretrain_epochs": 20, "bc_refit": True})
    info = model.pretrain()
    assert info["bc_refit_epochs"] == info["bc_best_epoch"] >= 1
    plain = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=pendulum_demos, **{**TINY, "bc_pretrain_epochs": 20})
    assert plain.pretrain()["bc_refit_epochs"] == 0
