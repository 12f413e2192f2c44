"""``auvgw swath``: the GeoSwath swath stage as its own process.

    auvgw swath --connect tcp/127.0.0.1:7447 [--vehicle auv1] [--device DEV]
        [--output-device NAME] [--set KEY=VALUE ...] [--duration S]

subscribes to the gateway's decoded GeoSwath pings (``auv/<V>/sensor/<DEV or *>/geoswathping``),
processes them into swaths (raw samples to soundings, filters, median filters, binning:
:mod:`auvgw.slam.bathymetric.swath_processing`) and publishes each swath as an XYZ 88 envelope
on ``auv/<V>/sensor/<DEV>_swath/xyz88`` (``--output-device``), where the bathymetric SLAM stage
takes it (``auvgw slam run --pipeline bathymetric --multibeam <DEV>_swath``); counters on
``auv/<V>/status/swath``. ``--set`` takes any processing value (``frequency_hz`` (the sonar's:
the broadcast pings do not carry it), ``n_bins``, ``swath_rate_hz``, ``sound_speed``,
``lever_arm_m``, ``min_amplitude``, ...), JSON values, repeated. Prints ``swath running`` on
stdout once its subscriptions are declared.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from auvgw.stages.swath import SwathStageConfig

from auvgw.bus import add_bus_arguments
from auvgw.commands.common import SubParsers, UserError, add_command, add_duration

__all__ = ["register", "run"]


def register(sub: SubParsers) -> None:
    p = add_command(sub, "swath", __doc__)
    p.add_argument("--vehicle", default="auv1", help="vehicle name (default auv1)")
    p.add_argument("--device", default=None, help="the GeoSwath gateway device (default: any)")
    p.add_argument("--output-device", default=None, help="publish as (default: DEVICE_swath)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a swath processing value (JSON), repeated")  # fmt: skip
    add_duration(p)
    add_bus_arguments(p)
    p.set_defaults(func=run)


def stage_config(args: argparse.Namespace) -> SwathStageConfig:
    """The stage's settings from the options; a bad one is a :class:`UserError`."""
    from pydantic import ValidationError

    from auvgw.commands.slam_bathy import parse_sets
    from auvgw.stages.swath import SwathStageConfig

    try:
        cfg = SwathStageConfig(vehicle=args.vehicle, device=args.device,
                               output_device=args.output_device,
                               processing=parse_sets(args.set))  # fmt: skip
        cfg.swath_processing()
    except (ValidationError, ValueError) as exc:
        raise UserError(f"--set: {exc}") from None
    return cfg


def run(args: argparse.Namespace) -> int:
    from auvgw.commands.run import serve_stage
    from auvgw.stages.swath import SwathStage

    cfg = stage_config(args)
    stage = serve_stage(
        args,
        lambda session: SwathStage(cfg, session),
        lambda st: f"swath running: vehicle {st.keys.vehicle}, swaths on {st.key('xyz88')}",
        lambda st: st.input_keys(),
    )
    print(f"swath counters: {json.dumps(stage.counters())}", file=sys.stderr)
    return 0
