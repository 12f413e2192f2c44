"""Actuators on CAN and the closed-loop vehicle (issue 30 part 2), in one process.

* ``config/actuators.dbc`` round trip (command and feedback sample);
* the gateway's :class:`CommandGate`: out-of-range and stale commands refused and counted;
* the emulated controller's limits (rate limit, time constant, saturation, dead band, command
  timeout) and a jammed fin, measured from its feedback read through a real SLCAN pty with
  python-can;
* :class:`ClosedLoopTruth`: a proportional heading and pitch hold written here (not the
  project's autopilot) keeps the unstable vehicle straight, and a heading step turns it.
"""

from __future__ import annotations

import math
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.config.scenario import Scenario, load_scenario
from auvgw.drivers.actuators import (
    COMMAND_TYPE,
    FAULT_BITS,
    CommandGate,
    CommandRefused,
    actuators_can,
    fault_names,
    fault_word,
    seq_newer,
)
from auvgw.sim_devices.actuators import ActuatorEmulator, ActuatorLimits, ActuatorModel
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.ins import body_rates
from auvgw.sim_devices.world import World
from auvgw.testing import REPO, wait_until

SCENARIO = REPO / "config" / "scenarios" / "closed_loop.json"
CODEC = actuators_can()
Command = CODEC.types[COMMAND_TYPE]
DEG = math.pi / 180


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


# -- the DBC -------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    seq=st.integers(0, 65535),
    rpm=st.integers(-16000, 16000),
    rudder=st.integers(-3000, 3000),
    stern=st.integers(-3000, 3000),
)
def test_command_round_trip(seq: int, rpm: int, rudder: int, stern: int) -> None:
    msg = Command(seq=seq, shaft_rpm=rpm * 0.1, rudder=rudder * 0.01 * DEG,
                  stern=stern * 0.01 * DEG)  # fmt: skip
    frame = CODEC.encode(msg)
    assert (frame.arbitration_id, frame.is_extended_id, len(frame.data)) == (0x200, False, 8)
    back = CODEC.decode_frame(frame)
    assert back.seq == seq and back.shaft_rpm == pytest.approx(rpm * 0.1)
    assert back.rudder == pytest.approx(rudder * 0.01 * DEG)
    assert CODEC.encode(back) == frame  # decode then encode: the same bytes


def test_feedback_sample_round_trip_and_fault_word() -> None:
    word = fault_word("rudder_jammed", "command_timeout")
    assert word == 0b10001 and fault_names(word) == ("rudder_jammed", "command_timeout")
    assert fault_names(1 << 9) == ("bit9",)
    sample = CODEC.sample_type(
        counter=65535, shaft_rpm=-1234.5, rudder=19.99 * DEG, stern=-20 * DEG,
        motor_current=4.56, faults=word, cmd_seq=7,
    )  # fmt: skip
    frames = CODEC.encode_sample(sample)
    assert [f.arbitration_id for f in frames] == [0x210, 0x211]
    asm = CODEC.assembler()
    out = [asm.add(CODEC.decode_frame(f)) for f in reversed(frames)]  # any order
    got = out[-1]
    assert type(got).__name__ == "ActuatorState" and got.faults == word and got.cmd_seq == 7
    assert got.shaft_rpm == pytest.approx(-1234.5) and got.motor_current == pytest.approx(4.56)
    assert CODEC.encode_sample(got) == frames


# -- the gateway's gate --------------------------------------------------------------------


