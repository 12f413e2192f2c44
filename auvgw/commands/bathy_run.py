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
import math
from typing import TYPE_CHECKING, Any

from auvgw.commands.demo_parts import (
    DemoContext,
    DemoPlan,
    DemoProcess,
    InProcessContext,
    InProcessPlan,
)
from auvgw.commands.demo_report import SlamReport, Track, path_error, print_gain, print_vs_truth
from auvgw.ground.errors import UserError, format_validation_error
from auvgw.ground.procs import free_endpoint

if TYPE_CHECKING:
    from auvgw.config.scenario import Scenario
    from auvgw.stages.bathymetric import BathymetricStageConfig

#: the stage's name in the demo's summary
DISPLAY_NAME = "mtm-pf (bathymetric PF-SLAM)"
#: the demo's bathymetric stage settings (filter values by name, BathyConfig), checked offline
#: by benchmarks/study_bathy_demo.py on survey.json (1530 pings at 2 m, N = 200, 3 surveys, DR
#: drifting 0.003 m per ping and axis as the emulated INS + DVL does: RMS error 3.5-3.9 m):
#: - mse_max_m2 = 4 (paper 0.5): the relief (8 m, four octaves) is rougher than the paper's; a
#:   particle a few metres off fails the 0.5 m^2 gate, and no crossing ever matched;
#: - lccd off: the tie line crosses each line once, and LCCD (a closure is accepted only when
#:   another agrees with it) rejected every crossing;
#: - sigma_c2 = 0.05 m^2, jitter_a = 0.1 m^2 (paper 1, 1, for its eq. 28 DR): the unweighted
#:   centroid of N particles random-walks sqrt(T sigma_c2 / N) per axis, 3.7 m over this survey
#:   with the paper's values, as much as the INS + DVL drift itself.
#: RMS error 2.76 / 2.56 / 3.65 m against DR's 3.79 / 3.53 / 3.88 m (paper values: 2.36 / 3.15 /
#: 4.93 m, no closure at all: the centroid's random walk).
#: Frozen for issues 28 and 33 on tuning seeds 11-14 (docs/results/bathymetric/e2e/tables.md,
#: "Tuning"; offline with the survey's own INS + DVL errors, then one run end to end):
#: - radius_m = 90 (Sec. V-A's R; paper 10): half the 180 m swath, so a ping is matched wherever
#:   its swath overlaps an older one by half its width or more: every line after the first
#:   overlaps its neighbour 80 m away, and the closures come along the whole route (first at
#:   vehicle t ~ 300 s) instead of only at the tie line after 84 % of it (R = 10 m);
#: - sigma_s_m, unmatched_weight, jitter_in_crossing and closure_estimate at the filter's
#:   defaults (0.15 m measured, neutral, off, mode): the demo's older values (0.3 m, uniform,
#:   on, mean) gave closures 1-3 m off the truth, as large as the drift they correct; these
#:   0.1-0.7 m (median).
#: - drift_estimate = false: the world-frame bias of eq. 28 would be wrong on the next leg
#:   (the emulated INS heading bias and DVL scale turn with the vehicle).
DEMO_PARTICLES = 200
DEMO_FILTER: dict[str, Any] = {
    "mse_max_m2": 4.0,
    "lccd": False,
    "sigma_c2": 0.05,
    "jitter_a": 0.1,
    "radius_m": 90.0,
    "drift_estimate": False,
}


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


def demo_config(vehicle: str, multibeam: str | None) -> BathymetricStageConfig:
    """The demo's stage settings (:data:`DEMO_PARTICLES`, :data:`DEMO_FILTER`) on gateway
    device ``multibeam`` (None: any)."""
    from auvgw.stages.bathymetric import BathymetricStageConfig

    return BathymetricStageConfig(
        vehicle=vehicle, multibeam_device=multibeam, n_particles=DEMO_PARTICLES,
        filter=dict(DEMO_FILTER),
    )  # fmt: skip


def demo_argv(cfg: BathymetricStageConfig, hub: str) -> list[str]:
    """``auvgw slam run --pipeline bathymetric`` with the settings ``cfg``, on the bus ``hub``."""
    sets = [a for k, v in cfg.filter.items() for a in ("--set", f"{k}={json.dumps(v)}")]
    return ["slam", "run", "--pipeline", "bathymetric", "--vehicle", cfg.vehicle,
            "--multibeam", str(cfg.multibeam_device), "--particles", str(cfg.n_particles),
            "--seed", str(cfg.seed), *sets,
            "--connect", hub, "--listen", free_endpoint()]  # fmt: skip


def geoswath_khz(scn: Scenario) -> float:
    """The scenario's GeoSwath model (kHz: 125, 250 or 500)."""
    return float(scn.devices.geoswath.options.get("model_khz", 250))


def demo_plan(ctx: DemoContext) -> DemoPlan:
    """``demo --processes`` on a survey: this stage on the Kongsberg multibeam or, with the
    GeoSwath on, on the swaths the swath stage (its own process, at the model's frequency)
    makes of its pings; both up before vehicle t = 0."""
    component = "slam-bathymetric"
    procs: tuple[DemoProcess, ...]
    if ctx.scn.devices.geoswath.enabled:  # its pings -> the swath stage -> SLAM
        cfg = demo_config(ctx.vehicle, "geoswath_swath")
        khz = geoswath_khz(ctx.scn)
        swath = DemoProcess("swath", lambda _: [
            "swath", "--vehicle", ctx.vehicle, "--device", "geoswath",
            "--set", f"frequency_hz={khz * 1000.0}", *ctx.bus_args()])  # fmt: skip
        procs = (swath, DemoProcess("slam", lambda _: demo_argv(cfg, ctx.hub)))
        alive = {"geoswath", "swath", component}
    else:
        cfg = demo_config(ctx.vehicle, "multibeam")
        procs = (DemoProcess("slam", lambda _: demo_argv(cfg, ctx.hub)),)
        alive = {"multibeam", component}
    return DemoPlan(procs, frozenset(alive), component, DISPLAY_NAME)


