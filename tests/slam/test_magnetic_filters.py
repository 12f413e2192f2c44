"""AMB-SLAM / MB-SLAM filters: the acoustic anchor update against a hand-computed EKF step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from auvgw.slam.magnetic.filters import MagneticSLAM, make_magnetic
from auvgw.slam.models import BicycleModel


def _filter(anchor: tuple[float, float] | None = (10.0, 0.0)) -> MagneticSLAM:
    f = MagneticSLAM(BicycleModel(2.0), np.diag([0.09, 0.0027]), np.diag([0.01, 3e-4]),
                     anchor_xy=anchor)  # fmt: skip
    f.p[:3, :3] = np.diag([1.0, 1.0, 0.01])
    return f


def test_anchor_update_matches_hand_computed_ekf_step() -> None:
    f = _filter()
    # a beacon in the state, uncorrelated with the vehicle: it must not move
    f.update_each(np.array([[5.0, math.pi / 2]]))
    assert f.n_lm == 1
    f.p[:3, 3:5] = 0.0
    f.p[3:5, :3] = 0.0
    lm_before = f.xs[3:5].copy()
    p_lm_before = f.p[3:5, 3:5].copy()
    f.xs[:3] = 0.0
    f.p[:3, :3] = np.diag([1.0, 1.0, 0.01])
    # anchor at (10, 0) from (0, 0, 0): h = (10, 0), H = [[-1, 0, 0], [0, -0.1, -1]]
    # R = diag(0.25, 4e-4): S = diag(1 + 0.25, 0.1^2 * 1 + 1^2 * 0.01 + 4e-4) = diag(1.25, 0.0204)
    # W = P H^T S^-1 = [[-0.8, 0], [0, -0.1 / 0.0204], [0, -0.01 / 0.0204]]
    # v = (9.5 - 10, 0.01 - 0) -> x+ = (0.4, -0.001/0.0204, -0.0001/0.0204)
    d2 = f.anchor_update(np.array([9.5, 0.01]), np.diag([0.25, 4e-4]))
    np.testing.assert_allclose(f.xs[:3], [0.4, -0.001 / 0.0204, -0.0001 / 0.0204], rtol=1e-12)
    # P+ = P - W S W^T: x: 1 - 0.64 * 1.25 = 0.2; y: 1 - 0.01 / 0.0204; phi: 0.01 - 1e-4/0.0204
    # cross y-phi: 0 - (0.1 * 0.01) / 0.0204
    expect = np.array([
        [0.2, 0.0, 0.0],
        [0.0, 1 - 0.01 / 0.0204, -0.001 / 0.0204],
        [0.0, -0.001 / 0.0204, 0.01 - 1e-4 / 0.0204],
    ])  # fmt: skip
    np.testing.assert_allclose(f.p[:3, :3], expect, rtol=1e-12, atol=1e-15)
    assert d2 == pytest.approx(0.25 / 1.25 + 1e-4 / 0.0204)
    np.testing.assert_array_equal(f.xs[3:5], lm_before)
    np.testing.assert_allclose(f.p[3:5, 3:5], p_lm_before, rtol=1e-14, atol=1e-15)


def test_range_only_anchor_and_names() -> None:
    f = _filter()
    f.anchor_update(np.array([9.0]), np.array([[0.25]]))
    # only x moves: H = [-1, 0, 0]; W = [-1/1.25, 0, 0]; x+ = -0.8 * (9 - 10) = 0.8
    np.testing.assert_allclose(f.xs[:3], [0.8, 0.0, 0.0])
    with pytest.raises(ValueError, match="no acoustic"):
        _filter(None).anchor_update(np.array([1.0]), np.eye(1))
    q, r = np.diag([0.09, 0.0027]), np.diag([0.01, 3e-4])
    dr = make_magnetic("dr", BicycleModel(2.0), q, r, (0, 0, 0), (1, 1))
    dr.update_each(np.array([[5.0, 0.0]]))
    assert dr.n_lm == 0 and dr.anchor is None
    assert make_magnetic("mb-slam", BicycleModel(2.0), q, r, (0, 0, 0), (1, 1)).anchor is None
    with pytest.raises(ValueError, match="unknown magnetic"):
        make_magnetic("x", BicycleModel(2.0), q, r, (0, 0, 0), (1, 1))


def test_gates_and_forgetting() -> None:
    f = _filter()
    f.p[:3, :3] = np.diag([1e-4, 1e-4, 1e-6])
    f.update_each(np.array([[5.0, 0.5]]))
    f.update_each(np.array([[5.05, 0.51]]))  # close: associated, no new beacon
    assert f.n_lm == 1
    f.update_each(np.array([[5.0, -1.5]]))  # far beyond the augment gate: a new beacon
    assert f.n_lm == 2
    f.forget_landmarks()
    assert f.n_lm == 0 and np.all(f.p[3:7] == 0)
    f.update_each(np.array([[5.0, 0.5]]))
    assert f.n_lm == 1


def _pair(fej_first: bool = True) -> tuple[MagneticSLAM, MagneticSLAM]:
    q, r = np.diag([0.09, 0.0027]), np.diag([0.01, 3e-4])
    ekf = make_magnetic("mb-slam", BicycleModel(2.0), q, r, (0, 0, 0.3), (1, 1))
    fej = make_magnetic("mb-slam-fej", BicycleModel(2.0), q, r, (0, 0, 0.3), (1, 1))
    assert fej.fej and not ekf.fej and fej.anchor is None
    return ekf, fej


def test_fej_equals_the_ekf_until_an_update() -> None:
    """Without updates the first estimates are the latest ones: FEJ's prediction is the EKF's."""
    ekf, fej = _pair()
    for k in range(50):
        u = np.array([5.0, 0.2 * math.sin(k / 7)])
        ekf.predict(u, 0.025, np.random.default_rng(0))
        fej.predict(u, 0.025, np.random.default_rng(0))
    np.testing.assert_allclose(fej.xs[:3], ekf.xs[:3], rtol=0, atol=0)
    np.testing.assert_allclose(fej.p[:3, :3], ekf.p[:3, :3], rtol=1e-12, atol=1e-15)
    assert np.linalg.matrix_rank(fej.p[:3, :3]) == 3


def test_fej_jacobians_are_evaluated_at_the_first_estimates() -> None:
    """Huang et al. 2008: eq. (22) at the pose's prior and each beacon's first estimate, eq. (20)
    with the displacement from the prior; the EKF re-linearises at the updated estimates."""
    ekf, fej = _pair()
    prior = fej.xs[:3].copy()  # the pose's prior at this step (no prediction in between)
    for f in (ekf, fej):
        f.p[:3, :3] = np.diag([0.5, 0.5, 0.01])
        f.update_each(np.array([[8.0, 0.4]]))  # adds beacon 0
    first = fej.xs[3:5].copy()
    np.testing.assert_array_equal(fej.lm_first, [first])
    for f in (ekf, fej):
        f.update_each(np.array([[7.9, 0.41]]))  # associated: moves the pose and the beacon
    assert not np.allclose(fej.xs[3:5], first)
    _, hx, hm = fej._h_blocks(np.array([0]))
    hx0, hm0 = fej.obs.jacobians(prior, first[None])
    np.testing.assert_array_equal(hx, hx0)
    np.testing.assert_array_equal(hm, hm0)
    _, hx_e, _ = ekf._h_blocks(np.array([0]))
    np.testing.assert_allclose(hx_e, ekf.obs.jacobians(ekf.xs[:3], ekf.xs[3:5][None])[0])
    assert not np.allclose(hx_e, hx)
    # the prediction after the update: F uses p_k+1|k - p_k|k-1, not p_k+1|k - p_k|k
    u = np.array([5.0, 0.1])
    fej.xs[:2] += (0.3, -0.2)  # as an update that moved the pose would
    p_before, post = fej.p[:3, :3].copy(), fej.xs[:3].copy()
    fej.predict(u, 0.025, np.random.default_rng(0))
    new = BicycleModel(2.0).f(post, u, 0.025)
    fx = np.eye(3)
    fx[0, 2], fx[1, 2] = -(new[1] - prior[1]), new[0] - prior[0]
    _, fu = BicycleModel(2.0).jacobians(post, u, 0.025)
    expect = fx @ p_before @ fx.T + fu @ fej.q @ fu.T
    np.testing.assert_allclose(fej.p[:3, :3], expect, rtol=1e-12)
    assert not np.allclose(fx, BicycleModel(2.0).jacobians(post, u, 0.025)[0])
    np.testing.assert_array_equal(fej.x_first, fej.xs[:3])
    fej.forget_landmarks()
    assert fej.lm_first.shape == (0, 2)


def test_acoustic_only_uses_the_anchor_and_no_beacon() -> None:
    q, r = np.diag([0.09, 0.0027]), np.diag([0.01, 3e-4])
    f = make_magnetic("acoustic-only", BicycleModel(2.0), q, r, (0, 0, 0), (10, 0))
    f.update_each(np.array([[5.0, 0.0]]))
    assert f.n_lm == 0 and f.anchor is not None
    f.p[:3, :3] = np.eye(3)
    f.anchor_update(np.array([9.0]), np.array([[0.25]]))
    assert f.xs[0] == pytest.approx(0.8)
