"""Hostile bus input into every stage (issue 27): property-based envelopes and raw payloads with
numbers at the edges of their types, wrong types, deep nesting, huge sizes and old versions,
interleaved with good traffic. Nothing raises, every hostile sample is counted, and the good
traffic's outputs are unchanged (compared with a run of the good traffic alone).

The stages are driven in-process through :meth:`Stage.handle_sample`, the path every bus payload
takes (the end-to-end form, a forged message sent to a running ``auvgw fusion``, is
``tests/commands/test_fusion_stage.py::test_forged_envelopes_mid_stream_change_no_odometry``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.bus import Keys, encode_envelope
from auvgw.stages.fusion import FusionStage
from auvgw.testing import REPO, hostile
from auvgw.testing.hostile import hostile_payloads

T0, T1 = 100.0, 104.0
KEYS = Keys("auv1")
@pytest.fixture(scope="module")
def fusion_traffic(tmp_path_factory):
    """(good (key, payload) samples of 4 s of the emulated survey's INS and DVL, settings)."""
    good, cfg = hostile.fusion_traffic(tmp_path_factory.mktemp("ports"), T1 - T0, T0)
    return [(k, p) for _, k, p in good], cfg


@pytest.fixture(scope="module")
def good_odometry(fusion_traffic):
    """The fusion's odometry over the good traffic alone (once: every example compares with it)."""
    good, cfg = fusion_traffic
    return _odometry(cfg, good)[0]


@pytest.fixture(scope="module")
def stage_traffic(fusion_traffic, good_odometry):
    """The good sensor traffic with the fusion's odometry envelopes merged in by time (what
    every downstream stage takes)."""
    good, _ = fusion_traffic
    odometry = good_odometry
    odo = [(round(o.t * 1e9), (KEYS.odometry(), encode_envelope(o, "fusion", round(o.t * 1e9),
                                                                  i + 1)[0]))
           for i, o in enumerate(odometry)]  # fmt: skip
    from auvgw.envelope import decode_envelope

    sensors = [(decode_envelope(p).t_recv_ns, (k, p)) for k, p in good]
    return [kp for _, kp in sorted(sensors + odo, key=lambda x: x[0])]


def _odometry(cfg, samples) -> tuple[list, FusionStage]:
    out: list = []
    stage = FusionStage(cfg, on_odometry=out.append)
    for key, payload in samples:
        stage.handle_sample(key, payload)
    stage.flush()
    return out, stage


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(bad=st.lists(hostile_payloads(), min_size=1, max_size=6), where=st.floats(0.05, 0.95),
       on_ins=st.booleans())  # fmt: skip
def test_fusion_outputs_do_not_change_under_hostile_envelopes(fusion_traffic, good_odometry, bad,
                                                              where, on_ins):  # fmt: skip
    good, cfg = fusion_traffic
    expected = good_odometry
    assert expected  # the good traffic gives odometry to compare with
    at = int(len(good) * where)
    key = KEYS.sensor("ins" if on_ins else "dvl", "ins" if on_ins else "ensemble")
    mixed = good[:at] + [(key, b) for b in bad] + good[at:]
    got, stage = _odometry(cfg, mixed)
    assert got == expected  # the good traffic's odometry, sample for sample
    c = stage.counters()
    refused = c["stage"]["bad_payloads"] + c["stage"]["bad_stamps"]
    # every hostile sample accounted for: refused and counted, or a well-formed message of no
    # use here (another device, an empty body) taken and set aside by the adapter
    taken = c["stage"]["received"] - len(good)
    assert refused + taken == len(bad)
    assert c["adapter"]["ins"] + c["adapter"]["dvl"] == len(good)


def _stage_factories(tmp_path: Path) -> dict:
    tmp_path.mkdir(parents=True, exist_ok=True)
    from auvgw.control.mission import MISSIONS_DIR, load_mission
    from auvgw.recording import McapRecorder
    from auvgw.stages.bathymetric import BathymetricStage, BathymetricStageConfig
    from auvgw.stages.magnetic import MagneticStage, config_from_scenario
    from auvgw.stages.pilot import PilotStage, PilotStageConfig
    from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig
    from auvgw.stages.slam import SlamStage, SlamStageConfig
    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.stage import VizStage

    return {
        "slam": lambda: SlamStage(SlamStageConfig(vehicle="auv1")),
        "bathymetric": lambda: BathymetricStage(BathymetricStageConfig(vehicle="auv1")),
        "magnetic": lambda: MagneticStage(config_from_scenario(
            REPO / "config" / "scenarios" / "beacons_amb.json", vehicle="auv1")),
        "ros2": lambda: Ros2Bridge(Ros2BridgeConfig(vehicle="auv1")),
        "pilot": lambda: PilotStage(load_mission(MISSIONS_DIR / "box.toml"),
                                    PilotStageConfig(vehicle="auv1")),
        "viz": lambda: VizStage(RerunLogger(rrd=tmp_path / "hostile.rrd"), "auv1"),
        "recorder": lambda: McapRecorder(tmp_path / "hostile.mcap", "auv1"),
    }


def _run(name: str, tmp_path: Path, samples: list[tuple[str, bytes]]) -> tuple[list, dict]:
    """(what the stage published, its last counters) over ``samples``."""
    out: list = []
    stage = _stage_factories(tmp_path)[name]()
    if hasattr(stage, "on_publish"):
        stage.on_publish = lambda key, payload, t_ns: out.append((key, bytes(payload), t_ns))
    try:
        for key, payload in samples:
            stage.handle_sample(key, payload)
    finally:
        if name == "viz":
            stage.stop()
            stage.logger.close()
        else:
            stage.stop(flush=True)
    return out, stage.counters()


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory, stage_traffic):
    """``clean_run(name)``: stage ``name``'s run over the good traffic alone (:func:`_run`), made
    once per stage: every example compares with it."""
    runs: dict[str, tuple[list, dict]] = {}

    def get(name: str) -> tuple[list, dict]:
        if name not in runs:
            runs[name] = _run(name, tmp_path_factory.mktemp(f"clean-{name}"), stage_traffic)
        return runs[name]

    return get


