"""Expert demonstrations: flat arrays of steps plus episode boundaries.

A :class:`Demonstrations` holds ``observations`` (N, *obs_shape), ``actions`` (N, *act_shape), optional
``rewards`` (N,), the length of each episode and, when known, the reset seed of each episode (so an
evaluation can restart the environment exactly where the expert started). It is immutable in
practice: every operation returns a new object.

Out-of-bounds Box actions: :meth:`Demonstrations.check_spaces` *clips* them to the bounds and warns
(how many, and the largest excess). Imitation targets beyond the bounds cannot be executed by the
environment anyway (SB3 clips the policy's actions too), and DRIL's ensemble is trained on clipped
actions. Every other mismatch (shape, NaN/inf, empty, Discrete action out of range) raises
``ValueError`` naming the problem.
"""
from __future__ import annotations

import warnings
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces

from sb3_cmzdril.data.spaces import check_action_space, concatenate, match_observations, n_steps, take
from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.io import PathLike, atomic_path

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

FORMAT_VERSION = 1
UNKNOWN_SEED = -1


def _observation_arrays(observations: Any) -> np.ndarray | dict[str, np.ndarray]:
    """Observations as float32 (floats) or integer arrays, checked; a dict (Dict spaces) key by key."""
    if isinstance(observations, Mapping):
        if not observations:
            raise UserError("dict observations have no entries")
        arrays: dict[str, np.ndarray] = {}
        for key, value in observations.items():
            if isinstance(value, Mapping):
                raise UserError(f"nested dict observations (key {key!r}) are not supported, as in SB3")
            arrays[str(key)] = _observation_arrays(value)  # type: ignore[assignment]
        if len({len(v) for v in arrays.values()}) > 1:
            raise UserError("the entries of the dict observations differ in their number of steps")
        return arrays
    obs = np.asarray(observations)
    if obs.ndim < 1:
        raise UserError(f"observations must be (n_steps, *obs_shape); got shape {obs.shape}")
    if obs.dtype.kind not in "fiub":
        raise UserError(f"observations and actions must be numeric; got {obs.dtype}")
    obs = obs.astype(np.float32, copy=False) if obs.dtype.kind == "f" else obs
    if obs.dtype.kind == "b":
        obs = obs.astype(np.int8)
    _finite("observations", obs)
    return obs


def _obs_shape(obs: np.ndarray | dict[str, np.ndarray]) -> Any:
    """Shape of one observation (a dict of shapes for dict observations)."""
    return {k: v.shape[1:] for k, v in obs.items()} if isinstance(obs, dict) else obs.shape[1:]


def _seed_array(seeds: Sequence[Any] | np.ndarray) -> np.ndarray:
    """The reset seeds as int64, refusing what a cast would change: a fraction (``1.5`` would become
    seed 1 without a word), a non-finite float, a boolean, text, or an integer beyond int64."""
    try:
        given = np.asarray(seeds)
    except (OverflowError, ValueError):  # e.g. ragged lists
        raise UserError(f"seeds must be one integer per episode (-1 for unknown); got {seeds!r}") from None
    given = given.reshape(-1)
    if given.dtype.kind == "f":
        fractional = np.flatnonzero(~np.isfinite(given) | (given != np.round(given)))
        if fractional.size:
            raise UserError(
                f"reset seeds must be whole numbers (-1 for unknown); episodes {fractional.tolist()[:5]} have "
                f"{given[fractional].tolist()[:5]}"
            )
    elif given.dtype.kind not in "iuO" and given.size:  # "O": Python integers beyond int64 (checked below)
        raise UserError(f"reset seeds must be integers (-1 for unknown); got {given.dtype} values {given.tolist()[:5]}")
    try:
        beyond = (given >= 2**63) | (given < -(2**63))  # exact for floats too (int64.max rounds up to 2**63)
    except TypeError:  # objects that are not numbers
        raise UserError(f"reset seeds must be integers (-1 for unknown); got {given.tolist()[:5]}") from None
    if np.any(beyond):
        raise UserError(f"seeds must fit in int64 (-1 for unknown); got {given[beyond].tolist()[:5]}")
    return given.astype(np.int64)


