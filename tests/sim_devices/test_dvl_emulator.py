"""Emulated Pathfinder DVL: PD0 ensembles decoded with the drivers and compared with the ground
truth (velocity in every coordinate frame, ranges against the terrain geometry), bottom lock lost
and regained where the terrain says, fault windows, clock jumps, and a run over a real pty read
with pyserial."""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from auvgw.drivers import pd0
from auvgw.drivers.framing import ErrorPolicy
from auvgw.drivers.spec import raw_value
from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.sim_devices.emulator import DEFAULT_EPOCH
from auvgw.sim_devices.runner import Runner, RunOptions
from auvgw.sim_devices.vehicle import Truth
from auvgw.sim_devices.world import body_to_ned
from auvgw.testing.dvl import BASE, offline, scenario
from auvgw.testing.emulators import SerialReader

S30, C30 = math.sin(math.radians(30)), math.cos(math.radians(30))
#: beams 1-4 out of a down-facing transducer with beam 3 forward, body axes (fwd, stbd, down):
#: from the Pathfinder guide, X runs beam 1 -> beam 2 (starboard), Y beam 4 -> beam 3 (forward)
BEAMS = np.array([[0, -S30, C30], [0, S30, C30], [S30, 0, C30], [-S30, 0, C30]])
SIGMA_V = 0.002  # the Pathfinder's 0.2 cm/s
MM = 0.001  # 0x0600 resolution

def run(
    em: DvlEmulator, times: np.ndarray, reencode_every: int = 1
) -> tuple[bytes, list[pd0.Ensemble]]:
    """Frames at ``times`` as one byte stream, split by the PD0 framer and decoded; every
    frame must be good, and every ``reencode_every``-th must re-encode to the same bytes."""
    frames = [em.frame_at(float(t)) for t in times]
    stream = b"".join(frames)
    framer = pd0.Pd0Framer(policy=ErrorPolicy.RAISE)
    got = [f.data for f in framer.feed(stream)] + [f.data for f in framer.finish()]
    assert got == frames and framer.stats.bad_frames == 0 and framer.stats.skipped_bytes == 0
    ens = pd0.decode_many(got)
    for e, f in zip(ens[::reencode_every], frames[::reencode_every], strict=True):
        assert pd0.encode(e) == f
    return stream, ens


def ping_times(truth: Truth, rate: float, t_end: float | None = None) -> np.ndarray:
    end = truth.duration if t_end is None else t_end
    return np.arange(int(end * rate) + 1) / rate


def expected_velocity(frame: str, truth: Truth, t: float) -> np.ndarray:
    """The vehicle's velocity over ground in ``frame`` (3 axes, or the 4 beams' closing
    speeds), from the truth alone."""
    s = truth.at(t)
    vn, ve, vd = s.vn, s.ve, s.vd
    if frame == "earth":
        return np.array([ve, vn, -vd])
    if frame == "ship":  # levelled: starboard, forward, up = the truth's sway, surge, -heave
        return np.array([s.v, s.u, -s.w])
    body = body_to_ned(s.heading, s.pitch, s.roll).T @ np.array([vn, ve, vd])
    if frame == "instrument":
        return np.array([body[1], body[0], -body[2]])
    return BEAMS @ body  # beams: the instrument's speed along each outward beam


def check_noise(err: np.ndarray, sigma: float, quantum: float, what: str) -> None:
    """Errors of one component: mean about 0, standard deviation the configured sigma (plus
    the wire's rounding)."""
    n = len(err)
    expect = math.sqrt(sigma**2 + quantum**2 / 12)
    assert abs(err.mean()) < 5 * expect / math.sqrt(n) + 1e-5, f"{what}: mean {err.mean():.5f}"
    assert 0.85 * expect < err.std() < 1.15 * expect, f"{what}: std {err.std():.5f} vs {expect}"


# -- the ensemble is a Pathfinder's ---------------------------------------------------------------


