"""Vehicle dynamics speed: RK4 steps per second and the real-time factor at dt = 0.01 s.

    .venv/bin/python benchmarks/bench_dynamics.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from auvgw.sim_devices import dynamics as d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per case")
    args = ap.parse_args()
    prestero, fossen = d.load_params(), d.load_params(d.REMUS100_FOSSEN_FILE)
    dt = 0.01
    n = int(args.seconds / dt)
    rows = []
    for name, p, inputs, current in [
        ("cruise 1000 rpm", prestero, [0.0, 0.0, 1000.0], None),
        ("turn 10 deg rudder", prestero, [0.17, 0.0, 1000.0], None),
        ("cruise in 0.3 m/s current", prestero, [0.0, 0.0, 1000.0], np.array([0.3, 0.1, 0.0])),
        ("Fossen set: cruise 1000 rpm", fossen, [0.0, 0.0, 1000.0], None),
        ("Fossen set: turn 10 deg", fossen, [0.17, 0.0, 1000.0], None),
    ]:
        x = np.zeros(12)
        u = np.array(inputs)
        t0 = time.perf_counter()
        for _ in range(n):
            x = d.step(p, x, u, dt, current)
        wall = time.perf_counter() - t0
        rows.append((name, n / wall, n * dt / wall))
    base = rows[0][1]
    print(f"{'case':28s} {'steps/s':>10s} {'x real time':>12s} {'ratio':>6s}  "
          f"(dt = {dt} s, bar: 50x; ratio to the first row, same run)")
    for name, sps, rtf in rows:
        print(f"{name:28s} {sps:10.0f} {rtf:12.1f} {sps / base:6.2f}")


if __name__ == "__main__":
    main()
