"""Closed loop, part 3: the reference autopilot flying the REMUS 100 model (prints pilot.txt).

    .venv/bin/python docs/results/closed_loop/pilot.py

1. the 2 km lawnmower (config/missions/lawnmower.toml) in truth, in a current, with noisy
   navigation, and both: cross-track and depth error RMS against the truth;
2. the manoeuvres of manoeuvres.py with the autopilot holding the other axes: speed against
   shaft speed, turning diameter at a fixed rudder, pitch after a stern-plane step; and the
   closed-loop responses (heading, depth and pitch steps);
3. fault detection: vehicle time from the fault to the abort.
"""

from __future__ import annotations

import math

import numpy as np

from auvgw.control.closed_loop import ActuatorModel, NavNoise, fly, hold, trimmed_start
from auvgw.control.mission import MISSIONS_DIR, Mission, lawnmower, load_mission
from auvgw.sim_devices import dynamics as dyn

D = np.degrees
R = math.radians
NOISE = NavNoise(position=0.3, depth=0.05, attitude=R(0.5), velocity=0.02, rate=R(0.2))
CURRENT = (0.1, 0.2, 0.0)


def survey() -> None:
    m = load_mission(MISSIONS_DIR / "lawnmower.toml")
    print(f"1. {m.name}: {m.n_legs} legs ({len(m.waypoints) // 2} lines), {m.length:.0f} m, "
          f"{m.waypoints[0].depth:g} m depth, {m.waypoints[0].speed:g} m/s; trimmed start at the "
          "first waypoint; errors against the truth over every step flown (turns included)")
    print("  case                       XTE RMS m  XTE max m  depth RMS m  depth max m  "
          "time s  abort")
    for name, kw in (
        ("truth navigation", {}),
        ("current 0.22 m/s (N 0.1 E 0.2)", {"current_ned": CURRENT}),
        ("noisy navigation", {"noise": NOISE, "rng": np.random.default_rng(1)}),
        ("noisy + current", {"noise": NOISE, "rng": np.random.default_rng(1),
                             "current_ned": CURRENT}),
    ):
        f = fly(m, **kw)  # type: ignore[arg-type]
        run = f.running()
        print(f"  {name:30s} {f.rms(f.cross_track):6.2f} {np.abs(f.cross_track[run]).max():10.2f}"
              f" {f.rms(f.depth_error):12.3f} {np.abs(f.depth_error[run]).max():12.3f}"
              f" {f.done_t or f.t[-1]:7.0f}  {f.abort_reason or '-'}")
    x0 = trimmed_start(m)
    x0[0] = x0[8] = 0.0  # at rest on the surface
    f = fly(m, start=x0)
    later = f.running() & (f.t >= 60.0)
    on = f.t[np.argmax(np.abs(f.depth_error) < 0.3)]
    print(f"  from rest at the surface: XTE RMS {f.rms(f.cross_track):.2f} m, depth RMS "
          f"{f.rms(f.depth_error):.2f} m with the 10 m dive (within 0.3 m at t = {on:.0f} s); "
          f"from t = 60 s: XTE RMS {f.rms(f.cross_track, later):.2f} m, depth RMS "
          f"{f.rms(f.depth_error, later):.3f} m; {f.abort_reason or 'no abort'}")
    print(f"  noise (1 sigma, white): position {NOISE.position} m, depth {NOISE.depth} m, "
          f"attitude {D(NOISE.attitude):.1f} deg, velocity {NOISE.velocity} m/s, rates "
          f"{D(NOISE.rate):.1f} deg/s")


def start(u: float, depth: float = 10.0) -> np.ndarray:
    x = np.zeros(12)
    x[0], x[8] = u, depth
    return x


