"""Transports against real parts: ptys, pyserial URLs, python-can buses, UDP sockets, files."""

from __future__ import annotations

import contextlib
import itertools
import os
import random
import re
import select
import socket
import threading
import time
import tomllib
import tty
import uuid
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError

from auvgw.config.transport import (
    FileTransportConfig,
    TransportConfig,
    TransportConfigError,
    format_validation_error,
    parse_transport_config,
)
from auvgw.drivers.transports import (
    CanTransport,
    Chunk,
    Disconnected,
    EndOfStream,
    FileReplayTransport,
    SerialTransport,
    TransportClosed,
    TransportError,
    TransportOpenError,
    UdpTransport,
    make_transport,
    open_transport,
    replay_schedule,
)

DOCS = Path(__file__).resolve().parents[2] / "docs" / "transports.md"


# --- helpers ----------------------------------------------------------------------------------


@pytest.fixture
def pty_pair():
    """A raw pty: (master fd, slave path). The slave fd stays open until the test ends."""
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    fds = {"master": master, "slave": slave}
    yield fds, path
    for fd in fds.values():
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)


def read_exactly(t, n: int, timeout_s: float = 2.0) -> list[Chunk]:
    """Read chunks until n bytes arrived (fails the test on a stall)."""
    chunks: list[Chunk] = []
    got = 0
    deadline = time.monotonic() + timeout_s
    while got < n:
        assert time.monotonic() < deadline, f"stalled after {got} of {n} bytes"
        c = t.read(0.2)
        if c is not None:
            chunks.append(c)
            got += len(c.data)
    return chunks


def drain_master(fd: int) -> bytes:
    """Bytes waiting on a pty master (what the transport wrote)."""
    out = b""
    while select.select([fd], [], [], 0.2)[0]:
        out += os.read(fd, 4096)
    return out


# --- serial -----------------------------------------------------------------------------------


@pytest.mark.e2e
def test_pty_bytes_arrive_in_order_with_increasing_receive_times(pty_pair):
    fds, path = pty_pair
    with open_transport({"kind": "serial", "url": path, "baud": 115200}) as t:
        assert isinstance(t, SerialTransport) and t.is_open
        assert path in t.describe() and "115200" in t.describe()
        messages = [b"$PD6,first\r\n", b"\x7f\x7f\x10\x00binary\x00\xff", b"third"]
        chunks: list[Chunk] = []
        for msg in messages:
            os.write(fds["master"], msg)
            chunks += read_exactly(t, len(msg))
        assert b"".join(c.data for c in chunks) == b"".join(messages)
        times = [c.t_recv_ns for c in chunks]
        assert all(b > a for a, b in itertools.pairwise(times)), times
        assert all(c.can_id is None and c.t_device_s is None for c in chunks)
        assert t.bytes_read == sum(map(len, messages)) and t.chunks_read == len(chunks)
        assert t.read(0.02) is None  # nothing more


@pytest.mark.e2e
def test_pty_large_stream_beyond_pty_buffer(pty_pair):
    fds, path = pty_pair
    payload = random.Random(7).randbytes(50_000)  # > the 16 KiB an unread pty holds

    def writer() -> None:
        view = memoryview(payload)
        while view:
            n = os.write(fds["master"], view[:4096])
            view = view[n:]

    with open_transport({"kind": "serial", "url": path}) as t:
        th = threading.Thread(target=writer)
        th.start()
        chunks = read_exactly(t, len(payload), timeout_s=10.0)
        th.join()
    assert b"".join(c.data for c in chunks) == payload
    assert all(len(c.data) <= 65536 for c in chunks)


@pytest.mark.e2e
def test_pty_write_reaches_the_other_end(pty_pair):
    fds, path = pty_pair
    with open_transport({"kind": "serial", "url": path}) as t:
        t.write(b"@\x00\x0c")
        t.write(b"poll\n")
        assert t.bytes_written == 8
        assert drain_master(fds["master"]) == b"@\x00\x0cpoll\n"