def test_default_ensemble_is_a_bottom_track_only_pathfinder(tmp_path: Path) -> None:
    em, _, _ = offline(scenario(), tmp_path)
    frame = em.frame_at(10.0)
    assert frame[:2] == b"\x7f\x7f" and frame[5] == 3  # fixed, variable leader, bottom track
    offs = [int.from_bytes(frame[6 + 2 * i : 8 + 2 * i], "little") for i in range(3)]
    ids = [int.from_bytes(frame[o : o + 2], "little") for o in offs]
    nbytes = int.from_bytes(frame[2:4], "little")
    sizes = np.diff([*offs, nbytes]).tolist()
    assert ids == [0x0000, 0x0080, 0x0600] and sizes == [58, 77, 81]
    assert len(frame) == 6 + 6 + 58 + 77 + 81 + 2
    ens = pd0.decode(frame)
    fl, vl = ens.fixed_leader, ens.variable_leader
    assert fl.firmware_version == 67 and fl.n_beams == 4 and fl.n_cells == 0
    assert fl.system_config & 0x7 == 0b011  # 600 kHz
    assert fl.system_config & 0x08 and not fl.system_config & 0x80  # convex, down-facing
    assert (fl.system_config >> 8) & 0x3 == 0b10  # 30 degree beams
    assert fl.coord_transform == 0b10111  # EX10111: ship, tilts, 3-beam, bin mapping
    assert ens.coordinate_frame is pd0.CoordinateFrame.SHIP and fl.beam_angle is None
    assert fl.time_per_ping == pytest.approx(0.2)  # 5 Hz
    bt = ens.bottom_track
    assert bt.pings_per_ensemble == 1 and bt.mode == 8 and bt.reserved_81 is None
    assert bt.max_depth == pytest.approx(110.0)
    assert vl.ensemble == 1 and vl.speed_of_sound == 1500
    assert em.rate_hz == 5.0


@pytest.mark.parametrize(("frame", "ex"), [("beam", 0x07), ("instrument", 0x0F), ("earth", 0x1F)])
def test_frame_option_sets_the_ex_byte(tmp_path: Path, frame: str, ex: int) -> None:
    em, _, _ = offline(scenario({"options": {"frame": frame}}), tmp_path)
    assert pd0.decode(em.frame_at(0.0)).fixed_leader.coord_transform == ex


def test_bad_options_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"devices\.dvl\.options\.frame"):
        offline(scenario({"options": {"frame": "compass"}}), tmp_path)
    with pytest.raises(ValueError, match="min_altitude_m"):
        offline(scenario({"options": {"min_altitude_m": 100.0}}), tmp_path)


# -- velocities against the truth -----------------------------------------------------------------


@pytest.mark.parametrize("frame", ["ship", "instrument", "earth", "beam"])
def test_bottom_velocity_matches_truth_within_the_noise(tmp_path: Path, frame: str) -> None:
    em, truth, _ = offline(scenario({"options": {"frame": frame}}), tmp_path)
    times = ping_times(truth, em.rate_hz, 90.0)
    _, ens = run(em, times, reencode_every=10)
    assert len(ens) == 451
    exp = np.array([expected_velocity(frame, truth, t) for t in times])
    bt = np.array([e.bottom_track.velocity for e in ens])
    assert np.isfinite(bt).all(), "locked all the way at 12 m altitude"
    if frame == "beam":
        # a closing speed along each beam: positive toward the transducer in PD0 beam coordinates
        got = bt
        comps = 4
    else:
        # 0x0600 is the bottom relative to the instrument: the vehicle's velocity is its negation
        got = np.array([e.bottom_track.vehicle_velocity for e in ens])[:, :3]
        comps = 3
        err_v = bt[:, 3]
        check_noise(err_v, SIGMA_V, MM, f"{frame} error velocity")
    # every component varies by many sigmas, so a wrong sign or axis would show
    assert np.ptp(exp[:, :comps], axis=0).min() > 5 * SIGMA_V
    for i in range(comps):
        check_noise(got[:, i] - exp[:, i], SIGMA_V, MM, f"{frame} component {i + 1}")


