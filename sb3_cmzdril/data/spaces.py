"""Observations and actions of every space PPO takes, encoded as SB3 encodes them for its policies.

SB3's ``preprocess_obs`` turns an observation into network inputs: Box as floats (images, i.e. uint8
Boxes in [0, 255] with three dimensions, divided by 255), Discrete as a one-hot vector, MultiDiscrete
as concatenated one-hots, MultiBinary as floats, and a Dict key by key. :class:`ObsEncoder` does the
same in numpy for the ensemble, whose per-step scoring cannot afford torch's per-call overhead:
every non-image part becomes columns of one flat float32 matrix, images stay (B, C, H, W) for a CNN.

Actions are handled as SB3's distributions see them: Box flattened to ``prod(shape)`` values,
Discrete and MultiDiscrete as 0-based indices (SB3's policies output index ``k``; a space with a
``start`` means action ``start + k``), MultiBinary flattened to 0/1 values.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first

from sb3_cmzdril.errors import UserError

#: an observation batch: an array, or a dict of arrays for a Dict space
Observations = np.ndarray | dict[str, np.ndarray]

ACTION_SPACES = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)
_LEAF_SPACES = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)


def shape_of(space: spaces.Space) -> tuple[int, ...]:
    """The shape of one sample of ``space`` (``()`` for Discrete)."""
    return tuple(int(s) for s in (space.shape or ()))


def check_action_space(space: spaces.Space) -> None:
    """ValueError naming an action space PPO (and so CMZDRIL) cannot act in."""
    if not isinstance(space, ACTION_SPACES):
        raise UserError(
            f"unsupported action space {space}: Box, Discrete, MultiDiscrete and MultiBinary are supported"
        )


def action_dim(space: spaces.Space) -> int:
    """Number of values per action in SB3's rollout buffer: 1 (Discrete), len(nvec), or prod(shape)."""
    if isinstance(space, spaces.Discrete):
        return 1
    if isinstance(space, spaces.MultiDiscrete):
        return int(space.nvec.size)
    return int(np.prod(shape_of(space)))


def categorical_starts(space: spaces.Discrete | spaces.MultiDiscrete) -> np.ndarray:
    """The ``start`` of each categorical component (Discrete: one; MultiDiscrete: one per entry)."""
    return np.asarray(space.start, dtype=np.int64).reshape(-1)


def actions_as_indices(actions: np.ndarray, space: spaces.Space) -> np.ndarray:
    """The space's actions as SB3's distributions index them: (B,) or (B, k) 0-based int64 for
    Discrete / MultiDiscrete, (B, d) float32 for Box and MultiBinary."""
    actions = np.asarray(actions)
    if isinstance(space, spaces.Discrete):
        return actions.reshape(-1).astype(np.int64) - int(space.start)
    if isinstance(space, spaces.MultiDiscrete):
        return actions.reshape(len(actions), -1).astype(np.int64) - categorical_starts(space)
    return actions.reshape(len(actions), -1).astype(np.float32)


def indices_as_actions(indices: np.ndarray, space: spaces.Space) -> np.ndarray:
    """Inverse of :func:`actions_as_indices` for the categorical spaces (adds the starts back)."""
    if isinstance(space, spaces.Discrete):
        return np.asarray(indices).reshape(-1).astype(np.int64) + int(space.start)
    if isinstance(space, spaces.MultiDiscrete):
        return np.asarray(indices).reshape(len(indices), -1).astype(np.int64) + categorical_starts(space)
    return np.asarray(indices)


def n_steps(obs: Observations) -> int:
    """Number of rows of an observation batch (a dict: of its first entry)."""
    if isinstance(obs, Mapping):
        return len(next(iter(obs.values())))
    return len(obs)


def take(obs: Observations, index: Any) -> Observations:
    """Rows ``index`` (a slice or an index array) of an observation batch."""
    if isinstance(obs, Mapping):
        return {k: v[index] for k, v in obs.items()}
    return obs[index]


