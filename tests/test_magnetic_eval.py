"""The magnetic evaluation harness and ``auvgw slam eval --pipeline magnetic``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import load_scenario
from auvgw.paths import config_file
from auvgw.slam.magnetic.evaluation import Variant, parse_variant, prepare, run_filter

SCENARIO = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "beacons_amb.json"


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


def test_cli_pipeline_magnetic_writes_tables_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "res"
    cmd = [sys.executable, "-m", "auvgw", "slam", "eval", "--pipeline", "magnetic",
           "--scenario", str(SCENARIO), "--algorithms", "amb-slam,dr", "--runs", "2",
           "--max-steps", "1500", "--no-progress", "--out", str(out)]  # fmt: skip
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "amb-slam" in p.stdout and "dr" in p.stdout
    md = (out / "tables.md").read_text()
    assert "--pipeline magnetic" in md and "| amb-slam |" in md
    res = json.loads((out / "results.json").read_text())
    rows = {r["algorithm"]: r for r in res["variants"][0]["rows"]}
    assert rows["amb-slam"]["runs"] == 2 and rows["amb-slam"]["rmse"] < rows["dr"]["rmse"]
    assert len(list(out.glob("*_map.png"))) == 1 and len(list(out.glob("*_errors.png"))) == 1
    assert config_file("acoustic.toml").exists()
