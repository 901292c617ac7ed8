"""The checks of the options both learners take, run in their constructors before anything is built:
the imitation options (reward, alpha, ema, u0, dril_quantile, cmz_clip_quantile, the BC pretraining's
epochs, held-out share and patience, absorbing) mean the same for CMZDRIL and CMZDRILSAC, and checking
them in one place keeps the two from drifting apart; :func:`check_whole_numbers` and
:func:`check_interval` serve the learners' own options too.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from sb3_cmzdril.errors import UserError
from sb3_cmzdril.rewards import make_rule

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
    cmz_clip_quantile: float | str | None = None,
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
    if isinstance(cmz_clip_quantile, str):
        if cmz_clip_quantile != "auto":
            raise UserError(f"cmz_clip_quantile must lie in (0, 1], be None or 'auto', got {cmz_clip_quantile!r}")
    elif cmz_clip_quantile is not None and not 0.0 < cmz_clip_quantile <= 1.0:
        raise UserError(f"cmz_clip_quantile must lie in (0, 1], be None or 'auto', got {cmz_clip_quantile}")
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


def check_interval(interval: str, error: type[UserError] = UserError, **values: Any) -> None:
    """``error`` (a UserError) naming the first option in ``values`` outside ``interval``, written as in
    maths: ``"[0, 1]"``, ``"(0, 1]"``, ``"(0, inf)"``. None (an option switched off) and schedules
    (callables, checked when training starts) pass; inf and nan are
    :func:`~sb3_cmzdril.errors.check_finite`'s."""
    low_open, high_open = interval[0] == "(", interval[-1] == ")"
    low, high = (float(bound) for bound in interval[1:-1].split(","))
    rule = f"finite and {'>' if low_open else '>='} {low:g}" if math.isinf(high) else f"in {interval}"
    for name, value in values.items():
        if value is None or callable(value):
            continue
        if not _is_number(value):
            raise error(f"{name} must be a number {rule}, got {value!r}")
        above = value > low if low_open else value >= low
        below = value < high if high_open else value <= high
        if not (above and below):
            raise error(f"{name} must be {rule}, got {float(value)!r}")


__all__ = ["REWARD_MODES", "check_imitation_options", "check_interval", "check_whole_numbers"]