@pytest.mark.e2e
def test_pty_writer_closing_raises_disconnected_naming_the_port(pty_pair):
    fds, path = pty_pair
    t = open_transport({"kind": "serial", "url": path})
    os.write(fds["master"], b"last words")
    assert read_exactly(t, 10)[0].data.startswith(b"last")
    os.close(fds["master"])
    fds["master"] = None
    with pytest.raises(Disconnected) as info:
        t.read(1.0)
    assert path in str(info.value) and info.value.port == f"serial {path}"
    assert not t.is_open
    with pytest.raises(TransportError, match="not open"):
        t.read(0.0)
    t.close()  # closing again is harmless
    # the pty node is gone: reconnecting fails with a clear open error until it returns
    with pytest.raises(TransportOpenError, match=re.escape(path)):
        t.open()


def _read_empty(fd: int) -> None:
    """Make the kernel read the tty ``fd`` empty while it reports readiness: canonical mode
    with EOF = ^D (each ^D from the master is one readable, zero-byte read), the pty's other
    end still open, as a loaded pty did to the gateway (issue 30)."""
    import termios

    attrs = termios.tcgetattr(fd)
    attrs[3] |= termios.ICANON
    attrs[6][termios.VEOF] = b"\x04"
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


@pytest.mark.e2e
def test_pty_readable_but_empty_is_counted_and_read_again_until_it_persists(pty_pair):
    from auvgw.drivers.emptyreads import EMPTY_READS_LIMIT

    fds, path = pty_pair
    t = open_transport({"kind": "serial", "url": path})
    assert isinstance(t, SerialTransport)
    _read_empty(t._fd)
    os.write(fds["master"], b"\x04" * 3)
    assert [t.read(1.0) for _ in range(3)] == [None] * 3  # each one ready and empty: no close
    assert t.is_open and t.empty_reads.total == 3 and t.losses() == {"empty_reads": 3}
    tty.setraw(t._fd)
    os.write(fds["master"], b"after")
    assert b"".join(c.data for c in read_exactly(t, 5)) == b"after"
    assert t.empty_reads.in_a_row == 0  # bytes ended the run
    # persisting (no byte between): the port is taken as gone and closed, as a real hang-up
    _read_empty(t._fd)
    os.write(fds["master"], b"\x04" * EMPTY_READS_LIMIT)
    with pytest.raises(Disconnected, match=f"no data {EMPTY_READS_LIMIT} times in a row"):
        for _ in range(EMPTY_READS_LIMIT):
            t.read(1.0)
    assert not t.is_open and t.empty_reads.total == 3 + EMPTY_READS_LIMIT  # (this connection)


@pytest.mark.e2e
def test_slcan_adapter_readable_but_empty_is_read_again(pty_pair):
    """The same on the actuators' SLCAN port: the frame after the empty reads arrives, with
    the transport open throughout (a reopen refused the commands sent meanwhile)."""
    fds, path = pty_pair
    master = fds["master"]
    t = _slcan_on(path)
    drain_master(master)
    bus = t._handle
    _read_empty(bus._fd)
    os.write(master, b"\x04\x04")
    assert t.read(0.3) is None and t.is_open
    tty.setraw(bus._fd)
    os.write(master, b"t3102ABCD\r")
    c = t.read(2.0)
    assert c is not None and (c.can_id, c.data) == (0x310, b"\xab\xcd")
    assert bus.empty_reads.total == 2 and t.losses()["empty_reads"] == 2
    t.close()


def test_missing_device_open_error_names_port_and_what_to_check():
    path = f"/dev/ttyUSB-auvgw-missing-{uuid.uuid4().hex[:6]}"
    with pytest.raises(TransportOpenError) as info:
        open_transport({"kind": "serial", "url": path})
    msg = str(info.value)
    assert path in msg and "check" in msg and "plugged" in msg


def test_loop_url_write_then_read():
    with open_transport({"kind": "serial", "url": "loop://"}) as t:
        assert t.read(0.0) is None
        data = bytes(range(256)) * 8
        t.write(data)
        chunks = read_exactly(t, len(data))
        assert b"".join(c.data for c in chunks) == data
        assert t.bytes_written == len(data) == t.bytes_read
        with pytest.raises(ValueError, match="timeout_s"):
            t.read(-1.0)