def test_ship_frame_is_the_truths_sway_surge_and_heave(tmp_path: Path) -> None:
    em, truth, _ = offline(scenario({"noise": {"velocity_mps": 0.0}}), tmp_path)
    for t in (5.0, 31.2, 77.4, 110.0):
        v = pd0.decode(em.frame_at(t)).bottom_track.vehicle_velocity
        s = truth.at(t)
        np.testing.assert_allclose(v[:3], [s.v, s.u, -s.w], atol=0.6 * MM)
        assert v[3] == 0.0


def test_high_resolution_block_is_the_instrument_over_the_bottom(tmp_path: Path) -> None:
    em, truth, _ = offline(
        scenario({"options": {"frame": "instrument", "bt_high_res": True}}), tmp_path
    )
    times = ping_times(truth, em.rate_hz, 60.0)
    _, ens = run(em, times, reencode_every=10)
    hr = np.array([e.bt_high_res.vehicle_velocity for e in ens])
    bt = np.array([e.bottom_track.velocity for e in ens])
    np.testing.assert_allclose(hr, -bt, atol=0.5 * MM + 1e-9)  # the same ping, other sign
    exp = np.array([expected_velocity("instrument", truth, t) for t in times])
    for i in range(3):
        check_noise(hr[:, i] - exp[:, i], SIGMA_V, 1e-5, f"0x5803 axis {i + 1}")
    # distance made good: the velocities integrated ping by ping (0.01 mm resolution)
    dmg = np.array([e.bt_high_res.bt_distance for e in ens])
    np.testing.assert_allclose(np.diff(dmg, axis=0), hr[1:] * 0.2, atol=3e-5)


def test_noise_bursts_scale_the_noise(tmp_path: Path) -> None:
    faults = {"noise_burst_p": 0.3, "noise_burst_n": 100.0}
    em, truth, _ = offline(scenario({"options": {"frame": "earth"}, "faults": faults}), tmp_path)
    pings = [em.measure(float(t)) for t in ping_times(truth, em.rate_hz, 80.0)]
    burst = np.array([p.burst for p in pings])
    err = np.array([p.velocity[0] - expected_velocity("earth", truth, p.t)[0] for p in pings])
    assert 0.2 < burst.mean() < 0.4
    assert err[~burst].std() == pytest.approx(SIGMA_V, rel=0.2)
    assert err[burst].std() == pytest.approx(10 * SIGMA_V, rel=0.25)  # sqrt(100) x sigma


# -- ranges against the terrain -------------------------------------------------------------------


def test_beam_ranges_end_on_the_terrain(tmp_path: Path) -> None:
    """Each reported range, followed along its beam from the true pose, ends on the world's
    seabed (not on a flat seabed at the nadir depth)."""
    em, truth, world = offline(scenario({"noise": {"range_m": 0.0}}), tmp_path)
    times = ping_times(truth, em.rate_hz, 80.0)
    _, ens = run(em, times, reencode_every=10)
    off_flat = 0.0
    for t, e in zip(times, ens, strict=True):
        s = truth.at(float(t))
        rng = e.bottom_track.range
        assert np.isfinite(rng).all()
        dirs = BEAMS @ body_to_ned(s.heading, s.pitch, s.roll).T
        hits = np.array([s.x, s.y, s.z]) + (rng / C30)[:, None] * dirs
        seabed = world.terrain.depth(hits[:, 0], hits[:, 1])
        np.testing.assert_allclose(hits[:, 2], seabed, atol=0.012)
        off_flat = max(off_flat, float(np.max(np.abs(rng - s.altitude))))
    assert off_flat > 0.5, "the beams see relief, not the nadir altitude"


