"""Whether the pretrained clone falls, and how far its own path leaves the demonstrations.

The clone plays a few episodes deterministically in the training env. ``cmz_clip_quantile="auto"`` reads
how many of them the env terminated; ``absorbing="auto"``, where the expert ends its own episodes, how
long they lasted before the env ended them; ``bc_epochs_per_update="auto"`` whether the clone falls by
either test (:func:`clone_falls`; :class:`~sb3_cmzdril.CMZDRIL`). The ensemble's mean disagreement u along
them, over its mean u on the demonstrations, is the clone's drift (:attr:`Drift.ratio`), logged with them.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_cmzdril.rewards import terminations

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


def falls_early(mean_end: float, shortest: float) -> bool:
    """Where the expert ends its own episodes: whether the env ends the clone's, after ``mean_end`` steps on
    average, before :data:`EARLY_END_FRACTION` of the ``shortest`` demonstration's length."""
    return mean_end < EARLY_END_FRACTION * shortest


def clone_falls(drift: Drift, demo_lengths: np.ndarray, limit: int | None) -> tuple[bool, str]:
    """Whether the clone whose episodes ``drift`` measured falls, and why: where every demonstration lasts
    the env's time ``limit``, the env terminated one of its episodes; elsewhere (the expert ends its own
    episodes, or the env has no time limit) the env ended them, on average, before
    :data:`EARLY_END_FRACTION` of the shortest demonstration's length."""
    ended = f"the env terminated {drift.terminated} of the clone's {drift.episodes} episodes"
    lengths = np.asarray(demo_lengths)
    if limit is not None and bool(np.all(lengths >= limit)):
        return drift.terminated > 0, f"{ended}, where every demonstration lasts the time limit ({limit} steps)"
    if not drift.terminated_lengths:
        return False, ended
    mean_end, shortest = float(np.mean(drift.terminated_lengths)), int(np.min(lengths))
    falls = falls_early(mean_end, shortest)
    return falls, (f"{ended}, after {mean_end:.0f} steps on average: {'under' if falls else 'at least'} "
                   f"{EARLY_END_FRACTION:g} times the shortest demonstration's {shortest}")
