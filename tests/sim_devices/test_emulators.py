"""Device emulators on their virtual ports, read with the real client libraries (pyserial,
python-can slcan, a UDP socket), decoded with the drivers and compared with the ground truth."""

from __future__ import annotations

import copy
import json
import math
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from auvgw.config.gateway import load_gateway_config
from auvgw.config.scenario import Scenario
from auvgw.drivers import hn100, kongsberg, ms3a
from auvgw.drivers import seanet as sn
from auvgw.drivers.can_codec import hn100_can, ms3a_can
from auvgw.drivers.framing import ErrorPolicy
from auvgw.sim_devices.emulator import DEFAULT_EPOCH
from auvgw.sim_devices.ins import body_rates, latlon, specific_force
from auvgw.sim_devices.runner import Runner, RunOptions, gateway_toml
from auvgw.sim_devices.vehicle import MOTION_FIELDS, TRUTH_FIELDS
from auvgw.sim_devices.world import MU0_OVER_4PI, body_to_ned, wrap_angle
from auvgw.testing.emulators import SerialReader, endpoint, run_for

BASE: dict[str, Any] = {
    "name": "emu-test",
    "seed": 17,
    "vehicle": {
        "waypoints": [[0, 0], [15, 0], [15, 30], [0, 30], [0, 0]],
        "speed_mps": 1.5,
        "depth_m": 6.0,
        "max_yaw_rate_dps": 12.0,
        "accept_radius_m": 3.0,
        "lookahead_m": 6.0,
    },
    "terrain": {"kind": "procedural", "depth_m": 30.0, "relief_m": 4.0, "wavelength_m": 40.0,
                "octaves": 2, "seed": 4},
    "earth_field_nt": [20000.0, 500.0, 45000.0],
    "magnetic_beacons": [
        {"x": 20, "y": 5, "z": 30, "moment_am2": 20000.0},
        {"x": 35, "y": 25, "z": 30, "moment_am2": 8000.0, "frequency_hz": 1.3,
         "axis": [1.0, 0.0, 1.0]},
    ],
}


def make_scenario(**changes: Any) -> Scenario:
    """BASE with top-level keys replaced and ``devices`` merged per device."""
    data = copy.deepcopy(BASE)
    for k, v in changes.items():
        data[k] = v
    return Scenario.model_validate(data)


class CanReader:
    """python-can's slcan interface on the emulated adapter, in a thread."""

    def __init__(self, path: str, bitrate: int) -> None:
        self.bus = can.Bus(interface="slcan", channel=path, bitrate=bitrate, sleep_after_open=0)
        self.messages: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.02)
            if msg is not None:
                self.messages.append(msg)

    def finish(self, quiet: float = 1.0, timeout: float = 15.0) -> list[can.Message]:
        end = time.monotonic() + timeout
        n = -1
        while time.monotonic() < end:
            if len(self.messages) == n:
                break
            n = len(self.messages)
            time.sleep(quiet)
        self._stop.set()
        self._thread.join(5)
        self.bus.shutdown()
        return self.messages


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


# -- ground truth sampling ---------------------------------------------------------------------


