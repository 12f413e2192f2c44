"""Lag and loss visible per device: the age and transport lag of the newest sample, the bytes
the framer skipped and what the transport lost (an SLCAN adapter's overruns, UDP datagrams the
kernel dropped), in the gateway's device status."""

from __future__ import annotations

import os
import socket
import threading
import tty
from pathlib import Path

import can
import numpy as np
import pytest

from auvgw.config.gateway import parse_gateway_config
from auvgw.drivers import hn100
from auvgw.drivers.geoswath import default_codec
from auvgw.drivers.transports import (
    CanTransport,
    UdpTransport,
    open_transport,
    udp_receive_buffer,
)
from auvgw.health import DeviceHealth, LagTracker, device_time_s
from auvgw.sim_devices.slcan import SlcanAdapter
from auvgw.testing import PtyDevice, wait_until


def hn100_frame(i: int, t: float) -> bytes:
    """One HN-100 solution whose device clock reads ``t`` seconds."""
    status = hn100.CODEC.status_word(aligned=True, gnss_aided=False, dvl_aided=True, error=False)
    msg = hn100.Hn100Nav(
        seq=i % 65536, status=status, time=t, roll=0.01, pitch=-0.02, heading=0.5, rate_x=0.0,
        rate_y=0.0, rate_z=0.1, accel_x=0.01, accel_y=0.0, accel_z=-9.81, vel_n=1.0, vel_e=0.1,
        vel_d=0.0, latitude=0.7, longitude=0.1, depth=20.0,
    )  # fmt: skip
    return hn100.CODEC.encode(msg)


def test_lag_tracker_measures_against_the_best_offset_and_rebases_on_a_clock_step() -> None:
    lag = LagTracker()
    assert lag.observe(100.0, 10.0) == 0.0  # baseline offset 90
    assert lag.observe(100.5, 10.1) == pytest.approx(0.4)  # 0.4 s later than the device
    assert lag.observe(100.6, 10.6) == 0.0  # a better offset is the new baseline
    assert lag.observe(101.0, 0.2) == 0.0  # device clock wrapped: baseline again
    h = DeviceHealth("ins", "hn100")
    h.set_connected(True)
    h.seen(5_000_000_000, "Hn100Nav", 105_000_000_000, 10.0)
    h.seen(5_100_000_000, "Hn100Nav", 106_000_000_000, 10.5)  # vehicle-paced stamps
    snap = h.snapshot(6_000_000_000, now_stamp_ns=108_000_000_000)
    assert snap["lag_s"] == pytest.approx(0.5) and snap["lag_max_s"] == pytest.approx(0.5)
    assert snap["age_s"] == pytest.approx(2.5)  # 2 s on the stamp clock + the lag
    assert snap["silent_s"] == pytest.approx(0.9)  # host clock
    assert device_time_s(object()) is None


@pytest.mark.e2e
def test_a_stalled_device_ages_a_backlog_lags_and_garbage_is_skipped(tmp_path: Path) -> None:
    """A real pty and the in-process gateway: a burst of ten solutions, one second of nothing,
    then ten more that continue the device clock (as a reader that fell one second behind would
    see them), 37 garbage bytes between; then the device stalls and the age grows."""
    from auvgw.gateway import Gateway

    dev = PtyDevice(tmp_path / "ins")
    cfg = parse_gateway_config(
        {"vehicle": "lag1", "devices": {"ins": {"format": "hn100",
         "transport": {"kind": "serial", "url": str(tmp_path / "ins")}}}}
    )  # fmt: skip
    garbage = b"\x00\x11" * 18 + b"\x22"  # no sync byte (AA 48) in it
    try:
        with Gateway(cfg) as gw:
            wait_until(lambda: gw.device_status("ins")["connected"], what="connected")
            assert dev.master is not None
            os.write(dev.master, b"".join(hn100_frame(i, 10 + i / 100) for i in range(10)))
            wait_until(lambda: gw.device_status("ins")["frames"] == 10, what="first burst")
            first = gw.device_status("ins")
            assert first["lag_s"] < 0.5  # one burst: only a reader starved between its chunks lags
            threading.Event().wait(1.0)  # the device's next samples arrive a second late
            late = b"".join(hn100_frame(i, 10 + i / 100) for i in range(10, 20))
            os.write(dev.master, garbage + late)
            wait_until(lambda: gw.device_status("ins")["frames"] == 20, what="second burst")
            st = gw.device_status("ins")
            # received >= 1 s after the first burst, device times 0.1 s on: at least 0.9 s late
            assert st["lag_s"] >= 0.9 and st["lag_max_s"] >= st["lag_s"]
            assert st["skipped_bytes"] == len(garbage) and st["bad_frames"] == 0
            assert st["transport_losses"] == {} and st["transport_lost"] == 0  # a pty: none
            a0 = st["age_s"]
            # stalled: the newest sample keeps ageing on the host clock
            aged = wait_until(
                lambda: (s := gw.device_status("ins"))["age_s"] > a0 + 1.5 and s,
                what="age grows",
            )
            assert aged["age_s"] >= aged["silent_s"] + aged["lag_s"] - 0.01
            assert aged["frames"] == 20 and aged["lag_s"] == st["lag_s"]
            assert aged["stale"] is False  # stale_after_s defaults longer; the age says more
    finally:
        dev.unplug()


