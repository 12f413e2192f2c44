"""``auvgw demo`` in one process: the gateway, the fusion, the SLAM stage and the Rerun recording
in this process, fed in-process, beside ``auvgw sim`` in its own."""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from auvgw.bus import Keys, encode_envelope, open_session
from auvgw.commands.demo_parts import (
    InProcessContext,
    InProcessPlan,
    TruthSample,
    _fusion_config,
    _load_sim_config,
    _sim_done,
    _sim_epoch_ns,
    _streamed_frames,
    _true_beacons,
    _TruthTail,
    _wait_drained,
)
from auvgw.commands.demo_report import (
    Track,
    _map_summary,
    _Progress,
    _report,
    _smoothed_track,
)
from auvgw.config.bus import BusConfig
from auvgw.config.scenario import load_scenario
from auvgw.health import device_time_s
from auvgw.slam import pipelines
from auvgw.subscribe import slam_output

if TYPE_CHECKING:

    from auvgw.fusion.odometry import Odometry
    from auvgw.stages.fusion import FusionStage
    from auvgw.viz.stage import VizRunner



def _run_stages(
    args: argparse.Namespace,
    sim: subprocess.Popen[bytes],
    sim_dir: Path,
    scenario: Path,
    rrd: Path | None,
    speed: float,
) -> int:
    from auvgw.gateway import Gateway
    from auvgw.stages.fusion import FusionStage

    gw_cfg = _load_sim_config(sim_dir)
    keys = Keys(gw_cfg.vehicle)
    epoch_ns = _sim_epoch_ns(gw_cfg)
    epoch_s = epoch_ns / 1e9  # stamps (s) - epoch_s = vehicle seconds
    truth, dead_reckoning, slam_track = Track(), Track(), Track()
    lock = threading.Lock()
    scn = load_scenario(scenario)

    session = open_session(BusConfig())
    viz = None
    if rrd is not None or args.connect:
        from auvgw.viz.options import gateway_viz_options
        from auvgw.viz.stage import open_viz

        # the SLAM stage's outputs come in-process (on_slam): subscribed too, every SLAM row
        # was logged twice, and out of order where the two paths crossed (issue 33)
        viz = open_viz(session, gw_cfg.vehicle, rrd=rrd, connect=args.connect,
                       options=gateway_viz_options(gw_cfg), sections=("status",))  # fmt: skip

    # the SLAM pipeline the registry gives the scenario, and its stage in this process
    record = None if args.no_slam else pipelines.for_demo(scn)
    # a pipeline's latest DEM tile (its dem output: the whole map last) and its smoothed
    # trajectory (its path output, at flush): the map summary's
    outputs = () if record is None else record.outputs
    views = {o.view: keys.slam(record.name, o.what) for o in outputs if record is not None}
    dem_map: list[bytes] = []
    smoothed: list[bytes] = []

    def on_slam(key: str, payload: bytes, t_ns: int) -> None:
        if key == views.get("dem"):
            dem_map[:] = [payload]
        if key == views.get("path"):
            smoothed[:] = [payload]
        if key.endswith("/pose"):
            p = slam_output(payload, key)
            with lock:
                slam_track.add(p["t"] - epoch_s, p["x"], p["y"])
        if viz is not None:
            viz.stage.handle_sample(key, payload, t_ns)

    # fed in-process (publishes on auv/<v>/slam/<pipeline>/... too); the stages in front of it
    # (a GeoSwath's swath stage) first
    plan: InProcessPlan | None = None
    if record is not None and record.demo_inprocess is not None:
        ctx = InProcessContext(scenario, scn, gw_cfg, epoch_ns, session, on_slam)
        plan = pipelines.load(record.demo_inprocess)(ctx)
    slam = None if plan is None else plan.stage
    if slam is not None:
        slam.start(subscribe=False)
    before = {} if plan is None else plan.before
    for stage in before.values():
        stage.start(subscribe=False)

    def on_odometry(o: Odometry) -> None:
        with lock:
            dead_reckoning.add_odometry(o.t - epoch_s, o.x, o.y, o.coasting, o.heading)
        if viz is not None:
            payload, _ = encode_envelope(o, "fusion", int(o.t * 1e9), 0)
            viz.stage.handle_sample(keys.odometry(), payload, int(o.t * 1e9))
        if slam is not None:
            slam.post_odometry(o)

    fusion_box: list[FusionStage] = []

    def start_fusion(t_vehicle: float) -> FusionStage:
        """Dead reckoning from the true position at the first INS sample the gateway got."""
        deadline = time.monotonic() + 3.0
        while True:  # the truth log (a line per sample) may trail the first INS sample a little
            tail.poll()
            with lock:
                tt, xt, yt = truth.arrays()
            if (len(tt) and tt[-1] >= t_vehicle) or time.monotonic() > deadline:
                break
            time.sleep(0.02)
        if len(tt):
            x0, y0 = float(np.interp(t_vehicle, tt, xt)), float(np.interp(t_vehicle, tt, yt))
        else:
            x0, y0, _ = scn.start_pose
        cfg = _fusion_config(gw_cfg.vehicle, (x0, y0, scn.vehicle.depth_m), scn.devices.ins.noise,
                             speed)  # fmt: skip
        stage = FusionStage(cfg, session=session, on_odometry=on_odometry)
        stage.start(subscribe=False)  # fed in-process, publishes odometry and status
        return stage

    ins_span: list[float] = []  # device time of the first and the latest INS sample, s
    dvl_span: list[float] = []  # the same of the DVL's ensembles (their RTC), s

    def to_fusion(device: str, t_ns: int, msg: object) -> None:
        # t_ns: the gateway's vehicle-paced stamp (its [clock] section)
        if device == "dvl" and (t_dvl := device_time_s(msg)) is not None:
            dvl_span[:] = [dvl_span[0] if dvl_span else t_dvl, t_dvl]
        if device == "ins" and hasattr(msg, "time"):
            ins_span[1:] = [float(msg.time)]
            if not fusion_box:
                ins_span[:] = [float(msg.time), float(msg.time)]
                fusion_box.append(start_fusion(float(msg.time)))
        if fusion_box:
            fusion_box[0].feed(device, t_ns, msg)

    truth_pub = session.declare_publisher(keys.truth("pose"))

    def on_truth(sample: TruthSample) -> None:
        with lock:
            truth.add(sample["t"], sample["x"], sample["y"], sample["heading"])
        body = json.dumps(sample).encode()
        truth_pub.put(body)
        if viz is not None:
            viz.stage.handle_sample(keys.truth("pose"), body, epoch_ns + int(sample["t"] * 1e9))

    tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
    gateway = Gateway(gw_cfg, session=session)
    listeners: list[Callable[[str, int, object], object]] = [to_fusion]
    listeners += [st.post for st in ([slam] if slam is not None else []) + list(before.values())]
    if viz is not None:
        listeners.append(viz.on_message)
    for listener in listeners:
        gateway.listeners.subscribe(listener)
    if viz is not None:
        _log_true_map(viz, keys, scenario, epoch_ns)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    t_start = time.monotonic()
    gateway.start()
    try:
        progress = _Progress(tail, args.duration)
        while not _sim_done(sim, sim_dir) and not stop.is_set():
            tail.poll()
            stop.wait(0.2)
            progress.tick()
        # the emulators are silent but their ports open: drain, then stop the gateway first
        _wait_drained(lambda: _streamed_frames(gw_cfg, gateway.status()["devices"]))
        tail.poll()
    finally:
        status = gateway.status()
        gateway.stop()
        fusion_counters = None
        if fusion_box:
            fusion_box[0].stop(flush=True)
            fusion_counters = fusion_box[0].counters()
        before_counters: dict[str, Any] = {}
        for name, stage in before.items():  # their last outputs reach the SLAM stage first
            stage.stop(flush=True)
            before_counters[name] = stage.counters()
        slam_counters = None
        if slam is not None:
            slam.stop(flush=True)
            slam_counters = slam.counters()
        if viz is not None:
            viz.close()
        session.close()
    _report(
        args, status, fusion_counters,
        None if record is None or plan is None else (record, plan.display, slam_counters),
        dead_reckoning, slam_track, truth, rrd, time.monotonic() - t_start, speed,
        {"ins_time_span_s": ins_span[1] - ins_span[0] if ins_span else 0.0,
         "dvl_time_span_s": dvl_span[1] - dvl_span[0] if dvl_span else 0.0,
         **before_counters, **_map_summary(dem_map, scn)},
        smoothed=_smoothed_track(smoothed, epoch_s),
    )  # fmt: skip
    return 0


def _log_true_map(viz: VizRunner, keys: Keys, scenario: Path, epoch_ns: int) -> None:
    """The scenario's true point and line features, once, on ``truth/map`` at vehicle time 0
    (``epoch_ns`` on the stamps' clock)."""
    scn = load_scenario(scenario)
    lines = [
        {"p0": [x1, y1], "p1": [x2, y2],
         "rho": abs(x1 * (y2 - y1) - y1 * (x2 - x1)) / max(math.hypot(x2 - x1, y2 - y1), 1e-9),
         "theta": math.atan2(-(x2 - x1), y2 - y1)}
        for x1, y1, x2, y2 in scn.features.lines
    ]  # fmt: skip
    beacons = _true_beacons(scn)
    landmarks = [list(p) for p in scn.point_features()] + beacons.pop("landmarks", [])
    body = {"t": 0.0, "landmarks": landmarks, "lines": lines, **beacons}
    viz.stage.handle_sample(keys.truth("map"), json.dumps(body).encode(), epoch_ns)
