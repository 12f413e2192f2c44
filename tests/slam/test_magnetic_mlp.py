"""The AMB-SLAM MLP: learns a smooth function, reloads identically; the ranging chain."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.slam.magnetic.mlp import MLP, TrainConfig, cross_validate, train
from auvgw.slam.magnetic.ranging import RangingGeometry, make_training_set, to_range_bearing


def _smooth(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    x = rng.uniform(-2, 2, (n, 2))
    y = np.stack([np.sin(x[:, 0]) + 0.5 * x[:, 1] ** 2, np.tanh(x[:, 0] * x[:, 1])], axis=1)
    return x, y


@pytest.mark.parametrize("optimiser", ["adam", "gd"])
def test_learns_a_known_smooth_function(optimiser: str) -> None:
    rng = np.random.default_rng(3)
    x, y = _smooth(1500 if optimiser == "adam" else 600, rng)
    cfg = TrainConfig(hidden=(40, 20), optimiser=optimiser, transform="none",
                      lr=3e-3 if optimiser == "adam" else 0.5,
                      max_epochs=300 if optimiser == "adam" else 800, goal_mse=8e-4)  # fmt: skip
    net, hist = train(x, y, cfg, rng)
    assert hist[-1] < hist[0] / 20
    if optimiser == "adam":
        assert hist[-1] <= 8e-4  # the paper's goal, on scaled outputs
    xt, yt = _smooth(500, rng)
    err = net.predict(xt) - yt
    assert np.sqrt(np.mean(err**2)) < (0.05 if optimiser == "adam" else 0.15)


def test_saved_weights_reload_to_identical_outputs(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    x, y = _smooth(300, rng)
    net, _ = train(x, y, TrainConfig(max_epochs=5, transform="cbrt"), rng)
    net.resid_bins = np.array([0.0, 1.0, np.inf])
    net.resid_cov = np.stack([np.eye(2), 2 * np.eye(2)])
    net.save(tmp_path / "m.npz")
    back = MLP.load(tmp_path / "m.npz")
    xt = rng.normal(size=(50, 2))
    np.testing.assert_array_equal(back.predict(xt), net.predict(xt))
    np.testing.assert_array_equal(back.covariance(net.predict(xt)), net.covariance(net.predict(xt)))
    assert back.transform == "cbrt" and back.sizes == (2, 40, 20, 2)
    np.savez(tmp_path / "bad.npz", a=np.zeros(2))
    with pytest.raises(ValueError, match=r"bad\.npz.*missing"):
        MLP.load(tmp_path / "bad.npz")


def test_cross_validation_folds_and_ranging_geometry() -> None:
    rng = np.random.default_rng(7)
    x, y = make_training_set(600, rng, RangingGeometry(max_range_m=25.0))
    # the paper's geometry: beacon 5.4-6.6 m below, within Table 4's 25 m
    assert np.all((y[:, 2] > 5.3) & (y[:, 2] < 6.7)) and np.hypot(y[:, 0], y[:, 1]).max() <= 25
    cv = cross_validate(x, y, TrainConfig(max_epochs=30), rng, folds=3)
    assert cv["r"].shape == (3, 3) and cv["rmse"].shape == (3, 3)
    assert np.all(cv["r"][:, :2] > 0.7)  # horizontal offsets are learnt within 30 epochs
    z, r = to_range_bearing(np.array([[3.0, 4.0, 6.0]]), np.diag([1.0, 1.0, 0.1])[None], 0.0)
    np.testing.assert_allclose(z[0], [5.0, math.atan2(4, 3)])
    np.testing.assert_allclose(r[0], np.diag([1.0, 1.0 / 25.0]), atol=1e-12)
