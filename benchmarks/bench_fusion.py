"""Navigation fusion benchmark: throughput and (optionally) Monte Carlo consistency.

Throughput: INS steps per second of the online path (``NavFilter.push`` per sample), of
``run_filter_arrays``, and of a bare reference loop measured in the same run (one 8x8
``F @ P @ F.T + Q`` per step, the least an EKF at the INS rate must do), as the median of several
runs; ratios are against the reference and against real time (100 Hz INS).

Consistency (``--mc N``): N seeds of a survey lawnmower with HN-100 / Pathfinder noise; per run
the final horizontal error (% of distance), the fraction of epochs whose truth lies in the
2-sigma ellipse (chi-square 2 dof, 5.991) and the mean NEES (2 when consistent).

Usage: ``python benchmarks/bench_fusion.py [--duration 120] [--repeat 3] [--mc 0]
[--mc-duration 1800]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from auvgw.fusion import DvlMount, FusionConfig, InitialState, NavFilter, run_filter_arrays
from auvgw.fusion.synthetic import lawnmower, simulate_sensors

MOUNT = DvlMount(lever_arm_m=(-0.6, 0.1, 0.35), rotation_deg=(0.0, 0.0, 45.0))


def config() -> FusionConfig:
    return FusionConfig(dvl=MOUNT, initial=InitialState(position_m=(0.0, 0.0, 20.0)))


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def throughput(duration: float, repeat: int) -> None:
    truth = lawnmower(duration_s=duration)
    sim = simulate_sensors(truth, np.random.default_rng(0), mount=MOUNT)
    n = len(sim.ins)
    merged = sorted([*sim.ins, *sim.dvl, *sim.depth], key=lambda s: s.t)

    def online() -> None:
        nav = NavFilter(config())
        for s in merged:
            nav.push(s)
        nav.flush()

    def arrays() -> None:
        run_filter_arrays(sim.ins, sim.dvl, config(), sim.depth)

    def reference() -> None:
        P = np.eye(8)
        F = np.eye(8)
        F[0, 5] = F[1, 6] = 0.01
        Q = np.eye(8) * 1e-6
        for _ in range(n):
            P = F @ P @ F.T + Q

    ref = median_time(reference, repeat)
    rows = [
        ("reference F P F^T + Q", ref),
        ("NavFilter.push (online)", median_time(online, repeat)),
        ("run_filter_arrays", median_time(arrays, repeat)),
    ]
    print(f"throughput: {n} INS steps ({duration:.0f} s at 100 Hz, DVL 5 Hz, depth 1 Hz), "
          f"median of {repeat}")  # fmt: skip
    head = ("path", "s", "steps/s", "us/step", "x ref", "x real time")
    print("{:28s} {:>8s} {:>10s} {:>8s} {:>6s} {:>11s}".format(*head))
    for name, t in rows:
        print(f"{name:28s} {t:8.3f} {n / t:10.0f} {t / n * 1e6:8.1f} {t / ref:6.1f} "
              f"{duration / t:11.0f}")  # fmt: skip


def monte_carlo(seeds: int, duration: float) -> None:
    truth = lawnmower(duration_s=duration)
    distance = truth.distance()
    print(f"\nconsistency: {seeds} runs of {duration:.0f} s lawnmower ({distance:.0f} m)")
    print(f"{'seed':>4s} {'final err m':>11s} {'% dist':>7s} {'in 2-sigma':>10s} {'mean NEES':>9s}")
    allin, allnees = [], []
    for seed in range(seeds):
        sim = simulate_sensors(truth, np.random.default_rng(seed), mount=MOUNT)
        out = run_filter_arrays(sim.ins, sim.dvl, config(), sim.depth)
        e = np.stack([out.x - truth.x, out.y - truth.y], axis=1)
        nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(out.cov_xy), e)
        final = float(np.hypot(*e[-1]))
        allin.append(np.mean(nees <= 5.991))
        allnees.append(nees.mean())
        print(f"{seed:4d} {final:11.2f} {100 * final / distance:7.3f} {allin[-1]:10.3f} "
              f"{allnees[-1]:9.2f}")  # fmt: skip
    print(f"{'all':>4s} {'':11s} {'':7s} {np.mean(allin):10.3f} {np.mean(allnees):9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=120.0, help="throughput run, s")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mc", type=int, default=0, help="Monte Carlo runs (0: skip)")
    ap.add_argument("--mc-duration", type=float, default=1800.0)
    args = ap.parse_args()
    throughput(args.duration, args.repeat)
    if args.mc:
        monte_carlo(args.mc, args.mc_duration)


if __name__ == "__main__":
    main()
