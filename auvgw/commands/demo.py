"""``auvgw demo``: the whole vehicle on a desk, on embedded defaults.

Starts the emulated vehicle (``auvgw sim`` on a shipped scenario, in its own process, every device
on its own virtual port), then in this process the gateway (embedded Zenoh peer), the navigation
fusion, the SLAM stage where one is installed, and the Rerun recording; runs a few minutes of
vehicle time faster than real time; writes ``demo.rrd`` and ``summary.json`` and prints a summary:
messages per device, errors, and navigation error against ground truth.

``--processes``: the same chain as it runs on a vehicle, every part its own OS process joined by
Zenoh over loopback TCP: ``auvgw sim``, the gateway (``auvgw run``), the fusion stage (``auvgw
fusion``) and the SLAM stage (``auvgw slam-run``, live). This process only listens (the bus hub
the others connect to), publishes the ground truth on ``auv/<v>/truth/pose``, collects odometry
and SLAM poses and the components' status, stops the children (SIGINT, then kill) and reports
their exit codes. Vehicle time 0 is held back until every part is up (``auvgw sim
--start-delay``), so dead reckoning starts from the scenario's start pose.

``--scenario beacons`` (a scenario with magnetic beacons and a magnetometer): the SLAM stage is
the magnetic one (AMB-SLAM on the MS3A samples, the acoustic beacon's replies and the fusion
odometry; ``auvgw slam run --pipeline magnetic`` with ``--processes``, started once the sim's
``[clock]`` epoch, the beacons' phase reference, is known); the summary prints its counters and
its error against the truth beside dead reckoning's (RMSE / distance x 100), and the Rerun
recording gets the true and estimated beacons, their ellipses, the ranges and the acoustic beacon.

Time: the emulators run ``speed`` times faster than the host clock, so the device clocks advance
``speed`` vehicle seconds per host second. ``auvgw sim`` writes the gateway's ``[clock]`` section
(``time_scale = speed``, ``epoch_ns`` = host time of vehicle time 0), so the gateway stamps
*vehicle-paced* receive times (``epoch + (t_recv - epoch) * speed``) and every device clock keeps
a constant offset to them, exactly as on a real vehicle at speed 1; the stages take their time
from those stamps only, in this process or their own. Vehicle seconds = stamp - epoch.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from auvgw.bus import Keys, decode_envelope, encode_envelope, open_session
from auvgw.commands.bathy_run import DISPLAY_NAME as BATHY_NAME
from auvgw.commands.bathy_run import demo_config as _bathy_config
from auvgw.commands.common import SubParsers, UserError, add_command
from auvgw.commands.demo_parts import (
    DemoContext,
    DemoPlan,
    TruthSample,
    _fusion_config,
    _gateway_toml,
    _load_sim_config,
    _sim_epoch_ns,
    _TruthTail,
    _wait_for,
)
from auvgw.commands.magnetic_run import DISPLAY_NAME as MAGNETIC_NAME
from auvgw.commands.magnetic_run import mag_rate_hz
from auvgw.commands.slam_run import demo_config as _slam_config
from auvgw.config.bus import BusConfig
from auvgw.config.scenario import ScenarioError, load_scenario
from auvgw.ground.paths import config_file
from auvgw.ground.procs import Children, free_endpoint, stop_process
from auvgw.health import device_time_s
from auvgw.slam import pipelines
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
    from auvgw.subscribe import GatewaySubscriber
    from auvgw.viz.stage import VizRunner

    #: the in-process SLAM stage of a demo
    DemoSlam = SlamStage | BathymetricStage | MagneticStage

DEFAULT_SCENARIO = "harbour"
#: the demo's vehicle seconds and speed (x real time) unless told otherwise
DEFAULT_DURATION_S = 180.0
DEFAULT_SPEED = 2.0
#: a survey's speed: its whole route (1812 s of survey.json) in about 3 minutes; measured here
#: with --processes, every INS sample arrives and the bathymetric stage keeps up
SURVEY_SPEED = 10.0
#: the emulated vehicle's name (the <v> key segment)
VEHICLE = "auv1"
#: a stage's in-process publication hook: (key, payload, stamp ns)
OnPublish = Callable[[str, bytes, int], object]
#: RMSE / distance x 100 of VB-AUFastSLAM in the sea trial of Mu et al. 2022 (INS + DVL + MSIS)
VB_PAPER_RMSE_PCT = 0.742


def register(sub: SubParsers) -> None:
    p = add_command(sub, "demo", __doc__)
    p.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        help="shipped scenario name ("
        + ", ".join(f"{r.demo_scenario}: {r.name} SLAM" for r in pipelines.PIPELINES)
        + ") or a scenario JSON file",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help=f"vehicle seconds (default {DEFAULT_DURATION_S:.0f}; a survey with --processes: its "
        "whole route, about 30 min, whose tie line crosses every line: the loop closures)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help=f"x real time (default {DEFAULT_SPEED:g}; a survey with --processes "
        f"{SURVEY_SPEED:g}: about 3.5 min)",
    )
    p.add_argument("--pace", choices=("elastic", "free"), default="elastic",
                   help="the sim's clock (auvgw sim --pace): elastic (default) waits for its "
                   "devices on a loaded host; free runs at --speed whatever happens")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--rrd", type=Path, default=None, help="Rerun file (default OUT/demo.rrd)")
    p.add_argument("--connect", default=None, help="also stream to a Rerun viewer at this URL")
    p.add_argument("--no-viz", action="store_true", help="no Rerun recording")
    p.add_argument("--no-slam", action="store_true", help="no SLAM stage")
    p.add_argument(
        "--multibeam",
        choices=("kongsberg", "geoswath"),
        default="kongsberg",
        help="a survey's multibeam: Kongsberg XYZ 88 swaths (default) or GeoSwath raw pings, "
        "processed into swaths by the swath stage (auvgw.stages.swath) for the bathymetric SLAM",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="the scenario's emulator seed (every device's noise draws; default: the "
        "scenario's). Tuning runs take seeds below 1000, reported runs 1000 and up "
        "(auvgw.slam.evaluation.heldout)",
    )
    p.add_argument(
        "--processes",
        action="store_true",
        help="sim, gateway, fusion and SLAM each in its own OS process (this one only collects)",
    )
    p.add_argument(
        "--start-delay",
        type=float,
        default=10.0,
        metavar="S",
        help="--processes: host seconds from the sim's gateway.toml to vehicle time 0, for the "
        "gateway process to start and open every port (default 10)",
    )
    p.add_argument(
        "--closed-loop",
        action="store_true",
        help="fly --mission with the reference autopilot through the whole chain (the "
        "closed-loop scenario; sim, gateway, fusion, pilot, viz, record each a process) and "
        "print the errors against the truth (auvgw/commands/demo_closed_loop.py)",
    )
    p.add_argument("--mission", type=Path, default=None,
                   help="--closed-loop: mission file (default config/missions/box.toml)")
    p.set_defaults(func=run)


def _scenario_path(name: str) -> Path:
    p = Path(name)
    if p.suffix == ".json" or p.exists():
        return p
    shipped = config_file(f"scenarios/{name}.json")
    if not shipped.is_file():
        raise UserError(f"--scenario {name}: not a file and not a shipped scenario")
    return shipped


def _demo_scenario(
    src: Path, out: Path, multibeam: str = "kongsberg", seed: int | None = None
) -> Path:
    """The scenario with the INS on serial only: python-can's slcan reader handles ~1400 CAN
    frames/s here, and the HN-100's 800 frames/s x speed would overrun it (the CAN form of the
    INS is exercised by the tests; the magnetometer keeps its CAN form). ``multibeam``
    "geoswath": the GeoSwath emulator replaces a multibeam the scenario has on. ``seed``: the
    emulators' seed instead of the scenario's. A survey (the bathymetric pipeline) runs without
    the devices that pipeline does not read (:data:`SURVEY_IDLE_DEVICES`) unless its file turns
    them on: on a loaded host they only add lag, and the INS clock resets lag causes move dead
    reckoning's stamps off the vehicle's time."""
    try:
        scn = load_scenario(src)
    except ScenarioError as exc:
        raise UserError(str(exc)) from exc
    data = json.loads(src.read_text())
    devices = data.setdefault("devices", {})
    ins = devices.setdefault("ins", {})
    ins.setdefault("options", {})["can"] = False
    if seed is not None:
        data["seed"] = seed
    if _bathymetric_scenario(scn):
        for name in SURVEY_IDLE_DEVICES:
            devices.setdefault(name, {}).setdefault("enabled", False)
    if multibeam == "geoswath" and scn.devices.multibeam.enabled:
        devices["multibeam"] = {**devices.get("multibeam", {}), "enabled": False}
        devices["geoswath"] = {**devices.get("geoswath", {}), "enabled": True}
    # relative file references stay valid: resolve them against the original scenario
    for section, key in (("features", "points_file"), ("vehicle", "waypoints_file")):
        ref = data.get(section, {}).get(key)
        if ref and not str(ref).startswith("shared:") and not Path(ref).is_absolute():
            data[section][key] = str((src.parent / ref).resolve())
    path = out / f"{scn.name}-demo.json"
    path.write_text(json.dumps(data, indent=1))
    return path


@dataclass
class _Track:
    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)

    def add(self, t: float, x: float, y: float) -> None:
        self.t.append(t)
        self.x.append(x)
        self.y.append(y)

    def add_odometry(self, t: float, x: float, y: float, coasting: bool) -> None:
        """Dead reckoning is scored from its first DVL fix: before it the filter has no
        velocity and holds its start position whatever the vehicle does (how long depends on
        which port the gateway opened first), after it the fix's correction carries back."""
        if self.t or not coasting:
            self.add(t, x, y)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.asarray(self.t), np.asarray(self.x), np.asarray(self.y)


