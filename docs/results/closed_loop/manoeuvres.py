"""REMUS 100 model manoeuvres beside published numbers (prints the table in README.md).

    .venv/bin/python docs/results/closed_loop/manoeuvres.py
"""

from __future__ import annotations

import math

import numpy as np

from auvgw.sim_devices import dynamics as d

DT = 0.02


def run(p: d.VehicleParams, x: np.ndarray, inputs: list[float], seconds: float) -> np.ndarray:
    out = [x]
    for _ in range(int(seconds / DT)):
        x = d.step(p, x, np.array(inputs), DT)
        out.append(x)
    return np.array(out)


def main() -> None:
    p = d.load_params()
    print("speed against shaft speed (60 s from rest, fins 0)")
    for rpm in (500, 1000, 1525):
        xs = run(p, np.zeros(12), [0, 0, rpm], 60)
        last = xs[-500:]
        speed = np.linalg.norm(last[:, :3], axis=1).mean()
        print(f"  {rpm:5d} rpm: |V| = {speed:.2f} m/s, u = {last[-1, 0]:.2f}, roll = "
              f"{math.degrees(last[-1, 9]):.1f} deg, pitch = {math.degrees(last[-1, 10]):.1f} deg, "
              f"yaw rate = {math.degrees(last[-1, 5]):.1f} deg/s")
    start = run(p, np.array([1.5, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.0]), [0, 0, 1000], 1)[-1]
    xs = run(p, start, [math.radians(10), 0, 1000], 120)
    ne = xs[-3000:, 6:8]
    print(f"turn, 10 deg rudder, 1000 rpm: diameter N {np.ptp(ne[:, 0]):.1f} m, "
          f"E {np.ptp(ne[:, 1]):.1f} m, speed {np.linalg.norm(xs[-1, :3]):.2f} m/s")
    xs = run(p, start, [0, math.radians(5), 1000], 10)
    print("pitch after a 5 deg stern-plane step at t=0 (deg, every 1 s):",
          " ".join(f"{math.degrees(t):.1f}" for t in xs[:: int(1 / DT), 10]))


if __name__ == "__main__":
    main()
