"""The online SLAM stage on the emulated harbour route, offline and deterministic: path error of
SLAM against dead reckoning (issue 7: RMSE / distance x 100; the VB paper's sea trial 0.742 %).

The INS and DVL emulators' encoders are called for every tick, their byte streams framed and
decoded by the drivers and fed to the in-process fusion stage (as ``tests/fusion_emulated.py``
and ``benchmarks/bench_fusion_emulated.py``; filter settings of ``auvgw demo``, whose INS
heading-error model follows the scenario); the fusion's odometry is dead reckoning (DR). The MSIS
head emulator (echo model of the scenario's world, its noise and noise bursts) is polled every
``--period`` s with the gateway's head settings (30 m, 300 bins, 1.8 deg steps) and its scan
lines, decoded by the SeaNet driver, go with the odometry to the online landmark pipeline
(:class:`auvgw.slam.landmark.online.LandmarkOnline`, the core of the bus stage, no bus) in
arrival order: odometry after the fusion's lag (0.25 s), a ping when its data would have
arrived.

Prints one row per scenario, filter seed and feature set (``points``: point targets only,
``points+lines``: the walls too, ``use_lines``): DR and SLAM path RMSE, final error and RMSE as
a percentage of the distance, SLAM / DR, the features used and the run time. ``rmse*``: the
same RMSE with the initial heading error removed from both tracks (each rotated about the start
by the odometry's heading error at the first sample: the INS alignment error, which no SLAM
without an absolute reference can observe, as the map is built in the odometry's initial frame).
The header line of each scenario gives that error and the RMSE of a *perfect* SLAM in that
frame (the true track turned by it about the start): what no SLAM run can go below.

Usage::

    nice -n 5 .venv/bin/python benchmarks/bench_slam_online.py \\
        --scenarios config/scenarios/harbour.json config/scenarios/harbour_bursts.json \\
        --duration 600 --seeds 0 1 2 [--features points points+lines] [--json out.json]

A 600 s run takes about a minute per row on one core (the MSIS emulator and the feature
extraction dominate); ``--cache DIR`` keeps the emulated odometry and pings between runs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import pickle
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.commands.demo_parts import _fusion_config
from auvgw.commands.demo_report import Track, path_error
from auvgw.config.scenario import Scenario
from auvgw.drivers import seanet as sn
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.faults import FaultInjector
from auvgw.sim_devices.ins import InsEmulator
from auvgw.sim_devices.msis import MsisHead, make_echo
from auvgw.sim_devices.vehicle import Truth, simulate
from auvgw.sim_devices.world import World
from auvgw.slam.landmark.online import LandmarkOnline, LandmarkOnlineConfig
from auvgw.slam.models import wrap_angle
from auvgw.testing.fusion_emulated import (
    HOST_EPOCH,
    Emulated,
    decode_serial,
    dvl_stream,
    ins_output,
    run_stage,
)

#: the fusion stage's output lag (odometry reaches the SLAM stage this much after its time), s
ODOMETRY_LAG_S = 0.25
FEATURE_SETS = {"points": False, "points+lines": True}


@dataclass
class Emulation:
    """One scenario's emulated data: odometry (fusion output), pings (arrival s, HeadData),
    the truth track and the world."""

    odometry: list[Any]
    pings: list[tuple[float, sn.HeadData]]
    truth: Truth
    world: World
    burst_pings: int


def load(path: str, duration: float) -> Scenario:
    """The scenario file with ``duration`` and the INS / DVL on their binary outputs only."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"cannot read scenario {path}: {exc}") from exc
    data["duration_s"] = duration
    dev = data.setdefault("devices", {})
    dev.setdefault("ins", {}).setdefault("options", {}).update(serial=False, can=False)
    dev.setdefault("dvl", {}).setdefault("options", {}).update(serial=False)
    return Scenario.model_validate(data)


def emulate_odometry(scn: Scenario, world: World, truth: Truth, tmp: Path) -> list[Any]:
    """INS + DVL emulators -> drivers -> fusion stage (the demo's settings): odometry."""
    ctx = SimContext(scn, world, truth, SimClock(0), tmp)
    em = Emulated(scn, truth, ctx, InsEmulator(ctx), DvlEmulator(ctx))
    ins = ins_output(em, 0.0, em.duration)
    dvl = dvl_stream(em, 0.0, em.duration)
    msgs = decode_serial(ins.serial, "hn100", "ins") + decode_serial(dvl, "pd0", "dvl")
    s0 = truth.at(0.0)
    cfg = _fusion_config("auv1", (s0.x, s0.y, s0.z), scn.devices.ins.noise)
    cfg = cfg.model_copy(
        update={"latency_s": {"ins": ins.serial.frame_latency_s, "dvl": dvl.frame_latency_s}}
    )
    out, _ = run_stage(msgs, cfg)
    return out


