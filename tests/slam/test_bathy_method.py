"""Unit tests of the bathymetric PF-SLAM (slam/bathymetric): IDW, submap shift and overlap
test, weight indexation, loop correction ramp, LCCD, and the noise-free single particle."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.world import ProceduralTerrain
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import (
    error_budget,
    gauge_error,
    gauge_floor,
    grid_dem,
    label_loops,
    run_filter,
    spread_after_resampling,
)
from auvgw.slam.bathymetric.filters import (
    MTMPF,
    BodyDrift,
    fill_weights,
    jitter_variance,
    mode_odds,
    mode_ratio,
    mode_weights,
    no_match_weight,
    rotate,
)
from auvgw.slam.bathymetric.loops import (
    LCCD,
    DriftModel,
    LoopClosure,
    consistent,
    correction_ramp,
    max_clique,
)
from auvgw.slam.bathymetric.matching import _column_sums, alpha_exponent, idw, match_weights
from auvgw.slam.bathymetric.simulate import DRModel, simulate_survey, swath_offsets
from auvgw.testing.bathy_helpers import TINY


def test_idw_hand_computed() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [50.0, 50.0]])
    z = np.array([1.0, 2.0, 4.0, 100.0])
    tree = cKDTree(pts)
    # at (0, 1): distances 1, sqrt 2, 1 -> weights 1, 1/2, 1 (p = 2); (50, 50) is out of range
    got, ok = idw(tree, z, np.array([[0.0, 1.0], [1.0, 0.0], [30.0, 30.0]]), 4, 10.0, 2.0, 3)
    assert got[0] == pytest.approx((1 * 1 + 0.5 * 2 + 1 * 4) / 2.5)
    assert got[1] == 2.0  # a sample's own value at zero distance
    assert ok.tolist() == [True, True, False]  # (30, 30) has no neighbour within 10 m


def test_idw_equals_brute_force_next_to_the_radius() -> None:
    """idw queries the tree only for rows its grid test cannot rule out: every row equals a
    brute-force IDW, rows just inside the radius of a sample (at any angle, so across cell
    borders) included, and rows out of range are (nan, False)."""
    rng = np.random.default_rng(3)
    pts, z = rng.uniform(0.0, 40.0, (300, 2)), rng.normal(0.0, 1.0, 300)
    r, k = 4.0, 8
    ang = rng.uniform(0.0, 2 * math.pi, 3000)
    rim = pts[rng.integers(0, 300, 3000)] + (r - 1e-9) * np.column_stack([np.cos(ang), np.sin(ang)])
    q = np.vstack([rim, rng.uniform(-20.0, 60.0, (3000, 2))])
    got, ok = idw(cKDTree(pts), z, q, k, r, 2.0, 1)
    d = np.linalg.norm(q[:, None, :] - pts[None], axis=-1)
    near = np.argsort(d, axis=1)[:, :k]
    dn = np.take_along_axis(d, near, 1)
    w = np.where(dn < r, dn**-2.0, 0.0)
    want = (w * z[near]).sum(1) / np.where(w.sum(1) > 0, w.sum(1), np.nan)
    assert ok.tolist() == (dn[:, 0] < r).tolist()
    assert ok[:3000].all() and not ok.all()  # every rim row is in range; some rows are not
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-12)
    assert np.isnan(got[~ok]).all()


@pytest.mark.parametrize("k", [3, 8, 13, 20])
def test_neighbour_sums_by_whole_rows(k: int) -> None:
    """The IDW's sums over neighbours held column-wise equal numpy's row sums (same order:
    equal to the bit on the numpy it was checked with; the tolerance only guards against a
    numpy that changes its summation order)."""
    a = np.exp(np.random.default_rng(k).normal(0.0, 5.0, (1000, k)))
    np.testing.assert_allclose(_column_sums(np.ascontiguousarray(a.T)), a.sum(1), rtol=1e-14)


def _crossing() -> tuple[MTMPF, np.ndarray]:
    """Line 1 north along y = 0 (pings 0-99), then line 2 east along x = 50 (pings 100-199):
    the mean trajectory of line 2 is off by (3, -2) m (drift), so the Pmap matches the older
    map when shifted by (-3, 2)."""
    terrain = ProceduralTerrain(30.0, 3.0, 40.0, seed=3, octaves=3)
    truth = np.vstack(
        [
            np.column_stack([np.arange(100.0) - 20, np.zeros(100)]),
            np.column_stack([np.full(100, 50.0), np.arange(100.0) - 60]),
        ]
    )
    heading = np.r_[np.zeros(100), np.full(100, math.pi / 2)]
    offsets = swath_offsets(heading, np.linspace(-40, 40, 81))
    depth = terrain.depth(truth[:, None, 0] + offsets[..., 0], truth[:, None, 1] + offsets[..., 1])
    cfg = BathyConfig(n_particles=4, t_l=30, min_matched_fraction=0.0, mmap_beam_stride=2)
    f = MTMPF(cfg, 200, np.random.default_rng(0))
    est = truth.copy()
    est[100:] += (3.0, -2.0)
    f.traj[:] = est
    f.offsets, f.depths, f.t = offsets, depth, 160  # line 2 at (50, 0): over line 1
    assert np.linalg.norm(truth[160] - (50.0, 0.0)) < 1.0
    return f, est


def test_submap_shift_and_overlap_on_a_crossing() -> None:
    f, est = _crossing()
    c = est[160]
    # particles: the right shift, two wrong shifts (inside R) and one 30 m off the old line
    f.x = c + np.array([(-3.0, 2.0), (2.0, 6.0), (-8.0, -4.0), (0.0, 30.0)])
    w, tlp = f.weights()
    assert w is not None
    assert f.matched[160] == 3  # the overlap test leaves out the particle 30 m away
    assert abs(tlp[0] - 70) <= 3  # nearest old centroid: line 1 at x = 50 (ping 70)
    assert np.argmax(w) == 0 and w[0] > 1.5 * max(w[1], w[2])
    # 'neutral': the particle outside R carries no evidence (the mean matched weight): below
    # the right shift, above the poor fit that failed the gates (at most the gate's weight)
    assert w[0] > w[3] > min(w[1], w[2])


def test_weight_indexation_flattens_on_flat_terrain_only() -> None:
    rng = np.random.default_rng(1)
    cfg = BathyConfig()
    n = 300
    flat = 30.0 + rng.normal(0, 0.05, (2, n))
    rough = 30.0 + rng.normal(0, 2.0, (2, n))
    valid = np.ones((2, n), dtype=bool)
    for base, flattened in ((flat, True), (rough, False)):
        z_m = base
        z_good = base + rng.normal(0, 0.1, base.shape)
        z_bad = base + rng.normal(0, 0.5, base.shape)
        z_p = np.stack([z_good[0], z_bad[1]])
        a = alpha_exponent(z_p, z_m, valid, cfg)
        w, ok, _ = match_weights(z_p, z_m, valid, np.full(2, n), cfg, fallback=1 / 400)
        w_raw, _, _ = match_weights(z_p, z_m, valid, np.full(2, n), cfg, use_alpha=False)
        assert ok.all()
        if flattened:
            assert a.max() < 0.05
            assert w[0] / w[1] < 1.1  # no preference left between a good and a bad match
            assert w_raw[0] / w_raw[1] > 1.5
        else:
            assert a.min() > 0.95
            assert w[0] / w[1] == pytest.approx(w_raw[0] / w_raw[1], rel=0.1)


def test_alpha_is_one_without_map_error() -> None:
    cfg = BathyConfig(sigma_map2=0.0)
    z = 30.0 + np.random.default_rng(2).normal(0, 0.3, (1, 50))
    assert alpha_exponent(z, z, np.ones_like(z, dtype=bool), cfg)[0] == pytest.approx(1.0)


def test_jitter_variance_follows_fig2() -> None:
    cfg = BathyConfig(sigma_c2=1.0, jitter_a=5.0, jitter_b=10, jitter_c=10.0)
    got = [jitter_variance(t, cfg) for t in (1, 9, 10, 11, 15, 20, 30, 50)]
    assert got == pytest.approx([1.0, 1.0, 2.839, 2.664, 2.116, 1.677, 1.249, 1.034], abs=1e-3)


def test_loop_correction_ramp_is_continuous_at_both_ends() -> None:
    covered = np.zeros(60, dtype=bool)
    covered[:10] = True  # an earlier loop
    covered[25:35] = True  # a solidified gap inside the new loop's interval
    m = np.array([6.0, -3.0])
    t_a, delta = correction_ramp(covered, 5, 50, m)
    assert t_a == 10  # U starts after the earlier loop (eq. 15)
    n_u = (~covered[10:51]).sum()
    step = np.linalg.norm(m) / n_u
    # start: the first corrected point moves by one ramp step from an unmoved neighbour
    assert np.linalg.norm(delta[0]) == pytest.approx(step)
    # end: the full jump, so the trajectory joins the resampled cloud
    assert delta[-1] == pytest.approx(m)
    # no jump anywhere: consecutive corrections differ by at most one ramp step
    assert np.linalg.norm(np.diff(delta, axis=0), axis=1).max() <= step + 1e-12
    # the gap moves rigidly with the last U time before it (eq. 22)
    assert np.allclose(delta[25 - 10 : 35 - 10], delta[24 - 10])


def _loop(t_loop: int, t_end: int, drift: np.ndarray, error: np.ndarray) -> LoopClosure:
    """A loop of a run whose DR drifts by ``drift`` per ping; the SLAM positions are the truth
    (truth = 0 at all times here) plus ``error`` at the end."""
    dr = lambda t: drift * t  # noqa: E731
    return LoopClosure(
        m=-drift * (t_end - t_loop),
        t_loop=t_loop,
        t_end=t_end,
        dr_loop=dr(t_loop),
        dr_end=dr(t_end),
        s_loop=np.zeros(2),
        s_end=np.asarray(error, float),
        s_end_before=dr(t_end),
    )


def _judge_all(lccd: LCCD, loops: list[LoopClosure]) -> list[list[LoopClosure]]:
    """Judge ``loops`` in order; what each judgement overturned."""
    over = []
    for lp in loops:
        lccd.judge(lp)
        over.append(list(lccd.overturned_now))
    return over


def test_lccd_rejects_a_planted_inconsistent_closure() -> None:
    drift = np.array([0.012, 0.012])
    lccd = LCCD(tau_m=3.0)
    d_nested = LCCD.distance(_loop(100, 300, drift, (0, 0)), _loop(50, 400, drift, (0, 0)))
    d_overlap = LCCD.distance(_loop(100, 300, drift, (0, 0)), _loop(200, 500, drift, (0, 0)))
    assert d_nested == pytest.approx(0.0, abs=1e-9)  # eq. (26)
    assert d_overlap == pytest.approx(0.0, abs=1e-9)  # eq. (27) over the overlap (A16)
    decisions = [
        lccd.judge(_loop(100, 300, drift, (0, 0))),
        lccd.judge(_loop(101, 301, drift, (0.3, -0.2))),
        lccd.judge(_loop(90, 330, drift, (15.0, -12.0))),  # a false match: 19 m off
        lccd.judge(_loop(120, 340, drift, (-0.4, 0.5))),
    ]
    assert decisions == [False, True, False, True]  # the first waits for a partner (A17)


def _small_scenario() -> Scenario:
    return Scenario.model_validate(TINY)


def test_one_noise_free_particle_reproduces_the_truth() -> None:
    scn = _small_scenario()
    sim = simulate_survey(scn, np.random.default_rng(4), dr=DRModel(0.0, 0.0))
    cfg = BathyConfig(
        n_particles=1, sigma_c2=0.0, jitter_a=0.0, omega_sigma_m=0.0, bpslam_sigma_c2=0.0
    )
    for name in ("mtm-pf", "bpslam"):
        res, f = run_filter(name, sim, cfg, np.random.default_rng(0))
        assert len(res.final) == len(sim.t) > 100
        assert np.allclose(res.final, sim.truth, atol=1e-9)
        assert np.allclose(res.online, sim.truth, atol=1e-9)
    grid, _ = grid_dem(f.map_points(), 2.0)
    assert np.nanmax(grid) < 40 and np.nanmin(grid) > 20


def test_one_closure_per_crossing() -> None:
    """closure = "crossing": the TINY survey crosses its first line once; the weights of that
    crossing's pings are accumulated and resampled once, where eq. (13) resamples at many
    consecutive pings of the same crossing; the one closure still pulls the track in."""
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3))
    cfg1 = BathyConfig(n_particles=100, closure="resampling", unmatched_weight="uniform")
    per_ping, f1 = run_filter("mtm-pf", sim, cfg1, np.random.default_rng(1))
    # the whole weighted cloud as the closure: on this short single crossing at N = 100 the
    # dominant 3 m mode ('mode', the default) is a wrong one for seeds 1 and 3 (6.4, 9.0 m
    # against DR's 4.4 m; 'mean' 2.0, 2.2 m)
    cfg = BathyConfig(n_particles=100, closure="crossing", closure_estimate="mean")
    per_crossing, f2 = run_filter("mtm-pf", sim, cfg, np.random.default_rng(1))
    assert len(f1.loops) > 3  # many small resamplings in a row
    assert 1 <= len(f2.loops) <= 2
    t_ends = [lp.t_end for lp in f2.loops]
    # the crossing's matched pings: each closure comes after the last of them
    matched = np.flatnonzero(f2.matched > 0)
    assert all(t >= matched.min() + 1 for t in t_ends)
    err = np.hypot(*(per_crossing.final[-1] - sim.truth[-1]))
    err_dr = np.hypot(*(sim.dr[-1] - sim.truth[-1]))
    print(
        f"final error: per crossing {err:.2f} m, per resampling "
        f"{np.hypot(*(per_ping.final[-1] - sim.truth[-1])):.2f} m, DR {err_dr:.2f} m"
    )
    assert err < err_dr


@pytest.mark.parametrize("rule", ["uniform", "gate"])
def test_no_match_weight_scales_with_n_only_when_uniform(rule: str) -> None:
    """A matched particle against one without a usable match: with 1/N (as written) the ratio
    grows with N, so the more particles, the sharper every crossing's weights; with the gate's
    weight (default) it is the same at any N: 1 / w_gate = sqrt(2 pi (sigma_s^2 + mse_max))."""
    ratios = []
    for n in (50, 400):
        cfg = BathyConfig(n_particles=n, unmatched_weight=rule, min_matched_fraction=0.0)
        w = fill_weights(n, np.array([0]), np.array([1.0]), cfg)
        ratios.append(w[0] / w[1])
        assert w.sum() == pytest.approx(1.0)
    if rule == "uniform":
        assert ratios == pytest.approx([50.0, 400.0])
    else:
        assert ratios[0] == pytest.approx(ratios[1])
        assert ratios[0] == pytest.approx(math.sqrt(2 * math.pi * (0.15**2 + 0.5)))
    # the weight indexation flattens a featureless match to the same no-match weight
    cfg = BathyConfig(n_particles=400, unmatched_weight=rule)
    flat = np.full((1, 50), 30.0)
    w0 = no_match_weight(400, cfg)
    w, ok, _ = match_weights(flat, flat, np.ones_like(flat, bool), np.full(1, 50), cfg, fallback=w0)
    assert ok[0] and w[0] == pytest.approx(w0)


@pytest.mark.parametrize("jitter_in_crossing", [False, True])
def test_particles_keep_their_offsets_through_a_crossing(jitter_in_crossing: bool) -> None:
    """closure = "crossing": between the matched pings of one crossing the particles move by
    the DR step only (omega = 0 here), so the crossing's multiplied weights score one offset
    per particle; outside crossings (and with jitter_in_crossing) eq. (3)'s jitter applies."""
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3))
    cfg = BathyConfig(
        n_particles=50, omega_sigma_m=0.0, lccd=False, jitter_in_crossing=jitter_in_crossing
    )
    f = MTMPF(cfg, len(sim.t), np.random.default_rng(1))
    u = sim.controls()
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    in_crossing, outside = [], []
    for k in range(1, len(sim.t)):
        x0, was_crossing, n_loops = f.x.copy(), f.crossing_len > 0, len(f.loops)
        f.step(u[k - 1], sim.offsets[k], sim.depth[k])
        if len(f.loops) > n_loops:
            continue  # resampled at this ping
        moved = np.abs(f.x - x0 - u[k - 1]).max()
        (in_crossing if was_crossing else outside).append(moved)
    assert len(in_crossing) >= 5 and len(outside) >= 50
    assert min(outside) > 0.01  # jitter of sigma_c^2 = 1 m^2
    if jitter_in_crossing:
        assert min(in_crossing) > 0.01
    else:
        assert max(in_crossing) < 1e-9


