"""The Rerun bus stage: real codec messages in JSON envelopes -> the right entities in the .rrd."""

from __future__ import annotations

import json
import math
import threading
import time

import numpy as np
import pytest

from auvgw.bus import BusConfig, encode_envelope, open_session
from auvgw.cli import main
from auvgw.drivers import hn100, kongsberg, ms3a, pd0, seanet
from auvgw.fusion import Odometry
from auvgw.ground.procs import free_port
from auvgw.health import DeviceHealth
from auvgw.viz import entities as ent
from auvgw.viz.logger import RerunLogger
from auvgw.viz.readback import health_metrics, read_recording, read_views
from auvgw.viz.stage import VizStage, host_clock, open_viz

T_RECV = 1_763_800_000.0  # host receive time of the samples (s)
NS = 1e9
BASE = "auv/auv1"


def _env(msg, device: str, t: float = T_RECV, seq: int = 1, body=None) -> bytes:
    return encode_envelope(msg, device, int(t * NS), seq, body)[0]


def _xyz88(t: float) -> kongsberg.XYZ88:
    across = np.linspace(-40.0, 40.0, 9)
    depth = 10.0 + 0.1 * np.abs(across)
    depth[4] = np.nan  # no detection
    return kongsberg.make_xyz88(
        time=t, depth=depth, across=across, along=np.full(9, 0.5), heading=0.3,
        transducer_depth=20.0,
    )  # fmt: skip


def _hn100(time_s: float) -> object:
    return hn100.Hn100Nav(
        seq=7, status=hn100.CODEC.status_word(aligned=True, gnss_aided=False, dvl_aided=True,
                                              error=False),
        time=time_s, roll=0.1, pitch=-0.05, heading=1.0, rate_x=0.0, rate_y=0.0, rate_z=0.01,
        accel_x=0.0, accel_y=0.0, accel_z=-9.81, vel_n=1.0, vel_e=0.2, vel_d=0.0,
        latitude=0.7, longitude=0.1, depth=20.0,
    )  # fmt: skip


def _odometry(t: float, x: float, y: float, heading: float) -> Odometry:
    cov = np.diag([4.0, 1.0, 0.5, 0.01, 0.01, 0.1, 0.1, 0.1])
    return Odometry(
        t=t, x=x, y=y, z=20.0, roll=0.0, pitch=0.0, heading=heading,
        velocity_ned=(1.0, 0.0, 0.0), velocity_body=(1.0, 0.0, 0.0), angular_rate=(0.0, 0.0, 0.0),
        covariance=cov, bottom_lock=True, coasting=False, dvl_age_s=0.1, depth_age_s=0.1,
        ins_gap=False, increment=None,
    )  # fmt: skip