def plane_grid(tmp_path: Path, d0: float, gx: float, gy: float) -> dict[str, Any]:
    """A 2x2 depth grid whose bilinear interpolation is the plane d0 + gx x + gy y over
    [-200, 200] m in x and y."""
    x = np.array([-200.0, 200.0])
    grid = d0 + gx * x[:, None] + gy * x[None, :]
    np.save(tmp_path / "plane.npy", grid)
    return {"kind": "grid", "file": str(tmp_path / "plane.npy"), "cell_m": 400.0,
            "origin": [-200.0, -200.0]}


def test_ranges_match_the_analytic_geometry_over_a_sloping_seabed(tmp_path: Path) -> None:
    d0, gx, gy = 40.0, 0.08, -0.05
    scn = scenario(
        {"options": {"bt_range": True}},
        terrain=plane_grid(tmp_path, d0, gx, gy),
        vehicle={**BASE["vehicle"], "altitude_m": None, "depth_m": 8.0},
    )
    em, truth, _ = offline(scn, tmp_path)
    sigma_r = 0.01
    times = ping_times(truth, em.rate_hz, 80.0)
    _, ens = run(em, times, reencode_every=10)
    res = []
    for t, e in zip(times, ens, strict=True):
        s = truth.at(float(t))
        dirs = BEAMS @ body_to_ned(s.heading, s.pitch, s.roll).T
        seabed = d0 + gx * s.x + gy * s.y
        slant = (seabed - s.z) / (dirs[:, 2] - gx * dirs[:, 0] - gy * dirs[:, 1])
        res.append(e.bottom_track.range - slant * C30)
        br = e.bt_range
        np.testing.assert_allclose(br.raw_range, e.bottom_track.range, atol=0.0051)
        assert br.vertical_range == pytest.approx(s.altitude, abs=6 * sigma_r)
        r = br.raw_range
        assert br.slant_range == pytest.approx(r.mean(), abs=2e-4)
        assert br.axis_delta_range == pytest.approx((r[0] + r[1] - r[2] - r[3]) / 2, abs=2e-4)
        assert (br.percent_good_4beam, br.percent_good_beams12, br.percent_good_beams34) == (
            100, 100, 100,
        )
    res = np.array(res)
    for i in range(4):
        check_noise(res[:, i], sigma_r, 0.01, f"range beam {i + 1}")


# -- bottom lock ----------------------------------------------------------------------------------


def valley_and_shoal(tmp_path: Path) -> dict[str, Any]:
    """Seabed along x (constant across): 60 m, a V valley to 120 m, 60 m, a shoal at 5.1 m."""
    knots_x = [0, 150, 300, 450, 600, 680, 760, 840, 1100]
    knots_d = [60, 60, 120, 60, 60, 5.1, 5.1, 60, 60]
    x = np.arange(0, 1101, 10.0)
    profile = np.interp(x, knots_x, knots_d)
    np.save(tmp_path / "valley.npy", np.repeat(profile[:, None], 2, axis=1))
    return {"kind": "grid", "file": str(tmp_path / "valley.npy"), "cell_m": 10.0,
            "origin": [0.0, -200.0]}


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index intervals where ``mask`` is true."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def test_bottom_lock_is_lost_and_regained_where_the_terrain_says(tmp_path: Path) -> None:
    """Straight and level at 5 m depth over a valley (altitude up to 115 m) and a shoal
    (altitude 0.1 m): no lock exactly while the altitude is outside [0.2, 89] m."""
    scn = scenario(
        {"rate_hz": 2.0},
        duration_s=None,
        terrain=valley_and_shoal(tmp_path),
        vehicle={"waypoints": [[0, 0], [1000, 0]], "speed_mps": 4.0, "depth_m": 5.0},
    )
    em, truth, _ = offline(scn, tmp_path)
    times = ping_times(truth, 2.0)
    _, ens = run(em, times, reencode_every=10)
    alt = np.array([truth.at(float(t)).altitude for t in times])
    expect = (alt >= 0.2) & (alt <= 89.0)
    lock = np.array([np.isfinite(e.bottom_track.velocity[:3]).all() for e in ens])
    # two losses (valley, shoal), each regained
    assert len(runs(~expect)) == 2 and len(runs(~lock)) == 2
    assert lock[0] and lock[-1]
    changes = np.flatnonzero(np.diff(expect.astype(int))) + 0.5  # between pings
    for i in np.flatnonzero(lock != expect):
        assert np.min(np.abs(changes - i)) <= 1.0, f"ping {i} at t={times[i]}: within one ping"
    for e, ok, a in zip(ens, lock, alt, strict=True):
        bt = e.bottom_track
        vel_raw = raw_value(bt, "velocity")
        rng_raw = raw_value(bt, "range_lsb")
        if ok:
            assert (vel_raw[:3] != -32768).all()
            # beams 1 and 2 look across a seabed that is constant across: they see the altitude
            np.testing.assert_allclose(bt.range[:2], a, atol=0.06)
        else:
            assert (vel_raw == -32768).all(), "no lock: the four velocities are bad"
            assert (rng_raw[:2] == 0).all(), "beams 1 and 2 do not see the bottom"
            # beam 3 or 4 may still see a slope within range: never more than two beams
            assert np.count_nonzero(rng_raw) <= 2


