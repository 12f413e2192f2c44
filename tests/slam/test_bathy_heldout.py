"""Issue 28, the bathymetric half: BPSLAM as an SIR filter (weights accumulated between
resamplings), the navigation-error models of the synthetic DR, and the held-out protocol
(seed / scenario split, frozen parameters, paired bootstrap)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import Scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import run_filter
from auvgw.slam.bathymetric.filters import BPSLAM, own_nearest, rotate
from auvgw.slam.bathymetric.heldout import (
    GAUGE_KEYS,
    SPLIT,
    gauge_fields,
    load_frozen,
    paired_rows,
    run_rows,
)
from auvgw.slam.bathymetric.simulate import DRModel, simulate_survey
from auvgw.slam.evaluation.heldout import (
    TEST_SEED_MIN,
    Split,
    paired_bootstrap_arrays,
    seed_split,
)
from auvgw.testing.bathy_helpers import TINY

ROOT = Path(__file__).resolve().parents[2]
FROZEN = ROOT / "docs/results/bathymetric/heldout/frozen.json"


class _Spy(BPSLAM):
    """BPSLAM recording each ping's likelihoods (its own ``weights()``), its weights after the
    ping, and whether the ping resampled."""

    def __init__(self, *a: object, **k: object) -> None:
        super().__init__(*a, **k)  # type: ignore[arg-type]
        self.log: list[tuple[np.ndarray | None, np.ndarray, bool]] = []

    def weights(self) -> np.ndarray | None:
        self._lik = super().weights()
        return self._lik

    def step(self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        before = self.resamplings
        super().step(u, offsets, depth)
        self.log.append((self._lik, self.w.copy(), self.resamplings > before))


def _spy_run(**cfg: object) -> _Spy:
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3))
    c = BathyConfig(n_particles=60, t_l=30, closure="resampling", **cfg)  # type: ignore[arg-type]
    f = _Spy(c, len(sim.t), np.random.default_rng(5))
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    u = sim.controls()
    for k in range(1, len(sim.t)):
        f.step(u[k - 1], sim.offsets[k], sim.depth[k])
    return f


def test_bpslam_weights_are_the_product_of_the_likelihoods_between_resamplings() -> None:
    f = _spy_run(bpslam_weights="accumulate", unmatched_weight="uniform")
    n = f.cfg.n_particles
    prod = np.full(n, 1.0 / n)
    checked = resampled = 0
    for lik, w, res in f.log:
        if lik is None:
            np.testing.assert_allclose(w, prod / prod.sum())  # no evidence: unchanged
            continue
        prod = prod * lik
        if res:  # resampled on Neff < 2N/3 of the product; weights back to 1/N
            p = prod / prod.sum()
            assert 1.0 / np.sum(p**2) < f.cfg.neff_fraction * n
            np.testing.assert_allclose(w, 1.0 / n)
            prod = np.full(n, 1.0 / n)
            resampled += 1
        else:
            np.testing.assert_allclose(w, prod / prod.sum(), rtol=1e-9)
            checked += 1
    assert checked > 10 and resampled >= 1


def test_bpslam_replace_keeps_only_the_latest_likelihood() -> None:
    f = _spy_run(bpslam_weights="replace")
    seen = 0
    for lik, w, res in f.log:
        if lik is not None and not res:
            np.testing.assert_allclose(w, lik / lik.sum())
            seen += 1
    assert seen > 10


def test_bpslam_jitter_is_its_own() -> None:
    """``bpslam_sigma_c2`` (not MTM-PF's sigma_c2) spreads BPSLAM's particles between
    matches: zero jitter and no process noise keep every particle on the DR track."""
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(4))
    cfg = BathyConfig(n_particles=20, bpslam_sigma_c2=0.0, omega_sigma_m=0.0, sigma_c2=5.0)
    res, _ = run_filter("bpslam", sim, cfg, np.random.default_rng(0))
    np.testing.assert_allclose(res.final, sim.dr, atol=1e-9)


def test_nav_models() -> None:
    # a straight track north, then back south: 1 m per ping
    leg = np.arange(200.0)
    truth = np.column_stack([np.r_[leg, leg[::-1]], np.zeros(400)])
    # eq. 28: the same draws as N(m_e, sigma_e) per axis
    e = DRModel().errors(truth, 1.0, np.random.default_rng(1))
    np.testing.assert_array_equal(e, np.random.default_rng(1).normal(0.012, 0.01, (399, 2)))
    # turning: 45 deg at the start, turned 180 deg at the end
    e = DRModel(kind="turning", sigma_m=0.0).errors(truth, 1.0, np.random.default_rng(1))
    b = 0.012 * math.sqrt(2)
    np.testing.assert_allclose(e[0], [b / math.sqrt(2), b / math.sqrt(2)])
    np.testing.assert_allclose(e[-1], [-b / math.sqrt(2), -b / math.sqrt(2)], atol=1e-12)
    # insdvl: a body-frame error, it reverses with the vehicle (scale and misalignment only)
    m = DRModel(kind="insdvl", sigma_m=0.0, heading_sigma_deg=0.0, misalign_sigma_deg=2.0)
    e = m.errors(truth, 1.0, np.random.default_rng(2))
    north = e[:199].mean(0)
    assert np.abs(e[:199] - north).max() < 1e-12  # constant on a leg
    assert np.abs(e[200:] + north).max() < 1e-12  # reversed with the vehicle
    assert abs(e[0, 1]) > 0.01  # 2 deg of a 1 m step across track
    # the INS heading error it turned each step by (issue 28: the online stage rotates the
    # swaths by it too): a heading error alone turns each 1 m step by exactly psi
    m = DRModel(kind="insdvl", sigma_m=0.0, misalign_sigma_deg=0.0, scale_sigma=0.0)
    e, psi = m.errors_and_heading(truth, 1.0, np.random.default_rng(4))
    np.testing.assert_array_equal(e, m.errors(truth, 1.0, np.random.default_rng(4)))
    assert psi.shape == (399,) and 0.1 < np.degrees(psi).std() < 3.0
    np.testing.assert_allclose(e[:199, 1], np.sin(psi[:199]), atol=1e-12)
    assert not DRModel().errors_and_heading(truth, 1.0, np.random.default_rng(1))[1].any()
    with pytest.raises(ValueError, match="nav model"):
        DRModel(kind="gps")


def test_split_refuses_test_seeds_and_scenarios_in_tuning() -> None:
    assert seed_split(TEST_SEED_MIN - 1) == "tuning" and seed_split(TEST_SEED_MIN) == "test"
    SPLIT.check(0, "bathy_survey", "tuning")
    SPLIT.check(TEST_SEED_MIN, "bathy_test_a", "test")
    with pytest.raises(ValueError, match="test seed"):
        SPLIT.check(TEST_SEED_MIN, "bathy_survey", "tuning")
    with pytest.raises(ValueError, match="not a tuning scenario"):
        SPLIT.check(0, "bathy_test_b", "tuning")
    with pytest.raises(ValueError, match="tuning seed"):
        SPLIT.check(5, "bathy_test_c", "test")
    with pytest.raises(ValueError, match="not a test scenario"):
        SPLIT.check(TEST_SEED_MIN + 3, "bathy_sandfield", "test")
    with pytest.raises(ValueError, match="both"):
        Split(tuning=("a", "b"), test=("b",))
    scn = Scenario.model_validate(TINY)  # in neither list: refused before any run
    with pytest.raises(ValueError, match="tiny_survey"):
        next(run_rows([scn], [], 1, 0, DRModel(), "tuning"))
    for name in SPLIT.test:  # the test scenarios exist and are what they say
        s = json.loads((ROOT / f"config/scenarios/{name}.json").read_text())
        assert s["name"] == name and "TEST" in s["description"]


def test_frozen_presets() -> None:
    frozen = load_frozen(FROZEN)
    lit = frozen.config("literal", "mtm-pf", 100)
    assert (lit.closure, lit.unmatched_weight, lit.lccd_mode, lit.drift_estimate) == (
        "resampling",
        "uniform",
        "pool",
        False,
    )
    eng = frozen.config("engineered", "mtm-pf", 100)
    assert eng == BathyConfig(n_particles=100)  # the defaults
    assert frozen.config("literal", "bpslam", 100).bpslam_weights == "accumulate"
    with pytest.raises(ValueError, match="preset"):
        frozen.config("tuned-on-test", "bpslam", 100)


def test_paired_bootstrap() -> None:
    base = np.array([10.0, 20.0, 30.0, 40.0, 50.0])
    c = paired_bootstrap_arrays(base, base / 2)
    assert c["ratio"] == 0.5 and c["ratio_ci"] == [0.5, 0.5] and c["other_better"] == 5
    assert c["diff"] == -15.0 and c["diff_ci"][0] < -15 < c["diff_ci"][1]
    assert paired_bootstrap_arrays(base, base / 2) == c  # seeded
    rows = paired_rows({"a/dr": list(base), "a/bpslam": list(base + 1)}, [("a/dr", "a/bpslam")])
    assert rows[0]["diff"] == 1.0 and rows[0]["other_better"] == 0
    with pytest.raises(ValueError, match="same runs"):
        paired_bootstrap_arrays(base, base[:3])


def test_gauge_fields_score_a_turn_about_the_start() -> None:
    """heldout.gauge_fields (the study's ``--gauge``): a track turned rigidly about its start by
    a known angle scores that angle and ~0 aligned error; the floor is the truth turned by DR's
    own fitted yaw; a translation is not absorbed (the start is known)."""
    a = np.arange(301.0)
    truth = np.concatenate([np.column_stack([a, 0.0 * a]),
                            np.column_stack([300.0 - a, np.full_like(a, 60.0)])])  # fmt: skip
    truth += np.array([500.0, -200.0])

    def turned(deg: float) -> np.ndarray:
        return truth[0] + rotate(truth - truth[0], math.radians(deg))

    g = gauge_fields(turned(1.5), truth, turned(-0.8))
    assert tuple(g) == GAUGE_KEYS
    assert g["gauge_yaw_deg"] == pytest.approx(1.5, abs=1e-9)
    assert g["gauge_final_m"] == pytest.approx(0.0, abs=1e-8)
    assert g["gauge_rms_m"] == pytest.approx(0.0, abs=1e-8)
    assert g["gauge_dr_yaw_deg"] == pytest.approx(-0.8, abs=1e-9)
    # the last point is 60 m from the start: the floor's final error is the chord 2 r sin(a / 2)
    assert g["gauge_floor_final_m"] == pytest.approx(2 * 60.0 * math.sin(math.radians(0.4)))
    rms = np.sqrt(np.mean(np.sum((turned(-0.8) - truth) ** 2, axis=1)))
    assert g["gauge_floor_rms_m"] == pytest.approx(rms)
    shifted = gauge_fields(truth + np.array([3.0, 4.0]), truth, truth)
    assert shifted["gauge_final_m"] > 4.0 and shifted["gauge_floor_final_m"] == 0.0


def test_own_nearest_is_the_brute_force_search() -> None:
    """BPSLAM's overlap test searches only the history near the particles (``own_nearest``);
    it finds what the whole (h, N) distance matrix finds."""
    rng = np.random.default_rng(8)
    for spread in (0.1, 1.0, 5.0):
        h, n = 400, 50
        ref = np.column_stack([np.linspace(0, 300, h), 20 * np.sin(np.linspace(0, 9, h))])
        trajs = ref[:, None, :] + np.cumsum(rng.normal(0, spread, (h, n, 2)), axis=0) / 10
        mean = trajs.mean(1)
        dev = np.linalg.norm(trajs - mean[:, None], axis=2).max(0)
        x = trajs[rng.integers(0, h, n), np.arange(n)] + rng.normal(0, 8, (n, 2))
        d2 = ((trajs - x[None]) ** 2).sum(-1)
        tlp = d2.argmin(0)
        near = np.flatnonzero(d2[tlp, np.arange(n)] <= 10.0**2)
        got_t, got_near = own_nearest(trajs, x, mean, dev, 10.0)
        np.testing.assert_array_equal(got_near, near)
        np.testing.assert_array_equal(got_t[near], tlp[near])
        assert 0 < len(near) < n
