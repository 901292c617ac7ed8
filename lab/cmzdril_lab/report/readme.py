"""Patching the README's results block: the README's numbers are written by the report, not by hand.

The block sits between :data:`README_BEGIN` and :data:`README_END`; :func:`update_readme` replaces
what is between them (atomically) and leaves the rest of the README as it is.
"""
from __future__ import annotations

import os
from pathlib import Path

from sb3_cmzdril.errors import MissingFileError, UserError
from sb3_cmzdril.io import PathLike, atomic_write_text

#: Markers of the README block that ``write_report(readme=...)`` replaces.
README_BEGIN = "<!-- results table: written by `sb3-cmzdril report --readme`, do not edit by hand -->"
README_END = "<!-- end of results table -->"


def readme_block(path: PathLike) -> tuple[str, int, int]:
    """(README text, end of the begin marker, start of the end marker); errors name what is missing.

    Called before a report writes anything, so a README without the block fails early.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"README not found: {path}")
    text = path.read_text(encoding="utf-8")
    start, end = text.find(README_BEGIN), text.find(README_END)
    if start < 0 or end < start:
        raise UserError(f"{path} has no results block: add the lines {README_BEGIN!r} and {README_END!r} "
                         "where it goes")
    return text, start + len(README_BEGIN), end


def update_readme(path: PathLike, block: str) -> None:
    """Replace the text between :data:`README_BEGIN` and :data:`README_END` in ``path`` (atomically)."""
    text, start, end = readme_block(path)
    atomic_write_text(path, text[:start] + "\n" + block.strip() + "\n" + text[end:])


def link(target: PathLike, start: PathLike) -> str:
    """``target`` relative to the folder ``start`` with forward slashes, for a markdown link."""
    return Path(os.path.relpath(Path(target).resolve(), Path(start).resolve())).as_posix()


def short_command(command: str | None) -> str:
    """The command with its program's folder dropped (a README should not show this machine's paths)."""
    if not command:
        return "sb3-cmzdril report"
    program, _, rest = command.partition(" ")
    return f"{Path(program).name} {rest}".strip()


__all__ = ["README_BEGIN", "README_END", "readme_block", "update_readme", "link", "short_command"]
