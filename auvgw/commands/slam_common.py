"""What the SLAM stage commands share (``slam run`` for every pipeline): serving a stage on the
bus, replaying a recording through the fusion and a stage, and the error against the truth.

Imported by :mod:`auvgw.commands.slam_run` and by each pipeline's module
(:mod:`~auvgw.commands.bathy_run`, :mod:`~auvgw.commands.magnetic_run`), which import nothing of
each other.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from auvgw.bus import parse_key
from auvgw.ground.errors import UserError

if TYPE_CHECKING:
    import zenoh

    from auvgw.fusion.odometry import Odometry
    from auvgw.stages.base import Stage
    from auvgw.stages.fusion import FusionStage, FusionStageConfig


class Paths:
    """Dead-reckoning and SLAM tracks (s, x, y) and the truth, for the summary."""

    def __init__(self) -> None:
        self.dr: list[tuple[float, float, float]] = []
        self.slam: list[tuple[float, float, float]] = []
        self.truth: list[tuple[float, float, float]] = []


def track_error(
    est: list[tuple[float, float, float]], truth: np.ndarray
) -> dict[str, float] | None:
    """The error of track ``est`` ``(t s, x m, y m)`` against ``truth`` (rows ``t, x, y``,
    interpolated at the track's times) over the part of the track inside the truth's span:
    distance (m), RMSE and final error (m), RMSE / distance x 100; None with fewer than 2 rows."""
    if len(est) < 2 or len(truth) < 2:
        return None
    e = np.asarray(est)
    keep = (e[:, 0] >= truth[0, 0]) & (e[:, 0] <= truth[-1, 0])
    if keep.sum() < 2:
        return None
    e = e[keep]
    err = np.hypot(e[:, 1] - np.interp(e[:, 0], truth[:, 0], truth[:, 1]),
                   e[:, 2] - np.interp(e[:, 0], truth[:, 0], truth[:, 2]))  # fmt: skip
    seg = (truth[:, 0] >= e[0, 0]) & (truth[:, 0] <= e[-1, 0])
    dist = float(np.sum(np.hypot(*np.diff(truth[seg, 1:], axis=0).T)))
    rmse = float(np.sqrt(np.mean(err**2)))
    return {"distance_m": dist, "rmse_m": rmse, "final_m": float(err[-1]),
            "rmse_pct_distance": 100 * rmse / dist if dist > 0 else math.nan}  # fmt: skip


def fusion_settings(args: argparse.Namespace) -> FusionStageConfig:
    from auvgw.stages.fusion import FusionStageConfig, SettingsError, load_stage_config

    cfg = FusionStageConfig()
    if args.fusion_settings is not None:
        try:
            cfg = load_stage_config(args.fusion_settings)
        except SettingsError as exc:
            raise UserError(str(exc)) from None
    named = {k: v for k, v in (("ins_device", args.ins), ("dvl_device", args.dvl)) if v}
    return cfg.model_copy(update=named)


def serve_slam(
    args: argparse.Namespace, make: Callable[[zenoh.Session], Stage], name: str
) -> int:
    """Run the stage ``make(session)`` on the bus until stopped (``slam run``, both pipelines);
    its counters on stderr at the end."""
    from auvgw.commands.run import serve_stage

    stage = serve_stage(
        args,
        make,
        lambda st: f"slam running: vehicle {st.keys.vehicle}, {name} on {st.key('pose')}",
        lambda st: st.input_keys(),
    )
    print(f"slam counters: {json.dumps(stage.counters())}", file=sys.stderr)
    return 0


def check_recording(args: argparse.Namespace) -> None:
    """A :class:`UserError` unless ``--recording`` names a file."""
    if not args.recording.is_file():
        raise UserError(f"{args.recording}: no such file")


def replay_recording(
    args: argparse.Namespace, stage: Stage, paths: Paths, flush: bool = True
) -> FusionStage:
    """The recording through the fusion stage (``--fusion-settings``) and ``stage``, in recording
    order, fed in-process: the fusion's odometry (also into ``paths.dr``) and every decoded
    message go to ``stage``; the simulation truth into ``paths.truth``. Returns the fusion
    stage; ``flush``: flush ``stage`` at the end too."""
    from auvgw.recording import RecordingError, iter_recording
    from auvgw.stages.fusion import FusionStage

    def on_odometry(o: Odometry) -> None:
        paths.dr.append((o.t, o.x, o.y))
        stage.feed_odometry(o)

    fusion = FusionStage(fusion_settings(args), on_odometry=on_odometry)
    try:
        for rec in iter_recording(args.recording, truth=True):
            if "/truth/" in rec.key:
                s = rec.messages[0] if rec.messages else None
                if rec.key.endswith("/pose") and isinstance(s, dict) and "t" in s:
                    paths.truth.append((float(s["t"]), float(s["x"]), float(s["y"])))
                continue
            device = parse_key(rec.key)[2]
            for msg in rec.messages:
                fusion.feed(device, rec.t_recv_ns, msg)
                stage.feed(device, rec.t_recv_ns, msg)
        fusion.flush()
        if flush:
            stage.flush()
    except RecordingError as exc:
        raise UserError(str(exc)) from None
    return fusion


def report_truth(
    fusion: FusionStage, paths: Paths, track: Sequence[tuple[float, ...]], name: str
) -> None:
    """Print dead reckoning's (``paths.dr``) and the stage's error against the recording's truth
    (``paths.truth``, simulation time moved to the odometry clock): RMSE (m) over the distance
    (m) and RMSE / distance x 100 (``track``: the stage's ``(t s, x m, y m, ...)`` poses;
    ``name``: the stage's name in the lines). Prints nothing without truth or INS clock."""
    ins = fusion.adapter.ins_device
    if not paths.truth or ins not in fusion.adapter.clocks:
        return
    tr = np.asarray(sorted(paths.truth))
    tr[:, 0] += fusion.adapter.clocks[ins].offset
    slam = [(t, x, y) for t, x, y, *_ in track]
    for label, est in (("dead reckoning", paths.dr), (name, slam)):
        e = track_error(est, tr)
        if e is not None:
            print(f"  {label} vs truth over {e['distance_m']:.0f} m: RMSE {e['rmse_m']:.2f} m, "
                  f"RMSE/distance x 100 {e['rmse_pct_distance']:.3f} %")  # fmt: skip


