"""The pilot stage (auvgw.stages.pilot) in-process and as ``auvgw pilot`` on a real Zenoh bus,
flying the 6-DOF model in lock-step over the bus; ``auvgw pilot --check``."""

from __future__ import annotations

import json
import math
import threading

import numpy as np
import pytest

from auvgw.control.autopilot import ActuatorCommand, ActuatorFeedback, Autopilot, AutopilotConfig
from auvgw.control.closed_loop import trimmed_start
from auvgw.control.mission import Mission, Waypoint
from auvgw.fusion.odometry import Odometry
from auvgw.sim_devices import dynamics as dyn
from auvgw.stages.pilot import PilotStage, PilotStageConfig, nav_fix
from auvgw.testing import AUVGW, REPO

MISSION_TOML = """[mission]
name = "hook"
speed = 1.5
depth = 3.0
acceptance_radius = 4.0
[[waypoints]]
north = 0.0
east = 0.0
[[waypoints]]
north = 25.0
east = 0.0
[[waypoints]]
north = 25.0
east = 60.0
"""
MISSION = Mission((Waypoint(0, 0, 3, 1.5), Waypoint(25, 0, 3, 1.5), Waypoint(25, 60, 3, 1.5)),
                  4.0, "hook")  # fmt: skip
DT = 0.05


def odometry(t: float, x: np.ndarray) -> Odometry:
    """The fusion's message for a dynamics state (truth navigation)."""
    u, v, w, p, q, r = (float(a) for a in x[:6])
    return Odometry(t=t, x=float(x[6]), y=float(x[7]), z=float(x[8]), roll=float(x[9]),
                    pitch=float(x[10]), heading=float(x[11]), velocity_ned=(0.0, 0.0, 0.0),
                    velocity_body=(u, v, w), angular_rate=(p, q, r), covariance=np.eye(8),
                    bottom_lock=True, coasting=False, dvl_age_s=0.0, depth_age_s=0.0,
                    ins_gap=False, increment=None)  # fmt: skip


def step(params: dyn.VehicleParams, x: np.ndarray, cmd: ActuatorCommand) -> np.ndarray:
    return dyn.step(params, x, np.array([cmd.rudder, cmd.stern, cmd.rpm]), DT)


def test_in_process_the_stage_commands_what_the_autopilot_does_and_publishes_its_state():
    params = dyn.load_params()
    sent: list[ActuatorCommand] = []
    published: list[tuple[str, dict]] = []
    stage = PilotStage(MISSION, PilotStageConfig(control_period_s=0.1), sink=sent.append,
                       on_publish=lambda k, b, t: published.append((k, json.loads(b))))  # fmt: skip
    twin = Autopilot(MISSION, AutopilotConfig(feedback_timeout_s=0.5))
    x = trimmed_start(MISSION)
    cmd = ActuatorCommand(0.0, 0.0, 0.0, 0.0)
    for k in range(400):  # 20 s, odometry at 20 Hz, control at 10 Hz
        t = k * DT
        fb = ActuatorFeedback(t, cmd.rpm, cmd.rudder, cmd.stern)
        stage.feed_actuators(fb)
        stage.feed_odometry(odometry(t, x))
        if k % 2 == 0:
            twin.feedback(fb)
            twin.nav(nav_fix(odometry(t, x)))
            assert sent[-1] == twin.step(t)
        cmd = sent[-1]
        x = step(params, x, cmd)
    assert len(sent) == 200 and stage.stats.steps == 200 and stage.stats.feedback == 400
    keys = {k for k, _ in published}
    assert keys == {"auv/auv1/pilot/command", "auv/auv1/pilot/state"}
    states = [b for k, b in published if k.endswith("/state")]
    assert states[-1]["mode"] == "running" and states[-1]["leg"] == 1
    assert abs(states[-1]["depth_d"] - 3.0) < 1e-9 and states[-1]["speed_d"] == 1.5
    assert abs(states[-1]["cross_track"]) < 5.0
    c = stage.counters()
    assert (c["mode"], c["leg"], c["n_legs"], c["mission"]) == ("running", 1, 2, "hook")


