"""``auvgw slam run --pipeline magnetic``: the online AMB-SLAM stage, live or over a recording.

Live::

    auvgw slam run --pipeline magnetic --scenario config/scenarios/beacons_amb.json \\
        --connect tcp/127.0.0.1:7447 [--vehicle auv1] [--duration S]

subscribes to ``auv/<V>/nav/odometry``, ``auv/<V>/sensor/*/magnetometer`` and
``auv/<V>/sensor/*/acousticreply``; publishes ``auv/<V>/slam/magnetic/{pose,landmarks,
observations}`` and counters on ``auv/<V>/status/slam-magnetic``. The scenario gives the beacon
channels and the acoustic beacon's position (:func:`~auvgw.stages.magnetic.config_from_scenario`).
``--mag-device NAME`` takes one magnetometer device (default: the first seen); ``--mag-rate HZ``
times its samples by their counter at that rate from ``--clock-epoch-ns`` (the gateway's
``[clock] epoch_ns``, vehicle time 0: the beacons' phase reference) instead of by the receive
stamps (``auvgw demo --scenario beacons`` passes all three).

Offline (``--recording run.mcap``): the recorded frames decoded as the gateway did, the fusion
stage's odometry and the magnetometer / acoustic messages fed to the same stage; prints the
counters and, with ``truth/pose`` in the recording, AMB-SLAM and dead-reckoning RMSE / distance.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from auvgw.commands.demo_parts import (
    DemoContext,
    DemoPlan,
    DemoProcess,
    InProcessContext,
    InProcessPlan,
)
from auvgw.commands.demo_report import SlamReport, print_gain, print_vs_truth
from auvgw.ground.errors import UserError

if TYPE_CHECKING:
    from auvgw.config.scenario import Scenario
    from auvgw.stages.magnetic import MagneticStageConfig

#: the stage's name in the demo's summary
DISPLAY_NAME = "AMB-SLAM"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The magnetic pipeline's own options (on ``auvgw slam run``'s parser)."""
    g = p.add_argument_group("magnetic pipeline (--pipeline magnetic)")
    g.add_argument("--scenario", type=Path, default=None, metavar="FILE.json",
                   help="beacons scenario giving the channels and the acoustic beacon")
    g.add_argument("--mag-device", default=None, metavar="NAME",
                   help="gateway device of the magnetometer (default: the first seen)")
    g.add_argument("--mag-rate", type=float, default=None, metavar="HZ",
                   help="time the magnetometer samples by their counter at HZ from "
                   "--clock-epoch-ns (default: by the receive stamps)")
    g.add_argument("--clock-epoch-ns", type=int, default=0, metavar="NS",
                   help="vehicle time 0 on the stamp clock, ns (the gateway's [clock] epoch_ns; "
                   "the beacons' phase reference; default 0)")  # fmt: skip


def demo_accepts(scn: Scenario) -> bool:
    """A scenario ``auvgw demo`` runs this pipeline on: magnetic beacons and an emulated
    magnetometer."""
    return bool(scn.magnetic_beacons) and scn.devices.magnetometer.enabled


def mag_rate_hz(scn: Scenario) -> float:
    """The scenario's magnetometer rate (Hz; its emulator's nominal one unless set)."""
    from auvgw.sim_devices.magnetometer import MagnetometerEmulator

    return float(scn.devices.magnetometer.rate_hz or MagnetometerEmulator.nominal_rate_hz)


def demo_argv(scenario: Path, scn: Scenario, vehicle: str, epoch_ns: int,
              bus: list[str]) -> list[str]:  # fmt: skip
    """``auvgw slam run --pipeline magnetic`` as the demo's SLAM process: the scenario's channels
    and acoustic beacon, the serial magnetometer timed by its counter from the gateway's epoch
    (``epoch_ns``: vehicle time 0, the beacons' phase reference); ``bus``: its bus options."""
    return ["slam", "run", "--pipeline", "magnetic", "--vehicle", vehicle,
            "--scenario", str(scenario), "--mag-device", "magnetometer",
            "--mag-rate", str(mag_rate_hz(scn)), "--clock-epoch-ns", str(epoch_ns),
            *bus]  # fmt: skip


