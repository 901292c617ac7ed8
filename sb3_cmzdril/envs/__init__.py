"""Environments that ship with sb3-cmzdril (registered with gymnasium on import).

``WaypointNav-v0`` (our stand-in for the paper's PyUXV) and its scripted expert
``"waypoint-reactive"``. ``gym.make("sb3_cmzdril:WaypointNav-v0", n_beams=16, max_steps=200)``
works without other imports: gymnasium imports ``sb3_cmzdril`` for the ``module:`` prefix.
"""
import gymnasium

from sb3_cmzdril.envs.waypoint import POSITION_SLICE, WaypointField, WaypointNavEnv
from sb3_cmzdril.envs.waypoint_expert import WaypointReactiveExpert, make_waypoint_expert

__all__ = ["WaypointNavEnv", "WaypointField", "WaypointReactiveExpert", "make_waypoint_expert",
           "POSITION_SLICE"]

if "WaypointNav-v0" not in gymnasium.registry:
    # No TimeLimit (max_episode_steps=None): the env truncates at its own ``max_steps`` option, so
    # ``gym.make(..., max_steps=N)`` changes the one limit there is.
    gymnasium.register(
        id="WaypointNav-v0",
        entry_point="sb3_cmzdril.envs.waypoint:WaypointNavEnv",
        max_episode_steps=None,
    )


def _register_experts() -> None:
    from sb3_cmzdril.experts import SCRIPTED_EXPERTS, register_scripted_expert

    # A reload of this package makes a new factory object; keep the first one instead of failing.
    if "waypoint-reactive" not in SCRIPTED_EXPERTS:
        register_scripted_expert("waypoint-reactive", make_waypoint_expert)


_register_experts()
