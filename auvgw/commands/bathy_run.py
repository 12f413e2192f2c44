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
import sys
from typing import Any

import numpy as np

from auvgw.cli import UserError


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def stage_config(args: argparse.Namespace, vehicle: str) -> Any:
    """The stage's settings from ``--particles``, ``--seed``, ``--multibeam`` and ``--set``."""
    from pydantic import ValidationError

    from auvgw.slam.bathymetric.config import BathyConfig
    from auvgw.stages.bathymetric import BathymetricStageConfig

    stage: dict[str, Any] = {"vehicle": vehicle, "n_particles": args.particles, "seed": args.seed,
                             "multibeam_device": getattr(args, "multibeam", None)}  # fmt: skip
    filt: dict[str, Any] = {}
    for item in getattr(args, "set", None) or []:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise UserError(f"--set {item!r}: expected KEY=VALUE")
        if key in BathymetricStageConfig.model_fields and key != "filter":
            stage[key] = _value(text)
        elif key in BathyConfig.model_fields:
            filt[key] = _value(text)
        else:
            raise UserError(f"--set {key}: not a bathymetric stage or filter setting")
    try:
        cfg = BathymetricStageConfig(**stage, filter=filt)
        cfg.bathy_config()
    except ValidationError as exc:
        raise UserError("\n".join(f"--set {'.'.join(map(str, e['loc']))}: {e['msg']}"
                                  for e in exc.errors())) from None  # fmt: skip
    return cfg


def run(args: argparse.Namespace) -> int:
    if args.recording is None:
        return _live(args)
    return _offline(args)


def _live(args: argparse.Namespace) -> int:
    from auvgw.commands.run import serve_stage
    from auvgw.stages.bathymetric import BathymetricStage

    cfg = stage_config(args, args.vehicle)
    stage = serve_stage(
        args,
        lambda session: BathymetricStage(cfg, session),
        lambda st: (
            f"slam running: vehicle {cfg.vehicle}, mtm-pf ({cfg.n_particles} particles) "
            f"on {st.key('pose')}"
        ),
        lambda st: st.input_keys(),
    )
    print(f"slam counters: {json.dumps(stage.counters())}", file=sys.stderr)
    return 0


def _offline(args: argparse.Namespace) -> int:
    from auvgw.commands.slam_run import _error, _Paths, check_recording, replay_recording
    from auvgw.stages.bathymetric import BathymetricStage

    cfg = stage_config(args, "auv1")
    check_recording(args)
    out_file = None
    if args.out is not None:
        from auvgw.cli import open_output

        out_file = open_output(args.out)

    def on_publish(key: str, payload: bytes, _t_ns: int) -> None:
        if out_file is not None:
            out_file.write(payload.decode() + "\n")

    stage = BathymetricStage(cfg, on_publish=on_publish)
    paths = _Paths()
    try:
        fusion = replay_recording(args, stage, paths)
    finally:
        if out_file is not None:
            out_file.close()
    truth, dr = paths.truth, paths.dr
    c = stage.counters()
    print(f"{args.recording}: {json.dumps(c['stage'])}, {c['pings']} pings, loop closures "
          f"{c['loops_accepted']} accepted / {c['loops_rejected']} rejected")  # fmt: skip
    ins = fusion.adapter.ins_device
    if truth and ins in fusion.adapter.clocks:
        tr = np.asarray(sorted(truth))
        tr[:, 0] += fusion.adapter.clocks[ins].offset
        slam = [(t, x, y) for t, x, y, _ in stage.track]
        for name, track in (("dead reckoning", dr), ("mtm-pf", slam)):
            e = _error(track, tr)
            if e is not None:
                print(f"  {name} vs truth over {e['distance_m']:.0f} m: RMSE {e['rmse_m']:.2f} m, "
                      f"RMSE/distance x 100 {e['rmse_pct_distance']:.3f} %")  # fmt: skip
    return 0