@pytest.mark.e2e
def test_auvgw_pilot_flies_the_model_over_the_bus_then_surfaces_when_navigation_stops(procs,
                                                                                     tmp_path):
    """``auvgw pilot`` in its own process; this one runs the dynamics, publishes the odometry
    and applies each command before the next step (lock-step, 40 s of vehicle time). When the
    odometry stops, the stage's timer steps on and it aborts (nav_lost) and surfaces."""
    import zenoh

    from auvgw.bus import encode_envelope
    from auvgw.testing import endpoint, free_port, wait_matched, wait_until

    mission = tmp_path / "hook.toml"
    mission.write_text(MISSION_TOML)
    ep = endpoint(free_port())
    proc = procs.start([AUVGW, "pilot", "--mission", str(mission), "--listen", ep,
                        "--nav-timeout", "2"], "pilot")  # fmt: skip
    proc.wait_line("pilot running", timeout=60)
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    cond = threading.Condition()
    got: dict[str, list[dict]] = {"command": [], "state": [], "pilot": []}

    def on(sample: zenoh.Sample) -> None:
        with cond:
            what = str(sample.key_expr).rsplit("/", 1)[-1]
            got[what].append(json.loads(sample.payload.to_bytes()))
            cond.notify_all()

    params = dyn.load_params()
    x = trimmed_start(MISSION)
    with zenoh.open(conf) as s:
        subs = [s.declare_subscriber("auv/auv1/pilot/*", on),
                s.declare_subscriber("auv/auv1/status/pilot", on)]  # fmt: skip
        odo = s.declare_publisher("auv/auv1/nav/odometry")
        wait_until(lambda: got["pilot"], what="the pilot's status")
        wait_matched(odo)
        track = []
        for k in range(800):
            t = 100.0 + k * DT
            odo.put(encode_envelope(odometry(t, x), "fusion", int(t * 1e9), k)[0])
            with cond:
                ok = cond.wait_for(lambda t=t: got["command"] and got["command"][-1]["t"] >= t,
                                   timeout=30)  # fmt: skip
                assert ok, f"no command for the odometry at t = {t}"
                c = got["command"][-1]
            x = step(params, x, ActuatorCommand(c["t"], c["rpm"], c["rudder"], c["stern"]))
            track.append(x)
        # the odometry stops: the timer steps the autopilot on and it aborts within nav_timeout
        wait_until(lambda: got["state"][-1]["mode"] == "aborted", timeout=30, what="the abort")
        for sub in subs:
            sub.undeclare()
    proc.signal()
    assert proc.wait(60) == 0  # once 30 s was not enough beside two burners (s42): stacks if not
    with cond:
        states, commands = list(got["state"]), list(got["command"])
    running = [st for st in states if st["mode"] == "running"]
    assert {st["leg"] for st in running} == {0, 1}
    last = running[-1]
    assert last["leg"] == 1 and abs(last["cross_track"]) < 2.0
    xs = np.array(track)
    assert abs(xs[-1, 8] - 3.0) < 0.3  # depth held
    assert abs(xs[-1, 11] - math.pi / 2) < math.radians(10)  # heading east on leg 1
    end = states[-1]
    assert end["abort_reason"] == "nav_lost" and "limit 2 s" in end["abort_detail"]
    assert end["t"] - (100.0 + 799 * DT) <= 3.0  # vehicle time: 2 s timeout + the timer's step
    assert commands[-1]["rpm"] == 0.0 and commands[-1]["stern"] < 0
    counters = json.loads(proc.stderr().split("pilot counters: ", 1)[1].splitlines()[0])
    assert counters["stage"]["received"] == 800 and counters["abort_reason"] == "nav_lost"
    assert counters["stage"]["timer_steps"] >= 1


