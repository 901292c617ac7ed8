"""SB3's own PPO tests with CMZDRIL standing in for PPO: how much of a drop-in replacement it is.

    python benchmarks/sb3_suite.py /path/to/stable-baselines3 [--by-design] [-- pytest args]

The argument is a checkout of the stable-baselines3 repository (only its ``tests/`` and
``pyproject.toml`` are used; nothing is fetched or modified). This file is also the pytest plugin
(``-p sb3_suite``) that the command loads: before SB3's test modules are imported it replaces
``stable_baselines3.PPO`` by :class:`CMZDRILAsPPO`, a CMZDRIL on its defaults whose demonstrations
are recorded from the model's own env with random actions (a few hundred steps), and it keeps only
the PPO cases: those parametrised with PPO, and unparametrised tests whose code uses PPO.

Cases that differ from PPO by design are counted apart (``--by-design`` lists them; the README's
"Spaces" paragraph says why): ``test_gae.py`` (it checks PPO's returns against the env reward, which
CMZDRIL replaces), ``test_identity.py`` (PPO must learn to a reward threshold in a few thousand
steps from the env reward), and ``test_tensorboard.py`` (CMZDRIL's default run name is
``CMZDRIL``, not ``PPO``).

The summary line at the end is pytest's; the counts go to docs/sb3_suite.md.
"""
from __future__ import annotations

import argparse
import inspect
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

BY_DESIGN = ("test_gae.py", "test_identity.py", "test_tensorboard.py")
#: random-action steps recorded per model (split over the envs of a VecEnv)
DEMO_STEPS = 256
_OTHER_ALGOS = ("A2C", "DQN", "SAC", "TD3", "DDPG", "HER")


def _record_demos(venv: Any, n_steps: int = DEMO_STEPS) -> Any:
    """Random-action demonstrations from ``venv`` (raw observations, one episode per env)."""
    from stable_baselines3.common.vec_env import VecNormalize, unwrap_vec_wrapper

    from sb3_cmzdril.demos import Demonstrations

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


def _make_stand_in() -> type:
    from sb3_cmzdril import CMZDRIL

    class CMZDRILAsPPO(CMZDRIL):
        """CMZDRIL with demonstrations recorded from its env when none are given."""

        def __init__(self, policy: Any, env: Any, *args: Any, **kwargs: Any) -> None:
            super().__init__(policy, env, *args, **kwargs)
            if self.demonstrations is None and self.env is not None and kwargs.get("_init_setup_model", True):
                self.demonstrations = _record_demos(self.env)

    CMZDRILAsPPO.__name__ = CMZDRILAsPPO.__qualname__ = "PPO"
    return CMZDRILAsPPO


def pytest_configure(config: Any) -> None:
    import stable_baselines3
    import stable_baselines3.ppo

    stand_in = _make_stand_in()
    stable_baselines3.PPO = stand_in  # type: ignore[misc]
    stable_baselines3.ppo.PPO = stand_in  # type: ignore[misc]


def _is_ppo_case(item: Any) -> bool:
    params = item.nodeid.partition("[")[2].rstrip("]")
    if "ppo" in [p.lower() for p in params.split("-")]:  # [PPO], [True-PPO], test_tensorboard's [ppo]
        return True
    if any(algo in params for algo in _OTHER_ALGOS):
        return False
    try:
        source = inspect.getsource(item.function)
    except (OSError, TypeError):
        return False
    return "PPO" in source and not any(algo in source for algo in _OTHER_ALGOS)


def pytest_collection_modifyitems(session: Any, config: Any, items: list[Any]) -> None:
    by_design = config.getoption("sb3_by_design", False)
    keep, drop = [], []
    for item in items:
        designed = Path(str(item.fspath)).name in BY_DESIGN
        (keep if _is_ppo_case(item) and designed == by_design else drop).append(item)
    items[:] = keep
    config.hook.pytest_deselected(items=drop)


def pytest_addoption(parser: Any) -> None:
    parser.addoption("--sb3-by-design", action="store_true", dest="sb3_by_design",
                     help="run only the PPO cases that differ by design")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkout", type=Path, help="a stable-baselines3 checkout (its tests/ are run)")
    parser.add_argument("--by-design", action="store_true", help="run the cases that differ by design instead")
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    args = parser.parse_args(argv[: len(argv) - len(extra) - (1 if extra or "--" in argv else 0)])
    tests = args.checkout / "tests"
    if not tests.is_dir():
        print(f"error: {args.checkout} has no tests/ folder (is it a stable-baselines3 checkout?)", file=sys.stderr)
        return 2
    env = dict(os.environ)
    here = str(Path(__file__).resolve().parent)
    env["PYTHONPATH"] = os.pathsep.join([here, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("PYTHONHASHSEED", "0")
    env.setdefault("OMP_NUM_THREADS", "1")
    # Node ids among the pytest arguments (tests/test_x.py::case) replace the whole tests/ folder.
    targets = [] if any(not a.startswith("-") for a in extra) else [str(tests)]
    cmd = [sys.executable, "-m", "pytest", *targets, "-p", "sb3_suite", "-q", "-p", "no:cacheprovider"]
    # Modules whose optional dependencies are missing (ale_py for test_utils.py) hold no PPO case.
    cmd.append("--continue-on-collection-errors")
    if args.by_design:
        cmd.append("--sb3-by-design")
    return subprocess.call(cmd + extra, cwd=args.checkout, env=env)


if __name__ == "__main__":
    sys.exit(main())
