"""Points and wall lines on the same particles (``update(..., model=LineFeature(), r=...)``) and
the SLAM stage feeding its Hough lines to the filter (``use_lines``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from auvgw.slam.landmark.registry import make_filter
from auvgw.slam.models import LineFeature, RangeBearing, VelocityModel, wrap_angle
from auvgw.testing import slam_harbour
from auvgw.testing.slam_harbour import run_events

#: the emulated harbour run of the landmark SLAM stage (a module-scoped fixture)
harbour_run = slam_harbour.harbour_run

#: a 100 m x 60 m basin: walls x = 0, x = 100 (theta 0), y = 0, y = 60 (theta pi/2), as
#: (rho, theta) with rho >= 0 seen from the origin; piles inside
WALLS = np.array([[0.0, math.pi], [100.0, 0.0], [0.0, -math.pi / 2], [60.0, math.pi / 2]])
PILES = np.array([[30.0, 20.0], [70.0, 40.0], [50.0, 10.0]])
SIG_RHO, SIG_TH = 0.05, math.radians(0.3)
SIG_R, SIG_B = 0.2, math.radians(1.0)
DT = 0.5
YAW_BIAS = math.radians(0.03)  # rad/s in the odometry's yaw rate


def _truth(n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """A loop around the basin at 1 m/s: poses (n + 1, 3) and true controls (n, 3)."""
    motion = VelocityModel()
    x = np.array([20.0, 15.0, 0.0])
    poses, controls = [x], []
    corners = [(80.0, 15.0), (80.0, 45.0), (20.0, 45.0), (20.0, 15.0)]
    k = 0
    for _ in range(n_steps):
        gx, gy = corners[k % 4]
        if math.hypot(gx - x[0], gy - x[1]) < 3.0:
            k += 1
            gx, gy = corners[k % 4]
        err = wrap_angle(math.atan2(gy - x[1], gx - x[0]) - x[2])
        u = np.array([1.0, 0.0, float(np.clip(err, -0.1, 0.1))])
        x = motion.f(x, u, DT)
        poses.append(x)
        controls.append(u)
    return np.array(poses), np.array(controls)


def _observe(pose: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Wall lines (rho_v >= 0 form, as the extractor reports them) and piles within 40 m."""
    zl = LineFeature().h(pose, WALLS)
    flip = zl[:, 0] < 0
    zl[flip, 0] *= -1
    zl[flip, 1] = wrap_angle(zl[flip, 1] + math.pi)
    zl = zl[zl[:, 0] < 40.0]
    zl = zl + rng.normal(0, [SIG_RHO, SIG_TH], zl.shape)
    zp = RangeBearing().h(pose, PILES)
    zp = zp[zp[:, 0] < 40.0]
    zp = zp + rng.normal(0, [SIG_R, SIG_B], zp.shape)
    return zl, zp


def _run(name: str, lines: bool, n_steps: int = 500, seed: int = 1):
    poses, controls = _truth(n_steps)
    q = np.diag([0.02**2, 0.02**2, math.radians(0.1) ** 2])  # covers the 0.03 deg/s bias
    r = np.diag([SIG_R**2, SIG_B**2])
    f = make_filter(name, VelocityModel(), RangeBearing(), q, r, n_particles=30,
                    x0=poses[0], association="nn")  # fmt: skip
    rng = np.random.default_rng(seed)
    obs_rng = np.random.default_rng(100)
    rline = np.diag([SIG_RHO**2, SIG_TH**2])
    err = []
    for k, u in enumerate(controls):
        f.predict(u + np.array([0.0, 0.0, YAW_BIAS]), DT, rng)
        if k % 10 == 9:  # a scan every 5 s
            zl, zp = _observe(poses[k + 1], obs_rng)
            f.update(zp, rng)
            if lines:
                f.update(zl, rng, model=LineFeature(), r=np.broadcast_to(rline, (len(zl), 2, 2)))
        est = f.estimate()
        err.append((math.hypot(*(est[:2] - poses[k + 1, :2])),
                    abs(wrap_angle(est[2] - poses[k + 1, 2]))))  # fmt: skip
    return f, np.array(err)


