"""``auvgw run --config FILE``: the gateway daemon.

Loads and validates the TOML configuration (every problem is one line naming the file, the field
and what is expected; exit code 2), opens every device, publishes raw and decoded data on Zenoh
until SIGINT or SIGTERM, then withdraws its liveliness tokens and closes its session (exit code
0). Device connects and disconnects are logged (stderr). docs/gateway.md is the reference.
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import zenoh

from auvgw.commands.common import (
    SubParsers,
    UserError,
    add_command,
    handle_stop_signals,
    load_or_fail,
)
from auvgw.config.gateway import ConfigError, GatewayConfig
from auvgw.gateway import Gateway, GatewayRunning, probe_running_gateway
from auvgw.ground.procs import STOP_GRACE_S, end_without_finalising

log = logging.getLogger(__name__)

__all__ = ["RunSettings", "serve", "serve_stage"]


@dataclass(frozen=True)
class RunSettings:
    """What ``auvgw run`` was asked to do.

    ``viz_rrd`` (a ``.rrd`` file to write) and ``viz_connect`` (a Rerun viewer URL) are carried
    for the Rerun logging stage; None means no such output.
    """

    config: GatewayConfig
    viz_rrd: Path | None = None
    viz_connect: str | None = None
    exit_when_done: bool = False

if TYPE_CHECKING:
    from auvgw.stages.base import Stage

#: the stage a command serves (:func:`serve_stage`)
S = TypeVar("S", bound="Stage")


def register(sub: SubParsers) -> None:
    p = add_command(sub, "run", __doc__)
    p.add_argument("--config", "-c", required=True, type=Path, help="gateway configuration (TOML)")
    p.add_argument(
        "--viz-rrd",
        type=Path,
        default=None,
        metavar="FILE",
        help="Rerun stage: write the session to this .rrd file",
    )
    p.add_argument(
        "--viz-connect",
        default=None,
        metavar="URL",
        help="Rerun stage: stream to a running viewer at this URL",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="validate the configuration (and load its tables, DBCs, password file), then exit: "
        "0 and one line if usable, else one line per problem and exit code 2",
    )
    p.add_argument(
        "--exit-when-done",
        action="store_true",
        help="exit once every device's finite source (file replay) has ended",
    )
    from auvgw.bus import add_bus_arguments

    add_bus_arguments(
        p,
        "Zenoh bus (replace the configuration's [bus] endpoints; with none anywhere the gateway "
        "listens on tcp/127.0.0.1:7447 or $AUVGW_BUS_ENDPOINT: docs/bus.md)",
        mode=False,
    )
    p.set_defaults(func=run)  # fmt: skip


def serve_stage(
    args: argparse.Namespace,
    make: Callable[[zenoh.Session], S],
    banner: Callable[[S], str],
    inputs: Callable[[S], list[str]] | None = None,
) -> S:
    """Run a bus stage from a command line: open the session of the bus options (``--listen``,
    ``--connect``, ...), ``make(session)`` the stage, start it, print ``banner(stage)``, run
    until ``--duration`` seconds or SIGINT/SIGTERM, stop it (flushing; its backlog drained for
    half of :data:`~auvgw.ground.procs.STOP_GRACE_S` at most) and close the session.
    ``inputs(stage)``: its input key expressions, watched for "no publisher"
    (:class:`~auvgw.bus.InputWatch`). Returns the stopped stage (for its counters); bad options
    are a :class:`UserError`."""
    from auvgw.bus import InputWatch, bus_from_args, open_cli_session

    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0, got {args.duration}")
    try:
        bus = bus_from_args(args)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    session = open_cli_session(
        bus, "bus: cannot open the Zenoh session", "; check --listen/--connect"
    )
    stop = threading.Event()
    try:
        stage = make(session)
        with handle_stop_signals(stop):
            stage.start()
            what = f"auvgw {getattr(args, 'command', 'stage')}"
            watch = None if inputs is None else InputWatch(session, inputs(stage), what, bus)
            print(banner(stage), flush=True)
            try:
                stop.wait(args.duration)
            finally:
                if watch is not None:
                    watch.close()
                # at most half a supervisor's grace on a backlog (a stage far behind on a loaded
                # host must not drain past it and be killed, its flush and counters unsent);
                # what is left is dropped, counted in queue_dropped
                stage.stop(flush=True, drain_limit_s=STOP_GRACE_S / 2)
    finally:
        session.close()
    # stopped cleanly, every output sent: the interpreter's finalisation (a garbage collection
    # of the whole heap, then the modules' teardown) only frees what the OS frees anyway, and it
    # was most of a stage's stop: 0.8-3.6 s of an idle fusion's at load 13, 0.02-0.12 s before
    # its counters (py-spy: gc_collect_main after them); a loaded host stretched it past the
    # demo's 15 s grace (fusion killed, exit -9). The caller's last prints are flushed by entry
    end_without_finalising()
    return stage


def check(cfg: GatewayConfig) -> int:
    """``--check``: what :class:`Gateway` loads before it opens anything (decoders with their
    tables and DBCs, the bus password file), without opening a port or a session."""
    from auvgw.decoding import make_decoders

    try:
        make_decoders(cfg)
        if cfg.bus.auth is not None:
            cfg.bus.auth.zenoh()
    except ConfigError as exc:
        source = cfg.source or "<config>"
        raise UserError(f"{source}: {exc}" if source not in str(exc) else str(exc)) from exc
    print(f"{cfg.source}: ok ({len(cfg.devices)} device(s), bus {cfg.bus.describe()})")
    return 0


def serve(settings: RunSettings, stop: threading.Event | None = None) -> int:
    """Run the gateway until ``stop`` is set (or a signal, or the end of finite sources)."""
    cfg = settings.config
    stop = stop or threading.Event()
    try:
        gateway = Gateway(cfg)
    except ConfigError as exc:
        raise UserError(str(exc)) from exc
    except zenoh.ZError as exc:
        running = probe_running_gateway(cfg)  # its listen endpoint taken: by our gateway?
        if running is not None:
            raise running from None
        raise UserError(
            f"{cfg.source}: bus: cannot open the Zenoh session ({exc}); check bus.mode, "
            "bus.listen (port free?) and bus.connect (router reachable?)"
        ) from exc
    try:  # one gateway per vehicle: asked before any port (or viewer, or bridge) is opened
        gateway.check_alone()
    except GatewayRunning:
        gateway.stop()
        raise
    viz = None
    if settings.viz_rrd is not None or settings.viz_connect is not None:
        from auvgw.viz.options import gateway_viz_options
        from auvgw.viz.stage import open_viz

        # sensor data reaches the Rerun stage in-process (no JSON round trip); estimates and
        # status come from the bus
        viz = open_viz(
            gateway.session,
            cfg.vehicle,
            rrd=settings.viz_rrd,
            connect=settings.viz_connect,
            options=gateway_viz_options(cfg),
            sections=("nav", "slam", "truth", "status"),
        )
        gateway.listeners.subscribe(viz.on_message)
    # on the gateway's session, from the bus like any stage (never on the raw frames' path)
    bridges: list[Stage] = []
    if cfg.ros2.enabled or cfg.foxglove.enabled:
        from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig

        ros_cfg = Ros2BridgeConfig(vehicle=cfg.vehicle, **cfg.ros2.model_dump())
        # the sensors come from the gateway's listeners (no envelope round trip), the rest
        # (odometry, SLAM, status) from the bus
        from_bus = ("nav", "slam", "status")
        if cfg.ros2.enabled:
            bridges.append(Ros2Bridge(ros_cfg, gateway.session, sections=from_bus))
        if cfg.foxglove.enabled:
            from auvgw.stages.foxglove import FoxgloveStage

            bridges.append(FoxgloveStage(ros_cfg, gateway.session, host=cfg.foxglove.host,
                                         port=cfg.foxglove.port, sections=from_bus))  # fmt: skip
    with handle_stop_signals(stop):
        try:
            for b in bridges:  # before the devices: no message reaches a stopped worker
                b.start()
                gateway.listeners.subscribe(b.post)
                if (port := getattr(b, "port", None)) is not None:
                    log.info("foxglove: ws://%s:%d", getattr(b, "host", ""), port)
            gateway.start()
            while not stop.wait(0.2):
                if settings.exit_when_done and gateway.finished.is_set():
                    log.info("every device's source has ended")
                    break
        finally:
            for b in bridges:
                b.stop()
            if viz is not None:
                viz.close()
            gateway.stop()
    end_without_finalising()  # stopped cleanly: nothing left for the interpreter's exit
    return 0


def run(args: argparse.Namespace) -> int:
    for name in ("auvgw.gateway", __name__):  # connects/disconnects are always worth a line
        lg = logging.getLogger(name)
        if lg.getEffectiveLevel() > logging.INFO:
            lg.setLevel(logging.INFO)
    from auvgw.bus import bus_from_args

    cfg = load_or_fail(args.config)
    if args.bus_config is not None:  # replaces the configuration's [bus] (its own certificate)
        try:
            cfg = cfg.model_copy(update={"bus": bus_from_args(args, hub=True)})
        except ValueError as exc:
            raise UserError(str(exc)) from None
    if args.check:
        return check(cfg)
    if args.bus_config is None and (args.listen or args.connect):
        try:
            bus = cfg.bus.model_copy(update={"listen": args.listen, "connect": args.connect})
            bus = type(cfg.bus).model_validate(bus.model_dump())
        except ValueError as exc:
            raise UserError(f"--listen/--connect: {exc}") from None
        cfg = cfg.model_copy(update={"bus": bus})
    cfg = cfg.model_copy(update={"bus": cfg.bus.as_hub()})
    log.info("%s: bus: %s", args.config, cfg.bus.describe())
    settings = RunSettings(
        config=cfg,
        viz_rrd=args.viz_rrd,
        viz_connect=args.viz_connect,
        exit_when_done=args.exit_when_done,
    )
    return serve(settings)
