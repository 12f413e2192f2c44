"""Monte Carlo of closed-loop missions: the autopilot flying a mission file through random
currents with noisy navigation and start offsets (``auvgw.control.closed_loop.trial``), on the
evaluation harness's executor (``--jobs`` local processes or ``--dask`` a cluster).

    .venv/bin/python benchmarks/mc_pilot.py [--mission config/missions/lawnmower.toml]
        [--runs 20] [--seed 0] [--max-current 0.3] [--jobs 1] [--dask tcp://host:8786]

Run k is seeded ``(seed, k)``: the same wherever it runs. Prints one line per run and the
pooled table: cross-track and depth error RMS against the truth (m; mean, 95th percentile and
max over runs), runs finished, aborts.
"""

from __future__ import annotations

import argparse
import functools
import math
from pathlib import Path

import numpy as np

from auvgw.control.closed_loop import NavNoise, Trial, trial
from auvgw.control.mission import MISSIONS_DIR, load_mission
from auvgw.slam.evaluation.executor import map_unordered, open_executor

NOISE = NavNoise(position=0.3, depth=0.05, attitude=math.radians(0.5), velocity=0.02,
                 rate=math.radians(0.2))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", type=Path, default=MISSIONS_DIR / "lawnmower.toml")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-current", type=float, default=0.3, help="m/s")
    ap.add_argument("--jobs", type=int, default=1, help="local worker processes")
    ap.add_argument("--dask", default=None, help="Dask scheduler address")
    args = ap.parse_args()
    m = load_mission(args.mission)
    print(f"{m.name}: {m.length:.0f} m, {m.n_legs} legs; {args.runs} runs (seed {args.seed}), "
          f"currents up to {args.max_current} m/s; navigation noise (1 sigma) position "
          f"{NOISE.position} m, depth {NOISE.depth} m, attitude 0.5 deg, velocity "
          f"{NOISE.velocity} m/s, rates 0.2 deg/s; start offsets up to 3 m, 0.5 m, 5 deg")
    fn = functools.partial(trial, m, args.seed, max_current=args.max_current, noise=NOISE)
    with open_executor(args.jobs, args.dask) as ex:
        out: list[Trial] = sorted(map_unordered(fn, range(args.runs), ex), key=lambda r: r.run)
    print("  run  current m/s  dir deg  offset m  XTE RMS m  depth RMS m  done s  abort")
    for r in out:
        speed = math.hypot(r.current[0], r.current[1])
        direction = math.degrees(math.atan2(r.current[1], r.current[0]))
        print(f"  {r.run:3d} {speed:12.2f} {direction:8.0f}"
              f" {r.offset:9.2f} {r.xte_rms:10.2f} {r.depth_rms:12.3f} {r.done_t:7.0f}  "
              f"{r.abort_reason or '-'}")
    print(f"{'':17s}{'mean':>8s}{'p95':>8s}{'max':>8s}")
    for name, v in (("XTE RMS m", [r.xte_rms for r in out]),
                    ("depth RMS m", [r.depth_rms for r in out])):  # fmt: skip
        a = np.array(v)
        print(f"  {name:15s}{a.mean():8.3f}{np.percentile(a, 95):8.3f}{a.max():8.3f}")
    aborts = [r.abort_reason for r in out if r.abort_reason]
    done = sum(not math.isnan(r.done_t) for r in out)
    print(f"  finished {done}/{args.runs}, aborts: {', '.join(aborts) or 'none'}")


if __name__ == "__main__":
    main()
