"""Generic fusion inputs: named sources chosen the same whatever the arrival order, PD6 and
PD0-compass adapters, beam / earth DVL frames, position fixes, heading offset and declination.

The two-INS check uses 10 s of the emulated survey (tests/support/fusion_emulated.py): the HN-100
binary frames as device ``ins`` and a second INS ``ins_b`` (the same frames with the heading
turned by 3 deg, so choosing it would change the odometry), fed to the in-process stage in two
arrival orders - each INS's frames first in turn - as a live run and a replay would see them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from auvgw.drivers import pd6
from auvgw.fusion import DvlMount, FusionConfig, NavFilter, run_filter
from auvgw.fusion.adapters import MessageAdapter, dvl_from_pd6
from auvgw.fusion.frames import beam_matrix, body_to_ned
from auvgw.fusion.samples import DvlSample, InsSample, PositionFix
from auvgw.stages.fusion import FusionStage, FusionStageConfig
from auvgw.testing.fusion_emulated import (
    decode_serial,
    dvl_stream,
    emulate,
    filter_config,
    ins_output,
    survey_scenario,
)

T0, T1 = 100.0, 110.0


@pytest.fixture(scope="module")
def two_ins(tmp_path_factory):
    em = emulate(survey_scenario(T1 + 1.0), tmp_path_factory.mktemp("ports"))
    ins = ins_output(em, T0, T1)
    dvl = dvl_stream(em, T0, T1)
    a = decode_serial(ins.serial, "hn100", "ins")
    b = [(t, "ins_b", dataclasses.replace(m, heading=m.heading + math.radians(3.0)))
         for t, _, m in a]
    d = decode_serial(dvl, "pd0", "dvl")
    lat = {"ins": ins.serial.frame_latency_s, "ins_b": ins.serial.frame_latency_s,
           "dvl": dvl.frame_latency_s}
    return a, b, d, lat, filter_config(em, T0)


def _run(msgs, cfg):
    out = []
    stage = FusionStage(cfg, on_odometry=out.append)
    for t, dev, m in msgs:
        stage.feed(dev, round(t * 1e9), m)
    stage.flush()
    return out, stage


def test_two_ins_devices_any_arrival_order_same_source_identical_odometry(two_ins):
    a, b, d, lat, filt = two_ins
    cfg = FusionStageConfig(vehicle="v", latency_s=lat, filter=filt)  # attitude "ins"
    # order 1: ins_b's frame of each tick arrives first; order 2: ins's first
    first_b = sorted(b + a + d, key=lambda m: m[0])
    first_a = sorted(a + b + d, key=lambda m: m[0])
    assert first_b[0][1] == "ins_b" and first_a[0][1] == "ins"
    o1, s1 = _run(first_b, cfg)
    o2, s2 = _run(first_a, cfg)
    assert len(o1) == len(o2) > 900
    assert o1 == o2  # field for field
    assert s1.adapter.ins_device == s2.adapter.ins_device == "ins"
    assert s1.adapter.stats.ignored == s2.adapter.stats.ignored == len(b)
    # not vacuous: the other INS as the named source gives other odometry
    cfg_b = cfg.model_copy(update={"ins_device": "ins_b"})
    o3, _ = _run(first_a, cfg_b)
    assert len(o3) == len(o1)
    assert abs(o3[-1].heading - o1[-1].heading) == pytest.approx(math.radians(3.0), abs=1e-3)
    assert math.hypot(o3[-1].x - o1[-1].x, o3[-1].y - o1[-1].y) > 0.2


def test_settings_name_sources_as_attitude_and_velocity(tmp_path):
    from auvgw.stages.fusion import load_stage_config

    p = tmp_path / "f.toml"
    p.write_text('[fusion]\nattitude = "ahrs"\nvelocity = "dvl2"\n')
    cfg = load_stage_config(p)
    assert (cfg.ins_device, cfg.dvl_device) == ("ahrs", "dvl2")


def _bi(x, y, z, status="A"):
    return pd6.decode(pd6.encode(pd6.BottomInstrumentVelocity(x=x, y=y, z=z, error=0.0,
                                                               status=status)))


def test_pd6_velocities_and_compass_feed_the_filter():
    bi = _bi(0.123, -0.045, 0.01)
    s = dvl_from_pd6(bi, 5.0)
    assert s.frame == "instrument" and s.bottom_lock
    assert s.velocity == pytest.approx((0.123, -0.045, 0.01))
    bad = dvl_from_pd6(_bi(0.1, 0.0, 0.0, status="V"), 5.0)
    assert not bad.bottom_lock and all(math.isnan(c) for c in bad.velocity)
    be = pd6.decode(pd6.encode(pd6.BottomEarthVelocity(east=0.2, north=1.0, up=-0.1, status="A")))
    e = dvl_from_pd6(be, 6.0)
    assert e.frame == "earth" and e.velocity == pytest.approx((1.0, 0.2, 0.1))
    bs = pd6.decode(pd6.encode(pd6.BottomShipVelocity(transverse=0.1, longitudinal=1.5,
                                                      normal=0.05, status="A")))
    assert dvl_from_pd6(bs, 7.0).velocity == pytest.approx((1.5, 0.1, -0.05))
    # one device as attitude AND velocity source: its :SA and :BI both feed the filter
    sa = pd6.decode(pd6.encode(pd6.SystemAttitude(pitch=0.01, roll=-0.02, heading=1.0)))
    a = MessageAdapter(ins_device="dvl", dvl_device="dvl", latency_s={"dvl": 0.01})
    att = a.adapt_all("dvl", 10.0, sa)
    vel = a.adapt_all("dvl", 10.2, bi)
    assert isinstance(att[0], InsSample) and att[0].heading == pytest.approx(1.0, abs=1e-4)
    assert att[0].t == pytest.approx(9.99) and isinstance(vel[0], DvlSample)
    assert vel[0].t == pytest.approx(10.19)
    assert a.adapt_all("ins", 10.0, sa) == [] and a.stats.ignored == 1


def _line(frame, n=200, heading=0.7, speed=1.2, beam_angle_deg=30.0):
    """A straight line at ``heading`` with DVL fixes in ``frame`` (noise-free)."""
    t = np.arange(n) * 0.1
    ins = [InsSample(float(x), 0.0, 0.0, heading) for x in t]
    v_body = np.array([speed, 0.0, 0.0])
    if frame == "earth":
        v = body_to_ned(v_body, 0.0, 0.0, heading)
    elif frame == "beam":
        v = beam_matrix(math.radians(beam_angle_deg)) @ v_body
    else:
        v = v_body
    dvl = [DvlSample(float(x) + 0.05, tuple(v.tolist()), frame=frame) for x in t[:-1]]
    return ins, dvl, t


@pytest.mark.parametrize("frame", ["body", "earth", "beam", "beam3"])
def test_beam_and_earth_frames_give_the_body_velocity(frame):
    ins, dvl, t = _line(frame.removesuffix("3"))
    if frame == "beam3":  # beam 2 bad in every fix: the 3-beam solution; a 3-tuple: no lock
        dvl = [d._replace(velocity=(d.velocity[0], math.nan, *d.velocity[2:])) for d in dvl]
        bad = run_filter(ins[:50], [DvlSample(1.0, (0.1, 0.2, 0.3), frame="beam")])
        assert not bad[-1].bottom_lock
    out = run_filter(ins, dvl, FusionConfig(max_latency_s=0.0))
    last = out[-1]
    assert last.velocity_body == pytest.approx((1.2, 0.0, 0.0), abs=1e-3)
    assert last.x == pytest.approx(1.2 * math.cos(0.7) * t[-1], abs=0.05)


def test_heading_offset_declination_and_scale_factor():
    ins, dvl, _ = _line("body")
    dvl = [d._replace(velocity=tuple(1.02 * c for c in d.velocity)) for d in dvl]
    cfg = FusionConfig(heading_offset_deg=2.0, magnetic_declination_deg=-5.0,
                       dvl=DvlMount(scale_factor=1.02))
    last = run_filter(ins, dvl, cfg)[-1]
    assert last.heading == pytest.approx(0.7 + math.radians(-3.0), abs=1e-9)
    assert last.velocity_body[0] == pytest.approx(1.2, abs=1e-3)


def test_position_fix_pulls_the_estimate_and_outliers_are_gated():
    from auvgw.fusion import InitialState

    ins, dvl, _ = _line("body")
    start = InitialState(position_m=(10.0, 3.0, 0.0), position_sigma_m=(20.0, 20.0, 1.0))
    nav = NavFilter(FusionConfig(max_latency_s=0.0, initial=start))
    truth_n = 1.2 * math.cos(0.7) * 12.0  # the vehicle started at (0, 0)
    truth_e = 1.2 * math.sin(0.7) * 12.0
    for d in dvl:
        nav.push(d)
    nav.push(PositionFix(12.0, truth_n, truth_e, sigma_m=0.5, source="gnss"))
    nav.push(PositionFix(13.0, 500.0, 3.0, sigma_m=0.5, source="usbl"))  # an outlier
    out = [o for s in ins for o in nav.push(s)] + nav.flush()
    assert nav.stats.position_updates == 1 and nav.stats.position_rejected == 1
    at = {round(o.t, 3): o for o in out}
    assert math.hypot(at[11.9].x - truth_n - 10.0, at[11.9].y - truth_e - 3.0) < 0.2
    assert math.hypot(at[12.0].x - truth_n, at[12.0].y - truth_e) < 0.6
    assert at[12.0].cov_xy.trace() < 0.6 < at[11.9].cov_xy.trace()


def test_replay_of_a_two_ins_recording_chooses_the_same_source(two_ins, tmp_path, capsys):
    """The same traffic recorded (``auvgw record``'s MCAP: raw frames, receive-time
    attachments, the gateway configuration with both INS) and run by ``auvgw fusion
    --recording``: the named INS, and odometry identical to the live (in-process) run."""
    import json

    from auvgw.bus import Keys, pack_raw_attachment
    from auvgw.cli import main as cli_main
    from auvgw.drivers import hn100, pd0
    from auvgw.drivers.spec import from_jsonable
    from auvgw.recording import McapRecorder

    a, b, d, lat, filt = two_ins
    live = sorted(b + a + d, key=lambda m: m[0])  # ins_b first at every tick
    cfg = FusionStageConfig(vehicle="rec2", latency_s=lat, filter=filt)
    expected, _ = _run(live, cfg)
    def serial(d: str) -> dict:
        return {"kind": "serial", "url": f"/dev/recorded-{d}"}  # one port each, never opened

    rec = McapRecorder(tmp_path / "two.mcap", "rec2")
    rec.set_gateway_config(json.dumps({"vehicle": "rec2", "devices": {
        "ins_b": {"format": "hn100", "transport": serial("ins_b")},
        "ins": {"format": "hn100", "transport": serial("ins")},
        "dvl": {"format": "pd0", "transport": serial("dvl")}}}))  # fmt: skip
    keys = Keys("rec2")
    offsets = {"ins": 0, "ins_b": 0, "dvl": 0}
    for seq, (t, dev, m) in enumerate(live):
        raw = pd0.encode(m) if dev == "dvl" else hn100.CODEC.encode(m)
        rec.add(keys.raw(dev), raw, pack_raw_attachment(round(t * 1e9), seq, offsets[dev]),
                "application/octet-stream")
        offsets[dev] += len(raw)
    rec.close()
    settings = tmp_path / "fusion.json"
    settings.write_text(cfg.model_dump_json())
    out = tmp_path / "odo.jsonl"
    assert cli_main(["fusion", "--recording", str(tmp_path / "two.mcap"), "--settings",
                     str(settings), "--out", str(out)]) == 0
    got = [from_jsonable(json.loads(x)) for x in out.read_text().splitlines()]
    assert got == expected and len(got) > 900
    assert '"ins_device": "ins"' in capsys.readouterr().err


def test_diagnostics_warn_on_rejections_and_on_a_minute_of_inconsistent_nis():
    from auvgw.fusion.diagnostics import FixRecord, FusionDiagnostics

    d = FusionDiagnostics(window_s=60.0)
    ok = (0.5, -0.5, 1.0)
    for i in range(60):  # a minute of fixes with NIS 3 per 3 dof: consistent
        d.add_fix(FixRecord(float(i), True, False, 3.0, 3, ok))
    s = d.summary()
    assert s["warnings"] == [] and s["window"]["nis_consistent"] is True
    assert s["window"]["nis_mean_per_dof"] == pytest.approx(1.0)
    # NIS 10 times too large, but not yet for a whole window after the start: no warning
    d2 = FusionDiagnostics(window_s=60.0)
    for i in range(30):
        d2.add_fix(FixRecord(float(i), True, False, 30.0, 3, ok))
    assert d2.summary()["window"]["nis_consistent"] is False and d2.summary()["warnings"] == []
    for i in range(30, 62):
        d2.add_fix(FixRecord(float(i), True, False, 30.0, 3, ok))
    assert [w.split(":")[0] for w in d2.summary()["warnings"]] == ["nis_inconsistent"]
    assert d2.summary()["window"]["nis_side"] == "high"
    # NIS 20 times too small for a minute: a conservative filter, a note and not a warning
    d4 = FusionDiagnostics(window_s=60.0)
    for i in range(62):
        d4.add_fix(FixRecord(float(i), True, False, 0.15, 3, ok))
    s4 = d4.summary()
    assert s4["warnings"] == [] and s4["window"]["nis_side"] == "low"
    assert [w.split(":")[0] for w in s4["notes"]] == ["nis_conservative"]
    # rejections: a third is tolerated, more is not
    d3 = FusionDiagnostics(window_s=60.0)
    for i in range(30):
        d3.add_fix(FixRecord(float(i), i % 3 != 0, False, 3.0, 3, ok))
    assert d3.summary()["warnings"] == []
    d3.add_fix(FixRecord(30.0, False, False, 50.0, 3, ok))
    w = d3.summary()["warnings"]
    assert len(w) == 1 and w[0].startswith("dvl_rejections: 11 of 31")
    # the window forgets: 61 s later only the new fixes count
    d3.add_fix(FixRecord(91.5, True, False, 3.0, 3, ok))
    assert d3.summary()["window"]["fixes"] == 1 and d3.summary()["total"]["fixes"] == 32