def test_loop_url_max_chunk_splits_reads():
    with open_transport({"kind": "serial", "url": "loop://", "max_chunk": 100}) as t:
        t.write(b"z" * 250)
        sizes = [len(c.data) for c in read_exactly(t, 250)]
    assert sizes == [100, 100, 50]


def test_socket_url_reads_writes_and_reports_peer_close():
    with socket.create_server(("127.0.0.1", 0)) as srv:
        port = srv.getsockname()[1]
        t = open_transport({"kind": "serial", "url": f"socket://127.0.0.1:{port}"})
        peer, _ = srv.accept()
        data = random.Random(3).randbytes(20_000)
        peer.sendall(data)
        chunks = read_exactly(t, len(data))
        assert b"".join(c.data for c in chunks) == data
        t.write(b"ping")
        assert peer.recv(16) == b"ping"
        peer.close()
        with pytest.raises(Disconnected, match=f"127.0.0.1:{port}"):
            for _ in range(10):
                t.read(0.5)
        assert not t.is_open


def test_socket_url_refused_is_an_open_error():
    with socket.create_server(("127.0.0.1", 0)) as srv:
        port = srv.getsockname()[1]
    with pytest.raises(TransportOpenError, match="nothing listens"):
        open_transport({"kind": "serial", "url": f"socket://127.0.0.1:{port}"})


# --- CAN --------------------------------------------------------------------------------------


def virtual_can(channel: str, **extra) -> CanTransport:
    t = open_transport({"kind": "can", "interface": "virtual", "channel": channel, **extra})
    assert isinstance(t, CanTransport)
    return t


def test_can_virtual_standard_and_extended_frames():
    ch = f"auvgw-{uuid.uuid4().hex}"
    with virtual_can(ch) as tx, virtual_can(ch) as rx:
        frames = [
            (0x123, b"\x01\x02\x03", False),
            (0x18FF50E5, b"\x10\x20\x30\x40\x50\x60\x70\x80", True),
            (0x7FF, b"", False),
            (0x123, b"\xaa", True),  # same number, extended: a different identity
        ]
        for can_id, data, ext in frames:
            tx.send_frame(can_id, data, is_extended_id=ext)
        got = [rx.read(1.0) for _ in frames]
        assert rx.read(0.02) is None
    assert [(c.can_id, c.data, c.is_extended_id) for c in got] == frames
    assert all(c.t_device_s is not None and c.t_device_s > 0 for c in got)
    times = [c.t_recv_ns for c in got]
    assert times == sorted(times)
    assert tx.bytes_written == 12 and rx.bytes_read == 12


def test_can_filters_pass_only_matching_ids():
    ch = f"auvgw-{uuid.uuid4().hex}"
    filters = [{"can_id": 0x120, "can_mask": 0x7F0, "extended": False}]
    with virtual_can(ch) as tx, virtual_can(ch, filters=filters) as rx:
        tx.send_frame(0x300, b"\x01", is_extended_id=False)
        tx.send_frame(0x125, b"\x02", is_extended_id=True)  # right number, wrong id type
        tx.send_frame(0x12A, b"\x03", is_extended_id=False)
        c = rx.read(1.0)
        assert (c.can_id, c.data, c.is_extended_id) == (0x12A, b"\x03", False)
        assert rx.read(0.02) is None


def test_can_write_uses_configured_id_and_checks_ids():
    ch = f"auvgw-{uuid.uuid4().hex}"
    with virtual_can(ch, tx_id=0x0CF00400, tx_extended=True) as tx, virtual_can(ch) as rx:
        tx.write(b"\x01\x02")
        c = rx.read(1.0)
        assert (c.can_id, c.is_extended_id, c.data) == (0x0CF00400, True, b"\x01\x02")
        with pytest.raises(ValueError, match="standard 11-bit"):
            tx.send_frame(0x800, b"", is_extended_id=False)
        with pytest.raises(ValueError, match="exceed"):
            tx.send_frame(0x10, bytes(9), is_extended_id=False)
        with pytest.raises(TransportError, match="tx_id"):
            rx.write(b"\x00")  # no tx_id configured on rx