def _status(connected: bool, error: str = "") -> bytes:
    h = DeviceHealth("dvl", "pd0")
    h.set_connected(connected, error)
    return json.dumps(h.snapshot()).encode()


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """Every known message type through VizStage.handle_sample, then the .rrd read back."""
    path = tmp_path_factory.mktemp("stage") / "stage.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    bins = np.zeros(300, dtype=np.uint8)
    bins[100:110] = 250
    samples = [
        # navigation first, so the swath is placed at its pose
        (f"{BASE}/nav/odometry", _env(_odometry(1000.0, 10.0, 5.0, 0.5), "fusion")),
        (f"{BASE}/sensor/mbes/xyz88", _env(_xyz88(T_RECV - 0.2), "mbes")),
        (f"{BASE}/sensor/msis/headdata", _env(seanet.head_data(bins, math.radians(45)), "msis")),
        (f"{BASE}/sensor/ins/hn100nav", _env(_hn100(12.5), "ins", T_RECV + 0.01)),
        (f"{BASE}/sensor/ins/hn100nav", _env(_hn100(12.51), "ins", T_RECV + 0.03)),
        (f"{BASE}/sensor/mag/ms3asample",
         _env(ms3a.Ms3aSample(counter=5, bx=20000.0, by=-1000.0, bz=44000.0), "mag")),
        (f"{BASE}/sensor/msis/mtalive", _env(seanet.alive(12.0), "msis")),
        (f"{BASE}/sensor/foo/foo", _env(None, "foo", body={"type": "Foo", "x": 1})),
        (f"{BASE}/sensor/foo/bad", b"not json"),
        (f"{BASE}/sensor/foo/old", json.dumps({"v": 99, "type": "X", "msg": {}}).encode()),
        (f"{BASE}/status/dvl", _status(True)),
        (f"{BASE}/status/dvl", _status(False, "port unplugged")),
        (f"{BASE}/status/gateway", json.dumps({"vehicle": "auv1", "devices": {}}).encode()),
        (f"{BASE}/status/fusion", json.dumps({
            "v": 1, "component": "fusion", "t_ns": 5, "stage": {"published": 7, "dropped": 0},
            "filter": {"dvl_rejected": 2}, "ins_device": "ins"}).encode()),
        (f"{BASE}/truth/pose", json.dumps({"t": 3.0, "x": 1.0, "y": 2.0, "z": 20.0,
                                            "heading": 0.25}).encode()),
        (f"{BASE}/truth/world", json.dumps({
            "landmarks": [{"id": 4, "x": 30.0, "y": -5.0}, {"id": 9, "x": -20.0, "y": 12.0}],
            "lines": [{"rho": 50.0, "theta": 0.0}, {"rho": 30.0, "theta": math.pi / 2}]}).encode()),
        (f"{BASE}/slam/fastslam2/pose", json.dumps({
            "t": 3.0, "x": 1.5, "y": 2.5, "heading": 0.3,
            "cov": [[0.25, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.01]],
            "particles": [[1.0, 2.0, 0.3], [2.0, 3.0, 0.3], [1.5, 2.5, 0.3]],
            "weights": [0.2, 0.5, 0.3]}).encode()),
        (f"{BASE}/slam/fastslam2/landmarks", json.dumps({
            "t": 3.0, "mean": [[30.1, -5.2], [-19.8, 12.1]],
            "cov": [[[0.04, 0.0], [0.0, 0.09]], [[0.16, 0.0], [0.0, 0.01]]], "ids": [4, 9],
            "lines": {"rho": [50.2], "theta": [0.01], "cov": [[[0.04, 0.0], [0.0, 1e-4]]]},
        }).encode()),
    ]  # fmt: skip
    outcomes = [stage.handle_sample(k, p, int((T_RECV + 0.05) * NS)) for k, p in samples]
    typed = stage.on_message("mbes", int(T_RECV * NS), _xyz88(T_RECV + 0.8))
    stage.stop()
    logger.close()
    return outcomes, typed, stage, read_recording(path)


def test_outcomes_and_counters(mapped) -> None:
    outcomes, typed, stage, _ = mapped
    assert outcomes == [
        "logged", "logged", "logged", "logged", "logged", "logged", "ignored", "unknown",
        "error", "error", "logged", "logged", "ignored", "logged", "logged", "logged", "logged",
        "logged",
    ]  # fmt: skip
    assert typed == "logged"
    s = stage.stats
    assert (s.received, s.logged, s.ignored, s.errors) == (19, 14, 2, 2)
    assert s.unknown == {"sensor:Foo": 1}


def test_swath_is_placed_at_the_navigation_pose(mapped) -> None:
    *_, rec = mapped
    sw = rec[ent.SOUNDINGS]
    assert len(sw) == 2
    assert sw.times[0] == pytest.approx((T_RECV - 0.2) * NS, abs=1e6)  # device time (ms)
    pts = np.asarray(sw.values("Points3D:positions")[0])
    msg = _xyz88(0.0)
    valid = msg.beams.valid
    assert len(pts) == valid.sum() == 8
    along, across, depth = msg.xyz[valid].T
    h = 0.5  # odometry heading, position (10, 5), transducer 20 m deep
    assert pts[:, 0] == pytest.approx(10.0 + along * math.cos(h) - across * math.sin(h), abs=1e-4)
    assert pts[:, 1] == pytest.approx(5.0 + along * math.sin(h) + across * math.cos(h), abs=1e-4)
    assert pts[:, 2] == pytest.approx(20.0 + depth, abs=1e-4)


