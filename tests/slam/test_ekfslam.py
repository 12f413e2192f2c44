"""The adaptive parts of EKF-SLAM (slam/landmark/ekfslam.py): Sage-Husa noise estimation and
Zhou's strong-tracking fading factor, on linear-Gaussian and small SLAM toys with a wrong R0."""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.slam.landmark.ekfslam import (
    EKFSLAM,
    fading_factor,
    innovation_power,
    observed_fading,
    sage_husa_gain,
    sage_husa_step,
)
from auvgw.slam.models import BicycleModel, RangeBearing

R_TRUE = np.array([0.1**2, np.radians(1.0) ** 2])  # range m^2, bearing rad^2


def _linear_sage_husa(scale: float, steps: int, rng: np.random.Generator) -> np.ndarray:
    """A 2-D random walk observed directly (z = x + v), Kalman-filtered with the Sage-Husa
    estimate of R started at ``scale * R_TRUE``. Returns the R estimate after every step."""
    q = np.array([0.05**2, 0.002**2])
    x = np.zeros(2)
    xe = np.zeros(2)
    p = np.zeros(2)
    r = scale * R_TRUE
    out = np.empty((steps, 2))
    for k in range(1, steps + 1):
        x = x + rng.normal(0.0, np.sqrt(q))
        z = x + rng.normal(0.0, np.sqrt(R_TRUE))
        p = p + q  # predict (H = I, F = I)
        v = z - xe
        r = sage_husa_step(r, v[None], p[None], sage_husa_gain(k, 0.98), 0.01 * scale * R_TRUE)
        kg = p / (p + r)
        xe = xe + kg * v
        p = (1.0 - kg) * p
        out[k - 1] = r
    return out


@pytest.mark.parametrize("scale", [10.0, 0.1])
def test_sage_husa_recovers_r_from_a_10x_wrong_start(scale: float) -> None:
    r = _linear_sage_husa(scale, 3000, np.random.default_rng(11))
    late = r[1000:].mean(axis=0) / R_TRUE
    np.testing.assert_allclose(late, 1.0, atol=0.1)
    # the fading memory: within a factor 3 of the truth after 100 steps (one noisy sample a step)
    assert np.all(np.abs(np.log(r[100:] / R_TRUE)) < np.log(3.0))
    assert np.abs(np.log(r[0] / R_TRUE)).max() > np.log(5.0)
    assert np.all(r > 0.0)


def test_sage_husa_weights_and_floor() -> None:
    b = 0.98
    assert sage_husa_gain(1, b) == pytest.approx(1.0 / (1.0 + b))
    assert sage_husa_gain(10_000, b) == pytest.approx(1.0 - b)
    with pytest.raises(ValueError, match="forgetting factor"):
        sage_husa_gain(1, 1.0)
    r0 = np.array([0.01, 3e-4])
    floor = np.array([1e-4, 1e-6])
    # the mean of v^2 - HPH^T enters with weight d, even where it is negative (unbiased) ...
    v = np.array([[0.3, 0.0], [0.1, 0.0]])
    hph = np.array([[0.01, 1e-4], [0.01, 1e-4]])
    r = sage_husa_step(r0, v, hph, 0.25, floor)
    np.testing.assert_allclose(r, 0.75 * r0 + 0.25 * np.array([0.04, -1e-4]))
    # ... and the floor on the result keeps R positive definite when innovations vanish
    r = sage_husa_step(r0, np.zeros((3, 2)), np.ones((3, 2)), 0.5, floor)
    np.testing.assert_array_equal(r, floor)


def test_fading_factor_only_when_innovations_exceed_the_prediction() -> None:
    rng = np.random.default_rng(5)
    w = 1.0 / R_TRUE
    m = 400
    hah = np.tile(R_TRUE * 0.5, (m, 1))  # H A H^T (diagonal)
    hqh = np.tile(R_TRUE * 0.2, (m, 1))  # H Q_acc H^T
    v = rng.normal(0.0, np.sqrt(hah + hqh + R_TRUE))  # innovations with the true R
    vk = innovation_power(v, w)
    # the filter assumes the true R: beta = 1 gives about 1, beta = 3 never fades
    assert fading_factor(vk, hah, hqh, R_TRUE, w, beta=3.0) == 1.0
    # R over-estimated 10x: innovations smaller than predicted -> no fading
    assert fading_factor(vk, hah, hqh, 10 * R_TRUE, w, beta=1.0) == 1.0
    # R under-estimated 10x: innovations larger than predicted -> lambda > 1, Zhou's value
    lam = fading_factor(vk, hah, hqh, 0.1 * R_TRUE, w, beta=1.0)
    expected = (vk - np.mean(hqh @ w) - 1.0 * (w @ (0.1 * R_TRUE))) / np.mean(hah @ w)
    assert lam == pytest.approx(expected)
    # tr(W(HAH + HQH + R)) = 1 + 0.4 + 2 = 3.4 on average; N / M = (3.4 - 0.4 - 0.2) / 1
    assert lam == pytest.approx(2.8, rel=0.1)
    assert fading_factor(vk, 0.0 * hah, hqh, 0.1 * R_TRUE, w, beta=1.0) == 1.0


