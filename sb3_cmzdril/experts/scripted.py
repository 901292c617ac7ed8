"""The scripted-expert registry: hand-written controllers that ``collect-demos --expert NAME`` finds.

A *scripted expert* is any object with SB3's ``predict(observation, state=None, episode_start=None,
deterministic=True) -> (actions, None)`` that accepts one observation or a batch of them. It is built
by a factory ``factory(env) -> expert`` (the env gives it the spaces and options it needs) and
registered by name.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym

from sb3_cmzdril.errors import UserError

ScriptedExpertFactory = Callable[[gym.Env], Any]
#: Registered factories by name (``sb3_cmzdril.envs`` adds ``"waypoint-reactive"`` on import).
SCRIPTED_EXPERTS: dict[str, ScriptedExpertFactory] = {}


def register_scripted_expert(name: str, factory: ScriptedExpertFactory) -> None:
    """Make ``factory`` available as ``--expert NAME`` (names are unique)."""
    if name in SCRIPTED_EXPERTS and SCRIPTED_EXPERTS[name] is not factory:
        raise UserError(f"a scripted expert named {name!r} is already registered")
    SCRIPTED_EXPERTS[name] = factory