def test_lccd_parts_judges_a_crossing_by_its_own_pings() -> None:
    """lccd_mode = 'parts': a crossing whose two halves point at the same offset is consistent
    (also the first closure of a mission: no partner needed); halves pointing 10 m apart, or a
    single ping with evidence, are not."""
    assert consistent(np.array([[0.0, 0.0], [2.0, 1.0]]), 3.0)
    assert not consistent(np.array([[0.0, 0.0], [8.0, 6.0]]), 3.0)
    assert not consistent(np.zeros((1, 2)), 3.0)
    cfg = BathyConfig(n_particles=3, lccd_tau_m=3.0)
    f = MTMPF(cfg, 10, np.random.default_rng(0))
    f.x = np.array([[0.0, 0.0], [1.0, 0.5], [10.0, 0.0]])
    near0 = np.log(np.array([0.90, 0.09, 0.01]))
    near1 = np.log(np.array([0.09, 0.90, 0.01]))
    far = np.log(np.array([0.01, 0.01, 0.98]))
    assert f._parts_agree([near0, near0, near1, near1])  # 1.1 m apart
    assert not f._parts_agree([near0, near0, far, far])  # ~9.7 m apart
    assert not f._parts_agree([near0])


def test_closure_resamples_the_dominant_mode_only() -> None:
    """closure_estimate = 'mode': two modes 20 m apart holding 0.6 and 0.4 of the weight; the
    weighted mean lies between them, where no particle is; the closure draws only from the
    heavier mode, so the resampled centroid lands on it."""
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [20.0, 0.0], [50.0, 50.0]])
    w = np.array([0.2, 0.2, 0.2, 0.4, 0.0])
    assert np.linalg.norm(w @ x - (8.0, 0.0)) < 0.5  # the mean: between the modes
    wm = mode_weights(x, w, 3.0)
    assert wm.sum() == pytest.approx(1.0)
    assert wm[3] == 0.0 and wm[4] == 0.0 and wm[:3] == pytest.approx([1 / 3] * 3)
    cfg = BathyConfig(n_particles=5, lccd=False, t_l=2)
    f = MTMPF(cfg, 10, np.random.default_rng(0))
    f.t, f.x = 5, x.copy()
    f.traj[:6] = np.arange(6.0)[:, None] * (0.0, 1.0)
    f.traj[5] = x.mean(0)
    f._resample(w, np.zeros(5, dtype=int))
    assert (np.linalg.norm(f.x, axis=1) <= 1.0 + 1e-9).all()
    assert np.allclose(f.traj[5], f.x.mean(0))  # the closure moved the track to the mode


