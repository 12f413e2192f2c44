"""``auvgw demo``: the whole vehicle on a desk, on embedded defaults.

Starts the emulated vehicle (``auvgw sim`` on a shipped scenario, in its own process, every device
on its own virtual port), then in this process the gateway (embedded Zenoh peer), the navigation
fusion, the SLAM stage where one is installed, and the Rerun recording; runs a few minutes of
vehicle time faster than real time; writes ``demo.rrd`` and prints a summary: messages per device,
errors, and navigation error against ground truth.

Time: the emulators run ``speed`` times faster than the host clock, so the device clocks advance
``speed`` vehicle seconds per host second. The stages here are fed a *vehicle-paced* receive time
(``t0 + (t_recv - t0) * speed``, where ``t0`` is the host instant of vehicle time 0 estimated from
the first INS sample), so every device clock keeps a constant offset to it, exactly as on a real
vehicle at speed 1.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.bus import Keys, encode_envelope, open_session
from auvgw.cli import UserError
from auvgw.config.bus import BusConfig
from auvgw.config.gateway import ConfigError, load_gateway_config
from auvgw.config.scenario import ScenarioError, load_scenario
from auvgw.paths import config_file

DEFAULT_SCENARIO = "harbour"
#: RMSE / distance x 100 of VB-AUFastSLAM in the sea trial of Mu et al. 2022 (INS + DVL + MSIS)
VB_PAPER_RMSE_PCT = 0.742


def register(sub: Any) -> None:
    p = sub.add_parser(
        "demo",
        help="run the emulated vehicle, gateway, fusion, SLAM and Rerun recording (main job)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        help="shipped scenario name (harbour, survey, beacons) or a scenario JSON file",
    )
    p.add_argument("--duration", type=float, default=180.0, help="vehicle seconds (default 180)")
    p.add_argument("--speed", type=float, default=2.0, help="x real time (default 2)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--rrd", type=Path, default=None, help="Rerun file (default OUT/demo.rrd)")
    p.add_argument("--connect", default=None, help="also stream to a Rerun viewer at this URL")
    p.add_argument("--no-viz", action="store_true", help="no Rerun recording")
    p.add_argument("--no-slam", action="store_true", help="no SLAM stage")
    p.set_defaults(func=run)


def _scenario_path(name: str) -> Path:
    p = Path(name)
    if p.suffix == ".json" or p.exists():
        return p
    shipped = config_file(f"scenarios/{name}.json")
    if not shipped.is_file():
        raise UserError(f"--scenario {name}: not a file and not a shipped scenario")
    return shipped


def _demo_scenario(src: Path, out: Path) -> Path:
    """The scenario with the INS on serial only: python-can's slcan reader handles ~1400 CAN
    frames/s here, and the HN-100's 800 frames/s x speed would overrun it (the CAN form of the
    INS is exercised by the tests; the magnetometer keeps its CAN form)."""
    try:
        scn = load_scenario(src)
    except ScenarioError as exc:
        raise UserError(str(exc)) from exc
    data = json.loads(src.read_text())
    devices = data.setdefault("devices", {})
    ins = devices.setdefault("ins", {})
    ins.setdefault("options", {})["can"] = False
    # relative file references stay valid: resolve them against the original scenario
    for section, key in (("features", "points_file"), ("vehicle", "waypoints_file")):
        ref = data.get(section, {}).get(key)
        if ref and not str(ref).startswith("shared:") and not Path(ref).is_absolute():
            data[section][key] = str((src.parent / ref).resolve())
    path = out / f"{scn.name}-demo.json"
    path.write_text(json.dumps(data, indent=1))
    return path


@dataclass
class _VehicleClock:
    """Host receive time -> vehicle-paced time (see the module docstring), ns."""

    speed: float
    t0_ns: int | None = None

    def anchor(self, t_recv_ns: int, vehicle_s: float) -> None:
        if self.t0_ns is None:
            self.t0_ns = t_recv_ns - int(vehicle_s / self.speed * 1e9)

    def __call__(self, t_recv_ns: int) -> int:
        if self.t0_ns is None:
            return t_recv_ns
        return self.t0_ns + int((t_recv_ns - self.t0_ns) * self.speed)

    def vehicle_s(self, t_s: float) -> float:
        """Vehicle seconds of a vehicle-paced time in seconds."""
        assert self.t0_ns is not None
        return t_s - self.t0_ns / 1e9


@dataclass
class _Track:
    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)

    def add(self, t: float, x: float, y: float) -> None:
        self.t.append(t)
        self.x.append(x)
        self.y.append(y)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.asarray(self.t), np.asarray(self.x), np.asarray(self.y)


def _path_error(est: _Track, truth: _Track) -> dict[str, float] | None:
    """Horizontal error of ``est`` against ``truth`` (interpolated at the estimate's times)."""
    te, xe, ye = est.arrays()
    tt, xt, yt = truth.arrays()
    if len(te) < 2 or len(tt) < 2:
        return None
    keep = (te >= tt[0]) & (te <= tt[-1])
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
        "distance_m": dist,
        "rmse_m": rmse,
        "rmse_x_m": float(np.sqrt(np.mean(ex**2))),
        "rmse_y_m": float(np.sqrt(np.mean(ey**2))),
        "final_m": float(err[-1]),
        "rmse_pct_distance": 100.0 * rmse / dist if dist > 0 else math.nan,
    }