def _finite(name: str, array: np.ndarray) -> None:
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array.reshape(len(array), -1)))[0, 0]
        raise UserError(f"{name} contains NaN or inf (first at step {bad})")


class Demonstrations:
    """Expert episodes stored as flat step arrays with episode boundaries.

    :param observations: (N, *obs_shape) observations the expert acted on; for a Dict observation
        space, a dict of such arrays.
    :param actions: (N, *act_shape) expert actions (integers (N,) for a Discrete space).
    :param episode_lengths: (n_episodes,) positive lengths summing to N.
    :param rewards: optional (N,) environment rewards.
    :param seeds: optional (n_episodes,) reset seed of each episode; -1 where unknown.
    """

    def __init__(
        self,
        observations: np.ndarray | Mapping[str, np.ndarray],
        actions: np.ndarray,
        episode_lengths: Sequence[int] | np.ndarray,
        rewards: np.ndarray | None = None,
        seeds: Sequence[int] | np.ndarray | None = None,
    ) -> None:
        obs_in = _observation_arrays(observations)
        obs = next(iter(obs_in.values())) if isinstance(obs_in, dict) else obs_in
        act = np.asarray(actions)
        lengths = np.asarray(episode_lengths, dtype=np.int64).reshape(-1)
        if lengths.size == 0 or obs.size == 0 or len(obs) == 0:
            raise UserError("demonstrations are empty: at least one episode with one step is needed")
        if np.any(lengths <= 0):
            raise UserError(f"every episode needs at least one step; got lengths {lengths.tolist()}")
        if len(act) != len(obs):
            with_final = len(obs) == len(act) + lengths.size
            hint = " (observations include the final observation? drop it)" if with_final else ""
            raise UserError(f"observations and actions differ in length: {len(obs)} vs {len(act)} steps{hint}")
        if int(lengths.sum()) != len(obs):
            raise UserError(f"episode lengths sum to {int(lengths.sum())} but there are {len(obs)} steps")
        if act.dtype.kind not in "fiu":
            raise UserError(f"observations and actions must be numeric; got {obs.dtype} and {act.dtype}")
        self.observations: np.ndarray | dict[str, np.ndarray] = obs_in
        self.actions: np.ndarray = (
            act.astype(np.float32, copy=False) if act.dtype.kind == "f" else act.astype(np.int64, copy=False)
        )
        _finite("actions", self.actions)
        if rewards is not None:
            rew = np.asarray(rewards, dtype=np.float32).reshape(-1)
            if len(rew) != len(obs):
                raise UserError(f"rewards have {len(rew)} entries but there are {len(obs)} steps")
            _finite("rewards", rew)
            rewards = rew
        self.rewards: np.ndarray | None = rewards
        self.episode_lengths = lengths
        self.seeds = _seed_array(np.full(lengths.size, UNKNOWN_SEED, dtype=np.int64) if seeds is None else seeds)
        if self.seeds.size != lengths.size:
            raise UserError(f"{self.seeds.size} seeds given for {lengths.size} episodes")
        # numpy and gymnasium reset only with seeds in [0, 2**32): anything else fails at the first
        # replay, after a run has written its files.
        bad = np.flatnonzero((self.seeds != UNKNOWN_SEED) & ((self.seeds < 0) | (self.seeds >= 2**32)))
        if bad.size:
            raise UserError(
                f"reset seeds must be integers in [0, 2**32) (-1 for unknown); episodes {bad.tolist()[:5]} have "
                f"{self.seeds[bad].tolist()[:5]}"
            )

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_episodes(cls, episodes: Iterable[Mapping[str, Any]]) -> Demonstrations:
        """Build from dicts with ``observations`` and ``actions`` (and optional ``rewards``, ``seed``)."""
        episodes = list(episodes)
        if not episodes:
            raise UserError("demonstrations are empty: from_episodes got no episodes")
        for i, ep in enumerate(episodes):
            missing = {"observations", "actions"} - set(ep)
            if missing:
                raise UserError(f"episode {i} lacks {sorted(missing)}")
            if n_steps(ep["observations"]) != len(ep["actions"]):
                raise UserError(
                    f"episode {i}: {n_steps(ep['observations'])} observations but {len(ep['actions'])} actions"
                )
            if len(ep["actions"]) == 0:
                raise UserError(f"episode {i} is empty")
        with_rewards = [ep.get("rewards") is not None for ep in episodes]
        if any(with_rewards) and not all(with_rewards):
            raise UserError("rewards must be given for every episode or for none")
        rewards = [np.asarray(ep["rewards"]).reshape(-1) for ep in episodes] if all(with_rewards) else None
        return cls(
            observations=concatenate([ep["observations"] for ep in episodes]),
            actions=np.concatenate([np.asarray(ep["actions"]) for ep in episodes]),
            episode_lengths=[len(ep["actions"]) for ep in episodes],
            rewards=None if rewards is None else np.concatenate(rewards),
            seeds=[UNKNOWN_SEED if ep.get("seed") is None else ep["seed"] for ep in episodes],
        )

    @classmethod
    def from_trajectories(cls, trajectories: Iterable[Any]) -> Demonstrations:
        """Build from imitation-style trajectories (``imitation.data.types.Trajectory`` or dicts).

        Each has ``obs`` (T + 1 observations, the final one is dropped), ``acts`` (T actions) and
        optionally ``rews``; ``infos`` and ``terminal`` are ignored, seeds are unknown. The
        ``imitation`` package is not needed. See :func:`sb3_cmzdril.data.readers.trajectory_episodes`.
        """
        from sb3_cmzdril.data.readers import trajectory_episodes

        return cls.from_episodes(trajectory_episodes(trajectories))

    @classmethod
    def from_minari(cls, dataset_or_id: Any) -> Demonstrations:
        """Build from a ``minari.MinariDataset`` or the id of a locally stored one (never downloads).

        Episodes keep the reset seeds their metadata records. Needs the ``minari`` extra. See
        :func:`sb3_cmzdril.data.readers.minari_episodes`.
        """
        from sb3_cmzdril.data.readers import minari_episodes

        return cls.from_episodes(minari_episodes(dataset_or_id))

    @classmethod
    def load(cls, path: PathLike) -> Demonstrations:
        """Load a file written by :meth:`save`; clear errors for a missing or corrupt file."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"demonstrations file not found: {path}")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
            raise UserError(f"demonstrations file {path} is corrupt or not an npz file: {e}") from e
        _check_format_version(path, arrays.get("format_version"))
        # Dict observations are saved one array per key, as "observations.<key>".
        dict_obs = {k.partition(".")[2]: v for k, v in arrays.items() if k.startswith("observations.")}
        if dict_obs:
            arrays["observations"] = dict_obs
        missing = {"observations", "actions", "episode_lengths"} - set(arrays)
        if missing:
            raise UserError(f"demonstrations file {path} lacks arrays {sorted(missing)}")
        try:
            return cls(
                observations=arrays["observations"],
                actions=arrays["actions"],
                episode_lengths=arrays["episode_lengths"],
                rewards=arrays.get("rewards"),
                seeds=arrays.get("seeds"),
            )
        except ValueError as e:
            raise UserError(f"demonstrations file {path}: {e}") from e

    def save(self, path: PathLike) -> None:
        """Write a compressed npz atomically (temp file + rename)."""
        obs = self.observations
        # Values typed Any, not np.ndarray: mypy would match a dict of arrays against the stub's
        # `allow_pickle: bool` keyword, which none of these keys is.
        arrays: dict[str, Any] = {
            "format_version": np.asarray(FORMAT_VERSION),
            **({f"observations.{k}": v for k, v in obs.items()} if isinstance(obs, dict) else {"observations": obs}),
            "actions": self.actions,
            "episode_lengths": self.episode_lengths,
            "seeds": self.seeds,
        }
        if self.rewards is not None:
            arrays["rewards"] = self.rewards
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez_compressed(tmp, **arrays)

    # -- views --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return n_steps(self.observations)

    @property
    def n_episodes(self) -> int:
        return int(self.episode_lengths.size)

    @property
    def episode_starts(self) -> np.ndarray:
        """Index of the first step of each episode, (n_episodes,)."""
        return np.concatenate([[0], np.cumsum(self.episode_lengths)[:-1]]).astype(np.int64)

    @property
    def episode_returns(self) -> np.ndarray | None:
        """Sum of rewards of each episode, or None without rewards."""
        if self.rewards is None:
            return None
        return np.add.reduceat(self.rewards.astype(np.float64), self.episode_starts)

    def episode(self, index: int) -> dict[str, Any]:
        """One episode as a dict: observations, actions, rewards (or None), seed."""
        if not -self.n_episodes <= index < self.n_episodes:
            raise IndexError(f"episode {index} out of range for {self.n_episodes} episodes")
        index %= self.n_episodes
        start = int(self.episode_starts[index])
        sl = slice(start, start + int(self.episode_lengths[index]))
        return {
            "observations": take(self.observations, sl),
            "actions": self.actions[sl],
            "rewards": None if self.rewards is None else self.rewards[sl],
            "seed": int(self.seeds[index]),
        }

    def select(self, episode_indices: Iterable[int]) -> Demonstrations:
        """A new Demonstrations holding only those episodes, in the order given."""
        indices = [int(i) for i in episode_indices]
        if not indices:
            raise UserError("select() needs at least one episode index")
        for i in indices:
            if not 0 <= i < self.n_episodes:
                raise IndexError(f"episode {i} out of range for {self.n_episodes} episodes")
        return Demonstrations.from_episodes([self.episode(i) for i in indices])

    def same_steps(self, other: Demonstrations) -> bool:
        """Whether ``other`` holds the same episodes, step for step: observations, actions and episode
        lengths (what the ensemble, the reward's bounds and the input standardisation are fitted on);
        rewards and seeds aside."""
        if not (np.array_equal(self.episode_lengths, other.episode_lengths)
                and np.array_equal(self.actions, other.actions)):
            return False
        mine, theirs = self.observations, other.observations
        if isinstance(mine, dict) or isinstance(theirs, dict):
            return (isinstance(mine, dict) and isinstance(theirs, dict) and mine.keys() == theirs.keys()
                    and all(np.array_equal(mine[key], theirs[key]) for key in mine))
        return np.array_equal(mine, theirs)

    def __repr__(self) -> str:
        return (
            f"Demonstrations(n_episodes={self.n_episodes}, n_steps={len(self)}, "
            f"obs_shape={_obs_shape(self.observations)}, action_shape={self.actions.shape[1:]})"
        )

    # -- validation ---------------------------------------------------------------------------
    def check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> Demonstrations:
        """Check the demos against an env's spaces; return the demos to train on.

        Raises ``ValueError`` naming the mismatch (unsupported space, observation or action shape,
        Discrete / MultiDiscrete / MultiBinary action out of range or not an integer). Channel-last
        image observations are transposed for a channel-first space (SB3's VecTransposeImage). Box
        actions outside the bounds are clipped with a ``UserWarning``. The returned object is then a
        new one, otherwise ``self``.
        """
        obs = match_observations(self.observations, observation_space)
        check_action_space(action_space)  # refuses an unsupported one, naming it: the others are handled below
        if obs is not self.observations:
            return Demonstrations(obs, self.actions, self.episode_lengths, self.rewards, self.seeds).check_spaces(
                observation_space, action_space
            )
        if isinstance(action_space, spaces.Discrete):
            acts = self.actions.reshape(len(self.actions), -1)
            if acts.shape[1] != 1:
                raise UserError(
                    f"Discrete action space needs scalar actions; demos have shape {self.actions.shape[1:]}"
                )
            if self.actions.dtype.kind == "f" and not np.all(self.actions == np.round(self.actions)):
                raise UserError("Discrete action space needs integer actions; the demonstrations hold fractions")
            lo, hi = int(action_space.start), int(action_space.start + action_space.n - 1)
            if acts.min() < lo or acts.max() > hi:
                raise UserError(
                    f"demonstration actions span [{acts.min()}, {acts.max()}] "
                    f"but the Discrete space allows [{lo}, {hi}]"
                )
            if self.actions.dtype != np.int64 or self.actions.ndim != 1:
                as_int = acts[:, 0].astype(np.int64)
                return Demonstrations(self.observations, as_int, self.episode_lengths, self.rewards, self.seeds)
            return self
        if isinstance(action_space, (spaces.MultiDiscrete, spaces.MultiBinary)):
            return self._check_multi_actions(action_space)
        assert isinstance(action_space, spaces.Box)
        if self.actions.shape[1:] != action_space.shape:
            raise UserError(
                f"action shape {self.actions.shape[1:]} of the demonstrations does not match "
                f"the action space shape {action_space.shape}"
            )
        low = action_space.low.astype(np.float32)
        high = action_space.high.astype(np.float32)
        excess = np.maximum(self.actions - high, low - self.actions)
        n_out = int(np.sum(np.any(excess.reshape(len(excess), -1) > 1e-6, axis=1)))
        if n_out == 0:
            return self
        warnings.warn(
            f"{n_out} of {len(self)} demonstration actions lie outside the action bounds "
            f"(largest excess {float(excess.max()):.4g}); clipping them to the bounds",
            UserWarning,
            stacklevel=2,
        )
        clipped = np.clip(self.actions, low, high)
        return Demonstrations(self.observations, clipped, self.episode_lengths, self.rewards, self.seeds)


    def _check_multi_actions(self, action_space: spaces.MultiDiscrete | spaces.MultiBinary) -> Demonstrations:
        shape = tuple(action_space.shape)
        if self.actions.shape[1:] != shape:
            raise UserError(
                f"action shape {self.actions.shape[1:]} of the demonstrations does not match "
                f"the action space shape {shape}"
            )
        if self.actions.dtype.kind == "f" and not np.all(self.actions == np.round(self.actions)):
            name = type(action_space).__name__
            raise UserError(f"{name} actions must be integers; the demonstrations hold fractions")
        acts = self.actions.astype(np.int64)
        if isinstance(action_space, spaces.MultiBinary):
            low, high = np.zeros(shape, np.int64), np.ones(shape, np.int64)
        else:
            low = np.asarray(action_space.start, np.int64)
            high = low + np.asarray(action_space.nvec, np.int64) - 1
        if np.any(acts < low) or np.any(acts > high):
            raise UserError(
                f"demonstration actions span [{acts.min()}, {acts.max()}], outside the {type(action_space).__name__} "
                f"space's [{low.min()}, {high.max()}] in some component"
            )
        if acts.dtype == self.actions.dtype:
            return self
        return Demonstrations(self.observations, acts, self.episode_lengths, self.rewards, self.seeds)


def _check_format_version(path: Path, version: np.ndarray | None) -> None:
    """Refuse a file of a newer format than this package writes: its arrays may mean something
    else (files without a version predate it and are version 1's layout)."""
    if version is None:
        return
    try:
        number = int(np.asarray(version).reshape(()))
    except (TypeError, ValueError):
        raise UserError(f"demonstrations file {path} has an unreadable format_version {version!r}") from None
    if number > FORMAT_VERSION:
        raise UserError(
            f"demonstrations file {path} has format_version {number}, newer than this sb3-cmzdril reads "
            f"({FORMAT_VERSION}): upgrade sb3-cmzdril"
        )


def time_limit(venv: VecEnv) -> int | None:
    """The step limit of the env's gymnasium spec (``max_episode_steps``); None where there is none."""
    try:
        spec = venv.get_attr("spec", [0])[0]
    except (AttributeError, IndexError):  # an env without a gymnasium spec: its time limit is unknown
        return None
    limit = getattr(spec, "max_episode_steps", None)
    return None if limit is None else int(limit)


def expert_never_terminates(demonstrations: Demonstrations, venv: VecEnv) -> bool:
    """Whether every demonstration lasts the env's time limit (``absorbing="auto"``'s test): then a
    termination is something the expert never did. False for an env without a gymnasium spec or
    time limit, whose episodes' ends say nothing about the expert."""
    limit = time_limit(venv)
    return limit is not None and bool(np.all(demonstrations.episode_lengths >= limit))


def as_demonstrations(demos: Demonstrations | PathLike | list[Mapping[str, Any]]) -> Demonstrations:
    """Accept a Demonstrations, a path to a saved file, or a list of episode dicts."""
    if isinstance(demos, Demonstrations):
        return demos
    if isinstance(demos, (str, Path)):
        return Demonstrations.load(demos)
    if isinstance(demos, list):
        return Demonstrations.from_episodes(demos)
    raise TypeError(f"expected Demonstrations, a path or a list of episode dicts; got {type(demos).__name__}")
