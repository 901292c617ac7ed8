"""How the command line shows the library's messages.

Library modules print nothing: their notes for a person (resuming, training N -> M steps, saved X,
a summary table) go to loggers under ``sb3_cmzdril``, which stay silent unless the program that
uses the library configures logging. The CLI shows them with :func:`show_library_messages`: each
INFO (or higher) message as a plain line on stdout, without prefixes, as a command's output.
"""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator

#: The logger above every module of the package.
LIBRARY_LOGGER = "sb3_cmzdril"
#: Attribute of a log record holding a rich renderable (a table) of its message: shown with rich
#: in place of the plain-text message (``logger.info(text, extra={RENDERABLE: table})``).
RENDERABLE = "renderable"


class StdoutHandler(logging.Handler):
    """Print each record's message to ``sys.stdout`` as it is at that moment (so pytest's capture
    and redirections see it), or its rich renderable where it has one."""

    def __init__(self, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.setFormatter(logging.Formatter("%(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            renderable = getattr(record, RENDERABLE, None)
            if renderable is not None:
                from rich.console import Console  # only a record made where rich imported carries one

                Console().print(renderable)
            else:
                print(self.format(record), flush=True)
        except Exception:  # logging's convention: a failing handler reports, it does not raise
            self.handleError(record)


@contextlib.contextmanager
def show_library_messages(level: int = logging.INFO, also: Iterable[str] = ()) -> Iterator[StdoutHandler]:
    """Within the block, messages of ``level`` and above of the package's loggers (and of the loggers
    named in ``also``: the packages that add commands) go to stdout.

    The loggers' levels and handlers are restored afterwards, so a program (or test) that calls the
    CLI's ``main`` keeps its own logging configuration.
    """
    loggers = [logging.getLogger(name) for name in dict.fromkeys((LIBRARY_LOGGER, *also))]
    handler = StdoutHandler(level)
    previous = [logger.level for logger in loggers]
    for logger, before in zip(loggers, previous, strict=True):
        if before == logging.NOTSET or before > level:
            logger.setLevel(level)
        logger.addHandler(handler)
    try:
        yield handler
    finally:
        for logger, before in zip(loggers, previous, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(before)
