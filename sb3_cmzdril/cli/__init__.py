"""Command line: ``sb3-cmzdril <command> --help``.

One module a command group, each command with an ``add_<command>`` function that builds its parser
and a ``_run_<command>`` function that only translates arguments into calls of the library; the work
lives in the library's modules:

- :mod:`~sb3_cmzdril.cli.experts`: ``train-expert``, ``collect-demos``
- :mod:`~sb3_cmzdril.cli.train`: ``train``
- :mod:`~sb3_cmzdril.cli.evaluate`: ``evaluate``

``benchmark`` and ``report`` belong to the lab beside the library (``lab/`` in the repository, the
package ``sb3-cmzdril-lab``); it adds them here through the entry point group
:data:`PLUGIN_GROUP`, and without it they answer with one line saying where they went.

Here: the parser of all commands and :func:`main`, the console script ``sb3-cmzdril`` (also
``python -m sb3_cmzdril``), which turns a user's error into one line and an exit code.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from sb3_cmzdril.cli.evaluate import add_evaluate
from sb3_cmzdril.cli.experts import add_collect_demos, add_train_expert
from sb3_cmzdril.cli.train import add_train
from sb3_cmzdril.errors import UserError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    AddCommand = Callable[[Any], None]

#: The library's commands, in the order ``--help`` lists them.
_COMMANDS: tuple[AddCommand, ...] = (add_train_expert, add_collect_demos, add_train, add_evaluate)
#: Entry point group through which another package adds commands (each entry: a function that adds its
#: subparser, as the ``add_<command>`` functions here do).
PLUGIN_GROUP = "sb3_cmzdril.commands"
#: Commands that lived in this package until 0.2.0 and now come from the lab, with where to get it.
MOVED_TO_LAB = {
    "benchmark": "the trial grid",
    "report": "results.md, its tables and figures from runs folders",
}
LAB_INSTALL = "pip install -e lab/ in a clone of the sb3-cmzdril repository (the package sb3-cmzdril-lab)"


def _plugin_commands() -> dict[str, AddCommand]:
    """The ``add_<command>`` functions that installed packages register under :data:`PLUGIN_GROUP`."""
    from importlib.metadata import entry_points

    return {entry.name: entry.load() for entry in entry_points(group=PLUGIN_GROUP)}


def _moved(name: str, what: str) -> AddCommand:
    """A stand-in for a command of the lab that is not installed: any arguments, one line, exit 2."""

    def add(sub) -> None:
        # No options of its own (no prefix characters): whatever follows the command is taken as it is.
        p = sub.add_parser(name, help=f"{what} (needs the lab: sb3-cmzdril-lab)", add_help=False, prefix_chars="\0")
        p.add_argument("rest", nargs=argparse.REMAINDER)

        def run(args) -> int:
            raise UserError(f"`{name}` moved to the lab beside the library in 0.2.0; install it: {LAB_INSTALL}")

        p.set_defaults(func=run)

    return add


#: What ``sb3-cmzdril --help`` says the command line is.
DESCRIPTION = "CMZ-DRIL imitation learning for stable-baselines3: experts, demos, training, benchmarks."


def build_parser(
    prog: str = "sb3-cmzdril", commands: Sequence[AddCommand] | None = None, description: str = DESCRIPTION
) -> argparse.ArgumentParser:
    """The ``sb3-cmzdril`` parser: the library's :data:`_COMMANDS` and those the lab adds (or their
    stand-ins); ``commands`` and ``description`` give another console script its own."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    from sb3_cmzdril._version import __version__

    parser.add_argument("--version", action="version", version=f"{prog} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    if commands is None:
        plugins = _plugin_commands()
        moved = [plugins.pop(name, _moved(name, what)) for name, what in MOVED_TO_LAB.items()]
        commands = (*_COMMANDS, *moved, *plugins.values())
    for add in commands:
        add(sub)
    return parser


#: Exceptions that mean "the input is wrong" (a bad value, a missing or existing file, an optional
#: package not installed): one line and exit code 2. The package raises them where it checks its
#: input; anything else, a ValueError or KeyError of an env or of SB3 included, is a bug somewhere
#: and keeps its traceback (exit code 1).
USER_ERRORS = (UserError,)
#: Commands that continue from their checkpoints when run again.
RESUMABLE = ("train-expert", "train", "benchmark")


class Terminated(BaseException):
    """SIGTERM arrived: unwinds like Ctrl-C (a benchmark ends its workers on the way out), but no
    ``except Exception`` of a run may swallow it."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


@contextlib.contextmanager
def _signal_handlers() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt and SIGTERM :class:`Terminated` while a command runs; the
    previous handlers come back afterwards (``main`` is also called from Python, e.g. tests).

    SIGINT gets Python's default handler even where the process started with it ignored: a
    non-interactive runner (nohup, some CI shells) hands its children SIG_IGN, and a command that
    cannot be interrupted would train to the end.
    """
    try:
        previous = {signal.SIGINT: signal.signal(signal.SIGINT, signal.default_int_handler),
                    signal.SIGTERM: signal.signal(signal.SIGTERM, _terminate)}
    except ValueError:  # not the main thread: signals are not ours to handle
        yield
        return
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def _one_line(error: BaseException) -> str:
    text = str(error)
    return "; ".join(line.strip() for line in text.splitlines() if line.strip()) or type(error).__name__


def _check_output_option(args: argparse.Namespace) -> None:
    """An empty ``-o`` is a UserError: ``Path("")`` is the current folder, so ``-o "$OUT"`` with
    ``$OUT`` unset would otherwise write the command's files into whatever folder the shell is in."""
    output = getattr(args, "output", None)
    if output is not None and not str(output).strip():
        raise UserError(f"-o/--output is empty ({output!r}); name the output explicitly (an unset variable?)")


def main(
    argv: list[str] | None = None,
    *,
    prog: str = "sb3-cmzdril",
    commands: Sequence[AddCommand] | None = None,
    description: str = DESCRIPTION,
) -> int:
    """Run one command; every user error ends here as one line on stderr and exit code 2, an
    interruption as one line and exit code 130 (Ctrl-C, SIGINT) or 143 (SIGTERM). ``prog`` and
    ``commands`` serve another console script (the lab's ``cmzdril-lab``)."""
    from sb3_cmzdril._mujoco_log import route_mujoco_warnings
    from sb3_cmzdril.console import show_library_messages
    from sb3_cmzdril.extras import require_extra

    parser = build_parser(prog, commands, description)
    args = parser.parse_args(argv)
    route_mujoco_warnings()
    again = "resume" if args.command in RESUMABLE else "start again"
    try:
        # Progress displays and tables are rich's: the command line is the experiments extra's tooling.
        require_extra("rich", "experiments", "the sb3-cmzdril command line")
        _check_output_option(args)
        # The CLI shows the library's notes, and those of the package that gave the command (the lab).
        command_package = (args.func.__module__ or "").split(".")[0]
        with _signal_handlers(), show_library_messages(also=(command_package,)):
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{prog} {args.command}: interrupted; rerun the same command to {again}", file=sys.stderr)
        return 130
    except Terminated:
        print(f"{prog} {args.command}: terminated (SIGTERM); rerun the same command to {again}", file=sys.stderr)
        return 128 + signal.SIGTERM
    except USER_ERRORS as e:
        print(f"{prog} {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2


__all__ = ["MOVED_TO_LAB", "PLUGIN_GROUP", "RESUMABLE", "USER_ERRORS", "Terminated", "build_parser", "main"]