def test_lccd_veto_accepts_what_nothing_contradicts() -> None:
    """lccd_mode = 'veto': the first closure and one disjoint from every accepted closure have
    no partner and nothing that contradicts them: accepted (the pool rule rejects both); the
    planted false match, comparable with accepted closures and 19 m off, is still rejected."""
    drift = np.array([0.012, 0.012])
    loops = [
        _loop(100, 300, drift, (0, 0)),
        _loop(101, 301, drift, (0.3, -0.2)),
        _loop(90, 330, drift, (15.0, -12.0)),  # a false match: 19 m off
        _loop(120, 340, drift, (-0.4, 0.5)),
        _loop(400, 600, drift, (0.2, 0.1)),  # disjoint from all the others (A14)
    ]
    veto, pool = LCCD(tau_m=3.0, veto=True), LCCD(tau_m=3.0)
    assert [veto.judge(lp) for lp in loops] == [True, True, False, True, True]
    assert [pool.judge(lp) for lp in loops] == [False, True, False, True, False]


def test_mode_ratio_weighs_the_dominant_mode_against_a_disjoint_one() -> None:
    """The closure's evidence (min_mode_ratio): two modes 20 m apart holding 0.55 and 0.45 of
    the weight are ambiguous (ratio 1.2); 0.9 against 0.1 is not (9); one mode and nothing
    beyond 2 radii is infinite. It compares posterior masses, not particle counts, so the
    same posterior gives about the same ratio at any N."""
    x = np.array([[0.0, 0.0], [1.0, 0.0], [20.0, 0.0], [21.0, 0.0]])
    assert mode_ratio(x, np.array([0.3, 0.25, 0.25, 0.2]), 3.0, 10.0) == pytest.approx(0.55 / 0.45)
    assert mode_ratio(x, np.array([0.5, 0.4, 0.05, 0.05]), 3.0, 10.0) == pytest.approx(9.0)
    assert mode_ratio(x[:2], np.array([0.5, 0.5]), 3.0, 10.0) == math.inf
    # a posterior of two modes holding 0.7 and 0.3 over a uniform cloud: the median ratio over
    # 40 clouds is near 0.7 / 0.3 at N = 100 and at N = 400 (Monte Carlo noise grows as N falls)
    for n in (100, 400):
        ratios = []
        for seed in range(40):
            pts = np.random.default_rng(seed).uniform(-15.0, 15.0, (n, 2))
            d2a = ((pts - (8.0, 0.0)) ** 2).sum(-1)
            d2b = ((pts - (-8.0, 0.0)) ** 2).sum(-1)
            lik = 0.7 * np.exp(-0.5 * d2a / 1.5**2) + 0.3 * np.exp(-0.5 * d2b / 1.5**2)
            ratios.append(mode_ratio(pts, lik / lik.sum(), 3.0, 10.0))
        assert float(np.median(ratios)) == pytest.approx(0.7 / 0.3, rel=0.35)