def _path_error(est: _Track, truth: _Track, since: float = -math.inf) -> dict[str, float] | None:
    """Horizontal error of ``est`` against ``truth`` (interpolated at the estimate's times),
    from vehicle time ``since`` (s); ``samples``: the estimates scored, ``outside_truth``: those
    left out, stamped outside the truth log's span (the last swath's pose may be stamped after
    the last truth sample) or before ``since``."""
    te, xe, ye = est.arrays()
    tt, xt, yt = truth.arrays()
    if len(te) < 2 or len(tt) < 2:
        return None
    keep = (te >= max(tt[0], since)) & (te <= tt[-1])
    if keep.sum() < 2:
        return None
    te, xe, ye = te[keep], xe[keep], ye[keep]
    ex = xe - np.interp(te, tt, xt)
    ey = ye - np.interp(te, tt, yt)
    err = np.hypot(ex, ey)
    seg = (tt >= te[0]) & (tt <= te[-1])
    dist = float(np.sum(np.hypot(np.diff(xt[seg]), np.diff(yt[seg]))))
    rmse = float(np.sqrt(np.mean(err**2)))
    return {
        "samples": len(te),
        "outside_truth": int(len(keep) - len(te)),
        "from_s": float(te[0]),
        "distance_m": dist,
        "rmse_m": rmse,
        "rmse_x_m": float(np.sqrt(np.mean(ex**2))),
        "rmse_y_m": float(np.sqrt(np.mean(ey**2))),
        "final_m": float(err[-1]),
        "rmse_pct_distance": 100.0 * rmse / dist if dist > 0 else math.nan,
    }