def test_truth_at_matches_a_reference_interpolation(tmp_path: Path) -> None:
    r = Runner(make_scenario(), RunOptions(out_dir=tmp_path, devices=[]))
    truth = r.truth
    assert r.ctx.sampler is truth
    ts = np.random.default_rng(1).uniform(-1.0, truth.duration + 1.0, 300)
    ts = np.concatenate([ts, truth.t[[0, 1, len(truth) // 2, -1]]])
    for t in ts:
        s = truth.at(float(t))
        assert s.t == t
        for f in TRUTH_FIELDS[1:]:
            a = getattr(truth, f)
            if t > truth.t[-1] and f in MOTION_FIELDS:  # after the route the vehicle rests
                assert getattr(s, f) == 0.0, f
            elif f in ("heading", "roll", "pitch", "steer"):  # the short way round
                ref = np.interp(t, truth.t, np.unwrap(a))
                assert abs(wrap_angle(getattr(s, f) - ref)) < 1e-9, f
                assert -math.pi <= getattr(s, f) < math.pi
            else:
                assert getattr(s, f) == pytest.approx(np.interp(t, truth.t, a), abs=1e-9), f
    assert truth.at(-3.0).x == truth.x[0] and truth.at(1e9).y == truth.y[-1]
    many = truth.interp(ts)
    for k in (0, 100, 303):
        assert many.x[k] == pytest.approx(truth.at(float(ts[k])).x, abs=1e-9)
        assert abs(wrap_angle(many.heading[k] - truth.at(float(ts[k])).heading)) < 1e-9
    r.close()


# -- INS ---------------------------------------------------------------------------------------


@pytest.mark.e2e
def test_ins_serial_frames_match_the_truth_within_the_seed_noise(tmp_path: Path) -> None:
    scn = make_scenario(devices={"ins": {"options": {"can": False}}})
    # 4x, not 20x: at 20x the pty carries 230 kB/s. A reader thread starved past the port's
    # block timeout (the pty full) loses writes, as a UART overruns, and the port counts them:
    # two workers beside two burners cut a frame at 20x (s41) and at 4x (s42), and in another
    # run lost 439 of 2001 writes (the reader, the emulator and pytest share one interpreter).
    # So every frame arrives but the ones the port counted lost, and at least half arrive (the
    # noise figures below hold to 3.6 sigma on 1,000 frames)
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=4, devices=["ins"])) as r:
        ep = endpoint(r, "ins")
        assert ep.format == "hn100" and Path(ep.target).is_symlink()
        reader = SerialReader(ep.target, 115200)
        run_for(r, 20.0)
        data = reader.finish()
        em = r.emulators["ins"]
        framer = hn100.Hn100Framer(policy=ErrorPolicy.IGNORE)
        msgs = [hn100.CODEC.decode(f.data) for f in framer.frames([data])]
        port = em.serial.port.stats
        lost = port.writes_lost
        assert em.ticks == 2001 and len(msgs) == em.ticks - lost, "every frame not counted lost"
        assert lost <= em.ticks // 2 and framer.stats.bad_frames <= port.writes_cut
        seqs = [m.seq for m in msgs]
        assert seqs == sorted(set(seqs)) and set(seqs) <= set(range(em.ticks))
        lat0, lon0 = em.origin
        err: dict[str, list[float]] = {k: [] for k in ("h", "r", "p", "w", "a", "v", "x", "z")}
        for m in msgs:
            t = m.seq * em.period
            assert m.time == pytest.approx(t, abs=1e-4)
            s = r.truth.at(t)
            assert m.aligned and m.dvl_aided and not m.error
            err["h"].append(math.degrees(wrap_angle(m.heading - s.heading)))
            err["r"].append(math.degrees(m.roll - s.roll))
            err["p"].append(math.degrees(m.pitch - s.pitch))
            err["w"] += list(np.degrees(m.rates - body_rates(s)))
            err["a"] += list(m.accel - specific_force(s))
            err["v"] += list(m.vel_ned - np.array([s.vn, s.ve, s.vd]))
            lat_t, lon_t = latlon(s.x, s.y, lat0, lon0)
            err["x"] += [(m.latitude - lat_t) / (lat_t - latlon(s.x - 1, s.y, lat0, lon0)[0]),
                         (m.longitude - lon_t) / (lon_t - latlon(s.x, s.y - 1, lat0, lon0)[1])]
            err["z"].append(m.depth - s.z)
        e = {k: np.asarray(v) for k, v in err.items()}
        n = len(msgs)
        # heading 0.3 deg RMS, roll/pitch 0.02 deg RMS (the seed's figures), unbiased
        assert abs(e["h"].mean()) < 3 * 0.3 / math.sqrt(n)
        assert rms(e["h"]) == pytest.approx(0.3, rel=0.08)
        assert rms(e["r"]) == pytest.approx(0.02, rel=0.08)
        assert rms(e["p"]) == pytest.approx(0.02, rel=0.08)
        assert abs(e["r"].mean()) < 3 * 0.02 / math.sqrt(n)
        assert rms(e["w"]) == pytest.approx(0.05, rel=0.08)
        assert rms(e["a"]) == pytest.approx(0.01, rel=0.08)
        assert rms(e["v"]) == pytest.approx(0.01, rel=0.08)
        assert rms(e["x"]) == pytest.approx(0.5, rel=0.08)
        assert rms(e["z"]) == pytest.approx(0.02, rel=0.08)
        # the route turns: real rates, and gravity on the accelerometers
        assert max(abs(m.rate_z) for m in msgs) > math.radians(5)
        assert np.mean([m.accel_z for m in msgs]) == pytest.approx(-9.80665, abs=0.01)
        assert r.emulators["ins"].errors == 0


@pytest.mark.e2e
def test_ins_can_bursts_through_python_can_slcan_with_exact_dropouts(tmp_path: Path) -> None:
    scn = make_scenario(
        devices={"ins": {"options": {"serial": False}, "faults": {"dropout_p": 0.1}}}
    )
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=2, devices=["ins"])) as r:
        ep = endpoint(r, "ins_can")
        assert ep.kind == "can" and ep.transport["interface"] == "slcan"
        reader = CanReader(ep.target, ep.transport["bitrate"])
        run_for(r, 4.0)
        messages = reader.finish()
        codec = hn100_can()
        asm = codec.assembler()
        samples = [s for m in messages if (s := asm.add(codec.decode_frame(m))) is not None]
        ch = r.emulators["ins"].channels[0]
        counts = ch.injector.counts
        assert counts.frames_in == 401 and counts.dropped > 10
        assert len(samples) == counts.frames_sent == 401 - counts.dropped
        assert len(messages) == 8 * len(samples) and asm.dropped == 0
        assert all(m.is_extended_id for m in messages)
        period = r.emulators["ins"].period
        herr, rerr = [], []
        for s in samples:
            t = s.time  # device clock = vehicle time (no clock jumps)
            k = round(t / period)
            assert t == pytest.approx(k * period, abs=1e-6) and s.seq == k & 0xFF
            tr = r.truth.at(k * period)
            herr.append(math.degrees(wrap_angle(s.heading - tr.heading)))
            rerr.append(math.degrees(s.roll - tr.roll))
            assert s.alignment == "FINE" and s.error == "OK" and s.dvl_aided == 1
        assert rms(np.array(herr)) == pytest.approx(0.3, rel=0.15)
        # CAN carries roll in 1e-4 rad steps: 0.02 deg noise plus rounding (0.0033 deg RMS)
        assert rms(np.array(rerr)) == pytest.approx(math.hypot(0.02, 0.0033), rel=0.15)
        assert ch.adapter.stats.dropped_closed == 0 and ch.adapter.stats.dropped_port == 0