def test_mode_odds_weighs_the_mode_against_all_the_weight_elsewhere() -> None:
    """min_mode_odds: a mode holding 0.045 of the weight beats each of 24 rivals holding 0.04
    of it (rival ratio >= 1) but its odds against all of them are 0.04 / 0.96; the shoulder
    within mode_apart_m counts with the mode (same peak), the weight beyond it against."""
    rng = np.random.default_rng(1)
    mode = rng.normal(0.0, 0.5, (10, 2))
    rivals = np.array([[30.0 * np.cos(a), 30.0 * np.sin(a)] for a in np.arange(24) * 0.26])
    x = np.vstack([mode, rivals])
    w = np.concatenate([np.full(10, 0.0045), np.full(24, 0.04)])  # mode 0.045, rivals 0.04
    w /= w.sum()
    assert mode_ratio(x, w, 3.0, 10.0) >= 1.0
    assert mode_odds(x, w, 3.0, 10.0) == pytest.approx(w[:10].sum() / w[10:].sum())
    assert mode_odds(x, w, 3.0, 10.0) < 0.05
    shoulder = np.array([[0.0, 0.0], [6.0, 0.0], [25.0, 0.0]])  # 6 m: the same peak's shoulder
    assert mode_odds(shoulder, np.array([0.5, 0.3, 0.2]), 3.0, 10.0) == pytest.approx(4.0)
    assert mode_odds(shoulder[:2], np.array([0.5, 0.5]), 3.0, 10.0) == math.inf


def test_a_crossing_below_min_mode_odds_does_not_close() -> None:
    """A crossing whose heaviest 3 m mode passes min_mode_ratio but holds less than all the
    weight beyond mode_apart_m makes no closure when min_mode_odds = 1; with 0 (off) it
    closes on that mode."""
    x = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [20.0, 0.0], [40.0, 0.0], [60.0, 0.0]])
    w = np.array([0.45, 0.0, 0.0, 0.3, 0.25, 0.0])  # Neff 2.8 < 4; odds 0.45 / 0.55
    for odds in (0.0, 1.0):
        cfg = BathyConfig(
            n_particles=6,
            lccd=False,
            t_l=2,
            crossing_max_pings=1,
            min_mode_ratio=1.2,
            min_mode_odds=odds,
        )
        f = MTMPF(cfg, 10, np.random.default_rng(0))
        f.t, f.x = 6, x.copy()
        f.traj[:7] = np.arange(7.0)[:, None] * (0.0, 1.0)
        f._crossing(w, np.zeros(6, dtype=int))
        assert (len(f.loops), f.weak_crossings) == ((0, 1) if odds else (1, 0))


@pytest.mark.parametrize("min_ratio", [1.0, 2.0])
def test_a_weak_crossing_neither_resamples_nor_closes(min_ratio: float) -> None:
    """A crossing whose weights split 0.55 / 0.45 between two modes 20 m apart reaches
    Neff < 2N/3 but is ambiguous: with min_mode_ratio = 2 it makes no closure, the particles
    stay where they were and the crossing's weights are dropped; with 1 (eq. 13 alone) it
    closes on the heavier mode."""
    x = np.array([[0.0, 0.0], [1.0, 0.0], [20.0, 0.0], [21.0, 0.0]])
    w = np.array([0.5, 0.05, 0.05, 0.4])  # Neff 2.2 < 2/3 x 4
    cfg = BathyConfig(
        n_particles=4, lccd=False, t_l=2, crossing_max_pings=1, min_mode_ratio=min_ratio
    )
    f = MTMPF(cfg, 10, np.random.default_rng(0))
    f.t, f.x = 6, x.copy()
    f.traj[:7] = np.arange(7.0)[:, None] * (0.0, 1.0)
    f._crossing(w, np.zeros(4, dtype=int))
    assert f.crossing_len == 0 and not f.logw.any()  # the crossing ended, its weights dropped
    if min_ratio > 1:
        assert f.loops == [] and f.weak_crossings == 1
        assert np.array_equal(f.x, x)
    else:
        assert len(f.loops) == 1 and f.weak_crossings == 0
        assert (np.linalg.norm(f.x, axis=1) <= 1.0 + 1e-9).all()


def test_lccd_overturns_a_planted_wrong_first_closure() -> None:
    """lccd_overturn: a wrong first closure (19 m off) is accepted by 'veto' (nothing
    contradicts it) and vetoes the next right one; the one after agrees with that right one,
    so their cluster (2) outweighs the wrong one's (1): it is accepted and overturns the wrong
    one, and every later right closure is kept. Without overturn the wrong one stays."""
    drift = np.array([0.012, 0.012])
    loops = lambda: [  # noqa: E731
        _loop(90, 330, drift, (15.0, -12.0)),  # a false match: 19 m off
        _loop(100, 340, drift, (0, 0)),
        _loop(101, 350, drift, (0.3, -0.2)),
        _loop(120, 360, drift, (-0.4, 0.5)),
    ]
    lccd = LCCD(tau_m=3.0, veto=True, overturn=True)
    lps = loops()
    over = _judge_all(lccd, lps)
    assert [lp.accepted for lp in lps] == [False, False, True, True]
    assert lps[0].overturned and [len(o) for o in over] == [0, 0, 1, 0] and over[2][0] is lps[0]
    assert all(lp is not lps[0] for lp in lccd.pool)
    plain = LCCD(tau_m=3.0, veto=True)
    lps = loops()
    assert [plain.judge(lp) for lp in lps] == [True, False, True, True]


def test_overturn_undoes_a_closure_on_the_mean_trajectory() -> None:
    """Undoing a closure: its ramp and the jump the particles carried on are subtracted; the
    closure that overturned it keeps ping t aligned with the map at its t_loop (which the undo
    moved by -c(t_loop)), through a linear ramp over [t_loop, t]: no jump anywhere."""
    cfg = BathyConfig(n_particles=3, t_l=2)
    f = MTMPF(cfg, 200, np.random.default_rng(0))
    f.t = 150
    base = np.column_stack([np.arange(151.0), np.zeros(151)])
    f.traj[:151] = base
    f.x = base[150] + np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]])
    m = np.array([0.0, 20.0])
    t_a, delta = correction_ramp(np.zeros(151, bool), 40, 100, m)
    wrong = _loop(40, 100, np.zeros(2), (0, 0))
    wrong.m, wrong.t_a, wrong.delta = m, t_a, delta
    f.traj[t_a:101] += delta
    f.traj[101:151] += m
    f.x += m
    keep = _loop(70, 150, np.zeros(2), (0, 0))
    keep.accepted = True
    wrong.accepted, wrong.overturned = False, True
    f.loops = [wrong, keep]
    x_before, traj_before = f.x.copy(), f.traj[:151].copy()
    f._overturn(keep, [wrong])
    c70 = delta[70 - t_a]
    assert np.allclose(f.traj[:40], base[:40])  # before the wrong ramp: untouched
    assert np.allclose(f.traj[40:71], base[40:71])  # the wrong ramp removed up to t_loop
    assert np.allclose(f.traj[150], traj_before[150] - c70)  # end follows the map at 70
    assert np.allclose(f.x, x_before - c70)
    assert np.linalg.norm(np.diff(f.traj[:151], axis=0) - (1.0, 0.0), axis=1).max() < 0.5
    assert f.covered[70:151].all() and not f.covered[:70].any()


