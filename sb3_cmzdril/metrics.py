"""Metrics of the paper's figures: true return, discrete Fréchet distance to the expert, action MSE.

* :func:`frechet_distance` — exact discrete Fréchet distance between two N-D polylines.
* :func:`action_mse` — how far the policy's deterministic actions are from the expert's, on the
  expert's own observations.
* :func:`evaluate_against_expert` — replays held-out expert episodes from their recorded reset seeds
  with the agent in control, and reports return, Fréchet distance to the expert's path and action MSE.
* :class:`ExpertEvalCallback` — runs that evaluation every k PPO updates (epoch 0 included: the
  BC-pretrained policy), logs ``eval/return``, ``eval/frechet``, ``eval/action_mse`` and appends to a CSV.

The paper does not say on which features it measures the Fréchet distance. We use the vehicle's 2-D
position for WaypointNav (the paper's PyUXV path) and the full observation vector elsewhere
(:data:`TRAJECTORY_FEATURES`); pass ``trajectory_fn`` to choose otherwise.
"""
from __future__ import annotations

import csv
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple, Union

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.lib.stride_tricks import as_strided
from scipy.spatial.distance import cdist
from stable_baselines3.common.callbacks import BaseCallback

from sb3_cmzdril.demos import UNKNOWN_SEED, Demonstrations, as_demonstrations

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

ObsTransform = Callable[[np.ndarray], np.ndarray]
TrajectoryFn = Callable[[np.ndarray], np.ndarray]

# Above this many pairwise distances (200 MB of float64) the Fréchet DP computes each anti-diagonal's
# distances on the fly instead of holding the full matrix: O(n + m) memory, about 4-5x slower.
_MAX_MATRIX_ELEMENTS = 25_000_000
# Observations per predict() call in action_mse: bounds memory for long demonstration sets.
_PREDICT_CHUNK = 8192


# ---------------------------------------------------------------------------------------------
# Discrete Fréchet distance
# ---------------------------------------------------------------------------------------------
def _as_curve(curve: Any, name: str) -> np.ndarray:
    try:
        arr = np.asarray(curve, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a numeric array of points, (n, d) or (n,): {e}") from e
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be (n, d) or (n,), got an array with shape {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}): a curve needs at least one point of dimension >= 1")
    if not np.all(np.isfinite(arr)):
        bad = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise ValueError(f"{name} contains NaN or inf (first at point {bad})")
    return arr


def frechet_distance(P: Any, Q: Any) -> float:
    """Exact discrete Fréchet distance between polylines ``P`` (n, d) and ``Q`` (m, d).

    ``n != m`` is allowed; 1-D inputs are read as (n, 1). The point-to-point metric is Euclidean.
    Symmetric, 0 for identical curves, and ``>= max(|P[0]-Q[0]|, |P[-1]-Q[-1]|)``.

    Algorithm: the usual O(n*m) coupling DP
    ``ca[i, j] = max(d[i, j], min(ca[i-1, j], ca[i, j-1], ca[i-1, j-1]))``, swept one anti-diagonal at a
    time so each sweep step is three in-place numpy calls over a whole diagonal. Exactness is kept
    because the DP only ever selects (max/min) among the pairwise distances, never combines them.

    :raises ValueError: empty curve, ndim > 2, different point dimensions, NaN or inf.
    """
    p = _as_curve(P, "P")
    q = _as_curve(Q, "Q")
    if p.shape[1] != q.shape[1]:
        raise ValueError(f"P and Q have points of different dimension: {p.shape[1]} vs {q.shape[1]}")
    # The distance is symmetric, so put the shorter curve on the diagonal axis: shorter buffers.
    if len(p) > len(q):
        p, q = q, p
    if len(p) * len(q) > _MAX_MATRIX_ELEMENTS:
        return _frechet_low_memory(p, q)
    return _frechet_matrix(p, q)