@pytest.mark.parametrize("name", ["slam", "bathymetric", "magnetic", "ros2", "viz", "pilot"])
@settings(max_examples=3, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(bad=st.lists(hostile_payloads(), min_size=40, max_size=40))
def test_downstream_stages_publish_the_same_under_hostile_payloads(name, tmp_path, stage_traffic,
                                                                   clean_run, bad):  # fmt: skip
    """Each downstream stage (SLAM pipelines, ROS 2 bridge, Rerun, autopilot) is fed the good
    sensor and odometry traffic with 40 hostile payloads in the middle, on sensor and odometry
    keys: nothing raises, what it publishes for the good traffic is what it publishes without
    them, and the good samples after them are taken as before. (The ROS 2 bridge also
    republishes a hostile payload that is a well-formed envelope, as a bridge does: its good
    outputs must all be there.)"""
    from collections import Counter

    good = stage_traffic
    keys = [KEYS.sensor("dvl", "ensemble"), KEYS.odometry(), KEYS.sensor("ins", "ins")]
    half = len(good) // 2
    mixed = good[:half] + [(keys[i % 3], b) for i, b in enumerate(bad)] + good[half:]
    run = len(list(tmp_path.iterdir()))
    clean_out, clean = clean_run(name)
    mixed_out, counted = _run(name, tmp_path / f"mixed{run}", mixed)
    if name == "ros2":
        lost = Counter(map(repr, clean_out)) - Counter(map(repr, mixed_out))
        assert not lost, list(lost)[:3]
    else:
        assert mixed_out == clean_out
    assert counted["stage"]["received"] >= clean["stage"]["received"]
    if name == "viz":  # the Rerun stage counts its own way: errors and unknown samples
        assert counted["stage"]["errors"] + sum(counted["stage"]["unknown"].values()) > 0
    else:  # refused and counted (a well-formed one of no use here is set aside, uncounted)
        assert 0 < counted["stage"]["bad_payloads"] + counted["stage"]["bad_stamps"] <= len(bad)


def test_the_recorder_keeps_every_good_sample_among_hostile_ones(tmp_path, fusion_traffic):
    """The recorder writes every good sample whatever is published around it (a hostile one is
    skipped and counted, never the file)."""
    from auvgw.recording import read_info

    good, _ = fusion_traffic
    name = "recorder"
    stage = _stage_factories(tmp_path)[name]()
    bad = [hostile_payloads().example() for _ in range(40)]
    keys = [KEYS.sensor("dvl", "ensemble"), KEYS.odometry(), KEYS.sensor("ins", "ins")]
    half = len(good) // 2
    try:
        if name == "recorder":
            for key, payload in good[:half] + [(keys[i % 3], b) for i, b in enumerate(bad)]:
                stage.add(key, payload, None)
            for key, payload in good[half:]:
                stage.add(key, payload, None)
        else:
            for key, payload in good[:half]:
                stage.handle_sample(key, payload)
            before = stage.counters()["stage"]["received"]
            for i, b in enumerate(bad):
                stage.handle_sample(keys[i % 3], b)
            for key, payload in good[half:]:
                stage.handle_sample(key, payload)
            after = stage.counters()["stage"]["received"]
            assert after > before  # good samples are still taken after the hostile ones
    finally:
        if name == "recorder":
            stage.close()
        elif name == "viz":
            stage.stop()
            stage.logger.close()
        else:
            stage.stop(flush=True)
    if name == "recorder":
        from auvgw.recording import read_info

        info = read_info(tmp_path / "hostile.mcap")
        assert sum(info.counts.values()) >= len(good)  # the good samples all written