def test_bottom_lock_loss_fault_window(tmp_path: Path) -> None:
    faults = {"bottom_lock_loss": [[10.0, 20.0], [40.0, 41.0]]}
    scn = scenario({"options": {"bt_high_res": True, "bt_range": True}, "faults": faults})
    em, truth, _ = offline(scn, tmp_path)
    times = ping_times(truth, em.rate_hz, 60.0)
    _, ens = run(em, times)
    in_window = ((times >= 10.0) & (times < 20.0)) | ((times >= 40.0) & (times < 41.0))
    assert in_window.sum() == 50 + 5
    for t, lost, e in zip(times, in_window, ens, strict=True):
        bt, hr, br = e.bottom_track, e.bt_high_res, e.bt_range
        if lost:
            assert (raw_value(bt, "velocity") == -32768).all(), t
            assert (raw_value(bt, "range_lsb") == 0).all()
            assert (raw_value(bt, "range_msb") == 0).all()
            assert (bt.percent_good == 0).all() and (bt.correlation == 0).all()
            assert (raw_value(hr, "bt_velocity") == -(2**31)).all()
            assert raw_value(br, "vertical_range") == 0 and (raw_value(br, "raw_range") == 0).all()
        else:
            assert np.isfinite(bt.velocity).all() and np.isfinite(bt.range).all(), t
            assert (bt.percent_good == 100).all()
            assert np.isfinite(hr.bt_velocity).all() and br.vertical_range > 5.0
    # the distance made good holds while there is no lock
    dmg = np.array([e.bt_high_res.bt_distance for e in ens])
    lost_idx = np.flatnonzero(in_window)
    np.testing.assert_array_equal(dmg[lost_idx], dmg[lost_idx - 1])


def test_three_beam_solution_when_one_beam_is_beyond_range(tmp_path: Path) -> None:
    """Over a steep slope at high altitude the downslope beam is beyond 89 m: three beams,
    the velocity still good and its error velocity 0 (the Pathfinder stops computing it)."""
    scn = scenario(
        {"options": {"frame": "instrument"}},
        terrain=plane_grid(tmp_path, 88.0, 0.2, 0.0),
        vehicle={"waypoints": [[0, 0], [10, 0]], "speed_mps": 1.0, "depth_m": 5.0,
                 "accept_radius_m": 1.0},
    )
    em, truth, _ = offline(scn, tmp_path)
    e = pd0.decode(em.frame_at(2.0))
    bt = e.bottom_track
    alt = truth.at(2.0).altitude
    assert 83.0 < alt < 89.0
    assert math.isnan(bt.range[2]) and np.isfinite(bt.range[[0, 1, 3]]).all()  # beam 3 forward
    assert np.isfinite(bt.velocity).all() and bt.velocity[3] == 0.0
    exp = expected_velocity("instrument", truth, 2.0)
    np.testing.assert_allclose(bt.vehicle_velocity[:3], exp, atol=5 * SIGMA_V)
    em2, _, _ = offline(
        scenario({"options": {"frame": "instrument", "three_beam": False}},
                 terrain=scn.terrain.model_dump(), vehicle=scn.vehicle.model_dump()),
        tmp_path,
    )
    assert np.isnan(pd0.decode(em2.frame_at(2.0)).bottom_track.velocity).all()


