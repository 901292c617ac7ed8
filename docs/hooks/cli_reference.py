"""MkDocs hook: the command-line page, generated from ``sb3_cmzdril.cli.build_parser()``.

In ``docs/cli.md`` the line ``<!-- cli-reference -->`` becomes one section per subcommand with its
``sb3-cmzdril COMMAND --help`` text, so the page cannot drift from the parsers.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

#: This checkout's package, whatever else is installed: the page documents the parsers next to it.
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

MARKER = "<!-- cli-reference -->"
#: Help text wrapped at this width whatever the terminal that builds the site.
WIDTH = "100"


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def render() -> str:
    """Markdown: the top-level help, then each subcommand's, in the order ``--help`` lists them."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH  # argparse's formatter reads the width from the environment
    try:
        from sb3_cmzdril.cli import build_parser

        parser = build_parser()
        parts = ["## sb3-cmzdril", "", "```text", parser.format_help().rstrip(), "```", ""]
        for name, sub in _subcommands(parser).items():
            parts += [f"## {name}", "", "```text", sub.format_help().rstrip(), "```", ""]
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous
    return "\n".join(parts)


def on_page_markdown(markdown: str, page: object, config: object, files: object) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, render())
    return markdown
