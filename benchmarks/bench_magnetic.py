"""Speed of the magnetic-beacon chain (demodulation + MLP + EKF) and the online stage's latency on
the bus, in one run, printed as one table.

    nice -n 10 .venv/bin/python benchmarks/bench_magnetic.py [--repeat 3] [--max-steps N]
        [--latency-s 60] [--latency-speed 1]

1. **Offline chain** (the evaluation's ``mlp`` track on ``config/scenarios/beacons_amb.json``,
   2 loops, ~1356 s of vehicle time): 20 Hz MS3A samples of every beacon, rotated to NED,
   demodulated on the six channels, gated, ranged by the shipped MLP, then each filter (AMB-SLAM,
   MB-SLAM, dead reckoning). Median wall seconds over ``--repeat`` and the real-time factor
   (vehicle time / seconds) per stage and for the whole chain (demodulation + MLP + AMB-SLAM).
   Bar (issue 15): >= 100x real time.
2. **Online stage in process**: the same kind of run as the stage's inputs
   (:mod:`auvgw.slam.magnetic.stream`: 40 Hz odometry, 20 Hz MS3A samples, acoustic replies) fed
   to :class:`~auvgw.stages.magnetic.MagneticStage` as fast as it takes them (attitude
   interpolation, odometry composition, demodulation, MLP, EKF, pose and map publication).
3. **Latency on the bus**: the stage as its own process (``auvgw slam run --pipeline magnetic``);
   this process publishes the odometry and MS3A envelopes (and acoustic replies) paced at
   ``--latency-speed`` x real time for ``--latency-s`` s of vehicle time (odometry first, so the
   stage never waits for it), and subscribes to the poses. Each pose names the newest
   magnetometer sample in it (``t_mag``): latency = the pose's arrival - that sample's put, host
   clock, for every pose a sample caused. p50 / p99 / max; bar (issue 15): p99 < 200 ms (one
   observation period).
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.slam.magnetic.evaluation import Variant, prepare, run_filter
from auvgw.slam.magnetic.stream import StageInputs, stage_inputs

SCENARIO = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "beacons_amb.json"
BAR_RT = 100.0
BAR_P99_MS = 200.0
T = TypeVar("T")
T0 = 1000.0  # input clock of the latency run, s (f x T0 integer: the beacons' phase at 0)


Timed = tuple[float, float]  # (wall s, processor s)


def _cpu_share(fn: Callable[[], T]) -> tuple[T, float]:
    """``fn()`` and the share of the wall time this process ran (processor / wall s)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, (time.process_time() - c) / max(time.perf_counter() - w, 1e-9)


def _median(xs: list[Timed]) -> Timed:
    return statistics.median(x[0] for x in xs), statistics.median(x[1] for x in xs)


def offline_chain(repeat: int, max_steps: int | None) -> tuple[float, Timed, dict[str, Timed]]:
    """``(vehicle s, demod + MLP, {filter: ...})`` as (wall s, processor s), medians over
    ``repeat`` runs (the evaluation times wall seconds; the processor seconds are those times
    the share of the wall clock this process got in that call)."""
    scn = load_scenario(SCENARIO)
    v = Variant(track="mlp")
    chain: list[Timed] = []
    filt: dict[str, list[Timed]] = {k: [] for k in ("amb-slam", "mb-slam", "dr")}
    duration = 0.0
    for i in range(repeat):
        prep, share = _cpu_share(lambda i=i: prepare(scn, v, seed=0, run=i, max_steps=max_steps))
        duration = prep.sim.duration_s
        chain.append((prep.chain_s, prep.chain_s * share))
        for name in filt:
            res, share = _cpu_share(lambda n=name, p=prep, i=i: run_filter(n, p, v, i))
            filt[name].append((res.seconds, res.seconds * share))
        print(f"  offline run {i + 1}/{repeat} done", file=sys.stderr, flush=True)
    return duration, _median(chain), {k: _median(x) for k, x in filt.items()}


def online_in_process(inputs: StageInputs) -> Timed:
    """(wall s, processor s) of the stage over ``inputs``, fed in process."""
    from auvgw.stages.magnetic import MagneticStage, config_from_scenario

    truth0 = tuple(float(x) for x in inputs.prep.sim.truth[0])
    stage = MagneticStage(config_from_scenario(SCENARIO, x0=truth0))
    events = list(inputs.events())
    t, c = time.perf_counter(), time.process_time()
    for kind, args in events:
        getattr(stage, f"feed_{kind}")(*args)
    return time.perf_counter() - t, time.process_time() - c


