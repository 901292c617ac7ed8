"""Metrics of the paper's figures: true return, discrete Fréchet distance to the expert, action MSE.

* :func:`frechet_distance` — exact discrete Fréchet distance between two N-D polylines.
* :func:`action_mse` — how far the policy's deterministic actions are from the expert's, on the
  expert's own observations.
* :func:`evaluate_against_expert` — replays held-out expert episodes from their recorded reset seeds
  with the agent in control, and reports return, Fréchet distance to the expert's path and action MSE.
* :class:`ExpertEvalCallback` — runs that evaluation every k PPO updates (epoch 0 included: the
  BC-pretrained policy), logs ``eval/mean_reward`` (SB3's key), ``eval/frechet``, ``eval/action_mse``
  and appends to a CSV.

The paper does not say on which features it measures the Fréchet distance. We use the vehicle's 2-D
position for WaypointNav (the paper's PyUXV path) and the full observation vector elsewhere
(:data:`TRAJECTORY_FEATURES`); pass ``trajectory_fn`` to choose otherwise.
"""

from sb3_cmzdril.metrics.action_mse import action_mse
from sb3_cmzdril.metrics.callbacks import ExpertEvalCallback
from sb3_cmzdril.metrics.evaluation import ExpertEvaluation, evaluate_against_expert
from sb3_cmzdril.metrics.frechet import frechet_distance
from sb3_cmzdril.metrics.trajectories import (
    TRAJECTORY_FEATURES,
    full_observation,
    trajectory_features,
    waypoint_position,
)

__all__ = [
    "frechet_distance",
    "action_mse",
    "TRAJECTORY_FEATURES",
    "trajectory_features",
    "full_observation",
    "waypoint_position",
    "ExpertEvaluation",
    "evaluate_against_expert",
    "ExpertEvalCallback",
]
