"""Shared fixtures: small scripted-expert demonstrations and a tiny experiment workspace. Plain
helpers (the tiny setting, the experts, hand-written run folders) are in helpers.py."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from helpers import ENV, POOL_EPISODES, SHORT_OFFPOLICY_EPOCH, TINY_PPO_YAML, cartpole_expert, pendulum_expert, record
from sb3_cmzdril.data.demos import Demonstrations

torch.set_num_threads(1)
# Ray renices its workers to 15: beside a test of another pytest-xdist worker they got almost no CPU,
# and a Ray test that takes 20 s alone ran past its 300 s timeout. Read by the Ray processes the tests
# start, which inherit it.
os.environ.setdefault("RAY_worker_niceness", "0")


@pytest.fixture(scope="session")
def pendulum_demos() -> Demonstrations:
    return record("Pendulum-v1", pendulum_expert, n_episodes=2, max_steps=100)


@pytest.fixture(scope="session")
def cartpole_demos() -> Demonstrations:
    return record("CartPole-v1", cartpole_expert, n_episodes=2, max_steps=100)


@pytest.fixture(scope="module")
def tiny_experiment(tmp_path_factory) -> dict[str, Path]:
    """A demo pool in the <demos_dir>/<EnvName>/demos.npz layout and the tiny CMZDRIL hyperparameters:
    ``root``, ``demos_dir``, ``pool`` and ``hp`` (the YAML file)."""
    root = tmp_path_factory.mktemp("exp")
    pool = root / "experts" / ENV / "demos.npz"
    pool.parent.mkdir(parents=True)
    record(ENV, pendulum_expert, n_episodes=POOL_EPISODES, max_steps=50, seed=100).save(pool)
    hp = root / "cmzdril.yml"
    hp.write_text(TINY_PPO_YAML)
    return {"root": root, "demos_dir": root / "experts", "pool": pool, "hp": hp}



@pytest.fixture
def short_offpolicy_epochs(monkeypatch) -> int:
    """Off-policy epochs of :data:`SHORT_OFFPOLICY_EPOCH` steps for the runs a test executes in this process."""
    from sb3_cmzdril.training import runs, spec

    monkeypatch.setattr(spec, "OFFPOLICY_EPOCH_STEPS", SHORT_OFFPOLICY_EPOCH)
    monkeypatch.setattr(runs, "OFFPOLICY_EPOCH_STEPS", SHORT_OFFPOLICY_EPOCH)
    return SHORT_OFFPOLICY_EPOCH
