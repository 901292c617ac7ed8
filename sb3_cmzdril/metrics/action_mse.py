"""Action MSE: how far a policy's deterministic actions are from the expert's, on the expert's own
observations (and the prediction helpers the evaluation shares)."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_cmzdril.data.demos import Demonstrations, as_demonstrations
from sb3_cmzdril.data.spaces import Observations, n_steps, take
from sb3_cmzdril.errors import UserError

#: What VecNormalize.normalize_obs is: an array or a dict of arrays in, the same kind out.
ObsTransform = Callable[[Observations], Observations]
# Observations per predict() call in action_mse: bounds memory for long demonstration sets.
_PREDICT_CHUNK = 8192


def _model_action_space(model: Any) -> spaces.Space | None:
    for holder in (model, getattr(model, "policy", None)):
        space = getattr(holder, "action_space", None)
        if isinstance(space, spaces.Space):
            return space
    return None


def _action_space_of(model: Any, action_space: spaces.Space | None = None) -> spaces.Space:
    if action_space is not None:
        return action_space
    space = _model_action_space(model)
    if space is None:
        raise ValueError(
            f"cannot tell the action space of {type(model).__name__}: it has no action_space attribute "
            "(nor policy.action_space); pass action_space="
        )
    return space


def _observation_transform(model: Any, obs_transform: ObsTransform | None) -> ObsTransform | None:
    """The transform the policy expects its observations through: explicit, else VecNormalize's."""
    if obs_transform is not None:
        return obs_transform
    getter = getattr(model, "get_vec_normalize_env", None)
    if callable(getter):
        vec_normalize = getter()
        if vec_normalize is not None:
            # normalize_obs uses the current statistics and does not update them.
            return vec_normalize.normalize_obs
    return None


def _predict(model: Any, observations: Observations, transform: ObsTransform | None) -> np.ndarray:
    """Deterministic actions for a batch of observations, one row per observation."""
    batch = transform(observations) if transform is not None else observations
    result = model.predict(batch, deterministic=True)
    # SB3 returns (actions, state); a bare array from a hand-written expert is accepted too.
    actions = np.asarray(result[0] if isinstance(result, tuple) else result)
    if len(actions) != n_steps(observations) or actions.ndim == 0:
        raise ValueError(
            f"{type(model).__name__}.predict returned actions of shape {actions.shape} for "
            f"{n_steps(observations)} observations; it must predict on the whole batch"
        )
    return actions


def _step_errors(
    model: Any,
    demos: Demonstrations,
    action_space: spaces.Space,
    transform: ObsTransform | None,
) -> np.ndarray:
    """Per-step error (n_steps,): squared error averaged over action dims, or 0/1 disagreement."""
    n = len(demos)
    if isinstance(action_space, spaces.Box):
        dim = int(np.prod(action_space.shape))
        expert = demos.actions.reshape(n, -1)
        if expert.shape[1] != dim:
            raise UserError(
                f"demonstration actions have {expert.shape[1]} entries but the action space {action_space} has {dim}"
            )
        low = action_space.low.astype(np.float32).reshape(-1)
        high = action_space.high.astype(np.float32).reshape(-1)
        expert = np.clip(expert.astype(np.float32), low, high).astype(np.float64)
    elif isinstance(action_space, spaces.Discrete):
        expert = demos.actions.reshape(n, -1)
        if expert.shape[1] != 1:
            raise UserError(
                f"Discrete action space needs scalar actions; demonstrations have shape {demos.actions.shape[1:]}"
            )
        expert = expert[:, 0]
    else:
        raise UserError(f"action MSE supports Box and Discrete action spaces, got {action_space}")

    errors = np.empty(n, dtype=np.float64)
    for start in range(0, n, _PREDICT_CHUNK):
        stop = min(n, start + _PREDICT_CHUNK)
        pred = _predict(model, take(demos.observations, slice(start, stop)), transform)
        if isinstance(action_space, spaces.Box):
            # Compared at the precision the demonstrations are stored in (float32), so that replaying
            # the expert gives exactly 0 rather than float32 rounding noise.
            pred = pred.reshape(stop - start, -1).astype(np.float32)
            if pred.shape[1] != expert.shape[1]:
                raise ValueError(
                    f"predicted actions have {pred.shape[1]} entries, the action space has {expert.shape[1]}"
                )
            pred = np.clip(pred, low, high).astype(np.float64)
            errors[start:stop] = np.mean((pred - expert[start:stop]) ** 2, axis=1)
        else:
            pred = pred.reshape(stop - start, -1)
            if pred.shape[1] != 1:
                raise ValueError(f"predicted Discrete actions have shape {pred.shape[1:]}, expected scalars")
            errors[start:stop] = pred[:, 0].astype(np.int64) != expert[start:stop]
    return errors


def action_mse(
    model_or_policy: Any,
    demos: Demonstrations | str | Path,
    obs_transform: ObsTransform | None = None,
    action_space: spaces.Space | None = None,
) -> float:
    """Mean squared difference between the policy's deterministic actions and the expert's.

    The policy predicts on the expert's observations (in batches); both actions are clipped to the
    Box bounds (what the environment can execute) and the squared error is averaged over steps and
    action dimensions. For a **Discrete** action space the value is the fraction of steps where the
    policy's action differs from the expert's (mean 0/1 disagreement), which is the MSE of one-hot
    actions up to a factor 2/n_actions and stays in [0, 1].

    :param model_or_policy: anything with SB3's ``predict(obs, deterministic=True)`` that accepts a
        batch: an SB3 algorithm, an SB3 ``BasePolicy``, or a scripted expert. Recurrent policies are
        not supported (no state is carried).
    :param demos: the expert's steps (a :class:`Demonstrations` or a path to one).
    :param obs_transform: applied to observation batches before ``predict``. Default: when the model
        is an SB3 algorithm trained under ``VecNormalize``, its current observation normalisation.
    :param action_space: needed only when the model has no ``action_space`` (nor ``policy.action_space``).
    :return: 0.0 for the expert itself.
    """
    demos = as_demonstrations(demos)
    space = _action_space_of(model_or_policy, action_space)
    return float(
        np.mean(_step_errors(model_or_policy, demos, space, _observation_transform(model_or_policy, obs_transform)))
    )