def test_ins_attitude_and_relative_clock(mapped) -> None:
    *_, rec = mapped
    att = rec[ent.INS_ATTITUDE]
    assert len(att) == 2
    assert att.values("Scalars:scalars")[0] == pytest.approx(
        [math.degrees(0.1), math.degrees(-0.05)], abs=1e-3
    )
    assert rec[ent.INS_HEADING].values("Scalars:scalars")[0] == pytest.approx(
        [math.degrees(1.0)], abs=1e-3
    )
    # time since power-up mapped onto the host clock by the least delayed sample
    assert att.times[0] == pytest.approx((T_RECV + 0.01) * NS, abs=1e4)
    assert att.times[1] - att.times[0] == pytest.approx(0.01 * NS, abs=1e4)
    assert len(rec[ent.VEHICLE]) == 1  # the transform at most at 20 Hz


def test_magnetometer_sonar_health(mapped) -> None:
    *_, rec = mapped
    assert rec[ent.MAG_FIELD].values("Scalars:scalars") == [[20000.0, -1000.0, 44000.0]]
    assert rec[ent.MAG_MAGNITUDE].values("Scalars:scalars")[0][0] == pytest.approx(
        math.sqrt(20000.0**2 + 1000.0**2 + 44000.0**2)
    )
    fan = rec[ent.SONAR_FAN]
    assert len(fan) == 1
    img = np.asarray(fan.values("SegmentationImage:buffer")[0][0], dtype=np.uint8).reshape(256, 256)
    c = 127.5
    r_px = 128 * 105 / 300  # bins 100..109 of 300 at 45 deg (up-right)
    row, col = (
        round(c - r_px * math.cos(math.radians(45))),
        round(c + r_px * math.sin(math.radians(45))),
    )
    assert img[row, col] == 250 and img.max() == 250
    rows = [m for _, m in health_metrics(rec, "dvl")]
    assert [r["connected"] for r in rows] == [1.0, 0.0]
    assert rows[0]["bad_frames"] == 0.0 and math.isnan(rows[0]["silent_s"])
    # a stage's counters: cumulative, so a table (text) and a series in no view, never a line
    fusion = rec["health/count/fusion"]
    assert fusion.static["SeriesLines:names"] == [
        "fusion stage.published",
        "fusion stage.dropped",
        "fusion filter.dvl_rejected",
    ]
    assert fusion.values("Scalars:scalars") == [[7.0, 0.0, 2.0]]
    table = rec[ent.HEALTH_COUNTERS].values("TextDocument:text")[-1][0]
    assert "| fusion | stage.published 7, stage.dropped 0, filter.dvl_rejected 2 |" in table
    events = rec["health/dvl/events"].values("TextLog:text")
    assert events == [["dvl connected"], ["dvl disconnected: port unplugged"]]


def test_trajectories_landmarks_lines(mapped) -> None:
    *_, rec = mapped
    dr = rec["map/dead_reckoning/pose"]
    assert dr.values("Points2D:positions")[0] == [pytest.approx([5.0, -10.0])]  # (east, -north)
    cov = np.asarray(rec["map/dead_reckoning/pose"].values("LineStrips2D:strips")[0][0])
    assert (cov[:, 1].max() - cov[:, 1].min()) / 2 == pytest.approx(2 * 2.0, rel=0.01)  # 2 sigma_x
    assert rec["map/truth/pose"].values("Points2D:positions")[0] == [pytest.approx([2.0, -1.0])]
    truth_lm = rec["map/truth/landmarks"]
    assert truth_lm.values("Points2D:labels")[0] == ["4", "9"]
    pos = np.asarray(truth_lm.values("Points2D:positions")[0])
    assert pos == pytest.approx(np.array([[-5.0, -30.0], [12.0, 20.0]]))
    assert len(rec["map/truth/lines"].values("LineStrips2D:strips")[0]) == 2
    slam = "map/slam/fastslam2"
    assert rec[f"{slam}/pose"].values("Points2D:positions")[0] == [pytest.approx([2.5, -1.5])]
    assert len(rec[f"{slam}/particles"].values("Points2D:positions")[0]) == 3
    assert rec[f"{slam}/landmarks"].values("Points2D:labels")[0] == ["4", "9"]
    ell = np.asarray(rec[f"{slam}/landmarks"].values("LineStrips2D:strips")[0][1])
    assert (ell[:, 1].max() - ell[:, 1].min()) / 2 == pytest.approx(2 * 0.4, rel=0.01)
    assert len(rec[f"{slam}/line_cov"]) == 1