def _slcan_on(path: str):
    """A CAN transport through python-can's slcan driver on the pty at ``path`` (500 kbit/s)."""
    return open_transport(
        {
            "kind": "can",
            "interface": "slcan",
            "channel": path,
            "bitrate": 500000,
            "options": {"sleep_after_open": 0},
        }
    )


@pytest.mark.e2e
def test_can_slcan_adapter_on_a_pty(pty_pair):
    """python-can's real slcan driver against a pty: the way an emulated USB-CAN adapter works."""
    fds, path = pty_pair
    master = fds["master"]
    t = _slcan_on(path)
    setup = drain_master(master)
    assert b"S6\r" in setup and b"O\r" in setup  # 500 kbit/s, channel opened
    os.write(master, b"t1232AABB\rT18FF50E53010203\r")
    a, b = t.read(1.0), t.read(1.0)
    assert (a.can_id, a.is_extended_id, a.data) == (0x123, False, b"\xaa\xbb")
    assert (b.can_id, b.is_extended_id, b.data) == (0x18FF50E5, True, b"\x01\x02\x03")
    t.send_frame(0x1ABCDEF0, b"\x01\x02", is_extended_id=True)
    t.send_frame(0x42, b"\xff", is_extended_id=False)
    assert drain_master(master) == b"T1ABCDEF020102\rt0421FF\r"
    os.close(master)
    fds["master"] = None
    with pytest.raises(Disconnected, match=re.escape(path)):
        for _ in range(10):
            t.read(0.5)
    assert not t.is_open
    t.close()


def test_can_open_errors_name_channel_and_hint():
    ch = f"auvgwnope{uuid.uuid4().hex[:4]}"
    with pytest.raises(TransportOpenError) as info:
        open_transport({"kind": "can", "interface": "socketcan", "channel": ch})
    assert ch in str(info.value) and "ip link show" in str(info.value)


# --- UDP --------------------------------------------------------------------------------------


def test_udp_preserves_datagram_boundaries_and_replies_to_sender():
    with open_transport({"kind": "udp", "host": "127.0.0.1", "port": 0}) as t:
        assert isinstance(t, UdpTransport)
        port = t.local_address[1]
        assert port > 0 and f"bound port {port}" in t.describe()
        with pytest.raises(TransportError, match="no destination"):
            t.write(b"x")
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sender.bind(("127.0.0.1", 0))
        grams = [b"X" + bytes(100), b"", b"\x02" * 1, random.Random(1).randbytes(60_000)]
        for g in grams:
            sender.sendto(g, ("127.0.0.1", port))
        got = [t.read(1.0) for _ in grams]
        assert [c.data for c in got] == grams
        assert t.read(0.02) is None
        assert t.last_sender == sender.getsockname()
        t.write(b"reply")
        assert sender.recv(100) == b"reply"
        sender.close()


def test_udp_remote_and_port_in_use():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    cfg = {
        "kind": "udp",
        "host": "127.0.0.1",
        "port": 0,
        "remote_host": "127.0.0.1",
        "remote_port": rx.getsockname()[1],
        "receive_buffer_bytes": 65536,
    }
    with open_transport(cfg) as t:
        assert t._handle is not None
        assert t._handle.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= 65536
        t.write(b"hello")
        assert rx.recv(100) == b"hello" and t.bytes_written == 5
        port = t.local_address[1]
        with pytest.raises(TransportOpenError, match=f"127.0.0.1:{port}.*address in use"):
            open_transport({"kind": "udp", "host": "127.0.0.1", "port": port})
    rx.close()


def test_udp_multicast_group_join_on_loopback():
    group = "239.255.77.1"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cfg = {
        "kind": "udp",
        "host": "0.0.0.0",
        "port": port,
        "multicast_group": group,
        "multicast_interface": "127.0.0.1",
    }
    with open_transport(cfg) as a, open_transport(cfg) as b:  # reuse_address defaults on
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        s.sendto(b"XYZ88 datagram", (group, port))
        assert a.read(1.0).data == b"XYZ88 datagram"
        assert b.read(1.0).data == b"XYZ88 datagram"
        s.close()


