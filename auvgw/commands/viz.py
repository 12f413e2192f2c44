"""``auvgw viz``: log a vehicle's bus to Rerun, into a file or a running viewer.

    auvgw viz --rrd run.rrd --bus-connect tcp/192.168.1.10:7447        # record
    auvgw viz --connect rerun+http://127.0.0.1:9876/proxy --config vehicle.toml   # live
    auvgw viz --save-blueprint auvgw.rbl                                # the layout alone
    auvgw viz --synthetic 200 --rrd demo.rrd                            # a demo file, no bus

Subscribes to ``auv/<vehicle>/{sensor,nav,slam,truth,status}/**`` and logs until SIGINT or
SIGTERM (or ``--duration`` seconds), then writes the ``.rrd`` footer and prints the counters on
stderr. Open a recording with ``rerun FILE.rrd``; see docs/viz.md for what each entity shows.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path
from typing import Any

from auvgw.commands.common import SubParsers, UserError, add_command, handle_stop_signals
from auvgw.config.bus import BusConfig
from auvgw.viz.options import VizOptions

_URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


def add_output_arguments(p: argparse.ArgumentParser) -> None:
    """``--rrd FILE`` and ``--connect URL`` (shared with commands that run the stage)."""
    p.add_argument("--rrd", type=Path, default=None, metavar="FILE", help="write a .rrd file")
    p.add_argument(
        "--connect",
        default=None,
        metavar="URL",
        help="stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument(
        "--map-frame",
        choices=("ned", "xy"),
        default="ned",
        help="positions: ned (x north, y east; default) or xy (x right, y up)",
    )
    p.add_argument(
        "--flush-period",
        type=float,
        default=VizOptions.flush_period_s,
        metavar="S",
        help="send batches every S s of device time: the live lag (default %(default)s)",
    )
    p.add_argument(
        "--fan-jpeg",
        type=int,
        default=None,
        metavar="Q",
        help="store the sonar fan as JPEG of quality Q (1-100; default lossless)",
    )


def register(sub: SubParsers) -> None:
    p = add_command(sub, "viz", __doc__)
    add_output_arguments(p)
    p.add_argument("--vehicle", default=None, help="vehicle name (default: from --config, auv1)")
    p.add_argument(
        "--config", type=Path, default=None, help="gateway TOML: vehicle name and [bus] endpoints"
    )
    p.add_argument(
        "--bus-config",
        type=Path,
        default=None,
        metavar="TOML",
        help="take the [bus] table (endpoints, tls, auth) of this file instead of --config's, e.g. "
        "config/security/viz-bus.toml; --bus-* options override it (docs/security.md)",
    )
    p.add_argument(
        "--bus-mode", choices=("peer", "client"), default=None, help="Zenoh mode (default peer)"
    )
    p.add_argument(
        "--bus-connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    p.add_argument(
        "--bus-listen", action="append", default=None, metavar="ENDPOINT", help="listen endpoint"
    )
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--synthetic",
        type=float,
        default=None,
        metavar="S",
        help="log S seconds of a synthetic run (every sensor, truth, SLAM) instead of the bus",
    )
    p.add_argument(
        "--save-blueprint",
        type=Path,
        default=None,
        metavar="FILE",
        help="write the default layout as a .rbl file and exit",
    )
    p.set_defaults(func=run)


def options_from_args(args: argparse.Namespace) -> VizOptions:
    """Logger options of ``--map-frame``, ``--flush-period`` and ``--fan-jpeg``; validates
    the outputs."""
    if args.rrd is not None:
        parent = args.rrd.resolve().parent
        if not parent.is_dir():
            raise UserError(f"{args.rrd}: directory {parent} does not exist")
        if args.rrd.is_dir():
            raise UserError(f"{args.rrd}: is a directory, not a .rrd file")
    if args.connect is not None and not args.connect.startswith(_URL_SCHEMES):
        raise UserError(
            f"--connect {args.connect}: a viewer URL starts with {', '.join(_URL_SCHEMES)} "
            "(e.g. rerun+http://127.0.0.1:9876/proxy)"
        )
    if args.fan_jpeg is not None and not 1 <= args.fan_jpeg <= 100:
        raise UserError(f"--fan-jpeg {args.fan_jpeg}: quality must be 1..100")
    if not 0.05 <= args.flush_period <= 60:
        raise UserError(f"--flush-period {args.flush_period}: give 0.05 .. 60 s")
    return VizOptions(
        map_frame=args.map_frame,
        fan_jpeg_quality=args.fan_jpeg,
        flush_period_s=args.flush_period,
    )


def _bus(args: argparse.Namespace) -> tuple[str, BusConfig]:
    vehicle, bus = "auv1", BusConfig()
    if args.config is not None:
        from auvgw.config.gateway import ConfigError, load_gateway_config

        try:
            cfg = load_gateway_config(args.config)
        except ConfigError as exc:
            raise UserError(str(exc)) from exc
        vehicle = cfg.vehicle
        # a second process on the gateway's host connects to the gateway's listen endpoints
        bus = BusConfig(mode="peer", connect=[*cfg.bus.connect, *cfg.bus.listen])
    if args.bus_config is not None:  # its [bus] table, --bus-* options over it

        from auvgw.bus import bus_from_args

        given = argparse.Namespace(
            bus_config=args.bus_config,
            mode=args.bus_mode,
            connect=args.bus_connect or [],
            listen=args.bus_listen or [],
        )
        try:
            return args.vehicle or vehicle, bus_from_args(given)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    update: dict[str, Any] = {}
    if args.bus_mode is not None:
        update["mode"] = args.bus_mode
    if args.bus_connect is not None:
        update["connect"] = args.bus_connect
    if args.bus_listen is not None:
        update["listen"] = args.bus_listen
    if update:
        bus = BusConfig(**{**bus.model_dump(), **update})
    return args.vehicle or vehicle, bus.as_spoke()


def _summary(args: argparse.Namespace, **counts: object) -> int:
    """Print the run's summary (``counts`` and the ``.rrd`` written) as one JSON line on
    stderr; the exit status, 0."""
    summary = {**counts, "rrd": None if args.rrd is None else str(args.rrd)}
    print(json.dumps(summary), file=sys.stderr)
    return 0


def _synthetic(args: argparse.Namespace, options: VizOptions) -> int:
    from dataclasses import replace

    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.synthetic import synthetic_calls

    if not 0 < args.synthetic <= 3600:
        raise UserError(f"--synthetic {args.synthetic}: give 0 .. 3600 s")
    calls = synthetic_calls(args.synthetic)
    logger = RerunLogger(
        rrd=args.rrd, connect=args.connect, options=replace(options, queue_size=len(calls) + 16)
    )
    try:
        for name, a, kw in calls:
            getattr(logger, name)(*a, **kw)
    finally:
        logger.close()
    st = logger.stats()
    return _summary(
        args, synthetic_s=args.synthetic, logged=st.processed, dropped=st.dropped, errors=st.errors
    )


def run(args: argparse.Namespace) -> int:
    if args.save_blueprint is not None:
        from auvgw.viz.blueprint import save_blueprint

        try:
            out = save_blueprint(args.save_blueprint)
        except OSError as exc:
            raise UserError(f"{args.save_blueprint}: {exc}") from exc
        print(f"auvgw viz: layout written to {out}", file=sys.stderr)
        return 0
    if args.rrd is None and args.connect is None:
        raise UserError("nothing to do: give --rrd FILE and/or --connect URL")
    options = options_from_args(args)
    if args.synthetic is not None:
        return _synthetic(args, options)
    vehicle, bus = _bus(args)
    if not bus.connect and not bus.listen and not bus.multicast_scouting:
        print(
            "auvgw viz: no bus endpoint (--bus-connect / --config): only peers that connect "
            "to this process will be heard",
            file=sys.stderr,
        )

    from auvgw.bus import open_cli_session
    from auvgw.viz.stage import open_viz

    session = open_cli_session(bus, "bus: cannot open the Zenoh session", "")
    stop = threading.Event()
    try:
        runner = open_viz(session, vehicle, rrd=args.rrd, connect=args.connect, options=options)
        try:
            with handle_stop_signals(stop):
                stop.wait(args.duration)
        finally:
            runner.close()
    finally:
        session.close()
    s, ls = runner.stage.stats, runner.logger.stats()
    return _summary(
        args, vehicle=vehicle, received=s.received, logged=s.logged, ignored=s.ignored,
        unknown=dict(s.unknown), errors=s.errors, stage_dropped=s.queue_dropped,
        logger_dropped=ls.dropped,
    )  # fmt: skip
