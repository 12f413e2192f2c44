"""Offline check of the bathymetric settings ``auvgw demo --scenario survey`` uses.

    nice -n 10 .venv/bin/python benchmarks/study_bathy_demo.py [--seeds 0 1 2] [--particles 200]
        [--dr-bias 0.003] [--set KEY=VALUE ...]

Simulates ``config/scenarios/survey.json`` as the demo's emulators see it (1800 s, a swath of
12 x the altitude with 141 soundings, one ping per 2 m of track: 0.85 Hz at 1.7 m/s) with the
paper's eq. (28) dead reckoning at ``--dr-bias`` m per ping and axis (0.003: RMS error 3.5-3.9 m,
as the emulated INS + DVL fusion drifts on this survey), then runs mtm-pf with the paper's
values and with the demo's (``auvgw.commands.bathy_run.DEMO_FILTER``) on each seed and prints the
final and RMS error of each against dead reckoning's, and the loop closures accepted / made.
``RMS m`` is the smoothed trajectory's (the mean trajectory once every closure is in, what the
stage publishes at the end as ``track``), ``filt. RMS`` the filtered estimate's (each ping's
estimate when it was made: the stage's ``pose``), ``1st loop`` the ping of the first closure.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from auvgw.commands.bathy_run import DEMO_FILTER
from auvgw.config.scenario import Scenario
from auvgw.ground.paths import config_file
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import run_filter
from auvgw.slam.bathymetric.simulate import DRModel, simulate_survey


def dr_model(devices: dict[str, Any], nav: str, bias_m: float) -> DRModel:
    """eq. (28) at ``bias_m`` per ping and axis, or ``insdvl`` with the scenario's own INS
    heading bias and DVL scale / misalignment (``devices``: its JSON; 1-sigma, drawn per run)."""
    if nav == "eq28":
        return DRModel(bias_m, 0.01)
    ins, dvl = devices["ins"]["noise"], devices["dvl"]["noise"]
    return DRModel(
        sigma_m=0.01, kind="insdvl", heading_sigma_deg=ins["heading_bias_deg"],
        heading_tau_s=ins["heading_bias_tau_s"], misalign_sigma_deg=dvl["misalignment_deg"],
        scale_sigma=dvl["scale_factor_pct"] / 100.0,
    )  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--dr-bias", type=float, default=0.003, help="m per ping and axis")
    ap.add_argument("--nav", choices=("eq28", "insdvl"), default="eq28",
                    help="DR error model: eq. (28) at --dr-bias, or insdvl with the survey's own "
                    "emulated INS + DVL errors (heading bias 0.4 deg, 400 s; DVL scale 0.3 %%, "
                    "misalignment 0.15 deg)")  # fmt: skip
    ap.add_argument("--scenario", default=None, help="a survey scenario JSON (default survey.json)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a third setting to compare (JSON values)")  # fmt: skip
    a = ap.parse_args()
    path = Path(a.scenario) if a.scenario else config_file("scenarios/survey.json")
    data = json.loads(path.read_text())
    dr = dr_model(data["devices"], a.nav, a.dr_bias)
    data["duration_s"] = 1800
    data["devices"] = {"multibeam": {"rate_hz": 0.85,
                                     "options": {"n_beams": 141, "swath_factor": 12}}}  # fmt: skip
    scn = Scenario.model_validate(data)
    world = World.from_scenario(scn)
    variants: dict[str, dict[str, Any]] = {"paper": {}, "demo": dict(DEMO_FILTER)}
    if a.set:
        extra = {k: json.loads(v) for k, _, v in (s.partition("=") for s in a.set)}
        variants["--set"] = {**DEMO_FILTER, **extra}
    rows = []
    for seed in tqdm(a.seeds, desc="surveys"):
        sim = simulate_survey(scn, np.random.default_rng(seed), dr=dr,
                              world=world)  # fmt: skip
        e_dr = np.hypot(*(sim.dr - sim.truth).T)
        rms_dr = float(np.sqrt(np.mean(e_dr**2)))
        rows.append((seed, "dr", e_dr[-1], rms_dr, rms_dr, "", "", 0.0))
        for name, kw in variants.items():
            cfg = BathyConfig(n_particles=a.particles, **kw)
            t0 = time.perf_counter()
            res, f = run_filter("mtm-pf", sim, cfg, np.random.default_rng([seed, 1]))
            e = np.hypot(*(res.final - sim.truth).T)
            acc = [lp for lp in f.loops if lp.accepted]
            rows.append((seed, name, e[-1], float(np.sqrt(np.mean(e**2))),
                         float(np.sqrt(np.mean(res.err_online**2))), f"{len(acc)}/{len(f.loops)}",
                         str(acc[0].t_end) if acc else "-", time.perf_counter() - t0))  # fmt: skip
    print(f"survey.json, {len(sim.t)} pings, {sim.distance_m:.0f} m, N = {a.particles}, "
          f"DR {dr}; demo: {DEMO_FILTER}")  # fmt: skip
    print(f"{'seed':>4} {'variant':8} {'final m':>8} {'RMS m':>7} {'filt. RMS':>9} {'loops':>6} "
          f"{'1st loop':>8} {'s':>5}")  # fmt: skip
    for seed, name, fin, rms, rms_f, loops, first, sec in rows:
        print(f"{seed:>4} {name:8} {fin:8.2f} {rms:7.2f} {rms_f:9.2f} {loops:>6} {first:>8} "
              f"{sec:5.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
