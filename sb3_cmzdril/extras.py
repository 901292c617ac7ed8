"""Optional dependencies: import one, or fail with the pip command that installs it.

The core install (``pip install sb3-cmzdril``) is what an SB3 script needs to train ``CMZDRIL``.
Plots, tables, progress bars, MuJoCo, Ray, rl-zoo3, Minari and the Hugging Face Hub come with extras; code that needs
one imports it through :func:`require_extra` at the point of use, so ``import sb3_cmzdril`` never
pays for them and a missing one is a one-line message instead of a bare ``ModuleNotFoundError``.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from sb3_cmzdril.errors import UserError

#: The extras pyproject.toml defines (``pip install 'sb3-cmzdril[<extra>]'``).
EXTRAS = ("mujoco", "experiments", "ray", "zoo", "minari", "contrib", "hub", "test", "all")


class MissingExtraError(UserError, ImportError):
    """An optional dependency is not installed; the message names the extra that provides it (an
    install to complete, so the command line reports it in one line)."""


def require_extra(module: str, extra: str, feature: str | None = None) -> ModuleType:
    """Import ``module`` and return it, or raise :class:`MissingExtraError` naming ``extra``.

    :param module: the importable name, e.g. ``"matplotlib.pyplot"`` or ``"ray"``.
    :param extra: the sb3-cmzdril extra that installs it (one of :data:`EXTRAS`).
    :param feature: what needs it, for the message (default: the top-level module name).
    :raises ValueError: ``extra`` is not one of :data:`EXTRAS` (a bug in the caller, not the install).
    """
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}; sb3-cmzdril's extras are {', '.join(EXTRAS)}")
    try:
        return importlib.import_module(module)
    except ImportError as e:
        # Only a missing *top-level* package is the user's install; a broken import inside an
        # installed package must surface as itself, or the advice would be wrong.
        top = module.split(".", 1)[0]
        missing = getattr(e, "name", None)
        if missing is not None and missing.split(".", 1)[0] != top:
            raise
        what = feature or top
        raise MissingExtraError(
            f"{what} needs the {extra!r} extra: pip install 'sb3-cmzdril[{extra}]'"
        ) from e