def demo_inprocess(ctx: InProcessContext) -> InProcessPlan:
    """The in-process demo on a survey: this stage on the gateway's Kongsberg device or, with a
    GeoSwath, on the swaths the swath stage in front of it (at the model's frequency) makes of
    its pings (``auv/<v>/sensor/<device>_swath/xyz88``)."""
    from auvgw.bus import decode_envelope
    from auvgw.config.gateway import GeoSwathModel
    from auvgw.stages.bathymetric import BathymetricStage
    from auvgw.stages.swath import SwathStage, SwathStageConfig
    from auvgw.subscribe import envelope_message

    devices = ctx.gw_cfg.devices
    mb = [n for n, d in devices.items() if d.format == "kongsberg" and d.enabled]
    gs = [n for n, d in devices.items() if d.format == "geoswath" and d.enabled]
    device = mb[0] if mb else f"{gs[0]}_swath" if gs else None
    stage = BathymetricStage(demo_config(ctx.gw_cfg.vehicle, device), session=ctx.session,
                             on_publish=ctx.on_publish)  # fmt: skip
    if not gs:
        return InProcessPlan(stage, DISPLAY_NAME)

    def on_swath(key: str, payload: bytes, t_ns: int) -> None:
        env = decode_envelope(payload, key)
        stage.post(env.device, t_ns, envelope_message(env))
        ctx.on_publish(key, payload, t_ns)

    f_hz = (devices[gs[0]].geoswath or GeoSwathModel()).frequency_hz
    cfg = SwathStageConfig(vehicle=ctx.gw_cfg.vehicle, device=gs[0],
                           processing={"frequency_hz": f_hz})  # fmt: skip
    swath = SwathStage(cfg, session=ctx.session, on_publish=on_swath)
    return InProcessPlan(stage, DISPLAY_NAME, {"swath": swath})


def demo_report(r: SlamReport) -> dict[str, Any]:
    """The demo summary's lines of this stage (issues 28, 31, 33): its counters, its filtered
    poses (each as published) against the truth and dead reckoning, then its smoothed
    trajectory (mtm-pf's mean trajectory after every accepted closure) against the truth, one
    line of dead reckoning against the filtered and smoothed estimates as DR / SLAM ratios
    (> 1: SLAM better), and when the closures came. Returns ``summary.json``'s
    ``slam_smoothed`` and ``closures_vehicle_s``."""
    st = r.counters["stage"]
    print(f"slam: {st['swaths']} swaths, {st['pings']} used, {st['bad_swaths']} bad, "
          f"{r.counters['loops_accepted']} loop closures accepted, "
          f"{r.counters['loops_rejected']} rejected; {st['maps']} maps")  # fmt: skip
    print_vs_truth(f"SLAM filtered ({r.name}: each pose as published)", r.err,
                   "not enough SLAM poses or truth to compare")  # fmt: skip
    print_gain(r.name, r.err, r.dead_reckoning)
    return _smoothed_report(r.dead_reckoning, r.err, r.smoothed, r.truth)


def _ratio(dr: float, slam: float) -> str:
    return f"{dr / slam:.2f}x" if slam > 0 else "inf"


def _smoothed_report(
    dr: dict[str, float] | None,
    filtered: dict[str, float] | None,
    smoothed: tuple[Track, list[float]] | None,
    truth: Track,
) -> dict[str, Any]:
    """:func:`demo_report`'s lines of the smoothed trajectory and the closures."""
    if smoothed is None:
        print("SLAM smoothed: no trajectory from the bathymetric stage")
        return {"slam_smoothed": None, "closures_vehicle_s": None}
    track, closures = smoothed
    # over the filtered estimate's span (from dead reckoning's first DVL fix)
    err = path_error(track, truth, filtered["from_s"] if filtered else -math.inf)
    print_vs_truth("SLAM smoothed (mtm-pf mean trajectory after every closure)", err,
                   "not enough smoothed poses or truth to compare")  # fmt: skip
    when = (f"at vehicle t = {', '.join(f'{t:.0f}' for t in closures)} s" if closures
            else "none")  # fmt: skip
    print(f"loop closures accepted: {len(closures)}, {when}")
    if dr is not None and filtered is not None and err is not None:
        fin, rms = dr["final_m"], dr["rmse_m"]
        print(f"bathymetric SLAM vs dead reckoning (DR / SLAM, > 1: SLAM better): final "
              f"DR {fin:.2f} m / filtered {filtered['final_m']:.2f} m = "
              f"{_ratio(fin, filtered['final_m'])}; RMSE DR {rms:.2f} m / filtered "
              f"{filtered['rmse_m']:.2f} m = {_ratio(rms, filtered['rmse_m'])}, / smoothed "
              f"{err['rmse_m']:.2f} m = {_ratio(rms, err['rmse_m'])}")  # fmt: skip
    return {"slam_smoothed": err, "closures_vehicle_s": closures}


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
