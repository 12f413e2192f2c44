"""``auvgw slam run --pipeline bathymetric``: the online mtm-pf stage, live or over a recording.

Live::

    auvgw slam run --pipeline bathymetric --connect tcp/127.0.0.1:7447 [--vehicle auv1]
        [--multibeam DEV] [--particles 100] [--seed 0] [--set KEY=VALUE ...] [--duration S]

subscribes to ``auv/<V>/nav/odometry`` and ``auv/<V>/sensor/<DEV or *>/{xyz88,depth}``;
publishes ``auv/<V>/slam/bathymetric/{pose,map,cloud}`` and counters on
``auv/<V>/status/slam-bathymetric`` (:mod:`auvgw.stages.bathymetric`). ``--set`` takes any
:class:`~auvgw.stages.bathymetric.BathymetricStageConfig` field (``min_ping_spacing_m``,
``map_period_pings``, ``n_beams``...) or any :class:`~auvgw.slam.bathymetric.config.BathyConfig`
value (``radius_m``, ``t_p``, ``lccd``...), repeated.

Offline (``--recording run.mcap``): the recorded frames decoded as the gateway did, the fusion
stage's odometry and the multibeam datagrams fed to the same stage; prints the counters and, with
``truth/pose`` in the recording, mtm-pf and dead-reckoning RMSE / distance x 100.
"""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING, Any

from auvgw.ground.errors import UserError, format_validation_error

if TYPE_CHECKING:
    from auvgw.config.scenario import Scenario
    from auvgw.stages.bathymetric import BathymetricStageConfig

def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bathymetric pipeline's own options (on ``auvgw slam run``'s parser)."""
    g = p.add_argument_group("bathymetric pipeline (--pipeline bathymetric)")
    g.add_argument("--multibeam", default=None,
                   help="gateway device of the multibeam (default: any)")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a stage or filter setting (repeatable), e.g. radius_m=40")  # fmt: skip


def demo_accepts(scn: Scenario) -> bool:
    """A survey (``auvgw demo`` runs this pipeline on it): multibeam on, no point or line
    features and no magnetic beacons to map."""
    return bool(
        (scn.devices.multibeam.enabled or scn.devices.geoswath.enabled)
        and not len(scn.point_features())
        and not scn.features.lines
        and not getattr(scn, "magnetic_beacons", None)
    )


def stage_config(args: argparse.Namespace, vehicle: str) -> BathymetricStageConfig:
    """The stage's settings from ``--particles``, ``--seed``, ``--multibeam`` and ``--set``."""
    from pydantic import ValidationError

    from auvgw.commands.slam_bathy import parse_sets
    from auvgw.slam.bathymetric.config import BathyConfig
    from auvgw.stages.bathymetric import BathymetricStageConfig

    stage: dict[str, Any] = {"vehicle": vehicle, "n_particles": args.particles, "seed": args.seed,
                             "multibeam_device": getattr(args, "multibeam", None)}  # fmt: skip
    filt: dict[str, Any] = {}
    for key, value in parse_sets(getattr(args, "set", None)).items():
        if key in BathymetricStageConfig.model_fields and key != "filter":
            stage[key] = value
        elif key in BathyConfig.model_fields:
            filt[key] = value
        else:
            raise UserError(f"--set {key}: not a bathymetric stage or filter setting")
    try:
        cfg = BathymetricStageConfig(**stage, filter=filt)
        cfg.bathy_config()
    except ValidationError as exc:
        raise UserError(format_validation_error(exc, "--set")) from None
    return cfg


def live(args: argparse.Namespace) -> int:
    """Serve the stage on the bus (``slam run`` without ``--recording``)."""
    from auvgw.commands.slam_common import serve_slam
    from auvgw.stages.bathymetric import BathymetricStage

    cfg = stage_config(args, args.vehicle)
    name = f"mtm-pf ({cfg.n_particles} particles)"
    return serve_slam(args, lambda session: BathymetricStage(cfg, session), name)


def offline(args: argparse.Namespace) -> int:
    """The bathymetric stage (mtm-pf) over ``--recording``: its counters, pings and loop
    closures, and its error against the recorded truth beside dead reckoning's."""
    from auvgw.commands.slam_common import Paths, check_recording, replay_recording, report_truth
    from auvgw.stages.bathymetric import BathymetricStage
    from auvgw.subscribe import slam_output

    cfg = stage_config(args, "auv1")
    check_recording(args)
    out_file = None
    if args.out is not None:
        from auvgw.commands.common import open_output

        out_file = open_output(args.out)

    def on_publish(key: str, payload: bytes, _t_ns: int) -> None:
        if out_file is not None:
            out_file.write(json.dumps(slam_output(payload, key)) + "\n")

    stage = BathymetricStage(cfg, on_publish=on_publish)
    paths = Paths()
    try:
        fusion = replay_recording(args, stage, paths)
    finally:
        if out_file is not None:
            out_file.close()
    c = stage.counters()
    print(f"{args.recording}: {json.dumps(c['stage'])}, {c['pings']} pings, loop closures "
          f"{c['loops_accepted']} accepted / {c['loops_rejected']} rejected")  # fmt: skip
    report_truth(fusion, paths, stage.track, "mtm-pf")
    return 0
