"""``auvgw slam run --pipeline magnetic``: the online AMB-SLAM stage, live or over a recording.

Live::

    auvgw slam run --pipeline magnetic --scenario config/scenarios/beacons_amb.json \\
        --connect tcp/127.0.0.1:7447 [--vehicle auv1] [--duration S]

subscribes to ``auv/<V>/nav/odometry``, ``auv/<V>/sensor/*/magnetometer`` and
``auv/<V>/sensor/*/acousticreply``; publishes ``auv/<V>/slam/magnetic/{pose,landmarks,
observations}`` and counters on ``auv/<V>/status/slam-magnetic``. The scenario gives the beacon
channels and the acoustic beacon's position (:func:`~auvgw.stages.magnetic.config_from_scenario`).

Offline (``--recording run.mcap``): the recorded frames decoded as the gateway did, the fusion
stage's odometry and the magnetometer / acoustic messages fed to the same stage; prints the
counters and, with ``truth/pose`` in the recording, AMB-SLAM and dead-reckoning RMSE / distance.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from auvgw.cli import UserError


def stage_config(args: argparse.Namespace, vehicle: str) -> Any:
    """The stage's settings from ``--scenario`` (required)."""
    from pydantic import ValidationError

    from auvgw.stages.magnetic import config_from_scenario

    if args.scenario is None:
        raise UserError("--pipeline magnetic needs --scenario FILE.json (beacon channels, anchor)")
    if not args.scenario.is_file():
        raise UserError(f"{args.scenario}: no such scenario file")
    try:
        return config_from_scenario(args.scenario, vehicle=vehicle)
    except (ValidationError, ValueError) as exc:
        raise UserError(f"{args.scenario}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    if args.recording is None:
        return _live(args)
    return _offline(args)


def _live(args: argparse.Namespace) -> int:
    from auvgw.commands.slam_run import serve_slam
    from auvgw.stages.magnetic import MagneticStage

    cfg = stage_config(args, args.vehicle)
    return serve_slam(args, lambda session: MagneticStage(cfg, session), "AMB-SLAM")


def _offline(args: argparse.Namespace) -> int:
    from auvgw.commands.slam_run import _error, _Paths, check_recording, replay_recording
    from auvgw.stages.magnetic import MagneticStage

    cfg = stage_config(args, "auv1")
    check_recording(args)
    stage = MagneticStage(cfg)
    paths = _Paths()
    fusion = replay_recording(args, stage, paths, flush=False)
    dr, truth = paths.dr, paths.truth
    c = stage.counters()
    print(f"{args.recording}: {json.dumps(c['stage'])}, {c['landmarks']} beacons mapped")
    ins = fusion.adapter.ins_device
    if truth and ins in fusion.adapter.clocks:
        tr = np.asarray(sorted(truth))
        tr[:, 0] += fusion.adapter.clocks[ins].offset
        slam = [(t, x, y) for t, x, y, _ in stage.track]
        for name, track in (("dead reckoning", dr), ("AMB-SLAM", slam)):
            e = _error(track, tr)
            if e is not None:
                print(f"  {name} vs truth over {e['distance_m']:.0f} m: RMSE {e['rmse_m']:.2f} m, "
                      f"RMSE/distance x 100 {e['rmse_pct_distance']:.3f} %")  # fmt: skip
    return 0