def test_lccd_pending_holds_a_lone_closure_until_another_judges_it() -> None:
    """lccd_pending: the first closure is held (not accepted, nothing applied); a later one
    in its cluster confirms it (both accepted); a wrong first closure is held, the next right
    one is held too (no accepted closure can judge either), a third that agrees with the right
    one accepts both right ones and drops the wrong one without anything to undo. Without
    'pending' the wrong first closure is accepted and vetoes the right one after it."""
    drift = np.array([0.012, 0.012])
    lccd = LCCD(tau_m=3.0, veto=True, overturn=True, pending=True)
    a, b = _loop(100, 300, drift, (0, 0)), _loop(101, 301, drift, (0.3, -0.2))
    assert not lccd.judge(a) and a.pending
    assert lccd.judge(b) and a.accepted and not a.pending and lccd.overturned_now == []
    wrong = lambda: [  # noqa: E731
        _loop(90, 330, drift, (15.0, -12.0)),  # a false match: 19 m off
        _loop(100, 340, drift, (0, 0)),
        _loop(101, 350, drift, (0.3, -0.2)),
        _loop(120, 360, drift, (-0.4, 0.5)),
    ]
    lccd = LCCD(tau_m=3.0, veto=True, overturn=True, pending=True)
    lps = wrong()
    got = []
    for lp in lps:
        got.append((lccd.judge(lp), lp.pending))
        assert lccd.overturned_now == []  # nothing wrong was ever applied
    assert got == [(False, True), (False, True), (True, False), (True, False)]
    assert [lp.accepted for lp in lps] == [False, True, True, True]
    assert not lps[0].pending and not lps[0].overturned
    plain = LCCD(tau_m=3.0, veto=True)
    assert [plain.judge(lp) for lp in wrong()] == [True, False, True, True]


def test_a_pending_closure_changes_neither_particles_nor_track() -> None:
    """The filter with lccd_pending: the first closure of a run resamples, is held pending,
    and the particles and the mean trajectory are restored exactly (the map unchanged)."""
    f = _at_crossing_end(lccd_pending=True)
    x, traj = f.x.copy(), f.traj.copy()
    f._crossing(CROSSING_WEIGHTS, np.zeros(4, dtype=int))
    assert len(f.loops) == 1 and f.loops[0].pending and not f.loops[0].accepted
    assert np.array_equal(f.x, x) and np.array_equal(f.traj, traj) and not f.covered.any()


#: the weights of the crossing :func:`_at_crossing_end` ends: the dominant mode near (0.3, 0)
CROSSING_WEIGHTS = np.array([0.6, 0.3, 0.05, 0.05])


def _at_crossing_end(**cfg: Any) -> MTMPF:
    """A 4-particle filter at ping 6 of a straight track north whose crossing ends now
    (particles near (0, 0) and (20, 0)); ``cfg``: further BathyConfig values."""
    f = MTMPF(BathyConfig(n_particles=4, t_l=2, crossing_max_pings=1, **cfg), 10,
              np.random.default_rng(0))  # fmt: skip
    f.t, f.x = 6, np.array([[0.0, 0.0], [1.0, 0.0], [20.0, 0.0], [21.0, 0.0]])
    f.traj[:7] = np.arange(7.0)[:, None] * (0.0, 1.0)
    return f


def test_lccd_replace_lets_stronger_evidence_undo_a_lone_closure() -> None:
    """lccd_replace: a weak wrong first closure (mode ratio 3.4, 19 m off) is accepted; the
    next one contradicts it with more evidence (ratio 24) and nothing else has judged the first,
    so it replaces it (the first is overturned, to be undone); a weaker contradicting closure
    (ratio 2) is vetoed, and once a closure has a partner it is no longer replaced."""
    drift = np.array([0.012, 0.012])

    def loops() -> list[LoopClosure]:
        lps = [
            _loop(90, 330, drift, (15.0, -12.0)),  # a false match: 19 m off
            _loop(100, 340, drift, (0, 0)),
            _loop(95, 345, drift, (14.0, -11.0)),  # false again, weaker evidence
            _loop(101, 350, drift, (0.3, -0.2)),
        ]
        for lp, ev in zip(lps, (3.4, 24.0, 2.0, 10.0), strict=True):
            lp.evidence = ev
        return lps

    lccd = LCCD(tau_m=3.0, veto=True, replace=True)
    lps = loops()
    over = _judge_all(lccd, lps)
    assert [lp.accepted for lp in lps] == [False, True, False, True]
    assert lps[0].overturned and [len(o) for o in over] == [0, 1, 0, 0]
    plain = LCCD(tau_m=3.0, veto=True)
    assert [plain.judge(lp) for lp in loops()] == [True, False, True, True]


def _one_closure(truth_step: tuple[float, float], mode: str = "oracle") -> MTMPF:
    """A filter at ping 6 whose crossing ends now: the dominant mode sits near (0.3, 0), so
    the closure jumps from the centroid (0, 6) back to ping 0's (0, 0) map. ``truth_step``
    is the true displacement from ping 0 to ping 6."""
    f = _at_crossing_end(lccd_mode=mode)
    truth = np.zeros((10, 2))
    truth[6:] = truth_step
    f.oracle_truth = truth
    f._crossing(CROSSING_WEIGHTS, np.zeros(4, dtype=int))
    return f


def test_lccd_oracle_accepts_exactly_what_the_truth_label_calls_valid() -> None:
    """lccd_mode = 'oracle' (diagnostic only): the closure is accepted iff its A22 truth label
    says valid. Truly the vehicle came back to ping 0's place: the jump back is valid and
    applied; truly it went on 6 m north (the track was right): the same jump is invalid, the
    particles and the track are restored. Without the truth the mode refuses to guess."""
    x0 = np.array([[0.0, 0.0], [1.0, 0.0], [20.0, 0.0], [21.0, 0.0]])
    back = _one_closure((0.3, 0.0))
    assert len(back.loops) == 1 and back.loops[0].accepted
    assert label_loops(back, back.oracle_truth) == [True]
    assert np.linalg.norm(back.traj[6] - (0.3, 0.0)) < 1.0  # the track moved to the mode
    on = _one_closure((0.0, 6.0))
    assert len(on.loops) == 1 and not on.loops[0].accepted
    assert label_loops(on, on.oracle_truth) == [False]
    assert np.array_equal(on.x, x0) and np.allclose(on.traj[6], (0.0, 6.0))
    f = MTMPF(BathyConfig(n_particles=4, t_l=2, lccd_mode="oracle"), 10, np.random.default_rng(0))
    f.t, f.x = 6, x0.copy()
    f.traj[:7] = np.arange(7.0)[:, None] * (0.0, 1.0)
    with pytest.raises(ValueError, match="oracle"):
        f._resample(np.array([0.6, 0.3, 0.05, 0.05]), np.zeros(4, dtype=int))


