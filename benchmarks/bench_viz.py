"""Cost of Rerun logging: CPU per second of vehicle time and .rrd size per minute of vehicle time.

    .venv/bin/python benchmarks/bench_viz.py [--seconds 60] [--runs 3]

The synthetic run of :mod:`auvgw.viz.synthetic` (device rates: INS 100 Hz, DVL 5 Hz, MSIS 30
pings/s of 300 bins, multibeam 5 Hz x 256 beams, magnetometer 20 Hz, truth at 100 Hz, dead
reckoning 10 Hz, one SLAM pipeline at 2 Hz with 12 landmarks, 4 lines and 100 particles, health
of 5 devices at 1 Hz) is generated first; only the logger calls are timed. Each row logs one
group of streams (or all of them) into a fresh ``.rrd`` through :class:`RerunLogger`:

* ``caller us/call``: wall time per call in the caller (what the gateway's thread pays);
* ``CPU ms/s``: process CPU time (caller + logging thread + Rerun's encoder and file threads)
  from the first call to the end of ``close()``, per second of vehicle time;
* ``MB/min``: the ``.rrd`` file size per minute of vehicle time (blueprint included; the empty
  recording's size is shown on its own row).

The reference, measured in the same run, logs the INS row's content naively (one ``rr.log`` per
series sample, one per 20 Hz transform, no batching) so the batched row has a ratio to it.
The data are fed as fast as the logger takes them; flushing follows device time, so the
chunking, and therefore the file, is the same as when the data arrive in real time. Medians of
``--runs`` interleaved rounds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from auvgw.ground.paths import shared_dir
from auvgw.viz.logger import RerunLogger, VizOptions, attitude_quaternion
from auvgw.viz.synthetic import synthetic_calls

GROUPS: dict[str, tuple[str, ...]] = {
    "INS 100 Hz (attitude series + transform)": ("attitude",),
    "DVL 5 Hz (velocity, altitude, lock)": ("dvl",),
    "MSIS 30 pings/s x 300 bins (fan)": ("msis_ping",),
    "multibeam 5 Hz x 256 beams (+ grid)": ("swath",),
    "magnetometer 20 Hz (series + arrow)": ("magnetometer",),
    "trajectories + SLAM map (2 Hz)": ("trajectory", "landmarks", "lines", "particles"),
    "health 5 devices 1 Hz": ("health", "event"),
}


def _run_logger(calls: Sequence[tuple[str, tuple, dict]], path: Path, opts: VizOptions) -> dict:
    c0, w0 = time.process_time(), time.perf_counter()
    logger = RerunLogger(rrd=path, options=opts)
    w1 = time.perf_counter()
    for name, args, kw in calls:
        getattr(logger, name)(*args, **kw)
    w2 = time.perf_counter()
    logger.close()
    cpu = time.process_time() - c0
    st = logger.stats()
    assert st.dropped == 0 and st.errors == 0, st
    return {
        "caller_us": (w2 - w1) / max(1, len(calls)) * 1e6,
        "cpu_s": cpu,
        "wall_s": time.perf_counter() - w0,
        "bytes": path.stat().st_size,
    }


def _run_naive_ins(calls: Sequence[tuple[str, tuple, dict]], path: Path) -> dict:
    """Reference: the same content as the logger's INS row (series at 100 Hz, transform at
    20 Hz) with one rr.log per row, no batching."""
    c0, w0 = time.process_time(), time.perf_counter()
    rec = rr.RecordingStream("auvgw-bench", recording_id=f"naive-{time.time_ns()}")
    rec.save(str(path))
    w1 = time.perf_counter()
    every = round(100.0 / VizOptions().vehicle_pose_hz)
    for i, (_, (t, roll, pitch, heading), _) in enumerate(calls):
        rec.set_time("sensor_time", timestamp=t)
        rec.log("ins/attitude", rr.Scalars(np.degrees([roll, pitch, heading])))
        if i % every == 0:
            q = attitude_quaternion(roll, pitch, heading)
            rec.log("world/vehicle", rr.Transform3D(quaternion=q))
    w2 = time.perf_counter()
    rec.flush()
    rec.disconnect()
    return {
        "caller_us": (w2 - w1) / max(1, len(calls)) * 1e6,
        "cpu_s": time.process_time() - c0,
        "wall_s": time.perf_counter() - w0,
        "bytes": path.stat().st_size,
    }


def _stage_messages() -> list[tuple[str, float, str, bytes]]:
    """(label, rate Hz, key, payload) of one realistic bus message per device."""
    import json
    import math

    from auvgw.bus import encode_envelope
    from auvgw.drivers import hn100, kongsberg, ms3a, pd0, seanet
    from auvgw.fusion import Odometry
    from auvgw.health import DeviceHealth

    t = 1_700_000_000.0

    def env(msg: object, dev: str) -> bytes:
        return encode_envelope(msg, dev, int(t * 1e9), 1)[0]

    across = np.linspace(-55.0, 55.0, 256)
    xyz = kongsberg.make_xyz88(time=t, depth=10 + 0.1 * np.abs(across), across=across,
                               along=np.zeros(256), transducer_depth=20.0)  # fmt: skip
    bins = (np.arange(300) % 97).astype(np.uint8)
    ins = hn100.Hn100Nav(
        seq=1, status=hn100.CODEC.status_word(aligned=True, gnss_aided=False, dvl_aided=True,
                                              error=False),
        time=12.5, roll=0.1, pitch=-0.05, heading=1.0, rate_x=0.0, rate_y=0.0, rate_z=0.01,
        accel_x=0.0, accel_y=0.0, accel_z=-9.81, vel_n=1.0, vel_e=0.2, vel_d=0.0,
        latitude=0.7, longitude=0.1, depth=20.0,
    )  # fmt: skip
    odo = Odometry(
        t=1.0, x=1.0, y=2.0, z=20.0, roll=0.0, pitch=0.0, heading=0.5,
        velocity_ned=(1.0, 0.0, 0.0), velocity_body=(1.0, 0.0, 0.0), angular_rate=(0, 0, 0),
        covariance=np.eye(8), bottom_lock=True, coasting=False, dvl_age_s=0.1, depth_age_s=0.1,
        ins_gap=False, increment=None,
    )  # fmt: skip
    health = DeviceHealth("dvl", "pd0")
    health.set_connected(True)
    out = [
        ("HN-100 Hn100Nav", 100.0, "auv/auv1/sensor/ins/ins", env(ins, "ins")),
        ("SeaNet mtHeadData 300 bins", 30.0, "auv/auv1/sensor/msis/headdata",
         env(seanet.head_data(bins, math.radians(30)), "msis")),
        ("Kongsberg XYZ88 256 beams", 5.0, "auv/auv1/sensor/mbes/xyz88", env(xyz, "mbes")),
        ("MS3A Ms3aSample", 20.0, "auv/auv1/sensor/mag/magnetometer",
         env(ms3a.Ms3aSample(counter=1, bx=2e4, by=-1e3, bz=4.4e4), "mag")),
        ("fusion Odometry", 10.0, "auv/auv1/nav/odometry", env(odo, "fusion")),
        ("gateway DeviceStatus x 5 devices", 5.0, "auv/auv1/status/dvl",
         json.dumps(health.snapshot()).encode()),
    ]  # fmt: skip
    root = shared_dir()
    if root is not None and (root / "data/pd0/RDI_withBT.000").is_file():
        frames, _ = pd0.FORMAT.frames_of_file(root / "data/pd0/RDI_withBT.000")
        ens = [pd0.FORMAT.decode(f.data)[0] for f in frames][507]
        out.insert(3, ("PD0 Ensemble (Workhorse, 17 cells)", 5.0,
                       "auv/auv1/sensor/dvl/ensemble", env(ens, "dvl")))  # fmt: skip
    return out


def _bench_stage(runs: int) -> None:
    """Per message type: payload size and the stage's mapping time (JSON -> logger call)."""
    from auvgw.viz.stage import VizStage

    msgs = _stage_messages()
    n = 300
    with tempfile.TemporaryDirectory() as tmp:
        # the logging thread starts only at close: the timing is the mapping thread's alone
        logger = RerunLogger(
            rrd=Path(tmp) / "stage.rrd", options=VizOptions(queue_size=10**6), autostart=False
        )
        stage = VizStage(logger)
        rows = []
        for label, rate, key, payload in msgs:
            per: list[float] = []
            for _ in range(runs):
                c0 = time.process_time()
                for _ in range(n):
                    assert stage.handle_sample(key, payload) == "logged"
                per.append((time.process_time() - c0) / n)
            rows.append((label, rate, len(payload), statistics.median(per)))
        logger.close()
    print()
    print("bus stage (JSON envelope -> typed message -> logger call; logging not included):")
    head = f"{'message':38s} {'rate Hz':>8s} {'bytes':>7s} {'us/msg':>8s} {'CPU ms/s':>9s}"
    print(head)
    print("-" * len(head))
    total = 0.0
    for label, rate, size, sec in rows:
        total += sec * rate * 1e3
        print(f"{label:38s} {rate:8.0f} {size:7d} {sec * 1e6:8.1f} {sec * rate * 1e3:9.2f}")
    print(f"{'total':38s} {'':8s} {'':7s} {'':8s} {total:9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="vehicle time to log (s)")
    ap.add_argument("--runs", type=int, default=3, help="interleaved rounds (median shown)")
    a = ap.parse_args()
    seconds = a.seconds
    t = time.perf_counter()
    calls = synthetic_calls(seconds)
    gen = time.perf_counter() - t
    print(
        f"synthetic run: {seconds:.0f} s of vehicle time, {len(calls)} logger calls "
        f"(generated in {gen:.1f} s, not timed); median of {a.runs} runs"
    )
    big = VizOptions(queue_size=len(calls) + 16)
    cases: list[tuple[str, int, Callable[[Path], dict]]] = []
    for label, names in GROUPS.items():
        sub = [c for c in calls if c[0] in names]
        cases.append((label, len(sub), lambda p, sub=sub: _run_logger(sub, p, big)))
    cases.append(("ALL devices, lossless fan", len(calls), lambda p: _run_logger(calls, p, big)))
    jpeg = VizOptions(queue_size=len(calls) + 16, fan_jpeg_quality=85)
    cases.append(
        ("ALL devices, JPEG fan (q 85)", len(calls), lambda p: _run_logger(calls, p, jpeg))
    )
    cases.append(("empty recording (layout only)", 0, lambda p: _run_logger([], p, big)))
    ins = [c for c in calls if c[0] == "attitude"]
    cases.append(
        ("reference: INS, one rr.log per sample", len(ins), lambda p: _run_naive_ins(ins, p))
    )
    results: dict[str, list[dict]] = {label: [] for label, _, _ in cases}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.runs):
            for i, (label, _, fn) in enumerate(cases):
                results[label].append(fn(Path(tmp) / f"case{i}-{r}.rrd"))
    med = {k: {f: statistics.median(x[f] for x in v) for f in v[0]} for k, v in results.items()}
    head = f"{'stream':44s} {'calls/s':>8s} {'caller us/call':>15s} {'CPU ms/s':>9s} {'MB/min':>8s}"
    print()
    print(head)
    print("-" * len(head))
    for label, n, _ in cases:
        m = med[label]
        rate = n / seconds
        cpu_ms = m["cpu_s"] / seconds * 1e3
        mb_min = m["bytes"] / 1e6 / seconds * 60
        caller = f"{m['caller_us']:.1f}" if n else "-"
        print(f"{label:44s} {rate:8.0f} {caller:>15s} {cpu_ms:9.1f} {mb_min:8.2f}")
    ins_label = next(iter(GROUPS))
    ratio = med["reference: INS, one rr.log per sample"]["cpu_s"] / med[ins_label]["cpu_s"]
    print()
    print(f"batched INS vs one rr.log per sample: {ratio:.1f}x less CPU")
    total = med["ALL devices, lossless fan"]
    print(f"all devices: {total['cpu_s'] / seconds * 100:.1f} % of one core; logging "
          f"{seconds:.0f} s of vehicle time took {total['wall_s']:.1f} s wall "
          f"({seconds / total['wall_s']:.0f}x real time); cores: {os.cpu_count()}")  # fmt: skip
    _bench_stage(a.runs)


if __name__ == "__main__":
    main()