def test_udp_datagrams_the_kernel_dropped_are_counted() -> None:
    """A receive buffer of 2 KiB (the kernel doubles it) and 300 datagrams of 1000 B sent
    before one is read: every datagram is either read or counted as dropped (the count comes
    with the next datagram the kernel queues)."""
    n = 300
    t = open_transport(
        {"kind": "udp", "host": "127.0.0.1", "port": 0, "receive_buffer_bytes": 2048}
    )
    assert isinstance(t, UdpTransport)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for i in range(n):
            tx.sendto(i.to_bytes(2, "big") + bytes(998), ("127.0.0.1", t.local_address[1]))
        got = []
        while (c := t.read(0.2)) is not None:
            got.append(int.from_bytes(c.data[:2], "big"))
        # the kernel reports the count with the next datagram queued after the drops
        tx.sendto(n.to_bytes(2, "big"), ("127.0.0.1", t.local_address[1]))
        c = t.read(5.0)
        assert c is not None and c.data == n.to_bytes(2, "big")
        drops = t.losses()["kernel_drops"]
        assert drops > 0 and len(got) + drops == n
        assert got == sorted(got)  # the ones read, in order
    finally:
        tx.close()
        t.close()


def _rmem_max() -> int:
    return int(Path("/proc/sys/net/core/rmem_max").read_text())