def test_gate_refuses_out_of_range_and_stale_commands_and_counts_them() -> None:
    gate = CommandGate(CODEC)
    ok = Command(seq=10, shaft_rpm=800.0, rudder=5 * DEG, stern=0.0)
    gate.sent(gate.check(ok))
    for bad, reason in [
        (Command(seq=11, shaft_rpm=5000.0, rudder=0.0, stern=0.0), "out_of_range"),
        (Command(seq=11, shaft_rpm=0.0, rudder=45 * DEG, stern=0.0), "out_of_range"),
        (Command(seq=11, shaft_rpm=math.nan, rudder=0.0, stern=0.0), "out_of_range"),
        (Command(seq=10, shaft_rpm=800.0, rudder=0.0, stern=0.0), "stale_seq"),  # repeated
        (Command(seq=9, shaft_rpm=800.0, rudder=0.0, stern=0.0), "stale_seq"),  # older
        (CODEC.types["ACT_State"](counter=1, shaft_rpm=0.0, rudder=0.0, stern=0.0), "wrong_type"),
    ]:
        with pytest.raises(CommandRefused) as err:
            gate.check(bad)
        assert err.value.reason == reason, bad
    # a refused command did not move the sequence: 11 still goes, and wraps past 65535
    gate.sent(gate.check(Command(seq=11, shaft_rpm=800.0, rudder=0.0, stern=0.0)))
    assert gate.counts["forwarded"] == 2 and gate.counts["out_of_range"] == 3
    assert gate.counts["stale_seq"] == 2 and gate.counts["wrong_type"] == 1
    assert seq_newer(3, 65530) and not seq_newer(65530, 3) and seq_newer(0, None)
    # another class of the same DBC message (another codec instance) is taken by its fields
    other = actuators_can().types[COMMAND_TYPE](seq=12, shaft_rpm=1.0, rudder=0.0, stern=0.0)
    assert gate.check(other) == CODEC.encode(Command(seq=12, shaft_rpm=1.0, rudder=0.0, stern=0.0))


def test_gate_starts_a_new_stream_after_a_quiet_spell() -> None:
    """Within a stream an old sequence number is stale; after ``new_stream_after_s`` without a
    forwarded command (a controller restarted, counting from 0 again) it starts a new one."""
    gate = CommandGate(CODEC, new_stream_after_s=2.0)
    gate.sent(gate.check(Command(seq=500, shaft_rpm=800.0, rudder=0.0, stern=0.0), 10.0), 10.0)
    with pytest.raises(CommandRefused):
        gate.check(Command(seq=0, shaft_rpm=800.0, rudder=0.0, stern=0.0), 11.9)
    frame = gate.check(Command(seq=0, shaft_rpm=800.0, rudder=0.0, stern=0.0), 12.1)
    gate.sent(frame, 12.1)
    assert gate.last_seq == 0
    with pytest.raises(CommandRefused):  # and the new stream is guarded as before
        gate.check(Command(seq=0, shaft_rpm=800.0, rudder=0.0, stern=0.0), 12.2)


# -- the controller model (pure) -----------------------------------------------------------


def test_model_timeout_stops_the_thruster_and_a_command_clears_it() -> None:
    m = ActuatorModel(ActuatorLimits(command_timeout_s=0.5), rpm=1000.0)
    m.advance(0.45)
    assert m.read(0.45).faults == 0 and m.rpm == 1000.0
    r = m.read(3.0)
    assert r.faults == FAULT_BITS["command_timeout"] and abs(r.rpm) < 5.0  # spun down
    m.command(3.0, 900.0, 0.0, 0.0, seq=4)
    r = m.read(3.45)
    assert r.faults == 0 and r.cmd_seq == 4 and r.rpm == pytest.approx(450.0, abs=10.0)  # ramp
    assert m.read(3.6).faults == FAULT_BITS["command_timeout"]  # 0.5 s without a command


def test_a_command_takes_effect_at_its_own_time_even_when_ticks_run_late() -> None:
    """On a busy host the feedback ticks are dispatched late, after a command arrived at a
    later vehicle time: a tick for an earlier time reports the state before the command."""
    m = ActuatorModel(ActuatorLimits(command_timeout_s=100), rpm=1000.0)
    m.advance(1.0)
    m.command(1.2, 1100.0, 0.1, 0.0, seq=7)  # arrives at 1.2 s; ticks at 1.05... still due
    early = m.read(1.15)
    assert early.cmd_seq == 0 and early.rpm == 1000.0 and early.rudder == 0.0
    r = m.read(1.5)  # 0.3 s after the command: one time constant
    assert r.cmd_seq == 7 and r.rpm - 1000.0 == pytest.approx(63.2, abs=1.0)
    m.command(1.4, 900.0, 0.0, 0.0, seq=8)  # a time already integrated: at once
    assert m.cmd_seq == 8 and m.commands == 2


