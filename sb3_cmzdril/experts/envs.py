"""Environment ids and seeds as the commands take them: naming, checking, and the training VecEnv.

The checks run before a command creates any folder, so a typo leaves nothing behind.
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym

from sb3_cmzdril.errors import UserError


def env_name(env_id: str) -> str:
    """``module:EnvId-v0`` -> ``EnvId-v0`` (used for default folder names)."""
    return env_id.rsplit(":", 1)[-1]


def check_env_id(env_id: str) -> str:
    """The env id if gymnasium knows it (importing a ``module:`` prefix first) and its module imports
    with the optional dependencies it needs, else a UserError (a ValueError) naming the problem."""
    import importlib

    # A bare WaypointNav-v0 needs no import here: the package's __init__, which Python runs before
    # any of its modules, has registered it.
    module, sep, name = env_id.rpartition(":")
    if sep:
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise UserError(f"unknown environment {env_id!r}: cannot import module {module!r} ({e})") from None
    try:
        spec = gym.spec(name if sep else env_id)
    except gym.error.Error as e:
        raise UserError(f"unknown environment {env_id!r}: {e}") from None
    # gymnasium raises DependencyNotInstalled (Box2D, MuJoCo) when the env's module is imported, which
    # gym.make does after a command has made its folders: import it now. Other import errors are bugs
    # in that module and keep their traceback.
    if isinstance(spec.entry_point, str) and ":" in spec.entry_point:
        try:
            importlib.import_module(spec.entry_point.split(":", 1)[0])
        except gym.error.DependencyNotInstalled as e:
            raise UserError(f"cannot make {env_id}: {e}") from None
    return env_id


def check_seed(seed: int) -> int:
    """A reset/network seed: numpy and gymnasium accept integers in [0, 2**32)."""
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**32:
        raise UserError(f"seed must be an integer in [0, 2**32), got {seed!r}")
    return int(seed)


def make_vec_env(env_id: str, n_envs: int, seed: int, env_kwargs: dict[str, Any] | None):
    """SB3's ``make_vec_env`` (Monitor inside each env, env ``i`` seeded ``seed + i``)."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_cmzdril._mujoco_log import mujoco_warnings_routed

    with mujoco_warnings_routed():  # e.g. HalfCheetah's settotalmass notice, printed at model compile
        return sb3_make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs or None)