def test_error_budget_splits_the_final_error_at_the_last_closure() -> None:
    """evaluate.error_budget: the final trajectory's error at the last accepted closure plus
    what accrued after it; DR's own drift over that stretch beside it."""
    f = MTMPF(BathyConfig(n_particles=2), 101, np.random.default_rng(0))
    f.t = 100
    t = np.arange(101.0)
    truth = np.column_stack([t, np.zeros(101)])
    f.dr[:101] = truth + 0.01 * t[:, None]  # DR drifts 0.01 m per ping per axis
    f.traj[:101] = truth
    f.traj[60:101] += (3.0, 4.0)  # 5 m left at the closure, carried unchanged to the end
    f.traj[100] += (0.0, 2.0)  # and 2 m more accrued after it
    lc = _loop(10, 60, np.zeros(2), (0, 0))
    lc.accepted = True
    f.loops = [lc, _loop(20, 80, np.zeros(2), (0, 0))]  # the later one was rejected
    sim = type("Sim", (), {"truth": truth})()
    eb = error_budget(f, sim)  # type: ignore[arg-type]
    assert eb["last_closure_ping"] == 60
    assert eb["err_at_last_closure_m"] == pytest.approx(5.0)
    assert eb["accrued_since_m"] == pytest.approx(2.0)
    assert eb["dr_drift_since_m"] == pytest.approx(0.4 * math.sqrt(2))


def _lawnmower() -> np.ndarray:
    """Three 400 m lines 80 m apart from a start off the origin (NED, m, one point a metre)."""
    a = np.arange(401.0)
    legs = [np.column_stack([a, np.zeros_like(a)]),
            np.column_stack([400.0 - a, np.full_like(a, 80.0)]),
            np.column_stack([a, np.full_like(a, 160.0)])]  # fmt: skip
    return np.concatenate(legs) + np.array([1200.0, -350.0])


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.2, 0.2))
def test_gauge_error_recovers_a_rigid_turn_about_the_start(angle: float) -> None:
    """evaluate.gauge_error: a track turned rigidly about its start by a known angle gives that
    angle and no error once aligned; its raw error is the floor of that angle (gauge_floor)."""
    truth = _lawnmower()
    est = truth[0] + rotate(truth - truth[0], angle)
    g = gauge_error(est, truth)
    assert g.angle_rad == pytest.approx(angle, abs=1e-12)
    assert g.aligned_rmse_m == pytest.approx(0.0, abs=1e-8)
    assert g.aligned_final_m == pytest.approx(0.0, abs=1e-8)
    rmse, final = gauge_floor(truth, angle)
    assert (g.rmse_m, g.final_m) == (pytest.approx(rmse), pytest.approx(final))
    # the last point is r = |(400, 160)| m from the start: a chord of 2 r sin(angle / 2)
    assert final == pytest.approx(2.0 * math.hypot(400.0, 160.0) * abs(math.sin(angle / 2.0)))


def test_gauge_error_gives_the_least_squares_angle_under_noise() -> None:
    """With noise and a drift added to the turned track, the fitted angle is the one that
    minimises the summed squared error (a numerical search agrees), the aligned RMSE is that
    minimum and no larger than the raw one; a translation is not absorbed (the start is known)."""
    rng = np.random.default_rng(3)
    truth = _lawnmower()
    est = truth[0] + rotate(truth - truth[0], 0.01) + rng.normal(0.0, 0.5, truth.shape)
    est += np.linspace(0.0, 1.0, len(truth))[:, None] * (2.0, -1.0)

    def sse(a: float) -> float:
        return float(np.sum((truth[0] + rotate(est - truth[0], -a) - truth) ** 2))

    best = minimize_scalar(sse, bounds=(-0.1, 0.1), method="bounded", options={"xatol": 1e-10})
    g = gauge_error(est, truth)
    assert g.angle_rad == pytest.approx(best.x, abs=1e-7)
    assert g.aligned_rmse_m == pytest.approx(math.sqrt(best.fun / len(truth)), rel=1e-6)
    assert g.aligned_rmse_m < g.rmse_m
    shifted = gauge_error(truth + np.array([3.0, 4.0]), truth)
    assert shifted.rmse_m == pytest.approx(5.0) and shifted.aligned_rmse_m > 3.5


def test_drift_model_rates_spec_and_pairwise_agreement() -> None:
    """DriftModel: a closure's drift rate is -V(t_end) / span (eq. 25 per ping); closures of
    one constant-drift run agree pairwise even when their intervals are disjoint (eqs. 26-27
    cannot compare them, A14); a long closure 19 m off disagrees with right long ones but
    fits the spec; a short one as far off breaks the spec; a short right one is too vague
    to contradict the wrong long one."""
    drift = np.array([0.012, 0.012])
    dm = DriftModel()
    right = _loop(600, 2600, drift, (0, 0))
    rate, var = dm.rate(right)
    np.testing.assert_allclose(rate, drift)
    assert var == pytest.approx((2.0**2 + 0.01**2 * 2000) / 2000**2)
    far = _loop(3000, 3300, drift, (0.5, -0.3))  # disjoint from `right`
    assert LCCD.distance(right, far) == 1e6 and dm.agree(right, far)
    wrong = _loop(100, 2100, drift, (15.0, -12.0))
    assert dm.fits_spec(right) and dm.fits_spec(wrong) and not dm.agree(right, wrong)
    assert not dm.fits_spec(_loop(100, 340, drift, (15.0, -12.0)))
    assert dm.agree(wrong, _loop(2200, 2500, drift, (0, 0)))
    # the bias from right closures, pulled slightly towards the spec's zero mean
    est = dm.estimate([right, _loop(700, 2700, drift, (0.2, -0.2))], 2700)
    np.testing.assert_allclose(est, drift, rtol=0.02)
    assert (np.abs(est) < np.abs(drift) + 1e-4).all()


def test_max_clique_prefers_size_then_score() -> None:
    adj = np.zeros((5, 5), dtype=bool)
    for a, b in [(0, 1), (1, 2), (0, 2), (3, 4)]:
        adj[a, b] = adj[b, a] = True
    assert max_clique(adj, np.zeros(5)) == [0, 1, 2]
    adj[0, 2] = adj[2, 0] = False  # now three cliques of two
    assert max_clique(adj, np.array([0.0, 0.0, 0.0, 1.0, 1.0])) == [3, 4]
    assert max_clique(adj, np.zeros(5)) == [0, 1]  # a tie: the earliest
    assert max_clique(np.zeros((0, 0), dtype=bool), np.zeros(0)) == []


def test_lccd_drift_keeps_the_largest_consistent_set() -> None:
    """lccd_mode = 'drift': a wrong first closure that fits the spec is accepted (nothing
    contradicts it); a right one with more evidence contradicts it and wins the tie of two
    lone closures (the wrong one is overturned); a second right one joins it; a later wrong
    one, weaker, is rejected; one beyond the spec is rejected outright."""
    drift = np.array([0.012, 0.012])
    lps = [
        _loop(100, 2100, drift, (15.0, -12.0)),  # wrong, 19 m off over 2000 pings
        _loop(600, 2600, drift, (0.5, 0.0)),
        _loop(700, 2700, drift, (0.0, -0.6)),
        _loop(200, 2750, drift, (14.0, -12.0)),  # wrong again
        _loop(2500, 2800, drift, (30.0, 25.0)),  # beyond the spec
    ]
    for lp, ev in zip(lps, (3.4, 24.0, 10.0, 5.0, 100.0), strict=True):
        lp.evidence = ev
    lccd = LCCD(drift=DriftModel())
    over = _judge_all(lccd, lps)
    assert [lp.accepted for lp in lps] == [False, True, True, False, False]
    assert lps[0].overturned and [len(o) for o in over] == [0, 1, 0, 0, 0]