def test_model_silent_thruster_and_overcurrent_from_the_fault_windows() -> None:
    def windows(t: float) -> frozenset[str]:
        return frozenset({"thruster_silent"}) if 1.0 <= t < 3.0 else frozenset()

    m = ActuatorModel(ActuatorLimits(command_timeout_s=100, max_current_a=3.0), rpm=1000.0,
                      faults_at=windows)  # fmt: skip
    r = m.read(0.5)
    assert r.faults == 0 and r.current_a == pytest.approx(0.3 + 2.0)  # 1000 rpm: 2.3 A
    r = m.read(2.9)
    assert fault_names(r.faults) == ("thruster_no_answer",) and r.current_a == 0.0
    assert abs(r.rpm) < 10.0  # coasted down, whatever the command
    m.command(2.9, 1500.0, 0.0, 0.0, seq=1)
    r = m.read(6.0)  # answering again: 1500 rpm draws 4.8 A, over the 3 A limit
    assert fault_names(r.faults) == ("overcurrent",) and r.rpm == pytest.approx(1500, abs=5)


def test_feedback_reaches_the_ros2_path_as_a_decoded_message() -> None:
    from auvgw.ros2 import to_ros

    sample = CODEC.sample_type(counter=1, shaft_rpm=900.0, rudder=0.1, stern=0.0,
                               motor_current=1.2, faults=4, cmd_seq=3)  # fmt: skip
    (out,) = to_ros("sensor", "actuators", sample, 10**18, 5, "actuatorstate")
    assert out.topic == "sensor/actuators/actuatorstate"
    assert "ActuatorState" in str(out.msg) and "900" in str(out.msg)


# -- the emulated controller through SLCAN ---------------------------------------------------


def _scenario(faults: dict | None = None, **options: float) -> Scenario:
    scn = load_scenario(SCENARIO)
    data = scn.model_dump(exclude={"source"})
    data["devices"]["actuators"] = {"enabled": True, "rate_hz": 50.0,
                                    "options": {"command_timeout_s": 30.0, **options},
                                    "faults": faults or {}}  # fmt: skip
    return Scenario.model_validate(data)


class _Bench:
    """The actuators' emulator on its own clock and SLCAN pty, a python-can host on it."""

    def __init__(self, scn: Scenario, tmp: Path, speed: float = 2.0) -> None:
        world = World.from_scenario(scn)
        self.truth = ClosedLoopTruth(scn, world)
        self.clock = SimClock(speed)
        ctx = SimContext(scn, world, self.truth, self.clock, tmp / "ports")
        self.em = ActuatorEmulator(ctx)
        self.bus = can.Bus(interface="slcan", channel=self.em.can.adapter.device,
                           bitrate=500000, sleep_after_open=0)  # fmt: skip
        wait_until(lambda: self.em.can.adapter.is_open, 10, what="the adapter opened")
        self.samples: list = []
        self._asm = CODEC.assembler()

    def start(self) -> None:
        self.em.start(0.0)
        self.clock.start()
        self.clock.start_thread()

    def send(self, seq: int, rpm: float, rudder_deg: float, stern_deg: float) -> None:
        f = CODEC.encode(Command(seq=seq, shaft_rpm=rpm, rudder=rudder_deg * DEG,
                                 stern=stern_deg * DEG))  # fmt: skip
        self.bus.send(can.Message(arbitration_id=f.arbitration_id, data=f.data,
                                  is_extended_id=False))  # fmt: skip

    def read_until(self, pred) -> list:
        """Feedback samples (with the vehicle time they were sent at) until ``pred(sample)``."""

        def step() -> bool:
            msg = self.bus.recv(0.5)
            if msg is not None:
                s = self._asm.add(CODEC.decode_frame(msg))
                if s is not None:
                    self.samples.append(s)
                    return bool(pred(s))
            return False

        wait_until(step, 30, interval=0, what="feedback")
        return self.samples

    def close(self) -> None:
        self.clock.stop()
        self.bus.shutdown()
        self.em.close()


def _first_time(samples, start: int, cond) -> float:
    """Seconds (feedback periods of 1/50 s) from sample ``start`` to the first meeting cond."""
    for k, s in enumerate(samples[start:]):
        if cond(s):
            return k / 50.0
    raise AssertionError("never")