def _frechet_matrix(p: np.ndarray, q: np.ndarray) -> float:
    """Wavefront DP over the full (n, m) matrix of squared distances, n <= m."""
    # Squared distances: sqrt is monotone, so it commutes with the DP's max/min; one sqrt at the end
    # instead of n*m (cdist's sqeuclidean is ~2.5x faster than euclidean).
    d = cdist(p, q, "sqeuclidean")
    n, m = d.shape
    it = d.itemsize
    # Anti-diagonal k of a C-contiguous (n, m) array, cells (i, k - i), lives at flat offsets
    # k + i*(m - 1): a strided view gives every diagonal as a row without copying anything.
    # Rows k in [0, n+m-2], columns i in [0, n-1] reach flat offsets up to n*m - 1, so the view stays
    # inside the buffer (cells with k - i outside [0, m) alias other cells and are never read).
    diag = as_strided(d, shape=(n + m - 1, n), strides=(it, (m - 1) * it), writeable=False)

    # Three rotating diagonal buffers indexed by i + 1; index 0 is a permanent +inf guard for i = -1.
    # Cells a diagonal never writes stay +inf, and the index bounds below guarantee that the only
    # unwritten cells ever read are exactly the out-of-grid predecessors (j = -1 or i = -1).
    bufs = [np.full(n + 1, np.inf) for _ in range(3)]
    bufs[1][1] = d[0, 0]
    a, b, c = 0, 1, 2  # diagonal k-2, k-1, k
    tmp = np.empty(n)
    minimum, maximum = np.minimum, np.maximum

    # Phase 1, k < n: the diagonal grows, i in [0, k].
    for k in range(1, n):
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        t = tmp[: k + 1]
        minimum(p1[1 : k + 2], p1[: k + 1], out=t)  # (i, j-1) and (i-1, j)
        minimum(t, p2[: k + 1], out=t)  # (i-1, j-1)
        maximum(t, diag[k, : k + 1], out=cur[1 : k + 2])
        a, b, c = b, c, a
    # Phase 2, n <= k < m: full-length diagonals, i in [0, n-1]; the slices never change.
    views = [(buf[1:], buf[:-1]) for buf in bufs]
    for k in range(n, m):
        minimum(views[b][0], views[b][1], out=tmp)
        minimum(tmp, views[a][1], out=tmp)
        maximum(tmp, diag[k], out=views[c][0])
        a, b, c = b, c, a
    # Phase 3, k >= m: the diagonal shrinks, i in [k-m+1, n-1].
    for k in range(m, n + m - 1):
        lo = k - m + 1
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        t = tmp[lo:]
        minimum(p1[lo + 1 :], p1[lo:n], out=t)
        minimum(t, p2[lo:n], out=t)
        maximum(t, diag[k, lo:], out=cur[lo + 1 :])
        a, b, c = b, c, a
    return float(np.sqrt(bufs[b][n]))


def _frechet_low_memory(p: np.ndarray, q: np.ndarray) -> float:
    """Same DP, distances of each anti-diagonal computed when needed (n <= m); O(n + m) memory."""
    n, m = len(p), len(q)
    bufs = [np.full(n + 1, np.inf) for _ in range(3)]
    diff = p[0] - q[0]
    bufs[1][1] = float(diff @ diff)
    a, b, c = 0, 1, 2
    tmp = np.empty(n)
    for k in range(1, n + m - 1):
        lo = max(0, k - m + 1)
        hi = min(k, n - 1)
        t = tmp[lo : hi + 1]
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        np.minimum(p1[lo + 1 : hi + 2], p1[lo : hi + 1], out=t)
        np.minimum(t, p2[lo : hi + 1], out=t)
        # j = k - i runs from k - lo down to k - hi as i goes up: a reversed contiguous slice of q.
        qs = q[k - hi : k - lo + 1][::-1]
        delta = p[lo : hi + 1] - qs
        np.maximum(t, np.einsum("ij,ij->i", delta, delta), out=cur[lo + 1 : hi + 2])
        a, b, c = b, c, a
    return float(np.sqrt(bufs[b][n]))


# ---------------------------------------------------------------------------------------------
# Action MSE
# ---------------------------------------------------------------------------------------------
def _model_action_space(model: Any) -> Optional[spaces.Space]:
    for holder in (model, getattr(model, "policy", None)):
        space = getattr(holder, "action_space", None)
        if isinstance(space, spaces.Space):
            return space
    return None


