"""``auvgw`` command line: one subcommand per module in :data:`COMMANDS`.

Each command module defines ``register(subparsers)`` which adds its parser and sets
``func=run`` where ``run(args) -> int`` is the exit code. Exit code 2 means bad input
(unreadable file, wrong format, invalid configuration), with a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path
from typing import TextIO

#: command modules, in the order ``auvgw --help`` lists them
COMMANDS: list[str] = [
    "auvgw.commands.demo",
    "auvgw.commands.decode",
    "auvgw.commands.router",
    "auvgw.commands.run",
    "auvgw.commands.record",
    "auvgw.commands.replay",
    "auvgw.commands.export",
    "auvgw.commands.viz",
    "auvgw.commands.sim",
    "auvgw.commands.fusion",
    "auvgw.commands.slam",
    "auvgw.commands.slam_run",
]


class UserError(Exception):
    """A problem the user can fix (bad file, bad config); printed as one line, exit code 2."""


def open_output(path: Path | None) -> TextIO | None:
    """``path`` opened for writing text (``None``: none); a :class:`UserError` naming the file if
    it cannot be. The caller closes it."""
    if path is None:
        return None
    try:
        return open(path, "w")
    except OSError as exc:
        raise UserError(f"{path}: cannot write: {exc.strerror}") from exc


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="auvgw", description="AUV sensor gateway: codecs, emulators, Zenoh bus, SLAM, Rerun"
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"auvgw {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
