"""The landmark SLAM filters on short runs of Bailey's simulator."""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.slam.evaluation.simulate import simulate
from auvgw.slam.landmark import ALGORITHMS, make_filter
from auvgw.slam.models import BicycleModel, LineFeature, RangeBearing, VelocityModel
from auvgw.testing.slam_helpers import bailey_scenario, run_filter

PARTICLE_FILTERS = [
    "fastslam1",
    "fastslam2",
    "ufastslam",
    "vb-afastslam",
    "vb-aufastslam",
    "vrfastslam",
]


@pytest.fixture(scope="module")
def dense(shared_data, tmp_path_factory):
    return bailey_scenario(shared_data, tmp_path_factory.mktemp("slam"), "densemap")


@pytest.fixture(scope="module")
def clean_run(dense):
    return simulate(
        dense, np.random.default_rng(0), control_noise=False, sensor_noise=False, max_steps=1200
    )


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_one_particle_without_noise_reproduces_the_truth(name, clean_run):
    run = clean_run
    # zero process noise; a small nominal R so that the UKF's second-order terms are negligible
    f = make_filter(
        name,
        BicycleModel(run.wheelbase),
        RangeBearing(),
        np.zeros((2, 2)),
        np.diag([1e-4, 1e-6]),
        n_particles=1,
        x0=run.truth[0],
    )
    est = run_filter(f, run, np.random.default_rng(1))
    truth = run.truth[run.obs_step]
    np.testing.assert_allclose(est[:, :2], truth[:, :2], atol=1e-3)
    np.testing.assert_allclose(np.angle(np.exp(1j * (est[:, 2] - truth[:, 2]))), 0, atol=1e-5)
    lm = f.landmarks()
    seen = np.unique(np.concatenate(run.obs_ids))
    assert sorted(lm.ids.tolist()) == sorted(seen.tolist())
    np.testing.assert_allclose(lm.mean, run.landmarks[lm.ids], atol=1e-3)
    assert lm.cov.shape == (len(seen), 2, 2)
    assert np.all(np.linalg.eigvalsh(lm.cov) > 0)


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_noisy_run_beats_dead_reckoning(name, dense):
    run = simulate(dense, np.random.default_rng(7), max_steps=2400)
    f = make_filter(
        name,
        BicycleModel(run.wheelbase),
        RangeBearing(),
        run.q,
        run.r,
        n_particles=20,
        x0=run.truth[0],
    )
    est = run_filter(f, run, np.random.default_rng(8))
    err = np.hypot(*(est[:, :2] - run.truth[run.obs_step, :2]).T)
    dr = run.truth[0].copy()
    model = BicycleModel(run.wheelbase)
    dead = []
    for k, u in enumerate(run.controls):
        dr = model.f(dr, u, run.dt)
        if k + 1 in set(run.obs_step.tolist()):
            dead.append(dr[:2])
    dead_err = np.hypot(*(np.array(dead) - run.truth[run.obs_step, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.5 * np.sqrt(np.mean(dead_err**2))
    if name in PARTICLE_FILTERS:
        assert 1.0 <= f.neff <= 20.0
    else:
        assert np.isnan(f.neff)


def test_nearest_neighbour_builds_the_same_map_as_known_association(clean_run):
    run = clean_run
    maps = {}
    for assoc in ("known", "nn"):
        f = make_filter(
            "fastslam2",
            BicycleModel(run.wheelbase),
            RangeBearing(),
            np.zeros((2, 2)),
            run.r,
            n_particles=3,
            x0=run.truth[0],
            association=assoc,
        )
        run_filter(f, run, np.random.default_rng(2))
        maps[assoc] = f.landmarks().mean
    known, nn = maps["known"], maps["nn"]
    assert len(nn) == len(known)
    d = np.linalg.norm(nn[:, None] - known[None], axis=-1).min(axis=1)
    assert d.max() < 1e-6


def test_vrfastslam_never_resamples_and_keeps_neff_above_threshold(dense):
    run = simulate(dense, np.random.default_rng(3), max_steps=2400, burst_n=4, burst_p=0.3)
    f = make_filter(
        "vrfastslam",
        BicycleModel(run.wheelbase),
        RangeBearing(),
        run.q,
        run.r,
        n_particles=30,
        x0=run.truth[0],
    )
    run_filter(f, run, np.random.default_rng(4))
    assert f.resample_count == 0
    assert f.reduction_count > 0
    assert f.neff_of_weights() >= 0.5 * 30 - 1e-9


def test_vb_noise_estimate_follows_noisier_observations(dense):
    run = simulate(dense, np.random.default_rng(5), max_steps=2400, burst_n=6.0, burst_p=1.0)
    f = make_filter(
        "vb-afastslam",
        BicycleModel(run.wheelbase),
        RangeBearing(),
        run.q,
        run.r,
        n_particles=10,
        x0=run.truth[0],
    )
    run_filter(f, run, np.random.default_rng(6))
    est = np.average(f.noise_estimate(), axis=0, weights=f.weights())
    ratio = est / np.diag(run.r)
    assert np.all(ratio > 3.0), ratio  # all observations have 6 R0; R0 is the starting point


def test_unknown_names_and_missing_ids_are_clear_errors():
    with pytest.raises(ValueError, match="unknown algorithm"):
        make_filter("fastslam3", BicycleModel(), RangeBearing(), np.eye(2), np.eye(2))
    with pytest.raises(ValueError, match="unknown association"):
        make_filter(
            "fastslam1", BicycleModel(), RangeBearing(), np.eye(2), np.eye(2), association="psychic"
        )
    f = make_filter("fastslam1", BicycleModel(), RangeBearing(), np.eye(2), np.eye(2))
    with pytest.raises(ValueError, match="needs the observation ids"):
        f.update(np.array([[1.0, 0.0]]), np.random.default_rng(0))


@pytest.mark.parametrize("name", ["fastslam1", "fastslam2", "ufastslam", "vb-aufastslam", "ekf"])
def test_line_features_are_mapped_without_noise(name, clean_run):
    """The filters are generic in the observation model: (rho, theta) lines of the VR paper."""
    obs = LineFeature()
    # four walls of a basin, in normal form (rho m, theta rad)
    lines = np.array([[120.0, 0.0], [90.0, np.pi / 2], [110.0, np.pi], [100.0, -np.pi / 2]])
    run = clean_run
    f = make_filter(
        name,
        BicycleModel(run.wheelbase),
        obs,
        np.zeros((2, 2)),
        np.diag([1e-4, 1e-6]),
        n_particles=1,
        x0=run.truth[0],
    )
    rng = np.random.default_rng(0)
    scans = set(run.obs_step.tolist())
    for k, u in enumerate(run.controls):
        f.predict(u, run.dt, rng)
        if k + 1 in scans:
            f.update(obs.h(run.truth[k + 1], lines), rng, np.arange(4))
    np.testing.assert_allclose(f.estimate()[:2], run.truth[-1, :2], atol=1e-3)
    lm = f.landmarks()
    np.testing.assert_allclose(obs.wrap_feature(lm.mean - lines[lm.ids]), 0.0, atol=1e-3)


@pytest.mark.parametrize("name", ["fastslam1", "ufastslam", "vb-aufastslam", "caekf"])
def test_velocity_model_of_eq3_drives_the_filters(name):
    """The AUV model (DVL body velocities and yaw rate, VB eq. 3) instead of Bailey's car."""
    model, obs = VelocityModel(), RangeBearing()
    lms = np.array([[x, y] for x in range(-40, 41, 20) for y in range(-40, 41, 20)], float)
    u = np.array([1.5, 0.2, 0.05])  # a slow circle, drifting sideways
    truth = [np.zeros(3)]
    for _ in range(800):
        truth.append(model.f(truth[-1], u, 0.1))
    f = make_filter(name, model, obs, np.zeros((3, 3)), np.diag([1e-4, 1e-6]), n_particles=1)
    rng = np.random.default_rng(0)
    for k in range(800):
        f.predict(u, 0.1, rng)
        if k % 5 == 4:
            z = obs.h(truth[k + 1], lms)
            vis = z[:, 0] < 25.0
            f.update(z[vis], rng, np.nonzero(vis)[0])
    np.testing.assert_allclose(f.estimate()[:2], truth[-1][:2], atol=1e-3)
    lm = f.landmarks()
    assert len(lm.ids) > 5
    np.testing.assert_allclose(lm.mean, lms[lm.ids], atol=1e-3)


def test_absolute_heading_conditions_the_pose_gaussian_and_weighs_particles():
    """``observe_heading``: a Kalman update with ``H = [0, 0, 1]`` on each particle's pose
    Gaussian (FastSLAM 2.0, UFastSLAM) and weights ``N(v; 0, P_hh + var)``; FastSLAM 1.0 only
    weighs (``N(v; 0, var)``)."""
    rng = np.random.default_rng(0)
    q, r = np.diag([0.01, 0.01, 1e-4]), np.diag([0.01, 3e-4])
    for name in ("fastslam2", "ufastslam"):
        f = make_filter(name, VelocityModel(), RangeBearing(), q, r, n_particles=2,
                        x0=(0.0, 0.0, 0.1))  # fmt: skip
        p = np.array([[0.04, 0.0, 0.002], [0.0, 0.05, 0.001], [0.002, 0.001, 0.01]])
        f.pcov[:] = p
        f.x[1, 2] = 0.3
        f.logw[:] = 0.0
        var = 0.0025
        f.observe_heading(0.2, var, rng)
        s = p[2, 2] + var
        k = p[:, 2] / s
        for i, h in enumerate((0.1, 0.3)):
            v = 0.2 - h
            np.testing.assert_allclose(f.x[i], np.array([0.0, 0.0, h]) + k * v, atol=1e-12)
            np.testing.assert_allclose(f.pcov[i], p - np.outer(k, p[2]), atol=1e-12)
        w = np.exp(f.logw - f.logw.max())
        assert w[0] == pytest.approx(1.0) and w[1] == pytest.approx(1.0)  # |v| equal: 0.1
    f1 = make_filter("fastslam1", VelocityModel(), RangeBearing(), q, r, n_particles=3,
                     x0=(0.0, 0.0, 0.0), resample_fraction=0.0)  # fmt: skip
    f1.x[:, 2] = [0.0, 0.05, -0.2]
    f1.logw[:] = 0.0
    f1.observe_heading(0.05, 0.01, rng)
    w = np.exp(f1.logw - f1.logw.max())
    np.testing.assert_allclose(w, np.exp(-0.5 * (np.array([0.05, 0.0, 0.25]) ** 2 / 0.01)),
                               rtol=1e-9)  # fmt: skip