def _sim_argv(scenario: Path, speed: float, duration: float, sim_dir: Path,
              pace: str = "elastic") -> list[str]:  # fmt: skip
    return ["sim", "--scenario", str(scenario), "--speed", str(speed), "--duration",
            str(duration), "--out", str(sim_dir), "--vehicle", VEHICLE, "--hold",
            "--pace", pace]  # fmt: skip


def _sim_done(sim: subprocess.Popen[bytes], sim_dir: Path) -> bool:
    """The emulated run is over: the sim wrote ``finished`` (ports still open) or exited."""
    return sim.poll() is not None or (sim_dir / "finished").exists()


def _streamed_frames(gw_cfg: GatewayConfig, devices: dict[str, dict[str, int]]) -> int:
    """Frames the gateway has read from the devices that speak on their own: a polled device
    (a host driver, the MSIS head) answers every poll for as long as its port stays open, so its
    frames never go quiet; counted, they held the drain at its limit while the gateway kept
    stamping rows past the end of the run (issue 33: 20 s of vehicle time at ``--speed 2``)."""
    from auvgw.drivers import registry

    polled = {k.format for k in registry.DEVICES if k.host_driver}
    return sum(
        int(d.get("frames", 0))
        for name, d in devices.items()
        if name not in gw_cfg.devices or gw_cfg.devices[name].format not in polled
    )


def _wait_drained(frames: Callable[[], int], quiet_s: float = 0.5, limit_s: float = 10.0) -> None:
    """Wait until a count has not moved for ``quiet_s``, at most ``limit_s``: the gateway's
    frames (the last read from the held-open ports) or a stage's received messages."""
    last, since, end = frames(), time.monotonic(), time.monotonic() + limit_s
    while time.monotonic() < end and time.monotonic() - since < quiet_s:
        time.sleep(0.05)
        n = frames()
        if n != last:
            last, since = n, time.monotonic()