def test_drift_estimate_reanchors_the_track_and_removes_the_bias_in_prediction() -> None:
    """drift_estimate: one accepted closure over [1000, 3000] whose drift rate is the DR
    bias; before it the mean trajectory is DR (17 m of bias piled up since the known start
    by ping 1000, and carried rigidly after it). The re-anchor moves [0, 1000) by -b t and
    the rest rigidly by -b 1000: the track then matches the truth everywhere, stays
    continuous, the particles move with it, and the next prediction removes the bias from
    the DR step (DR itself stays raw)."""
    b = np.array([0.012, 0.012])
    t0, t1 = 1000, 3000
    cfg = BathyConfig(
        n_particles=3,
        drift_estimate=True,
        drift_min_agree=1,  # one closure suffices here (the default waits for two)
        lccd=False,
        t_l=5000,
        sigma_c2=0.0,
        jitter_a=0.0,
        omega_sigma_m=0.0,
    )
    f = MTMPF(cfg, t1 + 10, np.random.default_rng(0))
    t = np.arange(t1 + 1.0)
    truth = np.column_stack([t, np.zeros_like(t)])
    f.t = t1
    f.dr[: t1 + 1] = truth + t[:, None] * b
    f.traj[: t1 + 1] = truth + t0 * b  # the closure removed the drift over [t0, t1] ...
    f.traj[:t0] = f.dr[:t0]  # ... not before it
    f.x = truth[t1] + t0 * b + np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3]])
    lc = LoopClosure(
        m=-(t1 - t0) * b,
        t_loop=t0,
        t_end=t1,
        dr_loop=f.dr[t0].copy(),
        dr_end=f.dr[t1].copy(),
        s_loop=f.traj[t0].copy(),
        s_end=f.traj[t1].copy(),
        s_end_before=f.dr[t1].copy(),
        accepted=True,
    )
    f.loops = [lc]
    assert np.linalg.norm(f.traj[t0] - truth[t0]) == pytest.approx(t0 * 0.012 * math.sqrt(2))
    x_before = f.x.copy()
    f._reanchor()
    est = f.drift.estimate([lc], t1)
    np.testing.assert_allclose(f.bias, est)
    np.testing.assert_allclose(est, b, rtol=0.02)  # the spec prior and the walk shrink it
    assert np.abs(f.traj[: t1 + 1] - truth).max() < 0.02 * 0.012 * t0  # was 17 m at t0
    np.testing.assert_allclose(f.x, x_before - t0 * est)
    assert np.linalg.norm(np.diff(f.traj[: t1 + 1], axis=0) - (1.0, 0.0), axis=1).max() < 0.02
    x1 = f.x.copy()
    f.step(np.array([1.0, 0.0]) + b, np.zeros((4, 2)), np.full(4, 30.0))  # DR step: bias in it
    np.testing.assert_allclose(f.x, x1 + np.array([1.0, 0.0]) + b - est)
    np.testing.assert_allclose(f.dr[t1 + 1], f.dr[t1] + np.array([1.0, 0.0]) + b)


@pytest.mark.parametrize("min_agree", [1, 2])
def test_drift_estimate_waits_for_agreeing_closures(min_agree: int) -> None:
    """drift_min_agree = 2: a lone accepted closure (here a wrong one, 19 m off over 2000
    pings) does not bend the bias; once two right ones agree, the bias is theirs and the
    wrong one is left out. With 1 every accepted closure counts, the wrong one included."""
    drift = np.array([0.012, 0.012])
    cfg = BathyConfig(n_particles=2, drift_min_agree=min_agree)  # 2 is the default
    f = MTMPF(cfg, 3000, np.random.default_rng(0))
    f.t = 2800
    wrong = _loop(100, 2100, drift, (15.0, -12.0))
    right = [_loop(600, 2600, drift, (0.5, 0.0)), _loop(700, 2700, drift, (0.0, -0.6))]
    for lp in (wrong, *right):
        lp.accepted = True
    f.loops = [wrong]
    f._reanchor()
    lone = f.bias.copy()
    f.loops = [wrong, *right]
    f._reanchor()
    if min_agree == 2:
        assert np.array_equal(lone, np.zeros(2))
        np.testing.assert_allclose(f.bias, f.drift.estimate(right, 2800))
        np.testing.assert_allclose(f.bias, drift, rtol=0.03)
    else:
        np.testing.assert_allclose(lone, f.drift.estimate([wrong], 2800))
        assert np.abs(lone - drift).max() > 0.005  # the wrong closure's rate
        np.testing.assert_allclose(f.bias, f.drift.estimate([wrong, *right], 2800))


def _body_dr(truth: np.ndarray, s: float, psi_deg: float) -> np.ndarray:
    """A DR track of ``truth`` (T, 2) m whose every step is scaled by 1 + s and rotated by
    psi_deg: a constant body-frame (DVL scale + heading) error."""
    th = math.radians(psi_deg)
    rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    u = (1 + s) * np.diff(truth, axis=0) @ rot.T
    return np.vstack([truth[:1], truth[:1] + np.cumsum(u, axis=0)])


def test_body_drift_recovers_scale_and_heading_and_turns_with_the_vehicle() -> None:
    """BodyDrift: closures over a lawnmower (legs north, east, south) whose DR steps are 1 %
    long and 1 deg rotated; the fit gives s and psi, and the estimated error of every ping is
    the DR error, which turns with the vehicle (along and across each leg, not one world
    direction)."""
    legs = [np.linspace((0, 0), (600, 0), 300, endpoint=False)]
    legs.append(np.linspace((600, 0), (600, 100), 50, endpoint=False))
    legs.append(np.linspace((600, 100), (0, 100), 300))
    truth = np.vstack(legs)
    dr = _body_dr(truth, 0.01, 1.0)
    lcs = [
        LoopClosure(np.zeros(2), a, a + 200, dr[a], dr[a + 200], truth[a], truth[a + 200],
                    dr[a + 200], accepted=True)
        for a in range(0, len(truth) - 200, 100)
    ]  # fmt: skip
    cfg = BathyConfig(body_gm_sigma_deg=0.0, body_heading_sigma_deg=2.0, closure_sigma_m=0.05)
    bd = BodyDrift(cfg)
    s, psi = bd.fit(lcs, dr)
    assert s == pytest.approx(0.01, rel=0.02)
    np.testing.assert_allclose(np.degrees(psi), 1.0, rtol=0.02)
    err = dr - truth
    np.testing.assert_allclose(bd.cumulative(s, psi, dr), err, atol=0.05 * np.abs(err).max())
    steps = np.diff(err, axis=0)
    assert steps[0] @ steps[-1] < 0  # the step error reversed with the vehicle
    # a closure 20 m off the others fails the gate and is dropped before the refit
    bad = LoopClosure(np.zeros(2), 50, 350, dr[50], dr[350], truth[50], truth[350] + 20,
                      dr[350], accepted=True)  # fmt: skip
    s2, psi2 = bd.fit([*lcs, bad], dr)
    np.testing.assert_allclose(psi2, psi, rtol=0.02)
    assert s2 == pytest.approx(s, rel=0.02)
    # no closure: the prior mean, 0
    assert bd.fit([], dr)[0] == 0.0


