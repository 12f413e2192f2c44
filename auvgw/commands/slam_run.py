"""``auvgw slam-run``: the online SLAM stage, live on the bus or over a recording.

Live (the SLAM stage as its own process)::

    auvgw slam-run --vehicle auv1 --connect tcp/127.0.0.1:7447 [--msis msis] [--algorithm A]

subscribes to the fusion stage's odometry (``auv/<V>/nav/odometry``) and the MSIS scan lines
(``auv/<V>/sensor/<msis>/mtheaddata``), publishes ``auv/<V>/slam/<algorithm>/{pose,landmarks}``
and its counters on ``auv/<V>/status/slam-<algorithm>`` until SIGINT/SIGTERM (or ``--duration``
seconds), then flushes (publishes the last estimate) and prints its counters; prints ``slam
running`` on stdout once its subscriptions are declared. Its times are those of the messages
(the gateway's receive stamps, vehicle-paced under a gateway ``[clock]``), never the host clock.

Offline::

    auvgw slam-run --recording run.mcap [--algorithm vb-aufastslam] [--out slam.jsonl]

Decodes the recorded raw frames exactly as the gateway did
(:func:`auvgw.recording.iter_recording`), runs the fusion stage on the INS and DVL messages and
feeds its odometry and the MSIS scan lines to the same :class:`~auvgw.stages.slam.SlamStage` as
online (no bus). ``--out`` writes every published SLAM pose (and the last map) as JSON lines.
Prints the counters, the distance travelled and the SLAM-minus-dead-reckoning difference; with
``truth/pose`` samples in the recording (``auvgw record`` of an emulated run) it also reports
both paths' error against the truth (placed on the INS clock: truth time = INS time).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from auvgw.bus import add_bus_arguments
from auvgw.commands.common import SubParsers, UserError, add_duration, open_output
from auvgw.commands.demo_parts import (
    DemoContext,
    DemoPlan,
    DemoProcess,
    InProcessContext,
    InProcessPlan,
)
from auvgw.commands.demo_report import SlamReport, print_vs_truth
from auvgw.commands.slam_common import (
    Paths,
    check_recording,
    replay_recording,
    serve_slam,
    track_error,
)
from auvgw.ground.errors import format_validation_error
from auvgw.slam import pipelines

if TYPE_CHECKING:
    from auvgw.config.scenario import Scenario
    from auvgw.stages.fusion import FusionStage
    from auvgw.stages.slam import SlamStage, SlamStageConfig

HELP = "run the SLAM stage (fusion odometry + MSIS features), live or over a recording"


def register(sub: SubParsers) -> None:
    """``auvgw slam-run`` (also ``auvgw slam run``, :func:`configure`)."""
    configure(
        sub.add_parser(
            "slam-run",
            help=HELP,
            description=__doc__,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
    )


def configure(p: argparse.ArgumentParser) -> None:
    """The options of the SLAM stage command on parser ``p``: the common ones, then each
    registered pipeline's own (its ``run`` module's ``add_arguments``)."""
    p.add_argument(
        "--recording",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="offline: run over this recording (default: live on the bus)",
    )
    p.add_argument("--vehicle", default="auv1", help="live: vehicle name (default auv1)")
    add_duration(p, "live: ")
    p.add_argument("--pipeline", default=pipelines.default().name,
                   choices=pipelines.names("slam"),
                   help="; ".join(f"{r.name}: {r.summary}" for r in pipelines.of_kind("slam"))
                   + f" (default {pipelines.default().name})")  # fmt: skip
    p.add_argument("--particles", type=int, default=50, help="particles (default 50)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--ins", default=None, help="gateway device of the INS (default: first)")
    p.add_argument("--dvl", default=None, help="gateway device of the DVL (default: first)")
    p.add_argument(
        "--fusion-settings",
        type=Path,
        default=None,
        metavar="FILE",
        help="fusion stage settings (TOML/JSON, as auvgw fusion --settings)",
    )
    p.add_argument("--out", type=Path, default=None, help="offline: JSON lines of the SLAM output")
    for record in pipelines.of_kind("slam"):  # a control pipeline's options are its command's
        record.entry("run").add_arguments(p)
    add_bus_arguments(p)
    p.set_defaults(func=run)  # fmt: skip


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The landmark pipeline's own options (on ``auvgw slam run``'s parser)."""
    from auvgw.slam.landmark.registry import ALGORITHMS

    g = p.add_argument_group("landmark pipeline (--pipeline landmark)")
    g.add_argument("--algorithm", default="vb-aufastslam", choices=sorted(ALGORITHMS))
    g.add_argument("--msis", default=None, help="gateway device of the MSIS (default: first)")
    g.add_argument(
        "--target-radius",
        type=float,
        default=0.6,
        metavar="M",
        help="radius of the point targets, m (default 0.6)",
    )
    g.add_argument("--sound-speed", type=float, default=1500.0, help="m/s (default 1500)")


