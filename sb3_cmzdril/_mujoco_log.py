"""MuJoCo's own warnings, routed so that the command line does not show known noise.

MuJoCo (the C library) reports warnings through ``mju_warning``: unless a handler is installed it
prints ``WARNING: ...`` to the process's stderr and appends the message to ``MUJOCO_LOG.TXT`` in
the working directory. Gymnasium's HalfCheetah-v5 model sets the compiler attribute
``settotalmass``, which recent MuJoCo releases (4.0 here) deprecate, so every HalfCheetah env
creation printed that warning and left the file behind. It is not a Python warning, so
``warnings.filterwarnings`` cannot reach it; the handler below can.

The command line installs the handler for the whole process (:func:`route_mujoco_warnings`). The
library installs it only while it makes or steps environments (:func:`mujoco_warnings_routed`) and
puts back whatever handler the user's program had, so importing or using the package changes nothing
outside its own calls.
"""
from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

#: Warnings that say nothing about the user's run (their start, as MuJoCo words them).
KNOWN_NOISE: tuple[str, ...] = ("compiler attribute 'settotalmass' is deprecated",)


def _handle(message: str) -> None:
    if message.startswith(KNOWN_NOISE):
        return
    # sys.stderr at call time: a benchmark worker's stderr is redirected into its run's log.txt.
    print(f"MuJoCo warning: {message}", file=sys.stderr, flush=True)


def route_mujoco_warnings() -> bool:
    """Drop :data:`KNOWN_NOISE` and print any other MuJoCo warning to ``sys.stderr``; never write
    ``MUJOCO_LOG.TXT``. Process-wide (MuJoCo has one handler); returns False without MuJoCo."""
    try:
        import mujoco
    except ImportError:
        return False
    mujoco.set_mju_user_warning(_handle)
    return True


@contextlib.contextmanager
def mujoco_warnings_routed() -> Iterator[None]:
    """Within the block, MuJoCo's warnings go through :func:`route_mujoco_warnings`'s handler, and
    MuJoCo's default (stderr and ``MUJOCO_LOG.TXT``) is back afterwards. A handler the program
    installed itself (or the CLI's) is left alone: it already decides where warnings go."""
    try:
        import mujoco
    except ImportError:
        yield
        return
    if mujoco.get_mju_user_warning() is not None:
        yield
        return
    mujoco.set_mju_user_warning(_handle)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(None)
