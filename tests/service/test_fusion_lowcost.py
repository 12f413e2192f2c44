"""The fusion on the low-cost vehicle (config/scenarios/lowcost.json,
tests/support/fusion_lowcost.py):
with DEFAULT noise settings it does as well as the same filter told the true DVL noise, better
than a plain rotate-and-integrate of the DVL, learns the DVL noise, and its diagnostics show the
shares; the old defaults (a 0.002 m/s DVL) starve the filter and the diagnostics say so. Three
seeds here; docs/results/fusion_lowcost has 20 (benchmarks/study_fusion_lowcost.py)."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from auvgw.testing.fusion_lowcost import lowcost_scenario, run, truth_trajectory

SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def runs():
    scn = lowcost_scenario()
    truth = truth_trajectory(scn)
    return scn, [run(scn, truth, s) for s in SEEDS]


def _mean(rs, kind, field="rms_m"):
    return statistics.fmean(getattr(r[kind], field) for r in rs)


def test_default_settings_match_the_true_noise_and_beat_plain_integration(runs):
    _, rs = runs
    assert _mean(rs, "default") <= 1.1 * _mean(rs, "true")
    assert _mean(rs, "default") < _mean(rs, "plain")
    assert _mean(rs, "default", "final_m") < _mean(rs, "plain", "final_m")
    # the old defaults were worse than plain integration (the report)
    assert _mean(rs, "old") > _mean(rs, "plain")


def test_compass_deviation_is_estimated_and_removed(runs):
    """The AHRS's deviation is learned from its gyro (within 3 of the estimate's own sigma of
    the planted coefficients; the world model's heading and yaw rate disagree by up to 0.2 deg
    in turns, which biases D by about 2 sigma), applied, and the filter without it does worse."""
    scn, rs = runs
    noise = scn.devices.ins.noise
    keys = ("deviation_a1_deg", "deviation_b1_deg", "deviation_a2_deg", "deviation_b2_deg")
    planted = [noise[k] for k in keys]
    for r in rs:
        dev = r["deviation"]
        assert dev["detected"] and dev["applied"]
        got = list(dev["coefficients_deg"].values())
        sig = list(dev["sigma_deg"].values())
        assert all(abs(g - p) < 3 * e for g, p, e in zip(got, planted, sig, strict=True)), got
    assert _mean(rs, "default") < _mean(rs, "nodev")
    assert _mean(rs, "default", "final_m") < _mean(rs, "nodev", "final_m")


def test_adapted_dvl_noise_converges_to_the_truth(runs):
    scn, rs = runs
    true_sigma = scn.devices.dvl.noise["velocity_mps"]
    for r in rs:
        assert np.mean(r["adapted_sigma"]) == pytest.approx(true_sigma, rel=0.2)


def test_diagnostics_show_shares_and_warn_only_when_starved(runs):
    _, rs = runs
    for r in rs:
        d = r["diagnostics"]
        tot = d["total"]
        assert tot["fixes"] > 1400
        assert 0.95 < tot["accepted_share"] < 1.0 and 0.0 < tot["rejected_share"] < 0.05
        assert tot["coasting_share"] < 0.05
        assert d["warnings"] == []
        assert d["window"]["nis_consistent"] is True
        old = r["old_diagnostics"]
        assert old["total"]["rejected_share"] > 0.5 and old["total"]["coasting_share"] > 0.5
        assert any(w.startswith("dvl_rejections") for w in old["warnings"])


def test_rerun_shows_the_diagnostics_and_warns(runs, tmp_path):
    """The fusion status (as FusionStage.counters publishes it) through the Rerun stage: the
    shares, NIS and adapted noise as series, each new warning as one WARN event."""
    import json

    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.readback import health_metrics, read_recording
    from auvgw.viz.stage import VizStage

    _, rs = runs
    path = tmp_path / "diag.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    t0 = 1_763_800_000.0
    for i, diag in enumerate((rs[0]["diagnostics"], rs[0]["old_diagnostics"],
                              rs[1]["old_diagnostics"])):
        body = {"v": 1, "component": "fusion", "t_ns": 5, "stage": {"published": i},
                "diagnostics": diag}
        assert stage.handle_sample("auv/auv1/status/fusion", json.dumps(body).encode(),
                                   int((t0 + i) * 1e9)) == "logged"
    stage.stop()
    logger.close()
    rec = read_recording(path)
    rows = [m for _, m in health_metrics(rec, "fusion_diagnostics")]
    assert len(rows) == 3
    assert rows[0]["rejected_share"] < 0.1 and rows[1]["rejected_share"] > 0.5
    assert rows[0]["dvl_noise_x_mps"] == pytest.approx(rs[0]["adapted_sigma"][0])
    events = [e[0] for e in rec["health/fusion/events"].values("TextLog:text")]
    # the default run has no warning; the starved one warns once (not again while it lasts)
    assert len([e for e in events if "dvl_rejections" in e]) == 1


def test_device_emulators_play_the_lowcost_scenario(tmp_path):
    """The scenario's low-cost figures also drive the HN-100 and DVL emulators (auvgw sim /
    demo): compass deviation in the INS heading, spikes in the DVL's velocities."""
    import math

    from auvgw.testing.fusion_emulated import emulate

    scn = lowcost_scenario()
    data = scn.model_dump()
    data["devices"]["ins"]["options"] = {"serial": False, "can": False}
    data["devices"]["dvl"]["options"] = {"serial": False, "frame": "instrument"}
    data["duration_s"] = 400.0
    em = emulate(type(scn).model_validate(data), tmp_path)
    ins = scn.devices.ins.noise
    for t in (10.0, 150.0, 300.0):
        m = em.ins.measure(t)
        h = em.ctx.sampler.at(t).heading
        dev = math.radians(ins["deviation_a1_deg"] * math.sin(h) + ins["deviation_b1_deg"]
                           * math.cos(h) + ins["deviation_a2_deg"] * math.sin(2 * h))
        assert m.heading_error == pytest.approx(dev, abs=1e-9)
    pings = [em.dvl.measure(t) for t in np.arange(1.0, 400.0, 1 / 1.5)]
    speed = np.array([np.linalg.norm(p.velocity[:3]) for p in pings if p.lock])
    assert len(speed) > 500
    spikes = speed > 0.8  # 0.2 m/s + 0.17 m/s noise per axis: a spike beyond 0.8 is rare
    assert 0.005 < spikes.mean() < 0.05