# -- magnetometer ------------------------------------------------------------------------------


def _expected_mag(r: Runner, t: float) -> np.ndarray:
    s = r.truth.at(t)
    b = r.world.magnetic_field(np.array([s.x, s.y, s.z]), t)
    return body_to_ned(s.heading, s.pitch, s.roll).T @ b * 1e9


@pytest.mark.e2e
def test_magnetometer_serial_and_can_report_the_world_field(tmp_path: Path) -> None:
    scn = make_scenario(devices={"magnetometer": {"noise": {"field_nt": 2.0}}})
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=10, devices=["magnetometer"])) as r:
        em = r.emulators["magnetometer"]
        line = SerialReader(endpoint(r, "magnetometer").target, 38400)
        ep_can = endpoint(r, "magnetometer_can")
        bus = CanReader(ep_can.target, ep_can.transport["bitrate"])
        run_for(r, 15.0)
        lines = [ms3a.CODEC.decode(f.data) for f in ms3a.Ms3aFramer().frames([line.finish()])]
        codec = ms3a_can()
        asm = codec.assembler()
        frames = bus.finish()
        cans = [s for m in frames if (s := asm.add(codec.decode_frame(m))) is not None]
        assert len(lines) == len(cans) == em.ticks == 301
        assert [m.counter for m in lines] == list(range(301))
        assert [s.counter for s in cans] == list(range(301))
        err_line, err_can = [], []
        for m, c in zip(lines, cans, strict=True):
            exp = _expected_mag(r, m.counter * em.period)
            err_line += list(m.b_nt - exp)
            err_can += list(np.array([c.bx, c.by, c.bz]) - exp)
            assert c.status == "OK"
            assert np.allclose([c.bx, c.by, c.bz], m.b_nt, atol=0.051)  # one sample, two wires
        assert rms(np.array(err_line)) == pytest.approx(2.0, rel=0.12)
        assert abs(np.mean(err_line)) < 3 * 2.0 / math.sqrt(len(err_line))
        # the beacons matter here: the field is not the Earth field rotated
        earth = [np.linalg.norm(r.world.earth_field) * 1e9] * len(lines)
        assert np.max(np.abs(np.linalg.norm([m.b_nt for m in lines], axis=1) - earth)) > 50