# --- file replay ------------------------------------------------------------------------------


@pytest.fixture
def capture(tmp_path) -> tuple[Path, bytes]:
    data = random.Random(11).randbytes(10_000)
    path = tmp_path / "dvl.pd0"
    path.write_bytes(data)
    return path, data


def test_file_replay_as_fast_as_possible(capture):
    path, data = capture
    with open_transport({"kind": "file", "path": str(path), "chunk_size": 3000}) as t:
        assert isinstance(t, FileReplayTransport)
        chunks = [t.read(0.0) for _ in range(4)]
        with pytest.raises(EndOfStream, match="10000 bytes"):
            t.read(0.0)
        with pytest.raises(EndOfStream):
            t.read(0.0)
        t.write(b"poll")  # discarded, counted
        assert t.bytes_discarded == 4
    assert [len(c.data) for c in chunks] == [3000, 3000, 3000, 1000]
    assert b"".join(c.data for c in chunks) == data
    times = [c.t_recv_ns for c in chunks]
    assert times == sorted(times)


def test_file_replay_loops(capture):
    path, data = capture
    cfg = {"kind": "file", "path": path, "chunk_size": 4096, "byte_rate": 1e9, "loop": True}
    with open_transport(cfg) as t:
        got = b"".join(c.data for c in read_exactly(t, 25_000))
        assert t.loops == 2
    # chunks do not straddle the end of the file: each loop starts a fresh chunk
    assert got[:30_000] == (data * 3)[: len(got[:30_000])]


def test_file_replay_paced_follows_its_schedule(capture):
    path, data = capture
    cfg = {"kind": "file", "path": path, "byte_rate": 20_000, "chunk_size": 500}
    t = make_transport(cfg)
    schedule = replay_schedule(2_000, 500, 20_000)
    assert schedule == [(0, 500, 0.025), (500, 500, 0.05), (1000, 500, 0.075), (1500, 500, 0.1)]
    start = time.monotonic()
    with t:
        assert t.read(0.0) is None  # the first chunk is not due yet: nothing lost by asking
        chunks = []
        for _, length, due_s in schedule:
            c = t.read(1.0)
            assert len(c.data) == length
            chunks.append(c)
            assert time.monotonic() - start >= due_s  # released no earlier than due
    assert b"".join(c.data for c in chunks) == data[:2_000]


def test_file_replay_pace_from_baud_and_speed(tmp_path):
    cfg = parse_transport_config(
        {
            "kind": "file",
            "path": str(tmp_path / "x.bin"),
            "baud": 9600,
            "speed": 4.0,
        }
    )
    assert isinstance(cfg, FileTransportConfig)
    assert cfg.bytes_per_s == pytest.approx(9600 / 10 * 4)
    t = make_transport(cfg)
    assert t.chunk_size == 38  # 10 ms at 3840 B/s
    assert "9600 baud" in t.describe() and "4x real time" in t.describe()
    sched = replay_schedule(100, t.chunk_size, cfg.bytes_per_s)
    assert [n for _, n, _ in sched] == [38, 38, 24]
    assert sched[-1][2] == pytest.approx(100 / 3840)
    unpaced = make_transport({"kind": "file", "path": str(tmp_path / "x.bin")})
    assert unpaced.chunk_size == 4096 and "as fast as possible" in unpaced.describe()


def test_file_replay_open_errors(tmp_path):
    missing = tmp_path / "nope.bin"
    with pytest.raises(TransportOpenError, match=re.escape(str(missing)) + ".*no such file"):
        open_transport({"kind": "file", "path": missing})
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    with pytest.raises(TransportOpenError, match="empty"):
        open_transport({"kind": "file", "path": empty, "loop": True, "byte_rate": 1000})
    with open_transport({"kind": "file", "path": empty}) as t, pytest.raises(EndOfStream):
        t.read(0.0)