def test_body_drift_estimate_reanchors_the_track_and_corrects_the_prediction() -> None:
    """drift_frame = 'body': one accepted closure over [1000, 3000] on a straight track north
    with a 1 %, 1 deg body-frame DR error. Before it the mean trajectory is DR (the error
    piled up since the start); the re-anchor moves [0, 1000) by -E(t) and the rest rigidly
    by -E(1000): the track matches the truth, the particles move with it, and the next
    prediction removes (s I + psi J) u from the DR step (DR stays raw)."""
    t0, t1 = 1000, 3000
    cfg = BathyConfig(
        n_particles=3, drift_estimate=True, drift_frame="body", drift_min_agree=1,
        lccd=False, t_l=5000, sigma_c2=0.0, jitter_a=0.0, omega_sigma_m=0.0,
        body_gm_sigma_deg=0.0, body_heading_sigma_deg=2.0, body_scale_sigma=0.02,
    )  # fmt: skip
    f = MTMPF(cfg, t1 + 10, np.random.default_rng(0))
    t = np.arange(t1 + 1.0)
    truth = np.column_stack([t, np.zeros_like(t)])
    f.t = t1
    f.dr[: t1 + 1] = _body_dr(truth, 0.01, 1.0)
    e0 = f.dr[t0] - truth[t0]
    f.traj[: t1 + 1] = truth + e0  # the closure removed the drift over [t0, t1] ...
    f.traj[:t0] = f.dr[:t0]  # ... not before it
    f.x = truth[t1] + e0 + np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3]])
    f.loops = [
        LoopClosure(np.zeros(2), t0, t1, f.dr[t0].copy(), f.dr[t1].copy(), f.traj[t0].copy(),
                    f.traj[t1].copy(), f.dr[t1].copy(), accepted=True)
    ]  # fmt: skip
    x_before = f.x.copy()
    f._reanchor()
    assert f.body_s == pytest.approx(0.01, rel=0.05)
    np.testing.assert_allclose(np.degrees(f.body_psi), 1.0, rtol=0.05)
    assert np.abs(f.traj[: t1 + 1] - truth).max() < 0.05 * np.linalg.norm(e0)
    np.testing.assert_allclose(f.x - x_before, np.broadcast_to(f.x[0] - x_before[0], (3, 2)))
    x1 = f.x.copy()
    u = f.dr[t1] - f.dr[t1 - 1]
    f.step(u, np.zeros((4, 2)), np.full(4, 30.0))
    corr = f.body_s * u + f.body_psi[-1] * np.array([-u[1], u[0]])
    np.testing.assert_allclose(f.x, x1 + u - corr)
    np.testing.assert_allclose(f.x[0], x1[0] + (1.0, 0.0), atol=1e-3)  # the true step
    np.testing.assert_allclose(f.dr[t1 + 1], f.dr[t1] + u)


def test_insdvl_heading_error_is_gauss_markov_and_the_scale_runs_along_track() -> None:
    """DRModel 'insdvl' (the body-frame nav error): on a straight track east (1 m per ping)
    the heading error recovered from the step errors has the spec's std and its lag-tau
    autocorrelation is e^-1; with the scale factor alone the error runs along the track and
    its per-run std is scale_sigma."""
    truth = np.column_stack([np.zeros(20001), np.arange(20001.0)])
    m = DRModel(kind="insdvl", sigma_m=0.0, heading_sigma_deg=2.0, heading_tau_s=50.0,
                misalign_sigma_deg=0.0, scale_sigma=0.0)  # fmt: skip
    e = m.errors(truth, 1.0, np.random.default_rng(3))
    psi = np.degrees(np.arctan2(-e[:, 0], 1.0 + e[:, 1]))  # rotation of a step east
    assert psi.std() == pytest.approx(2.0, rel=0.15)
    c = np.corrcoef(psi[:-50], psi[50:])[0, 1]
    assert c == pytest.approx(math.exp(-1), abs=0.1)
    m = DRModel(kind="insdvl", sigma_m=0.0, heading_sigma_deg=0.0, misalign_sigma_deg=0.0,
                scale_sigma=0.01)  # fmt: skip
    s = [m.errors(truth[:3], 1.0, np.random.default_rng(k)) for k in range(400)]
    assert np.abs(np.array(s)[:, :, 0]).max() == 0.0  # nothing across the track
    assert np.std([x[0, 1] for x in s]) == pytest.approx(0.01, rel=0.15)


def test_spread_after_resampling_reads_the_logged_cloud() -> None:
    """Claim C4's measure: cloud_std is the RMS distance from the cloud's centre; the spread
    before and L pings after each logged resampling is averaged over the resamplings."""
    f = MTMPF(BathyConfig(n_particles=2), 200, np.random.default_rng(0))
    f.x = np.array([[0.0, 0.0], [2.0, 0.0]])
    assert f.cloud_std() == pytest.approx(1.0)
    f.t = 150
    f.spread[:] = np.arange(200.0)
    f.resampled_at = [20, 60]
    out = spread_after_resampling(f)
    assert out["spread_before_m"] == pytest.approx(39.0)  # pings 19 and 59
    assert out["spread_lag10_m"] == pytest.approx(50.0)
    assert out["spread_lag100_m"] == pytest.approx(120.0)  # 60 + 100 is past t: only 20's


@pytest.mark.parametrize("offset_deg", [3.0, -2.0])
def test_heading_bias_state_recovers_a_constant_heading_offset(offset_deg: float) -> None:
    """heading_bias (ours, issue 28): from ping 200 on the navigation's heading is off by a
    constant ``offset_deg`` (the DR steps and the swaths turned by it, as the online stage gets
    them); the particles carry heading offsets spread evenly over +-6 deg from then on. The
    TINY survey's one crossing of the first (error-free) line weighs each particle's turned
    step and Pmap (eqs. 2, 4-5), its resampling keeps the offsets of the survivors: their mean
    is the true offset, their spread far below the prior's, and the track ends on the truth."""
    sim = simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3), DRModel(0, 0))
    e = math.radians(offset_deg)
    cfg = BathyConfig(n_particles=100, heading_bias=True, heading_sigma0_deg=0.0,
                      heading_walk_deg=0.0, sigma_c2=0.0, jitter_a=0.0, omega_sigma_m=0.0,
                      lccd=False, min_mode_ratio=1.0)  # fmt: skip
    f = MTMPF(cfg, len(sim.t), np.random.default_rng(0))
    u = sim.controls()
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    k0 = 200
    for k in range(1, len(sim.t)):
        if k == k0:
            f.b = np.radians(np.linspace(-6.0, 6.0, cfg.n_particles))
        turn = e if k >= k0 else 0.0
        f.step(rotate(u[k - 1], turn), rotate(sim.offsets[k], turn), sim.depth[k])
    assert len(f.resampled_at) == 1 and f.resampled_at[0] > k0
    assert np.degrees(f.heading_log[k0, 1]) > 3.0  # the prior's spread before the crossing
    mean, spread = np.degrees(f.heading_log[len(sim.t) - 1])
    assert mean == pytest.approx(offset_deg, abs=0.5)
    assert spread < 1.2
    dr_err = np.hypot(*(sim.truth[0] + rotate(u[k0 - 1 :], e).sum(0) + u[: k0 - 1].sum(0)
                        - sim.truth[-1]))  # fmt: skip
    assert np.hypot(*(f.traj[len(sim.t) - 1] - sim.truth[-1])) < 0.1 * dr_err