@pytest.mark.parametrize("name", ["fastslam1", "ufastslam", "vb-aufastslam"])
def test_wall_lines_pin_the_heading_drift_that_points_alone_do_not(name):
    # the odometry turns 0.03 deg/s: 7.5 deg after 250 s, ~10 m off at the far end of the loop
    f_pts, e_pts = _run(name, lines=False)
    f_all, e_all = _run(name, lines=True)
    rmse_pts, rmse_all = np.sqrt(np.mean(e_pts[:, 0] ** 2)), np.sqrt(np.mean(e_all[:, 0] ** 2))
    assert rmse_all < 0.5 * rmse_pts, (rmse_all, rmse_pts)
    assert rmse_all < 0.8, rmse_all
    assert np.degrees(e_all[-50:, 1].max()) < 1.5
    # wall landmarks: re-seen walls are associated (about 90 wall observations make at most
    # 6 landmarks for the 4 walls), piles are points; both kinds on the same particles
    b = int(np.argmax(f_all.weights()))
    kinds = f_all.lm_kind[b, : f_all.n_lm[b]]
    assert type(f_all.models[1]) is LineFeature
    assert 4 <= np.sum(kinds == 1) <= 6 and np.sum(kinds == 0) == len(PILES), kinds
    lm = f_all.landmarks()
    walls = lm.of_kind(1).mean
    deg2 = math.radians(2.0)
    for rho, th in WALLS:  # each wall has its landmark within 2 m and 2 deg (normal form +-)
        d = [
            min(max(abs(m[0] - rho) / 2.0, abs(wrap_angle(m[1] - th)) / deg2),
                max(abs(m[0] + rho) / 2.0, abs(wrap_angle(m[1] - th - math.pi)) / deg2))
            for m in walls
        ]  # fmt: skip
        assert min(d) < 1.0, (rho, th, walls)
    assert np.all(np.hypot(*(lm.of_kind(0).mean[:, None] - PILES[None]).T).min(axis=0) < 1.5)
    # without lines: points only, kind 0 everywhere
    assert np.all(f_pts.lm_kind == 0) and len(f_pts.models) == 1


def test_line_updates_leave_the_vb_noise_posteriors_of_the_points_alone():
    f = make_filter("vb-aufastslam", VelocityModel(), RangeBearing(), np.eye(3) * 1e-4,
                    np.diag([0.04, 3e-4]), n_particles=10, x0=(20.0, 15.0, 0.0),
                    association="nn")  # fmt: skip
    rng = np.random.default_rng(0)
    zl, zp = _observe(np.array([20.0, 15.0, 0.0]), np.random.default_rng(3))
    f.update(zp, rng)
    eta, xi = f.eta.copy(), f.xi.copy()
    r = np.broadcast_to(np.diag([SIG_RHO**2, SIG_TH**2]), (len(zl), 2, 2))
    f.update(zl, rng, model=LineFeature(), r=r)
    np.testing.assert_array_equal(f.eta, eta)
    np.testing.assert_array_equal(f.xi, xi)
    # new wall landmarks start with the given covariance (G R G^T), not the points' R
    b = int(np.argmax(f.weights()))
    walls = f.lm_kind[b, : f.n_lm[b]] == 1
    assert walls.sum() == len(zl)
    cov = f.cov[b, : f.n_lm[b]][walls]
    assert np.allclose(cov[:, 1, 1], SIG_TH**2, rtol=1e-3)
    # a second look at the same walls is associated with them
    f.update(zl, rng, model=LineFeature(), r=r)
    assert np.all(np.sum(f.lm_kind[:, : f.n_lm.max()] == 1, axis=1) == len(zl))


def test_other_kinds_need_their_noise_and_known_ids_are_per_kind():
    f = make_filter("fastslam2", VelocityModel(), RangeBearing(), np.eye(3) * 1e-4,
                    np.diag([0.04, 3e-4]), n_particles=5, association="known")  # fmt: skip
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="need their noise covariances r"):
        f.update(np.array([[10.0, 0.1]]), rng, ids=[0], model=LineFeature())
    with pytest.raises(ValueError, match=r"\(2, 2, 2\)"):
        f.update(np.zeros((2, 2)), rng, ids=[0, 1], model=LineFeature(), r=np.eye(2)[None])
    # id 0 is a pile and a wall: two landmarks; a wall at theta ~ pi averages circularly
    f.update(np.array([[10.0, 0.0]]), rng, ids=[0])
    z = np.array([[5.0, math.pi - 1e-4]])
    r = np.diag([0.01, 1e-4])[None]
    f.update(z, rng, ids=[0], model=LineFeature(), r=r)
    f.update(z, rng, ids=[0], model=LineFeature(), r=r)
    lm = f.landmarks()
    assert lm.kinds is not None and lm.kinds.tolist() == [0, 1] and lm.ids.tolist() == [0, 0]
    np.testing.assert_allclose(lm.mean[0], [10.0, 0.0], atol=1e-6)
    assert abs(wrap_angle(lm.mean[1, 1] - (math.pi - 1e-4))) < 0.05
    assert lm.of_kind(1).mean.shape == (1, 2)


