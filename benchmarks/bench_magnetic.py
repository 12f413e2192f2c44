"""Speed of the magnetic-beacon chain (demodulation + MLP + EKF) as a real-time factor.

    .venv/bin/python benchmarks/bench_magnetic.py [--repeat 3] [--max-steps N]

One run of ``config/scenarios/beacons_amb.json`` (2 loops, ~1356 s of vehicle time) on the
``mlp`` track: 20 Hz MS3A samples of every beacon, rotated to NED, demodulated on the six
channels, gated, ranged by the shipped MLP (``config/magnetic_mlp.npz``), then each filter
(AMB-SLAM, MB-SLAM, dead reckoning) runs on the observations. Reported per stage: median wall
seconds over ``--repeat`` and the real-time factor (vehicle time / seconds), and for the whole
chain (demodulation + MLP + AMB-SLAM). Bar (issue 15): the whole chain >= 100x real time. The
bus latency bar (p99 sample -> pose < 200 ms) needs the online stage, not built yet.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.slam.magnetic.evaluation import Variant, prepare, run_filter

SCENARIO = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "beacons_amb.json"
BAR = 100.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--max-steps", type=int, default=None)
    a = ap.parse_args()
    scn = load_scenario(SCENARIO)
    v = Variant(track="mlp")
    chain, filt = [], {k: [] for k in ("amb-slam", "mb-slam", "dr")}
    duration = 0.0
    for i in range(a.repeat):
        prep = prepare(scn, v, seed=0, run=i, max_steps=a.max_steps)
        duration = prep.sim.duration_s
        chain.append(prep.chain_s)
        for name in filt:
            filt[name].append(run_filter(name, prep, v, i).seconds)
    med = {k: statistics.median(x) for k, x in filt.items()}
    c = statistics.median(chain)
    print(f"beacons_amb, mlp track: {duration:.0f} s of vehicle time, median of {a.repeat}")
    print(f"{'stage':32s} {'seconds':>8s} {'x real time':>12s}")
    print(f"{'demodulation + MLP':32s} {c:8.2f} {duration / c:12.0f}")
    for k, s in med.items():
        print(f"{'filter ' + k:32s} {s:8.2f} {duration / s:12.0f}")
    total = c + med["amb-slam"]
    ok = duration / total >= BAR
    print(f"{'whole chain (demod+MLP+AMB-SLAM)':32s} {total:8.2f} {duration / total:12.0f}"
          f"   bar >= {BAR:.0f}x: {'MET' if ok else 'NOT MET'}")  # fmt: skip
    print(f"ratio AMB-SLAM filter / demod+MLP: {med['amb-slam'] / c:.1f}")
    return 0 if np.isfinite(total) else 1


if __name__ == "__main__":
    raise SystemExit(main())
