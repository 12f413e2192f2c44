"""``auvgw router``: a Zenoh router in a Python process (no separate zenohd needed).

Peers and clients on the vehicle network connect to it; it routes between processes and hosts.
Prints ``auvgw router <zid> listening on ...`` once up; exits 0 on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

from pydantic import ValidationError

from auvgw.bus import load_bus_table, open_cli_session
from auvgw.commands.common import SubParsers, handle_stop_signals
from auvgw.config.bus import DEFAULT_ENDPOINT, BusConfig, default_endpoint
from auvgw.ground.errors import UserError, format_validation_error


def register(sub: SubParsers) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (for multi-process / multi-host buses)")
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        help=f"endpoint to listen on (repeatable), default {DEFAULT_ENDPOINT} (loopback only: "
        "give the vehicle network's address, e.g. tcp/0.0.0.0:7447, to serve other hosts)",
    )
    p.add_argument("--connect", action="append", default=[], help="other routers to join")
    p.add_argument(
        "--bus-config",
        type=Path,
        default=None,
        metavar="TOML",
        help="take tls, auth and access_control (and endpoints unless given) from this file's "
        "[bus] table (docs/security.md)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        base = {} if args.bus_config is None else load_bus_table(args.bus_config)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    base["mode"] = "router"
    base["listen"] = args.listen or base.get("listen") or [default_endpoint()]
    base["connect"] = args.connect or base.get("connect", [])
    try:
        cfg = BusConfig(**base)
        if args.bus_config is not None:
            cfg = cfg.rebased(args.bus_config.resolve().parent)
    except ValidationError as exc:
        raise UserError(format_validation_error(exc, "bus").replace("\n", "; ")) from exc
    stop = threading.Event()
    session = open_cli_session(cfg, "cannot start the router", "; is the port free?")
    try:
        with handle_stop_signals(stop):
            print(f"auvgw router {session.zid()} listening on {', '.join(cfg.listen)}", flush=True)
            stop.wait()
    finally:
        session.close()
    return 0