def demo_plan(ctx: DemoContext) -> DemoPlan:
    """``demo --processes`` on a beacons scenario: this stage, started once the sim's
    ``[clock]`` epoch (the beacons' phase reference) is known."""

    def argv(epoch_ns: int | None) -> list[str]:
        assert epoch_ns is not None  # after_clock
        return demo_argv(ctx.scenario, ctx.scn, ctx.vehicle, epoch_ns, ctx.bus_args())

    component = "slam-magnetic"
    return DemoPlan((DemoProcess("slam", argv, after_clock=True),),
                    frozenset({"magnetometer", "acoustic", component}), component,
                    DISPLAY_NAME)  # fmt: skip


def demo_inprocess(ctx: InProcessContext) -> InProcessPlan:
    """The in-process demo on a beacons scenario: this stage on the scenario's channels and
    acoustic beacon, the serial magnetometer timed by its counter from the gateway's epoch (the
    beacons' phase reference)."""
    from auvgw.stages.magnetic import MagneticStage, config_from_scenario

    cfg = config_from_scenario(
        ctx.scenario, vehicle=ctx.gw_cfg.vehicle, mag_device="magnetometer",
        mag_rate_hz=mag_rate_hz(ctx.scn), clock_epoch_s=ctx.epoch_ns / 1e9,
    )  # fmt: skip
    return InProcessPlan(MagneticStage(cfg, session=ctx.session, on_publish=ctx.on_publish),
                         DISPLAY_NAME)  # fmt: skip


def demo_report(r: SlamReport) -> dict[str, Any]:
    """The demo summary's lines of this stage: its counters and its error against the truth
    beside dead reckoning's (nothing more for ``summary.json``)."""
    st = r.counters["stage"]
    print(f"magnetic stage: {st['mag']} magnetometer samples, {st['acoustic']} acoustic fixes, "
          f"{st['observations']} beacon observations, {r.counters['landmarks']} beacons mapped, "
          f"{st['bad_payloads']} bad payloads")  # fmt: skip
    print_vs_truth(r.name, r.err, "not enough poses or truth to compare")
    print_gain(r.name, r.err, r.dead_reckoning)
    return {}


def stage_config(args: argparse.Namespace, vehicle: str) -> MagneticStageConfig:
    """The stage's settings from ``--scenario`` (required) and the magnetic options."""
    from pydantic import ValidationError

    from auvgw.stages.magnetic import config_from_scenario

    if args.scenario is None:
        raise UserError("--pipeline magnetic needs --scenario FILE.json (beacon channels, anchor)")
    if not args.scenario.is_file():
        raise UserError(f"{args.scenario}: no such scenario file")
    try:
        return config_from_scenario(
            args.scenario, vehicle=vehicle, mag_device=getattr(args, "mag_device", None),
            mag_rate_hz=getattr(args, "mag_rate", None),
            clock_epoch_s=getattr(args, "clock_epoch_ns", 0) / 1e9,
        )  # fmt: skip
    except (ValidationError, ValueError) as exc:
        raise UserError(f"{args.scenario}: {exc}") from None


def live(args: argparse.Namespace) -> int:
    """Serve the stage on the bus (``slam run`` without ``--recording``)."""
    from auvgw.commands.slam_common import serve_slam
    from auvgw.stages.magnetic import MagneticStage

    cfg = stage_config(args, args.vehicle)
    return serve_slam(args, lambda session: MagneticStage(cfg, session), "AMB-SLAM")


def offline(args: argparse.Namespace) -> int:
    """The magnetic stage (AMB-SLAM) over ``--recording``: its counters, the beacons mapped
    and its error against the recorded truth beside dead reckoning's."""
    from auvgw.commands.slam_common import Paths, check_recording, replay_recording, report_truth
    from auvgw.stages.magnetic import MagneticStage

    cfg = stage_config(args, "auv1")
    check_recording(args)
    stage = MagneticStage(cfg)
    paths = Paths()
    fusion = replay_recording(args, stage, paths, flush=False)
    c = stage.counters()
    print(f"{args.recording}: {json.dumps(c['stage'])}, {c['landmarks']} beacons mapped")
    report_truth(fusion, paths, stage.track, "AMB-SLAM")
    return 0
