"""How both learners keep their imitation state in a model's zip, and bring it back at ``load()``.

One demo format: the demonstrations travel as tensors next to the state dicts (SB3 loads them with
``weights_only=True``): ``_saved_demo_obs`` (a Dict space's arrays packed into one byte tensor, whose
layout the zip's JSON data keeps as ``_demo_obs_layout``), ``_saved_demo_actions``,
``_saved_demo_lengths``, ``_saved_demo_rewards`` (empty where the demos have none) and
``_saved_demo_seeds``; the reward rule's per-env state and the absorbing state's u travel the same way
(:data:`SAVED_TENSORS`). The rest: telling a ``load()`` restoring a model's own weights from weights a
user brings (:func:`restoring_saved_model`), refusing a zip of another learner in one line
(:func:`check_saved_learner`), and what a loaded model goes on with (:func:`demonstrations_to_go_on`).
"""
from __future__ import annotations

import json
import logging
import re
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.save_util import load_from_zip_file, open_path

from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.errors import UserError

logger = logging.getLogger(__name__)

#: Tensors that travel in the zip next to the state dicts, the same for both learners.
SAVED_TENSORS = (
    "_saved_demo_obs",
    "_saved_demo_actions",
    "_saved_demo_lengths",
    "_saved_demo_rewards",
    "_saved_demo_seeds",
    "_saved_reward_state",
    "_saved_absorbing_u",
)


def pack_observations(obs: np.ndarray | dict[str, np.ndarray]) -> tuple[th.Tensor, list | None]:
    """A tensor for the zip and, for dict observations, the layout that unpacks it: SB3 saves extra
    variables as single tensors, so a dict's arrays travel as one byte tensor."""
    if not isinstance(obs, dict):
        return th.as_tensor(np.asarray(obs)), None
    layout = [[key, value.dtype.str, list(value.shape)] for key, value in obs.items()]
    packed = np.concatenate([np.ascontiguousarray(value).view(np.uint8).reshape(-1) for value in obs.values()])
    return th.as_tensor(packed), layout


def unpack_observations(saved: np.ndarray, layout: list | None) -> np.ndarray | dict[str, np.ndarray]:
    """The observations :func:`pack_observations` packed (``layout`` None: they were an array)."""
    if layout is None:
        return saved
    out, offset = {}, 0
    for key, dtype, shape in layout:
        size = int(np.prod(shape)) * np.dtype(dtype).itemsize
        out[key] = saved[offset : offset + size].view(np.dtype(dtype)).reshape(shape)
        offset += size
    return out


def demo_tensors(demos: Demonstrations) -> dict[str, th.Tensor]:
    """A Demonstrations but for its observations (:func:`pack_observations`) as the tensors a model's
    zip holds (:func:`demos_from_tensors` reverses it)."""
    return {
        "actions": th.as_tensor(demos.actions),
        "lengths": th.as_tensor(demos.episode_lengths),
        "rewards": th.as_tensor(demos.rewards) if demos.rewards is not None else th.zeros(0),
        "seeds": th.as_tensor(demos.seeds),
    }


def demos_from_tensors(observations: Any, tensors: dict[str, th.Tensor]) -> Demonstrations:
    """The Demonstrations that :func:`demo_tensors` (and the observations, unpacked) were made from."""
    rewards = tensors["rewards"].cpu().numpy()
    return Demonstrations(
        observations,
        tensors["actions"].cpu().numpy(),
        tensors["lengths"].cpu().numpy(),
        rewards=rewards if rewards.size else None,
        seeds=tensors["seeds"].cpu().numpy(),
    )


def restored_state(saved: np.ndarray, n_envs: int) -> tuple[np.ndarray, bool]:
    """A saved per-env reward state for ``n_envs`` envs: as saved, or (True) each env started from
    the saved mean where the number of envs changed."""
    state = np.asarray(saved, dtype=np.float64).reshape(-1)
    if state.size and state.size != n_envs:
        return np.full(n_envs, state.mean()), True
    return state, False


_RESTORING: ContextVar[bool] = ContextVar("sb3_cmzdril_restoring_a_saved_model", default=False)


@contextmanager
def restoring_saved_model() -> Iterator[None]:
    """Within: a model's ``load()`` is running. SB3's ``load()`` calls ``set_parameters()`` with the
    weights the model was saved with; those are not weights a user brought, so the model keeps the
    pretrained flag it was saved with (see :func:`weights_brought_by_user`)."""
    token = _RESTORING.set(True)
    try:
        yield
    finally:
        _RESTORING.reset(token)


def parameters_to_set(load_path_or_dict: Any, device: th.device | str) -> dict[str, Any]:
    """The state dicts a ``set_parameters()`` call brings: the dict itself, or a saved zip's."""
    if isinstance(load_path_or_dict, dict):
        return load_path_or_dict
    _, params, _ = load_from_zip_file(load_path_or_dict, device=device, load_data=False)
    return params


def restoring() -> bool:
    """Whether a model's ``load()`` is running (within :func:`restoring_saved_model`)."""
    return _RESTORING.get()


