"""The online magnetic stage, in process: fusion-like odometry, MS3A samples and acoustic replies
fed as the bus would give them; poses, beacon map and observations published."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.slam.magnetic.stream import stage_inputs
from auvgw.stages.magnetic import MagneticStage, config_from_scenario
from auvgw.subscribe import slam_output

SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "beacons_amb.json"


def test_stage_publishes_pose_map_and_observations_and_beats_dead_reckoning() -> None:
    inputs = stage_inputs(SCENARIO, 4800)  # 120 s, 600 m
    sim = inputs.prep.sim
    published: list[tuple[str, dict]] = []
    cfg = config_from_scenario(SCENARIO, x0=tuple(float(x) for x in sim.truth[0]))
    stage = MagneticStage(cfg, on_publish=lambda k, p, _t: published.append((k, slam_output(p))))
    inputs.feed(stage)
    # malformed bus payloads are counted, never raised
    stage.handle("auv1/sensor/ms3a/magnetometer", b"\x00not an envelope")
    assert stage.stats.bad_payloads == 1
    keys = {k.rsplit("/", 1)[-1] for k, _ in published}
    assert keys == {"pose", "landmarks", "observations"}
    assert all(k.startswith("auv/auv1/slam/magnetic/") for k, _ in published)
    obs = [b for k, b in published if k.endswith("/observations")]
    assert len(obs) > 20 and all(o["snr"] >= 5 and 3 <= o["z"][0] <= 25 for o in obs)
    assert {round(o["freq"], 1) for o in obs} <= {round(f, 1) for f in cfg.channels_hz}
    lms = [b for k, b in published if k.endswith("/landmarks")]
    assert len(lms[-1]["mean"]) >= 2 and len(lms[-1]["cov"]) == len(lms[-1]["mean"])
    poses = [b for k, b in published if k.endswith("/pose")]
    # the start is known exactly (P0 = 0); the covariance stays symmetric PSD and grows
    assert all(np.all(np.linalg.eigvalsh(np.array(p["cov"])) > -1e-9) for p in poses)
    assert np.all(np.linalg.eigvalsh(np.array(poses[-1]["cov"])) > 0)
    tr = np.asarray(sim.truth)
    t_tr = np.arange(len(tr)) * sim.dt
    p_arr = np.array([(p["t"], p["x"], p["y"]) for p in poses])
    err = np.hypot(p_arr[:, 1] - np.interp(p_arr[:, 0], t_tr, tr[:, 0]),
                   p_arr[:, 2] - np.interp(p_arr[:, 0], t_tr, tr[:, 1]))  # fmt: skip
    dra = inputs.dr
    err_dr = np.hypot(*(dra[:, :2] - tr[:, :2]).T)
    rmse, rmse_dr = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(err_dr**2)))
    print(f"stage RMSE {rmse:.2f} m, dead reckoning {rmse_dr:.2f} m")
    assert rmse < rmse_dr and rmse < 8.0  # measured 5.93 m against DR 18.5 m


@pytest.mark.e2e
def test_stage_process_on_the_bus_publishes_poses_and_observations(tmp_path: Path) -> None:
    """The stage as its own process (``auvgw slam run --pipeline magnetic``): odometry, MS3A and
    acoustic-reply envelopes published on the bus by this process (30 s of vehicle time at
    ~20x); a malformed payload is counted, the worker goes on, publishes poses and beacon
    observations, and ends closer to the truth than dead reckoning."""
    import sys
    import threading
    import time

    import zenoh

    from auvgw.bus import encode_envelope
    from auvgw.drivers.acoustic import AcousticReply
    from auvgw.drivers.ms3a import Ms3aSample
    from auvgw.testing import Proc, endpoint, free_port, wait_matched, wait_until

    inputs = stage_inputs(SCENARIO, 1200)  # 30 s, 150 m
    sim, dr = inputs.prep.sim, inputs.dr
    ep = endpoint(free_port())
    stage = Proc([sys.executable, "-m", "auvgw", "slam", "run", "--pipeline", "magnetic",
                  "--scenario", str(SCENARIO), "--listen", ep], tmp_path / "stage.log")  # fmt: skip
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    got: dict[str, list[dict]] = {"pose": [], "landmarks": [], "observations": [], "status": []}
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        what = str(sample.key_expr).rsplit("/", 1)[-1]
        with lock:
            got["status" if what == "slam-magnetic" else what].append(
                slam_output(sample.payload.to_bytes())
            )

    try:
        stage.wait_line("slam running", timeout=60)
        with zenoh.open(conf) as s:
            subs = [s.declare_subscriber("auv/auv1/slam/magnetic/*", on),
                    s.declare_subscriber("auv/auv1/status/slam-magnetic", on)]  # fmt: skip
            odo, mag = (
                s.declare_publisher("auv/auv1/nav/odometry"),
                s.declare_publisher("auv/auv1/sensor/ms3a/magnetometer"),
            )
            aco = s.declare_publisher("auv/auv1/sensor/acoustic/acousticreply")
            wait_until(lambda: got["status"], what="the stage's status")
            wait_matched(odo, mag, aco)  # samples put before its subscriptions reach us are lost
            mag.put(b"\x00not an envelope")
            k_mag = 0
            for k, (kind, args) in enumerate(inputs.events(t0=1000.0)):
                if kind == "odometry":
                    o = args[0]
                    odo.put(encode_envelope(o, "fusion", int(o.t * 1e9), k)[0])
                elif kind == "acoustic":
                    t_a, rng_m, brg, dep = args
                    ac = AcousticReply(counter=k % 1000, range=rng_m, bearing=brg,
                                       depression=dep, beacon=1)  # fmt: skip
                    aco.put(encode_envelope(ac, "acoustic", int(t_a * 1e9), k)[0])
                else:
                    t_m, b = args
                    bx, by, bz = (float(x) for x in b)
                    m = Ms3aSample(counter=k_mag % 1000, bx=bx, by=by, bz=bz)
                    mag.put(encode_envelope(m, "ms3a", int(t_m * 1e9), k)[0])
                    k_mag += 1
                if k % 60 == 0:  # pace at ~20x real time: the stage keeps up, nothing dropped
                    time.sleep(0.05)

            def done() -> bool:
                with lock:
                    st = got["status"][-1]["stage"] if got["status"] else {}
                return st.get("mag", 0) >= k_mag - 20 and st.get("bad_payloads") == 1

            wait_until(done, timeout=90, what="the stage to use every sample and count the bad one")
            wait_until(lambda: len(got["observations"]) >= 3, timeout=30, what="observations")
            for sub in subs:
                sub.undeclare()
    finally:
        stage.stop()
    with lock:
        obs, poses = list(got["observations"]), list(got["pose"])
    assert all(o["snr"] >= 5 and 3 <= o["z"][0] <= 25 and len(o["amp_nt"]) == 3 for o in obs)
    assert len(poses) > 20
    tr = np.asarray(sim.truth)
    last = poses[-1]
    k_last = min(round((last["t"] - 1000.0) / sim.dt), len(tr) - 1)
    err = math.hypot(last["x"] - tr[k_last, 0], last["y"] - tr[k_last, 1])
    err_dr = math.hypot(*(dr[k_last][:2] - tr[k_last, :2]))
    print(f"final error: stage {err:.2f} m, dead reckoning {err_dr:.2f} m")
    assert err < err_dr


def test_acoustic_fixes_that_come_before_the_odometry_are_held_not_lost() -> None:
    """Odometry reaches the stage after the fusion's hold-back, the acoustic replies straight
    from the gateway: the fixes that arrive first are held until the first odometry sample and
    then used; a fix older than that sample is counted, not applied."""
    inputs = stage_inputs(SCENARIO, 800)  # 20 s
    events = list(inputs.events())
    n_fix = sum(1 for kind, _ in events if kind == "acoustic")
    early = [e for e in events if e[0] == "acoustic" and e[1][0] < 8.0]
    late = [e for e in events if not (e[0] == "acoustic" and e[1][0] < 8.0)]
    odo = [e for e in late if e[0] == "odometry"]
    # the odometry lags: every fix of the first 8 s arrives before it; one stale fix from
    # before the vehicle clock's first odometry sample comes with them
    stale = ("acoustic", (-1.0, 20.0, 0.1, 0.0))
    cfg = config_from_scenario(SCENARIO, x0=tuple(float(x) for x in inputs.prep.sim.truth[0]))
    stage = MagneticStage(cfg)
    for kind, args in [stale, *early, *late]:
        getattr(stage, f"feed_{kind}")(*args)
    assert len(early) >= 5 and len(odo) > 100
    assert stage.stats.acoustic == n_fix and stage.stats.acoustic_before_odometry == 1
    in_order = MagneticStage(cfg)
    inputs.feed(in_order)
    assert in_order.stats.acoustic == n_fix and in_order.stats.acoustic_before_odometry == 0
    p_held, p_order = stage.online.pose()[0], in_order.online.pose()[0]
    assert np.allclose(p_held, p_order, atol=1e-6)  # the filter saw the same fixes in time order