def emulate_pings(
    scn: Scenario, world: World, truth: Truth, period: float, range_m: float, n_bins: int
) -> tuple[list[tuple[float, sn.HeadData]], int]:
    """The MSIS head polled every ``period`` s: (arrival time s, scan line), burst pings."""
    s = scn.devices.msis
    now = [0.0]
    echo = make_echo(world, lambda: truth.at(now[0]).pose, np.random.default_rng([scn.seed, 11]))
    inj = FaultInjector(s.faults, np.random.default_rng([scn.seed, 12]))
    head = MsisHead(
        echo, sound_speed=world.sound_speed, config_delay_s=0.0,
        range_sigma_m=float(s.noise.get("range_m", 0.0)),
        bearing_sigma_deg=float(s.noise.get("bearing_deg", 0.0)),
        rng=np.random.default_rng([scn.seed, 13]), noise_scale=inj.sigma_multiplier,
    )  # fmt: skip
    head.power_up(0.0)
    cmd = sn.head_command(
        range_m=range_m, n_bins=n_bins, sound_speed=world.sound_speed, step=math.radians(1.8)
    )
    head.feed(sn.encode(cmd), 0.0)
    head.tick(0.0)
    framer = sn.SeaNetFramer(policy="raise")
    poll = sn.encode(sn.send_data(0))
    dur = head.ping_duration_s()
    out = []
    for tp in np.arange(0.5, float(truth.t[-1]), period):
        now[0] = float(tp)
        for f in framer.feed(head.feed(poll, float(tp))):
            for m in sn.decode(f.data):
                if isinstance(m, sn.HeadData):  # arrives after the ping and its transfer
                    out.append((float(tp) + dur + 0.03 * n_bins / 300, m))
    return out, int(head.stats.burst_pings)


def emulate(path: str, a: argparse.Namespace) -> Emulation:
    scn = load(path, a.duration)
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    key = hashlib.sha1(
        json.dumps([Path(path).read_text(), a.duration, a.period, a.range, a.bins]).encode()
    ).hexdigest()[:12]
    cache = Path(a.cache) / f"slam_online_{key}.pkl" if a.cache else None
    if cache is not None and cache.exists():
        odo, pings, bursts = pickle.loads(cache.read_bytes())
    else:
        with tempfile.TemporaryDirectory() as tmp:
            odo = emulate_odometry(scn, world, truth, Path(tmp))
        pings, bursts = emulate_pings(scn, world, truth, a.period, a.range, a.bins)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            cache.write_bytes(pickle.dumps((odo, pings, bursts)))
    return Emulation(odo, pings, truth, world, bursts)


def aligned(track: Track, x0: float, y0: float, e0: float) -> Track:
    """``track`` rotated about ``(x0, y0)`` by ``-e0`` rad (the initial heading error removed)."""
    t, x, y = track.arrays()
    c, s = math.cos(e0), math.sin(e0)
    dx, dy = x - x0, y - y0
    out = Track()
    for ti, xi, yi in zip(t, x0 + c * dx + s * dy, y0 - s * dx + c * dy, strict=True):
        out.add(float(ti), float(xi), float(yi))
    return out