def _action_space_of(model: Any, action_space: Optional[spaces.Space] = None) -> spaces.Space:
    if action_space is not None:
        return action_space
    space = _model_action_space(model)
    if space is None:
        raise ValueError(
            f"cannot tell the action space of {type(model).__name__}: it has no action_space attribute "
            "(nor policy.action_space); pass action_space="
        )
    return space


def _observation_transform(model: Any, obs_transform: Optional[ObsTransform]) -> Optional[ObsTransform]:
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


def _predict(model: Any, observations: np.ndarray, transform: Optional[ObsTransform]) -> np.ndarray:
    """Deterministic actions for a batch of observations, one row per observation."""
    batch = transform(observations) if transform is not None else observations
    result = model.predict(batch, deterministic=True)
    # SB3 returns (actions, state); a bare array from a hand-written expert is accepted too.
    actions = np.asarray(result[0] if isinstance(result, tuple) else result)
    if len(actions) != len(observations) or actions.ndim == 0:
        raise ValueError(
            f"{type(model).__name__}.predict returned actions of shape {actions.shape} for "
            f"{len(observations)} observations; it must predict on the whole batch"
        )
    return actions


def _step_errors(
    model: Any,
    demos: Demonstrations,
    action_space: spaces.Space,
    transform: Optional[ObsTransform],
) -> np.ndarray:
    """Per-step error (n_steps,): squared error averaged over action dims, or 0/1 disagreement."""
    n = len(demos)
    if isinstance(action_space, spaces.Box):
        dim = int(np.prod(action_space.shape))
        expert = demos.actions.reshape(n, -1)
        if expert.shape[1] != dim:
            raise ValueError(f"demonstration actions have {expert.shape[1]} entries but the action space {action_space} has {dim}")
        low = action_space.low.astype(np.float32).reshape(-1)
        high = action_space.high.astype(np.float32).reshape(-1)
        expert = np.clip(expert.astype(np.float32), low, high).astype(np.float64)
    elif isinstance(action_space, spaces.Discrete):
        expert = demos.actions.reshape(n, -1)
        if expert.shape[1] != 1:
            raise ValueError(f"Discrete action space needs scalar actions; demonstrations have shape {demos.actions.shape[1:]}")
        expert = expert[:, 0]
    else:
        raise ValueError(f"action MSE supports Box and Discrete action spaces, got {action_space}")

    errors = np.empty(n, dtype=np.float64)
    for start in range(0, n, _PREDICT_CHUNK):
        stop = min(n, start + _PREDICT_CHUNK)
        pred = _predict(model, demos.observations[start:stop], transform)
        if isinstance(action_space, spaces.Box):
            # Compared at the precision the demonstrations are stored in (float32), so that replaying
            # the expert gives exactly 0 rather than float32 rounding noise.
            pred = pred.reshape(stop - start, -1).astype(np.float32)
            if pred.shape[1] != expert.shape[1]:
                raise ValueError(f"predicted actions have {pred.shape[1]} entries, the action space has {expert.shape[1]}")
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
    demos: Union[Demonstrations, str, Path],
    obs_transform: Optional[ObsTransform] = None,
    action_space: Optional[spaces.Space] = None,
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
    return float(np.mean(_step_errors(model_or_policy, demos, space, _observation_transform(model_or_policy, obs_transform))))


# ---------------------------------------------------------------------------------------------
# Trajectory features for the Fréchet distance
# ---------------------------------------------------------------------------------------------
def full_observation(obs: np.ndarray) -> np.ndarray:
    """Default trajectory feature: the whole (flattened) observation, (T, obs_dim)."""
    obs = np.asarray(obs)
    return obs.reshape(len(obs), -1)


def waypoint_position(obs: np.ndarray) -> np.ndarray:
    """WaypointNav-v0: the vehicle's (x, y), the last two observation entries (normalised by the arena half-size)."""
    return np.asarray(obs)[..., -2:]


#: Env id (without ``module:`` prefix) -> function mapping observations (T, d) to path points (T, k).
TRAJECTORY_FEATURES: Dict[str, TrajectoryFn] = {
    "WaypointNav-v0": waypoint_position,
}


def _strip_module(env_id: str) -> str:
    return env_id.split(":", 1)[-1]