def _burst(t: UdpTransport, datagrams: list[bytes]) -> tuple[int, int]:
    """Send ``datagrams`` to ``t`` before it reads one (its reader paused), then read them all:
    (datagrams read, datagrams the kernel counted as dropped)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for d in datagrams:
            tx.sendto(d, ("127.0.0.1", t.local_address[1]))
        got = 0
        while (c := t.read(0.2)) is not None:
            assert c.data in datagrams
            got += 1
        # the kernel reports its drops with the next datagram it queues: a small carrier
        tx.sendto(b"end", ("127.0.0.1", t.local_address[1]))
        c = t.read(5.0)
        assert c is not None and c.data == b"end"
    return got, t.losses()["kernel_drops"]


def test_a_geoswath_udp_burst_fits_the_sized_buffer_and_the_default_s_drops_are_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """64 GeoSwath pings of 4000 samples (24 kB, as the emulator's) sent while the reader is
    paused: the kernel's default receive buffer drops some, and what was sent minus what was
    read is exactly its ``SO_RXQ_OVFL`` count; the buffer the gateway asks for a GeoSwath
    (:func:`udp_receive_buffer` of the format's largest datagram) holds them all where
    ``net.core.rmem_max`` grants it, and a size the kernel caps is said in the log."""
    codec = default_codec()
    rng = np.random.default_rng(0)
    raa = np.frombuffer(rng.bytes(6 * 4000), codec.layout.arrays[0][2])
    pings = [
        codec.encode(codec.make_ping({"ping_number": k, "ping_time": 1.0 + k, "side": k % 2},
                                     {"raa": raa}))
        for k in range(64)
    ]  # fmt: skip
    size = udp_receive_buffer(codec.framer().max_frame_size)
    udp = {"kind": "udp", "host": "127.0.0.1", "port": 0}
    default = open_transport(udp)
    sized = open_transport({**udp, "receive_buffer_bytes": size})
    assert isinstance(default, UdpTransport) and isinstance(sized, UdpTransport)
    try:
        got, drops = _burst(default, pings)
        assert drops > 0 and got + drops == len(pings)
        assert sized.receive_buffer_granted is not None
        if sized.receive_buffer_granted >= 2 * size:  # not capped by net.core.rmem_max
            assert _burst(sized, pings) == (len(pings), 0)
    finally:
        default.close()
        sized.close()
    with caplog.at_level("WARNING", "auvgw.drivers.transports"):
        capped = open_transport({**udp, "receive_buffer_bytes": 1 << 27})  # over rmem_max
        capped.close()
    assert isinstance(capped, UdpTransport) and capped.receive_buffer_granted is not None
    was_capped = capped.receive_buffer_granted < 2 << 27
    assert ("capped by net.core.rmem_max" in caplog.text) == was_capped


@pytest.mark.e2e
def test_slcan_adapter_overruns_are_counted(tmp_path: Path) -> None:
    """An emulated USB-CAN adapter whose host link stalls (the gateway does not read) loses
    frames and sets its data-overrun flag; the transport asks (Lawicel ``F``) and counts it,
    and every frame is either received or counted as dropped by the adapter."""
    adapter = SlcanAdapter("ovr", speed=1000.0, link=tmp_path / "can")
    adapter.port.max_queue_bytes = 2048
    t = open_transport(
        {"kind": "can", "interface": "slcan", "channel": adapter.device, "bitrate": 500000,
         "options": {"sleep_after_open": 0}}
    )  # fmt: skip
    assert isinstance(t, CanTransport)
    try:
        wait_until(lambda: adapter.is_open, what="channel open")
        c0 = adapter.stats.commands
        assert t.losses() == {
            "adapter_data_overrun": 0,
            "adapter_rx_fifo_full": 0,
            "malformed_lines": 0,
        }
        wait_until(lambda: adapter.stats.commands > c0, what="the first F answered")
        sent = 3000
        msgs = [can.Message(arbitration_id=0x100 + i % 8, data=bytes(8), is_extended_id=False)
                for i in range(sent)]  # fmt: skip
        for i in range(0, sent, 10):
            adapter.send_many(msgs[i : i + 10])
        assert adapter.stats.dropped_port > 0
        received = 0
        while t.read(0.3) is not None:
            received += 1
        assert received + adapter.stats.dropped_port == sent
        t.losses()  # F: the overrun flag set since the last request
        while t.read(0.3) is not None:
            received += 1
        assert t.losses()["adapter_data_overrun"] == 1  # one request, one set flag
    finally:
        t.close()
        adapter.close()


@pytest.mark.e2e
def test_malformed_slcan_lines_are_dropped_and_counted_not_a_reconnect() -> None:
    """Lines cut by bytes lost on the host link (the end of one frame joined to the next, a
    wrong length for the DLC, a bad digit) are dropped and counted; the frames around them
    come through and the transport stays open."""
    master, slave = os.openpty()
    tty.setraw(slave)
    t = open_transport(
        {"kind": "can", "interface": "slcan", "channel": os.ttyname(slave),
         "options": {"sleep_after_open": 0}}
    )  # fmt: skip
    try:
        os.read(master, 100)  # the open command
        good = [b"T0A1000062AABB\r", b"t1232AABB\r", b"t12380102030405060708\r"]
        cut = b"T0A10000682AB" + b"t1232AABB\r"  # a line cut short, joined to the next one
        bad = [cut, b"t12X2AABB\r", b"t1239AABB\r", b"T0A100006\r"]
        os.write(master, good[0] + b"".join(bad) + good[1] + good[2])
        got = []
        while (c := t.read(0.5)) is not None:
            got.append((c.can_id, c.data))
        assert got == [(0xA100006, b"\xaa\xbb"), (0x123, b"\xaa\xbb"), (0x123, bytes(range(1, 9)))]
        assert t.losses()["malformed_lines"] == len(bad) and t.is_open
    finally:
        t.close()
        os.close(master)
        os.close(slave)


@pytest.mark.e2e
def test_gateway_status_counts_udp_kernel_drops_and_garbage_as_lost_bytes() -> None:
    """The in-process gateway on a UDP port with a 2 KiB receive buffer: a flood of garbage
    datagrams (1000 B, no Kongsberg frame in them) is either read, then skipped by the framer
    (``skipped_bytes``), or dropped by the kernel (``transport_losses.kernel_drops``): every
    datagram is accounted for in the device status."""
    from auvgw.gateway import Gateway

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    cfg = parse_gateway_config(
        {"vehicle": "loss1", "devices": {"mbes": {"format": "kongsberg", "transport": {
            "kind": "udp", "host": "127.0.0.1", "port": port, "receive_buffer_bytes": 2048,
            "allowed_senders": ["127.0.0.1"]}},
            "gs": {"format": "geoswath", "transport": {"kind": "udp", "host": "127.0.0.1",
                                                       "port": 0}}}}
    )  # fmt: skip
    n, size = 400, 1000
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with Gateway(cfg) as gw:
            wait_until(lambda: gw.device_status("mbes")["connected"], what="connected")
            for _ in range(n):
                tx.sendto(b"\x55" * size, ("127.0.0.1", port))

            # Linux reports the drops with the next datagram it queues: send slow "carriers"
            # (garbage too) until one reports every drop before it and is read itself
            carriers = 0

            def counted() -> dict | None:
                st = gw.device_status("mbes")
                drops = st["transport_losses"].get("kernel_drops", 0)
                return st if st["skipped_bytes"] // size + drops == n + carriers else None

            while (st := counted()) is None:
                assert carriers < 60, (carriers, gw.device_status("mbes"))
                tx.sendto(b"\x55" * size, ("127.0.0.1", port))
                carriers += 1
                threading.Event().wait(0.6)  # the gateway reads the counters every 0.5 s
            assert st["transport_lost"] == st["transport_losses"]["kernel_drops"] > 0
            assert st["frames"] == 0 and st["skipped_bytes"] % size == 0
            # a UDP device without receive_buffer_bytes gets a buffer sized from its format
            gs = wait_until(lambda: gw.devices["gs"].transport, what="the GeoSwath socket")
            asked = udp_receive_buffer(default_codec().framer().max_frame_size)
            assert asked > 1 << 20  # 32 of its largest (a UDP payload's worth) datagrams
            assert gs.receive_buffer_granted == 2 * min(asked, _rmem_max())
    finally:
        tx.close()
