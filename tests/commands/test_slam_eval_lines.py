"""Line features in the evaluation: the harbour's walls as (rho, theta) lines seen from the AUV,
the filters on them, the line errors and the Neff measurement of resampling and VR filters."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from auvgw.commands import slam as slam_cmd
from auvgw.config.scenario import load_scenario
from auvgw.ground.errors import UserError
from auvgw.ground.paths import config_file
from auvgw.slam.evaluation.metrics import RunResult, line_errors, summarise
from auvgw.slam.evaluation.runner import drive
from auvgw.slam.evaluation.simulate import (
    LineSensor,
    line_of_segment,
    lines_of_segments,
    simulate,
    visible_lines,
)
from auvgw.slam.landmark.registry import make_filter
from auvgw.slam.models import LineFeature, VelocityModel, wrap_angle


@pytest.fixture(scope="module")
def harbour():
    return load_scenario(config_file("scenarios/harbour.json"))


@pytest.fixture(scope="module")
def clean_lines(harbour):
    return simulate(
        harbour,
        np.random.default_rng(0),
        features="lines",
        control_noise=False,
        sensor_noise=False,
        max_steps=3000,
    )


def test_segments_become_lines_in_normal_form():
    seg = np.array([[0, 0, 0, 240], [160, 0, 160, 100], [160, 140, 160, 240], [10, 0, 0, 10.0]])
    lines, owner = lines_of_segments(seg)
    # the two breakwater arms are one line; the diagonal has its normal towards (1, 1)
    assert owner.tolist() == [0, 1, 1, 2]
    np.testing.assert_allclose(lines[1], [160.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(lines[2], [10 / math.sqrt(2), math.pi / 4], atol=1e-12)
    for s, (rho, th) in zip(seg, line_of_segment(seg), strict=True):
        for x, y in (s[:2], s[2:]):  # both ends lie on the line
            assert x * math.cos(th) + y * math.sin(th) == pytest.approx(rho, abs=1e-9)
        assert rho >= 0
    with pytest.raises(ValueError, match="zero length"):
        line_of_segment(np.array([1.0, 2.0, 1.0, 2.0]))


def test_visibility_rule_needs_enough_wall_within_range_and_view():
    wall = np.array([[0.0, -100.0, 0.0, 100.0]])  # the line x = 0
    sensor = LineSensor(max_range_m=50.0, min_length_m=5.0)
    assert visible_lines(np.array([49.0, 0.0, 0.0]), wall, sensor).tolist() == [0]
    # 50 m range, 49.9 m off: the chord within range is 2 sqrt(50^2 - 49.9^2) = 6.3 m
    assert visible_lines(np.array([49.9, 0.0, 0.0]), wall, sensor).tolist() == [0]
    # 49.99 m off: chord 2.0 m < 5 m
    assert visible_lines(np.array([49.99, 0.0, 0.0]), wall, sensor).size == 0
    # a short pier head 3 m long is never a line
    assert visible_lines(np.zeros(3), np.array([[5.0, 0.0, 5.0, 3.0]]), sensor).size == 0
    # field of view 180 deg: a wall behind the vehicle is not seen, ahead it is
    front = LineSensor(field_of_view_deg=180.0)
    assert visible_lines(np.array([10.0, 0.0, 0.0]), wall, front).size == 0
    assert visible_lines(np.array([10.0, 0.0, math.pi]), wall, front).tolist() == [0]


def test_noise_free_line_observations_are_the_model_of_the_true_pose_and_wall(harbour, clean_lines):
    run = clean_lines
    assert run.motion == "auv" and run.features == "lines" and run.dt == 0.1
    np.testing.assert_array_equal(run.controls, run.true_controls)
    # the truth moves by eq. (2) of the VR paper (the filters' VelocityModel), exactly
    model = VelocityModel()
    np.testing.assert_allclose(
        model.f(run.truth[:-1], run.true_controls, run.dt), run.truth[1:], atol=1e-9
    )
    assert np.allclose(run.true_controls[:, 0], harbour.vehicle.speed_mps)
    obs = LineFeature()
    sensor = LineSensor()
    seen = np.zeros(len(run.landmarks), dtype=bool)
    for k, z, ids in zip(run.obs_step, run.obs_z, run.obs_ids, strict=True):
        pose = run.truth[k]
        np.testing.assert_allclose(z, obs.h(pose, run.landmarks[ids]), atol=1e-12)
        np.testing.assert_array_equal(ids, visible_lines(pose, run.segments, sensor))
        # |rho_v| is the distance to the infinite line: within range
        assert np.all(np.abs(z[:, 0]) < sensor.max_range_m)
        seen[ids] = True
    assert seen.sum() >= 5
    assert sum(len(i) for i in run.obs_ids) > len(run.obs_step)


def test_line_noise_has_the_papers_msis_resolution(harbour, clean_lines):
    noisy = simulate(
        harbour, np.random.default_rng(3), features="lines", control_noise=False, max_steps=3000
    )
    d = np.concatenate([z - c for z, c in zip(noisy.obs_z, clean_lines.obs_z, strict=True)])
    d[:, 1] = wrap_angle(d[:, 1])
    np.testing.assert_allclose(np.sqrt(np.diag(noisy.r)), [0.1, math.radians(1.8)])
    assert d[:, 0].std() == pytest.approx(0.1, rel=0.1)
    assert math.degrees(d[:, 1].std()) == pytest.approx(1.8, rel=0.1)


@pytest.mark.parametrize("name", ["fastslam2", "vrfastslam"])
def test_one_particle_without_noise_reproduces_the_truth_with_lines(name, clean_lines):
    run = clean_lines
    f = make_filter(
        name,
        run.motion_model(),
        run.obs_model(),
        np.zeros((3, 3)),
        np.diag([1e-4, 1e-6]),
        n_particles=1,
        x0=run.truth[0],
    )
    est, neff, _ = drive(f, run, np.random.default_rng(0))
    np.testing.assert_allclose(est[:, :2], run.truth[run.obs_step, :2], atol=1e-6)
    np.testing.assert_allclose(wrap_angle(est[:, 2] - run.truth[run.obs_step, 2]), 0, atol=1e-8)
    assert np.all(neff == 1.0)
    lm = f.landmarks()
    err = line_errors(lm.mean, lm.ids, run.landmarks)
    assert len(err) == len(np.unique(np.concatenate(run.obs_ids)))
    np.testing.assert_allclose(err, 0.0, atol=1e-6)


def test_neff_is_measured_before_resampling_or_reduction_for_both(harbour):
    """One definition for both filters (VR eq. 8 before the degeneracy step); after it, FastSLAM
    2.0 has N equal weights of copied particles, VRFastSLAM >= 0.5 N on N distinct ones."""
    sim = simulate(harbour, np.random.default_rng(4), features="lines", max_steps=1600)
    n = 40
    out = {}
    for name in ("fastslam2", "vrfastslam"):
        f = make_filter(
            name, sim.motion_model(), sim.obs_model(), sim.q, sim.r, n_particles=n, x0=sim.truth[0]
        )
        extra: dict[str, np.ndarray] = {}
        _, neff, _ = drive(f, sim, np.random.default_rng(9), extra)
        out[name] = (neff, extra["neff_post"], extra["distinct"])
    neff, post, distinct = out["fastslam2"]
    low = neff < 0.75 * n
    assert low.any() and (~low).any()
    np.testing.assert_allclose(post[low], n)  # resampled: uniform weights
    np.testing.assert_allclose(post[~low], neff[~low])  # not resampled: unchanged
    assert np.all(distinct[low] < n)  # resampling copies particles
    neff, post, distinct = out["vrfastslam"]
    low = neff < 0.5 * n
    assert low.any()
    assert np.all(post[low] >= 0.5 * n - 1e-9)  # annealed up to the threshold
    np.testing.assert_allclose(post[~low], neff[~low])
    assert np.all(post >= neff - 1e-9)
    assert np.all(distinct == n)  # never duplicated


def test_line_errors_wrap_theta_and_match_unlabelled_lines():
    truth = np.array([[10.0, math.pi - 0.01], [20.0, 0.5], [30.0, -1.0]])
    est = np.array([[10.5, -math.pi + 0.01], [19.0, 0.52]])
    e = line_errors(est, np.array([0, 1]), truth)
    np.testing.assert_allclose(e, [[0.5, 0.02], [-1.0, 0.02]], atol=1e-12)
    e2 = line_errors(est[::-1], np.array([-1, -1]), truth)
    np.testing.assert_allclose(np.sort(np.abs(e2[:, 0])), [0.5, 1.0], atol=1e-12)
    r = RunResult(
        algorithm="x",
        run=0,
        est=np.zeros((2, 3)),
        truth=np.zeros((2, 3)),
        neff=np.array([10.0, 20.0]),
        map_mean=est,
        map_ids=np.array([0, 1]),
        landmarks=truth,
        runtime_s=1.0,
        duration_s=1.0,
        distance_m=1.0,
        features="lines",
        neff_post=np.array([50.0, 20.0]),
        distinct=np.array([100.0, 100.0]),
    )
    s = summarise([r])
    assert s.feature_rho == pytest.approx(math.sqrt((0.25 + 1.0) / 2))
    assert s.feature_theta_deg == pytest.approx(math.degrees(0.02))
    assert math.isnan(s.feature)
    assert (s.neff, s.neff_post, s.distinct) == (15.0, 35.0, 100.0)


def parse(argv):
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    slam_cmd.register(sub)
    return p.parse_args(["slam", "eval", *argv])


def test_eval_command_with_lines_on_the_harbour(tmp_path, capsys):
    out = tmp_path / "out"
    args = parse(
        [
            "--scenario",
            str(config_file("scenarios/harbour.json")),
            "--features",
            "lines",
            "--algorithms",
            "fastslam2,vrfastslam",
            "--runs",
            "1",
            "--particles",
            "20",
            "--max-steps",
            "1500",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    assert slam_cmd.run(args) == 0
    text = capsys.readouterr().out
    assert "harbour, lines: n = 1, p = 0" in text
    for row in ["Feature rho (m)", "Feature theta (deg)", "Mean Neff", "Neff after", "Distinct"]:
        assert row in text
    assert "Feature " not in text.replace("Feature rho", "").replace("Feature theta", "")
    res = json.loads((out / "results.json").read_text())
    assert "--features lines" in res["command"]
    sums = res["settings"][0]["summaries"]
    assert [s["algorithm"] for s in sums] == ["fastslam2", "vrfastslam"]
    for s in sums:
        assert 0 < s["feature_rho"] < 5 and 0 < s["feature_theta_deg"] < 5
        assert 1 <= s["neff"] <= 20 and s["neff"] <= s["neff_post"] <= 20
    assert sums[1]["distinct"] == 20
    pytest.importorskip("matplotlib")
    assert (out / "harbour_lines_n1_p0.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_eval_command_rejects_lines_without_walls(tmp_path):
    scn = tmp_path / "nowalls.json"
    scn.write_text(
        json.dumps(
            {
                "name": "nowalls",
                "vehicle": {"waypoints": [[0, 0], [50, 0]]},
                "features": {"points": [[10, 5]]},
            }
        )
    )
    with pytest.raises(UserError, match=r"features\.lines"):
        slam_cmd.run(parse(["--scenario", str(scn), "--features", "lines"]))


def test_map_of_lines_averages_angles_on_the_circle():
    """Particles holding a line at theta = pi - 0.01 and -pi + 0.01 agree on theta = pi (the
    arithmetic mean, 0, is the perpendicular line)."""
    obs = LineFeature()
    f = make_filter(
        "fastslam2", VelocityModel(), obs, np.zeros((3, 3)), np.diag([1e-2, 1e-4]), n_particles=2
    )
    f.update(np.array([[5.0, math.pi - 0.01]]), np.random.default_rng(0), np.array([7]))
    f.mu[1, 0, 1] = -math.pi + 0.01
    lm = f.landmarks()
    assert lm.ids.tolist() == [7]
    assert abs(wrap_angle(lm.mean[0, 1] - math.pi)) < 1e-9
    assert lm.cov[0, 1, 1] == pytest.approx(1e-4 + 1e-4, rel=1e-3)  # + spread 0.01^2


@pytest.mark.e2e
def test_slam_run_is_also_a_slam_subcommand(tmp_path):
    """``auvgw slam run`` (the issue's spelling) and ``auvgw slam-run`` are one command; a missing
    recording is one line naming the file, exit 2."""
    import subprocess
    import sys

    from auvgw.cli import build_parser

    a = build_parser().parse_args(["slam", "run", "--recording", "x.mcap", "--particles", "7"])
    b = build_parser().parse_args(["slam-run", "--recording", "x.mcap", "--particles", "7"])
    assert a.func is b.func
    assert (a.recording, a.particles, a.algorithm) == (b.recording, b.particles, b.algorithm)
    missing = tmp_path / "nope.mcap"
    r = subprocess.run([sys.executable, "-m", "auvgw", "slam", "run", "--recording", str(missing)],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2
    assert str(missing) in r.stderr