def trajectory_features(env_id: Optional[str]) -> TrajectoryFn:
    """The trajectory feature function for an env id (``module:`` prefix allowed); full observation by default."""
    if env_id is None:
        return full_observation
    return TRAJECTORY_FEATURES.get(_strip_module(env_id), full_observation)


# ---------------------------------------------------------------------------------------------
# Evaluation against held-out expert episodes
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ExpertEvaluation:
    """Result of :func:`evaluate_against_expert`; arrays have one entry per evaluated episode."""

    seeds: np.ndarray  #: reset seed of each episode (the expert's)
    returns: np.ndarray  #: the agent's true (undiscounted) return
    lengths: np.ndarray  #: the agent's episode length
    frechet: np.ndarray  #: Fréchet distance between the agent's and the expert's paths
    episode_action_mse: np.ndarray  #: action MSE on that episode's expert observations
    expert_returns: np.ndarray  #: the expert's recorded return (NaN when the demos carry no rewards)
    expert_lengths: np.ndarray  #: the expert's episode length
    start_matches: np.ndarray  #: whether the reset observation equalled the expert's first one
    agent_observations: List[np.ndarray] = field(repr=False, default_factory=list)  #: (T_i, *obs_shape) each

    @property
    def n_episodes(self) -> int:
        return int(len(self.returns))

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std_return(self) -> float:
        return float(np.std(self.returns))

    @property
    def mean_frechet(self) -> float:
        return float(np.mean(self.frechet))

    @property
    def std_frechet(self) -> float:
        return float(np.std(self.frechet))

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths))

    @property
    def action_mse(self) -> float:
        """Over all expert steps (episodes weighted by length): equals ``action_mse(model, demos)``."""
        return float(np.sum(self.episode_action_mse * self.expert_lengths) / np.sum(self.expert_lengths))

    def summary(self) -> Dict[str, float]:
        """Scalars for logging and tables."""
        return {
            "return_mean": self.mean_return,
            "return_std": self.std_return,
            "frechet_mean": self.mean_frechet,
            "frechet_std": self.std_frechet,
            "action_mse": self.action_mse,
            "length_mean": self.mean_length,
            "n_episodes": self.n_episodes,
        }


def _require_seeds(demos: Demonstrations) -> None:
    unknown = np.flatnonzero(demos.seeds == UNKNOWN_SEED)
    if unknown.size:
        raise ValueError(
            f"episodes {unknown.tolist()} of the demonstrations have no recorded reset seed (-1): they cannot "
            "be replayed from the expert's start; record demos with seeds or choose other episodes"
        )


def _make_env(env: Union[str, gym.Env], env_kwargs: Optional[Mapping[str, Any]]) -> Tuple[gym.Env, bool, Optional[str]]:
    """(env, whether we own it and must close it, its id for the trajectory-feature lookup)."""
    if isinstance(env, str):
        return gym.make(env, **dict(env_kwargs or {})), True, env
    if not isinstance(env, gym.Env):
        raise TypeError(
            f"env must be a gymnasium Env or an env id, got {type(env).__name__} "
            "(VecEnvs are not accepted: each episode is reset with its own seed)"
        )
    if env_kwargs:
        raise ValueError("env_kwargs only apply when env is an env id")
    spec = getattr(env, "spec", None)
    return env, False, getattr(spec, "id", None)


def _checked(demos: Demonstrations, env: gym.Env) -> Demonstrations:
    """Demos validated against the env's spaces (ValueError naming a mismatch)."""
    with warnings.catch_warnings():
        # The metrics clip expert actions to the bounds by definition: check_spaces' warning about
        # out-of-bounds expert actions would only be noise, repeated at every evaluation.
        warnings.filterwarnings("ignore", message=".*outside the action bounds", category=UserWarning)
        return demos.check_spaces(env.observation_space, env.action_space)


