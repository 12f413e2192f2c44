"""Monte Carlo of closed-loop missions: the autopilot flying a mission file through random
currents with noisy navigation, seeded (one generator per run from ``--seed``).

    .venv/bin/python benchmarks/mc_pilot.py [--mission config/missions/lawnmower.toml]
        [--runs 20] [--seed 0] [--max-current 0.3]

Each run draws a constant current (direction uniform, speed uniform up to ``--max-current``
m/s), a navigation noise seed, and a start offset (up to 3 m across the first leg, 0.5 m in
depth, 5 deg in heading). Prints one line per run and the pooled table: cross-track and depth
error RMS against the truth (m, mean / 95th percentile / max over runs), runs finished, aborts.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from auvgw.control.closed_loop import NavNoise, fly, trimmed_start
from auvgw.control.mission import MISSIONS_DIR, load_mission
from auvgw.sim_devices import dynamics as d

NOISE = NavNoise(position=0.3, depth=0.05, attitude=math.radians(0.5), velocity=0.02,
                 rate=math.radians(0.2))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", type=Path, default=MISSIONS_DIR / "lawnmower.toml")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-current", type=float, default=0.3, help="m/s")
    args = ap.parse_args()
    m = load_mission(args.mission)
    p = d.load_params()
    seeds = np.random.SeedSequence(args.seed).spawn(args.runs)
    xte, dep, done, aborts = [], [], 0, []
    print(f"{m.name}: {m.length:.0f} m, {m.n_legs} legs; {args.runs} runs, currents up to "
          f"{args.max_current} m/s, noise {NOISE}")
    print("  run  current m/s  dir deg  XTE RMS m  depth RMS m  done s  abort")
    for k, ss in enumerate(seeds):
        rng = np.random.default_rng(ss)
        speed, heading = rng.uniform(0, args.max_current), rng.uniform(-math.pi, math.pi)
        x0 = trimmed_start(m)
        h = x0[11]
        off = rng.uniform(-3, 3)
        x0[6] -= off * math.sin(h)
        x0[7] += off * math.cos(h)
        x0[8] += rng.uniform(-0.5, 0.5)
        x0[11] += math.radians(rng.uniform(-5, 5))
        cur = (speed * math.cos(heading), speed * math.sin(heading), 0.0)
        f = fly(m, p, start=x0, current_ned=cur, noise=NOISE, rng=rng)
        xte.append(f.rms(f.cross_track))
        dep.append(f.rms(f.depth_error))
        done += f.done_t is not None
        if f.abort_reason:
            aborts.append(f.abort_reason)
        print(f"  {k:3d} {speed:12.2f} {math.degrees(heading):8.0f} {xte[-1]:10.2f} "
              f"{dep[-1]:12.3f} {f.done_t or math.nan:7.0f}  {f.abort_reason or '-'}")
    print(f"{'':17s}{'mean':>8s}{'p95':>8s}{'max':>8s}")
    for name, v in (("XTE RMS m", xte), ("depth RMS m", dep)):
        a = np.array(v)
        print(f"  {name:15s}{a.mean():8.3f}{np.percentile(a, 95):8.3f}{a.max():8.3f}")
    print(f"  finished {done}/{args.runs}, aborts: {', '.join(aborts) or 'none'}")


if __name__ == "__main__":
    main()