@pytest.mark.e2e
def test_magnetometer_field_falls_with_the_cube_of_the_range_to_a_beacon(tmp_path: Path) -> None:
    # one strong coil, no Earth field; the AUV drives straight away along the coil's axis
    scn = make_scenario(
        vehicle={"waypoints": [[10, 0], [70, 0]], "speed_mps": 2.0, "depth_m": 5.0},
        earth_field_nt=[0.0, 0.0, 0.0],
        magnetic_beacons=[{"x": 0, "y": 0, "z": 5, "moment_am2": 1e5, "axis": [1, 0, 0]}],
        devices={"magnetometer": {"options": {"can": False}}},
    )
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=20, devices=["magnetometer"])) as r:
        em = r.emulators["magnetometer"]
        reader = SerialReader(endpoint(r, "magnetometer").target, 38400)
        run_for(r, 25.0)
        msgs = [ms3a.CODEC.decode(f.data) for f in ms3a.Ms3aFramer().frames([reader.finish()])]
        port = em.serial.port.stats
    # every sample but those the port counted lost to a starved reader (the INS test's)
    dropped = port.writes_lost
    assert len(msgs) == em.ticks - dropped and dropped <= em.ticks // 2
    rng_m, mag = [], []
    for m in msgs:
        s = r.truth.at(m.counter * em.period)
        rng_m.append(math.dist((s.x, s.y, s.z), (0.0, 0.0, 5.0)))
        mag.append(float(np.linalg.norm(m.b_nt)))
        # on the axis the dipole field is along the axis: body x (the AUV heads north)
        assert abs(m.by) < 6 and abs(m.bz) < 6
    rng_m, mag = np.array(rng_m), np.array(mag)
    assert rng_m.min() < 12 and rng_m.max() > 55
    slope = np.polyfit(np.log(rng_m), np.log(mag), 1)[0]
    assert slope == pytest.approx(-3.0, abs=0.01)
    # two distances: |B| ratio is the cube of the range ratio, and the on-axis magnitude
    i, j = int(np.argmin(abs(rng_m - 15))), int(np.argmin(abs(rng_m - 30)))
    assert mag[i] / mag[j] == pytest.approx((rng_m[j] / rng_m[i]) ** 3, rel=0.01)
    assert mag[i] == pytest.approx(2 * MU0_OVER_4PI * 1e5 / rng_m[i] ** 3 * 1e9, rel=0.005)


# -- multibeam ---------------------------------------------------------------------------------


def _bind_udp() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    return sock


def _drain_udp(sock: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(sock.recv(1 << 16))
        except TimeoutError:
            return out


def test_multibeam_xyz88_over_udp_follows_the_terrain(tmp_path: Path) -> None:
    sock = _bind_udp()
    port = sock.getsockname()[1]
    scn = make_scenario(devices={"multibeam": {"options": {"udp_port": port, "n_beams": 128}}})
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=20, devices=["multibeam"])) as r:
        ep = endpoint(r, "multibeam")
        assert ep.transport == {"kind": "udp", "host": "127.0.0.1", "port": port}
        run_for(r, 12.0)
        datagrams = _drain_udp(sock)
    sock.close()
    em = r.emulators["multibeam"]
    assert len(datagrams) == em.ticks == 61
    pings = [kongsberg.decode(d)[0] for d in datagrams]
    z_norm, widths = [], []
    for k, p in enumerate(pings):
        assert isinstance(p, kongsberg.XYZ88) and p.counter == k and p.n_beams == 128
        t = p.device_time - DEFAULT_EPOCH
        assert t == pytest.approx(k * em.period, abs=1e-3)
        s = r.truth.at(t)
        assert p.transducer_depth == pytest.approx(s.z, abs=1e-5)
        assert p.sound_speed == pytest.approx(1500.0)
        b = p.beams
        ok = b.valid
        assert ok.sum() == p.n_valid > 100
        ch, sh = math.cos(s.heading), math.sin(s.heading)
        x = s.x + b.along[ok] * ch - b.across[ok] * sh
        y = s.y + b.along[ok] * sh + b.across[ok] * ch
        truth_depth = r.world.depth(x, y) - s.z
        slant = np.sqrt(b.depth[ok] ** 2 + b.across[ok] ** 2 + b.along[ok] ** 2)
        sd = np.hypot(0.05, 0.002 * slant)
        z_norm += list((b.depth[ok] - truth_depth) / sd)
        assert np.all(b.across[ok][:-1] <= b.across[ok][1:] + 1e-3), "port to starboard"
        widths.append((b.across[ok].max() - b.across[ok].min()) / (s.altitude))
    z_norm = np.asarray(z_norm)
    assert abs(z_norm.mean()) < 0.05 and z_norm.std() == pytest.approx(1.0, rel=0.05)
    # GeoSwath-like: the swath reaches about 12x the altitude (6x each side) on this relief
    assert 9.0 < float(np.median(widths)) < 14.0


