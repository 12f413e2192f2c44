"""Vehicle dynamics speed: RK4 steps per second and the real-time factor at dt = 0.01 s.

Wall-clock and CPU-time factors: on the shared machine the wall factor follows the load, the
CPU factor is what one core of it delivers to this process.

    .venv/bin/python benchmarks/bench_dynamics.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import os
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
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            x = d.step(p, x, u, dt, current)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        rows.append((name, n / wall, n * dt / wall, n * dt / cpu))
    base = rows[0][3]
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; dt = {dt} s; bar: 50x; "
          "ratio: CPU factor to the first row's, same run")
    print(f"{'case':28s} {'steps/s':>10s} {'x real (wall)':>14s} {'x real (CPU)':>13s} "
          f"{'ratio':>6s}")
    for name, sps, rtf, cpu_rtf in rows:
        print(f"{name:28s} {sps:10.0f} {rtf:14.1f} {cpu_rtf:13.1f} {cpu_rtf / base:6.2f}")


if __name__ == "__main__":
    main()
