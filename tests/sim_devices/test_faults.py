"""Fault injector: exact counts against framers, time windows, noise bursts, run-time switches."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from auvgw.config.scenario import FaultSettings
from auvgw.drivers.framing import BadFrame, ErrorPolicy, Framer
from auvgw.sim_devices.faults import FaultInjector, in_windows
from auvgw.sim_devices.ports import PtyPort


class ToyFramer(Framer):
    """``AA 55 | u8 n | n payload bytes | u8 sum(payload) mod 256`` (as in test_spec_framing)."""

    name = "toy"
    sync = b"\xaa\x55"

    def check(self, buf: bytearray, start: int) -> int:
        if len(buf) - start < 3:
            return 0
        n = buf[start + 2]
        if n > 50:
            raise BadFrame(f"bad length {n}")
        total = 3 + n + 1
        if len(buf) - start < total:
            return 0
        if sum(buf[start + 3 : start + 3 + n]) & 0xFF != buf[start + 3 + n]:
            raise BadFrame("bad checksum")
        return total


class WeakFramer(Framer):
    """``@ | u8 n | n payload bytes | LF``: no checksum at all, only a terminator (SeaNet-like),
    the hardest case for guaranteed rejection."""

    name = "weak"
    sync = b"@"

    def check(self, buf: bytearray, start: int) -> int:
        if len(buf) - start < 2:
            return 0
        total = buf[start + 1] + 3
        if len(buf) - start < total:
            return 0
        if buf[start + total - 1] != 0x0A:
            raise BadFrame("bad terminator")
        return total


def toy(payload: bytes) -> bytes:
    return b"\xaa\x55" + bytes([len(payload)]) + payload + bytes([sum(payload) & 0xFF])


def weak(payload: bytes) -> bytes:
    return b"@" + bytes([len(payload)]) + payload + b"\n"


ENCODERS = {ToyFramer: toy, WeakFramer: weak}


def _run(
    framer: type[Framer], fs: FaultSettings, n: int, seed: int, flush: bool = True
) -> tuple[FaultInjector, bytes, list[bytes]]:
    """Encode n random frames, pass them through an injector; return it, the wire bytes and
    the frames that went out intact (in order)."""
    rng = np.random.default_rng(seed)
    inj = FaultInjector(fs, np.random.default_rng(seed + 1), framer)
    wire = bytearray()
    intact: list[bytes] = []
    for i in range(n):
        payload = rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
        frame = ENCODERS[framer](payload)
        before = inj.counts.frames_sent
        wire += inj.process(frame, i * 0.01)
        if inj.counts.frames_sent > before:
            intact.append(frame)
    if flush:
        wire += inj.flush()
    return inj, bytes(wire), intact


def _chunks(data: bytes, rng: np.random.Generator) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        k = int(rng.integers(1, 200))
        out.append(data[i : i + k])
        i += k
    return out


@pytest.mark.parametrize("framer", [ToyFramer, WeakFramer], ids=["checksum", "terminator-only"])
def test_framer_counts_exactly_what_the_injector_did(framer: type[Framer]) -> None:
    fs = FaultSettings(
        garbage_p=0.2, garbage_max_bytes=24, corrupt_p=0.05, truncate_p=0.05, dropout_p=0.05
    )
    inj, wire, intact = _run(framer, fs, 4000, seed=3)
    c = inj.counts
    assert c.frames_in == 4000
    assert c.corrupted > 100 and c.truncated > 100 and c.garbage_events > 500 and c.dropped > 100
    assert c.frames_sent + c.dropped + c.corrupted + c.truncated + c.downgraded == 4000
    assert c.unverified == 0 and c.pending == 0
    f = framer(policy=ErrorPolicy.IGNORE)
    frames = [fr.data for fr in f.frames(_chunks(wire, np.random.default_rng(7)))]
    assert frames == intact, "no good frame lost, none invented"
    assert f.stats.bad_frames == c.bad_frames
    assert f.stats.skipped_bytes == c.skipped_bytes == len(wire) - sum(map(len, intact))
    if framer is ToyFramer:
        assert c.extra_bad == 0 and c.downgraded == 0


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    garbage=st.floats(0, 0.5),
    corrupt=st.floats(0, 0.3),
    truncate=st.floats(0, 0.3),
    dropout=st.floats(0, 0.2),
)
def test_exact_counts_for_any_seed_and_rates(
    seed: int, garbage: float, corrupt: float, truncate: float, dropout: float
):
    fs = FaultSettings(garbage_p=garbage, corrupt_p=corrupt, truncate_p=truncate, dropout_p=dropout)
    inj, wire, intact = _run(ToyFramer, fs, 300, seed)
    if inj.counts.unverified:  # more than max_pending bad frames in a row: no promise
        return
    f = ToyFramer(policy=ErrorPolicy.IGNORE)
    assert [fr.data for fr in f.frames(_chunks(wire, np.random.default_rng(seed)))] == intact
    assert f.stats.bad_frames == inj.counts.bad_frames


@pytest.mark.e2e
def test_exact_counts_through_a_real_pty_read_by_pyserial() -> None:
    fs = FaultSettings(garbage_p=0.3, corrupt_p=0.1, truncate_p=0.1)
    rng = np.random.default_rng(11)
    inj = FaultInjector(fs, np.random.default_rng(12), ToyFramer)
    framer = ToyFramer(policy=ErrorPolicy.IGNORE)
    intact: list[bytes] = []
    got: list[bytes] = []
    done = threading.Event()
    with PtyPort("toy", 115200, speed=0) as port, serial.Serial(port.device, timeout=0.05) as s:

        def reader() -> None:  # the gateway side: read continuously, frame, count
            while not (done.is_set() and framer.stats.bytes_in >= port.stats.bytes_written):
                got.extend(fr.data for fr in framer.feed(s.read(4096)))

        th = threading.Thread(target=reader)
        th.start()
        for i in range(1500):
            frame = toy(rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes())
            before = inj.counts.frames_sent
            port.write(inj.process(frame, i * 0.01))
            if inj.counts.frames_sent > before:
                intact.append(frame)
        port.write(inj.flush())
        assert port.wait_drained(10.0)
        done.set()
        th.join(10.0)
    got += [fr.data for fr in framer.finish()]
    assert port.stats.bytes_dropped == 0
    assert got == intact
    assert framer.stats.bad_frames == inj.counts.bad_frames > 100


def test_held_back_bad_frames_are_flushed_at_end_of_stream() -> None:
    inj = FaultInjector(FaultSettings(corrupt_p=1.0), np.random.default_rng(0), ToyFramer)
    wire = b"".join(inj.process(toy(bytes([i, 2 * i])), i) for i in range(3))
    assert wire == b"" and inj.counts.pending == 3
    wire = inj.flush()
    assert inj.counts.pending == 0 and inj.counts.corrupted == 3
    f = ToyFramer(policy=ErrorPolicy.IGNORE)
    assert list(f.frames([wire])) == [] and f.stats.bad_frames == 3


def test_blind_faults_without_a_framer_still_count() -> None:
    inj = FaultInjector(FaultSettings(corrupt_p=0.5, garbage_p=0.5), np.random.default_rng(1))
    frames = [bytes([i]) * 20 for i in range(200)]
    wire = b"".join(inj.process(f, 0.0) for f in frames) + inj.flush()
    c = inj.counts
    assert c.corrupted > 50 and c.unverified == c.corrupted
    assert len(wire) == 20 * 200 + c.garbage_bytes
    assert sum(wire.count(f) for f in frames) == c.frames_sent


def test_same_seed_same_faults() -> None:
    fs = FaultSettings(garbage_p=0.3, corrupt_p=0.1, truncate_p=0.1, dropout_p=0.1)
    a = _run(ToyFramer, fs, 500, seed=5)[1]
    b = _run(ToyFramer, fs, 500, seed=5)[1]
    c = _run(ToyFramer, fs, 500, seed=6)[1]
    assert a == b and a != c


def test_garbage_never_contains_sync_bytes() -> None:
    inj = FaultInjector(
        FaultSettings(garbage_p=1.0, garbage_max_bytes=64), np.random.default_rng(2), ToyFramer
    )
    frame = toy(b"abc")
    wire = b"".join(inj.process(frame, 0.0) for _ in range(300))
    junk = wire.replace(frame, b"")
    assert len(junk) == inj.counts.garbage_bytes > 5000
    assert b"\xaa" not in junk and b"\x55" not in junk


# -- time windows, noise, run-time switching -------------------------------------------------


@pytest.mark.e2e
def test_windows_stalls_unplug_bottom_lock_and_clock_jumps() -> None:
    fs = FaultSettings(
        unplug=[(10.0, 12.0)],
        stall=[(20.0, 21.0), (30.0, 30.5)],
        bottom_lock_loss=[(5.0, 6.0)],
        clock_jumps=[(40.0, 2.5), (50.0, -1.0)],
    )
    inj = FaultInjector(fs, np.random.default_rng(0), ToyFramer)
    out = [inj.process(toy(b"x"), t) for t in np.arange(0, 60, 0.5)]
    assert inj.counts.unplugged == 4 and inj.counts.stalled == 3
    assert inj.counts.frames_sent == 120 - 7 and sum(map(len, out)) == 113 * 5
    assert [inj.bottom_lock_lost(t) for t in (4.99, 5.0, 5.99, 6.0)] == [False, True, True, False]
    assert inj.device_time(39.0) == 39.0 and inj.device_time(45.0) == 47.5
    assert inj.device_time(55.0) == pytest.approx(56.5)
    assert in_windows([(0, 1)], 0.5) and not in_windows([(0, 1)], 1.0)
    with PtyPort("dev", 115200, speed=0) as port:
        assert inj.sync_port(port, 9.0) and port.plugged
        assert not inj.sync_port(port, 10.5) and not port.plugged
        assert inj.sync_port(port, 12.0) and port.plugged
        assert port.stats.unplugs == 1 and port.stats.replugs == 1


def test_noise_burst_multiplier_follows_the_vb_model() -> None:
    inj = FaultInjector(
        FaultSettings(noise_burst_p=0.2, noise_burst_n=16.0), np.random.default_rng(4)
    )
    m = np.array([inj.sigma_multiplier() for _ in range(20000)])
    assert set(np.unique(m)) == {1.0, 4.0}
    assert (m == 4.0).sum() == inj.counts.noise_bursts
    assert inj.counts.noise_samples == 20000
    assert abs((m == 4.0).mean() - 0.2) < 0.015
    # covariance is n times larger in a burst: the variance of scaled unit noise
    e = np.random.default_rng(5).normal(size=m.size) * m
    assert np.var(e[m == 4.0]) / np.var(e[m == 1.0]) == pytest.approx(16.0, rel=0.1)
    quiet = FaultInjector(None, np.random.default_rng(4))
    assert {quiet.sigma_multiplier() for _ in range(100)} == {1.0}


def test_faults_switch_at_run_time() -> None:
    inj = FaultInjector(FaultSettings(), np.random.default_rng(0), ToyFramer)
    frames = [toy(bytes([i])) for i in range(30)]
    wire = b"".join(inj.process(f, 0.0) for f in frames[:10])
    assert wire == b"".join(frames[:10])
    inj.update(corrupt_p=1.0)
    assert inj.process(frames[10], 0.0) == b"" and inj.counts.pending == 1
    inj.update(corrupt_p=0.0, garbage_p=1.0, garbage_max_bytes=3)
    out = inj.process(frames[11], 0.0)
    assert out.endswith(frames[11]) and inj.counts.corrupted == 1
    assert inj.settings.garbage_p == 1.0
    with pytest.raises(ValidationError):
        inj.update(dropout_p=1.5)
    assert inj.settings.dropout_p == 0.0, "a rejected change leaves the settings alone"
    inj.settings = FaultSettings(dropout_p=1.0)
    assert inj.process(frames[12], 0.0) == b"" and inj.counts.dropped == 1
    assert math.isclose(inj.sigma_multiplier(), 1.0)


@pytest.mark.parametrize("framer", [ToyFramer, WeakFramer], ids=["checksum", "terminator-only"])
def test_undetected_corruption_passes_the_framer_and_is_counted(framer: type[Framer]) -> None:
    """``undetected_p``: corruption no check can catch (a checksum kept by two changes, data
    bits of a format without one) reaches the receiver as valid frames: exactly as many frames
    differ from what the emulator encoded as the injector says, and none is lost."""
    fs = FaultSettings(undetected_p=0.3, garbage_p=0.1, corrupt_p=0.05)
    inj, wire, sent = _run(framer, fs, 1500, seed=11)
    c = inj.counts
    assert c.undetected > 300 and c.undetected_failed < c.undetected / 10
    f = framer(policy=ErrorPolicy.IGNORE)
    got = [fr.data for fr in f.frames(_chunks(bytes(wire), np.random.default_rng(5)))]
    assert len(got) == len(sent) and f.stats.bad_frames == c.bad_frames
    assert sum(g != s for g, s in zip(got, sent, strict=True)) == c.undetected
