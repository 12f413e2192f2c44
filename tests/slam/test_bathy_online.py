"""The step-by-step bathymetric driver (slam/bathymetric/online.py) against the batch filter."""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.config.scenario import Scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import run_filter
from auvgw.slam.bathymetric.online import OnlineBathy, resample_swath
from auvgw.slam.bathymetric.simulate import simulate_survey
from auvgw.testing.bathy_helpers import TINY


def test_online_driver_grows_and_matches_the_batch_filter() -> None:
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3))
    cfg = BathyConfig(n_particles=50)
    batch, _ = run_filter("mtm-pf", sim, cfg, np.random.default_rng(9))
    n_beams = sim.depth.shape[1]
    online = OnlineBathy(cfg, np.random.default_rng(9), n_beams=n_beams, capacity=16)
    for k in range(len(sim.t)):
        h = float(sim.heading[k])
        stbd = np.array([-np.sin(h), np.cos(h)])
        across = sim.offsets[k] @ stbd
        online.add_ping(sim.dr[k, 0], sim.dr[k, 1], h, across, np.zeros(n_beams), sim.depth[k])
    assert online.pings == len(sim.t) and len(sim.t) <= online.filter.T  # grew from 16
    np.testing.assert_allclose(online.filter.trajectory(), batch.final, atol=1e-6)
    np.testing.assert_allclose(online.dr.trajectory(), sim.dr, atol=1e-9)
    assert len(online.filter.loops) > 0  # the crossing was matched online too
    pts = online.map_points(last_pings=10)
    assert pts.shape == (10 * n_beams, 3)
    np.testing.assert_allclose(pts[:, 2], sim.depth[-10:].reshape(-1))


def test_swath_resampling_drops_invalid_beams_and_rejects_empty_swaths() -> None:
    across = np.array([10.0, -10.0, np.nan, 0.0])
    depth = np.array([31.0, 29.0, 50.0, 30.0])
    a, f, d = resample_swath(across, np.array([1.0, 0, 0, 0]), depth, 5)
    np.testing.assert_allclose(f[-1], 1.0)
    np.testing.assert_allclose(a, [-10, -5, 0, 5, 10])
    np.testing.assert_allclose(d, [29, 29.5, 30, 30.5, 31])
    with pytest.raises(ValueError, match="1 valid soundings"):
        resample_swath(np.array([1.0, np.nan]), np.zeros(2), np.ones(2), 5)
