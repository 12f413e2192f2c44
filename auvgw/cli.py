"""``auvgw`` command line, the entry point only: one subcommand per module in
:data:`~auvgw.commands.COMMANDS`, dispatched here; the helpers commands share are in
:mod:`auvgw.commands.common`.

Each command module defines ``register(subparsers)`` which adds its parser and sets
``func=run`` where ``run(args) -> int`` is the exit code. Exit code 2 means bad input
(unreadable file, wrong format, invalid configuration), with a one-line message on stderr: a
command raises :class:`~auvgw.ground.errors.UserError` (or lets a ``ConfigError`` / ``DataError``
through).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import NoReturn

from auvgw.commands import COMMANDS
from auvgw.ground import procs
from auvgw.ground.errors import ConfigError, DataError, UserError

__all__ = ["COMMANDS", "build_parser", "main"]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``auvgw`` parser. With ``command`` (a key of :data:`COMMANDS`) only that command's
    module is imported and registered; without, every command is (all options of all commands)."""
    parser = argparse.ArgumentParser(
        prog="auvgw", description="AUV sensor gateway: codecs, emulators, Zenoh bus, SLAM, Rerun"
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, _) in COMMANDS.items():
        if command is None or name == command:
            importlib.import_module(module).register(sub)
    return parser


def _listing_parser() -> argparse.ArgumentParser:
    """``auvgw --help`` (and unknown commands): the command list, importing no command module."""
    parser = argparse.ArgumentParser(
        prog="auvgw", description="AUV sensor gateway: codecs, emulators, Zenoh bus, SLAM, Rerun"
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_, text) in COMMANDS.items():
        sub.add_parser(name, help=text, add_help=False)
    return parser


def _command_in(argv: list[str]) -> str | None:
    """The command named in ``argv`` (the first word that is not an option), if it is one."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in COMMANDS else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = _command_in(argv)
    parser = build_parser(command) if command else _listing_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (UserError, ConfigError, DataError) as exc:  # bad input: one line, never a traceback
        print(f"auvgw {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def entry() -> NoReturn:
    """The ``auvgw`` console script and ``python -m auvgw``: :func:`main`, then exit with its
    code. After a command that asked for it (:func:`auvgw.ground.procs.end_without_finalising`:
    the gateway, once
    stopped), the process ends with ``os._exit``: a Zenoh thread calling into the finalising
    interpreter aborted ``auvgw run`` after its clean stop (glibc "FATAL: exception not
    rethrown", SIGABRT) in about 1 run in 10 with the ROS 2 bridge on."""
    rc = main()
    if procs.ending_without_finalising():
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    sys.exit(rc)


if __name__ == "__main__":
    entry()
