"""Speed of every landmark SLAM filter as a real-time factor on Bailey's webmap.

    .venv/bin/python benchmarks/bench_slam.py [--repeat 3] [--map webmap] [--algorithms a,b]

One simulated run of the map with Bailey's settings (2 loops, about 434 s of vehicle time,
100 particles, known association, observations every 8 control steps of 25 ms) is generated once;
each filter then processes it ``--repeat`` times (fresh filter, same seed) and the median time
spent in ``predict``/``update`` (wall clock) is reported, with the process CPU time beside it
(on a machine shared with other jobs the CPU time shows what the filter itself needs).
Real-time factor = vehicle time / filter time (wall clock; the bars apply to it). The
bars (issue 6): FastSLAM 1.0 >= 100x, VB-AUFastSLAM >= 20x on the 2-core reference machine. The
last column is each filter's time relative to FastSLAM 1.0 measured in the same run.

The scenario is ``config/scenarios/<map>.json`` when shipped, else built from
``../shared/data/bailey/<map>.json`` with Bailey's settings.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from auvgw.ground.paths import shared_dir
from auvgw.slam.evaluation.runner import drive
from auvgw.slam.evaluation.simulate import simulate
from auvgw.slam.landmark.registry import ALGORITHMS, DISPLAY_NAMES, make_filter
from auvgw.slam.models import BicycleModel, RangeBearing
from auvgw.testing.slam_helpers import bailey_scenario

BARS = {"fastslam1": 100.0, "vb-aufastslam": 20.0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--map", default="webmap")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--algorithms", default=",".join(ALGORITHMS))
    args = ap.parse_args()
    root = shared_dir()
    if root is None:
        sys.exit("../shared/data not found (set AUVGW_SHARED)")
    scn = bailey_scenario(root / "data", Path(tempfile.mkdtemp()), args.map)
    sim = simulate(scn, np.random.default_rng(0))
    print(
        f"{args.map}: {sim.duration_s:.1f} s vehicle time, {len(sim.controls)} steps, "
        f"{len(sim.obs_step)} scans, {np.mean([len(z) for z in sim.obs_z]):.2f} observations "
        f"per scan, {args.particles} particles, median of {args.repeat}"
    )
    names = [a.strip() for a in args.algorithms.split(",") if a.strip()]
    if "fastslam1" not in names:
        names.insert(0, "fastslam1")
    rows = []
    for name in names:
        times, cpu = [], []
        for _ in range(args.repeat):
            f = make_filter(
                name,
                BicycleModel(sim.wheelbase),
                RangeBearing(),
                sim.q,
                sim.r,
                n_particles=args.particles,
                x0=sim.truth[0],
            )
            c0 = time.process_time()
            est, _, spent = drive(f, sim, np.random.default_rng(1))
            cpu.append(time.process_time() - c0)
            times.append(spent)
        med = statistics.median(times)
        med_cpu = statistics.median(cpu)
        err = np.hypot(*(est[:, :2] - sim.truth[sim.obs_step, :2]).T)
        rmse = float(np.sqrt(np.mean(err**2)))
        rows.append((name, med, sim.duration_s / med, med_cpu, sim.duration_s / med_cpu, rmse))
    ref = rows[0][1]
    print(
        f"{'filter':<15}{'wall (s)':>9}{'real-time':>11}{'cpu (s)':>9}{'cpu RTF':>9}{'bar':>7}"
        f"{'':>6}{'path RMSE':>11}{'x FastSLAM1':>13}"
    )
    ok = True
    for name, med, rtf, med_cpu, rtf_cpu, rmse in rows:
        bar = BARS.get(name)
        verdict = "" if bar is None else ("ok" if rtf >= bar else "SLOW")
        ok &= verdict != "SLOW"
        print(
            f"{DISPLAY_NAMES[name]:<15}{med:>9.2f}{rtf:>10.0f}x{med_cpu:>9.2f}{rtf_cpu:>8.0f}x"
            f"{(f'{bar:.0f}x' if bar else ''):>7}{verdict:>6}{rmse:>10.2f}m{med / ref:>13.2f}"
        )
    print("all bars met" if ok else "some bars NOT met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
