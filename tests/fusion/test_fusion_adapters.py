"""Adapters from decoded device messages to fusion samples, and device clocks.

PD0 frames are checked against the DVL emulator's ensembles in every coordinate frame (the
vehicle turns, pitches over terrain and crabs in a current, so every axis and sign shows);
HN-100 messages come from the codecs (serial table and CAN DBC); the clock estimator against
hand-made receive times.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.config.scenario import Scenario
from auvgw.drivers import hn100, pd0
from auvgw.drivers.can_codec import CanDeviceCodec, hn100_can
from auvgw.fusion import DvlMount
from auvgw.fusion.adapters import (
    RDI_DOWN_BEAM3_FORWARD_DEG,
    AdapterError,
    DeviceClock,
    MessageAdapter,
    dvl_from_pd0,
    ins_from_hn100,
    ins_time_wrap,
)
from auvgw.fusion.frames import mount_matrix
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.vehicle import simulate
from auvgw.sim_devices.world import World, body_to_ned

SCENARIO = {
    "name": "fusion-adapters",
    "seed": 3,
    "duration_s": 60.0,
    "vehicle": {
        "waypoints": [[0, 0], [40, 0], [40, 30]],
        "speed_mps": 1.5,
        "altitude_m": 10.0,
        "max_yaw_rate_dps": 12.0,
        "lookahead_m": 6.0,
        "current_mps": [0.2, -0.15],
    },
    "terrain": {"kind": "procedural", "depth_m": 30.0, "relief_m": 4.0, "wavelength_m": 40.0,
                "octaves": 2, "seed": 4},
}  # fmt: skip
TIMES = np.arange(0.0, 50.0, 0.2)
SIGMA = math.hypot(0.002, 0.001 / math.sqrt(12))  # emulator noise and the 1 mm/s wire rounding


def dvl(tmp_path: Path, **options) -> tuple[DvlEmulator, object]:
    data = {**SCENARIO, "devices": {"dvl": {"options": {"serial": False, **options}}}}
    scn = Scenario.model_validate(data)
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    ctx = SimContext(scn, world, truth, SimClock(0), tmp_path / "ports")
    return DvlEmulator(ctx), truth


def body_velocity(truth, t: float) -> np.ndarray:
    s = truth.at(t)
    return body_to_ned(s.heading, s.pitch, s.roll).T @ np.array([s.vn, s.ve, s.vd])


@pytest.mark.parametrize(
    ("frame", "tilts", "out_frame"),
    [
        ("ship", True, "body"),
        ("ship", False, "body"),
        ("earth", True, "body"),
        ("earth", False, "body"),
        ("instrument", True, "instrument"),
        ("beam", True, "instrument"),
    ],
)
def test_pd0_velocity_in_every_frame_is_the_body_velocity(tmp_path, frame, tilts, out_frame):
    em, truth = dvl(tmp_path, frame=frame, tilts=tilts)
    rot = mount_matrix(DvlMount(rotation_deg=RDI_DOWN_BEAM3_FORWARD_DEG))
    err, spread = [], []
    for t in TIMES:
        s = dvl_from_pd0(pd0.decode(em.frame_at(float(t))))
        assert s.frame == out_frame and s.bottom_lock
        assert s.t == pytest.approx(em.ctx.epoch + t, abs=1e-6)  # the RTC, POSIX s
        v = np.array(s.velocity)
        if out_frame == "instrument":
            v = rot @ v  # RDI instrument axes -> body, the documented mounting
        expect = body_velocity(truth, float(t))
        err.append(v - expect)
        spread.append(expect)
    err = np.array(err)
    # surge and sway vary by many sigmas over the run, so a wrong axis or sign would show; the
    # body heave stays near 0, which a wrong tilt sign would break (2 x pitch x surge)
    assert np.ptp(np.array(spread)[:, :2], axis=0).min() > 20 * SIGMA
    rms = np.sqrt((err**2).mean(axis=0))
    assert np.abs(err.mean(axis=0)).max() < 4 * SIGMA / math.sqrt(len(TIMES)) + 2e-4
    assert rms.max() < 2.0 * SIGMA  # noise only (beam: per-beam noise through the Janus matrix)


def test_high_resolution_velocity_is_preferred_and_not_negated(tmp_path):
    em, _ = dvl(tmp_path, bt_high_res=True)
    ens = pd0.decode(em.frame_at(12.0))
    s = dvl_from_pd0(ens)
    hr = ens.bt_high_res.vehicle_velocity
    level = np.array([hr[1], hr[0], -hr[2]])  # ship (starboard, forward, up) -> level body
    vl = ens.variable_leader
    c, sp = math.cos(vl.pitch), math.sin(vl.pitch)
    cr, sr = math.cos(vl.roll), math.sin(vl.roll)
    ry = np.array([[c, 0, sp], [0, 1, 0], [-sp, 0, c]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    np.testing.assert_allclose(s.velocity, (ry @ rx).T @ level, atol=1e-12)
    low = dvl_from_pd0(ens, high_res=False)
    assert not np.allclose(s.velocity, low.velocity, rtol=0, atol=1e-7)  # 0.01 vs 1 mm/s
    np.testing.assert_allclose(s.velocity, low.velocity, atol=1e-3)


def test_no_lock_ping_keeps_depth_and_altitude_unknown_velocity(tmp_path):
    em, truth = dvl(tmp_path)
    em.set_faults(bottom_lock_loss=[(10.0, 11.0)])
    s = dvl_from_pd0(pd0.decode(em.frame_at(10.4)))
    assert not s.bottom_lock and all(math.isnan(c) for c in s.velocity)
    assert s.depth == pytest.approx(truth.at(10.4).z, abs=0.15)  # dm on the wire
    assert math.isnan(s.altitude)  # no beam detected the bottom in the fault window
    good = dvl_from_pd0(pd0.decode(em.frame_at(11.2)))
    assert good.bottom_lock and good.altitude == pytest.approx(truth.at(11.2).altitude, abs=1.0)


def with_bt_velocity(ens: pd0.Ensemble, v: np.ndarray) -> pd0.Ensemble:
    return dataclasses.replace(ens, bottom_track=dataclasses.replace(ens.bottom_track, velocity=v))


def test_three_beam_solution_in_beam_coordinates(tmp_path):
    em, _ = dvl(tmp_path, frame="beam")
    ens = pd0.decode(em.frame_at(20.0))
    rot = mount_matrix(DvlMount(rotation_deg=RDI_DOWN_BEAM3_FORWARD_DEG))
    full = rot @ np.array(dvl_from_pd0(ens).velocity)
    for bad in range(4):
        v = np.array(ens.bottom_track.velocity, dtype=float)
        v[bad] = np.nan
        s = dvl_from_pd0(with_bt_velocity(ens, v))
        assert s.bottom_lock
        np.testing.assert_allclose(rot @ np.array(s.velocity), full, atol=0.012)
    v[0] = np.nan  # two beams left: no lock
    assert not dvl_from_pd0(with_bt_velocity(ens, v)).bottom_lock


def test_depth_only_from_a_pressure_sensor(tmp_path):
    em, _ = dvl(tmp_path, pressure_sensor=False)
    assert math.isnan(dvl_from_pd0(pd0.decode(em.frame_at(5.0))).depth)


def test_pd0_errors_name_what_is_missing(tmp_path):
    em, _ = dvl(tmp_path, frame="earth")
    ens = pd0.decode(em.frame_at(5.0))
    with pytest.raises(AdapterError, match="fixed leader"):
        dvl_from_pd0(dataclasses.replace(ens, fixed_leader=None))
    with pytest.raises(AdapterError, match="earth coordinates without a variable leader"):
        dvl_from_pd0(dataclasses.replace(ens, variable_leader=None), t=1.0)
    bad_clock = dataclasses.replace(
        ens.variable_leader, rtc=np.array([24, 13, 40, 0, 0, 0, 0], np.uint8)
    )
    with pytest.raises(AdapterError, match="RTC"):
        dvl_from_pd0(dataclasses.replace(ens, variable_leader=bad_clock))
    assert dvl_from_pd0(dataclasses.replace(ens, variable_leader=bad_clock), t=7.5).t == 7.5


def _nav(**kw) -> object:
    base = dict(seq=1, status=hn100.CODEC.status_word(aligned=True, dvl_aided=True), time=12.3456,
                roll=0.01, pitch=-0.02, heading=6.0, rate_x=0.001, rate_y=-0.002, rate_z=0.05,
                accel_x=0.1, accel_y=0.0, accel_z=-9.8, vel_n=1.0, vel_e=0.5, vel_d=0.0,
                latitude=1.0, longitude=0.2, depth=10.0)  # fmt: skip
    base.update(kw)
    return hn100.CODEC.decode(hn100.CODEC.encode(hn100.Hn100Nav(**base)))


def test_ins_serial_and_can_messages_at_the_device_time():
    nav = _nav()
    s = ins_from_hn100(nav)
    assert s.t == pytest.approx(12.3456) and (s.roll, s.pitch, s.heading) == (0.01, -0.02, 6.0)
    assert s.rates == pytest.approx((0.001, -0.002, 0.05), abs=1e-9)
    assert s.accel == pytest.approx((0.1, 0.0, -9.8), abs=1e-9)
    assert ins_from_hn100(nav, t=99.0).t == 99.0
    codec = hn100_can()
    sample = codec.sample_type(seq=3, time=12.3456, roll=0.01, pitch=-0.02, heading=6.0,
                               rate_x=0.001, rate_y=-0.002, rate_z=0.05, accel_x=0.1, accel_y=0.0,
                               accel_z=-9.8, vel_n=1.0, vel_e=0.5, vel_d=0.0, latitude=1.0,
                               longitude=0.2, depth=10.0, alignment="FINE", gnss_aided=0,
                               dvl_aided=1, error="OK", reserved=0)  # fmt: skip
    dec = CanDeviceCodec(codec)
    frames = codec.encode_sample(sample)
    got = [dec.decode(f.arbitration_id, f.data, f.is_extended_id) for f in frames]
    c = ins_from_hn100(got[-1])
    assert c.t == pytest.approx(12.3456, abs=1e-6) and c.heading == pytest.approx(6.0, abs=1e-4)
    assert c.rates[2] == pytest.approx(0.05, abs=2e-4)
    # the time field wraps: u32 of 100 us in the shipped table; the CAN one does not say
    assert ins_time_wrap(type(nav)) == pytest.approx(2**32 * 1e-4)
    assert ins_time_wrap(type(got[-1])) is None


def test_adapter_drops_unaligned_ins_and_binds_one_device_per_role():
    a = MessageAdapter(latency_s={"ins": 0.005})
    assert a.adapt("ins", 100.0, _nav(status=0)) is None  # not aligned
    assert a.stats.ins_not_aligned == 1
    s = a.adapt("ins", 100.0, _nav(time=50.0))
    assert s.t == pytest.approx(100.0 - 0.005) and a.ins_device == "ins"
    assert a.adapt("ins2", 100.01, _nav(time=50.01)) is None  # a second INS is ignored
    assert a.stats.ignored == 1 and a.stats.ins == 1
    assert a.adapt("ins", 100.02, _nav(time=50.01)).t == pytest.approx(100.01 - 0.005)


def test_warm_up_retimes_the_late_first_frames_after_a_port_opens():
    """The first INS frames are read 0.6 s late (a backlog), then on time. Mapped at once they
    stand late and the on-time frames after them fall before the filter's time (the motion
    between is lost); held for the warm-up, every frame is released on its true time, in order,
    together with the DVL's."""
    dev = np.arange(300) * 0.01  # 100 Hz for 3 s
    host = np.maximum(1000.6, 1000.0 + dev + 0.005)  # the port opened 0.6 s in: a backlog
    plain = MessageAdapter(dvl_device=None)
    mapped = [plain.adapt("ins", h, _nav(time=d)).t for d, h in zip(dev, host, strict=True)]
    assert len(set(mapped)) < 300 - 55  # the backlog all on one time: its motion is lost
    warm = MessageAdapter(dvl_device=None, warmup_s=2.0)
    out = []
    for d, h in zip(dev, host, strict=True):
        out += warm.adapt_all("ins", h, _nav(time=d))
        if h - host[0] < 2.0:
            assert not out  # held
    out += warm.flush()
    t = np.array([s.t for s in out])
    assert len(t) == 300 and np.all(np.diff(t) > 0)
    assert np.abs(t - (1000.0 + dev + 0.005)).max() < 1e-9
    # after the window, samples pass at once
    assert warm.adapt("ins", host[-1] + 0.01, _nav(time=3.0)).t == pytest.approx(1003.005)