# -- leaders: ensemble numbers, clock, depth ------------------------------------------------------


def test_ensemble_numbers_clock_jumps_and_depth(tmp_path: Path) -> None:
    scn = scenario({"faults": {"clock_jumps": [[30.0, 2.5]]}, "options": {"frame": "earth"}})
    em, truth, _ = offline(scn, tmp_path)
    times = ping_times(truth, em.rate_hz, 60.0)
    _, ens = run(em, times)
    assert [e.variable_leader.ensemble for e in ens] == list(range(1, len(times) + 1))
    for t, e in zip(times, ens, strict=True):
        vl = e.variable_leader
        jump = 2.5 if t >= 30.0 else 0.0
        assert vl.device_time_s == pytest.approx(DEFAULT_EPOCH + t + jump, abs=0.006)
        s = truth.at(float(t))
        assert vl.depth == pytest.approx(s.z, abs=0.05 + 5 * 0.02)  # decimetres
        assert vl.pressure == pytest.approx(1025 * 9.80665 * s.z, abs=10 + 5 * 0.02 * 1e4)
        assert abs((vl.heading - s.heading + math.pi) % (2 * math.pi) - math.pi) < 1e-4
        assert vl.pitch == pytest.approx(s.pitch, abs=1e-4)
        assert vl.roll == pytest.approx(s.roll, abs=1e-4)
    assert ens[0].device_time == dt.datetime(2024, 6, 1, 8, 0, 0, tzinfo=dt.UTC)


def test_ensemble_number_carries_into_the_msb_byte(tmp_path: Path) -> None:
    em, _, _ = offline(scenario(), tmp_path)
    em.ensemble_number = 65535
    a, b = (pd0.decode(em.frame_at(t)).variable_leader for t in (1.0, 1.2))
    assert (a.ensemble_number, a.ensemble_number_msb, a.ensemble) == (65535, 0, 65535)
    assert (b.ensemble_number, b.ensemble_number_msb, b.ensemble) == (0, 1, 65536)


# -- water: profile cells and the water-mass layer -------------------------------------------------


def test_water_cells_and_water_mass_layer(tmp_path: Path) -> None:
    """The water relative to the instrument is the current minus the vehicle's velocity over
    ground; cells beyond 85 % of the bottom range are bad."""
    opts = {"frame": "earth", "cells": 12, "water_mass": True, "wm_min_m": 1.0,
            "wm_near_m": 2.0, "wm_far_m": 5.0, "bt_high_res": True}
    em, truth, _ = offline(scenario({"options": opts}), tmp_path)
    times = ping_times(truth, em.rate_hz, 40.0)
    _, ens = run(em, times)
    cn, ce = BASE["vehicle"]["current_mps"]
    errs, wm_errs = [], []
    for t, e in zip(times, ens, strict=True):
        s = truth.at(float(t))
        water_rel = np.array([ce - s.ve, cn - s.vn, s.vd])  # east, north, up (no vertical current)
        fl = e.fixed_leader
        assert fl.n_cells == 12 and fl.pings_per_ensemble == 1
        assert fl.bin1_distance == pytest.approx(0.88 + 1.0)
        v = e.velocity.velocity
        centres = 0.88 + np.arange(1, 13) * 1.0
        cutoff = 0.85 * np.nanmin(e.bottom_track.range)
        assert np.isfinite(v[centres <= cutoff - 0.05]).all()
        assert np.isnan(v[centres > cutoff + 0.05]).all()
        good = np.isfinite(v[:, 0])
        errs.append(v[good, :3] - water_rel)
        assert (e.percent_good.percent_good[good, 3] == 100).all()
        assert (e.percent_good.percent_good[~good, 2] == 100).all()
        # the water-mass layer: 0x0600 water relative to the instrument, 0x5803 the other way
        wm_errs.append(e.bottom_track.ref_velocity[:3] - water_rel)
        np.testing.assert_allclose(e.bt_high_res.wm_velocity, -e.bottom_track.ref_velocity,
                                   atol=0.5 * MM + 1e-9)
    errs = np.concatenate(errs)
    for i in range(3):
        check_noise(errs[:, i], 0.005, MM, f"water cell component {i + 1}")
        check_noise(np.array(wm_errs)[:, i], 0.005, MM, f"water mass component {i + 1}")