def demo_config(vehicle: str, msis: str | None, scn: Scenario) -> SlamStageConfig:
    """The demo's stage on the MSIS point features of gateway device ``msis`` (the scenario's
    sound speed and target size)."""
    from auvgw.stages.slam import SlamStageConfig

    return SlamStageConfig(
        vehicle=vehicle,
        msis_device=msis,
        sound_speed_mps=scn.sound_speed_mps,
        target_radius_m=scn.features.point_radius_m,
    )


def demo_plan(ctx: DemoContext) -> DemoPlan:
    """``demo --processes`` on a scenario of point and line features: this stage on the MSIS,
    up before vehicle t = 0."""
    cfg = demo_config(ctx.vehicle, "msis", ctx.scn)
    argv = ["slam-run", "--vehicle", ctx.vehicle, "--msis", "msis",
            "--algorithm", cfg.algorithm, "--particles", str(cfg.n_particles),
            "--seed", str(cfg.seed), "--sound-speed", str(cfg.sound_speed_mps),
            "--target-radius", str(cfg.target_radius_m), *ctx.bus_args()]  # fmt: skip
    component = f"slam-{cfg.pipeline_name}"
    return DemoPlan((DemoProcess("slam", lambda _: argv),), frozenset({"msis", component}),
                    component, cfg.display_name)  # fmt: skip


def demo_inprocess(ctx: InProcessContext) -> InProcessPlan:
    """The in-process demo on a scenario of point and line features: this stage on the
    gateway's first sonar device (the MSIS)."""
    from auvgw.drivers import registry
    from auvgw.stages.slam import SlamStage

    sonar = {dev.format for dev, m in registry.message_types() if "sonar" in m.roles}
    msis = [n for n, d in ctx.gw_cfg.devices.items() if d.format in sonar and d.enabled]
    cfg = demo_config(ctx.gw_cfg.vehicle, msis[0] if msis else None, ctx.scn)
    return InProcessPlan(SlamStage(cfg, session=ctx.session, on_publish=ctx.on_publish),
                         cfg.display_name)  # fmt: skip


#: RMSE / distance x 100 of VB-AUFastSLAM in the sea trial of Mu et al. 2022 (INS + DVL + MSIS)
VB_PAPER_RMSE_PCT = 0.742


def demo_report(r: SlamReport) -> dict[str, Any]:
    """The demo summary's lines of this stage (scan lines, features, updates, landmarks; its
    error against the truth beside the VB paper's sea trial); the paper's figure for
    ``summary.json``."""
    st = r.counters["stage"]
    print(f"slam: {st['pings']} scan lines, {st['point_features']} point and "
          f"{st['line_features']} line features, {st['updates']} updates, "
          f"{r.counters['landmarks']} landmarks")  # fmt: skip
    print_vs_truth(f"SLAM ({r.name})", r.err, "not enough SLAM poses or truth to compare",
                   f" (VB paper sea trial: {VB_PAPER_RMSE_PCT} %)")  # fmt: skip
    return {"paper_rmse_pct_distance": VB_PAPER_RMSE_PCT}


def _stage_config(args: argparse.Namespace, vehicle: str = "auv1") -> SlamStageConfig:
    from pydantic import ValidationError

    from auvgw.stages.slam import SlamStageConfig

    if args.particles < 1:
        raise UserError("--particles must be >= 1")
    try:
        return SlamStageConfig(
            vehicle=vehicle, algorithm=args.algorithm, n_particles=args.particles,
            seed=args.seed, msis_device=args.msis, sound_speed_mps=args.sound_speed,
            target_radius_m=args.target_radius,
        )  # fmt: skip
    except ValidationError as exc:
        opts = {"sound_speed_mps": "--sound-speed", "target_radius_m": "--target-radius",
                "vehicle": "--vehicle", "n_particles": "--particles"}  # fmt: skip
        raise UserError(format_validation_error(exc, rename=lambda f: opts.get(f, f))) from None