# -- device clocks -------------------------------------------------------------------------------


def test_clock_offset_is_the_smallest_delay_and_jitter_does_not_move_it():
    rng = np.random.default_rng(1)
    c = DeviceClock(latency_s=0.006)
    dev = np.arange(1000) * 0.01
    delay = 0.006 + rng.exponential(0.002, 1000)
    delay[::50] = 0.006  # the fastest deliveries
    host = 5000.0 + dev + delay
    mapped = np.array([c.to_common(d, h) for d, h in zip(dev, host, strict=True)])
    # after the first minimal-delay sample, every sample maps to its true time within the creep
    assert np.abs(mapped - (5000.0 + dev)).max() < 1e-4 * 0.6
    assert c.stats.resets == 0


def test_clock_follows_skew_and_unwraps():
    c = DeviceClock(skew=1e-4, wrap_s=100.0)
    host = 1000.0 + np.arange(3000) * 0.1
    dev = (np.arange(3000) * 0.1 * (1 - 5e-5)) % 100.0  # 50 ppm slow, wraps every 100 s
    mapped = np.array([c.to_common(d, h) for d, h in zip(dev, host, strict=True)])
    assert c.stats.wraps == 2 and c.stats.resets == 0
    assert np.abs(mapped - host).max() < 1e-3  # the slow clock is followed