def test_water_mass_layer_is_bad_when_the_bottom_is_too_close(tmp_path: Path) -> None:
    # the default layer (BL80,160,240 dm) needs more than 24 / 0.85 m below the DVL
    em, _, _ = offline(scenario({"options": {"water_mass": True}}), tmp_path)  # at 12 m
    bt = pd0.decode(em.frame_at(5.0)).bottom_track
    assert np.isnan(bt.ref_velocity).all() and (bt.ref_percent_good == 0).all()
    assert np.isfinite(bt.velocity).all()


# -- over a real pty ----------------------------------------------------------------------------


@pytest.mark.e2e
def test_runner_serves_the_dvl_on_a_pty(tmp_path: Path) -> None:
    """The runner's DVL on its pty, read with pyserial at 20x real time: every ensemble arrives
    in order but those the port counted lost (a reader thread starved past its block timeout,
    as test_emulators' INS test lost them beside two burners), the velocity matches the truth
    within the noise, lock follows the fault window."""
    scn = scenario({"options": {"serial": True}, "faults": {"bottom_lock_loss": [[8.0, 12.0]]}})
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=20, devices=["dvl"])) as r:
        assert "dvl" in r.emulators, r.unavailable
        (ep,) = r.endpoints()
        assert ep.name == "dvl" and ep.format == "pd0" and Path(ep.target).is_symlink()
        assert ep.transport == {"kind": "serial", "url": ep.target, "baud": 115200}
        reader = SerialReader(ep.target, 115200)
        r.start(duration=20.0)
        assert r.wait(60), "the run did not end"
        r.stop()
        r.flush()
        data = reader.finish()
        em = r.emulators["dvl"]
        config = r.gateway_config()
        toml = r.write_gateway_config(tmp_path / "gateway.toml").read_text()  # validated
    assert config["devices"]["dvl"]["format"] == "pd0" and "[devices.dvl]" in toml
    framer = pd0.Pd0Framer(policy=ErrorPolicy.IGNORE)
    frames = [f.data for f in framer.feed(data)]
    port = em.serial.port.stats
    dropped = port.writes_lost
    assert em.ticks == 101 and len(frames) == em.ticks - dropped, "every ensemble not counted lost"
    assert dropped <= em.ticks // 2 and framer.stats.bad_frames <= port.writes_cut
    ens = pd0.decode_many(frames)
    assert [pd0.encode(e) for e in ens] == frames
    numbers = [e.variable_leader.ensemble for e in ens]
    assert numbers == sorted(set(numbers)) and set(numbers) <= set(range(1, 102))
    errs = []
    for e in ens:
        t = (e.variable_leader.ensemble - 1) * em.period
        assert e.variable_leader.device_time_s == pytest.approx(DEFAULT_EPOCH + t, abs=0.006)
        lost = 8.0 <= t < 12.0
        assert np.isnan(e.bottom_track.velocity).all() == lost, t
        if not lost:
            exp = expected_velocity("ship", em.ctx.truth, t)
            errs.append(e.bottom_track.vehicle_velocity[:3] - exp)
    errs = np.array(errs)
    unlocked = len(ens) - len(errs)  # 20 ensembles in the window, 81 outside, all there or not
    assert unlocked <= 20 and len(errs) <= 81 and (dropped or (len(errs), unlocked) == (81, 20))
    assert np.abs(errs).max() < 5 * SIGMA_V + MM
    assert np.abs(errs.mean(axis=0)).max() < 5 * SIGMA_V / math.sqrt(len(errs)) + MM / 2
    assert json.dumps(em.stats())  # counters are plain JSON