def run(args: argparse.Namespace) -> int:
    """The pipeline's ``live`` (on the bus) or, with ``--recording``, ``offline`` entry (its
    registry record's ``run`` module); returns the exit code."""
    module = pipelines.get(args.pipeline).entry("run")
    if args.recording is None and (args.out is not None or args.fusion_settings is not None):
        raise UserError("--out and --fusion-settings are for --recording (offline) runs")
    return int(module.live(args) if args.recording is None else module.offline(args))


def live(args: argparse.Namespace) -> int:
    """Serve the landmark stage on the bus (``slam run`` without ``--recording``)."""
    from auvgw.stages.slam import SlamStage

    cfg = _stage_config(args, args.vehicle)
    return serve_slam(args, lambda session: SlamStage(cfg, session), cfg.display_name)


def offline(args: argparse.Namespace) -> int:
    """The landmark stage over ``--recording`` (see the module docstring)."""
    from auvgw.stages.slam import SlamStage
    from auvgw.subscribe import slam_output

    cfg = _stage_config(args)
    check_recording(args)
    paths = Paths()
    out_file = open_output(args.out)  # closed in finally
    last_map: list[str] = []

    def on_publish(key: str, payload: bytes, _t_ns: int) -> None:
        p = slam_output(payload, key)
        if key.endswith("/pose"):
            paths.slam.append((p["t"], p["x"], p["y"]))
            if out_file is not None:
                out_file.write(json.dumps(p) + "\n")
        else:
            last_map[:] = [json.dumps(p)]

    slam = SlamStage(cfg, on_publish=on_publish)
    try:
        fusion = replay_recording(args, slam, paths)
    finally:
        if out_file is not None:
            if last_map:
                out_file.write(last_map[0] + "\n")
            out_file.close()
    return _report(args.recording, slam, fusion, paths)


def _report(path: Path, slam: SlamStage, fusion: FusionStage, paths: Paths) -> int:
    c = slam.counters()
    st = c["stage"]
    print(f"{path}: {c['algorithm']} over {st['odometry']} odometry samples, {st['pings']} scan "
          f"lines of {c['msis_device']}: {st['point_features']} point and {st['line_features']} "
          f"line features, {st['updates']} updates, {c['landmarks']} landmarks, "
          f"{st['published']} poses published")  # fmt: skip
    if not paths.dr:
        print("no odometry: the recording has no usable INS messages")
        return 1
    dr = np.asarray(paths.dr)
    dist = float(np.sum(np.hypot(*np.diff(dr[:, 1:], axis=0).T)))
    if paths.slam:
        s = np.asarray(paths.slam)
        dx = s[:, 1] - np.interp(s[:, 0], dr[:, 0], dr[:, 1])
        dy = s[:, 2] - np.interp(s[:, 0], dr[:, 0], dr[:, 2])
        print(f"  distance travelled {dist:.1f} m; SLAM - dead reckoning: RMS "
              f"{float(np.sqrt(np.mean(dx**2 + dy**2))):.2f} m, final "
              f"{float(math.hypot(dx[-1], dy[-1])):.2f} m")  # fmt: skip
    if paths.truth:
        ins = fusion.adapter.ins_device
        offset = fusion.adapter.clocks[ins].offset if ins in fusion.adapter.clocks else None
        if offset is not None:
            truth = np.asarray(sorted(paths.truth))
            truth[:, 0] += offset  # INS time (= simulation time) -> odometry clock
            for name, track in (("dead reckoning", paths.dr), ("SLAM", paths.slam)):
                e = track_error(track, truth)
                if e is not None:
                    print(f"  {name} vs truth over {e['distance_m']:.0f} m: RMSE "
                          f"{e['rmse_m']:.2f} m, final {e['final_m']:.2f} m, RMSE/distance x 100 "
                          f"{e['rmse_pct_distance']:.3f} %")  # fmt: skip
    return 0