def weights_brought_by_user() -> bool:
    """Whether a ``set_parameters()`` call brings the user's weights (True), not a ``load()``
    restoring the saved model's own (False)."""
    return not restoring()


def _saved_data(path: Any) -> tuple[str, dict[str, Any]] | None:
    """The name of a saved model's file and the raw JSON of its ``data`` member (read with
    :func:`json.loads` only: no ``:serialized:`` value is unpickled); None where it cannot be read,
    so that SB3's ``load()`` reports the file as it does."""
    try:
        file = open_path(path, "r", verbose=0, suffix="zip")  # as SB3's load(): "agent" may mean agent.zip
    except (OSError, TypeError, ValueError):
        return None
    name = str(getattr(file, "name", "the model file"))
    start = file.tell() if file.seekable() else None
    try:
        if start is None:  # a stream read once: SB3's load() needs it whole
            return None
        with zipfile.ZipFile(file) as archive:
            data = json.loads(archive.read("data"))
    except (KeyError, OSError, ValueError, zipfile.BadZipFile):  # no data member, not a zip, not JSON
        return None
    finally:
        if isinstance(path, (str, Path)):
            file.close()
        elif start is not None:
            file.seek(start)
    return (name, data) if isinstance(data, dict) else None


def _saved_algorithm(data: dict[str, Any]) -> tuple[str, bool]:
    """What saved a model, from the keys of its data: the learner's name (a plain SB3 algorithm's
    read from its policy's module where that names it) and whether it learns off-policy."""
    off_policy = "buffer_size" in data  # OffPolicyAlgorithm's; OnPolicyAlgorithm saves gae_lambda
    if "ensemble_size" in data:
        return ("CMZDRILSAC" if off_policy else "CMZDRIL"), off_policy
    policy = data.get("policy_class")
    module = policy.get("__module__", "") if isinstance(policy, dict) else ""
    found = re.fullmatch(r"(?:stable_baselines3|sb3_contrib)\.(\w+)\.policies", str(module))
    if found is not None and found.group(1) != "common":
        return found.group(1).upper(), off_policy
    if off_policy:
        return "an off-policy SB3 model (SAC, TD3, DQN, ...)", True
    return ("PPO" if "n_epochs" in data else "A2C"), False


def check_saved_learner(path: Any, learner: str, off_policy: bool, plain_sb3: bool) -> None:
    """UserError, before SB3's ``load()`` fails on it with an unrelated TypeError or AttributeError,
    where the model saved at ``path`` is not one ``learner`` loads: one of the other kind (on- or
    off-policy), or, unless ``plain_sb3``, a plain SB3 model of the same kind. The message names
    the file, what it holds and what loads it. A file that cannot be read passes (SB3 reports it)."""
    saved = _saved_data(path)
    if saved is None:
        return
    name, data = saved
    algorithm, saved_off_policy = _saved_algorithm(data)
    if algorithm == learner or (saved_off_policy == off_policy and plain_sb3):
        return
    if algorithm.startswith("an "):
        raise UserError(f"{name} holds {algorithm}, not a {learner} one; load it with its own algorithm's load()")
    raise UserError(f"{name} holds a {algorithm} model, not a {learner} one; load it with {algorithm}.load")


def demonstrations_to_go_on(
    saved: Demonstrations | None,
    given: Demonstrations | None,
    observation_space: spaces.Space,
    action_space: spaces.Space,
    fitted: bool,
    learner: str,
) -> tuple[Demonstrations | None, bool]:
    """What a loaded model goes on with: the demonstrations ``load()`` was given (else the saved ones),
    checked against the spaces, and whether its fitted ensemble, and with it the reward's bounds (DRIL's
    threshold, the CMZ clip) and state, belong to other demonstrations and must be fitted again.

    They must where the model was saved ``fitted`` on demonstrations that hold other steps than the
    given ones: the reward would otherwise still measure the distance to the old demonstrations while
    the BC steps pull toward the new ones. The refit is logged. Given demonstrations that are the
    saved ones (a resumed run handed its pool again) keep everything as saved.
    """
    demos = given if given is not None else saved
    if demos is None:
        return None, False
    demos = demos.check_spaces(observation_space, action_space)
    if not fitted or given is None or saved is None or saved.same_steps(demos):
        return demos, False
    logger.info(
        "%s.load: the demonstrations given (%d episodes, %d steps) differ from those the model was saved "
        "with (%d episodes, %d steps): its ensemble and reward bounds are fitted again on them at the next "
        "learn(); the policy keeps its weights and input standardisation",
        learner, demos.n_episodes, len(demos), saved.n_episodes, len(saved),
    )
    return demos, True


__all__ = ["SAVED_TENSORS", "check_saved_learner", "demo_tensors", "demonstrations_to_go_on", "demos_from_tensors",
           "pack_observations", "parameters_to_set", "restored_state", "restoring", "restoring_saved_model",
           "unpack_observations", "weights_brought_by_user"]
