"""What every command shares: option helpers, loading a gateway configuration, stopping on signals.

Imported by the command modules (never by :mod:`auvgw.cli`, which only dispatches), so no command
imports another to reach a helper.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, TextIO, TypeAlias

from auvgw.commands import COMMANDS
from auvgw.ground.errors import ConfigError, UserError

if TYPE_CHECKING:
    from auvgw.config.gateway import GatewayConfig
    from auvgw.signing import SignatureCheck

log = logging.getLogger(__name__)

#: what a command's ``register`` is given: the CLI's sub-command parsers
SubParsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"

__all__ = [
    "SubParsers", "UserError", "add_command", "add_decode_config", "add_duration",
    "add_signature_arguments", "check_signature_args", "decode_config", "handle_stop_signals",
    "load_or_fail", "open_output", "study_algorithms",
]  # fmt: skip


def add_command(sub: SubParsers, name: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of command ``name`` (its help line from :data:`COMMANDS`, ``doc``, the
    module docstring, as its description, line breaks kept)."""
    return sub.add_parser(
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


def study_algorithms(args: argparse.Namespace, known: Collection[str]) -> tuple[str, ...]:
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


def load_or_fail(path: Path) -> GatewayConfig:
    """The validated gateway configuration at ``path``, or a :class:`UserError` listing every
    problem."""
    from auvgw.config.gateway import load_gateway_config

    try:
        return load_gateway_config(path)
    except ConfigError as exc:
        raise UserError(str(exc)) from exc


@contextmanager
def handle_stop_signals(stop: threading.Event) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM set ``stop`` (main thread only; restored after)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("%s received: stopping", signal.Signals(signum).name)
        stop.set()

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def add_signature_arguments(p: argparse.ArgumentParser) -> None:
    """``--key PUB`` (trusted signers) and ``--require-signature``: a recording's detached
    signature (``F.mcap.sig``, :mod:`auvgw.signing`) checked when present."""
    p.add_argument(
        "--key",
        action="append",
        type=Path,
        default=[],
        metavar="PUB",
        help="a trusted signer's public key (NAME.sign.pub, repeatable): a signature by any "
        "other key is INVALID (default: a signature is checked against its own key)",
    )
    p.add_argument(
        "--require-signature",
        action="store_true",
        help="a recording without its .sig is an error",
    )


def check_signature_args(path: Path, args: argparse.Namespace) -> SignatureCheck:
    """:func:`auvgw.signing.check_signature` of ``path`` with the options of
    :func:`add_signature_arguments`; an unsigned file with ``--require-signature`` comes back
    ``invalid``."""
    from auvgw.signing import SignatureCheck, check_signature, load_public_key

    trusted = tuple(load_public_key(k) for k in args.key)
    check = check_signature(path, trusted)
    if check.status == "unsigned" and args.require_signature:
        return SignatureCheck(path, "invalid", f"{check.line}; --require-signature")
    return check
