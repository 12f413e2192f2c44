"""``auvgw demo --scenario survey --processes`` end to end: the emulated vehicle, the gateway, the
fusion stage and the bathymetric SLAM stage (``auvgw slam run --pipeline bathymetric``) each in
its own OS process, joined by Zenoh; the demo's summary is read back and checked against the
emulator's ground truth: the stage published a pose track that follows the truth and the
odometry it was given, and a seabed map that matches the true terrain."""

from __future__ import annotations

import json

import pytest

from auvgw.testing import run_demo_processes

DURATION_S = 90.0  # 150 m of the first survey line at 1.7 m/s
SPEED = 3.0


@pytest.fixture(scope="module")
def survey_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo-survey")
    _, stdout, summary = run_demo_processes(out, "survey", DURATION_S, SPEED, 300)
    return out, stdout, summary


def test_bathymetric_stage_ran_in_its_own_process(survey_run) -> None:
    out, _stdout, summary = survey_run
    procs = summary["processes"]
    assert set(procs) == {"sim", "gateway", "fusion", "slam"}
    assert all(p["exit_code"] == 0 and not p["killed"] for p in procs.values()), procs
    assert "slam running" in (out / "slam.log").read_text()
    slam = summary["slam"]
    assert slam["component"] == "slam-bathymetric"
    st = slam["stage"]
    mb = summary["devices"]["multibeam"]["messages"]["XYZ88"]
    # every swath the gateway decoded reached the stage; one used per 2 m of track
    assert st["swaths"] >= 0.98 * mb and st["bad_payloads"] == 0 and st["bad_swaths"] == 0
    distance = summary["navigation"]["dead_reckoning"]["distance_m"]
    assert st["pings"] == pytest.approx(distance / 2.0, rel=0.2)
    assert st["published"] == st["pings"] and st["maps"] >= st["pings"] // 20


def test_pose_track_and_map_are_consistent_with_truth(survey_run) -> None:
    _, stdout, summary = survey_run
    nav = summary["navigation"]
    dr, slam = nav["dead_reckoning"], nav["slam"]
    # every pose the stage published reached the demo; the last may be stamped after the last
    # truth sample, the first before dead reckoning's first DVL fix (both not scored)
    assert slam["samples"] + slam["outside_truth"] == summary["slam"]["stage"]["published"]
    assert slam["outside_truth"] <= 3
    assert slam["distance_m"] == pytest.approx(dr["distance_m"], rel=0.1)
    # no overlap on one straight line (the overlap test skips the last t_l = 60 pings, 120 m,
    # more than the demo's R = 90 m): the particle centroid follows dead reckoning
    assert slam["rmse_m"] < 2.0 * dr["rmse_m"] + 1.0 and slam["rmse_pct_distance"] < 3.0
    # the seabed map (the stage's final DEM, the whole map) against the true terrain
    m = summary["bathymetric_map"]
    assert m["cells"] > 2000  # a 150 m line under a ~180 m swath, 2 m cells
    assert m["median_abs_error_m"] < 1.0 and m["share_under_2m"] > 0.9
    assert "bathymetric map vs true terrain" in stdout


