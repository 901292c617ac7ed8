"""The pytest plugin of benchmarks/speed/sb3_suite.py (``-p sb3_suite_plugin``): CMZDRIL stands in
for SB3's PPO (or CMZDRILSAC for SAC, ``--sb3-algo sac``), and only SB3's cases of that algorithm
are kept.

Before SB3's test modules are imported it replaces ``stable_baselines3.PPO`` (``.SAC``) by a CMZDRIL
(CMZDRILSAC) on its defaults whose demonstrations are recorded from the model's own env with random
actions (a few hundred steps). It keeps the cases parametrised with the algorithm and the
unparametrised tests whose code uses it and no other; those that differ by design (:data:`BY_DESIGN`)
run only with ``--sb3-by-design``.
"""
from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import numpy as np

#: per algorithm, the test files whose cases differ by design: returns or learning checked against the
#: env's reward, which the imitation reward replaces (test_gae.py, test_identity.py), and the default
#: run name, which is the class's (test_tensorboard.py)
BY_DESIGN = {"ppo": ("test_gae.py", "test_identity.py", "test_tensorboard.py"),
             "sac": ("test_identity.py", "test_tensorboard.py")}
#: random-action steps recorded per model (split over the envs of a VecEnv)
DEMO_STEPS = 256
_ALGOS = ("A2C", "DQN", "PPO", "SAC", "TD3", "DDPG", "HER")


def _record_demos(venv: Any, n_steps: int = DEMO_STEPS) -> Any:
    """Random-action demonstrations from ``venv`` (raw observations, one episode per env)."""
    from stable_baselines3.common.vec_env import VecNormalize, unwrap_vec_wrapper

    from sb3_cmzdril.data.demos import Demonstrations

    vec_normalize = unwrap_vec_wrapper(venv, VecNormalize)
    was_training = vec_normalize.training if vec_normalize is not None else False
    if vec_normalize is not None:
        vec_normalize.training = False  # recording must not move the user's running statistics

    def raw(obs: Any) -> Any:
        return vec_normalize.get_original_obs() if vec_normalize is not None else obs

    n_envs = venv.num_envs
    steps = max(16, n_steps // n_envs)
    venv.action_space.seed(0)
    obs = raw(venv.reset())
    observations: list[Any] = []
    actions = []
    for _ in range(steps):
        act = np.array([venv.action_space.sample() for _ in range(n_envs)])
        observations.append(obs)
        actions.append(act)
        obs, _, _, _ = venv.step(act)
        obs = raw(obs)
    venv.reset()
    if vec_normalize is not None:
        vec_normalize.training = was_training
    episodes = []
    for i in range(n_envs):
        if isinstance(observations[0], dict):
            ep_obs: Any = {k: np.stack([o[k][i] for o in observations]) for k in observations[0]}
        else:
            ep_obs = np.stack([o[i] for o in observations])
        episodes.append({"observations": ep_obs, "actions": np.stack([a[i] for a in actions])})
    return Demonstrations.from_episodes(episodes)


def _make_stand_in(algo: str) -> type:
    from sb3_cmzdril import CMZDRIL, CMZDRILSAC

    base = {"ppo": CMZDRIL, "sac": CMZDRILSAC}[algo]

    class StandIn(base):  # type: ignore[valid-type,misc]
        """The package's learner with demonstrations recorded from its env when none are given."""

        def __init__(self, policy: Any, env: Any, *args: Any, **kwargs: Any) -> None:
            super().__init__(policy, env, *args, **kwargs)
            if self.demonstrations is None and self.env is not None and kwargs.get("_init_setup_model", True):
                self.demonstrations = _record_demos(self.env)

    StandIn.__name__ = StandIn.__qualname__ = algo.upper()
    return StandIn


def pytest_configure(config: Any) -> None:
    import importlib

    import stable_baselines3

    algo = config.getoption("sb3_algo", "ppo")
    stand_in = _make_stand_in(algo)
    setattr(stable_baselines3, algo.upper(), stand_in)
    setattr(importlib.import_module(f"stable_baselines3.{algo}"), algo.upper(), stand_in)


def _is_case_of(item: Any, algo: str) -> bool:
    others = tuple(a for a in _ALGOS if a != algo.upper())
    params = item.nodeid.partition("[")[2].rstrip("]")
    if algo in [p.lower() for p in params.split("-")]:  # [PPO], [True-PPO], test_tensorboard's [ppo]
        return True
    if any(other in params for other in others):
        return False
    try:
        source = inspect.getsource(item.function)
    except (OSError, TypeError):
        return False
    return algo.upper() in source and not any(other in source for other in others)


def pytest_collection_modifyitems(session: Any, config: Any, items: list[Any]) -> None:
    by_design = config.getoption("sb3_by_design", False)
    algo = config.getoption("sb3_algo", "ppo")
    keep, drop = [], []
    for item in items:
        designed = Path(str(item.fspath)).name in BY_DESIGN[algo]
        (keep if _is_case_of(item, algo) and designed == by_design else drop).append(item)
    items[:] = keep
    config.hook.pytest_deselected(items=drop)


def pytest_addoption(parser: Any) -> None:
    parser.addoption("--sb3-by-design", action="store_true", dest="sb3_by_design",
                     help="run only the cases that differ by design")
    parser.addoption("--sb3-algo", choices=sorted(BY_DESIGN), default="ppo", dest="sb3_algo",
                     help="the algorithm whose cases run, with the package's learner in its place")
