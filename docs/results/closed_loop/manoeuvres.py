"""REMUS 100 model manoeuvres beside published numbers (prints the tables in README.md).

    .venv/bin/python docs/results/closed_loop/manoeuvres.py

Two published parameter sets: Prestero 2001 (config/vehicles/remus100.toml, open-loop
unstable) and Fossen 2021 (config/vehicles/remus100_fossen.toml, open-loop stable). Each
manoeuvre is printed beside the published figure it can be compared with, the % difference and
a verdict; where no published figure was found, it says so.
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


# (what, value, source): the published figures a manoeuvre can be compared with
PUBLISHED_SPEED = {
    1525: (2.5, "Fossen, MSS remus100.m / PVS remus100.py header: 2.5 m/s at 1525 rpm"),
    1500: (1.5, "Prestero 2001 trim run, 1.5 m/s with Xprop = 3.86 N, at 1500 rpm as cited in "
           "issue 30's first README (the thesis is not in our library to re-read the rpm)"),
}
NOT_FOUND = ("no published figure found (searched: Prestero 2001 ch. 6 shows closed-loop field "
             "runs only; Fossen 2021 / MSS / PVS give no number; Allen et al. 2000, Fodrea 2002, "
             "Hall & Anstee 2011 not readable in our library)")


def verdict(model: float, published: float, calibration: bool = False) -> str:
    diff = 100.0 * (model - published) / published
    if calibration:
        return f"{diff:+.1f} %  calibration (fitted to this point), not a check"
    return f"{diff:+.1f} %  {'within 10 %' if abs(diff) <= 10.0 else 'MISSES (> 10 %)'}"


def settle(p: d.VehicleParams, rpm: float, seconds: float = 80.0) -> np.ndarray:
    return run(p, np.zeros(12), [0, 0, rpm], seconds)[-1]


def turn(p: d.VehicleParams, rudder_deg: float, rpm: float) -> tuple[float, float, float]:
    """Steady turn at a fixed rudder from a settled straight run: (diameter m, speed m/s, yaw
    rate deg/s) over the last 60 s of 180 s."""
    xs = run(p, settle(p, rpm), [math.radians(rudder_deg), 0, rpm], 180)[-int(60 / DT):]
    diameter = 0.5 * (np.ptp(xs[:, 6]) + np.ptp(xs[:, 7]))
    return diameter, float(np.linalg.norm(xs[-1, :3])), math.degrees(float(xs[-1, 5]))


def fossen(p: d.VehicleParams) -> None:
    print("\nFossen 2021 spheroid set (config/vehicles/remus100_fossen.toml), full 6-DOF model")
    print("  speed against shaft speed (80 s from rest, fins at zero; published | model | diff)")
    for rpm in (500, 1000, 1250, 1500, 1525):
        x = settle(p, rpm)
        speed = float(np.linalg.norm(x[:3]))
        line = (f"    {rpm:5d} rpm: U = {speed:.3f} m/s (u {x[0]:.3f}), roll "
                f"{math.degrees(x[9]):.1f} deg, pitch {math.degrees(x[10]):.2f} deg")
        if rpm in PUBLISHED_SPEED:
            pub, src = PUBLISHED_SPEED[rpm]
            line += f"\n           | {pub} m/s ({src}) | {verdict(speed, pub)}"
        print(line)
    print("  steady turn at a fixed rudder (negative: bow to starboard), from a straight run:")
    for rpm in (1000, 1525):
        for rud in (-5.0, -10.0, -15.0, -30.0, 15.0):
            dia, speed, rate = turn(p, rud, rpm)
            print(f"    {rpm:5d} rpm, rudder {rud:+5.1f} deg: diameter {dia:6.1f} m "
                  f"({dia / 1.6:.1f} L), speed {speed:.2f} m/s, yaw rate {rate:+.2f} deg/s")
    print(f"    published: {NOT_FOUND}")
    print("  pitch after a stern-plane step (bow down +5 deg at t = 0, from a straight run at "
          "1525 rpm, other axes free):")
    x0 = settle(p, 1525)
    xs = run(p, x0, [0, math.radians(5), 1525], 30)
    print("    pitch deg, every 1 s:",
          " ".join(f"{math.degrees(t):.1f}" for t in xs[: int(10 / DT) + 1: int(1 / DT), 10]))
    final = xs[-1]
    rate = (xs[-1, 8] - xs[-int(1 / DT), 8])
    theta0 = math.degrees(x0[10])
    steady = math.degrees(final[10])
    t90 = next(i * DT for i, x in enumerate(xs)
               if abs(math.degrees(x[10]) - theta0) >= 0.9 * abs(steady - theta0))
    print(f"    steady pitch {steady:.2f} deg (from {theta0:.2f}), 90 % in {t90:.1f} s, depth rate "
          f"{rate:+.2f} m/s after 30 s")
    print(f"    published: {NOT_FOUND}")
    lin = linearise(p, x0, [0.0, 0.0, 1525.0])
    print("  eigenvalues at the 1525 rpm straight run: sway-yaw",
          " ".join(f"{z:.2f}" for z in np.linalg.eigvals(lin[np.ix_([1, 5], [1, 5])])),
          "| heave-pitch", " ".join(f"{z:.2f}" for z in
                                    np.linalg.eigvals(lin[np.ix_([2, 4, 10], [2, 4, 10])])))


def linearise(p: d.VehicleParams, x0: np.ndarray, inputs: list[float]) -> np.ndarray:
    jac = np.zeros((12, 12))
    u = np.array(inputs)
    for i in range(12):
        e = np.zeros(12)
        e[i] = 1e-6
        jac[:, i] = (d.rhs(p, x0 + e, u) - d.rhs(p, x0 - e, u)) / 2e-6
    return jac


def main() -> None:
    print("Prestero 2001 set (config/vehicles/remus100.toml)")
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
    print("Prestero beside the published figures (surge-only speed: the 6-DOF run loops):")
    for rpm, (pub, src) in PUBLISHED_SPEED.items():
        surge_only = rpm * math.sqrt(straight.thrust_coeff / -straight.quad[0])
        print(f"  {rpm} rpm: {surge_only:.3f} m/s | {pub} m/s ({src}) | "
              f"{verdict(surge_only, pub, calibration=rpm == 1525)}")
    print(f"  turning diameter, pitch step: {NOT_FOUND}")
    fossen(d.load_params(d.REMUS100_FOSSEN_FILE))


if __name__ == "__main__":
    main()
