"""The package's error for bad input, apart from the errors of bugs.

Where sb3-cmzdril checks what it was given (an option, a YAML entry, a demo pool, a run folder, a
model file) and refuses it, it raises :class:`UserError`: the command line prints its message as one
line and exits with code 2. Any other exception is a bug, in sb3-cmzdril or in the code it runs (an
environment, a policy), and keeps its traceback.

:class:`UserError` is a :class:`ValueError`, and its subclasses for missing and existing files are
also :class:`FileNotFoundError` and :class:`FileExistsError`, so code written against the built-in
types keeps catching them.

This module imports nothing of the package: every layer may raise these.
"""
from __future__ import annotations

import math
from typing import Any


class UserError(ValueError):
    """The input is wrong: a bad value, file or folder; the message names it and says what to do."""


class OptionError(UserError, AssertionError):
    """A learner option that SB3's own algorithm refuses with an assertion: one line on the command line,
    and code written for SB3 that catches its AssertionError catches this too."""


class MissingFileError(UserError, FileNotFoundError):
    """A file or folder the user named (or a default one the command needs) does not exist."""


class OutputExistsError(UserError, FileExistsError):
    """The output would replace a file or folder that is not the command's own to replace."""


def check_finite(**values: Any) -> None:
    """UserError naming the first numeric option that is inf or nan.

    Range checks written as ``not value > 0`` let inf through, and SB3's own checks none of them:
    such a value trains on nan, or fails inside torch once a run has written its files. None (an
    option switched off), booleans, strings (``ent_coef="auto"``) and schedules (callables, checked
    when training starts) pass.
    """
    for name, value in values.items():
        if value is None or callable(value) or isinstance(value, bool):
            continue
        try:
            finite = math.isfinite(value)
        except TypeError:  # not a number: the option's own check (or SB3's) reports it
            continue
        if not finite:
            raise UserError(f"{name} must be finite, got {value}")


__all__ = ["MissingFileError", "OptionError", "OutputExistsError", "UserError", "check_finite"]