def _rollout(
    model: Any,
    env: gym.Env,
    seed: int,
    transform: Optional[ObsTransform],
    max_steps: Optional[int],
) -> Tuple[np.ndarray, float]:
    """One deterministic episode: (observations acted on, (T, *obs_shape)), true return)."""
    space = env.action_space
    obs, _ = env.reset(seed=int(seed))
    observations: List[np.ndarray] = []
    total = 0.0
    while True:
        observations.append(np.asarray(obs))
        action = _predict(model, np.asarray(obs)[None], transform)[0]
        if isinstance(space, spaces.Box):
            # What SB3's collect_rollouts/predict would execute; keeps scripted experts in bounds too.
            action = np.clip(np.asarray(action, dtype=space.dtype).reshape(space.shape), space.low, space.high)
        elif isinstance(space, spaces.Discrete):
            action = int(np.asarray(action).reshape(-1)[0])
        obs, reward, terminated, truncated, _ = env.step(action)
        total += float(reward)
        if terminated or truncated or (max_steps is not None and len(observations) >= max_steps):
            break
    return np.stack(observations), total


def evaluate_against_expert(
    model: Any,
    env: Union[str, gym.Env],
    demos: Union[Demonstrations, str, Path],
    trajectory_fn: Optional[TrajectoryFn] = None,
    obs_transform: Optional[ObsTransform] = None,
    *,
    env_kwargs: Optional[Mapping[str, Any]] = None,
    max_steps: Optional[int] = None,
    start_mismatch: str = "warn",
) -> ExpertEvaluation:
    """Replay each held-out expert episode's start with the agent in control and compare.

    For each episode of ``demos``: reset ``env`` with the episode's recorded seed, roll ``model`` out
    deterministically until terminated or truncated, and record the true return and the observations
    the agent acted on (reset observation first, one per action: the demos' convention). Then the
    Fréchet distance between ``trajectory_fn(agent observations)`` and ``trajectory_fn(expert
    observations)``, and the action MSE of the model on that episode's expert observations.

    :param model: anything with SB3's ``predict(obs, deterministic=True)`` accepting a batch.
    :param env: a gymnasium Env (not wrapped in a reward wrapper: returns must be true returns), or
        an env id for ``gym.make`` (made with ``env_kwargs`` and closed afterwards).
    :param demos: held-out expert episodes with known reset seeds.
    :param trajectory_fn: observations (T, d) -> path points (T, k). Default: by env id from
        :data:`TRAJECTORY_FEATURES`, else the full observation.
    :param obs_transform: as in :func:`action_mse` (default: the model's VecNormalize, if any).
    :param max_steps: cut an episode after this many steps (for envs without a time limit).
    :param start_mismatch: what to do when the reset observation differs from the expert's first
        observation (the seed does not reproduce the expert's start): ``"warn"``, ``"raise"`` or ``"ignore"``.
    :raises ValueError: an episode's seed is unknown (-1), or the demos do not fit the env's spaces.
    """
    if start_mismatch not in ("warn", "raise", "ignore"):
        raise ValueError(f"start_mismatch must be 'warn', 'raise' or 'ignore', got {start_mismatch!r}")
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"max_steps must be positive, got {max_steps}")
    demos = as_demonstrations(demos)
    _require_seeds(demos)
    env_obj, owned, env_id = _make_env(env, env_kwargs)
    try:
        demos = _checked(demos, env_obj)
        features = trajectory_fn if trajectory_fn is not None else trajectory_features(env_id)
        transform = _observation_transform(model, obs_transform)
        space = _model_action_space(model)
        if space is None:  # a scripted expert without spaces: the env's
            space = env_obj.action_space
        step_errors = _step_errors(model, demos, space, transform)
        starts = demos.episode_starts
        episode_mse = np.add.reduceat(step_errors, starts) / demos.episode_lengths

        returns, lengths, frechet, matches, trajectories = [], [], [], [], []
        for i in range(demos.n_episodes):
            expert = demos.episode(i)
            agent_obs, total = _rollout(model, env_obj, expert["seed"], transform, max_steps)
            match = bool(
                np.allclose(agent_obs[0].astype(np.float32), expert["observations"][0], rtol=1e-5, atol=1e-6)
            )
            if not match and start_mismatch != "ignore":
                message = (
                    f"episode {i}: the reset observation for seed {expert['seed']} differs from the expert's "
                    "first observation; the seed does not reproduce the expert's start (different env, "
                    "env version or env_kwargs?), so the Fréchet distance compares different starts"
                )
                if start_mismatch == "raise":
                    raise ValueError(message)
                warnings.warn(message, UserWarning, stacklevel=2)
            returns.append(total)
            lengths.append(len(agent_obs))
            frechet.append(frechet_distance(features(agent_obs), features(expert["observations"])))
            matches.append(match)
            trajectories.append(agent_obs)
    finally:
        if owned:
            env_obj.close()

    expert_returns = demos.episode_returns
    return ExpertEvaluation(
        seeds=demos.seeds.copy(),
        returns=np.asarray(returns, dtype=np.float64),
        lengths=np.asarray(lengths, dtype=np.int64),
        frechet=np.asarray(frechet, dtype=np.float64),
        episode_action_mse=episode_mse,
        expert_returns=expert_returns if expert_returns is not None else np.full(demos.n_episodes, np.nan),
        expert_lengths=demos.episode_lengths.copy(),
        start_matches=np.asarray(matches, dtype=bool),
        agent_observations=trajectories,
    )


