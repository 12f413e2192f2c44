"""MB-SLAM as an observability-constrained EKF (``mb-slam-oc``): the property it is built for."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from auvgw.slam.landmark.ekfslam import EKFSLAM
from auvgw.slam.magnetic.filters import MagneticSLAM, make_magnetic, null_space
from auvgw.slam.models import BicycleModel, RangeBearing, wrap_angle

Q = np.diag([0.04, math.radians(1.0) ** 2])
R = np.diag([0.01, math.radians(1.0) ** 2])
BEACONS = np.array([[10.0, 5.0], [-5.0, 12.0], [3.0, -9.0], [-8.0, -6.0]])
MODEL = BicycleModel(2.0)


def _drive(
    name: str, steps: int, seed: int, p0_heading: float = 0.0, check: bool = False
) -> tuple[MagneticSLAM, list[float], float]:
    """A circle among four beacons (known association), observed every 5th step; returns the
    filter, its pose NEES at each scan and the smallest heading variance after the first scan.
    ``check``: at every step, the filter's covariance propagation with the process noise off
    must carry ``N_k N_k^T`` to ``N_k+1 N_k+1^T`` ((O2) Phi N_k = N_k+1) and every
    observation Jacobian must annihilate the propagated null space ((O3) H N = 0)."""
    rng = np.random.default_rng(seed)
    f = make_magnetic(name, MODEL, Q, R, (0, 0, 0.3), (1, 1), known=True)
    f.p[2, 2] = p0_heading
    x = np.array([0.0, 0.0, 0.3])
    nees, low = [], math.inf
    for k in range(steps):
        u = np.array([3.0, 0.1])
        x = MODEL.f(x, u, 0.025)
        un = u + rng.standard_normal(2) * np.sqrt(np.diag(Q))
        if check and f.n_lm:
            n = f.null_space()
            trial = copy.deepcopy(f)
            trial.q[:] = 0.0
            kk = 3 + 2 * f.n_lm
            trial.p[:kk, :kk] = n @ n.T
            trial.predict(un, 0.025, rng)
            n1 = trial.null_space()
            np.testing.assert_allclose(trial.p[:kk, :kk], n1 @ n1.T, rtol=0, atol=1e-9)
        f.predict(un, 0.025, rng)
        if k % 5 == 4:
            z = RangeBearing().h(x, BEACONS) + rng.standard_normal((4, 2)) * np.sqrt(np.diag(R))
            for j in range(4):
                if check and f.n_lm:
                    idx = np.arange(f.n_lm)
                    _, hx, hm = f._h_blocks(idx)
                    h = f._dense_h(idx, hx, hm).reshape(2 * f.n_lm, -1)
                    assert np.abs(h @ f.null_space()).max() < 1e-9
                f.update_each(z[j : j + 1], ids=np.array([j]))
            low = min(low, float(f.p[2, 2]))
            e = f.xs[:3] - x
            e[2] = wrap_angle(e[2])
            nees.append(float(e @ np.linalg.solve(f.p[:3, :3], e)))
    return f, nees, low


def test_the_propagated_null_space_stays_unobservable() -> None:
    """(O1)-(O5): OC's propagation carries N_k to N_k+1 and every H annihilates it, after updates
    that moved the pose away from its prior (where the plain EKF's Jacobians do not)."""
    f, _, _ = _drive("mb-slam-oc", 60, 0, check=True)
    assert f.n_lm == 4
    assert not np.allclose(f.lm_null, f.xs[3:11].reshape(4, 2))  # the beacons moved since
    n = null_space(f.x_first[:2], f.lm_null)
    np.testing.assert_array_equal(n, f.null_space())
    assert n.shape == (11, 3) and np.linalg.matrix_rank(n) == 3
    # eq. (22) at the latest estimates (the plain EKF's) does not annihilate it: (O5) is needed
    idx = np.arange(4)
    _, hx, hm = EKFSLAM._h_blocks(f, idx)
    assert np.abs(f._dense_h(idx, hx, hm).reshape(8, -1) @ n).max() > 1e-3


def test_no_heading_information_from_relative_observations() -> None:
    """Beacons seen from the vehicle carry no information on the absolute heading: OC keeps its
    heading variance at (above) its start; the plain EKF gains heading information it cannot
    have (the inconsistency Huang et al. explain)."""
    _, _, low_oc = _drive("mb-slam-oc", 400, 1, p0_heading=1e-2)
    _, _, low_ekf = _drive("mb-slam", 400, 1, p0_heading=1e-2)
    assert low_oc >= 1e-2 * (1 - 1e-6)
    assert low_ekf < 0.5e-2


def test_nees_in_the_band_on_an_easy_scenario() -> None:
    """Eight runs of the circle: OC's run-averaged pose NEES lies in the chi-square 95 % band
    of an 8-run average (chi2(24) / 8: 1.55-4.96) at most scans."""
    runs = np.array([_drive("mb-slam-oc", 250, s)[1] for s in range(8)])
    avg = runs.mean(axis=0)
    assert 1.55 < avg.mean() < 4.96
    assert np.mean((avg > 1.55) & (avg < 4.96)) > 0.8


def test_oc_is_mb_slam_only() -> None:
    with pytest.raises(ValueError, match="no acoustic anchor"):
        MagneticSLAM(MODEL, Q, R, anchor_xy=(1.0, 1.0), oc=True)
    f = make_magnetic("mb-slam-oc", MODEL, Q, R, (0, 0, 0), (1, 1))
    assert f.oc and not f.fej and f.anchor is None
    f.update_each(np.array([[5.0, 0.2]]))
    f.forget_landmarks()
    assert f.lm_null.shape == (0, 2)
