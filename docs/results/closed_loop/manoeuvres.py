"""REMUS 100 model manoeuvres beside published numbers (prints the table in README.md).

    .venv/bin/python docs/results/closed_loop/manoeuvres.py
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from auvgw.sim_devices import dynamics as d

DT = 0.02


def run(p: d.VehicleParams, x: np.ndarray, inputs: list[float], seconds: float) -> np.ndarray:
    """Simulate; stops early (and says so) if the vehicle loops past the Euler singularity."""
    out = [x]
    for i in range(int(seconds / DT)):
        try:
            x = d.step(p, x, np.array(inputs), DT)
        except d.PitchSingularityError as exc:
            print(f"    [stopped at t = {i * DT:.1f} s: {exc}]")
            break
        out.append(x)
    return np.array(out)


def linear_check(p: d.VehicleParams, u0: float = 1.5) -> None:
    """Derivatives per u of the model's forces at a straight run, beside Prestero's combined
    table, and the eigenvalues of the linearised sway-yaw and heave-pitch subsystems."""
    q = replace(p, torque_per_thrust=0.0, buoyancy=p.weight)
    rpm = math.sqrt(-q.quad[0] * u0 * u0 / q.thrust_coeff)
    x0 = np.zeros(12)
    x0[0] = u0
    inputs = np.array([0.0, 0.0, rpm])

    def total(nu: np.ndarray) -> np.ndarray:
        return d.forces(q, nu, inputs) - d.coriolis_force(q, nu)

    der = np.zeros((6, 6))
    jac = np.zeros((12, 12))
    for i in range(12):
        e = np.zeros(12)
        e[i] = 1e-6
        jac[:, i] = (d.rhs(q, x0 + e, inputs) - d.rhs(q, x0 - e, inputs)) / 2e-6
        if i < 6:
            der[:, i] = (total(x0[:6] + e[:6]) - total(x0[:6] - e[:6])) / 2e-6 / u0
    m = q.mass
    print(f"linear derivatives per u at u = {u0} m/s (model | Prestero combined, rigid-body "
          "m u r / m u q moved to the right-hand side)")
    for name, val, pub in [
        ("Yv (Yuv)", der[1, 1], -28.6), ("Yr (Yur - m)", der[1, 5], 5.22 - m),
        ("Nv (Nuv)", der[5, 1], -24.0), ("Nr (Nur)", der[5, 5], -2.00),
        ("Zw (Zuw)", der[2, 2], -28.6), ("Zq (Zuq + m)", der[2, 4], -5.22 + m),
        ("Mw (Muw)", der[4, 2], 24.0), ("Mq (Muq)", der[4, 4], -2.00),
    ]:
        print(f"  {name:14s} {val:8.2f} | {pub:8.2f}")
    lat = np.linalg.eigvals(jac[np.ix_([1, 5], [1, 5])])
    lon = np.linalg.eigvals(jac[np.ix_([2, 4, 10], [2, 4, 10])])
    print("  eigenvalues sway-yaw   (1/s):", " ".join(f"{z:.2f}" for z in lat))
    print("  eigenvalues heave-pitch(1/s):", " ".join(f"{z:.2f}" for z in lon))


def main() -> None:
    p = d.load_params()
    linear_check(p)
    straight = replace(p, torque_per_thrust=0.0, buoyancy=p.weight)
    print("speed against shaft speed, symmetric neutral vehicle without propeller torque "
          "(60 s from rest)")
    for rpm in (500, 1000, 1500, 1525):
        xs = run(straight, np.zeros(12), [0, 0, rpm], 60)
        surge_only = rpm * math.sqrt(straight.thrust_coeff / -straight.quad[0])
        print(f"  {rpm:5d} rpm: surge-only steady u = {surge_only:.2f} m/s; simulated u = "
              f"{xs[-1, 0]:.2f} m/s, yaw {math.degrees(xs[-1, 11]):.3f} deg, pitch "
              f"{math.degrees(xs[-1, 10]):.1f} deg, depth {xs[-1, 8]:.1f} m")
    print("speed against shaft speed, full model (B > W, propeller torque; 60 s from rest)")
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