# ---------------------------------------------------------------------------------------------
# Callback
# ---------------------------------------------------------------------------------------------
class ExpertEvalCallback(BaseCallback):
    """Evaluate against held-out expert episodes every ``eval_every`` policy updates.

    *Epoch* = number of completed rollout+update cycles (PPO updates). For on-policy algorithms it
    is computed from ``num_timesteps // (n_steps * n_envs)``, so it continues across resumed runs
    (``learn(..., reset_num_timesteps=False)``). Epoch 0 (the policy before the first update, e.g.
    the BC-pretrained one) is evaluated at the first rollout, then every ``eval_every`` epochs, and
    the last epoch at the end of training if it was not already.

    Each evaluation records ``eval/return``, ``eval/return_std``, ``eval/frechet``,
    ``eval/action_mse`` and ``eval/length`` with the model's logger (dumped with the logs of the
    rollout that follows; the final one is dumped at once) and appends a row with :attr:`CSV_COLUMNS` to
    ``csv_path``, flushed row by row. An existing CSV keeps its rows: the run appends to it, and a
    resumed run does not re-evaluate an (epoch, timesteps) already there.

    :param eval_env: env id (made with ``env_kwargs``) or a gymnasium Env, without reward wrappers.
    :param demos: held-out expert episodes with recorded reset seeds (or a path to them).
    :param eval_every: evaluate every this many PPO updates.
    :param csv_path: where to append the evaluation rows; None for no file.
    :param trajectory_fn: see :func:`evaluate_against_expert`.
    """

    CSV_COLUMNS: Tuple[str, ...] = (
        "epoch",
        "timesteps",
        "return_mean",
        "return_std",
        "frechet_mean",
        "frechet_std",
        "action_mse",
        "length_mean",
        "n_episodes",
    )

    def __init__(
        self,
        eval_env: Union[str, gym.Env],
        demos: Union[Demonstrations, str, Path],
        eval_every: int = 1,
        csv_path: Optional[Union[str, Path]] = None,
        trajectory_fn: Optional[TrajectoryFn] = None,
        env_kwargs: Optional[Mapping[str, Any]] = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if isinstance(eval_every, bool) or not isinstance(eval_every, (int, np.integer)) or eval_every < 1:
            raise ValueError(f"eval_every must be a positive integer, got {eval_every!r}")
        self.demos = as_demonstrations(demos)
        _require_seeds(self.demos)  # fail at construction, not after the first rollout
        self.eval_every = int(eval_every)
        self.csv_path = Path(csv_path) if csv_path is not None else None
        self.trajectory_fn = trajectory_fn
        self._env_arg = eval_env
        self._env_kwargs = dict(env_kwargs or {})
        self.eval_env: Optional[gym.Env] = None
        self._owns_env = False
        self._env_id: Optional[str] = None
        #: one summary dict per evaluation of this callback (epoch, timesteps and the CSV columns)
        self.history: List[Dict[str, float]] = []
        self.last_evaluation: Optional[ExpertEvaluation] = None
        self._done: set = set()  # (epoch, timesteps) already evaluated
        self._rollouts_completed = 0  # fallback epoch counter for algorithms without n_steps

    # -- setup ----------------------------------------------------------------------------------
    def _init_callback(self) -> None:
        if self.eval_env is None:
            self.eval_env, self._owns_env, self._env_id = _make_env(self._env_arg, self._env_kwargs or None)
            self.demos = _checked(self.demos, self.eval_env)
        if self.csv_path is not None:
            self._prepare_csv()

    def _prepare_csv(self) -> None:
        path = self.csv_path
        assert path is not None
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            with open(path, "w", newline="") as f:
                csv.writer(f, lineterminator="\n").writerow(self.CSV_COLUMNS)
            return
        text = path.read_text()
        if not text.strip():
            path.write_text(",".join(self.CSV_COLUMNS) + "\n")
            return
        rows = list(csv.reader(text.splitlines()))
        if tuple(rows[0]) != self.CSV_COLUMNS:
            raise ValueError(
                f"{path} exists with columns {rows[0]}, not {list(self.CSV_COLUMNS)}: pass another csv_path"
            )
        if not text.endswith("\n"):  # a run killed mid-row: start ours on a fresh line
            with open(path, "a", newline="") as f:
                f.write("\n")
        logged = set()
        for row in rows[1:]:
            try:
                logged.add((int(row[0]), int(row[1])))
            except (ValueError, IndexError):
                continue
        if self.model.num_timesteps > 0:
            # Resumed run: the previous run's final evaluation already covers where we restart.
            self._done |= logged
        elif logged:
            warnings.warn(f"{path} already has {len(logged)} rows from an earlier run; appending to them", UserWarning)

    # -- hooks ----------------------------------------------------------------------------------
    def _epoch(self) -> int:
        n_steps = getattr(self.model, "n_steps", None)
        if isinstance(n_steps, (int, np.integer)) and n_steps > 0:
            # A rollout is exactly n_steps * n_envs steps and each completed one is followed by an update.
            return int(self.model.num_timesteps // (n_steps * self.model.n_envs))
        return self._rollouts_completed

    def _on_rollout_start(self) -> None:
        epoch = self._epoch()
        if epoch % self.eval_every == 0:
            self._evaluate(epoch, dump=False)

    def _on_rollout_end(self) -> None:
        self._rollouts_completed += 1

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._evaluate(self._epoch(), dump=True)

    # -- work -----------------------------------------------------------------------------------
    def _evaluate(self, epoch: int, dump: bool) -> None:
        timesteps = int(self.model.num_timesteps)
        if (epoch, timesteps) in self._done:
            return
        self._done.add((epoch, timesteps))
        assert self.eval_env is not None
        trajectory_fn = self.trajectory_fn if self.trajectory_fn is not None else trajectory_features(self._env_id)
        result = evaluate_against_expert(self.model, self.eval_env, self.demos, trajectory_fn=trajectory_fn)
        self.last_evaluation = result
        row: Dict[str, float] = {"epoch": epoch, "timesteps": timesteps, **result.summary()}
        self.history.append(row)

        self.logger.record("eval/return", result.mean_return)
        self.logger.record("eval/return_std", result.std_return)
        self.logger.record("eval/frechet", result.mean_frechet)
        self.logger.record("eval/action_mse", result.action_mse)
        self.logger.record("eval/length", result.mean_length)
        self.logger.record("eval/epoch", epoch)
        if dump:
            self.logger.dump(timesteps)
        if self.csv_path is not None:
            with open(self.csv_path, "a", newline="") as f:
                csv.writer(f, lineterminator="\n").writerow([_csv_value(row[c]) for c in self.CSV_COLUMNS])
                f.flush()
        if self.verbose >= 1:
            print(
                f"[expert eval] epoch {epoch} ({timesteps} steps): return {result.mean_return:.1f} "
                f"± {result.std_return:.1f}, Fréchet {result.mean_frechet:.4g}, action MSE {result.action_mse:.4g}"
            )

    def close(self) -> None:
        """Close the eval env if this callback made it."""
        if self.eval_env is not None and self._owns_env:
            self.eval_env.close()
        self.eval_env = None


def _csv_value(value: float) -> str:
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    return repr(value) if math.isfinite(value) else str(value)