# --- configuration ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"kind": "serial", "url": "/dev/ttyUSB0", "baud": -1}, "dvl.transport.baud"),
        ({"kind": "serial", "url": "/dev/ttyUSB0", "baudrate": 9600}, "dvl.transport.baudrate"),
        ({"kind": "serial", "url": "/dev/ttyUSB0", "parity": "X"}, "dvl.transport.parity"),
        ({"kind": "serial"}, "dvl.transport.url"),
        ({"url": "/dev/ttyUSB0"}, "dvl.transport.kind"),
        ({"kind": "tcp", "url": "x"}, "dvl.transport.kind"),
        ({"kind": "can", "interface": "sockcan", "channel": "can0"}, "dvl.transport.interface"),
        ({"kind": "can", "interface": "socketcan"}, "'channel'"),
        ({"kind": "can", "interface": "virtual", "tx_id": 0x800, "tx_extended": False}, "tx_id"),
        ({"kind": "can", "interface": "virtual", "tx_id": 0x10}, "tx_extended"),
        (
            {
                "kind": "can",
                "interface": "virtual",
                "filters": [{"can_id": 0x900, "extended": False}],
            },
            "dvl.transport.filters.0",
        ),
        ({"kind": "can", "interface": "virtual", "options": {"bitrate": 1}}, "options"),
        ({"kind": "udp", "port": 70000}, "dvl.transport.port"),
        ({"kind": "udp", "port": 1, "multicast_group": "10.0.0.1"}, "multicast_group"),
        ({"kind": "udp", "port": 1, "remote_host": "10.0.0.2"}, "remote_port"),
        ({"kind": "file", "path": "x", "baud": 9600, "byte_rate": 960}, "byte_rate"),
        ({"kind": "file", "path": "x", "speed": 2.0}, "speed"),
        ({"kind": "file", "path": "x", "speed": 0}, "dvl.transport.speed"),
    ],
)
def test_config_errors_name_the_field(data, field):
    with pytest.raises(TransportConfigError) as info:
        parse_transport_config(data, where="dvl.transport")
    assert field in str(info.value)


def test_factory_builds_each_kind(tmp_path):
    kinds = {
        "serial": ({"url": "loop://"}, SerialTransport),
        "can": ({"interface": "virtual"}, CanTransport),
        "udp": ({"port": 0, "host": "127.0.0.1"}, UdpTransport),
        "file": ({"path": str(tmp_path / "f")}, FileReplayTransport),
    }
    for kind, (extra, cls) in kinds.items():
        cfg = parse_transport_config({"kind": kind, **extra})
        t = make_transport(cfg)
        assert type(t) is cls and not t.is_open and t.describe().startswith(kind)
        assert t.describe() == cfg.describe()  # the config alone names the port for status
    assert TransportClosed is Disconnected  # the gateway's name for the same exception
    with pytest.raises(TransportConfigError, match="kind"):
        make_transport({"kind": "carrier-pigeon"})


def test_docs_toml_examples_are_valid_configs():
    text = DOCS.read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    found = 0
    for block in blocks:
        doc = tomllib.loads(block)
        for name, dev in doc.get("devices", {}).items():
            if "transport" in dev:
                cfg = parse_transport_config(dev["transport"], where=f"devices.{name}.transport")
                assert make_transport(cfg).describe()
                found += 1
    assert found >= 8, found
    assert {"serial", "can", "udp", "file"} <= set(re.findall(r'kind = "(\w+)"', text))


def test_error_format_for_a_model_embedding_transport():
    """The gateway config embeds TransportConfig under devices.<name>.transport."""

    class Device(BaseModel):
        transport: TransportConfig

    class Vehicle(BaseModel):
        devices: dict[str, Device]

    bad = {"devices": {"dvl": {"transport": {"kind": "udp", "port": -5}}}}
    with pytest.raises(ValidationError) as info:
        Vehicle.model_validate(bad)
    text = format_validation_error(info.value, "vehicle.toml:")
    assert text == (
        "vehicle.toml: devices.dvl.transport.port: "
        "Input should be greater than or equal to 0 (got -5)"
    )


