"""What CMZDRIL (PPO) and CMZDRILSAC share of CMZ-DRIL's set-up: the checks of its options, the reward
rule they name (with the bounds it takes from the fitted ensemble), and the demonstrations as
tensors for a model's zip.

Both algorithms take the same imitation options (reward, alpha, ema, u0, dril_quantile,
cmz_clip_quantile, the BC pretraining's epochs, held-out share and patience, absorbing) with the
same meaning; checking and interpreting them here keeps the two from drifting apart.
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_cmzdril.demos import Demonstrations
from sb3_cmzdril.ensemble import quantile_of_disagreement
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.rewards import RewardRule, make_rule

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


__all__ = ["REWARD_MODES", "check_imitation_options", "demo_tensors", "demos_from_tensors", "parameters_to_set",
           "reward_rule", "restored_state", "restoring_saved_model", "rule_bounds", "weights_brought_by_user"]