# -- instrument errors: scale factor and misalignment ---------------------------------------------


@pytest.mark.parametrize("frame", ["ship", "instrument", "earth", "beam"])
def test_scale_factor_and_misalignment_reach_every_frame(tmp_path: Path, frame: str) -> None:
    """1 % scale factor and 2 deg misalignment, no white noise: every frame reports the body
    velocity scaled by 1.01 and turned 2 deg clockwise (to starboard), within the wire's mm."""
    noise = {"velocity_mps": 0.0, "scale_factor_pct": 1.0, "misalignment_deg": 2.0}
    em, truth, _ = offline(scenario({"options": {"frame": frame}, "noise": noise}), tmp_path)
    a = math.radians(2.0)
    turn = 1.01 * np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                            [0.0, 0.0, 1.0]])  # fmt: skip
    got, exp = [], []
    for t in np.arange(2.0, 110.0, 3.7):
        s = truth.at(float(t))
        rot = body_to_ned(s.heading, s.pitch, s.roll)
        body = turn @ rot.T @ np.array([s.vn, s.ve, s.vd])  # the measured body velocity
        if frame == "beam":
            exp.append(BEAMS @ body)
            got.append(pd0.decode(em.frame_at(float(t))).bottom_track.velocity)
            continue
        if frame == "earth":
            v = rot @ body
            exp.append([v[1], v[0], -v[2]])
        elif frame == "ship":  # levelled body axes: starboard, forward, up
            lev = body_to_ned(0.0, s.pitch, s.roll) @ body
            exp.append([lev[1], lev[0], -lev[2]])
        else:
            exp.append([body[1], body[0], -body[2]])
        got.append(pd0.decode(em.frame_at(float(t))).bottom_track.vehicle_velocity[:3])
    got, exp = np.array(got), np.array(exp)
    np.testing.assert_allclose(got, exp, atol=0.6 * MM)
    if frame == "earth":  # over ground: 1 % faster and 2 deg to starboard of the truth
        tv = np.array([[truth.at(float(t)).ve, truth.at(float(t)).vn]
                       for t in np.arange(2.0, 110.0, 3.7)])  # fmt: skip
        ratio = np.hypot(got[:, 0], got[:, 1]) / np.hypot(tv[:, 0], tv[:, 1])
        np.testing.assert_allclose(ratio, 1.01, atol=2e-3)
        turned = np.arctan2(got[:, 0], got[:, 1]) - np.arctan2(tv[:, 0], tv[:, 1])
        np.testing.assert_allclose(np.degrees((turned + np.pi) % (2 * np.pi) - np.pi), 2.0,
                                   atol=0.1)  # fmt: skip


def test_instrument_errors_are_off_by_default_and_checked(tmp_path: Path) -> None:
    em, _, _ = offline(scenario(), tmp_path)
    assert em.instrument_error is None
    with pytest.raises(ValueError, match=r"devices\.dvl\.noise\.scale_factor_pct"):
        offline(scenario({"noise": {"scale_factor_pct": 80.0}}), tmp_path)
    with pytest.raises(ValueError, match=r"devices\.dvl\.noise\.scale_factor.*scale_factor_pct"):
        offline(scenario({"noise": {"scale_factor": 0.003}}), tmp_path)
