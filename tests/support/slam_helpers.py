"""Shared helpers of the SLAM tests: Bailey scenarios written from ../shared/data/bailey."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from auvgw.config.scenario import Scenario, load_scenario
from auvgw.ground.paths import config_file
from auvgw.slam.evaluation.simulate import SimRun
from auvgw.slam.landmark.base import LandmarkFilter


def bailey_scenario(shared_data: Path, tmp: Path, name: str = "webmap", **obs: float) -> Scenario:
    """Bailey's map ``name`` with his simulator settings (start at the origin, 2 loops): the
    shipped ``config/scenarios/<name>.json``, or one written to ``tmp`` from the shared map."""
    shipped = config_file(f"scenarios/{name}.json")
    if shipped.is_file():
        scn = load_scenario(shipped)
        return scn.model_copy(update={"observations": scn.observations.model_copy(update=obs)})
    d = json.loads((shared_data / "bailey" / f"{name}.json").read_text())
    doc = {
        "name": name,
        "motion": "bicycle",
        "vehicle": {
            "waypoints": d["waypoints"],
            "loops": 2,
            "accept_radius_m": 1.0,
            "speed_mps": 3.0,
            "start": [0.0, 0.0, 0.0],
        },
        "features": {"points_file": f"shared:bailey/{name}.json"},
        "observations": dict(obs),
    }
    path = tmp / f"{name}.json"
    path.write_text(json.dumps(doc))
    return load_scenario(path)


def run_filter(f: LandmarkFilter, run: SimRun, rng: np.random.Generator) -> np.ndarray:
    """Drive ``f`` through ``run``; returns the estimated poses after every scan (n_scans, 3)."""
    out = []
    oi = 0
    for k in range(len(run.controls)):
        f.predict(run.controls[k], run.dt, rng)
        if oi < len(run.obs_step) and run.obs_step[oi] == k + 1:
            f.update(run.obs_z[oi], rng, run.obs_ids[oi])
            out.append(f.estimate())
            oi += 1
    return np.array(out)