def bus_latency(inputs: StageInputs, speed: float, log: Path) -> np.ndarray:
    """Latencies (s) from a magnetometer sample's put to the arrival of the pose it caused."""
    import zenoh

    from auvgw.bus import encode_envelope
    from auvgw.drivers.acoustic import AcousticReply
    from auvgw.drivers.ms3a import Ms3aSample
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "auvgw", "slam", "run", "--pipeline", "magnetic",
         "--scenario", str(SCENARIO), "--listen", ep],
        stdout=subprocess.PIPE, stderr=open(log, "w"), text=True,  # noqa: SIM115
    )  # fmt: skip
    put_at: dict[int, float] = {}  # sample stamp ns -> host put time
    lat: list[float] = []
    lock = threading.Lock()

    def on_pose(sample: zenoh.Sample) -> None:
        now = time.perf_counter()
        t_mag = json.loads(sample.payload.to_bytes()).get("t_mag")
        with lock:
            t_put = put_at.pop(round(t_mag * 1e9), None) if t_mag is not None else None
            if t_put is not None:
                lat.append(now - t_put)

    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # "slam running ..." once subscribed
        if "slam running" not in line:
            raise RuntimeError(f"the stage did not start: {line!r} (see {log})")
        conf = zenoh.Config()
        conf.insert_json5("connect/endpoints", json.dumps([ep]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(conf) as s:
            sub = s.declare_subscriber("auv/auv1/slam/magnetic/pose", on_pose)
            odo = s.declare_publisher("auv/auv1/nav/odometry")
            mag = s.declare_publisher("auv/auv1/sensor/ms3a/magnetometer")
            aco = s.declare_publisher("auv/auv1/sensor/acoustic/acousticreply")
            time.sleep(1.0)  # the stage's subscriptions reach this session (liveliness aside)
            start = time.perf_counter()
            n_mag = 0
            for k, (kind, args) in enumerate(inputs.events(t0=T0)):
                t = args[0].t if kind == "odometry" else args[0]
                delay = start + (t - T0) / speed - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                if kind == "odometry":
                    odo.put(encode_envelope(args[0], "fusion", int(t * 1e9), k)[0])
                elif kind == "acoustic":
                    _, r, b, d = args
                    m = AcousticReply(counter=k % 1000, range=r, bearing=b, depression=d, beacon=1)
                    aco.put(encode_envelope(m, "acoustic", int(t * 1e9), k)[0])
                else:
                    bx, by, bz = (float(x) for x in args[1])
                    payload = encode_envelope(Ms3aSample(counter=n_mag % 1000, bx=bx, by=by, bz=bz),
                                              "ms3a", int(t * 1e9), k)[0]  # fmt: skip
                    with lock:
                        put_at[int(t * 1e9)] = time.perf_counter()
                    mag.put(payload)
                    n_mag += 1
                if k % 2000 == 0:
                    print(f"  latency run: t = {t - T0:6.1f} s", file=sys.stderr, flush=True)
            time.sleep(1.0)  # the last poses
            sub.undeclare()
    finally:
        proc.terminate()
        proc.wait(30)
    return np.asarray(lat)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--max-steps", type=int, default=None, help="offline: control steps")
    ap.add_argument("--latency-s", type=float, default=60.0, help="vehicle s on the bus")
    ap.add_argument("--latency-speed", type=float, default=1.0, help="x real time on the bus")
    ap.add_argument("--log", type=Path, default=Path("/tmp/bench_magnetic_stage.log"))
    a = ap.parse_args()

    duration, chain_s, filt = offline_chain(a.repeat, a.max_steps)
    inputs = stage_inputs(SCENARIO, a.max_steps)
    online_s = _median([online_in_process(inputs) for _ in range(a.repeat)])
    lat_inputs = stage_inputs(SCENARIO, int(a.latency_s / inputs.prep.sim.dt))
    lat = bus_latency(lat_inputs, a.latency_speed, a.log)

    total = (chain_s[0] + filt["amb-slam"][0], chain_s[1] + filt["amb-slam"][1])
    rt = duration / total[1]
    print(f"\nbeacons_amb: offline {duration:.0f} s of vehicle time (mlp track), online stage "
          f"{inputs.duration_s:.0f} s, median of {a.repeat}; bus latency over "
          f"{lat_inputs.duration_s:.0f} s at {a.latency_speed:g}x")  # fmt: skip
    print("real-time factor = vehicle s / processor s of this process (wall: / wall s, which on a "
          "busy machine counts the others' time too)")  # fmt: skip
    print(f"{'measure':44s} {'value':>14s} {'bar':>10s} {'wall':>8s}")

    def row(name: str, d: float, t: Timed, bar: str = "", ok: bool | None = None) -> None:
        verdict = "" if ok is None else ("MET" if ok else "NOT MET")
        print(f"{name:44s} {d / t[1]:13.0f}x {bar:>10s} {d / t[0]:7.0f}x  {verdict}")

    row("demodulation + MLP", duration, chain_s)
    for k, t in filt.items():
        row(f"filter {k}", duration, t)
    row("whole chain (demod + MLP + AMB-SLAM)", duration, total, ">= 100x", rt >= BAR_RT)
    row("online stage in process (all of it)", inputs.duration_s, online_s)
    if len(lat):
        p50, p99, mx = (float(np.percentile(lat, q)) * 1e3 for q in (50, 99, 100))
        print(f"{'bus: MS3A sample -> pose, p50 ms':44s} {p50:14.1f}")
        print(f"{'bus: MS3A sample -> pose, p99 ms':44s} {p99:14.1f} {'< 200 ms':>10s}"
              f"  {'MET' if p99 < BAR_P99_MS else 'NOT MET'}")  # fmt: skip
        print(f"{'bus: MS3A sample -> pose, max ms':44s} {mx:14.1f}")
        print(f"{'bus: poses timed':44s} {len(lat):14d}")
    else:
        print("bus: no pose came back (see the stage log)")
    return 0 if len(lat) and np.isfinite(rt) else 1


if __name__ == "__main__":
    raise SystemExit(main())