def run(args: argparse.Namespace) -> int:
    if args.closed_loop:
        from auvgw.commands.demo_closed_loop import run_closed_loop

        return run_closed_loop(args)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    sim_dir = out / "sim"
    for stale in (sim_dir / "gateway.toml", sim_dir / "truth.jsonl", sim_dir / "finished"):
        stale.unlink(missing_ok=True)
    scenario = _demo_scenario(_scenario_path(args.scenario), out, args.multibeam, args.seed)
    _scenario_defaults(args, scenario)
    rrd = None if args.no_viz else (args.rrd or out / "demo.rrd")
    speed = float(args.speed)
    if speed <= 0:
        raise UserError("--speed must be > 0 (the gateway reads the devices in real time)")
    if not 0 <= args.start_delay <= 600:
        raise UserError(f"--start-delay must be 0 to 600 s, got {args.start_delay}")

    print(f"auvgw demo: scenario {scenario.name}, {args.duration:.0f} s of vehicle time at "
          f"{speed:g}x real time" + (", one process per part" if args.processes else ""),
          flush=True)  # fmt: skip
    if args.processes:
        return _run_processes(args, sim_dir, scenario, rrd, speed)
    sim_log = open(out / "sim.log", "wb")  # noqa: SIM115 (closed in finally)
    sim = subprocess.Popen(
        [sys.executable, "-m", "auvgw",
         *_sim_argv(scenario, speed, args.duration, sim_dir, args.pace)],
        stdout=sim_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        _wait_for(sim_dir / "gateway.toml", sim, 60.0)
        return _run_stages(args, sim, sim_dir, scenario, rrd, speed)
    finally:
        stop_process(sim, signal.SIGINT, 20.0)
        sim_log.close()


def _scenario_defaults(args: argparse.Namespace, scenario: Path) -> None:
    """``--duration`` and ``--speed`` where not given: a survey (the bathymetric pipeline) with
    ``--processes`` runs its whole route at :data:`SURVEY_SPEED` (its first loop closure comes
    with the second line, about 5 minutes in, the gain over dead reckoning with the whole
    route); any other run :data:`DEFAULT_DURATION_S` at
    :data:`DEFAULT_SPEED` (one process does not keep up with the survey's devices at 10x: it
    lost 40 % of the INS frames and dead reckoning diverged, measured here)."""
    survey = _bathymetric_scenario(load_scenario(scenario))
    whole = survey and args.processes
    if args.speed is None:
        args.speed = SURVEY_SPEED if whole else DEFAULT_SPEED
    if args.duration is None:
        args.duration = DEFAULT_DURATION_S
        if whole:
            from auvgw.sim_devices.vehicle import simulate
            from auvgw.sim_devices.world import World

            scn = load_scenario(scenario)
            args.duration = math.ceil(simulate(scn, World.from_scenario(scn)).duration)
        elif survey:
            print("note: the survey's first loop closure comes with its second line, about 5 "
                  "minutes of vehicle time in; `auvgw demo --scenario survey --processes` runs "
                  f"the whole route at {SURVEY_SPEED:g}x", flush=True)  # fmt: skip


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


@dataclass
class _Progress:
    """Prints the vehicle time every 5 host seconds: the newest truth sample's (the sim's own
    clock, which an elastic or lock-step sim holds while the host is behind), not host time."""

    tail: _TruthTail
    duration: float
    last: float = 0.0

    def tick(self) -> None:
        now = time.monotonic()
        if now - self.last > 5.0:
            self.last = now
            print(f"  vehicle t = {self.tail.t:6.1f} s / {self.duration:.0f} s", flush=True)


def _report(
    args: argparse.Namespace,
    status: dict[str, Any],
    fusion_counters: dict[str, Any] | None,
    slam: tuple[str, dict[str, Any] | None] | None,
    dead_reckoning: _Track,
    slam_track: _Track,
    truth: _Track,
    rrd: Path | None,
    wall: float,
    speed: float,
    extra: dict[str, Any],
    smoothed: tuple[_Track, list[float]] | None = None,
) -> dict[str, Any]:
    """Print the summary and write ``summary.json`` (both modes); returns the summary.
    ``smoothed``: the bathymetric stage's smoothed trajectory and its closures' vehicle times
    (:func:`_smoothed_track`)."""
    nav = _path_error(dead_reckoning, truth)
    _print_summary(status, fusion_counters, nav, rrd, wall)
    navigation: dict[str, Any] = {"dead_reckoning": nav}
    slam_counters: dict[str, Any] | None = None
    if slam is not None and slam[1] is not None:
        name, slam_counters = slam[0], slam[1]
        # over the same span as dead reckoning's: from the first DVL fix
        slam_err = _path_error(slam_track, truth, dead_reckoning.t[0] if dead_reckoning.t else 0.0)
        if slam_counters.get("component") == MAGNETIC_COMPONENT:
            _print_magnetic(name, slam_counters, slam_err, nav)
        else:
            _print_slam(name, slam_counters, slam_err)
            if name == BATHY_NAME:
                _print_gain(name, slam_err, nav)
                navigation.update(_bathy_report(nav, slam_err, smoothed, truth))
        # the VB paper's figure, for the landmark SLAM stage only
        landmark = name != BATHY_NAME and slam_counters.get("component") != MAGNETIC_COMPONENT
        paper = VB_PAPER_RMSE_PCT if landmark else None
        navigation.update(slam=slam_err, slam_algorithm=name,
                          paper_rmse_pct_distance=paper)  # fmt: skip
    summary = {"devices": status["devices"], "fusion": fusion_counters, "slam": slam_counters,
               "navigation": navigation,
               "rrd": str(rrd) if rrd else None, "wall_s": wall, "speed": speed,
               **extra}  # fmt: skip
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return summary


# -- one OS process per part ------------------------------------------------------------------


def _check_children(children: Children) -> None:
    """A :class:`UserError` if a child other than the sim has exited."""
    name = children.exited(but=("sim",))
    if name is not None:
        code = children.procs[name].returncode
        raise UserError(f"{name} stopped early (exit {code}): {children.tail(name)}")


class _Collector:
    """This process's subscriptions in ``--processes`` mode: odometry (stamped time, vehicle
    time, host arrival), SLAM poses and the latest status of every component."""

    def __init__(self, session: zenoh.Session, keys: Keys, epoch_s: float) -> None:
        self.epoch_s = epoch_s
        self.lock = threading.Lock()
        self.dead_reckoning, self.slam, self.truth = _Track(), _Track(), _Track()
        self.odometry_stamps: list[tuple[float, float]] = []  # (envelope stamp s, host s)
        self.status: dict[str, dict[str, Any]] = {}
        self._subs = [
            session.declare_subscriber(keys.odometry(), self._on_odometry),
            session.declare_subscriber(keys.slam("*", "pose"), self._on_slam),
            session.declare_subscriber(keys.status("*"), self._on_status),
        ]

    def _on_odometry(self, sample: zenoh.Sample) -> None:
        env = decode_envelope(sample.payload.to_bytes())
        o = env.body
        with self.lock:
            self.dead_reckoning.add_odometry(
                o["t"] - self.epoch_s, o["x"], o["y"], bool(o["coasting"])
            )
            self.odometry_stamps.append((env.t_recv_ns / 1e9, time.time()))

    def _on_slam(self, sample: zenoh.Sample) -> None:
        p = slam_output(sample.payload.to_bytes(), str(sample.key_expr))
        with self.lock:
            self.slam.add(p["t"] - self.epoch_s, p["x"], p["y"])

    def _on_status(self, sample: zenoh.Sample) -> None:
        component = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            self.status[component] = json.loads(sample.payload.to_bytes())

    def received(self, component: str) -> int:
        """Bus messages ``component`` (a stage) has counted as received, by its last status."""
        with self.lock:
            return int((self.status.get(component) or {}).get("stage", {}).get("received", 0))

    def close(self) -> None:
        from auvgw.bus import undeclare

        undeclare(self._subs)

    def wait_stopped(
        self, components: list[str], map_tap: _MapTap | None, limit_s: float = 10.0
    ) -> None:
        """Wait (at most ``limit_s``) for the last status of each stage in ``components`` (its
        ``stopped`` status, put after every pose and odometry sample it published) and, with
        ``map_tap``, for the whole map that went out before it (a lower-priority output, so it
        may arrive after the status)."""
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            with self.lock:
                last = [self.status.get(c) or {} for c in components]
            done = all(st.get("stopped") for st in last)
            if done and map_tap is not None:
                pings = last[-1].get("pings")
                done = (
                    bool(map_tap.last)
                    and bool(map_tap.track)
                    and slam_output(map_tap.last[-1]).get("pings") == pings
                )
            if done:
                return
            time.sleep(0.05)

    def timing(self) -> dict[str, Any]:
        """How the odometry envelopes' stamps advanced: the vehicle time of the first, their
        span (vehicle s) and their rate against the host clock of their arrival (stamped s per
        host s; the samples flushed at shutdown, all stamped with the last input's time, left
        out): ``speed`` when the stamps are vehicle-paced. The rate is the median slope over
        pairs half the run apart, so a burst delivered late by a stalled process (a busy
        machine) moves only the few pairs it is part of, where a least-squares fit would tilt."""
        with self.lock:
            st = np.asarray(self.odometry_stamps, float).reshape(-1, 2)
        if len(st) < 2:
            return {"samples": len(st)}
        live = st[st[:, 0] < st[:, 0].max()]
        half = len(live) // 2
        dt_host = live[half:, 1] - live[: len(live) - half, 1]
        ok = dt_host > 0
        d_stamp = live[half:, 0] - live[: len(live) - half, 0]
        rate = float(np.median(d_stamp[ok] / dt_host[ok])) if ok.any() else float("nan")
        return {
            "samples": len(st),
            "first_vehicle_s": float(st[0, 0] - self.epoch_s),
            "stamp_span_s": float(st[-1, 0] - st[0, 0]),
            "stamp_rate": rate if len(live) > 1 else None,
        }


def _wait_alive(
    sub: GatewaySubscriber, wanted: set[str], children: Children, timeout_s: float, what: str
) -> float:
    """Wait until every component in ``wanted`` holds its liveliness token; host time then."""
    deadline = time.monotonic() + timeout_s
    while True:
        _check_children(children)
        missing = wanted - sub.alive(timeout=0.5)
        if not missing:
            return time.time()
        if time.monotonic() > deadline:
            raise UserError(f"{what}: no {', '.join(sorted(missing))} on the bus after "
                            f"{timeout_s:.0f} s")  # fmt: skip
        time.sleep(0.1)


def _run_processes(
    args: argparse.Namespace, sim_dir: Path, scenario: Path, rrd: Path | None, speed: float
) -> int:
    from auvgw.subscribe import GatewaySubscriber

    out: Path = args.out
    scn = load_scenario(scenario)
    keys = Keys(VEHICLE)
    hub = free_endpoint()
    session = open_session(BusConfig(listen=[hub]))
    sub = GatewaySubscriber(VEHICLE, session=session)
    children = Children(out)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    t_start = time.monotonic()
    collector: _Collector | None = None
    map_tap: _MapTap | None = None
    slam_part: tuple[str, str] | None = None  # the SLAM stage's display name and component
    truth_pub = session.declare_publisher(keys.truth("pose"))
    try:
        # the stages first (they need nothing from the sim), so they are up before vehicle t = 0
        x0, y0, _ = scn.start_pose
        settings = out / "fusion.json"
        settings.write_text(_fusion_config(VEHICLE, (x0, y0, scn.vehicle.depth_m),
                                           scn.devices.ins.noise, speed)
                            .model_dump_json(indent=1))  # fmt: skip
        children.start("fusion", ["fusion", "--settings", str(settings),
                                  "--connect", hub, "--listen", free_endpoint()])  # fmt: skip
        wanted = {"fusion", "gateway", "ins", "dvl"}
        # the SLAM pipeline's processes, as its registry record says (demo_processes)
        record = None if args.no_slam else pipelines.for_demo(scn)
        ctx = DemoContext(scenario, scn, VEHICLE, hub, free_endpoint)
        plan: DemoPlan | None = None if record is None else pipelines.load(
            record.demo_processes)(ctx)  # fmt: skip
        if plan is not None:
            slam_part = (plan.display, plan.component)
            wanted |= plan.alive
            for proc in plan.processes:
                if not proc.after_clock:
                    children.start(proc.name, proc.argv(None))
        # the GeoSwath's emulator (numpy work on 4000-sample pings) in its own process, so it
        # never holds the INS emulator's interpreter (issue 31: in one sim process its pings
        # made the INS frames leave 40-58 vehicle s late at 10x); every device then has its own
        sim = children.start("sim", [*_sim_argv(scenario, speed, args.duration, sim_dir, args.pace),
                                     "--start-delay", str(args.start_delay),
                                     *(["--processes"] if scn.devices.geoswath.enabled
                                       else [])])  # fmt: skip
        _wait_for(sim_dir / "gateway.toml", sim, 120.0)
        gw_cfg = _load_sim_config(sim_dir)
        epoch_ns = _sim_epoch_ns(gw_cfg)
        collector = _Collector(session, keys, epoch_ns / 1e9)
        if record is not None and _MapTap.taps(record):
            map_tap = _MapTap(session, keys, record)
        gw_argv = ["run", "--config", str(_gateway_toml(sim_dir, out, free_endpoint(), hub))]
        if rrd is not None:
            gw_argv += ["--viz-rrd", str(rrd)]
        if args.connect:
            gw_argv += ["--viz-connect", args.connect]
        children.start("gateway", gw_argv)
        for proc in plan.processes if plan is not None else ():
            if proc.after_clock:  # after gateway.toml: its [clock] epoch (vehicle time 0)
                children.start(proc.name, proc.argv(epoch_ns))
        ready = _wait_alive(sub, wanted, children, 120.0, "--processes")
        beacons = _true_beacons(scn)
        if beacons and rrd is not None:  # the true beacons, for the gateway's Rerun recording
            session.put(keys.truth("map"), json.dumps({"t": 0.0, **beacons}).encode())
        ready_vehicle_s = (ready - epoch_ns / 1e9) * speed
        if ready_vehicle_s > 0:
            print(f"  warning: every part was up only at vehicle t = {ready_vehicle_s:.1f} s "
                  "(dead reckoning starts from the pose at t = 0)", flush=True)  # fmt: skip

        def on_truth(sample: TruthSample) -> None:
            assert collector is not None
            with collector.lock:
                collector.truth.add(sample["t"], sample["x"], sample["y"])
            truth_pub.put(json.dumps(sample).encode())

        tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
        progress = _Progress(tail, args.duration)
        while not _sim_done(sim, sim_dir) and not stop.is_set():
            tail.poll()
            _check_children(children)
            stop.wait(0.2)
            progress.tick()
        tail.poll()
        # the devices are silent, their ports still open: the gateway drains them; then stop in
        # data-flow order: gateway, fusion (flushes its held-back odometry), SLAM once what they
        # put has reached it (its received count quiet for two status periods; a loaded machine
        # holds samples in flight for seconds), which drains its queue and publishes its last
        # pose, and the emulators last
        _wait_drained(lambda: _streamed_frames(
            gw_cfg, (sub.status(timeout=2.0) or {"devices": {}})["devices"]), quiet_s=1.5)
        status = sub.status(timeout=2.0) or collector.status.get("gateway") or {"devices": {}}
        for name in ("gateway", "fusion", "swath"):  # (swath, if any: flushes its last swaths)
            children.stop(name)
        if slam_part is not None:
            _wait_drained(partial(collector.received, slam_part[1]), quiet_s=2.5, limit_s=20.0)
        for name in ("slam", "sim"):
            children.stop(name)
        collector.wait_stopped(["fusion", *([slam_part[1]] if slam_part else [])], map_tap)
    finally:
        children.close()
        if collector is not None:
            collector.close()
        if map_tap is not None:
            map_tap.close()
        truth_pub.undeclare()
        sub.close()
        session.close()
    wall = time.monotonic() - t_start
    procs = children.report()
    print()
    print("processes: " + ", ".join(
        f"{n} pid {p['pid']} exit {p['exit_code']}" + (" (killed)" if p["killed"] else "")
        for n, p in procs.items()))  # fmt: skip
    c = collector
    assert c is not None
    slam = None if slam_part is None else (slam_part[0], c.status.get(slam_part[1]))
    _report(
        args, status, c.status.get("fusion"), slam, c.dead_reckoning, c.slam, c.truth, rrd, wall,
        speed, {"processes": procs, "odometry_timing": c.timing(),
                "ready_vehicle_s": ready_vehicle_s,
                **_bathy_map_summary(map_tap.last if map_tap else [], scn)},
        smoothed=_smoothed_track(map_tap.track if map_tap else [], epoch_ns / 1e9),
    )  # fmt: skip
    bad = [n for n, p in procs.items() if p["exit_code"] != 0]
    if bad:
        print(f"not every part exited cleanly: {', '.join(bad)}", file=sys.stderr)
        return 1
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


def _print_summary(
    status: dict[str, Any],
    fusion: dict[str, Any] | None,
    err: dict[str, float] | None,
    rrd: Path | None,
    wall_s: float,
) -> None:
    print()
    print("device            connected  frames  bad  skipped  decode_err  messages")
    for name, d in sorted(status["devices"].items()):
        msgs = ", ".join(f"{k} {v}" for k, v in sorted(d["messages"].items()))
        print(f"{name:<17} {d['connected']!s:<9} {d['frames']:>7} {d['bad_frames']:>4} "
              f"{d['skipped_bytes']:>8} {d['decode_errors']:>11}  {msgs}")  # fmt: skip
    print()
    if fusion is None:
        print("fusion: no INS data, not started")
    else:
        st = fusion["stage"]
        print(f"fusion: {st.get('received', 0)} messages in, {st.get('published', 0)} "
              f"odometry out; filter {json.dumps(fusion['filter'])}")  # fmt: skip
    if err is None:
        print("navigation error: not enough odometry or truth to compare")
    else:
        print(
            f"dead reckoning vs truth over {err['distance_m']:.0f} m from its first DVL fix: "
            f"RMSE {err['rmse_m']:.2f} m "
            f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
            f"RMSE/distance {err['rmse_pct_distance']:.3f} %"
        )
    if rrd is not None:
        size = rrd.stat().st_size / 1e6 if rrd.is_file() else 0.0
        print(f"Rerun recording: {rrd} ({size:.1f} MB) - open it with: rerun {rrd}")
    print(f"wall time {wall_s:.0f} s")


def _print_slam(name: str, counters: dict[str, Any], err: dict[str, float] | None) -> None:
    st = counters["stage"]
    paper = f" (VB paper sea trial: {VB_PAPER_RMSE_PCT} %)"
    label = f"SLAM ({name})"
    if counters.get("component") == "slam-bathymetric":
        _print_bathy(counters)
        paper = ""
        label = f"SLAM filtered ({name}: each pose as published)"
    else:
        print(f"slam: {st['pings']} scan lines, {st['point_features']} point and "
              f"{st['line_features']} line features, {st['updates']} updates, "
              f"{counters['landmarks']} landmarks")  # fmt: skip
    _print_vs_truth(label, err, "not enough SLAM poses or truth to compare", paper)


def _print_vs_truth(label: str, err: dict[str, float] | None, missing: str, tail: str = "") -> None:
    """``<label> vs truth``: the error (m, RMSE / distance x 100, then ``tail``), or ``missing``
    without one."""
    if err is None:
        print(f"{label} vs truth: {missing}")
        return
    print(f"{label} vs truth over {err['distance_m']:.0f} m: RMSE {err['rmse_m']:.2f} m "
          f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
          f"RMSE/distance x 100 {err['rmse_pct_distance']:.3f} %{tail}")  # fmt: skip


# -- the bathymetric pipeline on survey scenarios (issue 14) -----------------------------------

#: emulated devices a survey's demo leaves off (the bathymetric pipeline reads the INS, DVL and
#: multibeam only): the MSIS (polled) and the magnetometer (serial and SLCAN) took 118,000 of
#: the 317,000 frames of a whole-route run here
SURVEY_IDLE_DEVICES = ("msis", "magnetometer")


#: the registry records of the pipelines the demo wires itself (in process and as processes)
BATHYMETRIC = pipelines.get("bathymetric")
MAGNETIC = pipelines.get("magnetic")


def _bathymetric_scenario(scn: Scenario) -> bool:
    """A survey: the registry gives the scenario to the bathymetric pipeline
    (:func:`auvgw.commands.bathy_run.demo_accepts`)."""
    return pipelines.for_demo(scn) is BATHYMETRIC


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


def _print_bathy(counters: dict[str, Any]) -> None:
    st = counters["stage"]
    print(f"slam: {st['swaths']} swaths, {st['pings']} used, {st['bad_swaths']} bad, "
          f"{counters['loops_accepted']} loop closures accepted, "
          f"{counters['loops_rejected']} rejected; {st['maps']} maps")  # fmt: skip


class _MapTap:
    """``--processes``: a pipeline's latest DEM payload (its output of view ``dem``: the whole map
    once the stage has flushed) and its smoothed trajectory (view ``path``, at flush)."""

    def __init__(self, session: zenoh.Session, keys: Keys, record: pipelines.Pipeline) -> None:
        self.last: list[bytes] = []
        self.track: list[bytes] = []
        what = {o.view: o.what for o in record.outputs}
        self._subs = [
            session.declare_subscriber(keys.slam(record.name, what["dem"]), self._on_map),
            session.declare_subscriber(keys.slam(record.name, what["path"]), self._on_track),
        ]

    @staticmethod
    def taps(record: pipelines.Pipeline) -> bool:
        """Whether ``record``'s stage publishes a DEM and a smoothed trajectory."""
        return {"dem", "path"} <= {o.view for o in record.outputs}

    def _on_map(self, sample: zenoh.Sample) -> None:
        self.last[:] = [sample.payload.to_bytes()]

    def _on_track(self, sample: zenoh.Sample) -> None:
        self.track[:] = [sample.payload.to_bytes()]

    def close(self) -> None:
        from auvgw.bus import undeclare

        undeclare(self._subs)


def _smoothed_track(payloads: list[bytes], epoch_s: float) -> tuple[_Track, list[float]] | None:
    """The bathymetric stage's ``track`` payload (the last of ``payloads``; None without one)
    as a vehicle-time track and its accepted closures' vehicle times (s)."""
    if not payloads:
        return None
    body = slam_output(payloads[-1])
    track = _Track([t - epoch_s for t in body["t"]], list(body["x"]), list(body["y"]))
    return track, [t - epoch_s for t in body.get("closures_t", [])]


def _ratio(dr: float, slam: float) -> str:
    return f"{dr / slam:.2f}x" if slam > 0 else "inf"


def _bathy_report(
    dr: dict[str, float] | None,
    filtered: dict[str, float] | None,
    smoothed: tuple[_Track, list[float]] | None,
    truth: _Track,
) -> dict[str, Any]:
    """The bathymetric SLAM's report lines (issues 28, 31, 33): the smoothed trajectory
    (mtm-pf's mean trajectory after every accepted closure) against the truth, then one line
    of dead reckoning against the filtered (published pose) and smoothed estimates, as
    DR / SLAM ratios (> 1: SLAM better), and when the closures came. Returns the summary's
    ``slam_smoothed`` and ``closures_vehicle_s``."""
    if smoothed is None:
        print("SLAM smoothed: no trajectory from the bathymetric stage")
        return {"slam_smoothed": None, "closures_vehicle_s": None}
    track, closures = smoothed
    # over the filtered estimate's span (from dead reckoning's first DVL fix)
    err = _path_error(track, truth, filtered["from_s"] if filtered else -math.inf)
    _print_vs_truth("SLAM smoothed (mtm-pf mean trajectory after every closure)", err,
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


def _bathy_map_summary(last: list[bytes], scn: Scenario) -> dict[str, Any]:
    """``{"bathymetric_map": ...}``: the stage's last DEM against the scenario's true terrain
    (depth of each cell centre): cells, mean / median |error| m, share under 2 m (the paper's
    registration measure); empty when no map was published."""
    if not last:
        return {}
    from auvgw.sim_devices.world import World

    body = slam_output(last[-1])
    grid = np.array([[math.nan if v is None else v for v in row] for row in body["depth"]], float)
    i, j = np.nonzero(np.isfinite(grid))
    cell = float(body["cell_m"])
    x = float(body["x0"]) + (i + 0.5) * cell
    y = float(body["y0"]) + (j + 0.5) * cell
    err = np.abs(grid[i, j] - World.from_scenario(scn).depth(x, y))
    out: dict[str, Any] = {"cells": len(err), "pings": body.get("pings"),
                           "loops": body.get("loops"),
           "mean_abs_error_m": float(err.mean()) if len(err) else None,
           "median_abs_error_m": float(np.median(err)) if len(err) else None,
           "share_under_2m": float(np.mean(err < 2.0)) if len(err) else None}  # fmt: skip
    if len(err):
        print(f"bathymetric map vs true terrain: {out['cells']} cells of {cell:g} m, mean "
              f"|error| {out['mean_abs_error_m']:.2f} m, {100 * out['share_under_2m']:.1f} % "
              "under 2 m")  # fmt: skip
    return {"bathymetric_map": out}


# -- the beacons scenario: AMB-SLAM on the magnetometer and the acoustic beacon -----------------

#: the magnetic stage's status component
MAGNETIC_COMPONENT = f"slam-{MAGNETIC.name}"


def _is_magnetic(scn: Scenario) -> bool:
    """A scenario for the magnetic stage: the registry gives it to the magnetic pipeline
    (:func:`auvgw.commands.magnetic_run.demo_accepts`; the MSIS SLAM stage otherwise)."""
    return pipelines.for_demo(scn) is MAGNETIC


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


def _print_magnetic(
    name: str, counters: dict[str, Any], err: dict[str, float] | None,
    dr: dict[str, float] | None,
) -> None:
    """The magnetic stage's counters and its error against the truth beside dead reckoning's."""
    st = counters["stage"]
    print(f"magnetic stage: {st['mag']} magnetometer samples, {st['acoustic']} acoustic fixes, "
          f"{st['observations']} beacon observations, {counters['landmarks']} beacons mapped, "
          f"{st['bad_payloads']} bad payloads")  # fmt: skip
    _print_vs_truth(name, err, "not enough poses or truth to compare")
    _print_gain(name, err, dr)


def _print_gain(name: str, err: dict[str, float] | None, dr: dict[str, float] | None) -> None:
    """The SLAM estimate against dead reckoning: RMSE and final error ratios (< 1: SLAM
    better)."""
    if err is None or dr is None or not dr["rmse_m"] or not dr["final_m"]:
        return
    rmse, final = err["rmse_m"] / dr["rmse_m"], err["final_m"] / dr["final_m"]
    print(f"  dead reckoning: RMSE/distance x 100 {dr['rmse_pct_distance']:.3f} %, final "
          f"{dr['final_m']:.2f} m; {name} / dead reckoning: RMSE {rmse:.2f}, "
          f"final {final:.2f}")  # fmt: skip


class _Beacons(TypedDict, total=False):
    landmarks: list[list[float]]  # the magnetic beacons, [x, y] m
    acoustic_beacon: list[float]  # [x, y] m


def _true_beacons(scn: Scenario) -> _Beacons:
    """The scenario's magnetic beacons (``landmarks``, [x, y] m) and acoustic beacon
    (``acoustic_beacon``) for ``truth/map`` (nothing without beacons)."""
    out: _Beacons = {}
    if scn.magnetic_beacons:
        out["landmarks"] = [[b.x, b.y] for b in scn.magnetic_beacons]
    if scn.acoustic_beacon is not None:
        out["acoustic_beacon"] = [scn.acoustic_beacon.x, scn.acoustic_beacon.y]
    return out