def test_fading_scales_only_the_observed_vehicle_directions() -> None:
    """A line observes 2 of the 3 pose directions: T A T^T scales H A H^T by lambda and leaves
    the rest (the covariance given H x: along the wall) as it was; scaling the whole vehicle
    block instead let the along-wall variance grow by lambda at every scan until S was singular."""
    rng = np.random.default_rng(0)
    g = rng.standard_normal((3, 3))
    a = g @ g.T + 0.1 * np.eye(3)
    hv = rng.standard_normal((2, 3))
    lam = 7.0
    t = observed_fading(a, hv, lam)
    a2 = t @ a @ t.T
    np.testing.assert_allclose(hv @ a2 @ hv.T, lam * (hv @ a @ hv.T), rtol=1e-10)
    # what the scan cannot see, the covariance conditioned on Hv x, is unchanged
    def conditional(c: np.ndarray) -> np.ndarray:
        return c - c @ hv.T @ np.linalg.solve(hv @ c @ hv.T, hv @ c)

    np.testing.assert_allclose(conditional(a2), conditional(a), atol=1e-10)
    assert np.linalg.eigvalsh(a2 - a).min() > -1e-10  # only inflated
    assert np.linalg.matrix_rank(a2 - a, tol=1e-9) == 2
    # three independent rows observe everything: plain scaling
    np.testing.assert_allclose(
        (t3 := observed_fading(a, np.eye(3), lam)) @ a @ t3.T, lam * a, rtol=1e-10
    )


def _stationary_toy(
    mode: str, scale: float, scans: int, seed: int = 3
) -> tuple[EKFSLAM, np.ndarray, np.ndarray]:
    """EKF-SLAM on a vehicle jittering along x (speed noise only) among 8 landmarks 15 m away,
    observed every 0.2 s with the true R; the filter assumes ``scale * R``. Returns the filter,
    its fading factor after every scan and the final truth pose."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    lms = 15.0 * np.column_stack([np.cos(ang), np.sin(ang)])
    ids = np.arange(8)
    q = np.diag([0.3**2, np.radians(3.0) ** 2])
    motion, obs = BicycleModel(4.0), RangeBearing()
    f = EKFSLAM(motion, obs, q, np.diag(R_TRUE) * scale, adaptive=mode)
    x = np.zeros(3)
    lams = np.empty(scans)
    for s in range(scans):
        for _ in range(8):
            x = motion.f(x, np.array([rng.normal(0.0, 0.3), 0.0]), 0.025)
            f.predict(np.zeros(2), 0.025, rng)
        z = obs.h(x, lms) + rng.normal(0.0, np.sqrt(R_TRUE), (8, 2))
        f.update(z, rng, ids)
        lams[s] = f.last_lambda
    return f, lams, x


@pytest.mark.parametrize("scale", [10.0, 0.1])
def test_shekf_learns_the_observation_noise(scale: float) -> None:
    f, _, x = _stationary_toy("sage-husa", scale, 300)
    np.testing.assert_allclose(f.rdiag / R_TRUE, 1.0, atol=0.3)
    assert np.linalg.norm(f.estimate()[:2] - x[:2]) < 0.5


def test_stekf_is_plain_ekf_when_r_is_over_estimated() -> None:
    ekf, _, _ = _stationary_toy("none", 10.0, 100)
    st, lams, _ = _stationary_toy("strong-tracking", 10.0, 100)
    assert np.all(lams == 1.0)
    np.testing.assert_array_equal(st.xs, ekf.xs)
    np.testing.assert_array_equal(st.p, ekf.p)


def test_combined_fades_with_the_adapted_r() -> None:
    # with R0 10x too small, strong tracking alone sees too large innovations at every scan
    _, st_lams, _ = _stationary_toy("strong-tracking", 0.1, 200)
    assert np.mean(st_lams[20:] > 1.0) > 0.9
    # the combined filter computes N_k with the Sage-Husa R, which has caught up: no fading
    ca, ca_lams, _ = _stationary_toy("combined", 0.1, 200)
    np.testing.assert_allclose(ca.rdiag / R_TRUE, 1.0, atol=0.3)
    assert np.mean(ca_lams[100:] > 1.0) < 0.05


def test_bad_adaptive_parameters_are_rejected() -> None:
    args = (BicycleModel(4.0), RangeBearing(), np.eye(2), np.diag(R_TRUE))
    with pytest.raises(ValueError, match="adaptive must be one of"):
        EKFSLAM(*args, adaptive="kalman")
    with pytest.raises(ValueError, match="sh_forgetting"):
        EKFSLAM(*args, adaptive="sage-husa", sh_forgetting=1.5)
    with pytest.raises(ValueError, match="softening"):
        EKFSLAM(*args, adaptive="strong-tracking", st_beta=0.5)
