"""Bailey's simulator from a scenario, the metrics and the ``auvgw slam eval`` command."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from auvgw.commands import slam as slam_cmd
from auvgw.ground.errors import UserError
from auvgw.slam.evaluation.metrics import RunResult, feature_errors, summarise
from auvgw.slam.evaluation.simulate import simulate
from auvgw.slam.models import RangeBearing
from auvgw.testing.slam_helpers import bailey_scenario


@pytest.fixture(scope="module")
def web(shared_data, tmp_path_factory):
    return bailey_scenario(shared_data, tmp_path_factory.mktemp("slam"), "webmap")


def test_webmap_run_has_baileys_length_and_settings(web):
    run = simulate(web, np.random.default_rng(0))
    assert run.dt == 0.025
    assert run.duration_s == pytest.approx(434.5, abs=1.0)  # 2 loops at 3 m/s
    assert run.distance_m == pytest.approx(3.0 * run.duration_s, rel=1e-6)
    assert len(run.landmarks) == 35
    assert np.all(np.diff(run.obs_step) == 8)
    np.testing.assert_allclose(np.sqrt(np.diag(run.q)), [0.3, math.radians(3.0)])
    np.testing.assert_allclose(np.sqrt(np.diag(run.r)), [0.1, math.radians(1.0)])
    steer = run.true_controls[:, 1]
    assert np.abs(steer).max() <= math.radians(30.0) + 1e-12
    assert np.abs(np.diff(steer)).max() <= math.radians(20.0) * 0.025 + 1e-12
    # the run ends on reaching the last waypoint of the second loop
    last = np.asarray(web.vehicle.waypoints[-1])
    assert np.hypot(*(run.truth[-1, :2] - last)) < web.vehicle.accept_radius_m + 0.1


def test_observations_are_the_visible_features_without_noise(web):
    run = simulate(
        web, np.random.default_rng(1), sensor_noise=False, control_noise=False, max_steps=4000
    )
    np.testing.assert_array_equal(run.controls, run.true_controls)
    obs = RangeBearing()
    for k, z, ids in zip(run.obs_step, run.obs_z, run.obs_ids, strict=True):
        pose = run.truth[k]
        np.testing.assert_allclose(z, obs.h(pose, run.landmarks[ids]), atol=1e-12)
        assert np.all(z[:, 0] < 30.0) and np.all(np.abs(z[:, 1]) < np.pi / 2)
        hidden = np.setdiff1d(np.arange(len(run.landmarks)), ids)
        zh = obs.h(pose, run.landmarks[hidden])
        assert not np.any((zh[:, 0] < 30.0) & (np.abs(zh[:, 1]) < np.pi / 2))
    assert sum(len(i) for i in run.obs_ids) > 100


def test_dynamic_noise_scales_the_covariance_with_probability_p(web):
    base = simulate(web, np.random.default_rng(2), sensor_noise=False)
    obs = RangeBearing()
    variances = {}
    for n, p in [(1.0, 0.0), (4.0, 0.5)]:
        run = simulate(web, np.random.default_rng(2), burst_n=n, burst_p=p)
        res = np.concatenate(
            [obs.residual(z, zc) for z, zc in zip(run.obs_z, base.obs_z, strict=True)]
        )
        variances[(n, p)] = res.var(axis=0) / np.diag(run.r)
    np.testing.assert_allclose(variances[(1.0, 0.0)], 1.0, rtol=0.1)
    np.testing.assert_allclose(variances[(4.0, 0.5)], 0.5 + 0.5 * 4.0, rtol=0.12)


def result(est, truth, **kw):
    defaults = dict(
        algorithm="a",
        run=0,
        neff=np.full(len(est), 50.0),
        map_mean=np.zeros((0, 2)),
        map_ids=np.zeros(0, dtype=int),
        landmarks=np.zeros((0, 2)),
        runtime_s=2.0,
        duration_s=100.0,
        distance_m=300.0,
    )
    defaults.update(kw)
    return RunResult(est=np.asarray(est, float), truth=np.asarray(truth, float), **defaults)


def test_summary_pools_runs_and_reports_the_papers_metrics():
    truth = np.zeros((4, 3))
    r1 = result([[3, 4, 0]] * 4, truth)  # 5 m error
    r2 = result([[0, 0, 0]] * 4, truth, runtime_s=4.0, neff=np.full(4, 70.0))
    s = summarise([r1, r2])
    assert s.path == pytest.approx(math.sqrt(12.5))
    assert s.path_x == pytest.approx(math.sqrt(4.5))
    assert s.path_y == pytest.approx(math.sqrt(8.0))
    assert s.neff == pytest.approx(60.0)
    assert s.runtime_s == pytest.approx(3.0)
    assert s.realtime_factor == pytest.approx(100.0 / 3.0)
    assert s.accuracy_pct == pytest.approx(100 * math.sqrt(12.5) / 300.0)
    assert math.isnan(s.feature)


def test_feature_errors_by_id_and_by_assignment():
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    est = np.array([[10.5, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(feature_errors(est, np.array([1, 0]), truth), [0.5, 0.0])
    np.testing.assert_allclose(sorted(feature_errors(est, np.array([-1, -1]), truth)), [0.0, 0.5])


def test_parse_noise():
    assert slam_cmd.parse_noise("n=2,p=0.3") == (2.0, 0.3)
    assert slam_cmd.parse_noise("p=0.1") == (1.0, 0.1)
    for bad in ["n=2;p=0.3", "q=1", "n=0.5,p=0.1", "n=2,p=1.5", "n=two"]:
        with pytest.raises(UserError):
            slam_cmd.parse_noise(bad)


def parse(argv):
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    slam_cmd.register(sub)
    return p.parse_args(["slam", "eval", *argv])


def test_eval_command_prints_tables_and_writes_results(web, tmp_path, capsys):
    scenario = tmp_path / "web.json"
    data = web.model_dump(exclude={"source"}, exclude_none=True)
    data["features"] = {"points": [list(p) for p in web.point_features()]}
    data["vehicle"].pop("waypoints_file", None)
    scenario.write_text(json.dumps(data))
    out = tmp_path / "out"
    args = parse(
        [
            "--scenario",
            str(scenario),
            "--algorithms",
            "fastslam1,ekf",
            "--runs",
            "2",
            "--noise",
            "n=3,p=0.5",
            "--particles",
            "10",
            "--max-steps",
            "1200",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    assert slam_cmd.run(args) == 0
    text = capsys.readouterr().out
    assert "n = 3, p = 0.5 (2 runs, 10 particles" in text
    for row in ["Path", "Path-X", "Path-Y", "Feature", "Mean Neff", "Real-time factor"]:
        assert row in text
    assert "FastSLAM1.0" in text and "EKF-SLAM" in text
    md = (out / "tables.md").read_text()
    assert "auvgw slam eval --scenario" in md and "--noise n=3,p=0.5" in md
    res = json.loads((out / "results.json").read_text())
    sums = res["settings"][0]["summaries"]
    assert [s["algorithm"] for s in sums] == ["fastslam1", "ekf"]
    assert all(0 < s["path"] < 10 and s["runs"] == 2 for s in sums)
    pytest.importorskip("matplotlib")
    png = out / "webmap_n3_p0.5.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_eval_command_rejects_bad_input(tmp_path, web):
    with pytest.raises(UserError, match="unknown algorithm"):
        slam_cmd.run(parse(["--scenario", "x.json", "--algorithms", "fastslam9"]))
    with pytest.raises(UserError, match="cannot read"):
        slam_cmd.run(parse(["--scenario", str(tmp_path / "missing.json")]))


def test_cli_pipeline_magnetic_rejects_options_it_does_not_read(capsys) -> None:
    """The recorded "Made by" line lists only options the pipeline reads: the others are
    user errors (exit 2, one line). (In this process: an interpreter each cost 3-4 s.)"""
    from auvgw.cli import main
    from auvgw.ground.paths import config_file

    scenario = config_file("scenarios/beacons_amb.json")
    for extra in (["--particles", "5"], ["--r0-scale", "2"], ["--association", "nn"]):
        code = main(["slam", "eval", "--pipeline", "magnetic", "--scenario", str(scenario),
                     "--runs", "1", *extra])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and f"does not read {extra[0]}" in err, err
        assert len(err.strip().splitlines()) == 1


def test_a_diverged_run_is_counted_and_kept_out_of_the_metrics(web, monkeypatch):
    """A filter that fails numerically (here: singular S at the 5th scan, NaN pose at the 3rd)
    does not stop the study: its run is marked with the scan and time, its scans before the
    failure are kept, the summary pools the other runs and the table shows the count."""
    from auvgw.slam.evaluation import runner
    from auvgw.slam.evaluation.report import format_table, summaries_by_algorithm
    from auvgw.slam.landmark.registry import make_filter

    def failing(name: str, *args: object, **kw: object) -> object:
        f = make_filter("ekf", *args, **kw)
        calls = {"n": 0}
        update = f.update

        def bad_update(z: np.ndarray, rng: np.random.Generator, ids: object = None) -> None:
            calls["n"] += 1
            update(z, rng, ids)
            if name == "ekf" and calls["n"] == 5:
                raise np.linalg.LinAlgError("Singular matrix")
            if name == "shekf" and calls["n"] == 3:
                f.xs[0] = np.nan

        f.update = bad_update  # type: ignore[method-assign]
        return f

    study = runner.Study(web, ("ekf", "shekf"), runs=2, max_steps=400)
    good = runner.run_one(study, 1, "ekf")
    monkeypatch.setattr(runner, "make_filter", failing)
    bad = runner.run_one(study, 0, "ekf")
    nan = runner.run_one(study, 0, "shekf")
    assert bad.diverged.startswith("diverged at ") and "(scan 4): Singular matrix" in bad.diverged
    assert len(bad.est) == len(bad.truth) == 4 and np.all(np.isfinite(bad.est))
    assert "(scan 2): non-finite pose" in nan.diverged and len(nan.est) == 2
    assert good.diverged == "" and len(good.est) > 4
    s_ekf, s_sh = summaries_by_algorithm([bad, good, nan], ("ekf", "shekf"))
    assert s_ekf.diverged == 1 and s_ekf.runs == 1
    assert s_ekf.path == pytest.approx(summarise([good]).path)
    assert s_ekf.path_runs == pytest.approx((s_ekf.path,)) and s_sh.path_runs == ()
    assert s_sh.diverged == 1 and s_sh.runs == 0 and math.isnan(s_sh.path)
    table = format_table("t", [s_ekf, s_sh])
    assert [ln.split()[-2:] for ln in table.splitlines() if ln.startswith("Diverged")] == [
        ["1", "1"]
    ]
    assert "Diverged" not in format_table("t", [summarise([good])])


def test_bursts_are_recorded_and_an_oracle_filter_is_told_them(web, monkeypatch):
    """``obs_scale`` holds the variance multiple each observation was drawn with, and with
    ``oracle_noise`` the particle filters get ``R0 x scale`` per observation."""
    sim = simulate(web, np.random.default_rng(4), burst_n=100.0, burst_p=0.3, max_steps=3000)
    scale = np.concatenate(sim.obs_scale)
    assert set(np.unique(scale)) == {1.0, 100.0}
    assert abs(np.mean(scale == 100.0) - 0.3) < 0.05
    clean = simulate(web, np.random.default_rng(4), max_steps=3000, sensor_noise=False)
    err = np.concatenate(sim.obs_z) - np.concatenate(clean.obs_z)
    err[:, 1] = (err[:, 1] + np.pi) % (2 * np.pi) - np.pi
    z = err / np.sqrt(np.diag(sim.r)) / np.sqrt(scale)[:, None]  # unit normal if scale is right
    assert np.std(z[scale == 100.0]) == pytest.approx(1.0, abs=0.1)
    assert np.std(z[scale == 1.0]) == pytest.approx(1.0, abs=0.1)

    from auvgw.slam.evaluation import runner
    from auvgw.slam.landmark.base import ParticleFilterSLAM

    seen: list[np.ndarray | None] = []
    update = ParticleFilterSLAM.update

    def spy(
        self: ParticleFilterSLAM, *a: object, r: np.ndarray | None = None, **kw: object
    ) -> None:
        seen.append(r)
        update(self, *a, r=r, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(ParticleFilterSLAM, "update", spy)
    study = runner.Study(web, ("fastslam2",), runs=1, burst_n=100.0, burst_p=0.3, max_steps=400)
    runner.run_one(study, 0, "fastslam2")
    assert seen and all(r is None for r in seen)
    seen.clear()
    oracle = runner.Study(web, ("fastslam2",), 1, 100.0, 0.3, max_steps=400, oracle_noise=True)
    runner.run_one(oracle, 0, "fastslam2")
    sim0 = simulate(web, np.random.default_rng([0, 0]), burst_n=100.0, burst_p=0.3, max_steps=400)
    assert len(seen) == len(sim0.obs_scale)
    for r, s in zip(seen, sim0.obs_scale, strict=True):
        np.testing.assert_array_equal(r, sim0.r * s[:, None, None])