@pytest.mark.e2e
def test_stage_feeds_the_walls_to_the_filter_and_holds_the_heading(harbour_run):
    """The harbour run of tests/commands/test_slam_stage.py (odometry with a 0.05 deg/s yaw-rate
    bias, emulated MSIS at 50 m, 150 s): with ``use_lines`` (the default) the walls update the
    filter and hold the heading; with the points only the path drifts with the odometry. The
    control noise covers the bias (``sigma_yaw_rate_dps`` 0.3, "raise it for a poorer
    odometry"), else no feature can pull the estimate off the odometry."""
    _, track, dr, t_odo, stage, published, events, cfg = harbour_run
    assert cfg.use_lines
    c = stage.counters()
    assert c["stage"]["line_updates"] >= 5 and c["line_landmarks"] >= 2
    assert c["line_landmarks"] <= c["stage"]["line_features"]
    body = [b for k, b, _ in published if k.endswith("/landmarks")][-1]
    walls = body["line_landmarks"]  # a LineSet: one column per field
    assert len(walls["rho"]) == len(walls["theta"]) == c["line_landmarks"]
    assert len(body["mean"]) == c["landmarks"]  # the point layer holds points only
    assert np.array(walls["cov"]).shape == (c["line_landmarks"], 2, 2)
    runs = {}
    for lines in (True, False):
        cfg2 = cfg.model_copy(
            update={"use_lines": lines, "sigma_yaw_rate_dps": 0.3, "heading_sigma_deg": None}
        )  # a biased gyro: no reference
        runs[lines], _ = run_events(cfg2, events)
    assert runs[False].counters()["stage"]["line_updates"] == 0
    assert runs[False].counters()["line_landmarks"] == 0

    def rmse(s) -> float:
        tr = np.array(s.track)
        truth = track(tr[:, 0])
        err = np.hypot(tr[:, 1] - truth[:, 0], tr[:, 2] - truth[:, 1])
        return float(np.sqrt(np.mean(err**2)))

    truth = track(t_odo)
    dr_rmse = float(np.sqrt(np.mean(np.sum((dr[:, :2] - truth[:, :2]) ** 2, axis=1))))
    with_lines, points_only = rmse(runs[True]), rmse(runs[False])
    assert with_lines < 0.7 * points_only, (with_lines, points_only, dr_rmse)
    assert with_lines < 0.7 * dr_rmse, (with_lines, dr_rmse)


def test_demo_fusion_heading_error_model_follows_the_emulated_ins():
    from auvgw.commands.demo_parts import _fusion_config
    from auvgw.config.scenario import load_scenario
    from auvgw.ground.paths import config_file

    scn = load_scenario(config_file("scenarios/harbour.json"))
    f = _fusion_config("auv1", (0.0, 0.0, 4.0), scn.devices.ins.noise).filter
    assert (f.heading_error_sigma_deg, f.heading_error_tau_s) == (0.4, 400.0)
    f = _fusion_config("auv1", (0.0, 0.0, 4.0), {"heading_bias_deg": 0.2}).filter
    assert (f.heading_error_sigma_deg, f.heading_error_tau_s) == (0.2, 300.0)
    f = _fusion_config("auv1", (0.0, 0.0, 4.0), {"heading_deg": 0.05}).filter
    assert (f.heading_error_sigma_deg, f.heading_error_tau_s) == (0.05, 0.0)  # white
    f = _fusion_config("auv1", (0.0, 0.0, 4.0)).filter
    assert (f.heading_error_sigma_deg, f.heading_error_tau_s) == (0.3, 0.0)
