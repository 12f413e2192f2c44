"""Speed and memory of the bathymetric PF-SLAM filters on the paper-analog 3613 s mission.

    .venv/bin/python benchmarks/bench_bathymetric.py [--particles 400] [--max-pings N]
        [--scenario config/scenarios/bathy_survey.json] [--seed 0]

One survey (3613 pings at 1 Hz, 141 soundings each, eq. 28 DR) is simulated once; mtm-pf and
BPSLAM then process it with the same seed. Printed, in one run: wall time and process CPU time
spent in the filters, real-time factor (mission seconds / filter wall seconds; the bar of
issue 14: mtm-pf >= 100x on the 2-core machine, the paper 12x in MATLAB), the ratio of the two
filters' times (bar: mtm-pf <= 0.6 x BPSLAM's), and the bytes each holds (numpy nbytes of its
state) at 25/50/75/100 % of the mission: mtm-pf's particle part must not grow with
N x mission length (Table 1: m_i N + m_j + m_k against m_j N + m_k).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.filters import FILTERS
from auvgw.slam.bathymetric.simulate import simulate_survey

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=ROOT / "config/scenarios/bathy_survey.json")
    ap.add_argument("--particles", type=int, default=400)
    ap.add_argument("--max-pings", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    scn = load_scenario(a.scenario)
    sim = simulate_survey(
        scn, np.random.default_rng(a.seed), max_pings=a.max_pings, world=World.from_scenario(scn)
    )
    cfg = BathyConfig(n_particles=a.particles)
    n = len(sim.t)
    marks = {int(n * q) - 1: q for q in (0.25, 0.5, 0.75, 1.0)}
    u = sim.controls()
    rows = {}
    for name in ("mtm-pf", "bpslam"):
        f = FILTERS[name](cfg, n, np.random.default_rng([a.seed, 1]))
        mem = {}
        w0, c0 = time.perf_counter(), time.process_time()
        f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
        for k in range(1, n):
            f.step(u[k - 1], sim.offsets[k], sim.depth[k])
            if k in marks:
                # bytes of what grows with the mission: per-ping state (swaths, mean or per-
                # particle trajectories); the swath store is preallocated, count its used part
                used = (k + 1) / n
                swaths = f.offsets.nbytes + f.depths.nbytes  # type: ignore[union-attr]
                traj = f.traj.nbytes if name == "mtm-pf" else f.trajs.nbytes  # type: ignore[attr-defined]
                mem[marks[k]] = (swaths * used, traj * used, f.bytes_held() - swaths - traj)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        err = float(np.linalg.norm(f.trajectory()[-1] - sim.truth[-1]))
        rows[name] = (wall, cpu, mem, err)
    dur = sim.duration_s
    print(f"{scn.name}: {n} pings ({dur:.0f} s, {sim.distance_m:.0f} m), N = {a.particles}")
    print(f"{'filter':8} {'wall s':>8} {'cpu s':>8} {'RTF':>7} {'final err m':>12}")
    for name, (wall, cpu, _, err) in rows.items():
        print(f"{name:8} {wall:8.1f} {cpu:8.1f} {dur / wall:6.0f}x {err:12.2f}")
    (wm, cm, _, _), (wb, cb, _, _) = rows["mtm-pf"], rows["bpslam"]
    print(f"time ratio mtm-pf / bpslam: wall {wm / wb:.2f}, cpu {cm / cb:.2f} (bar <= 0.6)")
    print("bytes held as the mission grows (MB): swaths | trajectory state | particles+rest")
    for name, (_, _, mem, _) in rows.items():
        cells = "  ".join(
            f"{int(q * 100)}%: {s / 1e6:.1f} | {t / 1e6:.2f} | {r / 1e6:.2f}"
            for q, (s, t, r) in sorted(mem.items())
        )
        print(f"{name:8} {cells}")


if __name__ == "__main__":
    main()