# -- faults ------------------------------------------------------------------------------------

FAULTS = {"garbage_p": 0.2, "garbage_max_bytes": 40, "corrupt_p": 0.06, "truncate_p": 0.05,
          "dropout_p": 0.03}  # fmt: skip


@pytest.mark.e2e
def test_garbage_and_corruption_are_counted_exactly_and_lose_no_good_frame(tmp_path: Path):
    sock = _bind_udp()
    scn = make_scenario(
        devices={
            "ins": {"options": {"can": False}, "faults": FAULTS},
            "magnetometer": {"options": {"can": False}, "faults": FAULTS},
            "multibeam": {"options": {"udp_port": sock.getsockname()[1], "n_beams": 64},
                          "faults": FAULTS},
        }
    )
    # 2x, not 10x: at 10x the INS pty carries 115 kB/s, and a reader thread starved for a few
    # tenths of a second (two test workers beside two burners, s41) lost 404 of 1,038 frames
    options = RunOptions(out_dir=tmp_path, speed=2, devices=["ins", "magnetometer", "multibeam"])
    with Runner(scn, options) as r:
        readers = {
            "ins": SerialReader(endpoint(r, "ins").target, 115200),
            "magnetometer": SerialReader(endpoint(r, "magnetometer").target, 38400),
        }
        run_for(r, 12.0)
        wire = {name: rd.finish() for name, rd in readers.items()}
        wire["multibeam"] = b"".join(_drain_udp(sock))
        framers = {
            "ins": (hn100.Hn100Framer, hn100.CODEC.decode, "seq"),
            "magnetometer": (ms3a.Ms3aFramer, ms3a.CODEC.decode, "counter"),
            "multibeam": (kongsberg.KongsbergFramer, lambda d: kongsberg.decode(d)[0], "counter"),
        }
        for name, (framer_cls, decode, key) in framers.items():
            em = r.emulators[name]
            ch = em.channels[0]
            c = ch.injector.counts
            assert c.corrupted and c.truncated and c.garbage_events and c.dropped
            assert c.unverified == 0 and c.pending == 0
            assert c.frames_sent + c.dropped + c.corrupted + c.truncated + c.downgraded == em.ticks
            f = framer_cls(policy=ErrorPolicy.IGNORE)
            frames = list(f.frames([wire[name][i : i + 97] for i in range(0, len(wire[name]), 97)]))
            got = [getattr(decode(fr.data), key) for fr in frames]
            assert len(frames) == c.frames_sent, f"{name}: no good frame lost or invented"
            assert f.stats.bad_frames == c.bad_frames, name
            assert f.stats.skipped_bytes == c.skipped_bytes, name
            assert got == sorted(set(got)) and got[-1] <= em.ticks - 1
            assert ch.port_stats()["bytes_dropped"] == 0
    sock.close()


@pytest.mark.e2e
def test_unplug_stall_and_clock_jump_windows(tmp_path: Path) -> None:
    faults = {"unplug": [[1.0, 1.5]], "stall": [[2.5, 3.0]], "clock_jumps": [[3.2, 100.0]]}
    scn = make_scenario(devices={"ins": {"options": {"can": False}, "faults": faults}})
    # 2x, not 10x: the unplug closes the pty with what the reader has not read yet, and at 10x
    # the 100 frames before it are 0.1 wall s, which a starved reader thread missed whole
    # (the suite on two workers beside two burners: no frame below seq 100)
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=2, devices=["ins"])) as r:
        ep = endpoint(r, "ins")
        first_pty = ep.path
        reader = SerialReader(ep.target, 115200, reconnect=True)
        run_for(r, 4.0)
        data = reader.finish()
        port = r.emulators["ins"].serial.port
        assert port.stats.unplugs == 1 and port.stats.replugs == 1
        assert reader.disconnects == 1
        assert os.readlink(ep.target) == port.path and port.path != ""
        assert first_pty  # the pty may come back under another number; the link follows
        counts = r.emulators["ins"].channels[0].injector.counts
        assert counts.unplugged == 50 and counts.stalled == 50
    msgs = [hn100.CODEC.decode(f.data) for f in hn100.Hn100Framer().frames([data])]
    seqs = [m.seq for m in msgs]
    assert not [s for s in seqs if 100 <= s < 150 or 250 <= s < 300]
    assert any(s < 100 for s in seqs) and any(150 <= s < 250 for s in seqs)
    assert max(seqs) == 400
    for m in msgs:
        t = m.seq * 0.01
        assert m.time == pytest.approx(t + (100.0 if t >= 3.2 else 0.0), abs=2e-4)


