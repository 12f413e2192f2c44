"""``auvgw`` command line: one subcommand per module in :data:`COMMANDS`.

Each command module defines ``register(subparsers)`` which adds its parser and sets
``func=run`` where ``run(args) -> int`` is the exit code. Exit code 2 means bad input
(unreadable file, wrong format, invalid configuration), with a one-line message on stderr: a
command raises :class:`~auvgw.errors.UserError` (or lets a ``ConfigError`` / ``DataError``
through).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from auvgw.errors import ConfigError, DataError, UserError

if TYPE_CHECKING:
    from auvgw.config.gateway import GatewayConfig

#: command name -> (module, one-line help), in the order ``auvgw --help`` lists them. Only the
#: module of the command being run is imported, so ``auvgw --help`` imports none of them (no
#: Zenoh, numpy or scipy at start-up).
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": (
        "auvgw.commands.demo",
        "run the emulated vehicle, gateway, fusion, SLAM and Rerun recording (main job)",
    ),
    "decode": ("auvgw.commands.decode", "decode a capture file to JSON lines"),
    "router": (
        "auvgw.commands.router",
        "run a Zenoh router (for multi-process / multi-host buses)",
    ),
    "run": (
        "auvgw.commands.run",
        "run the gateway daemon (devices -> Zenoh) from a TOML configuration",
    ),
    "record": (
        "auvgw.commands.record",
        "record a vehicle's raw bus traffic (all devices, receive times) to an MCAP file",
    ),
    "replay": ("auvgw.commands.replay", "republish an MCAP recording (raw and decoded) as if live"),
    "export": (
        "auvgw.commands.export",
        "convert a recording of the earlier layout to the ROS 2 profile (--ros2)",
    ),
    "viz": ("auvgw.commands.viz", "log the bus to Rerun (a .rrd file or a running viewer)"),
    "sim": (
        "auvgw.commands.sim",
        "run the emulated vehicle (world + device emulators on virtual ports)",
    ),
    "fusion": (
        "auvgw.commands.fusion",
        "INS + DVL dead reckoning: odometry on the bus, or over a recording",
    ),
    "slam": ("auvgw.commands.slam", "SLAM tools: evaluation, and the SLAM stage (slam run)"),
    "slam-run": ("auvgw.commands.slam_run", "run the SLAM stage (same as 'slam run')"),
}


__all__ = [
    "COMMANDS", "UserError", "add_command", "add_decode_config", "add_duration", "build_parser",
    "decode_config", "main", "open_output", "study_algorithms",
]  # fmt: skip


def add_command(sub: Any, name: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of command ``name`` (its help line from :data:`COMMANDS`, ``doc``, the
    module docstring, as its description, line breaks kept)."""
    return sub.add_parser(  # type: ignore[no-any-return]
        name, help=COMMANDS[name][1], description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip


def add_duration(p: argparse.ArgumentParser, when: str = "") -> None:
    """``--duration S``: a long-running command stops after S seconds (None: at SIGINT or
    SIGTERM); ``when`` starts the help (``"live: "``: it applies only when live)."""
    p.add_argument(
        "--duration", type=float, default=None, metavar="S",
        help=f"{when}stop after S seconds (default: until SIGINT/SIGTERM)",
    )  # fmt: skip


def add_decode_config(p: argparse.ArgumentParser) -> None:
    """``--config TOML``: the gateway configuration a recording is decoded with instead of its
    recorded one (``replay``, ``export``); read with :func:`decode_config`."""
    p.add_argument(
        "--config", type=Path, default=None, metavar="TOML",
        help="gateway configuration to decode with, instead of the recorded one",
    )  # fmt: skip


def decode_config(args: argparse.Namespace) -> GatewayConfig | None:
    """The validated ``--config`` of :func:`add_decode_config` (a :class:`UserError` listing
    every problem), or None: decode with the recorded configuration."""
    from auvgw.commands.run import load_or_fail

    return load_or_fail(args.config) if args.config is not None else None


def open_output(path: Path | None) -> TextIO | None:
    """``path`` opened for writing text (``None``: none); a :class:`UserError` naming the file if
    it cannot be. The caller closes it."""
    if path is None:
        return None
    try:
        return open(path, "w")
    except OSError as exc:
        raise UserError(f"{path}: cannot write: {exc.strerror}") from exc


def study_algorithms(args: argparse.Namespace, known: Any) -> tuple[str, ...]:
    """The names in ``--algorithms`` (comma separated), each one of ``known``; a
    :class:`UserError` for an unknown name or a ``--runs``, ``--jobs`` or ``--particles`` below 1
    (``slam eval``, both pipelines)."""
    algorithms = tuple(a.strip() for a in args.algorithms.split(",") if a.strip())
    unknown = [a for a in algorithms if a not in known]
    if not algorithms or unknown:
        raise UserError(f"unknown algorithm(s) {unknown}; choose from {', '.join(known)}")
    if args.runs < 1 or args.jobs < 1 or args.particles < 1:
        raise UserError("--runs, --jobs and --particles must be at least 1")
    return algorithms


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


if __name__ == "__main__":
    sys.exit(main())