def test_pilot_check_prints_one_line_per_problem_and_exits_2(tmp_path, capsys):
    from auvgw.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text("[mission]\nspeed = 1.0\ndepth = 200.0\n[lawnmower]\nleg_length = 100.0\n"
                   "spacing = 20.0\nlegs = 0\n")  # fmt: skip
    assert main(["pilot", "--mission", str(bad), "--check"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        f"auvgw pilot: error: {bad}: mission: mission.depth: 200 out of range (>= 0 and <= 100)",
        f"auvgw pilot: error: {bad}: mission: lawnmower.legs: must be an integer 1..1000, got 0",
        f"auvgw pilot: error: {bad}: mission: lawnmower.depth: missing (and no default in "
        "[mission])",
    ]
    good = REPO / "config" / "missions" / "lawnmower.toml"
    assert main(["pilot", "--mission", str(good), "--check"]) == 0
    assert capsys.readouterr() == (f"{good}: ok (7 legs, 2090 m, 8 waypoints)\n", "")
    assert main(["pilot", "--mission", str(good), "--period", "0"]) == 2
    assert capsys.readouterr().err == "auvgw pilot: error: --period must be > 0, got 0.0\n"


def test_rerun_shows_the_pilot_state_commands_and_the_abort(tmp_path):
    """The stage's publications through the Rerun stage (``auvgw viz``) and the .rrd read back:
    set-points and cross-track as series, commands in degrees, one event per change of mode."""
    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.readback import read_recording
    from auvgw.viz.stage import SECTIONS, VizStage

    assert "pilot" in SECTIONS
    published: list[tuple[str, bytes, int]] = []
    stage = PilotStage(MISSION, PilotStageConfig(nav_timeout_s=0.5, feedback_timeout_s=0.0),
                       on_publish=lambda k, b, t: published.append((k, b, t)))  # fmt: skip
    x = trimmed_start(MISSION)
    x[7] = 2.0  # 2 m to starboard of leg 0
    for k in range(5):
        stage.feed_odometry(odometry(10.0 + k * DT, x))
    x[8] = 61.0  # beyond max_depth
    stage.feed_odometry(odometry(11.0, x))
    path = tmp_path / "pilot.rrd"
    logger = RerunLogger(rrd=path)
    viz = VizStage(logger, "auv1")
    for key, payload, t_ns in published:
        assert viz.handle_sample(key, payload, t_ns) == "logged", key
    viz.stop()
    logger.close()
    rec = read_recording(path)

    def rows(path: str) -> list[dict[str, float]]:
        e = rec[path]
        names = list(e.static["SeriesLines:names"])
        return [dict(zip(names, v, strict=True)) for v in e.values("Scalars:scalars")]

    track = rows("pilot/track")
    assert len(track) == 6 and track[0]["cross_track_m"] == 2.0 and track[0]["depth_d_m"] == 3.0
    times = [round((10.0 + k * DT) * 1e9) for k in range(5)] + [11e9]
    assert list(rec["pilot/track"].times) == times
    assert rows("pilot/shaft")[-1]["rpm"] == 0.0
    assert rows("pilot/fins")[-1]["stern_deg"] == pytest.approx(-15.0)
    assert rec["health/pilot-state/events"].values("TextLog:text") == [
        ["mode running"], ["mode aborted: depth_limit (depth 61.0 m beyond 60 m)"]]


def test_against_a_lockstep_sim_the_timer_counts_vehicle_time_and_odometry_is_answered(tmp_path):
    import time

    from auvgw.ground.simclock import ClockFileWriter

    clock = ClockFileWriter(tmp_path / "clock")
    epoch = 1_000.0
    published: list[tuple[str, dict]] = []
    stage = PilotStage(MISSION, PilotStageConfig(nav_timeout_s=2.0, feedback_timeout_s=0.0,
                                                 lockstep_clock=str(tmp_path / "clock")),
                       on_publish=lambda k, b, t: published.append((k, json.loads(b))))  # fmt: skip
    x = trimmed_start(MISSION)
    clock.publish(10.0, time.monotonic(), 1.0, 10.0, int(epoch * 1e9))  # held at 10 s
    for k in range(3):
        stage.feed_odometry(odometry(epoch + 9.9 + 0.05 * k, x))
    acks = [b["t"] for k, b in published if k == "auv/auv1/pilot/ack"]
    assert acks == pytest.approx([epoch + 9.9, epoch + 9.95, epoch + 10.0])
    # with the feedback checked, an answer waits for the actuators' feedback too
    cfg = PilotStageConfig(feedback_timeout_s=1.0, lockstep_clock=str(tmp_path / "clock"))
    checked = PilotStage(MISSION, cfg,
                         on_publish=lambda k, b, t: published.append((k, json.loads(b))))
    checked.feed_actuators(ActuatorFeedback(epoch + 9.0, 1000.0, 0.0, 0.0))
    checked.feed_odometry(odometry(epoch + 9.9, x))
    assert published[-1] == ("auv/auv1/pilot/ack", {"t": pytest.approx(epoch + 9.5)})
    # a sink that numbers its commands (as BusCommands does): the answer carries the newest
    # one's seq, so the sim counts it once its actuators have that command

    class Numbered:
        seq = 0

        def __call__(self, cmd: object) -> None:
            self.seq += 1

    numbered = PilotStage(MISSION, PilotStageConfig(feedback_timeout_s=0.0,
                                                    lockstep_clock=str(tmp_path / "clock")),
                          sink=Numbered(),
                          on_publish=lambda k, b, t: published.append((k, json.loads(b))))
    for t in (9.9, 9.92, 9.95):  # 9.92: within the control period, no new command
        numbered.feed_odometry(odometry(epoch + t, x))
    assert [b for k, b in published[-7:] if k == "auv/auv1/pilot/ack"] == [
        {"t": pytest.approx(epoch + 9.9), "seq": 1}, {"t": pytest.approx(epoch + 9.92), "seq": 1},
        {"t": pytest.approx(epoch + 9.95), "seq": 2}]
    # the host moves on, the sim's clock does not (a stall): no timer step, no nav_lost
    stage.tick()
    assert stage.stats.timer_steps == 0 and stage.autopilot.status.mode == "running"
    # vehicle time moves on 0.1 s and holds (the sim waits on us): one timer step, not one a tick
    clock.publish(10.1, time.monotonic(), 1.0, 10.1, int(epoch * 1e9))
    for _ in range(5):
        stage.tick()
    assert stage.stats.timer_steps == 1 and stage.autopilot.status.mode == "running"
    # vehicle time moves 2.6 s on without odometry: the navigation is lost in vehicle time
    clock.publish(12.6, time.monotonic(), 1.0, 12.6, int(epoch * 1e9))
    stage.tick()
    assert stage.stats.timer_steps == 2
    st = stage.autopilot.status
    assert (st.mode, st.abort_reason) == ("aborted", "nav_lost"), st
    clock.close()
