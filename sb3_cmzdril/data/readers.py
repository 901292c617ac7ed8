"""Demonstrations from other tools' formats: imitation-style trajectories and Minari datasets.

Both formats store ``T + 1`` observations per episode (the final one included) next to ``T``
actions; :class:`~sb3_cmzdril.data.demos.Demonstrations` keeps only the observations the expert acted
on, so the readers drop the last observation of each episode. They return episode dicts for
:meth:`Demonstrations.from_episodes`, which does the remaining validation.

The ``imitation`` package is read by duck typing and never imported: it pins older
stable-baselines3/gymnasium releases than this package needs. Minari is an optional extra
(``pip install 'sb3-cmzdril[minari]'``) imported only by :func:`minari_episodes`.
"""
from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from sb3_cmzdril.errors import UserError
from sb3_cmzdril.extras import require_extra

#: Seeds are stored as int64 (-1 = unknown); Minari's automatic seeds are 64-bit unsigned.
_MAX_SEED = np.iinfo(np.int64).max


def _field(trajectory: Any, name: str) -> Any:
    """``trajectory[name]`` for a mapping, ``trajectory.name`` otherwise; None when absent."""
    if isinstance(trajectory, Mapping):
        return trajectory.get(name)
    return getattr(trajectory, name, None)


def _steps_array(value: Any, what: str) -> np.ndarray:
    """A numeric array of per-step values, or ValueError naming ``what`` (Dict/Tuple spaces)."""
    if isinstance(value, (Mapping, tuple)) or type(value).__name__ == "DictObs":
        raise UserError(
            f"{what} are a Dict or Tuple space's values; only flat arrays are supported "
            "(record through gymnasium.wrappers.FlattenObservation)"
        )
    array = np.asarray(value)
    if array.dtype == object:
        raise UserError(f"{what} are not a numeric array (got dtype object; nested or ragged values?)")
    return array


def trajectory_episodes(trajectories: Iterable[Any]) -> list[dict[str, Any]]:
    """Episode dicts from imitation-style trajectories.

    Each trajectory is an object or a mapping with ``obs`` (T + 1 observations), ``acts`` (T
    actions) and optionally ``rews`` (T rewards); ``infos`` and ``terminal`` are accepted and not
    used. These are the fields of ``imitation.data.types.Trajectory`` / ``TrajectoryWithRew``.

    :raises ValueError: no trajectories, a missing field, an empty trajectory, lengths that do not
        match, rewards on some trajectories only, or Dict observations.
    """
    if _field(trajectories, "obs") is not None and _field(trajectories, "acts") is not None:
        raise UserError("from_trajectories needs a list of trajectories, not a single trajectory: wrap it in [ ]")
    trajectories = list(trajectories)
    if not trajectories:
        raise UserError("demonstrations are empty: from_trajectories got no trajectories")
    episodes = []
    for i, traj in enumerate(trajectories):
        obs, acts, rews = _field(traj, "obs"), _field(traj, "acts"), _field(traj, "rews")
        if obs is None or acts is None:
            missing = [name for name, value in (("obs", obs), ("acts", acts)) if value is None]
            raise UserError(f"trajectory {i} lacks {missing} (expected imitation's obs/acts fields)")
        obs = _steps_array(obs, f"trajectory {i}: observations")
        acts = _steps_array(acts, f"trajectory {i}: actions")
        if len(acts) == 0:
            raise UserError(f"trajectory {i} has no actions")
        if len(obs) != len(acts) + 1:
            raise UserError(
                f"trajectory {i}: {len(obs)} observations for {len(acts)} actions; imitation-style "
                "trajectories hold one more observation than actions (the final one)"
            )
        if rews is not None and len(rews) != len(acts):
            raise UserError(f"trajectory {i}: {len(rews)} rewards for {len(acts)} actions")
        episodes.append({"observations": obs[:-1], "actions": acts, "rewards": rews})
    return episodes


def _storable_seeds(seeds: list[int | None], source: str) -> list[int | None]:
    """Seeds that fit the int64 field; larger ones become unknown, with one warning."""
    too_big = {i for i, s in enumerate(seeds) if s is not None and not 0 <= s <= _MAX_SEED}
    if too_big:
        warnings.warn(
            f"{len(too_big)} of {len(seeds)} episodes of {source} have reset seeds outside [0, 2**63); "
            f"they are kept as unknown (-1), so those episodes cannot be replayed from their seed "
            f"(first: episode {min(too_big)})",
            UserWarning,
            stacklevel=3,
        )
    return [None if i in too_big else s for i, s in enumerate(seeds)]


def minari_episodes(dataset_or_id: Any) -> list[dict[str, Any]]:
    """Episode dicts (with reset seeds where recorded) from a Minari dataset or a local dataset id.

    An id is loaded with ``minari.load_dataset(id, download=False)``: from ``MINARI_DATASETS_PATH``
    (default ``~/.minari/datasets``), never from the network (``minari download <id>`` fetches one).
    The episodes are the dataset's ``episode_indices`` in order, so a filtered dataset reads as
    filtered. Seeds come from the episodes' metadata (the DataCollector records the seed of each
    ``reset``).

    :raises ValueError: an empty dataset, Dict/Tuple observations or actions.
    :raises FileNotFoundError: an id that is not in the local Minari folder.
    """
    minari = require_extra("minari", "minari", feature="Demonstrations.from_minari")
    if isinstance(dataset_or_id, str):
        dataset = minari.load_dataset(dataset_or_id, download=False)
    elif hasattr(dataset_or_id, "iterate_episodes") and hasattr(dataset_or_id, "storage"):
        dataset = dataset_or_id
    else:
        raise TypeError(f"expected a minari.MinariDataset or a dataset id; got {type(dataset_or_id).__name__}")
    source = f"Minari dataset {dataset.id!r}"
    indices = [int(i) for i in dataset.episode_indices]
    if not indices:
        raise UserError(f"demonstrations are empty: {source} has no episodes")
    metadata = list(dataset.storage.get_episode_metadata(indices))
    seeds = _storable_seeds([None if m.get("seed") is None else int(m["seed"]) for m in metadata], source)
    episodes = []
    for k, episode in enumerate(dataset.iterate_episodes(indices)):
        obs = _steps_array(episode.observations, f"{source}, episode {episode.id}: observations")
        acts = _steps_array(episode.actions, f"{source}, episode {episode.id}: actions")
        if len(obs) != len(acts) + 1:
            raise UserError(
                f"{source}, episode {episode.id}: {len(obs)} observations for {len(acts)} actions "
                "(Minari stores one more observation than actions)"
            )
        episodes.append({"observations": obs[:-1], "actions": acts, "rewards": episode.rewards, "seed": seeds[k]})
    return episodes