def speeds(p: dyn.VehicleParams) -> None:
    print("2a. speed against shaft speed, full model (B > W, propeller torque), heading and depth "
          "held by the autopilot, 120 s, mean of the last 30 s")
    print("    rpm   u m/s  surge-only u  pitch deg  roll deg  stern deg  rudder deg  "
          "depth err m")
    for rpm in (500, 750, 1000, 1250, 1500, 1525):
        t, xs, cmd = hold(p, start(rpm / 610.0), 120.0, lambda t, c, n=rpm: (c[0], c[1], n),
                          heading_d=0.0, depth_d=10.0, speed_d=0.0)  # fmt: skip
        last = t >= t[-1] - 30.0
        surge = rpm * math.sqrt(p.thrust_coeff / -p.quad[0])
        print(f"  {rpm:5d} {xs[last, 0].mean():7.2f} {surge:13.2f} {D(xs[last, 10].mean()):10.1f}"
              f" {D(xs[last, 9].mean()):9.1f} {D(cmd[last, 2].mean()):10.1f}"
              f" {D(cmd[last, 1].mean()):11.1f} {np.abs(xs[last, 8] - 10.0).max():12.3f}")
    print("  published: 2.5 m/s at 1525 rpm (MSS remus100.m; the model's kT is fitted to it), "
          "~1.5 m/s at 1500 rpm (Prestero 2001 trim)")


def turns(p: dyn.VehicleParams) -> None:
    print("2b. turning at a fixed rudder from a straight run at 1000 rpm, depth held at 10 m; "
          "diameter from the last full turn of 150 s")
    print("  rudder deg  diameter m  yaw rate deg/s  u m/s  roll deg  pitch deg  depth err m")
    for rud in (5.0, 10.0, 15.0, 20.0):
        t, xs, _ = hold(p, start(1.6), 150.0,
                        lambda t, c, r=rud: (R(r) if t >= 10.0 else c[0], c[1], 1000.0),
                        heading_d=0.0, depth_d=10.0, speed_d=0.0)  # fmt: skip
        if t[-1] < 149.0:
            print(f"  {rud:10.0f}  (looped: pitch past 85 deg at t = {t[-1]:.1f} s)")
            continue
        yaw = np.unwrap(xs[:, 11])
        rate = np.gradient(yaw, t)
        one = np.abs(yaw - yaw[-1]) <= 2 * math.pi  # the last full turn
        dia = max(np.ptp(xs[one, 6]), np.ptp(xs[one, 7]))
        last = t >= t[-1] - 20.0
        print(f"  {rud:10.0f} {dia:11.1f} {D(rate[last].mean()):15.1f} {xs[last, 0].mean():6.2f}"
              f" {D(xs[last, 9].mean()):9.1f} {D(xs[last, 10].mean()):10.1f}"
              f" {np.abs(xs[last, 8] - 10).max():12.2f}")
    print("  open loop (manoeuvres.txt): 10 deg, 1000 rpm: a 2.1 m spiral at 0.36 m/s; "
          "published REMUS 100 turning circle: not in the sources we could read")
    print("2b'. steady turns the autopilot holds: yaw-rate set-point from t = 10 s (rudder from "
          "the yaw-rate loop), 1000 rpm, depth held at 10 m, the last 60 s of 150 s")
    print("  yaw rate deg/s  diameter m  rudder deg  u m/s  roll deg  depth err m")
    for rd in (4.0, 8.0, 12.0, 16.0):
        t, xs, cmd = hold(p, start(1.6), 150.0, lambda t, c: (c[0], c[1], 1000.0),
                          heading_d=0.0, depth_d=10.0, speed_d=0.0,
                          yaw_rate_d=lambda t, r=rd: R(r) if t >= 10.0 else None)  # fmt: skip
        if t[-1] < 149.0:
            print(f"  {rd:14.0f}  (looped: pitch past 85 deg at t = {t[-1]:.1f} s)")
            continue
        last = t >= t[-1] - 60.0
        u = xs[last, 0].mean()
        rate = np.gradient(np.unwrap(xs[:, 11]), t)[last].mean()
        print(f"  {rd:14.0f} {2 * math.hypot(u, xs[last, 1].mean()) / rate:11.1f}"
              f" {D(cmd[last, 1].mean()):11.1f} {u:6.2f} {D(xs[last, 9].mean()):9.1f}"
              f" {np.abs(xs[last, 8] - 10).max():12.2f}")


