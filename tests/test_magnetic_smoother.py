"""The batch smoother beside the filters (slam/magnetic/smoother.py, issue 28)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import load_scenario
from auvgw.slam.magnetic.evaluation import Variant, prepare, run_filter, run_smoother
from auvgw.slam.magnetic.smoother import odometry_increments, smooth
from auvgw.slam.models import BicycleModel

DENSE = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "beacons_dense.json"


def test_odometry_increments_compose_the_controls_and_propagate_q() -> None:
    """Each segment's increment is the model's composition from the origin and its covariance
    the EKF's prediction from zero; segments of different lengths at once."""
    m = BicycleModel(2.0)
    rng = np.random.default_rng(2)
    u = np.stack([5 + rng.normal(0, 0.3, 20), rng.normal(0, 0.1, 20)], axis=1)
    q = np.diag([0.09, 0.0027])
    d, s = odometry_increments(m, u, q, 0.025, np.array([0, 8, 20]))
    for j, (a, b) in enumerate([(0, 8), (8, 20)]):
        x, p = np.zeros(3), np.zeros((3, 3))
        for k in range(a, b):
            fx, fu = m.jacobians(x, u[k], 0.025)
            p = fx @ p @ fx.T + fu @ q @ fu.T
            x = m.f(x, u[k], 0.025, wrap=False)
        np.testing.assert_allclose(d[j], x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(s[j], p, rtol=1e-10, atol=1e-15)


def test_without_sightings_the_smoother_is_dead_reckoning() -> None:
    m = BicycleModel(2.0)
    rng = np.random.default_rng(3)
    u = np.stack([5 + rng.normal(0, 0.3, 400), 0.2 * np.sin(np.arange(400) / 40)], axis=1)
    steps = np.arange(8, 401, 8)
    z = [np.zeros((0, 2))] * len(steps)
    ids = [np.zeros(0, int)] * len(steps)
    res = smooth(m, u, np.diag([0.09, 0.0027]), np.diag([0.01, 3e-4]), 0.025,
                 np.array([1.0, 2.0, 0.3]), steps, z, ids, chunk=20)  # fmt: skip
    x = np.array([1.0, 2.0, 0.3])
    for k in range(400):
        x = m.f(x, u[k], 0.025)
    np.testing.assert_allclose(res.poses[-1, :2], x[:2], atol=1e-6)
    assert res.cost < 1e-8 and len(res.beacons) == 0


def test_smoother_on_a_dense_stretch_reaches_its_chi_square_cost() -> None:
    """With the true association the smoother's final cost is about its expectation (sightings
    2m residuals less the 2B beacon coordinates, halved: m - B), its path beats dead reckoning, its
    NEES comes from the marginals."""
    scn = load_scenario(DENSE)
    v = Variant(association="known")
    prep = prepare(scn, v, seed=0, run=0, max_steps=3000)
    assert prep.true_ids is not None
    sim = prep.sim
    res = smooth(sim.motion_model(), sim.controls, sim.q, sim.r, sim.dt, sim.truth[0],
                 sim.obs_step, prep.z, prep.true_ids)  # fmt: skip
    m = sum(len(z) for z in prep.z)
    expect = m - len(res.beacons)
    assert 0.7 * expect < res.cost < 1.3 * expect
    sm, dr = run_smoother(prep, v), run_filter("dr", prep, v)
    assert sm.rmse[0] < 0.5 * dr.rmse[0] and len(sm.lm_mean) == len(res.beacons)
    assert len(sm.nees_pose) == len(range(0, len(sim.obs_step), 25))
    assert np.isfinite(sm.nees_pose).all() and np.isfinite(sm.nees_heading).all()
    with pytest.raises(ValueError, match="generic track"):
        run_smoother(prepare(scn, Variant(track="mlp"), 0, 0, 400), Variant(track="mlp"))