def test_pd0_ensemble_to_dvl(tmp_path, shared_data) -> None:
    frames, _ = pd0.FORMAT.frames_of_file(shared_data / "pd0" / "RDI_withBT.000")
    ens = [pd0.FORMAT.decode(f.data)[0] for f in frames][507]  # bottom track valid here
    bt = ens.bottom_track
    assert np.all(np.isfinite(bt.velocity))
    path = tmp_path / "dvl.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    t_dev = ens.variable_leader.device_time_s  # 2017: received 50 ms later by a synced host
    assert stage.handle_sample(f"{BASE}/sensor/dvl/ensemble", _env(ens, "dvl", t_dev + 0.05)) == (
        "logged"
    )
    logger.close()
    rec = read_recording(path)
    v = rec[ent.DVL_VELOCITY]
    assert v.times[0] == pytest.approx(ens.variable_leader.device_time_s * NS, abs=1e3)
    assert v.values("Scalars:scalars")[0] == pytest.approx(list(-bt.velocity[:3]))
    assert v.static["SeriesLines:names"] == ["east m/s", "north m/s", "up m/s"]  # earth frame
    alt = rec[ent.DVL_ALTITUDE].values("Scalars:scalars")[0][0]
    assert alt == pytest.approx(float(np.mean(bt.range)))
    assert rec[ent.DVL_BOTTOM_LOCK].values("Scalars:scalars") == [[1.0]]


def test_device_clock() -> None:
    assert host_clock()(1.7e9, 1.7e9 + 0.3) == 1.7e9  # a UTC clock in sync: passes through
    other_epoch = host_clock()
    assert other_epoch(1.6e9, 1.7e9 + 0.3) == 1.7e9 + 0.3  # another epoch: mapped
    assert other_epoch(1.6e9 + 0.1, 1.7e9 + 0.5) == pytest.approx(1.7e9 + 0.4)
    c = host_clock(jump_s=1.0)
    assert c(None, 123.0) == 123.0  # no device time: host time
    assert c(10.0, 1000.3) == pytest.approx(1000.3)
    assert c(10.1, 1000.35) == pytest.approx(1000.35)  # less delayed: offset tightens
    assert c(10.2, 1000.9) == pytest.approx(1000.45)  # a late sample keeps the device spacing
    assert c(0.5, 1001.0) == pytest.approx(1001.0)  # device clock reset: re-anchored


@pytest.mark.e2e
def test_stage_over_zenoh(tmp_path) -> None:
    """A real Zenoh session: the stage's subscribers get the puts, the file gets the data."""
    path = tmp_path / "bus.rrd"
    session = open_session(BusConfig())
    try:
        runner = open_viz(session, "auv1", rrd=path)
        sample = ms3a.Ms3aSample(counter=1, bx=100.0, by=200.0, bz=300.0)
        deadline = time.monotonic() + 10.0
        n = 0
        while runner.stage.stats.logged < 5 and time.monotonic() < deadline:
            n += 1
            session.put(f"{BASE}/sensor/mag/ms3asample", _env(sample, "mag", T_RECV + n))
            session.put(f"{BASE}/raw/mag", b"$MS3A,...")  # raw frames are not subscribed
            time.sleep(0.02)
        runner.close()
    finally:
        session.close()
    assert runner.stage.stats.logged >= 5
    assert runner.stage.stats.unknown == {}
    rec = read_recording(path)
    assert len(rec[ent.MAG_FIELD]) == runner.stage.stats.logged
    assert rec[ent.MAG_FIELD].values("Scalars:scalars")[0] == [100.0, 200.0, 300.0]