class _TruthTail:
    """Follows the simulator's truth log (JSON lines), feeding each sample to ``on_sample``."""

    def __init__(self, path: Path, on_sample: Any) -> None:
        self.path = path
        self.on_sample = on_sample
        self._pos = 0
        self._partial = ""

    def poll(self) -> None:
        if not self.path.is_file():
            return
        with open(self.path) as fh:
            fh.seek(self._pos)
            data = fh.read()
            self._pos = fh.tell()
        text = self._partial + data
        lines = text.split("\n")
        self._partial = lines.pop()
        for line in lines:
            if line.strip():
                self.on_sample(json.loads(line))


def _wait_for(path: Path, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.is_file():
        if proc.poll() is not None:
            raise UserError(f"the emulated vehicle stopped early (exit {proc.returncode})")
        if time.monotonic() > deadline:
            raise UserError(f"the emulated vehicle wrote no {path.name} in {timeout_s:.0f} s")
        time.sleep(0.1)


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    sim_dir = out / "sim"
    for stale in (sim_dir / "gateway.toml", sim_dir / "truth.jsonl"):
        stale.unlink(missing_ok=True)
    scenario = _demo_scenario(_scenario_path(args.scenario), out)
    rrd = None if args.no_viz else (args.rrd or out / "demo.rrd")
    speed = float(args.speed)
    if speed <= 0:
        raise UserError("--speed must be > 0 (the gateway reads the devices in real time)")

    print(f"auvgw demo: scenario {scenario.name}, {args.duration:.0f} s of vehicle time at "
          f"{speed:g}x real time", flush=True)  # fmt: skip
    sim_log = open(out / "sim.log", "wb")  # noqa: SIM115 (closed in finally)
    sim = subprocess.Popen(
        [sys.executable, "-m", "auvgw", "sim", "--scenario", str(scenario), "--speed", str(speed),
         "--duration", str(args.duration), "--out", str(sim_dir)],
        stdout=sim_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        _wait_for(sim_dir / "gateway.toml", sim, 60.0)
        return _run_stages(args, sim, sim_dir, scenario, rrd, speed)
    finally:
        if sim.poll() is None:
            sim.send_signal(signal.SIGINT)
            try:
                sim.wait(20)
            except subprocess.TimeoutExpired:
                sim.kill()
        sim_log.close()


def _run_stages(
    args: argparse.Namespace,
    sim: subprocess.Popen[bytes],
    sim_dir: Path,
    scenario: Path,
    rrd: Path | None,
    speed: float,
) -> int:
    from auvgw.fusion.config import FusionConfig, InitialState
    from auvgw.gateway import Gateway
    from auvgw.stages.fusion import FusionStage, FusionStageConfig
    from auvgw.stages.slam import SlamStage, SlamStageConfig

    try:
        gw_cfg = load_gateway_config(sim_dir / "gateway.toml")
    except ConfigError as exc:
        raise UserError(str(exc)) from exc
    keys = Keys(gw_cfg.vehicle)
    clock = _VehicleClock(speed)
    truth, dead_reckoning, slam_track = _Track(), _Track(), _Track()
    lock = threading.Lock()
    scn = load_scenario(scenario)

    session = open_session(BusConfig())
    viz = None
    if rrd is not None or args.connect:
        from auvgw.viz.stage import open_viz

        viz = open_viz(session, gw_cfg.vehicle, rrd=rrd, connect=args.connect,
                       sections=("slam", "status"))  # fmt: skip

    def on_slam(key: str, payload: bytes, t_ns: int) -> None:
        if key.endswith("/pose"):
            p = json.loads(payload)
            with lock:
                slam_track.add(clock.vehicle_s(p["t"]), p["x"], p["y"])
        if viz is not None:
            viz.stage.handle_sample(key, payload, t_ns)

    # SLAM on the MSIS point features and the fusion odometry, fed in-process (publishes on
    # auv/<v>/slam/<pipeline>/{pose,landmarks} too)
    msis = [n for n, d in gw_cfg.devices.items() if d.format == "seanet" and d.enabled]
    slam = (
        None
        if args.no_slam
        else SlamStage(
            SlamStageConfig(
                vehicle=gw_cfg.vehicle,
                msis_device=msis[0] if msis else None,
                sound_speed_mps=scn.sound_speed_mps,
                target_radius_m=scn.features.point_radius_m,
            ),
            session=session,
            on_publish=on_slam,
        )
    )
    if slam is not None:
        slam.start(subscribe=False)

    def on_odometry(o: Any) -> None:
        with lock:
            dead_reckoning.add(clock.vehicle_s(o.t), o.x, o.y)
        if viz is not None:
            payload, _ = encode_envelope(o, "fusion", int(o.t * 1e9), 0)
            viz.stage.handle_sample(keys.odometry(), payload, int(o.t * 1e9))
        if slam is not None:
            slam.post_odometry(o)

    fusion_box: list[Any] = []

    def start_fusion(t_vehicle: float) -> Any:
        """Dead reckoning starts at the first INS sample from the true position then (what a
        GNSS fix at the surface gives a real vehicle); the emulated INS heading noise is white,
        hence tau = 0."""
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
        filt = FusionConfig(
            initial=InitialState(
                position_m=(x0, y0, scn.vehicle.depth_m), position_sigma_m=(0.5, 0.5, 0.5)
            ),
            heading_error_tau_s=0.0,
            pitch_error_tau_s=0.0,
        )
        cfg = FusionStageConfig(
            vehicle=gw_cfg.vehicle, ins_device="ins", dvl_device="dvl", filter=filt
        )
        stage = FusionStage(cfg, session=session, on_odometry=on_odometry)
        stage.start(subscribe=False)  # fed in-process, publishes odometry and status
        return stage

    ins_span: list[float] = []  # device time of the first and the latest INS sample, s

    def on_message(device: str, t_recv_ns: int, msg: Any) -> None:
        if device == "ins" and hasattr(msg, "time"):
            ins_span[1:] = [float(msg.time)]
            if not fusion_box:
                ins_span[:] = [float(msg.time), float(msg.time)]
                clock.anchor(t_recv_ns, float(msg.time))
                fusion_box.append(start_fusion(float(msg.time)))
        t = clock(t_recv_ns)
        if fusion_box:
            fusion_box[0].feed(device, t, msg)
        if slam is not None:
            slam.post(device, t, msg)
        if viz is not None:
            viz.on_message(device, t, msg)

    truth_pub = session.declare_publisher(keys.truth("pose"))

    def on_truth(sample: dict[str, Any]) -> None:
        with lock:
            truth.add(sample["t"], sample["x"], sample["y"])
        body = json.dumps(sample).encode()
        truth_pub.put(body)
        if viz is not None and clock.t0_ns is not None:
            viz.stage.handle_sample(keys.truth("pose"), body, clock.t0_ns + int(sample["t"] * 1e9))

    tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
    gateway = Gateway(gw_cfg, session=session, on_message=on_message)
    if viz is not None:
        _log_true_map(viz, keys, scenario)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    t_start = time.monotonic()
    gateway.start()
    try:
        last_print = 0.0
        while sim.poll() is None and not stop.is_set():
            if clock.t0_ns is not None:
                tail.poll()
            stop.wait(0.2)
            now = time.monotonic()
            if now - last_print > 5.0:
                last_print = now
                vt = (time.time_ns() - clock.t0_ns) * speed / 1e9 if clock.t0_ns else 0.0
                print(f"  vehicle t = {vt:6.1f} s / {args.duration:.0f} s", flush=True)
        # the emulators closed their ports: what follows is shutdown, not an outage
        logging.getLogger("auvgw.gateway").setLevel(logging.ERROR)
        tail.poll()
    finally:
        status = gateway.status()
        gateway.stop()
        fusion_counters = None
        if fusion_box:
            fusion_box[0].stop(flush=True)
            fusion_counters = fusion_box[0].counters()
        slam_counters = None
        if slam is not None:
            slam.stop(flush=True)
            slam_counters = slam.counters()
        if viz is not None:
            viz.close()
        session.close()
    wall = time.monotonic() - t_start
    nav = _path_error(dead_reckoning, truth)
    slam_err = _path_error(slam_track, truth)
    _print_summary(status, fusion_counters, nav, rrd, wall)
    navigation: dict[str, Any] = {"dead_reckoning": nav}
    if slam is not None and slam_counters is not None:
        _print_slam(slam.config.display_name, slam_counters, slam_err)
        navigation.update(slam=slam_err, slam_algorithm=slam.config.display_name,
                          paper_rmse_pct_distance=VB_PAPER_RMSE_PCT)  # fmt: skip
    summary = {"devices": status["devices"], "fusion": fusion_counters, "slam": slam_counters,
               "navigation": navigation,
               "rrd": str(rrd) if rrd else None, "wall_s": wall, "speed": speed,
               "ins_time_span_s": ins_span[1] - ins_span[0] if ins_span else 0.0}  # fmt: skip
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return 0


def _log_true_map(viz: Any, keys: Keys, scenario: Path) -> None:
    """The scenario's true point and line features, once, on ``truth/map``."""
    scn = load_scenario(scenario)
    lines = [
        {"p0": [x1, y1], "p1": [x2, y2],
         "rho": abs(x1 * (y2 - y1) - y1 * (x2 - x1)) / max(math.hypot(x2 - x1, y2 - y1), 1e-9),
         "theta": math.atan2(-(x2 - x1), y2 - y1)}
        for x1, y1, x2, y2 in scn.features.lines
    ]  # fmt: skip
    body = {"t": 0.0, "landmarks": [list(p) for p in scn.point_features()], "lines": lines}
    viz.stage.handle_sample(keys.truth("map"), json.dumps(body).encode(), time.time_ns())


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
            f"dead reckoning vs truth over {err['distance_m']:.0f} m: RMSE {err['rmse_m']:.2f} m "
            f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
            f"RMSE/distance {err['rmse_pct_distance']:.3f} %"
        )
    if rrd is not None:
        size = rrd.stat().st_size / 1e6 if rrd.is_file() else 0.0
        print(f"Rerun recording: {rrd} ({size:.1f} MB) - open it with: rerun {rrd}")
    print(f"wall time {wall_s:.0f} s")


def _print_slam(name: str, counters: dict[str, Any], err: dict[str, float] | None) -> None:
    st = counters["stage"]
    print(f"slam: {st['pings']} scan lines, {st['point_features']} point and "
          f"{st['line_features']} line features, {st['updates']} updates, "
          f"{counters['landmarks']} landmarks")  # fmt: skip
    if err is None:
        print(f"SLAM ({name}) vs truth: not enough SLAM poses or truth to compare")
        return
    print(
        f"SLAM ({name}) vs truth over {err['distance_m']:.0f} m: RMSE {err['rmse_m']:.2f} m "
        f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
        f"RMSE/distance x 100 {err['rmse_pct_distance']:.3f} % "
        f"(VB paper sea trial: {VB_PAPER_RMSE_PCT} %)"
    )