def pitch_steps(p: dyn.VehicleParams) -> None:
    print("2c. stern-plane step: 1000 rpm, heading held; depth loop trims until t = 30 s, "
          "then the stern plane is fixed at trim + step (bow down); pitch deg every 1 s")
    for step in (2.0, 5.0):
        trim: list[float] = []

        def ov(t: float, c: tuple[float, float, float], s: float = step,
               trim: list[float] = trim) -> tuple[float, float, float]:  # fmt: skip
            if t < 30.0:
                trim[:] = [c[1]]
                return c[0], c[1], 1000.0
            return c[0], trim[0] + R(s), 1000.0

        t, xs, _ = hold(p, start(1.6), 45.0, ov, heading_d=0.0, depth_d=10.0, speed_d=0.0)
        k = [i for i in range(len(t)) if t[i] >= 29.999 and abs(t[i] - round(t[i])) < 1e-6]
        end = "" if t[-1] >= 44.9 else f" [looped: stopped at t = {t[-1]:.1f} s]"
        print(f"  {step:g} deg (trim {D(trim[0]):.1f} deg): "
              + " ".join(f"{D(xs[i, 10]):.1f}" for i in k) + end)
    print("  open loop (manoeuvres.txt): 5 deg step from rest of the fins at 1.5 m/s: -71 deg "
          "in 3 s")
    print("2d. closed-loop steps at 1000 rpm (truth navigation)")
    t, xs, _ = hold(p, start(1.6), 60.0, lambda t, c: (c[0], c[1], 1000.0),
                    heading_d=R(90.0), depth_d=10.0, speed_d=0.0)  # fmt: skip
    psi = D(np.unwrap(xs[:, 11]))
    print(f"  heading 0 -> 90 deg: 90 % at t = {t[np.argmax(psi >= 81.0)]:.1f} s, overshoot "
          f"{max(0.0, psi.max() - 90):.1f} deg, error at 60 s {psi[-1] - 90:.2f} deg")
    t, xs, _ = hold(p, start(1.6), 90.0, lambda t, c: (c[0], c[1], 1000.0),
                    heading_d=0.0, depth_d=20.0, speed_d=0.0)  # fmt: skip
    z = xs[:, 8]
    print(f"  depth 10 -> 20 m: 90 % at t = {t[np.argmax(z >= 19.0)]:.1f} s, overshoot "
          f"{max(0.0, z.max() - 20):.2f} m, error at 90 s {z[-1] - 20:.3f} m, "
          f"pitch min {D(xs[:, 10].min()):.1f} deg")
    t, xs, _ = hold(p, start(1.6), 30.0, lambda t, c: (c[0], c[1], 1000.0),
                    heading_d=0.0, depth_d=10.0, speed_d=0.0,
                    pitch_d=lambda t: R(-10.0) if t >= 5.0 else None)  # fmt: skip
    th = D(xs[:, 10])
    after = t >= 5.0
    print(f"  pitch -> -10 deg at t = 5 s: 90 % at t = "
          f"{t[after][np.argmax(th[after] <= -9.0)]:.1f} s, overshoot "
          f"{max(0.0, -10 - th.min()):.1f} deg, error at 30 s {th[-1] + 10:.2f} deg")


def faults() -> None:
    m = Mission(lawnmower((0.0, 0.0), 120.0, 20.0, 2, 0.0, 5.0, 1.5), 5.0)
    print("3. faults at t = 20 s on a straight leg (dt = 0.05 s): vehicle time to the abort")
    for name, kw in (
        ("rudder jammed hard over (12 deg)", {"actuators": ActuatorModel(jam=("rudder", 20.0,
                                                                              R(12.0)))}),
        ("stern plane jammed at -6 deg", {"actuators": ActuatorModel(jam=("stern", 20.0,
                                                                          R(-6.0)))}),
        ("shaft stopped", {"actuators": ActuatorModel(thruster_stop=20.0)}),
        ("fault word bit", {"actuators": ActuatorModel(fault=(0x10, 20.0))}),
        ("navigation lost", {"nav_lost_at": 20.0}),
    ):
        f = fly(m, **kw)  # type: ignore[arg-type]
        print(f"  {name:34s} {f.abort_reason:15s} after {(f.abort_t or math.nan) - 20.0:.2f} s")


def main() -> None:
    p = dyn.load_params()
    survey()
    speeds(p)
    turns(p)
    pitch_steps(p)
    faults()


if __name__ == "__main__":
    main()
