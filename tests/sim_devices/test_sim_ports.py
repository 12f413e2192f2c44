"""Virtual ports with the real client libraries: pyserial on ptys, python-can's slcan, UDP."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import can
import numpy as np
import pytest
import serial

from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.ports import Pacer, PtyPort, UdpSender
from auvgw.sim_devices.slcan import SlcanAdapter, can_frame_bits, encode_frame


def _read_exactly(s: serial.Serial, n: int, timeout: float = 10.0) -> bytes:
    out = bytearray()
    end = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < end:
        out += s.read(n - len(out))
    return bytes(out)


# -- pacing ----------------------------------------------------------------------------------


def test_pacer_schedules_bytes_at_the_line_rate() -> None:
    p = Pacer()
    p.begin(now=10.0, size=100, line_s=0.01)  # 100 bytes in 10 ms
    assert p.due(9.0) == 0 and p.due(10.0) == 1
    assert p.due(10.00455) == 46 and p.due(10.5) == 100
    assert p.when(50) == pytest.approx(10.005)
    p.begin(now=10.002, size=10, line_s=0.001)  # the line is still busy: starts at 10.01
    assert p.start == pytest.approx(10.01) and p.due(10.009) == 0
    p.delay(0.5)  # the reader stalled
    assert p.start == pytest.approx(10.51) and p.line_free == pytest.approx(10.511)
    p.begin(now=20.0, size=7, line_s=0.0)  # unpaced
    assert p.due(20.0) == 7


# -- pty ports with pyserial -----------------------------------------------------------------


@pytest.mark.e2e
def test_pty_delivers_exact_bytes_both_ways(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    chunks = [
        rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
        for _ in range(200)
    ]
    with PtyPort("dev", 115200, speed=0, link=tmp_path / "dev") as port:
        assert os.readlink(port.device) == port.path and port.path.startswith("/dev/pts/")
        with serial.Serial(port.device, 115200, timeout=0.5) as s:
            for c in chunks:
                assert port.write(c)
            data = _read_exactly(s, sum(map(len, chunks)))
            assert data == b"".join(chunks)
            s.write(b"\x10\x02poll\x00\x0a")  # raw, binary-clean: no echo, no CR/LF mapping
            s.flush()
            got = b""
            while len(got) < 8:
                more = port.read(timeout=2.0)
                assert more, "host bytes never arrived"
                got += more
            assert got == b"\x10\x02poll\x00\x0a"
        assert port.stats.bytes_written == len(data) and port.stats.bytes_received == 8
        assert port.stats.writes == 200 and port.stats.bytes_dropped == 0


@pytest.mark.e2e
def test_pty_on_receive_callback() -> None:
    seen: list[bytes] = []
    with PtyPort("msis", 115200, speed=0, on_receive=seen.append) as port:
        with serial.Serial(port.device, timeout=0.5) as s:
            s.write(b"@000C...")
            s.flush()
            end = time.monotonic() + 30  # generous: a busy machine
            while b"".join(seen) != b"@000C..." and time.monotonic() < end:
                time.sleep(0.005)
        assert b"".join(seen) == b"@000C..."
        assert port.read(timeout=0) == b"", "with a callback nothing is buffered"


@pytest.mark.e2e
def test_pty_is_paced_at_the_baud_scaled_by_the_clock() -> None:
    clock = SimClock(speed=4.0)
    n = 1920  # 0.5 s on a 38400 baud 8N1 line, 0.125 s at 4 x real time
    with PtyPort("slow", 38400, clock=clock) as port:
        assert port.line_time(n) == pytest.approx(0.5)
        with serial.Serial(port.device, timeout=0.01) as s:
            t0 = time.monotonic()
            port.write(bytes(range(256)) * 7 + bytes(128))
            arrived = []  # (seconds since the write, bytes so far) at every read that got some
            data = bytearray()
            while len(data) < n and time.monotonic() - t0 < 10:
                chunk = s.read(n)
                if chunk:
                    data += chunk
                    arrived.append((time.monotonic() - t0, len(data)))
            elapsed = time.monotonic() - t0
        assert bytes(data) == bytes(range(256)) * 7 + bytes(128)
        assert elapsed >= 0.125 - 0.01, "the bytes took at least their line time"
        # never ahead of the line (a starved reader only falls behind it: holds on a busy host);
        # one quantum of slack, the size of the I/O thread's chunk
        quantum = PtyPort.PACING_QUANTUM_S / 0.125 * n
        for t, got in arrived:
            assert got <= n * t / 0.125 + quantum, f"{got} bytes {t:.3f} s after the write"
        assert port.stats.chunks > 3, "the bytes went on the line in paced chunks"


@pytest.mark.e2e
def test_short_frames_go_out_whole_and_long_ones_in_quantum_chunks() -> None:
    clock = SimClock(speed=10.0)
    frame = bytes(range(74))  # an INS frame: 6.4 ms on a 115200 line, 0.64 ms at 10 x
    with PtyPort("ins", 115200, clock=clock) as port:
        chunk = int(port.PACING_QUANTUM_S / (port.line_time(1) / 10.0))
        assert chunk > len(frame)
        with serial.Serial(port.device, timeout=0.05) as s:
            for _ in range(20):
                assert port.write(frame)
            assert port.wait_drained(10.0)
            assert _read_exactly(s, 20 * len(frame)) == frame * 20
            assert port.stats.chunks == 20, "one write into the pty per frame"
            long = bytes(5 * chunk)  # five quanta of line time
            port.write(long)
            assert port.wait_drained(10.0)
            assert _read_exactly(s, len(long)) == long
        assert port.stats.chunks - 20 <= 5, "never more writes than quanta"
        assert port.stats.bytes_written == 20 * len(frame) + len(long)


@pytest.mark.e2e
def test_unplug_gives_serial_exception_and_replug_comes_back_on_the_symlink(tmp_path: Path) -> None:
    link = tmp_path / "run" / "dvl"
    with PtyPort("dvl", 115200, speed=0, link=link) as port:
        first = port.path
        s = serial.Serial(str(link), timeout=0.5)
        port.write(b"before")
        assert _read_exactly(s, 6) == b"before"
        port.unplug()
        assert not port.plugged and not os.path.lexists(link), "the device disappears"
        with pytest.raises(serial.SerialException):
            s.read(1)
        s.close()
        assert not port.write(b"lost")
        with pytest.raises(serial.SerialException):
            serial.Serial(str(link))
        port.replug()
        assert port.plugged and os.readlink(link) == port.path
        s = serial.Serial(str(link), timeout=0.5)
        port.write(b"after")
        assert _read_exactly(s, 5) == b"after"
        s.close()
        assert port.stats.unplugs == 1 and port.stats.replugs == 1
        assert port.stats.writes_dropped == 1 and port.stats.bytes_dropped == 4
        assert first.startswith("/dev/pts/")


@pytest.mark.e2e
def test_full_pty_drops_and_counts_without_blocking_the_emulator() -> None:
    with PtyPort("ins", None, speed=0, block_timeout_s=0.1) as port:
        for _ in range(100):  # 100 kB into a pty nobody reads (it holds about 16 KiB)
            port.write(b"\x55" * 1000)
        assert port.wait_drained(20.0)
        st = port.stats
        assert st.bytes_written + st.bytes_dropped == 100_000
        assert 4_000 < st.bytes_written < 70_000
        assert st.writes_dropped >= 20
        # a reader that opens now starts clean (pyserial flushes) and gets what comes next
        with serial.Serial(port.device, timeout=0.5) as s:
            port.write(b"fresh frame")
            assert _read_exactly(s, 11) == b"fresh frame"


@pytest.mark.e2e
def test_bounded_queue_drops_what_the_baud_cannot_carry() -> None:
    with PtyPort("slow", 300, speed=1.0, max_queue_bytes=100) as port:
        assert port.write(b"a" * 50)  # 1.7 s on the line
        end = time.monotonic() + 30  # generous: a busy machine
        while port.queued_bytes and time.monotonic() < end:  # the I/O thread takes it
            time.sleep(0.001)
        assert port.write(b"b" * 60)
        assert not port.write(b"c" * 60)
        assert port.stats.writes_dropped == 1 and port.stats.bytes_dropped == 60


# -- UDP -------------------------------------------------------------------------------------


def test_udp_sender_delivers_datagrams_and_counts_unplugged_ones() -> None:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    port = rx.getsockname()[1]
    with UdpSender(port) as tx:
        grams = [bytes([i]) * (100 + i) for i in range(20)]
        for g in grams:
            assert tx.send(g)
        assert [rx.recv(65536) for _ in grams] == grams
        tx.unplug()
        assert not tx.send(b"lost")
        tx.replug()
        assert tx.send(b"back")
        assert rx.recv(65536) == b"back"
        assert tx.stats.writes == 21 and tx.stats.writes_dropped == 1
    rx.close()


# -- SLCAN adapter with python-can -----------------------------------------------------------


def test_encode_frame_lawicel_lines() -> None:
    std = can.Message(arbitration_id=0x1A5, data=b"\x01\xab", is_extended_id=False)
    ext = can.Message(arbitration_id=0x18FF50E5, data=bytes(8), is_extended_id=True)
    rtr = can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=3, is_extended_id=False)
    assert encode_frame(std) == b"t1A5201AB\r"
    assert encode_frame(ext) == b"T18FF50E580000000000000000\r"
    assert encode_frame(rtr) == b"r7FF3\r"
    assert encode_frame(std, timestamp_ms=61234) == b"t1A5201AB04D2\r"  # 1234 ms into the minute
    assert can_frame_bits(8, False) == 111 and can_frame_bits(8, True) == 131
    with pytest.raises(ValueError):
        encode_frame(can.Message(arbitration_id=0x800, is_extended_id=False))


@pytest.mark.e2e
def test_python_can_slcan_talks_to_the_adapter(tmp_path: Path) -> None:
    with SlcanAdapter(speed=0, link=tmp_path / "can0") as adapter:
        bus = can.Bus(interface="slcan", channel=adapter.device, sleep_after_open=0, bitrate=250000)
        try:
            assert bus.get_version(2.0) == (10, 13)
            assert bus.get_serial_number(2.0) == "AUV1"
            assert adapter.is_open and adapter.bitrate == 250_000
            sent = [
                can.Message(arbitration_id=0x100, data=b"\x01\x02\x03", is_extended_id=False),
                can.Message(arbitration_id=0x1ABCDE0F, data=bytes(range(8)), is_extended_id=True),
                can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False),
                can.Message(
                    arbitration_id=0x123, is_remote_frame=True, dlc=2, is_extended_id=False
                ),
            ]
            for m in sent:
                assert adapter.send(m)
            got = [bus.recv(2.0) for _ in sent]
            for a, b in zip(sent, got, strict=True):
                assert b is not None
                assert (b.arbitration_id, b.is_extended_id, b.is_remote_frame, b.dlc) == (
                    a.arbitration_id, a.is_extended_id, a.is_remote_frame, a.dlc)  # fmt: skip
                assert bytes(b.data) == bytes(a.data)
            host = [
                can.Message(arbitration_id=0x321, data=b"\xde\xad\xbe\xef", is_extended_id=False),
                can.Message(arbitration_id=0x0CF00400, data=b"\x11" * 8, is_extended_id=True),
            ]
            for m in host:
                bus.send(m)
            rx = [adapter.recv(2.0) for _ in host]
            assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in rx] == [
                (0x321, False, b"\xde\xad\xbe\xef"), (0x0CF00400, True, b"\x11" * 8)]  # fmt: skip
        finally:
            bus.shutdown()
        end = time.monotonic() + 30  # generous: a busy machine
        while adapter.is_open and time.monotonic() < end:
            time.sleep(0.005)
        assert not adapter.is_open, "python-can's shutdown sends C"
        assert not adapter.send(sent[0]) and adapter.stats.dropped_closed == 1
        assert adapter.stats.frames_to_host == 4 and adapter.stats.frames_from_host == 2


def _exchange(s: serial.Serial, cmd: bytes) -> bytes:
    s.write(cmd)
    s.flush()
    out = bytearray()
    end = time.monotonic() + 30  # generous: a busy machine
    while time.monotonic() < end:
        out += s.read(64)
        if out.endswith((b"\r", b"\a")):
            break
    return bytes(out)


@pytest.mark.e2e
def test_adapter_protocol_answers_bells_acks_status_and_timestamps() -> None:
    clock = SimClock(speed=0, start_time=61.5)
    with SlcanAdapter(clock=clock) as adapter, serial.Serial(adapter.device, timeout=0.05) as s:
        assert _exchange(s, b"C\r") == b"\a"  # not open
        assert _exchange(s, b"S9\r") == b"\a"  # no such bitrate code
        assert _exchange(s, b"S4\r") == b"\r" and adapter.bitrate == 125_000
        assert _exchange(s, b"Z1\r") == b"\r"
        assert _exchange(s, b"F\r") == b"\a"  # status only when open
        assert _exchange(s, b"O\r") == b"\r"
        assert _exchange(s, b"O\r") == b"\a"  # already open
        assert _exchange(s, b"S6\r") == b"\a"  # bitrate only when closed
        assert _exchange(s, b"t12\r") == b"\a"  # malformed
        assert _exchange(s, b"t12320102\r") == b"z\r"
        assert _exchange(s, b"T0000ABCD1FF\r") == b"Z\r"
        assert _exchange(s, b"F\r") == b"F00\r"
        assert _exchange(s, b"v\r") == b"v0013\r"
        assert _exchange(s, b"X\r") == b"\a"
        assert [(m.arbitration_id, bytes(m.data)) for m in (adapter.recv(1), adapter.recv(1))] == [
            (0x123, b"\x01\x02"), (0xABCD, b"\xff")]  # fmt: skip
        adapter.send(can.Message(arbitration_id=0x42, data=b"\x07", is_extended_id=False))
        line = _exchange(s, b"")
        assert line == b"t04210705DC\r"  # Z1: vehicle time 61.5 s is 1500 ms into the minute
        assert adapter.stats.errors == 7
