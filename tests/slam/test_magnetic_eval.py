"""The magnetic evaluation harness and ``auvgw slam eval --pipeline magnetic``."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import load_scenario
from auvgw.ground.paths import config_file
from auvgw.slam.magnetic.diagnose import diagnose_run, longest_gap
from auvgw.slam.magnetic.evaluation import (
    TEST_SEED_MIN,
    MagneticRun,
    Variant,
    nees_summary,
    paired_bootstrap,
    paired_change,
    parse_variant,
    prepare,
    run_filter,
    seed_split,
)

SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "beacons_amb.json"
DENSE = SCENARIO.with_name("beacons_dense.json")


def test_parse_variant_and_errors() -> None:
    assert parse_variant("default") == Variant()
    v = parse_variant("track=mlp,density=first-half,fov_deg=360")
    assert (v.track, v.density, v.fov_deg) == ("mlp", "first-half", 360.0)
    with pytest.raises(ValueError, match="unknown key 'trak'"):
        parse_variant("trak=mlp")
    with pytest.raises(ValueError, match="loop must be one of"):
        parse_variant("loop=sideways")
    with pytest.raises(ValueError, match="association=known needs track=generic"):
        parse_variant("track=mlp,association=known")


def test_known_association_maps_each_observed_beacon_once() -> None:
    """``association=known``: every observation carries its true beacon, so MB-SLAM maps each
    observed beacon exactly once (the paper's NN association may map one twice)."""
    scn = load_scenario(SCENARIO)
    v = parse_variant("association=known")
    prep = prepare(scn, v, seed=1, run=0, max_steps=6000)
    assert prep.ids is not None and [len(i) for i in prep.ids] == [len(z) for z in prep.z]
    seen = np.unique(np.concatenate(prep.ids))
    run = run_filter("mb-slam", prep, v)
    assert len(seen) >= 3 and len(run.lm_mean) == len(seen)
    nn = run_filter("mb-slam", prepare(scn, Variant(), seed=1, run=0, max_steps=6000), Variant())
    assert not np.array_equal(nn.est, run.est)  # the ids were used, not ignored
    assert prepare(scn, Variant(), seed=1, run=0, max_steps=600).ids is None


@pytest.mark.parametrize("track", ["generic", "mlp"])
def test_acoustic_anchor_bounds_the_drift(track: str) -> None:
    scn = load_scenario(SCENARIO)
    v = Variant(track=track)
    prep = prepare(scn, v, seed=1, run=0, max_steps=6000)  # 150 s, 750 m
    assert len(prep.beacons) == 20 and sum(len(z) for z in prep.z) > 50
    runs = {a: run_filter(a, prep, v) for a in ("amb-slam", "mb-slam", "dr")}
    assert runs["amb-slam"].rmse[0] < 5.0
    assert runs["amb-slam"].rmse[0] < 0.5 * runs["dr"].rmse[0]
    assert len(runs["dr"].lm_mean) == 0 and len(runs["mb-slam"].lm_mean) > 0


def test_first_half_keeps_only_the_first_half_beacons() -> None:
    scn = load_scenario(SCENARIO)
    prep = prepare(scn, Variant(density="first-half"), seed=0, run=0)
    n = len(prep.sim.obs_step)
    assert 0.45 * n < prep.lap2_scan < 0.6 * n  # lap 2 starts back at the origin, near half way
    assert 5 <= len(prep.beacons) <= 15
    assert np.all(prep.beacons[:, 1] < 300)  # the serpentine's first half is the south


@pytest.mark.e2e
def test_cli_pipeline_magnetic_writes_tables_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "res"
    cmd = [sys.executable, "-m", "auvgw", "slam", "eval", "--pipeline", "magnetic",
           "--scenario", str(SCENARIO), "--algorithms", "amb-slam,acoustic-only,dr", "--runs", "2",
           "--max-steps", "1500", "--no-progress", "--out", str(out)]  # fmt: skip
    cmd += ["--variant", "default", "--variant", "density=first-half"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "amb-slam" in p.stdout and "dr" in p.stdout
    md = (out / "tables.md").read_text()
    assert "--pipeline magnetic" in md and "| amb-slam |" in md
    assert "Seeds: **tuning** (base seed 0" in md and "(2 runs, tuning seeds)" in md
    assert "| amb-slam vs acoustic-only |" in md and "pose NEES (3" in md
    res = json.loads((out / "results.json").read_text())
    rows = {r["algorithm"]: r for r in res["variants"][0]["rows"]}
    assert rows["amb-slam"]["runs"] == 2 and rows["amb-slam"]["rmse"] < rows["dr"]["rmse"]
    assert len(list(out.glob("*_map.png"))) == 2 and len(list(out.glob("*_errors.png"))) == 2
    # the density study's run-by-run change table, from the two rows of each algorithm
    assert "density all -> first-half" in md and "runs worse" in md
    (ch,) = res["density_changes"]
    half = {r["algorithm"]: r for r in res["variants"][1]["rows"]}
    for c in ch["rows"]:
        a = c["algorithm"]
        assert c["change"] == pytest.approx(half[a]["rmse"] - rows[a]["rmse"], abs=2e-3)
    dr = next(c for c in ch["rows"] if c["algorithm"] == "dr")
    assert dr["change"] == 0.0 and dr["worse"] == 0  # dead reckoning sees no beacon either way
    assert config_file("acoustic.toml").exists()
    (pair,) = res["variants"][0]["pairs"]
    aco = {r["algorithm"]: r for r in res["variants"][0]["rows"]}["acoustic-only"]
    assert (pair["base"], pair["other"]) == ("acoustic-only", "amb-slam")
    assert pair["diff"] == pytest.approx(rows["amb-slam"]["rmse"] - aco["rmse"], abs=2e-3)
    assert 0.0 <= aco["nees_pose_in"] <= 1.0 and aco["n_landmarks"] == 0.0


@pytest.mark.e2e
def test_acoustic_only_without_fixes_is_dead_reckoning_and_the_acoustic_settings() -> None:
    scn = load_scenario(SCENARIO)
    v = Variant()
    prep = prepare(scn, v, seed=1, run=0, max_steps=2000)
    aco, dr = run_filter("acoustic-only", prep, v), run_filter("dr", prep, v)
    assert aco.rmse[0] < 0.5 * dr.rmse[0] and len(aco.lm_mean) == 0
    prep.acoustic_z[:] = np.nan  # no acoustic fix: the same filter only predicts
    aco = run_filter("acoustic-only", prep, v)
    np.testing.assert_array_equal(aco.est, dr.est)
    np.testing.assert_array_equal(aco.nees_pose, dr.nees_pose)
    # 1 Hz, 300 m range, 0.5 m sigma: the same draws, fixes only every 5th scan within range
    u = parse_variant("acoustic_every=5,acoustic_max_range_m=300,acoustic_sigma_m=0.5")
    pu, p0 = prepare(scn, u, seed=1, run=0, max_steps=2000), prepare(scn, v, 1, 0, 2000)
    st = pu.sim.truth[pu.sim.obs_step]
    hr = np.hypot(st[:, 0] - scn.acoustic_beacon.x, st[:, 1] - scn.acoustic_beacon.y)
    has = ~np.isnan(pu.acoustic_z[:, 0])
    idx = np.arange(len(st))
    assert np.array_equal(has, (idx % 5 == 0) & (hr <= 300)) and 10 < has.sum() < 0.2 * len(st)
    d_u = pu.acoustic_z[has, 0] - hr[has]
    d_0 = p0.acoustic_z[has, 0] - hr[has]
    np.testing.assert_allclose(d_u, 5 * d_0, rtol=0.02, atol=0.02)  # sigma 0.5 m, not 0.1
    assert pu.acoustic_r[0, 0, 0] == pytest.approx(5**2 * p0.acoustic_r[0, 0, 0], rel=1e-3)
    assert "acoustic every 5 scans" in u.label and "acoustic range 300 m" in u.label


def _run(nees: np.ndarray, hdg: np.ndarray) -> MagneticRun:
    z = np.zeros((len(nees), 2))
    return MagneticRun("x", 0, z[:, 0], z, z, z, z, z, 0.0, 0.0, 0.0, 1.0, 1.0,
                       nees_pose=nees, nees_heading=hdg)  # fmt: skip


def test_nees_summary_on_consistent_and_overconfident_runs() -> None:
    """Chi-square NEES (3 and 1 degrees of freedom) averages to 3 and 1, inside the 95 % band of
    a 20-run average at about 95 % of the scans; ten times that is outside everywhere."""
    from scipy.stats import chi2

    rng = np.random.default_rng(3)
    runs = [_run(rng.chisquare(3, 400), rng.chisquare(1, 400)) for _ in range(20)]
    s = nees_summary(runs)
    assert s["nees_pose"] == pytest.approx(3.0, abs=0.1)
    assert s["nees_heading"] == pytest.approx(1.0, abs=0.05)
    np.testing.assert_allclose(s["nees_pose_band"], chi2.ppf([0.025, 0.975], 60) / 20)
    assert 0.9 < s["nees_pose_in"] <= 1.0 and 0.9 < s["nees_heading_in"] <= 1.0
    bad = nees_summary([_run(10 * r.nees_pose, 10 * r.nees_heading) for r in runs])
    assert bad["nees_pose_in"] == 0.0 and bad["nees_heading"] == pytest.approx(10.0, abs=0.5)


def test_paired_bootstrap_and_seed_split() -> None:
    base = {"algorithm": "acoustic-only", "rmse_runs": [2.0, 4.0, 6.0, 8.0, 10.0]}
    other = {"algorithm": "amb-slam", "rmse_runs": [1.0, 2.0, 3.0, 4.0, 5.1]}
    c = paired_bootstrap(base, other)
    assert c["diff"] == pytest.approx(-2.98) and c["other_better"] == 5
    assert c["ratio"] == pytest.approx(15.1 / 30.0)
    lo, hi = c["ratio_ci"]
    assert 0.5 <= lo <= c["ratio"] <= hi <= 0.52  # every resample has ratio ~0.5
    assert c["diff_ci"][0] < c["diff"] < c["diff_ci"][1] < 0
    assert paired_bootstrap(base, other) == c  # seeded
    with pytest.raises(ValueError, match="same runs"):
        paired_bootstrap(base, {"algorithm": "amb-slam", "rmse_runs": [1.0]})
    assert seed_split(0) == seed_split(TEST_SEED_MIN - 1) == "tuning"
    assert seed_split(TEST_SEED_MIN) == seed_split(1028) == "test"


def test_paired_change_by_hand() -> None:
    base = {"algorithm": "mb-slam", "rmse_runs": [1.0, 2.0, 3.0, 4.0]}
    other = {"algorithm": "mb-slam", "rmse_runs": [2.0, 2.0, 5.0, 3.0]}
    c = paired_change(base, other)
    # differences 1, 0, 2, -1: mean 0.5, sample std sqrt(5/3), s.e. sqrt(5/3)/2
    assert c["change"] == pytest.approx(0.5)
    assert c["change_se"] == pytest.approx(np.sqrt(5 / 3) / 2)
    assert (c["worse"], c["runs"]) == (2, 4)
    assert c["ratio"] == pytest.approx(3.0 / 2.5)
    assert c["change_ci"][0] < c["change"] < c["change_ci"][1]
    with pytest.raises(ValueError, match="same runs"):
        paired_change(base, {"algorithm": "mb-slam", "rmse_runs": [1.0, 2.0]})
    with pytest.raises(ValueError, match="one algorithm"):
        paired_change(base, {**other, "algorithm": "dr"})


def test_dense_scenario_keeps_a_beacon_in_view_along_the_route() -> None:
    """``beacons_dense.json`` (docs/slam_magnetic.md): a beacon every 20 m of the route, 5 m to
    alternate sides, every one within the 25 m sensor range of the flown path, never more than
    ~2 s (a corner) without a sighting, and the paper's vehicle and sensor of the v03 field."""
    scn = load_scenario(DENSE)
    v03 = load_scenario(SCENARIO.with_name("beacons_amb_v03.json"))
    assert scn.bicycle == v03.bicycle and scn.observations == v03.observations
    assert scn.observations.max_range_m == 25.0 and len(scn.magnetic_beacons) == 30
    prep = prepare(scn, Variant(), seed=0, run=0)
    lap1 = prep.sim.truth[: prep.sim.obs_step[prep.lap2_scan], :2]
    b = np.array([(m.x, m.y) for m in scn.magnetic_beacons])
    d = np.hypot(*(b[:, None] - lap1[None]).transpose(2, 0, 1))
    assert d.min(axis=1).max() < 8.0  # 5 m off the route (corners cut a little)
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(lap1, axis=0).T))]
    spacing = np.diff(np.sort(arc[d.argmin(axis=1)]))  # along the flown path
    assert len(spacing) == 29 and abs(np.median(spacing) - 20.0) < 0.5
    assert spacing.max() < 27.0  # at a corner the flown path swings wide of the polyline
    g0, g1 = longest_gap(prep)
    assert (g1 - g0 + 1) / 5.0 <= 2.5  # seconds at 5 Hz
    assert np.mean([len(z) > 0 for z in prep.z]) > 0.95
    freqs = {m.frequency_hz for m in scn.magnetic_beacons}
    assert len(freqs) <= 6 and max(freqs) < 10.0  # the demodulator's channels, below Nyquist


def test_longest_gap_and_diagnosis_on_the_dense_field() -> None:
    prep = prepare(load_scenario(DENSE), Variant(), seed=0, run=0, max_steps=400)
    one, none = np.zeros((1, 2)), np.zeros((0, 2))
    z = [one, none, none, one, none, none, none, one, none]
    assert longest_gap(replace(prep, z=z)) == (4, 6)
    assert longest_gap(replace(prep, z=[one, one])) == (0, -1)
    d = diagnose_run(load_scenario(DENSE), Variant(), seed=0, run=1)
    assert d.longest_gap_s <= 2.5 and d.scans_with_sighting > 0.95
    assert d.mb_rmse < 0.5 * d.dr_rmse  # MB-SLAM beats dead reckoning on the dense field
    # revisits re-localise on the map: the vehicle's error is the beacon's, within a metre
    assert d.revisit_difference_m < 1.0 and d.map_error_first_sighting_m < 10.0
    assert 0.1 < d.mb_nees_heading < 5.0  # consistent (1 expected), unlike the sparse field
