"""``auvgw sim --scenario FILE``: the emulated vehicle on virtual ports.

Builds the scenario's world and ground truth, starts every enabled device emulator on its own
virtual port (serial ptys paced at their baud, emulated USB-CAN adapters speaking SLCAN, UDP on
loopback), prints the ports, writes a gateway configuration that points at them (stable
symlinks in ``OUT/ports/``, so a gateway finds a replugged device again) and runs until Ctrl-C
/ SIGTERM or ``--duration`` vehicle seconds (default: the end of the route). Then it prints
each device's counters and exits 0.

Files in ``OUT`` (``--out``, default a new temporary folder): ``gateway.toml`` (run it with ``auvgw
run --config OUT/gateway.toml``; at ``--speed k`` > 0 its ``[clock]`` section has ``time_scale = k``
and ``epoch_ns``, the host time of vehicle time 0, so the gateway stamps vehicle-paced receive
times: vehicle seconds = ``(t_recv_ns - epoch_ns) / 1e9``; vehicle time 0 is ``--start-delay`` host
seconds after the file is written, or earlier with ``--start-when FILE``: as soon as the parts
that should see the whole run say they are ready by writing FILE; the stamps then follow the
clock file and ``epoch_ns`` stays their origin), ``truth.jsonl`` (ground truth at
``--truth-rate`` Hz, one JSON object per line: t, x, y, z, heading, roll, pitch, ... in SI / NED /
radians) and the fault control
file ``faults.json``: write ``{"ins": {"corrupt_p": 0.1}, "dvl": {"unplug": [[30, 40]]}}`` (the
scenario's FaultSettings fields; windows in vehicle seconds) and each device's faults become the
scenario's plus those; delete the file to restore them.

Pacing (``--pace``, ``--speed`` > 0): ``elastic`` (the default) holds vehicle time within
``--elastic-lag`` vehicle s of what the devices have actually dispatched, as HIL benches do
when the host cannot keep up: on a loaded host wall time stretches instead of frames leaving
late (with ``--processes`` every device process reports its dispatch, and reads its time from
the clock file). The clock is shared through ``OUT/clock`` (:mod:`auvgw.ground.simclock`), and
gateway.toml's ``[clock] sim_clock`` makes the gateway stamp that vehicle time. ``free``: the
clock runs at ``--speed`` whatever happens; a tick dispatched late still carries its exact
vehicle time but leaves the host late. The end of the run prints the vehicle and wall seconds,
the effective speed, the time held and the late ticks.

``--lockstep`` (closed loop, one process, ``--speed`` > 0): the sim is paced by the controller
under test, as HIL benches' synchronous modes are. It joins the bus (``--connect``) and takes
the controller's answers on ``auv/<V>/pilot/ack`` (JSON ``{"t": s}``: the newest odometry time
the controller has acted on, on the gateway's stamp clock; ``auvgw pilot --lockstep`` sends
them); vehicle time never runs more than ``--lockstep-step`` past the last answer, so a stalled
host stretches wall time, not vehicle time. A hold longer than ``--lockstep-timeout`` host s
moves on one step and is counted (printed at the end). The clock is shared through
``OUT/clock`` (:mod:`auvgw.ground.simclock`): gateway.toml's ``[clock] sim_clock`` makes the
gateway stamp vehicle time, and ``auvgw pilot --lockstep OUT/clock`` times its navigation
timeout in vehicle time.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from auvgw.commands.common import SubParsers, UserError, add_command, handle_stop_signals
from auvgw.drivers import registry

if TYPE_CHECKING:
    import zenoh

    from auvgw.sim_devices.runner import DeviceProcesses, Runner

log = logging.getLogger(__name__)

#: the elastic clock's lag, vehicle s: 15 INS periods, 1.5 host ms x speed 10
ELASTIC_LAG_S = 0.15


def register(sub: SubParsers) -> None:
    p = add_command(sub, "sim", __doc__)
    p.add_argument("--scenario", "-s", required=True, type=Path, help="scenario file (JSON)")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="vehicle seconds per real second (default 1; 0: as fast as possible)",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after S vehicle seconds (default: the end of the route)",
    )
    p.add_argument(
        "--out",
        "-o",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder for ports, gateway.toml, truth log (default: a new temp folder)",
    )
    p.add_argument(
        "--devices",
        default=None,
        metavar="LIST",
        help="comma-separated subset of " + ",".join(em.key for em in registry.emulators()),
    )
    p.add_argument("--vehicle", default="auv1", help="vehicle name in the gateway configuration")
    p.add_argument(
        "--truth-rate",
        type=float,
        default=10.0,
        metavar="HZ",
        help="ground-truth log rate, vehicle Hz (default 10)",
    )
    p.add_argument("--no-truth-log", action="store_true", help="do not write truth.jsonl")
    p.add_argument(
        "--check",
        action="store_true",
        help="validate the scenario and build its world (terrain, features, beacons), then "
        "exit: 0 and one line if usable, else the problems and exit code 2",
    )
    p.add_argument(
        "--start-delay",
        type=float,
        default=0.5,
        metavar="S",
        help="host seconds from writing gateway.toml to vehicle time 0 (default 0.5; "
        "time to start a gateway and stages that should see the whole run)",
    )
    p.add_argument(
        "--start-when",
        type=Path,
        default=None,
        metavar="FILE",
        help="vehicle time 0 as soon as FILE appears (removed when gateway.toml is written; "
        "written whole, it holds the host time.monotonic() instant of vehicle time 0, empty: "
        "at once), at the "
        "latest --start-delay s after gateway.toml: the processes that should see the whole run "
        "say when they are ready instead of a fixed wait (elastic pacing or --lockstep: their "
        "stamps follow the clock file, not epoch_ns)",
    )
    p.add_argument(
        "--hold",
        action="store_true",
        help="at the end of the run keep the ports open (the devices silent) until SIGINT/"
        "SIGTERM, and write DIR/finished: a gateway is stopped before its devices vanish",
    )
    p.add_argument(
        "--processes",
        action="store_true",
        help="run each device in its own process on one shared clock (uses every "
        "core; one Python process runs on about one)",
    )
    p.add_argument("--pace", choices=("elastic", "free"), default="elastic",
                   help="elastic (default): vehicle time waits for the devices' dispatch on a "
                   "loaded host; free: it runs at --speed whatever happens")
    p.add_argument("--elastic-lag", type=float, default=ELASTIC_LAG_S, metavar="S",
                   help="vehicle s the elastic clock may run past the earliest tick not "
                   f"dispatched yet (default {ELASTIC_LAG_S:g})")
    g = p.add_argument_group("lock-step (closed loop: the sim paced by the controller)")
    g.add_argument("--lockstep", action="store_true",
                   help="hold vehicle time within --lockstep-step of the controller's last "
                   "answer (auv/<V>/pilot/ack); needs --speed > 0, one process")
    g.add_argument("--lockstep-step", type=float, default=0.15, metavar="S",
                   help="vehicle s the clock may run past the last answer (default 0.15)")
    g.add_argument("--lockstep-timeout", type=float, default=5.0, metavar="S",
                   help="host s a hold may last before the clock moves on one step anyway "
                   "(counted; default 5)")
    g.add_argument("--lockstep-first", type=float, default=1.0, metavar="S",
                   help="vehicle s the clock runs before the first answer (default 1)")
    from auvgw.bus import add_bus_arguments

    add_bus_arguments(p, "Zenoh bus (--lockstep only: where the controller's answers come from)")
    p.set_defaults(func=run)  # fmt: skip


def _print_ports(runner: Runner | DeviceProcesses) -> None:
    print(f"  {'device':18s} {'format':9s} {'transport':9s} {'open this':44s} now", flush=True)
    for ep in runner.endpoints():
        print(f"  {ep.name:18s} {ep.format:9s} {ep.kind:9s} {ep.target:44s} {ep.path or '-'}")
    for name, why in runner.unavailable.items():
        print(f"  {name:18s} not emulated: {why}")


def _print_stats(runner: Runner | DeviceProcesses) -> None:
    st = runner.stats()
    print(f"stopped at vehicle time {st['vehicle_time']:.2f} s "
          f"(clock max lag {st['max_lag_s']:.3f} s, late ticks {st['late_ticks']})")  # fmt: skip
    for d in st["devices"].values():
        for ch, cs in d["channels"].items():
            f, p = cs["faults"], cs["port"]
            faults = {
                k: f[k]
                for k in ("dropped", "stalled", "unplugged", "garbage_events", "corrupted",
                          "truncated")
                if f[k]
            }  # fmt: skip
            print(f"  {ch:18s} samples {d['ticks']:7d} sent {f['frames_sent']:7d} "
                  f"bytes {p['bytes_written']:9d} dropped bytes {p['bytes_dropped']:7d}"
                  + (f" faults {faults}" if faults else "")
                  + (f" noise bursts {d['noise_bursts']}" if d["noise_bursts"] else "")
                  + (f" ERRORS {d['errors']}" if d["errors"] else ""))  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from auvgw.config.scenario import ScenarioError, load_scenario
    from auvgw.sim_devices.runner import DeviceProcesses, Runner, RunOptions

    if args.speed < 0:
        raise UserError(f"--speed must be >= 0, got {args.speed}")
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 vehicle seconds, got {args.duration}")
    if not 0 <= args.start_delay <= 3600:
        raise UserError(f"--start-delay must be 0 to 3600 s, got {args.start_delay}")
    if args.start_when is not None and (args.speed == 0 or (args.pace == "free"
                                                            and not args.lockstep)):
        raise UserError("--start-when needs a real-time clock (--speed > 0) paced elastic or "
                        "--lockstep: with --pace free the gateway maps host time through "
                        "epoch_ns, fixed by --start-delay")
    if not args.truth_rate > 0:
        raise UserError(f"--truth-rate must be > 0, got {args.truth_rate}")
    try:
        scn = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise UserError(str(exc).replace("\n", "; ")) from exc
    if args.check:
        from auvgw.sim_devices.world import World

        try:
            World.from_scenario(scn)
        except ScenarioError as exc:
            raise UserError(f"{args.scenario}: {exc}".replace("\n", "; ")) from exc
        print(f"{args.scenario}: ok (scenario {scn.name!r})")
        return 0
    devices = None
    if args.devices:
        devices = [d.strip() for d in args.devices.split(",") if d.strip()]
    out = (
        args.out.resolve() if args.out is not None else Path(tempfile.mkdtemp(prefix="auvgw-sim-"))
    )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create: {exc.strerror}") from exc
    truth_log = None if args.no_truth_log else out / "truth.jsonl"
    control = out / "faults.json"
    if args.processes and args.speed == 0:
        raise UserError("--processes needs a real-time clock: --speed > 0")
    if not 0 < args.elastic_lag <= 60:
        raise UserError(f"--elastic-lag must be > 0 and <= 60 vehicle s, got {args.elastic_lag}")
    # lock-step holds on the controller instead; as fast as possible never runs late
    elastic = args.pace == "elastic" and args.speed > 0 and not args.lockstep
    if args.lockstep:
        if args.speed == 0 or args.processes:
            raise UserError("--lockstep needs one process (no --processes) and --speed > 0")
        for opt in ("step", "timeout", "first"):
            v = getattr(args, f"lockstep_{opt}")
            if not 0 < v <= 3600:
                raise UserError(f"--lockstep-{opt} must be > 0 and <= 3600 s, got {v}")
    try:
        options = RunOptions(
            out_dir=out, speed=args.speed, devices=devices, truth_log=truth_log,
            truth_rate_hz=args.truth_rate, elastic_lag=args.elastic_lag if elastic else 0.0,
        )  # fmt: skip
        if args.processes:
            runner: Runner | DeviceProcesses = DeviceProcesses(args.scenario, options,
                                                               control=control)  # fmt: skip
        else:
            runner = Runner(scn, options)
    except (ScenarioError, ValueError, OSError) as exc:
        raise UserError(f"{args.scenario}: {exc}") from exc
    stop = threading.Event()
    signals = contextlib.ExitStack()  # SIGINT / SIGTERM set stop until the end
    signals.enter_context(handle_stop_signals(stop))
    try:
        until = args.duration if args.duration is not None else runner.route_duration
        pace = "as fast as possible" if args.speed == 0 else f"{args.speed:g}x real time"
        if elastic:
            pace += f", elastic (lag {args.elastic_lag:g} vehicle s)"
        if args.processes:
            pace += ", one process per device"
        print(f"auvgw sim: scenario '{scn.name}' (route {runner.route_duration:.1f} s), {pace}, "
              f"until vehicle time {until:.1f} s", flush=True)  # fmt: skip
        _print_ports(runner)
        # vehicle time 0 at the latest: the gateway configuration's epoch (the stamps' origin;
        # --start-when may bring vehicle time 0 forward, the stamps then follow the clock file)
        start_at = time.monotonic() + args.start_delay if args.speed > 0 else None
        if args.start_when is not None:
            args.start_when.unlink(missing_ok=True)  # a stale one from an earlier run
        lockstep = None
        if args.lockstep and isinstance(runner, Runner):
            assert start_at is not None
            from auvgw.bus import bus_from_args, open_cli_session

            try:
                bus = bus_from_args(args)
            except ValueError as exc:
                raise UserError(str(exc)) from exc
            lockstep = signals.enter_context(Lockstep(
                runner, args.vehicle, args.lockstep_step, args.lockstep_timeout,
                args.lockstep_first, out / "clock", start_at, open_cli_session(bus),
                own_session=True))  # fmt: skip
        try:
            cfg = runner.write_gateway_config(
                out / "gateway.toml", vehicle=args.vehicle, start_at=start_at,
                **({"sim_clock": out / "clock"} if lockstep is not None else {}),
            )
        except ValueError as exc:
            raise UserError(f"gateway configuration: {exc}") from exc
        if lockstep is not None:
            lockstep.epoch_ns = _load_epoch_ns(cfg)
            lockstep.begin()
            print(f"lock-step: answers on {lockstep.key}, step {args.lockstep_step:g} s, "
                  f"hold timeout {args.lockstep_timeout:g} host s; clock file {out / 'clock'}",
                  flush=True)  # fmt: skip
        runner.watch_control(control)
        print(f"gateway config: {cfg}")
        if truth_log is not None:
            print(f"truth log: {truth_log}")
        print(f"fault control: {control} (JSON {{device: {{fault settings}}}}, applied on change)")
        if args.start_when is not None and start_at is not None:
            latest = start_at
            start_at = _wait_start(args.start_when, latest, stop)  # (the lock-step clock
            # file gets the new anchor of vehicle time 0 when the runner's clock starts)
            print(f"vehicle time 0: {args.start_when.name}'s, {latest - start_at:.2f} s before "
                  "--start-delay's" if start_at < latest else "vehicle time 0: --start-delay's "
                  f"({args.start_when.name} did not come before it)", flush=True)  # fmt: skip
        print("running; Ctrl-C to stop", flush=True)
        runner.start(duration=until, start_at=start_at)
        while not stop.is_set() and runner.running:
            stop.wait(0.2)
        wall_s = time.monotonic() - (start_at if start_at is not None else time.monotonic())
        if args.hold and not stop.is_set():
            (out / "finished").write_text(f"{runner.hold():.3f}\n")
            print("finished; ports held open until SIGINT/SIGTERM", flush=True)
            stop.wait()
        runner.stop()
        if args.speed > 0 and runner.stats()["vehicle_time"] > 0:  # (not stopped before 0)
            print(_pace_line(runner.stats(), wall_s, args.pace if elastic else "free"),
                  flush=True)  # fmt: skip
        _print_stats(runner)
        if lockstep is not None:
            print(f"lock-step: {lockstep.summary()}", flush=True)
    finally:
        runner.close()
        signals.close()
    return 0


def _pace_line(st: dict[str, object], wall_s: float, pace: str) -> str:
    """One line: vehicle and wall seconds of the run, effective speed, time held, late ticks."""
    vehicle = float(st["vehicle_time"])  # type: ignore[arg-type]
    speed = vehicle / wall_s if wall_s > 0 else 0.0
    line = (f"pacing {pace}: {vehicle:.1f} vehicle s in {wall_s:.1f} wall s, effective speed "
            f"{speed:.2f}x")  # fmt: skip
    if pace == "elastic":
        line += (f", held {float(st['held_s']):.1f} wall s ({st['holds']} holds, "  # type: ignore[arg-type]
                 f"{st['hold_timeouts']} timeouts)")  # fmt: skip
    return line + f", late ticks {st['late_ticks']} (max lag {float(st['max_lag_s']):.3f} s)"  # type: ignore[arg-type]


def _wait_start(path: Path, latest: float, stop: threading.Event) -> float:
    """The host ``time.monotonic()`` instant of vehicle time 0: the one written in ``path`` once
    it appears (empty or in the past: now), never later than ``latest`` (nor past a stop)."""
    while not path.exists():
        if time.monotonic() >= latest or stop.wait(0.02):
            return latest
    text = path.read_text().strip()
    try:
        wanted = float(text) if text else time.monotonic()
    except ValueError as exc:
        raise UserError(f"--start-when {path}: not a host time.monotonic() instant: "
                        f"{text[:40]!r}") from exc
    return min(latest, max(wanted, time.monotonic()))


def _load_epoch_ns(path: Path) -> int:
    """``[clock] epoch_ns`` of the gateway configuration just written."""
    from auvgw.config.gateway import load_gateway_config

    epoch = load_gateway_config(path).clock.epoch_ns
    assert epoch is not None
    return epoch


class Lockstep:
    """The sim's side of lock-step: the controller's answers (``auv/<vehicle>/pilot/ack`` on
    ``session``) move ``runner``'s clock hold limit (``step``, ``timeout``, ``first``: see
    :meth:`~auvgw.sim_devices.clock.SimClock.lockstep`); every new anchor goes to the clock file
    ``clock_file`` (:mod:`auvgw.ground.simclock`). An answer that carries the ``seq`` of the
    controller's newest command counts once the emulated actuators have applied it
    (:class:`~auvgw.sim_devices.actuators.CommandGate`; ``gate_commands`` False: at once).
    A closed-loop vehicle runs captive (straight, :meth:`~auvgw.sim_devices.closedloop.
    ClosedLoopTruth.hold_captive`) until the first answer counts.
    Set :attr:`epoch_ns` (the gateway's ``[clock] epoch_ns``), then :meth:`begin` before the
    runner starts at the host instant ``start_at``.
    Closing it withdraws the subscriber (and closes ``session`` if ``own_session``)."""

    def __init__(self, runner: Runner, vehicle: str, step: float, timeout: float, first: float,
                 clock_file: Path, start_at: float, session: zenoh.Session,
                 own_session: bool = False, gate_commands: bool = True) -> None:  # fmt: skip
        from auvgw.bus import Keys
        from auvgw.ground.simclock import ClockFileWriter
        from auvgw.sim_devices.actuators import ActuatorEmulator, CommandGate
        from auvgw.sim_devices.closedloop import ClosedLoopTruth
        from auvgw.stages.pilot import ACK

        self.clock = runner.clock
        #: a closed-loop truth held captive until the first answer counts (None: scripted)
        self.truth = runner.truth if isinstance(runner.truth, ClosedLoopTruth) else None
        #: answers that carry a command's ``seq`` count once the emulated actuators have it
        self.gate: CommandGate | None = None
        acts = [em for em in runner.emulators.values() if isinstance(em, ActuatorEmulator)]
        if gate_commands and len(acts) == 1:
            self.gate = CommandGate(self._answered)
            acts[0].on_applied = self.gate.applied
        self.key = f"{Keys(vehicle).base}/pilot/{ACK}"
        self.epoch_ns = 0
        self.bad = 0  # answers that could not be read
        self._params = (step, timeout, first)
        self._writer = ClockFileWriter(clock_file)
        self._start_at = start_at
        self._session = session
        self._own = own_session
        self._sub: object | None = None

    def __enter__(self) -> Lockstep:
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._sub is not None:
            self._sub.undeclare()  # type: ignore[attr-defined]
        if self._own:
            self._session.close()
        self._writer.close()

    def begin(self) -> None:
        """Hold the clock at ``first`` and listen for answers (before the start)."""

        def on_anchor(t: float, host: float, speed: float, limit: float) -> None:
            self._writer.publish(t, host, speed, limit, self.epoch_ns)

        self.clock.lockstep(*self._params, on_anchor)
        if self.truth is not None:  # on its launch rail until the controller answers
            self.truth.hold_captive()
        # the anchor of vehicle time 0 before the clock starts: readers map the host clock
        self._writer.publish(0.0, self._start_at, self.clock.speed, self.clock.limit,
                             self.epoch_ns)  # fmt: skip
        self._sub = self._session.declare_subscriber(self.key, self._on_ack)

    def _on_ack(self, sample: object) -> None:
        import json

        try:
            body = json.loads(sample.payload.to_bytes())  # type: ignore[attr-defined]
            t = float(body["t"])
            seq = body.get("seq")
            if seq is not None and (type(seq) is not int or seq < 0):
                raise ValueError(f"seq {seq!r}")
        except (ValueError, KeyError, TypeError, AttributeError):
            self.bad += 1
            return
        t -= self.epoch_ns / 1e9
        if self.gate is not None:
            self.gate.answered(t, seq)
        else:
            self._answered(t)

    def _answered(self, t: float) -> None:
        """An answer counts: the clock runs on, and the first one frees a captive vehicle."""
        if self.truth is not None and self.truth.released_at is None:
            self.truth.release()
        self.clock.answered(t)

    def summary(self) -> str:
        """One line: answers, holds, held host time, timeouts (and the vehicle times of the
        first few)."""
        c = self.clock
        at = ", ".join(f"{t:.2f}" for t in c.timeout_times[:5])
        more = ", ..." if c.hold_timeouts > 5 else ""
        return (f"{c.answers} answers, {c.holds} holds ({c.held_s:.1f} host s held), "
                f"{c.hold_timeouts} hold timeouts" + (f" (at vehicle t {at}{more} s)" if at else "")
                + f", {self.bad} unreadable answers"
                + (f", captive until vehicle t {self.truth.released_at:.2f} s"
                   if self.truth is not None and self.truth.released_at is not None else "")
                + (f", {self.gate.waited} waited for their command" if self.gate else ", ungated")
                + f"; limit at the end {c.limit:.2f} s")  # fmt: skip
