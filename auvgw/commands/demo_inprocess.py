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
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from auvgw.bus import Keys, decode_envelope, encode_envelope, open_session
from auvgw.commands.bathy_run import DISPLAY_NAME as BATHY_NAME
from auvgw.commands.bathy_run import demo_config as _bathy_config
from auvgw.commands.demo_parts import (
    BATHYMETRIC,
    VEHICLE,
    OnPublish,
    TruthSample,
    _bathymetric_scenario,
    _fusion_config,
    _is_magnetic,
    _load_sim_config,
    _sim_done,
    _sim_epoch_ns,
    _streamed_frames,
    _true_beacons,
    _TruthTail,
    _wait_drained,
)
from auvgw.commands.demo_report import (
    _bathy_map_summary,
    _Progress,
    _report,
    _smoothed_track,
    _Track,
)
from auvgw.commands.magnetic_run import DISPLAY_NAME as MAGNETIC_NAME
from auvgw.commands.magnetic_run import mag_rate_hz
from auvgw.commands.slam_run import demo_config as _slam_config
from auvgw.config.bus import BusConfig
from auvgw.config.scenario import load_scenario
from auvgw.health import device_time_s
from auvgw.subscribe import slam_output

if TYPE_CHECKING:
    import zenoh

    from auvgw.config.gateway import GatewayConfig
    from auvgw.config.scenario import Scenario
    from auvgw.fusion.odometry import Odometry
    from auvgw.stages.bathymetric import BathymetricStage
    from auvgw.stages.fusion import FusionStage
    from auvgw.stages.magnetic import MagneticStage
    from auvgw.stages.slam import SlamStage
    from auvgw.stages.swath import SwathStage
    from auvgw.viz.stage import VizRunner

    #: the in-process SLAM stage of a demo
    DemoSlam = SlamStage | BathymetricStage | MagneticStage


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
    from auvgw.stages.slam import SlamStage

    gw_cfg = _load_sim_config(sim_dir)
    keys = Keys(gw_cfg.vehicle)
    epoch_ns = _sim_epoch_ns(gw_cfg)
    epoch_s = epoch_ns / 1e9  # stamps (s) - epoch_s = vehicle seconds
    truth, dead_reckoning, slam_track = _Track(), _Track(), _Track()
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

    bathy_map: list[bytes] = []  # the bathymetric stage's latest DEM tile (the whole map last)
    bathy_track: list[bytes] = []  # its smoothed trajectory (at flush)

    def on_slam(key: str, payload: bytes, t_ns: int) -> None:
        if key == keys.slam(BATHYMETRIC.name, "map"):
            bathy_map[:] = [payload]
        if key.endswith("/bathymetric/track"):
            bathy_track[:] = [payload]
        if key.endswith("/pose"):
            p = slam_output(payload, key)
            with lock:
                slam_track.add(p["t"] - epoch_s, p["x"], p["y"])
        if viz is not None:
            viz.stage.handle_sample(key, payload, t_ns)

    # SLAM on the MSIS point features (or, on a survey, the multibeam swaths: bathymetric; with
    # magnetic beacons, AMB-SLAM) and the fusion odometry, fed in-process (publishes on
    # auv/<v>/slam/<pipeline>/... too)
    from auvgw.drivers import registry

    sonar = {dev.format for dev, m in registry.message_types() if "sonar" in m.roles}
    msis = [n for n, d in gw_cfg.devices.items() if d.format in sonar and d.enabled]
    slam: DemoSlam | None = None
    if args.no_slam:
        pass
    elif _is_magnetic(scn):  # the magnetic beacons' AMB-SLAM instead of the MSIS features
        slam = _magnetic_stage(scenario, scn, epoch_ns, session, on_slam)
    elif _bathymetric_scenario(scn):
        slam = _bathy_stage(gw_cfg, session, on_slam)
    else:
        slam = SlamStage(
            _slam_config(gw_cfg.vehicle, msis[0] if msis else None, scn),
            session=session,
            on_publish=on_slam,
        )
    if slam is not None:
        slam.start(subscribe=False)

    def on_swath(key: str, payload: bytes, t_ns: int) -> None:
        from auvgw.subscribe import envelope_message

        env = decode_envelope(payload, key)
        if slam is not None:
            slam.post(env.device, t_ns, envelope_message(env))
        if viz is not None:
            viz.stage.handle_sample(key, payload, t_ns)

    # GeoSwath raw pings -> swaths (XYZ 88 on auv/<v>/sensor/<device>_swath/xyz88) -> SLAM
    swath = _swath_stage(gw_cfg, session, on_swath)
    if swath is not None:
        swath.start(subscribe=False)

    def on_odometry(o: Odometry) -> None:
        with lock:
            dead_reckoning.add_odometry(o.t - epoch_s, o.x, o.y, o.coasting)
        if viz is not None:
            payload, _ = encode_envelope(o, "fusion", int(o.t * 1e9), 0)
            viz.stage.handle_sample(keys.odometry(), payload, int(o.t * 1e9))
        if slam is not None:
            slam.post_odometry(o)

    fusion_box: list[FusionStage] = []

    def start_fusion(t_vehicle: float) -> FusionStage:
        """Dead reckoning from the true position at the first INS sample the gateway got."""
        deadline = time.monotonic() + 3.0
        while True:  # the truth log trails the vehicle by its write buffer
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
            truth.add(sample["t"], sample["x"], sample["y"])
        body = json.dumps(sample).encode()
        truth_pub.put(body)
        if viz is not None:
            viz.stage.handle_sample(keys.truth("pose"), body, epoch_ns + int(sample["t"] * 1e9))

    tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
    gateway = Gateway(gw_cfg, session=session)
    for listener in (to_fusion, slam and slam.post, swath and swath.post, viz and viz.on_message):
        if listener:
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
        swath_counters = None
        if swath is not None:  # its last swaths reach the SLAM stage before that stops
            swath.stop(flush=True)
            swath_counters = swath.counters()
        slam_counters = None
        if slam is not None:
            slam.stop(flush=True)
            slam_counters = slam.counters()
        if viz is not None:
            viz.close()
        session.close()
    _report(
        args, status, fusion_counters,
        None if slam is None else (_slam_name(slam), slam_counters),
        dead_reckoning, slam_track, truth, rrd, time.monotonic() - t_start, speed,
        {"ins_time_span_s": ins_span[1] - ins_span[0] if ins_span else 0.0,
         "dvl_time_span_s": dvl_span[1] - dvl_span[0] if dvl_span else 0.0,
         **({"swath": swath_counters} if swath_counters is not None else {}),
         **_bathy_map_summary(bathy_map, scn)},
        smoothed=_smoothed_track(bathy_track, epoch_s),
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


def _geoswath_device(gw_cfg: GatewayConfig) -> str | None:
    """The gateway's GeoSwath device, if any."""
    gs = [n for n, d in gw_cfg.devices.items() if d.format == "geoswath" and d.enabled]
    return gs[0] if gs else None


def _bathy_stage(
    gw_cfg: GatewayConfig, session: zenoh.Session, on_publish: OnPublish
) -> BathymetricStage:
    """The in-process bathymetric stage on the gateway's Kongsberg device (or the swaths the
    swath stage makes of its GeoSwath device's pings)."""
    from auvgw.stages.bathymetric import BathymetricStage

    mb = [n for n, d in gw_cfg.devices.items() if d.format == "kongsberg" and d.enabled]
    gs = _geoswath_device(gw_cfg)
    device = mb[0] if mb else f"{gs}_swath" if gs else None
    cfg = _bathy_config(gw_cfg.vehicle, device)
    return BathymetricStage(cfg, session=session, on_publish=on_publish)


def _swath_stage(
    gw_cfg: GatewayConfig, session: zenoh.Session, on_publish: OnPublish
) -> SwathStage | None:
    """The in-process swath stage on the gateway's GeoSwath device (None: none), processing
    at the frequency of the device's model (its gateway configuration)."""
    from auvgw.config.gateway import GeoSwathModel
    from auvgw.stages.swath import SwathStage, SwathStageConfig

    device = _geoswath_device(gw_cfg)
    if device is None:
        return None
    f_hz = (gw_cfg.devices[device].geoswath or GeoSwathModel()).frequency_hz
    cfg = SwathStageConfig(vehicle=gw_cfg.vehicle, device=device,
                           processing={"frequency_hz": f_hz})  # fmt: skip
    return SwathStage(cfg, session=session, on_publish=on_publish)


def _slam_name(stage: DemoSlam) -> str:
    """The in-process SLAM stage's name in the summary."""
    name = getattr(stage.config, "display_name", None)
    if name is not None:
        return str(name)
    return BATHY_NAME if type(stage).__name__ == "BathymetricStage" else MAGNETIC_NAME


def _magnetic_stage(
    scenario: Path, scn: Scenario, epoch_ns: int, session: zenoh.Session, on_publish: OnPublish
) -> MagneticStage:
    """The in-process magnetic stage: the scenario's channels and acoustic beacon, the serial
    magnetometer timed by its counter from the gateway's epoch (the beacons' phase reference)."""
    from auvgw.stages.magnetic import MagneticStage, config_from_scenario

    cfg = config_from_scenario(
        scenario, vehicle=VEHICLE, mag_device="magnetometer", mag_rate_hz=mag_rate_hz(scn),
        clock_epoch_s=epoch_ns / 1e9,
    )  # fmt: skip
    return MagneticStage(cfg, session=session, on_publish=on_publish)
