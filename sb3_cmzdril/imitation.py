"""What CMZDRIL (PPO) and CMZDRILSAC share of CMZ-DRIL's set-up: the checks of its options, the reward
rule they name (with the bounds it takes from the fitted ensemble), and the demonstrations as
tensors for a model's zip.

Both algorithms take the same imitation options (reward, alpha, ema, u0, dril_quantile,
cmz_clip_quantile, the BC pretraining's epochs, held-out share and patience, absorbing) with the
same meaning; checking and interpreting them here keeps the two from drifting apart.
"""
from __future__ import annotations

import json
import logging
import math
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

from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.ensemble import quantile_of_disagreement
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.rewards import RewardRule, make_rule

logger = logging.getLogger(__name__)

#: The reward modes: the paper's, DRIL's, none (PPO or SAC plus BC only) and the env's own.
REWARD_MODES = ("cmz", "dril", "zero", "env")


def check_imitation_options(
    reward: str,
    alpha: float,
    ema: float,
    u0: float,
    dril_quantile: float,
    bc_pretrain_epochs: int,
    bc_validation_fraction: float,
    bc_patience: int,
    absorbing: bool | str,
    cmz_clip_quantile: float | None = None,
    absorbing_score: str = "highest",
    **counts: int,
) -> None:
    """UserError naming the first imitation option out of range (``counts``: other options that must
    be integers >= 0, such as ``bc_epochs_per_update``). Run before anything is built."""
    if reward not in REWARD_MODES:
        raise UserError(f"reward must be one of {REWARD_MODES}, got {reward!r}")
    if reward == "cmz":
        make_rule("cmz", alpha=alpha, ema=ema, u0=u0)  # validates alpha, ema, u0 now, not at learn()
    if not 0.0 < dril_quantile <= 1.0:
        raise UserError(f"dril_quantile must lie in (0, 1], got {dril_quantile}")
    if cmz_clip_quantile is not None and not 0.0 < cmz_clip_quantile <= 1.0:
        raise UserError(f"cmz_clip_quantile must lie in (0, 1] or be None, got {cmz_clip_quantile}")
    for name, value in {"bc_pretrain_epochs": bc_pretrain_epochs, **counts}.items():
        if int(value) < 0:
            raise UserError(f"{name} must be >= 0, got {value}")
    if not 0.0 <= bc_validation_fraction < 1.0:
        raise UserError(f"bc_validation_fraction must lie in [0, 1), got {bc_validation_fraction}")
    if int(bc_patience) < 1:
        raise UserError(f"bc_patience must be >= 1, got {bc_patience}")
    if absorbing not in (True, False, "auto"):
        raise UserError(f"absorbing must be True, False or 'auto', got {absorbing!r}")
    if absorbing_score not in ("highest", "terminal"):
        raise UserError(f"absorbing_score must be 'highest' or 'terminal', got {absorbing_score!r}")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _is_whole(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_whole_numbers(minimum: int, **counts: Any) -> None:
    """UserError naming the first option in ``counts`` (steps, epochs, a batch or buffer size) that is
    not a whole number >= ``minimum``. SB3 accepts many such values without a word and then learns
    nothing (``n_epochs=0``, ``gradient_steps=0``), fails once training runs (``batch_size=0``), or
    makes something else of them (``buffer_size=0`` is a buffer of one transition)."""
    for name, value in counts.items():
        if not _is_whole(value):
            raise UserError(f"{name} must be a whole number >= {minimum}, got {value!r}")
        if value < minimum:
            raise UserError(f"{name} must be >= {minimum}, got {value}")


def check_interval(interval: str, **values: Any) -> None:
    """UserError naming the first option in ``values`` outside ``interval``, written as in maths:
    ``"[0, 1]"``, ``"(0, 1]"``, ``"(0, inf)"``. None (an option switched off) and schedules (callables,
    checked when training starts) pass; inf and nan are :func:`~sb3_cmzdril.errors.check_finite`'s."""
    low_open, high_open = interval[0] == "(", interval[-1] == ")"
    low, high = (float(bound) for bound in interval[1:-1].split(","))
    rule = f"finite and {'>' if low_open else '>='} {low:g}" if math.isinf(high) else f"in {interval}"
    for name, value in values.items():
        if value is None or callable(value):
            continue
        if not _is_number(value):
            raise UserError(f"{name} must be a number {rule}, got {value!r}")
        above = value > low if low_open else value >= low
        below = value < high if high_open else value <= high
        if not (above and below):
            raise UserError(f"{name} must be {rule}, got {float(value)!r}")


def reward_rule(
    reward: str, alpha: float, ema: float, u0: float, dril_threshold: float | None, u_max: float | None = None
) -> RewardRule:
    """The rule a model's options name (``dril_threshold``: computed from the fitted ensemble)."""
    if reward == "cmz":
        return make_rule("cmz", alpha=alpha, ema=ema, u0=u0, u_max=u_max)
    if reward == "dril":
        assert dril_threshold is not None, "the DRIL threshold is computed when the ensemble is fitted"
        return make_rule("dril", threshold=dril_threshold)
    return make_rule(reward)


def rule_bounds(
    reward: str, ensemble: Any, demos: Demonstrations, dril_quantile: float, cmz_clip_quantile: float | None
) -> tuple[float | None, float | None]:
    """What the rule takes from the fitted ensemble: DRIL's threshold (``reward="dril"``) and the CMZ
    reward's clip of u (``reward="cmz"`` with ``cmz_clip_quantile``), each the named quantile of u on
    the demos, else None."""
    dril_threshold = quantile_of_disagreement(ensemble, demos, dril_quantile) if reward == "dril" else None
    u_max = None
    if reward == "cmz" and cmz_clip_quantile is not None:
        u_max = quantile_of_disagreement(ensemble, demos, cmz_clip_quantile)
        if not u_max > 0:  # an ensemble that agrees exactly on most demo steps: a clip at 0 erases the reward
            raise UserError(
                f"cmz_clip_quantile={cmz_clip_quantile} clips u at {u_max:.4g}, the ensemble's disagreement "
                "on that share of the demos; choose a higher quantile or None"
            )
    return dril_threshold, u_max


def demo_tensors(demos: Demonstrations) -> dict[str, th.Tensor]:
    """A Demonstrations with array observations as the tensors a model's zip can hold
    (:func:`demos_from_tensors` reverses it; Dict observations are CMZDRIL's to pack)."""
    return {
        "actions": th.as_tensor(demos.actions),
        "lengths": th.as_tensor(demos.episode_lengths),
        "rewards": th.as_tensor(demos.rewards) if demos.rewards is not None else th.zeros(0),
        "seeds": th.as_tensor(demos.seeds),
    }


def demos_from_tensors(observations: Any, tensors: dict[str, th.Tensor]) -> Demonstrations:
    """The Demonstrations that :func:`demo_tensors` (and the observations) were made from."""
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


def weights_brought_by_user() -> bool:
    """Whether a ``set_parameters()`` call brings the user's weights (True), not a ``load()``
    restoring the saved model's own (False)."""
    return not _RESTORING.get()


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


__all__ = ["REWARD_MODES", "check_imitation_options", "check_interval", "check_saved_learner", "check_whole_numbers",
           "demo_tensors", "demonstrations_to_go_on", "demos_from_tensors", "parameters_to_set", "reward_rule",
           "restored_state", "restoring_saved_model", "rule_bounds", "weights_brought_by_user"]