def test_noise_bursts_multiply_the_covariance(tmp_path: Path) -> None:
    faults = {"noise_burst_p": 0.3, "noise_burst_n": 16.0}
    scn = make_scenario(devices={"ins": {"options": {"can": False, "serial": False},
                                         "faults": faults}})  # fmt: skip
    with Runner(scn, RunOptions(out_dir=tmp_path, devices=["ins"])) as r:
        em = r.emulators["ins"]
        samples = [em.measure(k * 0.01) for k in range(6000)]
    bursts = np.array([s.burst for s in samples])
    err = np.array([math.degrees(wrap_angle(s.heading - r.truth.at(s.t).heading))
                    for s in samples])  # fmt: skip
    assert bursts.mean() == pytest.approx(0.3, abs=0.03)
    assert rms(err[~bursts]) == pytest.approx(0.3, rel=0.06)
    assert rms(err[bursts]) == pytest.approx(0.3 * 4.0, rel=0.08)  # sigma x sqrt(16)
    assert em.faults.counts.noise_bursts == bursts.sum()


@pytest.mark.e2e
def test_faults_switch_at_run_time_and_through_the_control_file(tmp_path: Path) -> None:
    scn = make_scenario(devices={"ins": {"faults": {"dropout_p": 0.1}}})
    with Runner(scn, RunOptions(out_dir=tmp_path, devices=["ins", "magnetometer"])) as r:
        ins = r.emulators["ins"]
        serial_ch, can_ch = ins.channels
        r.set_faults("ins", corrupt_p=0.2, garbage_p=0.1)
        assert serial_ch.injector.settings.corrupt_p == 0.2
        assert serial_ch.injector.settings.dropout_p == 0.1
        assert can_ch.injector.settings.corrupt_p == 0.0, "no byte faults on a CAN bus"
        assert can_ch.injector.settings.dropout_p == 0.1
        with pytest.raises(ValueError, match="no running device 'dvl'"):
            r.apply_control({"dvl": {"dropout_p": 0.5}})
        with pytest.raises(ValueError, match=r"magnetometer\.corrupt_p: .*less than or equal to 1"):
            r.apply_control({"magnetometer": {"corrupt_p": 2}})
        r.apply_control({"magnetometer": {"stall": [[5, 6]]}})
        assert ins.faults.settings.corrupt_p == 0.0  # back to the scenario's
        assert ins.faults.settings.dropout_p == 0.1
        assert r.emulators["magnetometer"].faults.settings.stall == [(5.0, 6.0)]
        r.unplug_for("ins", 2.0)
        assert serial_ch.injector.settings.unplug == [(0.0, 2.0)]
        # the control file: applied on change, removal restores the scenario's faults
        control = tmp_path / "faults.json"
        r.watch_control(control, interval_s=0.02)
        control.write_text(json.dumps({"ins": {"truncate_p": 0.25}}))

        def wait_for(cond: Any) -> bool:
            end = time.monotonic() + 30  # generous: a busy machine
            while not cond() and time.monotonic() < end:
                time.sleep(0.01)
            return bool(cond())

        assert wait_for(lambda: serial_ch.injector.settings.truncate_p == 0.25)
        assert serial_ch.injector.settings.unplug == []
        control.write_text("{not json")
        time.sleep(0.1)
        assert serial_ch.injector.settings.truncate_p == 0.25, "a bad file changes nothing"
        control.unlink()
        assert wait_for(lambda: serial_ch.injector.settings.truncate_p == 0.0)


# -- MSIS (host-polled) ------------------------------------------------------------------------


