"""`pretrained`, for both learners: a saved model loads with the flag it was saved with, weights a
model is given (set_parameters, or by hand with the flag set) are not cloned or refitted again, and a
CMZDRILSAC zip saved while the flag was a plain attribute still loads pretrained."""
from __future__ import annotations

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest

from helpers import TINY, TINY_SAC
from sb3_cmzdril import CMZDRIL, CMZDRILSAC, Demonstrations

TINY_FOR = {
    CMZDRIL: TINY,
    CMZDRILSAC: dict(TINY_SAC, ensemble_hidden=TINY["ensemble_hidden"], ensemble_epochs=TINY["ensemble_epochs"],
                     bc_pretrain_epochs=TINY["bc_pretrain_epochs"], seed=0, device="cpu"),
}
LEARNERS = pytest.mark.parametrize("cls", [CMZDRIL, CMZDRILSAC], ids=["CMZDRIL", "CMZDRILSAC"])


def _model(cls, demos: Demonstrations, seed: int = 0):
    return cls("MlpPolicy", "Pendulum-v1", demonstrations=demos, **{**TINY_FOR[cls], "seed": seed})


def _count_pretraining(model) -> dict[str, int]:
    """Count the model's BC pretraining runs and ensemble fits from now on."""
    calls = {"clone": 0, "fit": 0}
    clone, fit = model.bc.train_early_stopping, model.ensemble.fit

    def counted_clone(*args, **kwargs):
        calls["clone"] += 1
        return clone(*args, **kwargs)

    def counted_fit(*args, **kwargs):
        calls["fit"] += 1
        return fit(*args, **kwargs)

    model.bc.train_early_stopping, model.ensemble.fit = counted_clone, counted_fit
    return calls


def _actions(model, demos: Demonstrations) -> np.ndarray:
    return model.predict(demos.observations[:30], deterministic=True)[0]


@LEARNERS
def test_a_model_saved_before_pretraining_is_pretrained_at_its_first_learn_after_loading(cls, pendulum_demos, tmp_path):
    _model(cls, pendulum_demos).save(tmp_path / "m.zip")
    loaded = cls.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), device="cpu")
    assert not loaded.pretrained
    calls = _count_pretraining(loaded)
    loaded.learn(64)
    assert calls == {"clone": 1, "fit": 1} and loaded.pretrained


@LEARNERS
def test_set_parameters_of_a_pretrained_model_is_learnt_from_without_pretraining(cls, pendulum_demos, tmp_path):
    trained = _model(cls, pendulum_demos)
    trained.pretrain()
    trained.save(tmp_path / "m.zip")
    fresh = _model(cls, pendulum_demos, seed=7)
    assert not fresh.pretrained
    fresh.set_parameters(str(tmp_path / "m.zip"), device="cpu")
    assert fresh.pretrained
    np.testing.assert_array_equal(_actions(fresh, pendulum_demos), _actions(trained, pendulum_demos))
    calls = _count_pretraining(fresh)
    fresh.learn(64)
    assert calls == {"clone": 0, "fit": 0} and fresh.reward_rule is not None


@LEARNERS
def test_weights_put_in_by_hand_and_marked_pretrained_are_learnt_from(cls, pendulum_demos):
    trained = _model(cls, pendulum_demos)
    trained.pretrain()
    by_hand = _model(cls, pendulum_demos, seed=3)
    by_hand.policy.load_state_dict(trained.policy.state_dict())
    by_hand.ensemble.load_state_dict(trained.ensemble.state_dict())
    by_hand.pretrained = True
    calls = _count_pretraining(by_hand)
    by_hand.learn(64)
    assert calls == {"clone": 0, "fit": 0} and by_hand.reward_rule is not None
    by_hand.pretrained = False  # the next learn() clones and refits from the start
    assert not by_hand.pretrained
    by_hand.pretrain()
    assert calls == {"clone": 1, "fit": 1} and by_hand.pretrained


def test_a_cmzdrilsac_zip_with_the_plain_pretrained_attribute_loads_pretrained(pendulum_demos, tmp_path):
    model = _model(CMZDRILSAC, pendulum_demos)
    model.learn(64)
    model.save(tmp_path / "now.zip")
    # The zip as CMZDRILSAC saved it while `pretrained` was a plain attribute: the flag under that name.
    old = tmp_path / "old.zip"
    with zipfile.ZipFile(tmp_path / "now.zip") as src, zipfile.ZipFile(old, "w") as dst:
        for name in src.namelist():
            blob = src.read(name)
            if name == "data":
                data = json.loads(blob)
                data["pretrained"] = data.pop("_policy_pretrained")
                blob = json.dumps(data).encode()
            dst.writestr(name, blob)
    loaded = CMZDRILSAC.load(old, env=gym.make("Pendulum-v1"), device="cpu")
    assert loaded.pretrained and "pretrained" not in vars(loaded)
    np.testing.assert_array_equal(loaded.reward_rule.get_state(), model.reward_rule.get_state())
    calls = _count_pretraining(loaded)
    loaded.learn(64, reset_num_timesteps=False)
    assert calls == {"clone": 0, "fit": 0}
