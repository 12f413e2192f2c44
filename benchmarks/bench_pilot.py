"""Closed-loop speed: the autopilot + 6-DOF model against the model alone, in the same run.

    .venv/bin/python benchmarks/bench_pilot.py [--seconds 120] [--repeats 3]

Prints steps/s and the real-time factor at dt = 0.05 s (the closed loop's step) for the model
alone (fixed inputs), the closed loop on truth navigation and on noisy navigation; the ratio
column is each case's time per step over the model alone's (the autopilot's overhead).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from auvgw.control.closed_loop import NavNoise, fly, trimmed_start
from auvgw.control.mission import Mission, lawnmower
from auvgw.sim_devices import dynamics as d

DT = 0.05


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="vehicle seconds per case")
    ap.add_argument("--repeats", type=int, default=3, help="runs per case (median)")
    args = ap.parse_args()
    p = d.load_params()
    m = Mission(lawnmower((0.0, 0.0), 100.0, 20.0, 4, 0.0, 10.0, 1.5), 5.0)
    n = round(args.seconds / DT)
    noise = NavNoise(0.3, 0.05, math.radians(0.5), 0.02, math.radians(0.2))

    def model() -> int:
        x = trimmed_start(m)
        u = np.array([0.0, -0.15, 950.0])
        for _ in range(n):
            x = d.step(p, x, u, DT)
        return n

    def truth() -> int:
        return len(fly(m, p, dt=DT, t_max=args.seconds).t)

    def noisy() -> int:
        return len(fly(m, p, dt=DT, t_max=args.seconds, noise=noise,
                       rng=np.random.default_rng(0)).t)  # fmt: skip

    rows = []
    for name, fn in (("model alone", model), ("closed loop, truth nav", truth),
                     ("closed loop, noisy nav", noisy)):  # fmt: skip
        per_step = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            steps = fn()
            per_step.append((time.perf_counter() - t0) / steps)
        rows.append((name, statistics.median(per_step)))
    ref = rows[0][1]
    print(f"{'case':26s} {'steps/s':>9s} {'x real time':>12s} {'ratio':>6s}  "
          f"(dt = {DT} s, median of {args.repeats})")
    for name, sec in rows:
        print(f"{name:26s} {1 / sec:9.0f} {DT / sec:12.1f} {sec / ref:6.2f}")


if __name__ == "__main__":
    main()