@pytest.mark.e2e
def test_msis_head_is_silent_until_polled_and_pings_the_walls(tmp_path: Path) -> None:
    scn = Scenario.model_validate(
        {**json.loads((Path(__file__).parents[2] / "config/scenarios/harbour.json").read_text()),
         "devices": {"msis": {"options": {"alive_period_s": 1.0}}}}
    )
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=10, devices=["msis"])) as r:
        ep = endpoint(r, "msis")
        assert ep.format == "seanet"
        reader = SerialReader(ep.target, 115200)
        r.start(duration=200.0)
        framer = sn.SeaNetFramer(policy=ErrorPolicy.RAISE)
        got: list[Any] = []
        seen = 0

        def wait(pred: Any, timeout: float = 30.0) -> None:
            nonlocal seen
            end = time.monotonic() + timeout
            while True:
                data = reader.data()
                got.extend(m for fr in framer.feed(data[seen:]) for m in sn.decode(fr.data))
                seen = len(data)
                if pred() or time.monotonic() > end:
                    break
                time.sleep(0.005)
            assert pred()

        time.sleep(0.35)  # 3.5 vehicle s unpolled: power-up mtAlive plus one per second
        wait(lambda: len(got) >= 3)
        assert all(isinstance(m, sn.Alive) for m in got)
        reader.write(sn.encode(sn.send_version()))
        wait(lambda: any(isinstance(m, sn.VersionData) for m in got))
        cmd = sn.head_command(range_m=40.0, n_bins=400, sound_speed=r.world.sound_speed,
                              step=96 * sn.RAD_PER_ANGLE_UNIT, gain=0.4)  # fmt: skip
        reader.write(sn.encode(cmd))
        wait(lambda: any(isinstance(m, sn.Alive) and not m.head_inf & sn.HeadInf.NO_PARAMS
                         for m in got))  # fmt: skip
        pings = []
        for _ in range(24):  # 5.4 deg steps from the bow to starboard: the pier 30 m east
            n = len(got)
            t_sent = r.clock.now()
            reader.write(sn.encode(sn.send_data(0)))
            wait(lambda n=n: any(isinstance(m, sn.HeadData) for m in got[n:]))
            time.sleep(0.03)  # a second reply would show up now
            wait(lambda: True)
            heads = [m for m in got[n:] if isinstance(m, sn.HeadData)]
            assert len(heads) == 1, "exactly one mtHeadData per mtSendData"
            pings.append((t_sent, heads[0]))
        r.stop()
        reader.finish(quiet=0.05)
    bearings = np.array([h.bearing for _, h in pings])
    steps = wrap_angle(np.diff(bearings))
    assert np.allclose(steps, 96 * sn.RAD_PER_ANGLE_UNIT, atol=1e-9)
    # the strongest bin sits at the range of the wall/pile the beam points at
    errors = []
    for t, h in pings:
        s = r.truth.at(t)
        hit = r.world.cast((s.x, s.y), np.array([s.heading + h.bearing]), 40.0)
        if hit.kind[0] == 1:
            bin_len = 40.0 / 400
            errors.append(abs((np.argmax(h.bins) + 0.5) * bin_len - hit.range_m[0]))
    assert len(errors) >= 10 and float(np.median(errors)) < 1.0
    assert r.emulators["msis"].errors == 0


# -- configuration and logs --------------------------------------------------------------------


@pytest.mark.e2e
def test_gateway_configuration_points_at_every_port(tmp_path: Path) -> None:
    with Runner(make_scenario(), RunOptions(out_dir=tmp_path)) as r:
        path = r.write_gateway_config(tmp_path / "gw.toml", vehicle="sim-1")
        cfg = load_gateway_config(path)
        assert cfg.vehicle == "sim-1"
        names = [ep.name for ep in r.endpoints()]
        assert list(cfg.devices) == names
        assert {"ins", "ins_can", "msis", "multibeam", "magnetometer", "magnetometer_can"} <= set(
            names
        )
        for ep in r.endpoints():
            dev = cfg.devices[ep.name]
            assert dev.format == ep.format
            if ep.kind == "serial":
                assert os.path.realpath(dev.transport.url) == ep.path
                assert Path(dev.transport.url).parent == tmp_path / "ports"
            elif ep.kind == "can":
                assert dev.transport.interface == "slcan"
                assert os.path.realpath(str(dev.transport.channel)) == ep.path
                assert dev.transport.options == {"sleep_after_open": 0}
            else:
                assert dev.transport.port == ep.transport["port"]
        assert cfg.devices["ins_can"].dbc == "hn100.dbc"
        assert cfg.devices["magnetometer_can"].dbc == "ms3a.dbc"
    assert "dvl" in r.unavailable or "dvl" in r.emulators


