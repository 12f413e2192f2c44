"""Calibration of the drift model of ``lccd_mode = 'drift'`` and ``drift_estimate`` (issue 14,
session 6): over runs ``0 .. R-1`` of one mtm-pf study, every loop closure's alignment error
(the loop-interval displacement error left after its jump, m per axis) and its drift rate
(eq. 25 per ping) against DR's own drift over the interval, split by the truth label (A22).
Prints the alignment error of the valid closures (per-axis RMS, and the per-axis sigma of a 2-D
Gaussian with the same median norm: ``closure_sigma_m``) and the
share of valid / false closures whose rate misses DR's true rate by more than the chi-square
gate under the model (``loops.DriftModel``; the spec is left out: the truth is used here).

    nice -n 10 .venv/bin/python benchmarks/diag_bathy_drift.py \\
        --scenario config/scenarios/bathy_sandfield.json --runs 20 --set lccd=false
"""

from __future__ import annotations

import argparse
import zlib

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import label_loops, run_filter
from auvgw.slam.bathymetric.simulate import simulate_survey


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="config/scenarios/bathy_sandfield.json")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    scn = load_scenario(args.scenario)
    world = World.from_scenario(scn)
    extra = dict(kv.split("=", 1) for kv in args.set)
    cfg = BathyConfig.model_validate({**extra, "n_particles": args.particles})
    dm = None
    rows: list[tuple[bool, np.ndarray, float]] = []  # valid, alignment error, rate chi2
    for run in range(args.runs):
        rng = np.random.default_rng(np.random.SeedSequence([args.seed, run]))
        sim = simulate_survey(scn, rng, world=world)
        frng = np.random.default_rng(
            np.random.SeedSequence([args.seed, run, zlib.crc32(b"mtm-pf")])
        )
        _, f = run_filter("mtm-pf", sim, cfg, frng, run=run)
        dm = f.drift  # type: ignore[attr-defined]
        for lc, valid in zip(f.loops, label_loops(f, sim.truth), strict=True):
            true_d = sim.truth[lc.t_end] - sim.truth[lc.t_loop]
            align = (lc.s_end - lc.s_loop) - true_d
            span = max(lc.t_end - lc.t_loop, 1)
            true_rate = ((sim.dr[lc.t_end] - sim.dr[lc.t_loop]) - true_d) / span
            rate, var = dm.rate(lc)
            d = rate - true_rate
            rows.append((valid, align, float(d @ d) / var))
    assert dm is not None
    print(f"{scn.name}, runs 0-{args.runs - 1}, N = {args.particles}, {args.set}")
    for name, want in (("valid", True), ("false", False)):
        sel = [r for r in rows if r[0] == want]
        if not sel:
            continue
        a = np.array([r[1] for r in sel])
        chi = np.array([r[2] for r in sel])
        rms = float(np.sqrt(np.mean(a**2)))
        med = float(np.median(np.linalg.norm(a, axis=1)))
        print(
            f"{name}: {len(sel)} closures; alignment error per-axis RMS {rms:.2f} m, "
            f"norm median {med:.2f} m (a 2-D Gaussian's per-axis sigma: {med / 1.1774:.2f} m), p90 "
            f"{np.percentile(np.linalg.norm(a, axis=1), 90):.2f} m; rate vs DR's true rate beyond "
            f"the gate ({dm.gate_chi2}, sigma_a {dm.sigma_a} m): {np.mean(chi > dm.gate_chi2):.0%}"
        )


if __name__ == "__main__":
    main()