def run_slam(em: Emulation, cfg: LandmarkOnlineConfig) -> LandmarkOnline:
    """Odometry (after the fusion lag) and pings (at arrival) to the pipeline in time order."""
    online = LandmarkOnline(cfg)
    events = [(o.t + ODOMETRY_LAG_S, 0, o) for o in em.odometry]
    events += [(HOST_EPOCH + t, 1, m) for t, m in em.pings]
    events.sort(key=lambda e: (e[0], e[1]))
    for t, kind, m in events:
        if kind == 0:
            online.add_odometry(m)
        else:
            online.add_ping(round(t * 1e9) / 1e9, m)  # the stage's ns stamps
    online.finish()
    return online


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--scenarios",
        nargs="+",
        default=["config/scenarios/harbour.json", "config/scenarios/harbour_bursts.json"],
    )
    ap.add_argument("--duration", type=float, default=600.0, help="vehicle time, s")
    ap.add_argument("--period", type=float, default=0.1, help="MSIS polling period, s")
    ap.add_argument("--range", type=float, default=30.0, help="MSIS range, m")
    ap.add_argument("--bins", type=int, default=300, help="MSIS bins per ping")
    ap.add_argument("--algorithm", default="vb-aufastslam")
    ap.add_argument("--particles", type=int, default=50)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="filter seeds")
    ap.add_argument(
        "--features", nargs="+", choices=sorted(FEATURE_SETS), default=["points", "points+lines"]
    )
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=JSON",
        help="further LandmarkOnlineConfig settings, e.g. line_sigma_rho_m=0.1",
    )
    ap.add_argument("--cache", default="", help="directory for the emulated data")
    ap.add_argument("--json", default="", help="write the rows here")
    a = ap.parse_args()  # fmt: skip
    extra: dict[str, Any] = {}
    for kv in a.set:
        k, sep, v = kv.partition("=")
        if not sep:
            raise SystemExit(f"--set {kv!r}: expected KEY=JSON")
        extra[k] = json.loads(v)
    rows = []
    hdr = (f"{'scenario':<22} {'features':<13} {'seed':>4} {'DR rmse':>8} {'DR fin':>7} "
           f"{'DR %':>6} {'SLAM rmse':>9} {'SLAM fin':>8} {'SLAM %':>6} {'SLAM/DR':>7} "
           f"{'pts':>4} {'line upd':>8} {'walls':>5} {'DR rmse*':>8} {'SLAM rmse*':>10} "
           f"{'s':>5}")  # fmt: skip
    print(hdr)
    print("-" * len(hdr))
    for path in a.scenarios:
        t0 = time.perf_counter()
        em = emulate(path, a)
        name = Path(path).stem
        tt = Track()
        for t, x, y in zip(em.truth.t, em.truth.x, em.truth.y, strict=True):
            tt.add(float(t), float(x), float(y))
        dr = Track()
        for o in em.odometry:
            dr.add(o.t - HOST_EPOCH, o.x, o.y)
        dre = path_error(dr, tt)
        o0 = em.odometry[0]
        e0 = float(wrap_angle(o0.heading - em.truth.at(o0.t - HOST_EPOCH).heading))
        dra = path_error(aligned(dr, o0.x, o0.y, e0), tt)
        floor = path_error(aligned(tt, o0.x, o0.y, -e0), tt)
        print(
            f"# {name}: {len(em.odometry)} odometry, {len(em.pings)} pings ({em.burst_pings} "
            f"in noise bursts), initial heading error {math.degrees(e0):+.2f} deg (perfect SLAM "
            f"in that frame: RMSE {floor['rmse_m']:.2f} m), emulated in "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
        for feats in a.features:
            for seed in a.seeds:
                t1 = time.perf_counter()
                cfg = LandmarkOnlineConfig(
                    algorithm=a.algorithm, sound_speed_mps=em.world.sound_speed,
                    target_radius_m=em.world.point_radius, n_particles=a.particles, seed=seed,
                    use_lines=FEATURE_SETS[feats], **extra,
                )  # fmt: skip
                online = run_slam(em, cfg)
                st = Track()
                for t, x, y, _h in online.track:
                    st.add(t - HOST_EPOCH, x, y)
                se = path_error(st, tt)
                sea = path_error(aligned(st, o0.x, o0.y, e0), tt)
                c = {"stage": asdict(online.stats), **online.summary()}
                row = {"scenario": name, "features": feats, "seed": seed, "dr": dre, "slam": se,
                       "dr_aligned": dra, "slam_aligned": sea, "initial_heading_error_rad": e0,
                       "perfect_slam_rmse_m": floor["rmse_m"],
                       "stage": c["stage"], "landmarks": c["landmarks"],
                       "line_landmarks": c["line_landmarks"],
                       "seconds": time.perf_counter() - t1}  # fmt: skip
                rows.append(row)
                print(f"{name:<22} {feats:<13} {seed:>4} {dre['rmse_m']:>7.2f}m "
                      f"{dre['final_m']:>6.2f}m {dre['rmse_pct_distance']:>6.3f} "
                      f"{se['rmse_m']:>8.2f}m {se['final_m']:>7.2f}m "
                      f"{se['rmse_pct_distance']:>6.3f} {se['rmse_m'] / dre['rmse_m']:>7.2f} "
                      f"{c['stage']['point_features']:>4} {c['stage']['line_updates']:>8} "
                      f"{c['line_landmarks']:>5} {dra['rmse_m']:>7.2f}m {sea['rmse_m']:>9.2f}m "
                      f"{row['seconds']:>5.0f}", flush=True)  # fmt: skip
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
