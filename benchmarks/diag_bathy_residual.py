"""The depth residual of the Pmap against the Mmap at the true alignment (issue 14): what
sigma_s of eq. (8) should be. One noise-free particle on an error-free DR track, so the mean
trajectory is the truth; at every ping that overlaps the old track, IDW of the Pmap at the
Mmap points minus their depths (sounding noise twice plus interpolation error).

    nice -n 10 .venv/bin/python benchmarks/diag_bathy_residual.py config/scenarios/bathy_survey.json
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.filters import MTMPF
from auvgw.slam.bathymetric.simulate import DRModel, simulate_survey


def main(path: str) -> None:
    scn = Scenario.model_validate_json(Path(path).read_text())
    rng = np.random.default_rng(np.random.SeedSequence([0, 0]))
    sim = simulate_survey(scn, rng, dr=DRModel(0.0, 0.0), world=World.from_scenario(scn))
    cfg = BathyConfig(n_particles=1, sigma_c2=0.0, jitter_a=0.0, omega_sigma_m=0.0)
    f = MTMPF(cfg, len(sim.t), np.random.default_rng(0))
    u = sim.controls()
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    res = []
    for k in range(1, len(sim.t)):
        f.step(u[k - 1], sim.offsets[k], sim.depth[k])
        h = f.t - cfg.t_l
        if h < 2:
            continue
        d, tlp = cKDTree(f.traj[:h]).query(f.x)
        if d[0] > cfg.radius_m:
            continue
        tree, z_p = f._submap()
        idx, ok = f._mmap_index(tlp, h)
        z_pm, z_mm, valid, n_m = f._mmap_vs_pmap(tree, z_p, idx, ok, np.zeros((1, 2)), f.traj)
        r = (z_pm - z_mm)[valid]
        if len(r) > cfg.min_valid_fraction * n_m[0]:
            res.append(r)
    r = np.concatenate(res)
    mse = [float(np.mean(x**2)) for x in res]
    print(
        f"{scn.name}: {len(res)} pings; residual std {r.std():.3f} m, p50 |r| "
        f"{np.median(abs(r)):.3f} m, p95 |r| {np.percentile(abs(r), 95):.3f} m; per-ping MSE "
        f"p50 {np.median(mse):.3f} p95 {np.percentile(mse, 95):.3f} m^2"
    )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "config/scenarios/bathy_survey.json")
