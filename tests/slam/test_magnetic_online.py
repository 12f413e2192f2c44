"""Incremental AMB-SLAM (the online stage's core) on an emulated MS3A stream."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import load_scenario
from auvgw.slam.magnetic.evaluation import Variant, magnetometer_stream, prepare
from auvgw.slam.magnetic.filters import make_magnetic
from auvgw.slam.magnetic.mlp import MLP
from auvgw.slam.magnetic.online import MagneticOnline

SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "beacons_amb.json"


def test_online_chain_tracks_the_vehicle_and_publishes_observations() -> None:
    scn = load_scenario(SCENARIO)
    v = Variant(track="mlp")
    prep = prepare(scn, v, seed=2, run=0, max_steps=4800)  # 120 s, 600 m, past 4 beacons
    sim = prep.sim
    ts, b_body, att, channels = magnetometer_stream(
        scn, sim, v, np.random.default_rng(9), np.ones(len(scn.magnetic_beacons), bool)
    )
    filt = make_magnetic("amb-slam", sim.motion_model(), sim.q, sim.r, sim.truth[0],
                         prep.anchor_xy)  # fmt: skip
    online = MagneticOnline(filt, MLP.load(v.model), channels)
    scan_t = sim.obs_step * sim.dt
    k_mag = 0
    est, truth_at, obs = [], [], []
    for k in range(len(sim.controls)):
        t = (k + 1) * sim.dt
        online.add_odometry(t, sim.controls[k], sim.dt)
        while k_mag < len(ts) and ts[k_mag] <= t:
            obs += online.add_mag(ts[k_mag], b_body[k_mag], *att[k_mag])
            k_mag += 1
        i = np.searchsorted(scan_t, t)
        if i < len(scan_t) and scan_t[i] == pytest.approx(t):
            online.add_acoustic(t, prep.acoustic_z[i], prep.acoustic_r[i])
            x, p = online.pose()
            est.append(x)
            truth_at.append(sim.truth[k + 1])
            assert np.all(np.linalg.eigvalsh(p) > 0)
    est_a, tru = np.array(est), np.array(truth_at)
    rmse = float(np.sqrt(np.mean(np.sum((est_a[:, :2] - tru[:, :2]) ** 2, axis=1))))
    assert rmse < 4.0
    # the filter runs half a window behind the newest sample; the pose is propagated to now
    assert online.horizon == pytest.approx(ts[k_mag - 1] - 1.0, abs=0.25)
    assert len(obs) > 20 and all(o.snr >= 5 and 3 <= o.z[0] <= 25 for o in obs)
    assert {round(o.freq, 1) for o in obs} <= {round(f, 1) for f in channels}
    assert filt.n_lm >= 2
    with pytest.raises(ValueError, match="out of order"):
        online.add_mag(ts[0], b_body[0], *att[0])


def test_pose_propagation_fast_path_matches_the_velocity_model() -> None:
    """The scalar VelocityModel steps of ``MagneticOnline.pose`` give the model's own ``f`` and
    Jacobians' mean and covariance (the q_scale of composed steps included)."""
    from auvgw.slam.magnetic.online import _velocity_steps
    from auvgw.slam.models import VelocityModel

    rng = np.random.default_rng(3)
    m = VelocityModel()
    q = np.diag([0.05**2, 0.02**2, np.radians(0.2) ** 2])
    x = np.array([10.0, -4.0, 3.0])
    p = np.diag([0.3, 0.2, 0.01])
    steps = [(rng.normal([5.0, 0.2, 0.3], [0.5, 0.1, 0.2]), 0.05, 1.0 / rng.integers(1, 6))
             for _ in range(40)]  # fmt: skip
    xg, pg = x.copy(), p.copy()
    for u, dt, qs in steps:
        fx, fu = m.jacobians(xg, u, dt)
        xg = m.f(xg, u, dt)
        pg = fx @ pg @ fx.T + fu @ (q * qs) @ fu.T
    xf, pf = _velocity_steps(x, p, steps, q)  # type: ignore[arg-type]
    assert np.allclose(xf[:2], xg[:2]) and np.isclose(np.cos(xf[2] - xg[2]), 1.0)
    assert np.allclose(pf, pg, rtol=1e-10, atol=1e-12)