def test_gateway_toml_writer_round_trips() -> None:
    import tomllib

    data = {"vehicle": "a", "bus": {"mode": "peer", "listen": ["tcp/127.0.0.1:7447"]},
            "devices": {"x": {"format": "can", "transport": {"kind": "can", "options": {
                "sleep_after_open": 0, "odd key": "q\"uote"}}, "on": True, "f": 1.5}}}  # fmt: skip
    assert tomllib.loads(gateway_toml(data, "header\nlines")) == data


@pytest.mark.e2e
def test_truth_callback_and_logs(tmp_path: Path) -> None:
    seen: list[Any] = []
    scn = make_scenario(devices={"magnetometer": {"options": {"can": False}}})
    for log_name in ("truth.jsonl", "truth.npz"):
        options = RunOptions(out_dir=tmp_path, speed=0, devices=["magnetometer"], truth_rate_hz=5,
                             on_truth=seen.append, truth_log=tmp_path / log_name)  # fmt: skip
        with Runner(scn, options) as r:
            r.start(duration=3.0)
            assert r.wait(30)
    assert [s.t for s in seen] == pytest.approx([k * 0.2 for k in range(16)] * 2)
    rows = [json.loads(line) for line in (tmp_path / "truth.jsonl").read_text().splitlines()]
    assert len(rows) == 16 and set(rows[0]) == set(TRUTH_FIELDS)
    assert rows[7]["x"] == pytest.approx(r.truth.at(1.4).x)
    npz = np.load(tmp_path / "truth.npz")
    assert np.allclose(npz["t"], [k * 0.2 for k in range(16)])
    assert np.allclose(npz["heading"], [r.truth.at(k * 0.2).heading for k in range(16)])
    with pytest.raises(ValueError, match=r"use a \.jsonl or \.npz"):
        Runner(scn, RunOptions(out_dir=tmp_path, devices=[], truth_log=tmp_path / "t.csv"))


def test_bad_device_options_and_names_are_clear_errors(tmp_path: Path) -> None:
    scn = make_scenario(devices={"ins": {"options": {"baud": "fast"}}})
    with pytest.raises(ValueError, match=r"devices\.ins\.options\.baud: expected int, got 'fast'"):
        Runner(scn, RunOptions(out_dir=tmp_path, devices=["ins"]))
    scn = make_scenario(devices={"multibeam": {"options": {"spacing": "random"}}})
    with pytest.raises(ValueError, match=r"devices\.multibeam\.options\.spacing"):
        Runner(scn, RunOptions(out_dir=tmp_path, devices=["multibeam"]))
    with pytest.raises(ValueError, match="unknown device"):
        Runner(make_scenario(), RunOptions(out_dir=tmp_path, devices=["sonar"]))


def test_truth_log_lines_are_on_disk_as_the_samples_are_taken(tmp_path: Path) -> None:
    """A reader tailing ``truth.jsonl`` (the in-process demo starts dead reckoning from it, in
    the gateway's INS reader) finds every earlier sample on disk when a sample is taken:
    block-buffered, the first 8 KiB of lines (2.3 s at 10 Hz) were on disk only at once, and the
    INS reader stalled for up to that long after its first frame: its rate null for 2 s)."""
    log_path = tmp_path / "truth.jsonl"
    on_disk: dict[float, list[float]] = {}

    def on_truth(sample: Any) -> None:  # the clock thread, before the sample's own line
        lines = log_path.read_text().splitlines()
        on_disk[round(sample.t, 1)] = [json.loads(line)["t"] for line in lines]

    options = RunOptions(out_dir=tmp_path, speed=0, devices=[], on_truth=on_truth,
                         truth_log=log_path)  # fmt: skip
    with Runner(make_scenario(), options) as r:
        r.start(duration=1.0)
        assert r.wait(30)
    assert sorted(on_disk) == pytest.approx([k / 10 for k in range(11)])
    for t, lines in on_disk.items():
        assert lines == pytest.approx([k / 10 for k in range(round(t * 10))]), t
