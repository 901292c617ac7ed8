"""Published agents on a newer version of their env whose observation has another layout.

The RL Zoo's Ant-v3 agents (``DLR-RM/rl-trained-agents``, the Hugging Face Hub's ``sb3`` models) saw
111 numbers: the torso's height and orientation and the joints' angles (13), the velocities (14), then
84 contact forces (14 bodies x 6). Under mujoco >= 2.0, which the zoo trained with, gym's Ant-v3 read
those contact forces as zeros, so the agents learned with 84 inputs that never moved (their saved
``VecNormalize`` statistics show it: mean 0, variance 0). Ant-v4 dropped them by default and Ant-v5
puts back 78 real ones (13 bodies, the world body left out): 105 numbers, or 27 with
``include_cfrc_ext_in_observation=False``. The first 27 mean the same in every version, so the agent
acts as it was trained when it gets them followed by 84 zeros (:class:`PaddedObservationExpert`),
while the demo pool records the env's own observation.

Only layouts that are known and checked are adapted (:data:`PADDED_LAYOUTS`); any other shape
mismatch stays an error. The zoo's Humanoid-v3 agents cannot be adapted this way: their extra inputs
(inertias, velocities, actuator forces) were not zeros.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_cmzdril.errors import UserError


@dataclass(frozen=True)
class PaddedLayout:
    """An agent trained on ``name`` at one of ``trained_versions`` with ``trained_size`` inputs, of
    which the first ``kept`` are the same quantities as the first ``kept`` of the newer versions'
    observation (of a size in ``target_sizes``) and the rest were zeros in its training."""

    name: str
    trained_versions: tuple[int, ...]
    target_versions: tuple[int, ...]
    trained_size: int
    kept: int
    target_sizes: tuple[int, ...]

    @property
    def observation_space(self) -> gym.spaces.Box:
        """The observation space the agent was trained on."""
        return gym.spaces.Box(-np.inf, np.inf, (self.trained_size,), np.float32)

    def describe(self) -> str:
        return (f"the first {self.kept} of the env's observation followed by "
                f"{self.trained_size - self.kept} zeros, the contact forces the agent saw as zeros in training")


#: The largest running variance of an input that counts as never having moved (see check_padding_was_zeros).
_NEVER_MOVED = 1e-6

#: The layouts :func:`padded_layout` adapts, by env name.
PADDED_LAYOUTS: dict[str, PaddedLayout] = {
    "Ant": PaddedLayout(name="Ant", trained_versions=(2, 3), target_versions=(4, 5), trained_size=111, kept=27,
                        target_sizes=(27, 105)),
}


def padded_layout(trained: tuple[str, int] | None, target: tuple[str, int] | None, recorded_shape: Any,
                  env_shape: Any) -> PaddedLayout | None:
    """The known layout that adapts an agent trained on the env ``trained`` (name, version) with
    observations of ``recorded_shape`` to the env ``target`` whose observations have ``env_shape``, if any."""
    if trained is None or target is None or trained[0] != target[0]:
        return None
    layout = PADDED_LAYOUTS.get(trained[0])
    if (layout is None or trained[1] not in layout.trained_versions or target[1] not in layout.target_versions
            or recorded_shape is None or env_shape is None):
        return None
    if tuple(recorded_shape) != (layout.trained_size,) or tuple(env_shape) not in [(n,) for n in layout.target_sizes]:
        return None
    return layout


def check_padding_was_zeros(layout: PaddedLayout, stats: Any, model_path: Path) -> None:
    """Refuse the padding unless the agent's own ``VecNormalize`` statistics (``stats``) show the
    padded inputs at zero throughout its training (without statistics it is assumed); warn that the
    agent's inputs are padded either way."""
    if stats is not None:
        mean = np.asarray(stats.obs_rms.mean, dtype=np.float64)[layout.kept:]
        var = np.asarray(stats.obs_rms.var, dtype=np.float64)[layout.kept:]
        # SB3's running variance starts at 1 with a count of 1e-4, so an input that never moved keeps a
        # variance of about 1e-4 / (steps seen), not 0; real contact forces (clipped to [-1, 1]) vary far more.
        if mean.shape != (layout.trained_size - layout.kept,) or np.any(mean != 0.0) or np.any(var > _NEVER_MOVED):
            raise UserError(
                f"expert {model_path}: its observations {layout.kept}-{layout.trained_size - 1} were not all "
                "zeros in training (its saved statistics say so), so the env's observation cannot be padded for it"
            )
    why = "its saved statistics show they never moved" if stats is not None else "assumed: no saved statistics to check"
    warnings.warn(
        f"expert {model_path} was trained on {layout.trained_size} observations and the env gives another "
        f"layout: it gets {layout.describe()} ({why})",
        UserWarning,
        stacklevel=3,
    )


class PaddedObservationExpert:
    """An expert that acts on ``layout.trained_size`` inputs, given the env's observations: it sees
    their first ``layout.kept`` entries followed by zeros (see the module docstring)."""

    def __init__(self, expert: Any, layout: PaddedLayout) -> None:
        self.expert = expert
        self.layout = layout
        self.action_space = expert.action_space

    def pad(self, observation: np.ndarray) -> np.ndarray:
        """The agent's input for one observation or a batch of them."""
        observation = np.asarray(observation)
        kept = observation[..., :self.layout.kept]
        zeros = np.zeros(kept.shape[:-1] + (self.layout.trained_size - self.layout.kept,), dtype=kept.dtype)
        return np.concatenate([kept, zeros], axis=-1)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        return self.expert.predict(self.pad(observation), state=state, episode_start=episode_start,
                                   deterministic=deterministic)