@pytest.mark.e2e
def test_emulated_limits_measured_from_the_feedback(tmp_path: Path) -> None:
    """Commands at t ~ 0.2 s: rudder +30 deg (saturates at 20, rate limit 30 deg/s), shaft
    1000 -> 1100 rpm (tau 0.3 s, under the rate limit), stern 0.1 deg (inside the 0.2 deg dead
    band); the rudder jams at t = 8 s while a -10 deg command is pending. The emulator's clock
    runs on wall time (2x): the jam is late enough that a host thread starved for 3 s still
    commands before the move (at t = 2 s the command of a host about 0.9 s late, two burners
    beside the suite, met the jam after 0.4 deg of its ramp)."""
    jam_s = 8.0
    b = _Bench(_scenario({"rudder_jam": [[jam_s, 1000.0]]}), tmp_path)
    try:
        b.start()
        b.read_until(lambda s: s.counter >= 5)
        b.send(1, 1100.0, 30.0, 0.1)
        b.read_until(lambda s: s.cmd_seq == 1)
        i0 = len(b.samples) - 1
        assert b.samples[i0].counter / 50 < jam_s - 1.5, "the command came too late to measure"
        b.read_until(lambda s: s.counter >= b.samples[i0].counter + 75)  # 1.5 s
        s = b.samples
        rud = np.array([x.rudder for x in s[i0:]]) / DEG
        # saturation: the +30 deg command holds at 20 deg (within the dead band)
        assert 19.7 <= rud[-1] <= 20.0
        # rate limit: a straight ramp at 30 deg/s through the middle of the move
        k10 = _first_time(s, i0, lambda x: x.rudder >= 5 * DEG)
        k15 = _first_time(s, i0, lambda x: x.rudder >= 15 * DEG)
        assert 10 / (k15 - k10) == pytest.approx(30.0, rel=0.15)
        # time constant: 63 % of the 100 rpm step after tau = 0.3 s (one feedback period)
        rpm0 = s[i0 - 1].shaft_rpm
        tau = _first_time(s, i0, lambda x: x.shaft_rpm - rpm0 >= 0.632 * (1100 - rpm0))
        assert tau == pytest.approx(0.3, abs=0.06) and rpm0 == pytest.approx(1000, abs=1)
        assert s[-1].shaft_rpm == pytest.approx(1100, abs=5.0)  # settled within the dead band
        # dead band: a 0.1 deg stern command never moves the plane
        assert all(x.stern == 0.0 for x in s[i0:])
        assert all(x.faults == 0 for x in s) and s[-1].motor_current > 0.3
        # the jam: at t = 8 s the rudder freezes at 20 deg and the fault word says so
        jammed = b.read_until(lambda s: s.faults & FAULT_BITS["rudder_jammed"])[-1]
        b.send(2, 1100.0, -10.0, 0.0)
        b.read_until(lambda s: s.cmd_seq == 2)
        end = b.samples[-1].counter + 25
        b.read_until(lambda s: s.counter >= end)
        last = b.samples[-1]
        assert fault_names(last.faults) == ("rudder_jammed",)
        assert last.rudder == jammed.rudder and jammed.rudder / DEG > 19.7  # ignored -10 deg
        assert b.em.stats()["host"]["commands"] == 2
    finally:
        b.close()


# -- the closed-loop truth -------------------------------------------------------------------


