"""The online SLAM stage: odometry + emulated MSIS scan lines of the harbour in, pose and map out.

The odometry is built from the simulated truth with a heading bias (dead reckoning drifts, as
an INS with a gyro bias would); the pings come from the MSIS emulator (SeaNet bytes decoded as
the gateway decodes them) and arrive *before* the odometry that covers them, as online."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
import zenoh

from auvgw.bus import BusConfig, Keys, encode_envelope, open_session
from auvgw.drivers import seanet as sn
from auvgw.fusion.odometry import MotionIncrement
from auvgw.sim_devices.msis import MsisHead, make_echo
from auvgw.slam.features import PoseTrack
from auvgw.stages.slam import SlamStage, SlamStageConfig, compose_increments
from auvgw.subscribe import slam_output
from auvgw.testing import slam_harbour, wait_until
from auvgw.testing.slam_harbour import DURATION_S, ODO_DT, run_events

#: the emulated harbour run (a module-scoped fixture)
harbour_run = slam_harbour.harbour_run


def piles_through_odometry(world, track, dr, t_odo, t: float) -> np.ndarray:
    """Where the drifted odometry puts the true piles when it looks at them at time ``t``
    (a map made then, without revisits, can be no better): ``dr(t) + R(dr_h - true_h)
    (pile - true(t))``."""
    tp = track(np.array([t]))[0]
    i = min(int(np.searchsorted(t_odo, t)), len(t_odo) - 1)
    dh = dr[i, 2] - tp[2]
    c, s = math.cos(dh), math.sin(dh)
    rel = world.points - tp[:2]
    return dr[i, :2] + np.stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]], 1)


def test_stage_maps_the_piles_and_publishes_a_steady_pose(harbour_run):
    world, track, dr, t_odo, stage, published, _, _ = harbour_run
    c = stage.counters()["stage"]
    assert stage.msis_device == "msis"
    assert c["pings"] > 1000 and c["pings_before_odometry"] <= 1
    assert c["point_features"] >= 4 and c["updates"] >= 3 and c["line_features"] >= 5
    # steady publication: every 0.5 s of odometry time, pose and landmarks
    poses = [(b, t) for k, b, t in published if k == "auv/auv1/slam/vb-aufastslam/pose"]
    maps = [b for k, b, _ in published if k == "auv/auv1/slam/vb-aufastslam/landmarks"]
    assert len(poses) == len(maps) == c["published"]
    ts = np.array([b["t"] for b, _ in poses])
    assert np.all(np.diff(ts[:-1]) == pytest.approx(0.5, abs=ODO_DT + 1e-9))
    assert len(ts) >= DURATION_S / 0.5 - 2
    last = poses[-1][0]
    assert np.array(last["cov"]).shape == (3, 3)
    assert len(last["particles"]) == len(last["weights"]) == 30
    # landmarks: the point features mapped near the true piles as the drifting odometry saw
    # them when each landmark was first published (the drift is 0.05 deg/s: up to 9 m late in
    # the run, so the raw pile positions only bound the early ones)
    lm = np.array(maps[-1]["mean"])
    assert len(lm) >= 3
    first = {}
    for b in maps:
        for i in b["ids"]:
            first.setdefault(i, b["t"])
    d = np.array([np.min(np.hypot(*(piles_through_odometry(world, track, dr, t_odo,
                                                           first[i]) - p).T))
                  for i, p in zip(maps[-1]["ids"], lm, strict=True)])  # fmt: skip
    assert np.median(d) < 1.5, d
    assert np.sum(d < 2.0) >= 3, d
    # the first landmark, mapped while the drift was small, is near a true pile itself
    early = min(range(len(lm)), key=lambda k: first[maps[-1]["ids"][k]])
    assert np.min(np.hypot(*(world.points - lm[early]).T)) < 2.0
    # lines in the map frame, near true walls in direction
    ls = maps[-1]["lines"]  # a LineSet: one column per field, a row per observed wall
    n = len(ls["rho"])
    assert n and all(len(ls[k]) == n for k in ("theta", "p0", "p1", "cov"))


def test_slam_pose_follows_the_vehicle_no_worse_than_the_odometry(harbour_run):
    """One pass (no feature revisited after long): SLAM can only hold the drift, not undo it;
    it must follow the vehicle (a broken prediction or update is metres off at once) and not
    be worse than the odometry it is given."""
    _, track, dr, t_odo, stage, *_ = harbour_run
    tr = np.array(stage.track)
    truth = track(tr[:, 0])
    slam_err = np.hypot(tr[:, 1] - truth[:, 0], tr[:, 2] - truth[:, 1])
    dr_at = np.stack([np.interp(tr[:, 0], t_odo, dr[:, i]) for i in (0, 1)], 1)
    dr_err = np.hypot(dr_at[:, 0] - truth[:, 0], dr_at[:, 1] - truth[:, 1])
    assert dr_err[-1] > 4.0  # the heading bias made the odometry drift
    assert np.sqrt(np.mean(slam_err**2)) <= 1.05 * np.sqrt(np.mean(dr_err**2))
    assert np.max(np.abs(slam_err - dr_err)) < 2.0


@pytest.mark.e2e
def test_posted_and_bus_inputs_run_on_the_worker_like_direct_feeding(harbour_run):
    """``post``/``post_odometry`` (the demo) and the bus subscriptions (a real Zenoh session)
    go through the stage's worker thread: the same poses as feeding on the caller's thread."""
    *_, events, cfg = harbour_run
    events = [e for e in events if (e[1].t if e[0] == "odometry" else e[2] / 1e9) < 40.0]
    direct, _ = run_events(cfg, events)
    session = open_session(BusConfig())
    got: list[dict] = []
    try:
        posted = SlamStage(cfg, session=session)
        posted.start(subscribe=False)
        for e in events:
            posted.post_odometry(e[1]) if e[0] == "odometry" else posted.post(*e[1:])
        posted.stop(flush=True)
        assert posted.track == direct.track and len(direct.track) >= 79

        keys = Keys(cfg.vehicle)
        sub = session.declare_subscriber(
            keys.slam("vb-aufastslam", "pose"),
            lambda s: got.append(slam_output(s.payload.to_bytes())),
        )
        bus = SlamStage(cfg.model_copy(update={"msis_device": "msis"}), session=session)
        bus.start()
        pub = {k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
               for k in (keys.odometry(), keys.sensor("msis", "mtheaddata"),
                         keys.sensor("other-head", "mtheaddata"))}  # fmt: skip
        for seq, e in enumerate(events):
            if e[0] == "odometry":
                payload, _ = encode_envelope(e[1], "fusion", int(e[1].t * 1e9), seq)
                pub[keys.odometry()].put(payload)
            else:
                payload, _ = encode_envelope(e[3], e[1], e[2], seq)
                pub[keys.sensor(e[1], "mtheaddata")].put(payload)
        # a busy machine slows the worker down: wait while it makes progress
        n_odometry, last, deadline = sum(e[0] == "odometry" for e in events), -1, 0.0
        while bus.stats.odometry < n_odometry:
            if bus.stats.odometry > last:
                last, deadline = bus.stats.odometry, time.monotonic() + 30.0
            assert time.monotonic() < deadline, bus.counters()
            time.sleep(0.05)
        bus.stop(flush=True)
        # the last pose (put by the flush) reaches the callback on Zenoh's own thread
        wait_until(lambda: len(got) >= len(bus.track), 30.0, what="the flushed pose")
        sub.undeclare()
    finally:
        session.close()
    c = bus.counters()["stage"]
    assert c["bad_payloads"] == 0 and c["queue_dropped"] == 0
    assert c["pings"] == direct.stats.pings and c["received"] == direct.stats.received
    assert [p["t"] for p in got] == [t for t, *_ in bus.track]
    # arrival order across the two subscriptions may differ from the direct feed by a few
    # samples; the estimate does not
    final = np.array(bus.track[-1][1:3])
    assert np.hypot(*(final - np.array(direct.track[-1][1:3]))) < 0.5


def test_compose_increments_is_the_sequential_motion():
    a = MotionIncrement(t0=0.0, t1=1.0, dx=1.0, dy=0.0, dz=0.0, dheading=math.pi / 2,
                        covariance=np.eye(3), dt=1.0, v_forward=1.0, v_starboard=0.0,
                        yaw_rate=math.pi / 2)  # fmt: skip
    dx, dy, dh, dt = compose_increments([a, a])
    # forward 1 m, turn right 90 deg, forward 1 m (now starboard), turn again
    assert (dx, dy, dh, dt) == pytest.approx((1.0, 1.0, math.pi, 2.0))


def test_config_rejects_unknown_algorithm():
    with pytest.raises(ValueError, match="unknown algorithm"):
        SlamStageConfig(algorithm="nope")
    with pytest.raises(ValueError, match="association"):
        SlamStageConfig(association="known")
    assert SlamStageConfig().display_name == "VB-AUFastSLAM"


# -- offline over a recording: auvgw slam-run ----------------------------------------------------

REC_S = 60.0


def test_slam_run_over_a_recording_is_the_in_process_stage(tmp_path, capsys):
    """A recording as ``auvgw record`` writes it (INS, DVL and MSIS raw frames of the emulated
    harbour + the truth): ``auvgw slam-run`` gives the poses of the stages fed in-process."""
    from auvgw.cli import main as cli_main
    from auvgw.testing.fusion_emulated import (
        HOST_EPOCH,
        dvl_stream,
        emulate,
        feed_through_fusion,
        fusion_settings,
        harbour_ins_dvl,
        ins_dvl_frames,
        ins_output,
        write_recording,
    )

    scn = harbour_ins_dvl(REC_S + 1.0)
    em = emulate(scn, tmp_path)
    ins = ins_output(em, 0.0, REC_S)
    dvl = dvl_stream(em, 0.0, REC_S)
    raw = ins_dvl_frames(ins, dvl)
    # the MSIS head, polled every ping, at the true pose
    world = em.ctx.world
    track = PoseTrack(em.truth.t, em.truth.poses)
    cmd = sn.head_command(range_m=50.0, n_bins=400, sound_speed=world.sound_speed)
    head = MsisHead(sound_speed=world.sound_speed, config_delay_s=0.0)
    head.power_up(0.0)
    head.feed(sn.encode(cmd), 0.0)
    head.tick(0.0)
    ping_t = np.arange(0.0, REC_S, head.ping_duration_s() + 0.005)
    ping_pose = track(ping_t)
    now = [0]
    head.echo = make_echo(world, lambda: tuple(ping_pose[now[0]]), np.random.default_rng(5))
    poll = sn.encode(sn.send_data(0))
    for i, t in enumerate(ping_t):
        now[0] = i
        data_i = head.feed(poll, float(t))
        raw.append((HOST_EPOCH + t + 0.01, "msis", data_i, sn.decode(data_i)[0]))
    raw.sort(key=lambda r: r[0])

    rec_path = write_recording(tmp_path / "run.mcap", "s1",
                               {"ins": "hn100", "dvl": "pd0", "msis": "seanet"}, raw, em.truth)
    settings, fcfg = fusion_settings(tmp_path / "fusion.json", "s1", em, ins, dvl)
    out = tmp_path / "slam.jsonl"
    rc = cli_main(["slam-run", "--recording", str(rec_path), "--fusion-settings", str(settings),
                   "--sound-speed", str(world.sound_speed), "--out", str(out)])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    poses, last_map = lines[:-1], lines[-1]
    assert "mean" in last_map and all("heading" in p for p in poses)
    assert len(poses) >= REC_S / 0.5 - 4

    # the same stages fed in-process, message by message
    got: list[dict] = []
    slam = SlamStage(SlamStageConfig(sound_speed_mps=world.sound_speed),
                     on_publish=lambda k, p, _t: got.append(slam_output(p)) if k.endswith("/pose")
                     else None)  # fmt: skip
    feed_through_fusion(fcfg, slam, raw)
    assert got == poses
    assert slam.counters()["stage"]["pings"] == len(ping_t)
    # the report: counters and both paths against the recorded truth (decimetres here)
    assert f"{len(ping_t)} scan lines of msis" in text
    err = {ln.split(" vs truth")[0].strip(): float(ln.split("RMSE ")[1].split(" m")[0])
           for ln in text.splitlines() if " vs truth" in ln}  # fmt: skip
    assert set(err) == {"dead reckoning", "SLAM"}
    assert err["dead reckoning"] < 0.5 and err["SLAM"] < 1.0, text
