"""``auvgw pilot``: fly a mission file with the reference autopilot, on the bus.

    auvgw pilot --mission config/missions/lawnmower.toml [--vehicle auv1] [--connect ...]
    auvgw pilot --mission FILE --check

Subscribes to ``auv/<V>/nav/odometry`` (the fusion stage's), steps the autopilot every
``--period`` s of odometry time and publishes ``auv/<V>/pilot/command`` (rpm, rudder, stern
plane) and ``auv/<V>/pilot/state`` (mode, leg, cross-track error, set-points, abort reason);
counters on ``auv/<V>/status/pilot``. Prints ``pilot running: ...`` once subscribed. Aborts
(surface: shaft off, fins bow-up) on navigation older than ``--nav-timeout`` s or a depth beyond
``--max-depth`` m. Each command also goes to the vehicle's actuators as an ``ActuatorCommand`` on
``auv/<V>/cmd/<--actuators>`` (the gateway checks it and sends it on CAN; ``--no-commands``: only
the set-points are published), and the actuators' feedback (``auv/<V>/sensor/<--actuators>/
actuatorstate``: jammed fins, a silent thruster, the fault word) is read; ``--feedback-timeout``
S > 0 turns on the aborts that need it (silent actuators, a fin off its command, a shaft off its
speed). See docs/pilot.md.

``--check``: validate the mission file only; prints one line per problem (file, leg, field) on
stderr and exits 2, or ``FILE: ok (...)`` and exits 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

from auvgw.commands.common import SubParsers, add_command, add_duration
from auvgw.ground.errors import UserError


def register(sub: SubParsers) -> None:
    from auvgw.bus import add_bus_arguments

    p = add_command(sub, "pilot", __doc__)
    p.add_argument("--mission", type=Path, required=True, metavar="TOML",
                   help="mission file (config/missions/*.toml)")
    p.add_argument("--check", action="store_true",
                   help="validate the mission file and exit (one line per problem)")
    p.add_argument("--vehicle", default="auv1", help="vehicle name (default auv1)")
    p.add_argument("--period", type=float, default=0.05, metavar="S",
                   help="control period, s of odometry time (default 0.05)")
    p.add_argument("--nav-timeout", type=float, default=0.5, metavar="S",
                   help="abort when the odometry is older than S seconds (default 0.5)")
    p.add_argument("--max-depth", type=float, default=60.0, metavar="M",
                   help="abort deeper than M metres (default 60)")
    p.add_argument("--feedback-timeout", type=float, default=0.0, metavar="S",
                   help="abort when the actuators are silent S seconds; turns on the fin and "
                   "thruster checks (default 0: off)")  # fmt: skip
    p.add_argument("--fin-rate", type=float, default=30.0, metavar="DEG_S",
                   help="the fin servos' slew rate the jam check expects (default 30 deg/s, "
                   "the emulated controller's)")  # fmt: skip
    p.add_argument("--fin-tau", type=float, default=0.1, metavar="S",
                   help="the fin servos' time constant the jam check expects (default 0.1 s, "
                   "the emulated controller's)")  # fmt: skip
    p.add_argument("--actuators", default="actuators", metavar="DEVICE",
                   help="the actuators' device name in the gateway (default actuators)")
    p.add_argument("--no-commands", action="store_true",
                   help="publish the set-points only, send no command to the actuators")
    p.add_argument("--lockstep", type=Path, default=None, metavar="CLOCK",
                   help="against a lock-step sim (auvgw sim --lockstep): its clock file "
                   "(OUT/clock); the navigation timeout counts its vehicle time and every "
                   "odometry sample is answered on auv/<V>/pilot/ack")  # fmt: skip
    add_duration(p)
    add_bus_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from auvgw.commands.run import serve_stage
    from auvgw.control.mission import MissionFileError, load_mission
    from auvgw.stages.pilot import BusCommands, PilotStage, PilotStageConfig

    try:
        mission = load_mission(args.mission)
    except MissionFileError as exc:
        for e in exc.errors:
            print(f"auvgw pilot: error: {e}", file=sys.stderr)
        return 2
    if args.check:
        print(f"{args.mission}: ok ({mission.n_legs} legs, {mission.length:.0f} m, "
              f"{len(mission.waypoints)} waypoints)")  # fmt: skip
        return 0
    for opt, value in (("--period", args.period), ("--nav-timeout", args.nav_timeout),
                       ("--max-depth", args.max_depth)):  # fmt: skip
        if not value > 0:
            raise UserError(f"{opt} must be > 0, got {value}")
    if not 0 < args.fin_rate <= 1000:
        raise UserError(f"--fin-rate must be in (0, 1000] deg/s, got {args.fin_rate}")
    if not 0 <= args.fin_tau <= 10:
        raise UserError(f"--fin-tau must be in [0, 10] s, got {args.fin_tau}")
    if not args.feedback_timeout >= 0:
        raise UserError(f"--feedback-timeout must be >= 0, got {args.feedback_timeout}")
    cfg = PilotStageConfig(vehicle=args.vehicle, control_period_s=args.period,
                           nav_timeout_s=args.nav_timeout, max_depth=args.max_depth,
                           feedback_timeout_s=args.feedback_timeout,
                           actuators_device=args.actuators,
                           fin_rate_dps=args.fin_rate, fin_tau_s=args.fin_tau,
                           lockstep_clock=None if args.lockstep is None
                           else str(args.lockstep))  # fmt: skip

    def make(session: zenoh.Session) -> PilotStage:
        sink = None if args.no_commands else BusCommands(session, args.vehicle, args.actuators)
        return PilotStage(mission, cfg, session, sink=sink)

    stage = serve_stage(
        args,
        make,
        lambda st: f"pilot running: vehicle {st.keys.vehicle}, mission {mission.name} "
        f"({mission.n_legs} legs), set-points on {st.key('command')}"
        + ("" if args.no_commands else f", commands on {st.keys.cmd(args.actuators)}"),
        lambda st: st.input_keys(),
    )
    print(f"pilot counters: {json.dumps(stage.counters())}", file=sys.stderr)
    return 0