def test_closed_loop_truth_follows_the_commands_of_a_heading_hold() -> None:
    """A proportional-derivative heading / pitch hold (gains tuned by hand for this test) at
    20 Hz on the truth, through the actuator model: straight while the setpoint is north, then
    the setpoint turns to 30 deg at 5 deg/s from t = 5 s and the vehicle follows. Without the
    hold (fins at zero) the vehicle departs: the model is open-loop unstable."""
    scn = load_scenario(SCENARIO)
    world = World.from_scenario(scn)

    def run(hold: bool, seconds: float) -> list[float]:
        truth = ClosedLoopTruth(scn, world)
        model = ActuatorModel(ActuatorLimits(command_timeout_s=100), rpm=1000.0)
        truth.set_inputs(model.inputs)
        headings = []
        for k in range(int(seconds * 20)):
            t = k / 20
            s = truth.at(t)
            href = min(max(t - 5.0, 0.0) * 5.0, 30.0) * DEG
            rud = np.clip(_wrap(s.heading - href) + 4 * s.yaw_rate, -0.35, 0.35)
            stern = np.clip(s.pitch + 4 * s.pitch_rate, -0.35, 0.35)
            if hold:
                model.command(t, 1000.0, float(rud), float(stern), k)
            headings.append(s.heading)
        return headings

    h = np.degrees(run(True, 18.0))
    assert np.all(np.abs(h[40:100]) < 1.5)  # t 2-5 s: holds north
    assert h[-1] == pytest.approx(30.0, abs=2.5)  # t 18 s: on the new heading
    free = np.degrees(run(False, 10.0))  # zero fins: the open-loop instability turns it away
    assert np.max(np.abs(free)) > 10.0


def test_closed_loop_truth_is_causal_and_samples_the_past() -> None:
    scn = load_scenario(SCENARIO)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn))
    a = truth.at(1.0)
    assert truth.time == pytest.approx(1.0) and truth.steps == 100
    b = truth.at(0.5)  # the past: interpolated, nothing integrated
    assert truth.steps == 100 and b.t == 0.5 and b.x < a.x
    assert a.x == pytest.approx(1.3, rel=0.1) and a.z == pytest.approx(5.0, abs=0.1)


def test_a_captive_start_runs_straight_until_released() -> None:
    """What a lock-step sim does until the controller first answers: the vehicle runs straight
    at its start attitude and velocity (the inputs unread: a hard-over rudder does nothing),
    then the dynamics take over from there."""
    scn = load_scenario(SCENARIO)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn), inputs=lambda _t: (0.35, 0.35, 0.0))
    truth.hold_captive()
    s0, a = truth.at(0.0), truth.at(2.0)
    assert (a.heading, a.pitch, a.roll, a.z, a.u) == (s0.heading, s0.pitch, s0.roll, s0.z, s0.u)
    assert a.x - s0.x == pytest.approx(2.0 * s0.u, rel=1e-6) and a.y == s0.y
    truth.release()
    assert truth.released_at == pytest.approx(2.0)
    b = truth.at(4.0)  # released: the rudder and stern plane hard over turn and pitch it
    assert abs(b.heading - s0.heading) > 0.1 and abs(b.pitch) > 0.1
    truth.release()  # once
    assert truth.released_at == pytest.approx(2.0)


def test_the_ins_reports_the_dynamics_body_rates() -> None:
    """The truth's rates are Euler angle rates (the scripted truth's, which the INS emulator
    turns into body rates); the closed-loop truth stored the body rates p, q, r there, so a
    rolled vehicle (the propeller torque's roll) reported a wrong yaw rate to the autopilot. The
    INS's rates must be the dynamics state's p, q, r, rolled and pitched, in a turn."""
    scn = load_scenario(SCENARIO)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn), inputs=lambda _t: (-0.2, 0.1, 1500.0))
    s = truth.at(3.0)  # a turn, rolled and pitched by the fins and the propeller torque
    pqr = truth.state[3:6]
    assert abs(s.roll) > 0.05 and abs(s.pitch) > 0.05 and abs(pqr[2]) > 0.05
    np.testing.assert_allclose(body_rates(s), pqr, atol=1e-9)


def test_scenario_checks_the_closed_loop_keys() -> None:
    data = load_scenario(SCENARIO).model_dump(exclude={"source"})
    data.pop("duration_s")
    with pytest.raises(ValueError, match="needs duration_s"):
        Scenario.model_validate(data)
    data["duration_s"], data["motion"] = 10.0, "bicycle"
    with pytest.raises(ValueError, match="needs motion 'auv'"):
        Scenario.model_validate(data)


def test_a_closed_loop_scenario_refuses_one_process_per_device(tmp_path: Path) -> None:
    from auvgw.sim_devices.runner import DeviceProcesses, RunOptions

    with pytest.raises(ValueError, match="runs every device in one process"):
        DeviceProcesses(SCENARIO, RunOptions(out_dir=tmp_path, speed=1.0))
