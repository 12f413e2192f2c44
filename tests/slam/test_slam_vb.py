"""VB noise estimation against hand-computed Sarkka-Nummenmaa (2009) steps."""

from __future__ import annotations

import numpy as np

from auvgw.slam.landmark.association import KnownAssociation
from auvgw.slam.landmark.vb import VBAFastSLAM, VBAUFastSLAM, VBSettings, vb_noise_step
from auvgw.slam.models import BicycleModel, RangeBearing


def test_noise_step_matches_scalar_sarkka_nummenmaa():
    # scalar random walk, H = 2: m- = 1, P- = 0.5, y = 3.7; alpha- = 3, beta- = 0.6
    h, m_prior, p_prior, y = 2.0, 1.0, 0.5, 3.7
    alpha = 3.0 + 0.5
    beta_prior = 0.6
    beta = beta_prior
    for _ in range(4):  # the paper's loop, written out by hand
        sigma2 = beta / alpha
        s = h * h * p_prior + sigma2
        k = p_prior * h / s
        m = m_prior + k * (y - h * m_prior)
        p = p_prior - k * k * s
        beta_hand = beta_prior + 0.5 * (y - h * m) ** 2 + 0.5 * h * h * p
        e, pzz = vb_noise_step(
            np.array([[h * h * p_prior]]), np.array([y - h * m_prior]), np.array([beta / alpha])
        )
        np.testing.assert_allclose(pzz, [[s]])
        beta = beta_prior + 0.5 * e[0]
        np.testing.assert_allclose(beta, beta_hand, rtol=1e-12)
    assert beta > beta_prior


def one_landmark_filter(cls, settings, pose_cov):
    f = cls(
        BicycleModel(4.0),
        RangeBearing(),
        np.diag([0.09, 0.003]),
        np.diag([0.01, 3e-4]),
        n_particles=1,
        association=KnownAssociation(),
        vb=settings,
    )
    f.update(np.array([[10.0, 0.3]]), np.random.default_rng(0), np.array([7]))
    f.pcov[:] = pose_cov
    f.cov[0, 0] = np.array([[0.04, 0.01], [0.01, 0.02]])
    return f


def test_pose_stage_is_sarkka_nummenmaa_with_tied_components():
    settings = VBSettings(
        rho=0.9, eta0=10.0, pose_iterations=3, feature_iterations=0, outlier_dof=None
    )
    pose_cov = np.array([[0.05, 0.01, 0.0], [0.01, 0.08, 0.002], [0.0, 0.002, 0.004]])
    f = one_landmark_filter(VBAFastSLAM, settings, pose_cov)
    eta_prior, xi_prior = 0.9 * f.eta[0].copy(), 0.9 * f.xi[0].copy()
    x, mu, sig = f.x[0].copy(), f.mu[0, 0].copy(), f.cov[0, 0].copy()
    z = np.array([9.2, 0.42])  # a 0.8 m range error: the noise estimate must grow
    obs = RangeBearing()
    hx, hm = obs.jacobians(x, mu)
    s = hx @ pose_cov @ hx.T + hm @ sig @ hm.T
    v = obs.residual(z, obs.h(x, mu))
    eta = eta_prior + 0.5
    xi = xi_prior.copy()
    for _ in range(3):
        pzz = s + np.diag(xi / eta)
        g = np.linalg.solve(pzz, v)
        r = v - s @ g
        c = s - s @ np.linalg.solve(pzz, s)
        xi = xi_prior + 0.5 * (r * r + np.diag(c))
    f.update(z[None], np.random.default_rng(1), np.array([7]))
    np.testing.assert_allclose(f.eta[0], eta)
    np.testing.assert_allclose(f.xi[0], xi, rtol=1e-10)
    assert f.noise_estimate()[0, 0] > 0.0102  # the range variance adapted upwards from R0


def test_feature_stage_continues_the_iteration_and_updates_with_the_estimate():
    settings = VBSettings(
        rho=0.95, eta0=20.0, pose_iterations=3, feature_iterations=2, outlier_dof=None
    )
    for cls in (VBAFastSLAM, VBAUFastSLAM):
        f = one_landmark_filter(cls, settings, np.zeros((3, 3)))  # exact pose: both stages alike
        eta_prior, xi_prior = 0.95 * f.eta[0].copy(), 0.95 * f.xi[0].copy()
        x, mu, sig = f.x[0].copy(), f.mu[0, 0].copy(), f.cov[0, 0].copy()
        z = np.array([10.4, 0.28])
        obs = RangeBearing()
        _, hm = obs.jacobians(x, mu)
        s = hm @ sig @ hm.T
        v = obs.residual(z, obs.h(x, mu))
        eta = eta_prior + 0.5
        xi = xi_prior.copy()
        for _ in range(5):
            pzz = s + np.diag(xi / eta)
            r = v - s @ np.linalg.solve(pzz, v)
            c = s - s @ np.linalg.solve(pzz, s)
            xi = xi_prior + 0.5 * (r * r + np.diag(c))
        pzz = s + np.diag(xi / eta)
        k = sig @ hm.T @ np.linalg.inv(pzz)
        f.update(z[None], np.random.default_rng(2), np.array([7]))
        tol = 1e-9 if cls is VBAFastSLAM else 2e-3  # the UKF keeps second-order terms
        np.testing.assert_allclose(f.xi[0], xi, rtol=tol * 10)
        np.testing.assert_allclose(f.mu[0, 0], mu + k @ v, atol=tol)
        np.testing.assert_allclose(f.cov[0, 0], sig - k @ pzz @ k.T, atol=tol)


