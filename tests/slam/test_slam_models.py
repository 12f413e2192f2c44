"""Motion and observation models: Jacobians against finite differences, inverse models."""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.slam.models import BicycleModel, LineFeature, RangeBearing, VelocityModel, wrap_angle


def numeric_jac(f, x, eps=1e-6):
    cols = []
    for i in range(x.shape[-1]):
        d = np.zeros_like(x)
        d[..., i] = eps
        a, b = f(x + d), f(x - d)
        diff = a - b
        diff[..., -1] = wrap_angle(diff[..., -1]) if diff.shape[-1] == 3 else diff[..., -1]
        cols.append(diff / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize(
    "model,u", [(BicycleModel(4.0), [3.0, 0.2]), (VelocityModel(), [1.5, -0.3, 0.05])]
)
def test_motion_jacobians_match_finite_differences(model, u):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 3)) * [10, 10, 2]
    u = np.asarray(u)
    fx, fu = model.jacobians(x, u, 0.1)
    np.testing.assert_allclose(fx, numeric_jac(lambda xx: model.f(xx, u, 0.1), x), atol=1e-6)
    num_u = np.stack([numeric_jac(lambda uu, xi=xi: model.f(xi, uu, 0.1), u) for xi in x])
    np.testing.assert_allclose(fu, num_u, atol=1e-6)


def test_velocity_model_is_eq3():
    # heading 90 deg (+y): forward velocity moves +y, starboard velocity moves -x
    x = np.array([1.0, 2.0, np.pi / 2])
    out = VelocityModel().f(x, np.array([2.0, 1.0, 0.1]), 0.5)
    np.testing.assert_allclose(out, [1.0 - 0.5, 2.0 + 1.0, np.pi / 2 + 0.05], atol=1e-12)


def test_bicycle_model_is_baileys():
    x = np.array([0.0, 0.0, 0.0])
    out = BicycleModel(4.0).f(x, np.array([3.0, 0.1]), 0.025)
    np.testing.assert_allclose(
        out, [0.075 * np.cos(0.1), 0.075 * np.sin(0.1), 0.075 * np.sin(0.1) / 4.0]
    )


@pytest.mark.parametrize("obs", [RangeBearing(), LineFeature()])
def test_observation_jacobians_and_inverse(obs):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(6, 3)) * [5, 5, 1]
    m = rng.normal(size=(6, 2)) * [20, 20] + [30, 0]
    if isinstance(obs, LineFeature):
        m[:, 1] = rng.uniform(-3, 3, 6)
    hx, hm = obs.jacobians(x, m)

    def fx(xx):
        return obs.h(xx, m)

    def fm(mm):
        return obs.h(x, mm)

    nx = np.stack([(fx(x + d) - fx(x - d)) / 2e-6 for d in np.eye(3) * 1e-6], axis=-1)
    nm = np.stack([(fm(m + d) - fm(m - d)) / 2e-6 for d in np.eye(2) * 1e-6], axis=-1)
    np.testing.assert_allclose(hx, nx, atol=1e-5)
    np.testing.assert_allclose(hm, nm, atol=1e-5)
    z = obs.h(x, m)
    back = obs.inverse(x, z)
    np.testing.assert_allclose(obs.wrap_feature(back - m), 0.0, atol=1e-9)
    g = obs.inverse_jacobian(x, z)
    ng = np.stack(
        [(obs.inverse(x, z + d) - obs.inverse(x, z - d)) / 2e-6 for d in np.eye(2) * 1e-6], axis=-1
    )
    np.testing.assert_allclose(g, ng, atol=1e-5)


def test_range_bearing_conventions():
    # landmark straight ahead at 10 m, then one to the +y side (bearing +90 deg)
    obs = RangeBearing()
    x = np.array([0.0, 0.0, 0.0])
    np.testing.assert_allclose(obs.h(x, np.array([10.0, 0.0])), [10.0, 0.0])
    np.testing.assert_allclose(obs.h(x, np.array([0.0, 5.0])), [5.0, np.pi / 2])
    # innovations wrap across +-pi
    v = obs.residual(np.array([1.0, np.pi - 0.01]), np.array([1.0, -np.pi + 0.01]))
    np.testing.assert_allclose(v, [0.0, -0.02], atol=1e-12)


def test_line_feature_signed_distance():
    obs = LineFeature()
    # the line x = 10 (normal along +x): from (4, 7, heading 0) it is 6 m ahead, normal at 0
    z = obs.h(np.array([4.0, 7.0, 0.0]), np.array([10.0, 0.0]))
    np.testing.assert_allclose(z, [6.0, 0.0])
    # from beyond the line the signed distance is negative
    z = obs.h(np.array([12.0, 0.0, 0.5]), np.array([10.0, 0.0]))
    np.testing.assert_allclose(z, [-2.0, -0.5])
