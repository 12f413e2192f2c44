"""Unscented transform: filterpy's Merwe sigma points and the closed form on a linear model."""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.slam.landmark.unscented import UTParams, sigma_points, ut_cross, ut_moments


def random_cov(rng, n):
    a = rng.normal(size=(n, n))
    return a @ a.T + 0.1 * np.eye(n)


@pytest.mark.parametrize(
    "params", [UTParams(0.002, 2.0, 0.0), UTParams(0.5, 2.0, 1.0), UTParams(1.0, 0.0, 3.0)]
)
def test_linear_model_matches_closed_form(params):
    rng = np.random.default_rng(3)
    n, d = 4, 3
    mean = rng.normal(size=n)
    cov = random_cov(rng, n)
    a = rng.normal(size=(d, n))
    b = rng.normal(size=d)
    chi = sigma_points(mean, cov, params)
    y = chi @ a.T + b
    m, c, e, delta = ut_moments(y, params)
    np.testing.assert_allclose(m, a @ mean + b, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(c, a @ cov @ a.T, rtol=1e-6, atol=1e-7)
    _, _, ex, dx = ut_moments(chi, params)
    np.testing.assert_allclose(ut_cross(ex, dx, e, delta, params), cov @ a.T, rtol=1e-6, atol=1e-7)


def test_batched_sigma_points_match_one_by_one():
    rng = np.random.default_rng(4)
    means = rng.normal(size=(5, 3))
    covs = np.stack([random_cov(rng, 3) for _ in range(5)])
    p = UTParams(0.3, 2.0, 0.0)
    batch = sigma_points(means, covs, p)
    for i in range(5):
        np.testing.assert_allclose(batch[i], sigma_points(means[i], covs[i], p))


def test_matches_filterpy_merwe_sigma_points():
    filterpy = pytest.importorskip("filterpy.kalman")
    rng = np.random.default_rng(5)
    for alpha, beta, kappa in [(0.5, 2.0, 0.0), (0.1, 2.0, 1.0), (1.0, 0.0, 2.0)]:
        n = 3
        mean = rng.normal(size=n)
        cov = random_cov(rng, n)
        fp = filterpy.MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
        ours = UTParams(alpha, beta, kappa)
        np.testing.assert_allclose(
            sigma_points(mean, cov, ours), fp.sigma_points(mean, cov), atol=1e-10
        )
        wm, wc, _ = ours.weights(n)
        np.testing.assert_allclose(wm, fp.Wm)
        np.testing.assert_allclose(wc, fp.Wc)
        # a non-linear transform: same moments as filterpy's unscented_transform
        chi = fp.sigma_points(mean, cov)
        y = np.column_stack([np.sin(chi[:, 0]) * chi[:, 1], chi[:, 2] ** 2 + chi[:, 0]])
        m_ref, c_ref = filterpy.unscented_transform(y, fp.Wm, fp.Wc)
        m, c, _, _ = ut_moments(y, ours)
        np.testing.assert_allclose(m, m_ref, atol=1e-9)
        np.testing.assert_allclose(c, c_ref, atol=1e-9)


def test_angular_component_wraps():
    p = UTParams(0.5, 2.0, 0.0)
    chi = sigma_points(np.array([np.pi - 0.01]), np.array([[0.01]]), p)
    y = (chi + np.pi) % (2 * np.pi) - np.pi  # sigma points straddle the +-pi cut
    m, c, _, _ = ut_moments(y, p, angular=(True,))
    assert abs(abs(m[0]) - (np.pi - 0.01)) < 1e-9
    np.testing.assert_allclose(c, [[0.01]], rtol=1e-9)