def test_per_observation_scale_is_the_student_t_vb_step():
    """With ``outlier_dof = nu`` each observation j has noise ``lambda_j R``; one VB pass gives
    ``1/E[1/lambda_j] = (nu + sum E_j / R) / (nu + 2)`` and the level's scale grows by
    ``E_j / 2`` weighted with ``E[1/lambda_j]`` (exact pose, so the pose stage changes nothing)."""
    nu = 4.0
    settings = VBSettings(rho=0.95, eta0=20.0, pose_iterations=1, feature_iterations=1,
                          outlier_dof=nu)  # fmt: skip
    f = one_landmark_filter(VBAFastSLAM, settings, np.zeros((3, 3)))
    eta_prior, xi_prior = 0.95 * f.eta[0].copy(), 0.95 * f.xi[0].copy()
    x, mu, sig = f.x[0].copy(), f.mu[0, 0].copy(), f.cov[0, 0].copy()
    z = np.array([11.5, 0.3])  # a 1.5 m range error: 15 sigma of R0
    obs = RangeBearing()
    _, hm = obs.jacobians(x, mu)
    s = hm @ sig @ hm.T
    v = obs.residual(z, obs.h(x, mu))
    eta = eta_prior + 0.5
    level = xi_prior / eta
    lam, xi = 1.0, xi_prior.copy()
    # the pose stage's pass sees the same innovation covariance S = H_m Sigma H_m^T (exact
    # pose), and the feature stage continues from its lambda and xi: two identical passes
    for _ in range(2):
        r_j = level * lam
        pzz = s + np.diag(r_j)
        r = v - s @ np.linalg.solve(pzz, v)
        c = s - s @ np.linalg.solve(pzz, s)
        e = r * r + np.diag(c)
        lam = (nu + (e / level).sum()) / (nu + 2)
        xi = xi_prior + 0.5 * e / lam
        level = xi / eta
    f.update(z[None], np.random.default_rng(2), np.array([7]))
    np.testing.assert_allclose(f.xi[0], xi, rtol=1e-9)
    assert lam > 5.0  # the outlier's own noise is inflated ...
    assert f.noise_estimate()[0, 0] < 1.3 * 0.01  # ... while the level barely moves
    pzz = s + np.diag(level * lam)
    k = sig @ hm.T @ np.linalg.inv(pzz)
    np.testing.assert_allclose(f.mu[0, 0], mu + k @ v, atol=1e-9)


def test_per_observation_noise_resists_gross_outliers():
    """One particle, exact odometry, four landmarks seen every scan; one observation per scan is
    a 30-sigma multipath return. The per-observation VB keeps the map near the truth; the tied
    noise (every observation of a scan shares one R) lets the outliers pull the features."""
    rng = np.random.default_rng(4)
    lm = np.array([[10.0, 5.0], [12.0, -6.0], [20.0, 1.0], [15.0, 10.0]])
    obs = RangeBearing()
    r0 = np.diag([0.01, 3e-4])
    errors = {}
    for nu in (None, 4.0):
        f = VBAFastSLAM(BicycleModel(4.0), obs, np.diag([1e-8, 1e-8]), r0, n_particles=1,
                        association=KnownAssociation(), vb=VBSettings(outlier_dof=nu))  # fmt: skip
        g = np.random.default_rng(7)
        for k in range(60):
            z = obs.h(np.zeros(3), lm) + g.standard_normal((4, 2)) * np.sqrt(np.diag(r0))
            if k > 0:  # the features are first seen clean
                z[k % 4] += 30 * np.sqrt(np.diag(r0)) * np.sign(g.standard_normal(2))
            f.update(z, rng, np.arange(4))
        errors[nu] = np.abs(f.landmarks().mean - lm).max()
    assert errors[4.0] < 0.15  # m, features 11-20 m away (0.58 m with the tied noise)
    assert errors[None] > 3 * errors[4.0]


def test_default_start_is_r0_and_explicit_xi0_follows_eq19():
    r0 = np.diag([0.01, 3e-4])
    f = VBAFastSLAM(BicycleModel(), RangeBearing(), np.eye(2) * 1e-4, r0, n_particles=3)
    np.testing.assert_allclose(f.noise_estimate(), np.tile(np.diag(r0), (3, 1)))
    g = VBAFastSLAM(
        BicycleModel(),
        RangeBearing(),
        np.eye(2) * 1e-4,
        r0,
        n_particles=3,
        vb=VBSettings(eta0=50.0, xi0=(5.0, 5.0)),
    )
    np.testing.assert_allclose(g.noise_estimate(), 0.1)  # eq. (19): xi / eta


def test_low_rank_innovation_algebra_matches_dense_matrices():
    from auvgw.slam.landmark.fastslam import LowRank

    rng = np.random.default_rng(9)
    n, m, k = 4, 5, 7
    u = rng.normal(size=(n, 2 * m, k)) * 0.3
    a = rng.normal(size=(n, m, 2, 2))
    blocks = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(2)
    v = rng.normal(size=(n, m, 2))
    lr = LowRank(u, blocks, v)
    for i in range(n):
        b = np.zeros((2 * m, 2 * m))
        for j in range(m):
            b[2 * j : 2 * j + 2, 2 * j : 2 * j + 2] = blocks[i, j]
        pzz = b + u[i] @ u[i].T
        vi = v[i].reshape(-1)
        pinv = np.linalg.inv(pzz)
        np.testing.assert_allclose(lr.pzz_inv_v()[i], pinv @ vi, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lr.pzz_inv_diag()[i], np.diag(pinv), rtol=1e-9)
        np.testing.assert_allclose(lr.quad()[i], vi @ pinv @ vi, rtol=1e-9)
        np.testing.assert_allclose(lr.logdet()[i], np.linalg.slogdet(pzz)[1], rtol=1e-9)
        np.testing.assert_allclose(lr.z[i], u[i].T @ pinv @ vi, rtol=1e-9, atol=1e-12)