def concatenate(batches: list[Any]) -> Observations:
    """Concatenate observation batches row-wise (arrays or dicts with the same keys)."""
    if batches and isinstance(batches[0], Mapping):
        return {k: np.concatenate([np.asarray(b[k]) for b in batches]) for k in batches[0]}
    return np.concatenate([np.asarray(b) for b in batches])


def reshape_rows(obs: Observations, shape: tuple[int, ...], space: spaces.Space) -> Observations:
    """Reshape the leading dimensions of a batch (e.g. a rollout's (T, n_envs) to (T * n_envs,))."""
    if isinstance(obs, Mapping):
        assert isinstance(space, spaces.Dict)
        return {k: np.asarray(v).reshape(shape + shape_of(space[k])) for k, v in obs.items()}
    return np.asarray(obs).reshape(shape + shape_of(space))


def space_to_config(space: spaces.Space) -> dict[str, Any]:
    """A JSON-able description of a space (Box, Discrete, MultiDiscrete, MultiBinary, Dict of them)."""
    if isinstance(space, spaces.Dict):
        return {"type": "Dict", "spaces": {k: space_to_config(v) for k, v in space.spaces.items()}}
    if isinstance(space, spaces.Box):
        return {
            "type": "Box",
            "low": np.asarray(space.low, np.float64).tolist(),
            "high": np.asarray(space.high, np.float64).tolist(),
            "shape": list(space.shape),
            "dtype": str(space.dtype),
        }
    if isinstance(space, spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if isinstance(space, spaces.MultiDiscrete):
        return {"type": "MultiDiscrete", "nvec": np.asarray(space.nvec).tolist(), "start": space.start.tolist()}
    if isinstance(space, spaces.MultiBinary):
        return {"type": "MultiBinary", "n": np.asarray(space.n).tolist()}
    raise UserError(f"cannot describe the space {space}")


def space_from_config(cfg: Mapping[str, Any]) -> spaces.Space:
    """The space :func:`space_to_config` described."""
    kind = cfg["type"]
    if kind == "Dict":
        return spaces.Dict({k: space_from_config(v) for k, v in cfg["spaces"].items()})
    if kind == "Box":
        shape = tuple(cfg["shape"])
        dtype = np.dtype(cfg["dtype"])
        low = np.asarray(cfg["low"], np.float64).reshape(shape).astype(dtype)
        high = np.asarray(cfg["high"], np.float64).reshape(shape).astype(dtype)
        return spaces.Box(low, high, shape, dtype=dtype)
    if kind == "Discrete":
        return spaces.Discrete(int(cfg["n"]), start=int(cfg["start"]))
    if kind == "MultiDiscrete":
        return spaces.MultiDiscrete(np.asarray(cfg["nvec"]), start=np.asarray(cfg["start"]))
    if kind == "MultiBinary":
        return spaces.MultiBinary(cfg["n"])
    raise UserError(f"unknown space type {kind!r}")


def match_observations(obs: Observations, space: spaces.Space) -> Observations:
    """Demonstration observations checked against ``space`` (ValueError naming a mismatch).

    Channel-last images are transposed when the space is their channel-first form: SB3 wraps an
    image env in VecTransposeImage, so a model's space is channel-first while demos recorded from
    the env itself are not. A Discrete batch of shape (N, 1) becomes (N,).
    """
    if isinstance(space, spaces.Dict):
        if not isinstance(obs, Mapping):
            raise UserError(
                f"the observation space is a Dict (keys {list(space.spaces)}) but the demonstrations hold one array"
            )
        missing = set(space.spaces) - set(obs)
        if missing:
            raise UserError(f"the demonstrations' observations lack the keys {sorted(missing)}")
        matched = {k: _match_leaf(np.asarray(obs[k]), sub, k) for k, sub in space.spaces.items()}
        # The same object when nothing changed, so that callers can tell.
        return obs if list(obs) == list(matched) and all(matched[k] is obs[k] for k in matched) else matched
    if isinstance(obs, Mapping):
        raise UserError(f"the demonstrations hold dict observations but the observation space is {space}")
    return _match_leaf(obs, space, None)


def _match_leaf(arr: np.ndarray, space: spaces.Space, key: str | None) -> np.ndarray:
    where = f" (key {key!r})" if key is not None else ""
    if not isinstance(space, _LEAF_SPACES):
        raise UserError(
            f"unsupported observation space {space}{where}: Box, Discrete, MultiDiscrete, MultiBinary "
            "or a Dict of them are supported"
        )
    shape, want = arr.shape[1:], shape_of(space)
    if shape == want:
        return arr
    if isinstance(space, spaces.Discrete) and shape == (1,):
        return arr.reshape(-1)
    if _image(space) and is_image_space_channels_first(space) and shape == (want[1], want[2], want[0]):  # type: ignore[arg-type]
        return arr.transpose(0, 3, 1, 2)
    raise UserError(
        f"observation shape {shape}{where} of the demonstrations does not match the observation space shape {want}"
    )


@dataclass(frozen=True)
class _Part:
    key: str | None  # the Dict key, None for a plain space
    space: spaces.Space
    kind: str  # "box", "image", "discrete", "multidiscrete", "multibinary"
    width: int  # columns in the flat encoding (0 for images)


def _image(space: spaces.Space) -> bool:
    return isinstance(space, spaces.Box) and is_image_space(space, check_channels=False)


class ObsEncoder:
    """SB3's ``preprocess_obs`` in numpy: non-image parts to one flat float32 matrix, images apart.

    :param observation_space: Box (any shape; an image if SB3 takes it for one), Discrete,
        MultiDiscrete, MultiBinary, or a Dict of those.
    """

    def __init__(self, observation_space: spaces.Space) -> None:
        self.space = observation_space
        if isinstance(observation_space, spaces.Dict):
            items: list[tuple[str | None, spaces.Space]] = list(observation_space.spaces.items())
        else:
            items = [(None, observation_space)]
        parts = []
        for key, space in items:
            if not isinstance(space, _LEAF_SPACES):
                where = f" (key {key!r})" if key is not None else ""
                raise UserError(
                    f"unsupported observation space {space}{where}: Box, Discrete, MultiDiscrete, MultiBinary "
                    "or a Dict of them are supported"
                )
            if _image(space):
                kind, width = "image", 0
            elif isinstance(space, spaces.Box):
                kind, width = "box", int(np.prod(space.shape))
            elif isinstance(space, spaces.Discrete):
                kind, width = "discrete", int(space.n)
            elif isinstance(space, spaces.MultiDiscrete):
                if space.nvec.ndim != 1:
                    raise UserError(f"MultiDiscrete observations need a 1-D nvec (as SB3's), got {space.nvec.shape}")
                kind, width = "multidiscrete", int(space.nvec.sum())
            else:
                kind, width = "multibinary", int(np.prod(space.shape))
            parts.append(_Part(key, space, kind, width))
        self.parts = tuple(parts)
        self.flat_parts = tuple(p for p in parts if p.kind != "image")
        self.image_parts = tuple(p for p in parts if p.kind == "image")
        self.flat_dim = sum(p.width for p in self.flat_parts)
        #: whether the whole observation is one non-image Box (the flat fast path: no copy, no one-hot)
        self.plain_box = len(parts) == 1 and parts[0].kind == "box" and parts[0].key is None
        mask = [np.full(p.width, p.kind == "box") for p in self.flat_parts]
        #: which flat columns come from Box parts (the ones worth standardising)
        self.box_columns = np.concatenate(mask) if mask else np.zeros(0, bool)

    def image_shape(self, part: _Part) -> tuple[int, int, int]:
        """(C, H, W) of an image part, whichever layout its space has."""
        shape = shape_of(part.space)
        if is_image_space_channels_first(part.space):  # type: ignore[arg-type]
            return (shape[0], shape[1], shape[2])
        return (shape[2], shape[0], shape[1])

    def batch(self, obs: Any) -> Observations:
        """``obs`` as a batch: a single observation becomes a batch of one; shapes are checked."""
        if isinstance(self.space, spaces.Dict):
            if not isinstance(obs, Mapping):
                raise ValueError(f"a Dict observation space needs dict observations, got {type(obs).__name__}")
            missing = set(self.space.spaces) - set(obs)
            if missing:
                raise ValueError(f"observations lack the keys {sorted(missing)}")
            single = all(np.shape(obs[p.key]) == p.space.shape for p in self.parts)
            out = {p.key: self._rows(np.asarray(obs[p.key]), p, single) for p in self.parts if p.key is not None}
            if len({len(v) for v in out.values()}) > 1:
                raise ValueError("the entries of the dict observations differ in their number of rows")
            return out
        part = self.parts[0]
        arr = np.asarray(obs)
        return self._rows(arr, part, arr.shape == part.space.shape)

    def _rows(self, arr: np.ndarray, part: _Part, single: bool) -> np.ndarray:
        if single:
            arr = arr[None]
        shape = shape_of(part.space)
        if arr.shape[1:] != shape:
            # A Discrete batch may come as (B, 1), as SB3's rollout buffer keeps it.
            if part.kind == "discrete" and arr.shape[1:] == (1,):
                return arr.reshape(-1)
            where = f" (key {part.key!r})" if part.key is not None else ""
            raise ValueError(
                f"observations of shape {arr.shape[1:]}{where} do not match the observation space's {shape}"
            )
        return arr

    def flat(self, obs: Observations) -> np.ndarray:
        """(B, flat_dim) float32 encoding of the non-image parts of a batch (see :meth:`batch`)."""
        if self.plain_box:
            assert isinstance(obs, np.ndarray)
            x = np.asarray(obs, dtype=np.float32).reshape(len(obs), -1)
            if not np.isfinite(x).all():
                raise ValueError("observations contain NaN or inf")
            return x
        rows = n_steps(obs)
        out = np.zeros((rows, self.flat_dim), np.float32)
        col = 0
        for part in self.flat_parts:
            arr = _part_array(obs, part)
            block = out[:, col : col + part.width]
            space = part.space
            if isinstance(space, spaces.Discrete):
                _one_hot(arr.reshape(rows) - int(space.start), int(space.n), block, 0)
            elif isinstance(space, spaces.MultiDiscrete):
                nvec = np.asarray(space.nvec, np.int64)
                offsets = np.concatenate([[0], np.cumsum(nvec)[:-1]])
                values = arr.reshape(rows, -1).astype(np.int64) - categorical_starts(space)
                for j in range(len(nvec)):
                    _one_hot(values[:, j], int(nvec[j]), block, int(offsets[j]))
            else:
                block[:] = arr.reshape(rows, -1)
                if part.kind == "box" and not np.isfinite(block).all():
                    raise ValueError("observations contain NaN or inf")
            col += part.width
        return out

    def images(self, obs: Observations) -> list[np.ndarray]:
        """Each image part of a batch as (B, C, H, W) float32 in [0, 1], as SB3 scales it."""
        out = []
        for part in self.image_parts:
            arr = _part_array(obs, part).astype(np.float32)
            if not is_image_space_channels_first(part.space):  # type: ignore[arg-type]
                arr = arr.transpose(0, 3, 1, 2)
            out.append(np.ascontiguousarray(arr) / np.float32(255.0))
        return out


def _part_array(obs: Observations, part: _Part) -> np.ndarray:
    if isinstance(obs, Mapping):
        assert part.key is not None, "a dict batch for a space that is not a Dict"
        return np.asarray(obs[part.key])
    return np.asarray(obs)


def _one_hot(values: np.ndarray, n: int, out: np.ndarray, offset: int) -> None:
    values = values.astype(np.int64)
    if values.size and (values.min() < 0 or values.max() >= n):
        raise ValueError(f"discrete observations out of range: values span [{values.min()}, {values.max()}] for {n}")
    out[np.arange(len(values)), offset + values] = 1.0


__all__ = [
    "ACTION_SPACES",
    "ObsEncoder",
    "Observations",
    "action_dim",
    "categorical_starts",
    "actions_as_indices",
    "check_action_space",
    "concatenate",
    "indices_as_actions",
    "match_observations",
    "n_steps",
    "reshape_rows",
    "space_from_config",
    "space_to_config",
    "take",
]
