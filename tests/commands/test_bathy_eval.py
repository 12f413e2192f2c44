"""The bathymetric evaluation (``auvgw slam eval --pipeline bathymetric``) and the Monte Carlo
executor: identical results in this process, on local processes and on a Dask LocalCluster,
for the bathymetric and the landmark pipelines."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from auvgw.commands import slam as slam_cmd
from auvgw.config.scenario import Scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.study import BathyStudy, monte_carlo
from auvgw.slam.evaluation.executor import open_executor
from auvgw.testing.bathy_helpers import TINY, local_cluster
from auvgw.testing.slam_helpers import bailey_scenario


def _study() -> BathyStudy:
    cfg = BathyConfig(n_particles=40, t_l=30, min_matched_fraction=0.05)
    return BathyStudy(Scenario.model_validate(TINY), ("mtm-pf", "bpslam", "dr"), 2, cfg, seed=3)


def _same(a: list, b: list) -> None:
    assert [(r.run, r.algorithm) for r in a] == [(r.run, r.algorithm) for r in b]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.final, y.final)
        assert (x.loops_accepted, x.loops_rejected, x.map_err_mean_m) == (
            y.loops_accepted,
            y.loops_rejected,
            y.map_err_mean_m,
        )


@pytest.mark.e2e
def test_bathymetric_trials_are_identical_here_in_processes_and_on_dask() -> None:
    pytest.importorskip("distributed")
    study = _study()
    here = monte_carlo(study)
    assert len(here) == 6 and {r.algorithm for r in here} == {"mtm-pf", "bpslam", "dr"}
    dr = [r for r in here if r.algorithm == "dr"]
    assert all(r.final_error_m > 1.0 for r in dr)  # eq. (28) drift is there
    assert here[0].final_error_m != here[3].final_error_m  # runs differ
    with open_executor(jobs=2) as ex:
        _same(here, monte_carlo(study, ex))
    with local_cluster() as address, open_executor(dask=address) as ex:
        _same(here, monte_carlo(study, ex))


@pytest.mark.e2e
def test_landmark_trials_on_dask_match_the_serial_ones(shared_data, tmp_path) -> None:
    pytest.importorskip("distributed")
    from auvgw.slam.evaluation import runner

    web = bailey_scenario(shared_data, tmp_path, "webmap")
    study = runner.Study(web, ("fastslam2", "ekf"), runs=2, max_steps=300, n_particles=20)
    serial = runner.monte_carlo(study)
    with local_cluster() as address, open_executor(dask=address) as ex:
        remote = runner.monte_carlo(study, executor=ex)
    assert [(r.run, r.algorithm) for r in serial] == [(r.run, r.algorithm) for r in remote]
    for a, b in zip(serial, remote, strict=True):
        np.testing.assert_array_equal(a.est, b.est)


def test_unreachable_dask_scheduler_is_a_user_error(tmp_path, monkeypatch) -> None:
    pytest.importorskip("distributed")
    from auvgw.ground.errors import UserError
    from auvgw.slam.evaluation import executor

    # nothing listens on port 1: the refused connection is retried until the timeout (10 s by
    # default, all of it idle here)
    monkeypatch.setattr(executor, "DASK_CONNECT_TIMEOUT_S", 0.5)

    args = _bathy_args(tmp_path, "--runs", "1", "--dask", "tcp://127.0.0.1:1", "--no-progress")
    with pytest.raises(UserError, match="cannot reach the Dask scheduler"):
        slam_cmd.run(args)


def _bathy_args(tmp_path: Path, *argv: str) -> argparse.Namespace:
    """``slam eval --pipeline bathymetric --scenario <TINY written to tmp_path> *argv``."""
    scn = tmp_path / "tiny.json"
    scn.write_text(json.dumps(TINY))
    return _parse(["--pipeline", "bathymetric", "--scenario", str(scn), *argv])


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    slam_cmd.register(sub)
    return p.parse_args(["slam", "eval", *argv])


def test_eval_command_bathymetric_prints_the_measures_and_writes_plots(tmp_path, capsys) -> None:
    pytest.importorskip("matplotlib")
    out = tmp_path / "res"
    args = _bathy_args(
        tmp_path,
        "--runs",
        "1",
        "--particles",
        "30",
        "--set",
        "t_l=30",
        "--no-progress",
        "--out",
        str(out),
    )
    assert slam_cmd.run(args) == 0
    text = capsys.readouterr().out
    for row in (
        "Final error, mean (m)",
        "Real-time factor",
        "Memory held (MB)",
        "LCCD precision / recall / F1",
        "Closures labelled false, share per run",
        "Soundings within 2 m (%)",
    ):
        assert row in text
    assert text.splitlines()[1].split() == ["mtm-pf", "bpslam", "dr"]
    md = (out / "tables.md").read_text()
    assert "--pipeline bathymetric" in md and "--set t_l=30" in md
    res = json.loads((out / "results.json").read_text())
    assert res["config"]["t_l"] == 30 and len(res["final_errors"]["dr"]) == 1
    runs, mtm = res["loops_per_run"]["mtm-pf"], res["summaries"]["mtm-pf"]
    n = sum(runs[0].values())
    assert len(runs) == 1 and n == sum(mtm[k] for k in ("tp", "fp", "tn", "fn"))
    if n:  # the share of closures truth labels false
        assert mtm["false_share"] == pytest.approx((runs[0]["fp"] + runs[0]["tn"]) / n)
    for png in ("map", "trajectories", "error"):
        assert (out / f"tiny_survey_{png}.png").stat().st_size > 10_000
    from auvgw.ground.errors import UserError

    with pytest.raises(UserError, match=r"--set: .*n_particle"):
        slam_cmd.run(_bathy_args(tmp_path, "--set", "n_particle=3", "--no-progress"))