def test_report_prints_filtered_smoothed_and_closures(survey_run) -> None:
    """Issue 33's "figures printed by the demo": the filtered (published poses) and smoothed
    (the stage's trajectory after every closure, at flush) errors, the closures and the DR / SLAM
    ratios, in the printed report and in summary.json."""
    _, stdout, summary = survey_run
    nav = summary["navigation"]
    smoothed, filtered = nav["slam_smoothed"], nav["slam"]
    # one smoothed pose per used swath, stamped as the filtered ones
    assert smoothed["samples"] + smoothed["outside_truth"] == summary["slam"]["stage"]["pings"]
    assert smoothed["distance_m"] == pytest.approx(filtered["distance_m"], rel=0.01)
    # no overlap yet: no closure, so the smoothed track is the filtered one
    assert nav["closures_vehicle_s"] == [] and summary["slam"]["loops_accepted"] == 0
    assert smoothed["rmse_m"] == pytest.approx(filtered["rmse_m"], abs=0.01)
    lines = {ln.split(" vs ", 1)[0]: ln for ln in stdout.splitlines() if " vs " in ln}
    assert "SLAM filtered (mtm-pf (bathymetric PF-SLAM): each pose as published)" in lines
    assert f"RMSE {smoothed['rmse_m']:.2f} m" in lines[
        "SLAM smoothed (mtm-pf mean trajectory after every closure)"]  # fmt: skip
    assert "loop closures accepted: 0, none" in stdout
    ratio = lines["bathymetric SLAM"]
    dr = nav["dead_reckoning_at_slam"]  # the ratios compare the same instants
    assert f"final DR {dr['final_m']:.2f} m / filtered {filtered['final_m']:.2f} m" in ratio
    assert f"/ smoothed {smoothed['rmse_m']:.2f} m = " in ratio

def test_tracks_file_holds_the_scored_run(survey_run) -> None:
    """Issue 28's gauge: ``tracks.npz`` holds the truth, dead reckoning, the published and the
    smoothed poses at the scored pose times (the summary's filtered error comes back from it)
    and the odometry's heading error, which the INS's Gauss-Markov bias (0.4 deg) keeps small
    and not zero."""
    import numpy as np

    from auvgw.slam.bathymetric.evaluate import gauge_error

    out, _stdout, summary = survey_run
    nav = summary["navigation"]
    with np.load(out / "tracks.npz") as z:
        tr = {k: z[k] for k in z.files}
    filtered = nav["slam"]
    assert len(tr["t"]) == filtered["samples"] and tr["t"][0] == pytest.approx(filtered["from_s"])
    err = np.hypot(*(tr["filtered"] - tr["truth"]).T)
    assert np.sqrt(np.mean(err**2)) == pytest.approx(filtered["rmse_m"], abs=1e-3)
    assert err[-1] == pytest.approx(filtered["final_m"], abs=1e-3)
    # no closure: the smoothed track is the published one
    np.testing.assert_allclose(tr["smoothed"], tr["filtered"], atol=0.05)
    dr = np.hypot(*(tr["dr"] - tr["truth"]).T)
    assert 0.0 < np.sqrt(np.mean(dr**2)) < 2.0 * nav["dead_reckoning"]["rmse_m"] + 0.5
    psi = tr["heading_error_deg"]
    assert np.isfinite(psi).all() and 0.0 < np.abs(psi).max() < 3.0
    g = gauge_error(tr["dr"].astype(float), tr["truth"].astype(float))
    assert g.aligned_rmse_m <= g.rmse_m + 1e-9



def test_the_stage_process_runs_the_demo_settings() -> None:
    """The settings frozen for issues 28 and 33 (docs/results/bathymetric/e2e) reach the stage
    process's command line (``slam run --set``) and its filter: the overlap radius of half the
    swath, the filter's own likelihood and closure defaults."""
    import argparse

    from auvgw.commands.bathy_run import DEMO_FILTER, demo_argv, demo_config, stage_config
    from auvgw.slam.bathymetric.config import BathyConfig

    argv = demo_argv(demo_config("auv1", "multibeam"), "tcp/127.0.0.1:1")
    sets = [argv[i + 1] for i, a in enumerate(argv) if a == "--set"]
    assert {k: json.loads(v) for k, _, v in (s.partition("=") for s in sets)} == DEMO_FILTER
    args = argparse.Namespace(particles=200, seed=0, multibeam="multibeam", set=sets)
    cfg = stage_config(args, "auv1").bathy_config()
    # R = 90 m: half the 180 m swath (the lines are 80 m apart)
    assert cfg.radius_m == 90.0 and not cfg.drift_estimate and not cfg.lccd
    defaults = BathyConfig()
    for key in ("sigma_s_m", "unmatched_weight", "jitter_in_crossing", "closure_estimate"):
        assert getattr(cfg, key) == getattr(defaults, key), key