@pytest.mark.e2e
def test_stage_queue_full_drops_with_a_counter(tmp_path) -> None:
    """The Zenoh callback never blocks: with the mapping thread not started, a 3-slot queue keeps
    3 samples and counts the rest as dropped."""
    logger = RerunLogger(rrd=tmp_path / "drop.rrd")
    stage = VizStage(logger, "auv1", queue_size=3)
    session = open_session(BusConfig())
    try:
        stage.attach(session, ["sensor"])
        sample = ms3a.Ms3aSample(counter=1, bx=1.0, by=2.0, bz=3.0)
        for i in range(20):
            session.put(f"{BASE}/sensor/mag/ms3asample", _env(sample, "mag", T_RECV + i))
        deadline = time.monotonic() + 10.0
        while stage.stats.dropped < 17 and time.monotonic() < deadline:
            time.sleep(0.01)
        stage.stop()  # maps the 3 queued samples
    finally:
        session.close()
        logger.close()
    assert (stage.stats.dropped, stage.stats.received, stage.stats.logged) == (17, 3, 3)
    assert len(read_recording(tmp_path / "drop.rrd")[ent.MAG_FIELD]) == 3


@pytest.mark.e2e
def test_cli_records_from_the_bus(tmp_path) -> None:
    path = tmp_path / "cli.rrd"
    port = free_port()
    code: list[int] = []
    args = ["viz", "--rrd", str(path), "--duration", "2.5", "--bus-listen", f"tcp/127.0.0.1:{port}"]
    cmd = threading.Thread(target=lambda: code.append(main(args)))
    cmd.start()
    time.sleep(0.3)
    pub = open_session(BusConfig(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        n = 0
        while cmd.is_alive():
            n += 1
            sample = ms3a.Ms3aSample(counter=n, bx=1.0 * n, by=0.0, bz=0.0)
            pub.put(f"{BASE}/sensor/mag/ms3asample", _env(sample, "mag", T_RECV + n))
            time.sleep(0.05)
    finally:
        pub.close()
    cmd.join()
    assert code == [0]
    field = read_recording(path)[ent.MAG_FIELD]
    assert len(field) >= 5
    bx = [v[0] for v in field.values("Scalars:scalars")]
    assert bx == sorted(bx) and all(b == int(b) for b in bx)


def test_cli_errors_and_blueprint(tmp_path, capsys) -> None:
    assert main(["viz"]) == 2
    assert "nothing to do" in capsys.readouterr().err
    assert main(["viz", "--connect", "http://127.0.0.1:9876"]) == 2
    assert "rerun+http://" in capsys.readouterr().err
    assert main(["viz", "--rrd", str(tmp_path / "no" / "x.rrd")]) == 2
    assert main(["viz", "--synthetic", "0"]) == 2
    assert main(["viz", "--rrd", str(tmp_path / "demo.rrd"), "--synthetic", "3"]) == 0
    demo = read_recording(tmp_path / "demo.rrd")
    assert len(demo[ent.INS_ATTITUDE]) == 300 and len(demo[ent.SONAR_FAN]) >= 3
    assert main(["viz", "--save-blueprint", str(tmp_path / "auvgw.rbl")]) == 0
    names = {name.split(" (")[0] for _, name, _ in read_views(tmp_path / "auvgw.rbl")}
    assert {"Map", "Sonar fan", "Swath & bathymetry", "Roll & pitch", "Heading"} <= names
    assert {"DVL velocity", "Altitude"} <= names


def test_device_health_is_on_the_data_clock(tmp_path) -> None:
    """At sim speed 2 the gateway's stamps run ahead of the host clock; its status carries its
    stamp clock (``t_stamp_ns``), and the health rows land there, next to the data."""
    path = tmp_path / "health.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    for k in range(3):
        h = DeviceHealth("dvl", "pd0")
        h.set_connected(True, "")
        snap = {**h.snapshot(), "t_stamp_ns": int((T_RECV + 20.0 * k) * NS)}
        host = int((T_RECV + 10.0 * k) * NS)  # arrival on the host clock: half as fast
        assert stage.handle_sample(f"{BASE}/status/dvl", json.dumps(snap).encode(), host)
    stage.stop()
    logger.close()
    rows = health_metrics(read_recording(path), "dvl")
    assert [t for t, _ in rows] == [int((T_RECV + 20.0 * k) * NS) for k in range(3)]


def test_device_health_panel_shows_age_lag_and_transport_losses(tmp_path) -> None:
    """The gateway's lag and loss numbers (``age_s``, ``lag_s``, ``transport_lost``) become
    series of the device's health, next to the framer's skipped bytes."""
    path = tmp_path / "lag.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    h = DeviceHealth("ins", "hn100")
    h.set_connected(True, "")
    h.seen(int(T_RECV * NS), "Hn100Nav", int(T_RECV * NS), 10.0)
    h.seen(int((T_RECV + 1) * NS), "Hn100Nav", int((T_RECV + 1) * NS), 10.25)  # 0.75 s late
    h.set_transport_losses({"adapter_data_overrun": 2, "adapter_rx_fifo_full": 1})
    snap = h.snapshot(int((T_RECV + 3) * NS))
    snap.update(t_stamp_ns=int((T_RECV + 3) * NS), skipped_bytes=37)
    assert stage.handle_sample(f"{BASE}/status/ins", json.dumps(snap).encode(), T_RECV + 3)
    stage.stop()
    logger.close()
    rec = read_recording(path)
    [(t, row)] = health_metrics(rec, "ins")
    assert t == int((T_RECV + 3) * NS)
    assert row["lag_s"] == pytest.approx(0.75) and row["age_s"] == pytest.approx(2.75)
    assert row["transport_lost"] == 3.0 and row["skipped_bytes"] == 37.0
    assert row["silent_s"] == pytest.approx(2.0)
    # one unit per view: age and silence (s), lag (s) apart; the losses also as events
    assert rec["health/age/ins"].static["SeriesLines:names"] == ["ins silent_s", "ins age_s"]
    assert rec["health/lag/ins"].static["SeriesLines:names"] == ["ins lag_s"]
    events = [e[0] for e in rec["health/ins/events"].values("TextLog:text")]
    assert "ins: skipped_bytes 37 (+37)" in events and "ins: transport_lost 3 (+3)" in events


def test_acoustic_fix_is_a_line_from_the_vehicle_to_the_beacon(tmp_path) -> None:
    """An acoustic reply (slant range, bearing from the bow, depression) is drawn from the
    navigation pose to where it places the beacon: horizontal range along heading + bearing."""
    from auvgw.drivers.acoustic import AcousticReply

    path = tmp_path / "acoustic.rrd"
    logger = RerunLogger(rrd=path)
    stage = VizStage(logger, "auv1")
    odo = _env(_odometry(1000.0, 10.0, 5.0, 0.5), "fusion")
    assert stage.handle_sample(f"{BASE}/nav/odometry", odo, int(T_RECV * NS)) == "logged"
    reply = AcousticReply(counter=1, range=25.0, bearing=0.3, depression=math.acos(0.8), beacon=1)
    assert stage.on_message("acoustic", int((T_RECV + 0.5) * NS), reply) == "logged"
    stage.stop()
    logger.close()
    strips = read_recording(path)["map/acoustic/ranges"].values("LineStrips2D:strips")
    (start, end), = (np.asarray(s) for s in strips[0])
    north, east = 10.0 + 20.0 * math.cos(0.8), 5.0 + 20.0 * math.sin(0.8)  # 25 m x 0.8
    assert start == pytest.approx([5.0, -10.0]) and end == pytest.approx([east, -north])
