"""Evaluation against held-out expert episodes: replay each one's start with the agent in control."""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_cmzdril._mujoco_log import mujoco_warnings_routed
from sb3_cmzdril.data.demos import UNKNOWN_SEED, Demonstrations, as_demonstrations
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.metrics.action_mse import (
    ObsTransform,
    _model_action_space,
    _observation_transform,
    _predict,
    _step_errors,
)
from sb3_cmzdril.metrics.frechet import frechet_distance
from sb3_cmzdril.metrics.trajectories import TrajectoryFn, trajectory_features


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
    agent_observations: list[np.ndarray] = field(repr=False, default_factory=list)  #: (T_i, *obs_shape) each

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

    def summary(self) -> dict[str, float]:
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
        raise UserError(
            f"episodes {unknown.tolist()} of the demonstrations have no recorded reset seed (-1): they cannot "
            "be replayed from the expert's start; record demos with seeds or choose other episodes"
        )


def same_observation(reset_observation: Any, episode_observations: Any) -> bool:
    """Whether an env's reset observation is an episode's first one (as the demos store it: float32,
    so compared at float32's precision); dict observations key by key."""
    if isinstance(episode_observations, Mapping):
        return isinstance(reset_observation, Mapping) and set(reset_observation) == set(episode_observations) and all(
            same_observation(reset_observation[k], episode_observations[k]) for k in episode_observations
        )
    ours, theirs = np.asarray(reset_observation), np.asarray(episode_observations)[0]
    if ours.shape != theirs.shape:
        return False
    return bool(np.allclose(ours.astype(np.float32), theirs, rtol=1e-5, atol=1e-6))


def make_env(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)``, or a UserError naming the env and the kwargs when it
    cannot be made with them (an unknown keyword, a bad value: a TypeError, ValueError or assertion).

    Without kwargs, or with another exception, the failure is the env's own and propagates as it is.
    """
    kwargs = dict(env_kwargs or {})
    try:
        with mujoco_warnings_routed():
            return gym.make(env_id, **kwargs)
    except (TypeError, ValueError, AssertionError) as e:
        if not kwargs:
            raise
        raise UserError(f"cannot make {env_id} with env_kwargs {kwargs}: {type(e).__name__}: {e}") from None


def _make_env(env: str | gym.Env, env_kwargs: Mapping[str, Any] | None) -> tuple[gym.Env, bool, str | None]:
    """(env, whether we own it and must close it, its id for the trajectory-feature lookup)."""
    if isinstance(env, str):
        return make_env(env, env_kwargs), True, env
    if not isinstance(env, gym.Env):
        raise TypeError(
            f"env must be a gymnasium Env or an env id, got {type(env).__name__} "
            "(VecEnvs are not accepted: each episode is reset with its own seed)"
        )
    if env_kwargs:
        raise UserError("env_kwargs only apply when env is an env id")
    spec = getattr(env, "spec", None)
    return env, False, getattr(spec, "id", None)


def _checked(demos: Demonstrations | str | Path, env: gym.Env) -> Demonstrations:
    """Demos (or their file) validated against the env's spaces (ValueError naming a mismatch)."""
    with warnings.catch_warnings():
        # The metrics clip expert actions to the bounds by definition: check_spaces' warning about
        # out-of-bounds expert actions would only be noise, repeated at every evaluation.
        warnings.filterwarnings("ignore", message=".*outside the action bounds", category=UserWarning)
        return as_demonstrations(demos).check_spaces(env.observation_space, env.action_space)


def _rollout(
    model: Any,
    env: gym.Env,
    seed: int,
    transform: ObsTransform | None,
    max_steps: int | None,
) -> tuple[np.ndarray, float]:
    """One deterministic episode: (observations acted on, (T, *obs_shape)), true return)."""
    space = env.action_space
    obs, _ = env.reset(seed=int(seed))
    observations: list[np.ndarray] = []
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


def _start_mismatch_message(differing: list[int], seeds: np.ndarray) -> str:
    """What :func:`evaluate_against_expert` says of the episodes (of the demos it was given) whose
    recorded seed does not reproduce their first observation: every one of them, with its seed."""
    shown = ", ".join(f"{i} (seed {int(seeds[i])})" for i in differing[:10]) + (", ..." if len(differing) > 10 else "")
    return (
        f"episode{'s' if len(differing) > 1 else ''} {shown} of {len(seeds)}: the reset observation for the "
        "recorded seed differs from the expert's first observation; the seed does not reproduce the expert's "
        "start (different env, env version or env_kwargs?), so the Fréchet distance and the return compare "
        "different starts"
    )


@mujoco_warnings_routed()  # the rollouts step MuJoCo: its warnings go to stderr, not MUJOCO_LOG.TXT
def evaluate_against_expert(
    model: Any,
    env: str | gym.Env,
    demos: Demonstrations | str | Path,
    trajectory_fn: TrajectoryFn | None = None,
    obs_transform: ObsTransform | None = None,
    *,
    env_kwargs: Mapping[str, Any] | None = None,
    max_steps: int | None = None,
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
        raise UserError(f"start_mismatch must be 'warn', 'raise' or 'ignore', got {start_mismatch!r}")
    if max_steps is not None and max_steps < 1:
        raise UserError(f"max_steps must be positive, got {max_steps}")
    env_obj, owned, env_id = _make_env(env, env_kwargs)
    try:
        demos = _checked(demos, env_obj)
        experts = [demos.episode(i) for i in range(demos.n_episodes)]
        _require_seeds(demos)
        features = trajectory_fn if trajectory_fn is not None else trajectory_features(env_id)
        transform = _observation_transform(model, obs_transform)
        space = _model_action_space(model)
        if space is None:  # a scripted expert without spaces: the env's
            space = env_obj.action_space
        step_errors = _step_errors(model, demos, space, transform)
        starts = demos.episode_starts
        episode_mse = np.add.reduceat(step_errors, starts) / demos.episode_lengths

        if start_mismatch == "raise":
            # Every start before the first rollout: the error names each episode that differs.
            differing = [i for i, expert in enumerate(experts) if not same_observation(
                env_obj.reset(seed=int(demos.seeds[i]))[0], expert["observations"])]
            if differing:
                raise UserError(_start_mismatch_message(differing, demos.seeds))

        returns, lengths, frechet, matches, trajectories = [], [], [], [], []
        for expert in experts:
            agent_obs, total = _rollout(model, env_obj, expert["seed"], transform, max_steps)
            matches.append(same_observation(agent_obs[0], expert["observations"]))
            returns.append(total)
            lengths.append(len(agent_obs))
            frechet.append(frechet_distance(features(agent_obs), features(expert["observations"])))
            trajectories.append(agent_obs)
    finally:
        if owned:
            env_obj.close()
    differing = [i for i, match in enumerate(matches) if not match]
    if differing and start_mismatch == "warn":  # one warning naming every episode that differs
        warnings.warn(_start_mismatch_message(differing, demos.seeds), UserWarning, stacklevel=2)

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
