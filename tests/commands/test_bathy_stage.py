"""The online bathymetric stage: in process (odometry and XYZ 88 / Depth datagrams fed as the bus
gives them) and as its own process on the bus (``auvgw slam run --pipeline bathymetric``)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from auvgw.config.scenario import Scenario
from auvgw.drivers import kongsberg
from auvgw.fusion.odometry import Odometry
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import run_filter
from auvgw.slam.bathymetric.online import ned_offsets
from auvgw.slam.bathymetric.simulate import BathyRun, simulate_survey
from auvgw.stages.bathymetric import BathymetricStage, BathymetricStageConfig
from auvgw.subscribe import slam_output
from auvgw.testing.bathy_helpers import TINY

#: transducer depth of the emulated swaths (m): the stage must add it to the beam depths
DRAFT = 0.5
EPOCH = 1_780_000_000.0


def _odometry(t: float, x: float, y: float, heading: float) -> Odometry:
    return Odometry(
        t=t, x=x, y=y, z=DRAFT, roll=0.0, pitch=0.0, heading=heading,
        velocity_ned=(0.0, 0.0, 0.0), velocity_body=(0.0, 0.0, 0.0),
        angular_rate=(0.0, 0.0, 0.0), covariance=np.eye(8), bottom_lock=True, coasting=False,
        dvl_age_s=0.0, depth_age_s=0.0, ins_gap=False, increment=None,
    )  # fmt: skip


def ned_offsets_all(heading: np.ndarray, across: np.ndarray) -> np.ndarray:
    """(T, B, 2) NED offsets of soundings ``across`` (T, B) m to starboard."""
    return np.stack(
        [ned_offsets(float(h), a, np.zeros_like(a)) for h, a in zip(heading, across, strict=True)]
    )


def _swath(sim: BathyRun, k: int, kind: str = "xyz88", t: float | None = None) -> Any:
    """Ping ``k`` as the multibeam sends it: depths from the transducer, across / along in the
    vehicle frame; its clock reads ``EPOCH`` + ``t`` (default: the ping's time)."""
    h = float(sim.heading[k])
    across = sim.offsets[k] @ np.array([-math.sin(h), math.cos(h)])
    make = kongsberg.make_xyz88 if kind == "xyz88" else kongsberg.make_depth
    t_ping = float(sim.t[k]) if t is None else t
    return make(time=EPOCH + t_ping, depth=sim.depth[k] - DRAFT, across=across,
                along=np.zeros_like(across), heading=h % math.tau,
                transducer_depth=DRAFT, ping_counter=k)  # fmt: skip


@pytest.fixture(scope="module")
def tiny() -> BathyRun:
    return simulate_survey(Scenario.model_validate(TINY), np.random.default_rng(3))


def test_stage_reproduces_the_batch_filter_and_maps_the_true_terrain(tiny: BathyRun) -> None:
    sim = tiny
    n_b = sim.depth.shape[1]
    published: list[tuple[str, dict]] = []
    cfg = BathymetricStageConfig(n_particles=50, seed=9, n_beams=n_b, min_ping_spacing_m=0.0,
                                 map_period_pings=50)  # fmt: skip
    stage = BathymetricStage(cfg, on_publish=lambda k, p, _t: published.append((k, slam_output(p))))
    seen = []  # what the stage is given: the swaths as decoded (float32 on the wire)
    for k in range(len(sim.t)):
        t = float(sim.t[k])
        # odometry at 10 Hz (the DR interpolated), the swath arriving as soon as it is stamped
        if k:
            for s in np.arange(1, 10) / 10:
                xy = sim.dr[k - 1] + s * (sim.dr[k] - sim.dr[k - 1])
                stage.feed_odometry(_odometry(t - 1 + s, float(xy[0]), float(xy[1]),
                                              float(sim.heading[k - 1])))  # fmt: skip
        msg = _swath(sim, k)
        seen.append(msg)
        # received 0-0.6 s after its ping (a loaded sonar, emulator or host; issue 28): placed
        # at its own time, the batch filter's, not at its receive stamp (to within the
        # DeviceClock's skew allowance, 1e-4 s/s between the prompt ones: < 1 ms here)
        delay = 0.0 if k == len(sim.t) - 1 else 0.2 * (k % 4)
        stage.feed("mb", int((t + delay) * 1e9), msg)
        stage.feed_odometry(_odometry(t, float(sim.dr[k, 0]), float(sim.dr[k, 1]),
                                      float(sim.heading[k])))  # fmt: skip
    stage.feed("ins", 0, object())  # not a swath: ignored
    stage.flush()
    st = stage.stats
    assert st.pings == st.swaths == len(sim.t) and st.bad_swaths == 0 and st.before_odometry == 0
    assert st.ping_timed == len(sim.t)
    assert st.stamp_delay_max_s == pytest.approx(0.6, abs=1e-3)
    assert 0.25 < st.stamp_delay_mean_s < 0.35
    # the same filter, ping by ping, as the batch run over the same (decoded) soundings
    depth = np.array([m.beams.depth + DRAFT for m in seen], float)
    across = np.array([m.beams.across for m in seen], float)
    offsets = ned_offsets_all(sim.heading, across)
    same = dataclasses.replace(sim, depth=depth, offsets=offsets)
    batch, _ = run_filter("mtm-pf", same, BathyConfig(n_particles=50), np.random.default_rng(9))
    np.testing.assert_allclose(stage.online.filter.trajectory(), batch.final, atol=2e-3)
    poses = [b for k, b in published if k.endswith("/pose")]
    assert all(k.startswith("auv/auv1/slam/bathymetric/") for k, _ in published)
    assert len(poses) == len(sim.t)
    assert len(stage.online.filter.loops) > 0  # the crossing closed a loop online
    np.testing.assert_allclose([p["dr"] for p in poses], sim.dr, atol=2e-3)
    np.testing.assert_allclose(stage.ping_times, sim.t, atol=1e-3)
    final = np.array([poses[-1]["x"], poses[-1]["y"]])
    assert np.hypot(*(final - sim.truth[-1])) < 1.5 * np.hypot(*(sim.dr[-1] - sim.truth[-1])) + 2
    # maps: every 50 pings, and the whole map at flush; the transducer depth was added back
    maps = [b for k, b in published if k.endswith("/map")]
    clouds = [b for k, b in published if k.endswith("/cloud")]
    assert len(maps) == len(sim.t) // 50 + 1 and len(clouds) == len(maps)
    last = maps[-1]
    grid = np.array([[np.nan if v is None else v for v in row] for row in last["depth"]])
    i, j = np.nonzero(np.isfinite(grid))
    x = last["x0"] + (i + 0.5) * last["cell_m"]
    y = last["y0"] + (j + 0.5) * last["cell_m"]
    world = World.from_scenario(Scenario.model_validate(TINY))
    err = np.abs(grid[i, j] - world.depth(x, y))
    assert len(err) > 1000 and np.median(err) < 0.5 and np.mean(err < 2.0) > 0.95
    pts = np.array(clouds[-1]["points"])
    assert pts.shape[1] == 3
    assert np.median(np.abs(pts[:, 2] - world.depth(pts[:, 0], pts[:, 1]))) < 0.5
    c = stage.counters()
    loops = stage.online.filter.loops
    assert c["pings"] == len(sim.t)
    assert c["loops_accepted"] + c["loops_rejected"] == len(loops) >= 1
    assert last["loops"] == [c["loops_accepted"], c["loops_rejected"]]
    # the smoothed trajectory, once, at flush before the whole map: the batch filter's final
    # (corrected) trajectory at the swaths' times, and the time of each accepted closure
    tracks = [(i, b) for i, (k, b) in enumerate(published) if k.endswith("/track")]
    assert len(tracks) == 1 and published[tracks[0][0] + 1][0].endswith("/map")
    track = tracks[0][1]
    np.testing.assert_allclose(track["t"], sim.t, atol=1e-3)
    np.testing.assert_allclose(np.column_stack([track["x"], track["y"]]), batch.final, atol=3e-3)
    closures_t = [float(sim.t[lp.t_end]) for lp in loops if lp.accepted]
    assert track["closures_t"] == pytest.approx(closures_t, abs=1e-3)
    assert track["loops"] == last["loops"]


def test_stage_places_swaths_at_the_odometry_and_spaces_pings(tiny: BathyRun) -> None:
    """A swath waits for odometry covering its time; one older than the odometry history is
    dropped (counted); swaths closer than ``min_ping_spacing_m`` are skipped; a swath with no
    valid sounding is counted, not raised."""
    sim = tiny
    cfg = BathymetricStageConfig(n_particles=10, n_beams=sim.depth.shape[1],
                                 min_ping_spacing_m=5.0, odometry_window_s=5.0)  # fmt: skip
    stage = BathymetricStage(cfg)
    stage.feed_odometry(_odometry(100.0, 0.0, 0.0, 0.0))
    stage.feed_swath(99.0, _swath(sim, 0, t=99.0))  # older than the odometry history
    assert stage.stats.before_odometry == 1
    stage.feed_swath(100.9, _swath(sim, 1, t=100.5))  # pinged at 100.5: waits for odometry
    assert stage.stats.pings == 0
    stage.feed_odometry(_odometry(101.0, 2.0, 0.0, 0.0))
    # placed at its ping time (interpolated), not at its receive stamp (x = 1.8 m)
    assert stage.stats.pings == 1 and stage.track[-1][:2] == pytest.approx((100.5, 1.0), abs=2e-3)
    for k in range(2, 12):  # 1 m apart: every 5th one is used
        stage.feed_swath(100.5 + k + 0.1 * k, _swath(sim, k, t=100.5 + k))
        stage.feed_odometry(_odometry(101.0 + k, 2.0 + k, 0.0, 0.0))
    assert stage.stats.pings == 3 and stage.stats.spacing_skipped == 8
    # placed at x 1.0, 6.5 and 11.5 m
    assert stage.ping_times == pytest.approx([100.5, 105.5, 110.5], abs=2e-3)
    empty = kongsberg.make_xyz88(time=EPOCH + 113.0, depth=np.full(5, np.nan),
                                 across=np.zeros(5), along=np.zeros(5))  # fmt: skip
    stage.feed_swath(113.0, empty)
    stage.feed_odometry(_odometry(114.0, 30.0, 0.0, 0.0))
    assert stage.stats.bad_swaths == 1 and stage.stats.pings == 3
    # a Depth ('D') datagram: the transducer depth (with its offset multiplier) added back
    d = _swath(sim, 20, "depth", t=115.0)
    assert d.n_beams == sim.depth.shape[1]
    stage.feed("mb", int(115e9), d)
    stage.feed_odometry(_odometry(116.0, 40.0, 0.0, 0.0))
    assert stage.stats.pings == 4
    # (resampled onto an even across-track grid: the cm-rounded positions move it by < 1 cm)
    np.testing.assert_allclose(stage.online.map_points(1)[:, 2], d.beams.depth + DRAFT, atol=0.01)
    # malformed bus payloads are counted, never raised
    stage.handle("auv/auv1/sensor/mb/xyz88", b"\x00not an envelope")
    stage.handle("auv/auv1/sensor/mb/xyz88", b"[]")
    assert stage.stats.bad_payloads == 2


@pytest.mark.e2e
def test_stage_process_on_the_bus(tmp_path: Path, tiny: BathyRun) -> None:
    """``auvgw slam run --pipeline bathymetric`` as its own process: odometry and XYZ 88
    envelopes published on the bus by this process; a malformed payload is counted, the worker
    goes on and publishes poses, maps and clouds, and its status counts every ping."""
    import zenoh

    from auvgw.bus import encode_envelope
    from auvgw.testing import Proc, endpoint, free_port, wait_matched, wait_until

    sim = tiny
    n = 200
    ep = endpoint(free_port())
    stage = Proc([sys.executable, "-m", "auvgw", "slam", "run", "--pipeline", "bathymetric",
                  "--particles", "30", "--set", "min_ping_spacing_m=0", "--set",
                  f"n_beams={sim.depth.shape[1]}", "--set", "map_period_pings=50",
                  "--listen", ep], tmp_path / "stage.log")  # fmt: skip
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    got: dict[str, list[dict]] = {"pose": [], "map": [], "cloud": [], "status": []}
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        what = str(sample.key_expr).rsplit("/", 1)[-1]
        with lock:
            got["status" if what == "slam-bathymetric" else what].append(
                slam_output(sample.payload.to_bytes())
            )

    try:
        stage.wait_line("slam running", timeout=60)
        with zenoh.open(conf) as s:
            subs = [s.declare_subscriber("auv/auv1/slam/bathymetric/*", on),
                    s.declare_subscriber("auv/auv1/status/slam-bathymetric", on)]  # fmt: skip
            # BLOCK: a loaded machine must slow this publisher down, not drop its samples
            block = zenoh.CongestionControl.BLOCK
            odo = s.declare_publisher("auv/auv1/nav/odometry", congestion_control=block)
            mb = s.declare_publisher("auv/auv1/sensor/mb/xyz88", congestion_control=block)
            wait_until(lambda: got["status"], what="the stage's status")
            # its status reaching us does not mean its subscriptions have: samples put before
            # would be routed nowhere (under load the first 23 odometry samples were lost so)
            wait_matched(odo, mb)
            mb.put(b"{not json")
            for k in range(n):
                t = float(sim.t[k])
                payload, _ = encode_envelope(_swath(sim, k), "mb", int(t * 1e9), k)
                mb.put(payload)
                o = _odometry(t, float(sim.dr[k, 0]), float(sim.dr[k, 1]), float(sim.heading[k]))
                payload, _ = encode_envelope(o, "fusion", int(t * 1e9), k)
                odo.put(payload)
            wait_until(lambda: len(got["pose"]) >= n, timeout=120, what="every pose")
            stage.stop()
            wait_until(lambda: got["status"][-1]["stage"]["pings"] == n, timeout=30,
                       what="the final status")  # fmt: skip
            for sub in subs:
                sub.undeclare()
    finally:
        stage.stop()
    st = got["status"][-1]["stage"]
    assert st["bad_payloads"] == 1 and st["swaths"] == n and st["odometry"] == n
    poses = got["pose"]
    np.testing.assert_allclose([[p["t"], *p["dr"]] for p in poses],
                               np.column_stack([sim.t[:n], sim.dr[:n]]), atol=1e-6)  # fmt: skip
    assert len(got["map"]) >= n // 50 and len(got["cloud"]) >= n // 50
    world = World.from_scenario(Scenario.model_validate(TINY))
    pts = np.array(got["cloud"][-1]["points"])
    assert np.median(np.abs(pts[:, 2] - world.depth(pts[:, 0], pts[:, 1]))) < 0.5


def test_stage_output_in_rerun(tmp_path: Path, tiny: BathyRun) -> None:
    """The stage's pose, DEM tiles and clouds through the Rerun stage, read back from the .rrd:
    the corrected trajectory, depth-coloured seabed points at the published positions and the
    DEM discs."""
    from auvgw.viz import entities as ent
    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.readback import read_recording
    from auvgw.viz.stage import VizStage

    sim = tiny
    path = tmp_path / "bathy.rrd"
    logger = RerunLogger(rrd=path)
    viz = VizStage(logger, "auv1")
    outcomes: list[str] = []
    published: list[tuple[str, dict]] = []

    def on_publish(key: str, payload: bytes, t_ns: int) -> None:
        published.append((key, slam_output(payload)))
        outcomes.append(viz.handle_sample(key, payload, t_ns))

    cfg = BathymetricStageConfig(n_particles=20, n_beams=sim.depth.shape[1],
                                 min_ping_spacing_m=0.0, map_period_pings=40)  # fmt: skip
    stage = BathymetricStage(cfg, on_publish=on_publish)
    for k in range(120):
        t = EPOCH + float(sim.t[k])
        stage.feed("mb", int(t * 1e9), _swath(sim, k))
        stage.feed_odometry(_odometry(t, float(sim.dr[k, 0]), float(sim.dr[k, 1]),
                                      float(sim.heading[k])))  # fmt: skip
    stage.flush()
    logger.close()
    # every output drawn but the smoothed track (one at flush), which the viz stage leaves alone
    drawn = [o for o, (k, _) in zip(outcomes, published, strict=True) if not k.endswith("/track")]
    assert drawn and set(drawn) == {"logged"} and len(drawn) == len(outcomes) - 1
    rec = read_recording(path)
    track = rec[ent.world_path("slam/bathymetric", "track")]
    assert len(track) >= 1
    seabed = rec[ent.world_path("slam/bathymetric", "seabed")]
    rows = [v for v in seabed.values("Points3D:positions") if v is not None]
    pts = np.concatenate([np.asarray(v, float).reshape(-1, 3) for v in rows])
    sent = np.concatenate([np.array(b["points"]) for k, b in published if k.endswith("/cloud")])
    assert len(pts) == len(sent) > 0
    np.testing.assert_allclose(np.sort(pts[:, 2]), np.sort(sent[:, 2]), atol=1e-3)
    dem = rec[ent.map_path("slam/bathymetric", "dem")]
    assert len(dem) == 3 + 1  # 120 / 40 tiles and the whole map at flush


def test_slam_run_bathymetric_over_a_recording(tmp_path: Path, capsys) -> None:
    """``auvgw slam run --pipeline bathymetric --recording F``: a recording as ``auvgw record``
    writes it (INS, DVL and multibeam raw frames of 60 s of the emulated survey + the truth)
    gives the poses of the same stages fed in-process, and its report puts both paths against
    the recorded truth."""
    from auvgw.cli import main as cli_main
    from auvgw.sim_devices.multibeam import MultibeamEmulator
    from auvgw.testing.fusion_emulated import (
        HOST_EPOCH,
        dvl_stream,
        emulate,
        feed_through_fusion,
        fusion_settings,
        ins_dvl_frames,
        ins_output,
        survey_scenario,
        write_recording,
    )

    rec_s = 60.0
    em = emulate(survey_scenario(rec_s + 1.0), tmp_path)
    ins = ins_output(em, 0.0, rec_s)
    dvl = dvl_stream(em, 0.0, rec_s)
    raw = ins_dvl_frames(ins, dvl)
    mb = MultibeamEmulator(em.ctx)
    for t in np.arange(0.0, rec_s, 0.2):
        m = mb.ping(float(t))
        raw.append((HOST_EPOCH + t + 0.01, "mb", kongsberg.encode(m), m))
    raw.sort(key=lambda r: r[0])
    rec_path = write_recording(tmp_path / "run.mcap", "s1",
                               {"ins": "hn100", "dvl": "pd0", "mb": "kongsberg"}, raw, em.truth)
    settings, fcfg = fusion_settings(tmp_path / "fusion.json", "s1", em, ins, dvl)
    out = tmp_path / "bathy.jsonl"
    rc = cli_main(["slam", "run", "--pipeline", "bathymetric", "--recording", str(rec_path),
                   "--fusion-settings", str(settings), "--particles", "20",
                   "--out", str(out)])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    poses = [p for p in lines if "dr" in p]
    assert len(poses) >= 40 and any("depth" in p for p in lines)  # ~100 m at 2 m spacing

    # the same stages fed in-process, message by message
    got: list[dict] = []
    stage = BathymetricStage(BathymetricStageConfig(n_particles=20),
                             on_publish=lambda k, p, _t: got.append(slam_output(p)) if
                             k.endswith("/pose") else None)  # fmt: skip
    feed_through_fusion(fcfg, stage, raw)
    assert got == poses
    err = {ln.split(" vs truth")[0].strip(): float(ln.split("RMSE ")[1].split(" m")[0])
           for ln in text.splitlines() if " vs truth" in ln}  # fmt: skip
    assert set(err) == {"dead reckoning", "mtm-pf"}, text
    assert err["dead reckoning"] < 2.0 and err["mtm-pf"] < 5.0, text


def test_stage_keeps_drift_estimate_off_unless_asked() -> None:
    """Online the world-frame drift model (eq. 28) is off by default (a vehicle's INS + DVL
    error turns with each leg) while the offline default is on; ``filter`` turns it on."""
    assert BathyConfig().drift_estimate
    assert not BathymetricStageConfig().bathy_config().drift_estimate
    on = BathymetricStageConfig(filter={"drift_estimate": True, "radius_m": 12.0})
    assert on.bathy_config().drift_estimate and on.bathy_config().radius_m == 12.0