def test_clock_jumps_forward_at_once_and_backward_after_confirmation():
    c = DeviceClock(latency_s=0.02, confirm=3, confirm_s=0.5)
    host = [1e9 + 0.2 * k + 0.02 for k in range(100)]
    dev = [1.7e9 + 0.2 * k + (5.0 if 20 <= k < 50 else 0.0) - (30.0 if k >= 50 else 0.0)
           for k in range(100)]  # fmt: skip
    mapped = [c.to_common(d, h) for d, h in zip(dev, host, strict=True)]
    ok = [abs(m - (h - 0.02)) < 1e-6 for m, h in zip(mapped, host, strict=True)]
    # forward jump (k=20): followed at once (the smaller difference is taken); backward jump
    # (k=50): three samples and 0.5 s of receive time to confirm, then followed again
    assert all(ok[:50]) and not any(ok[50:53]) and all(ok[53:]) and c.stats.resets == 1


def test_lag_is_not_a_clock_jump_but_a_new_common_epoch_is_after_a_while():
    """Frames 5 s late for 10 s (a loaded host at 10x): the device time runs on, so they map
    onto their true times, no reset. A common clock that jumps 100 s for good (a gateway
    restarted on another epoch): followed once the excess has lasted 30 s of device time."""
    dev = np.arange(6000) * 0.01
    host = 100.0 + dev + 0.005
    host[1000:2000] += 5.0 * np.minimum(1.0, np.arange(1000) / 100.0)  # lag builds to 5 s
    host[2000:2500] = np.maximum(host[1999], host[2000:2500])  # then the backlog drains
    c = DeviceClock()
    mapped = np.array([c.to_common(d, h) for d, h in zip(dev, host, strict=True)])
    assert c.stats.resets == 0
    np.testing.assert_allclose(mapped, 100.005 + dev, atol=3e-3)  # the 1e-4 s/s skew creep
    c = DeviceClock()
    host = 100.0 + dev + 0.005 + np.where(dev >= 10.0, 100.0, 0.0)
    mapped = np.array([c.to_common(d, h) for d, h in zip(dev, host, strict=True)])
    assert c.stats.resets == 1
    # until then on the old epoch (plus the skew creep over the 100 s step: 0.01 s)
    np.testing.assert_allclose(mapped[dev < 40.0], 100.005 + dev[dev < 40.0], atol=0.02)
    np.testing.assert_allclose(mapped[dev >= 40.01], host[dev >= 40.01], atol=5e-3)


def test_a_backlog_after_a_stall_is_not_a_clock_jump():
    c = DeviceClock(confirm=3, confirm_s=0.5)
    dev = np.arange(300) * 0.01
    host = 100.0 + dev.copy()
    host[100:150] = 100.0 + 1.0 + 1.5 + np.arange(50) * 0.001  # stalled 1.5 s, then a burst
    mapped = [c.to_common(d, h) for d, h in zip(dev, host, strict=True)]
    assert c.stats.resets == 0
    np.testing.assert_allclose(mapped, 100.0 + dev, atol=1e-3)
