"""Command line: ``sb3-cmzdril <command> --help``.

Each command's parser is built by an ``_add_<command>`` function and runs a ``_run_<command>``
function that only translates arguments into calls of the library; the work lives in the modules.
"""
from __future__ import annotations

import argparse
import sys
from typing import List, Optional


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-cmzdril",
        description="CMZ-DRIL imitation learning for stable-baselines3: experts, demos, training, benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_COMMANDS):
        add(sub)
    return parser


_COMMANDS: list = []


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, KeyError) as e:
        print(f"sb3-cmzdril {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
