"""How far the pretrained clone's own path leaves the demonstrations, and whether it falls.

The clone plays a few episodes deterministically in the training env; the ensemble's mean disagreement
u along them, over its mean u on the demonstrations, is the clone's drift. Near 1 the clone stays where
the demonstrations are (and the NLL epochs that hold the policy to them cost nothing); well above it the
clone leaves them, and the pull back toward the clone fights the reward that would correct it. The
``"auto"`` setting of ``bc_epochs_per_update`` reads it; ``cmz_clip_quantile="auto"`` reads how many of
the clone's episodes the env terminated, and ``absorbing="auto"``, where the expert ends its own episodes,
how long the clone's lasted before the env ended them (:class:`~sb3_cmzdril.CMZDRIL`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_cmzdril.rewards import terminations

#: drift at and above which ``bc_epochs_per_update="auto"`` turns the NLL epochs off: the geometric mean
#: of the drifts measured on Swimmer-v5 (1.2, where the epochs are needed) and WaypointNav-v0 (2.2, the
#: lowest where dropping them was measured to hold); measured per trial, not adopted: docs/one_default.md
DRIFT_LIMIT = 1.6
#: the quantile of u on the demonstrations ``cmz_clip_quantile="auto"`` clips u at where the clone falls
AUTO_CLIP_QUANTILE = 0.98
#: where the expert ends its own episodes, ``absorbing="auto"`` takes the env's ends of the clone's episodes
#: for falls when they come, on average, before this fraction of the shortest demonstration's length
EARLY_END_FRACTION = 0.5
#: episodes the clone plays to measure its drift
PROBE_EPISODES = 5
#: the most steps per env the clone plays (for an env whose episodes do not end)
PROBE_STEPS = 5_000


@dataclasses.dataclass(frozen=True)
class Drift:
    """The clone's mean u along its own episodes (``path_u``) and on the demonstrations (``demo_u``), and
    how many of its ``episodes`` the env ``terminated`` (not cut by a time limit), each after how many
    steps (``terminated_lengths``)."""

    path_u: float
    demo_u: float
    episodes: int
    steps: int
    terminated: int
    terminated_lengths: tuple[int, ...] = ()

    @property
    def ratio(self) -> float:
        """``path_u / demo_u`` (inf where the ensemble agrees exactly on every demonstration step)."""
        if self.demo_u > 0:
            return self.path_u / self.demo_u
        return 1.0 if self.path_u == 0 else float("inf")


def clone_drift(
    policy: Any,
    env: VecEnv,
    disagreement: Callable[[Any], np.ndarray],
    demo_u: float,
    vec_normalize: VecNormalize | None = None,
    episodes: int = PROBE_EPISODES,
    max_steps: int = PROBE_STEPS,
) -> Drift:
    """Play ``policy`` deterministically in ``env`` from a reset until ``episodes`` episodes have ended
    (or ``max_steps`` steps per env) and measure its drift: ``disagreement`` scores a batch of raw
    observations, ``demo_u`` is the mean u on the demonstrations. ``vec_normalize``: the env's
    VecNormalize, whose statistics the probe leaves as they are."""
    training = vec_normalize.training if vec_normalize is not None else False
    raw_from = vec_normalize if vec_normalize is not None and vec_normalize.norm_obs else None
    if vec_normalize is not None:
        vec_normalize.training = False
    u: list[np.ndarray] = []
    ended = steps = 0
    lengths = np.zeros(env.num_envs, dtype=np.int64)
    terminated_lengths: list[int] = []
    try:
        obs = env.reset()
        while ended < episodes and steps < max_steps:
            u.append(np.asarray(disagreement(obs if raw_from is None else raw_from.get_original_obs()), np.float64))
            obs, _, dones, infos = env.step(policy.predict(obs, deterministic=True)[0])
            lengths += 1
            terminated_lengths += [int(n) for n in lengths[terminations(dones, infos)]]
            lengths[np.asarray(dones, bool)] = 0
            ended += int(np.sum(dones))
            steps += 1
    finally:
        if vec_normalize is not None:
            vec_normalize.training = training
    return Drift(float(np.mean(np.concatenate(u))), float(demo_u), ended, steps, len(terminated_lengths),
                 tuple(terminated_lengths))