@pytest.mark.e2e
def test_can_slcan_reads_bursts_and_split_frames_in_order(pty_pair):
    """The slcan port is read in bulk (drivers/slcanbus.py BulkSlcanBus): frames of a burst, and a
    frame whose bytes arrive in two writes, come out whole and in order."""
    fds, path = pty_pair
    master = fds["master"]
    t = _slcan_on(path)
    drain_master(master)
    lines = [b"t3108%016X\r" % i for i in range(300)]
    os.write(master, b"".join(lines[:200]))
    os.write(master, lines[200][:7])  # half a frame: nothing to deliver yet from these bytes
    got = [t.read(1.0) for _ in range(200)]
    os.write(master, lines[200][7:] + b"".join(lines[201:]))
    got += [t.read(1.0) for _ in range(100)]
    assert [(c.can_id, int.from_bytes(c.data, "big")) for c in got] == [
        (0x310, i) for i in range(300)
    ]
    assert t.read(0.05) is None
    # lines cut by lost bytes are dropped and counted, status replies and BELLs are not frames
    bad = [b"t3108%015X\r" % 1, b"t31090011223344556677\r", b"T1234567g100\r", b"t31\r",
           b"t3108001122334455667\r"]  # fmt: skip
    good = [b"t3100\r", b"T123456782BEEF\r", b"r7FF8\r", b"t3102ABCD1234\r"]
    os.write(master, b"".join([bad[0], good[0], b"F00\r", bad[1], b"\a", good[1], bad[2],
                               good[2], bad[3], bad[4], good[3]]))  # fmt: skip
    got = [t.read(1.0) for _ in range(3)]  # (the remote frame is skipped, and counted)
    assert [(c.can_id, c.data) for c in got] == [
        (0x310, b""), (0x12345678, b"\xbe\xef"), (0x310, b"\xab\xcd")
    ]
    assert t.read(0.05) is None
    assert t.losses()["malformed_lines"] == len(bad) and t.frames_skipped == 1
    t.close()


def _count_selects(monkeypatch) -> list[int]:
    """Count the SLCAN reader's waits on its port: ``[n]``, n the ``select`` calls so far."""
    import types

    from auvgw.drivers import slcanbus

    waits = [0]
    real_select = slcanbus.select.select

    def counting_select(*a):
        waits[0] += 1
        return real_select(*a)

    monkeypatch.setattr(slcanbus, "select", types.SimpleNamespace(select=counting_select))
    return waits


@pytest.mark.e2e
def test_can_slcan_idle_line_waits_without_polling(pty_pair, monkeypatch):
    """A quiet slcan line is waited on with ``select`` (one wake when bytes come), not polled
    with python-can's 1 ms ``read(1)``: a 0.3 s read of nothing waits once or twice."""
    fds, path = pty_pair
    master = fds["master"]
    t = _slcan_on(path)
    drain_master(master)
    waits = _count_selects(monkeypatch)
    assert t.read(0.3) is None
    assert waits[0] <= 2  # polling: about 300
    os.write(master, b"t3108%016X\r" % 7)
    c = t.read(2.0)
    assert c is not None and (c.can_id, int.from_bytes(c.data, "big")) == (0x310, 7)
    t.close()


@pytest.mark.e2e
def test_can_slcan_drain_takes_a_burst_without_waiting(pty_pair, monkeypatch):
    """``drain()`` after a read: the frames whose lines came in the same read of the adapter,
    in order, without waiting on the port (no ``select``); an error line (BELL) ends it; with
    nothing buffered it returns at once. Other transports drain nothing."""
    fds, path = pty_pair
    master = fds["master"]
    t = _slcan_on(path)
    drain_master(master)
    os.write(master, b"".join(b"t3108%016X\r" % i for i in range(5)) + b"\at3101AA\r")
    first = t.read(2.0)
    waits = _count_selects(monkeypatch)
    rest = t.drain()
    assert [int.from_bytes(c.data, "big") for c in [first, *rest]] == [0, 1, 2, 3, 4]
    assert waits[0] == 0
    after_bell = t.read(2.0)
    assert (after_bell.can_id, after_bell.data) == (0x310, b"\xaa")
    assert t.drain() == [] and waits[0] <= 1
    t.close()
    with open_transport({"kind": "udp", "host": "127.0.0.1", "port": 0}) as u:
        assert u.drain() == []
