"""Closed-loop truth cost: the online truth (dynamics + actuator model + truth row) against the
bare RK4 step, and the emulated vehicle at a --speed with the INS and the actuators running.

    .venv/bin/python benchmarks/bench_closed_loop.py [--seconds 20] [--runs 3] [--speeds 1,4,8]

Part 1 (one thread, no ports): vehicle seconds integrated per host second, median of ``runs``,
``dynamics.step`` alone and ``ClosedLoopTruth.at`` stepping the same vehicle through the
actuator model (20 Hz commands of a heading hold), and their ratio in the same run. Part 2:
``Runner`` on the closed-loop scenario (INS at 100 Hz on a pty, actuators on SLCAN, nobody
reading: the ports drop what they cannot hold) for ``seconds / speed`` host seconds at each
speed: the clock's late ticks and largest lag, and the process CPU per host second.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.ground.paths import config_file
from auvgw.sim_devices import dynamics
from auvgw.sim_devices.actuators import ActuatorLimits, ActuatorModel
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.runner import Runner, RunOptions
from auvgw.sim_devices.world import World

SCENARIO = config_file("scenarios/closed_loop.json")


def bare(seconds: float) -> float:
    p = dynamics.load_params()
    x = np.zeros(12)
    x[0], x[8] = 1.3, 5.0
    u = np.array([0.0, 0.0, 1000.0])
    n = int(seconds / 0.01)
    t0 = time.perf_counter()
    for _ in range(n):
        x = dynamics.step(p, x, u, 0.01)
    return seconds / (time.perf_counter() - t0)


def online(seconds: float) -> float:
    scn = load_scenario(SCENARIO)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn))
    model = ActuatorModel(ActuatorLimits(command_timeout_s=1e9), rpm=1000.0)
    truth.set_inputs(model.inputs)
    t0 = time.perf_counter()
    for k in range(int(seconds * 20)):
        s = truth.at(k / 20)
        rud = float(np.clip(s.heading + 4 * s.yaw_rate, -0.35, 0.35))
        stern = float(np.clip(s.pitch + 4 * s.pitch_rate, -0.35, 0.35))
        model.command(k / 20, 1000.0, rud, stern, k)
    return seconds / (time.perf_counter() - t0)


def emulated(speed: float, seconds: float) -> tuple[int, float, float]:
    scn = load_scenario(SCENARIO)
    with tempfile.TemporaryDirectory() as out:
        r = Runner(scn, RunOptions(out_dir=out, speed=speed))
        try:
            t0 = time.monotonic()
            r.start(duration=seconds)
            while r.running:
                time.sleep(0.2)
            wall = time.monotonic() - t0
            st = r.stats()
        finally:
            r.close()
    return st["late_ticks"], st["max_lag_s"], st["process_cpu_s"] / wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="vehicle seconds per case")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--speeds", default="1,4,8")
    args = ap.parse_args()
    b = [bare(args.seconds) for _ in range(args.runs)]
    o = [online(args.seconds) for _ in range(args.runs)]
    mb, mo = statistics.median(b), statistics.median(o)
    print(f"{'integration (dt 0.01 s)':34s} {'x real time':>12s}  (median of {args.runs})")
    print(f"{'dynamics.step alone':34s} {mb:12.1f}")
    print(f"{'ClosedLoopTruth + actuator model':34s} {mo:12.1f}   ratio {mo / mb:.2f}")
    print()
    print(f"{'speed':>6s} {'late ticks':>11s} {'max lag s':>10s} {'CPU s per s':>12s}"
          f"  (INS 100 Hz + actuators 20 Hz, {args.seconds:g} vehicle s)")  # fmt: skip
    for sp in (float(v) for v in args.speeds.split(",")):
        late, lag, cpu = emulated(sp, args.seconds)
        print(f"{sp:6g} {late:11d} {lag:10.3f} {cpu:12.2f}")


if __name__ == "__main__":
    main()
