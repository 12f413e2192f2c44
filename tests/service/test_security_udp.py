"""UDP inputs filtered and bounded: allowed senders, counted rejects, no cache grown by the wire.

Loopback only: the gateway's device binds 127.0.0.1, the "attacker" sends from 127.0.0.2 (any
127/8 address is loopback on Linux). Memory is measured with tracemalloc (Python allocations of
every thread), with a tolerance, never a time.
"""

from __future__ import annotations

import gc
import socket
import tracemalloc

import pytest

from auvgw.config.gateway import parse_gateway_config
from auvgw.config.transport import TransportConfigError, parse_transport_config
from auvgw.drivers import kongsberg
from auvgw.drivers.transports import open_transport
from auvgw.gateway import Gateway
from auvgw.testing import free_port, wait_until

ATTACKER = "127.0.0.2"
#: datagrams sent before waiting for the gateway to catch up (well inside the default socket
#: receive buffer, so the kernel drops none of them)
BATCH = 200
N_REJECTED = 1_000
N_ALLOWED = 300


def _crafted(i: int) -> bytes:
    """A valid Depth ('D') datagram with zero beams and the i-th resolution pair: each one used to
    build (and cache forever) a new beam table class."""
    empty = kongsberg.make_depth(time=0.0, depth=[], across=[], along=[])
    base = bytearray(kongsberg.encode(empty))
    base[28], base[29] = 1 + i % 255, 1 + (i // 255) % 255
    return kongsberg._seal(base, base[5])


def _sender(host: str) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((host, 0))
    return s


def test_udp_transport_drops_and_counts_datagrams_from_other_senders():
    port = free_port()
    cfg = {"kind": "udp", "host": "127.0.0.1", "port": port, "allowed_senders": ["127.0.0.1"]}
    with open_transport(cfg) as t, _sender(ATTACKER) as bad, _sender("127.0.0.1") as good:
        for i in range(5):
            bad.sendto(b"evil%d" % i, ("127.0.0.1", port))
        good.sendto(b"hello", ("127.0.0.1", port))
        chunk = t.read(10.0)
        assert chunk is not None and chunk.data == b"hello"
        assert t.rejected_datagrams == 5 and t.rejected_bytes == 25
        assert t.last_rejected_sender.startswith(f"{ATTACKER}:")
        assert t.chunks_read == 1 and t.last_sender == good.getsockname()


def test_udp_default_allows_the_configured_device_address_only():
    port = free_port()
    cfg = {
        "kind": "udp",
        "host": "127.0.0.1",
        "port": port,
        "remote_host": "127.0.0.3",
        "remote_port": 9,
    }
    assert parse_transport_config(cfg).sender_filter() == ["127.0.0.3"]
    assert "from 127.0.0.3" in parse_transport_config(cfg).describe()
    with open_transport(cfg) as t, _sender(ATTACKER) as bad, _sender("127.0.0.3") as dev:
        bad.sendto(b"x", ("127.0.0.1", port))
        dev.sendto(b"ping", ("127.0.0.1", port))
        chunk = t.read(10.0)
        assert chunk is not None and chunk.data == b"ping" and t.rejected_datagrams == 1
    any_cfg = {**cfg, "allowed_senders": ["any"]}
    assert parse_transport_config(any_cfg).sender_filter() is None
    nets = {**cfg, "allowed_senders": ["127.0.0.0/30", "::1"]}
    assert parse_transport_config(nets).sender_filter() == ["127.0.0.0/30", "::1"]


def test_udp_allowed_senders_are_validated():
    with pytest.raises(TransportConfigError, match=r"allowed_senders.*not an IP address"):
        parse_transport_config({"kind": "udp", "port": 1, "allowed_senders": ["10.0.0.300"]})


def _traced_mb() -> float:
    gc.collect()
    return tracemalloc.get_traced_memory()[0] / 1e6


def _flood(sock: socket.socket, port: int, start: int, n: int, done, what: str) -> None:
    """Send crafted datagrams i = start..start+n in batches, waiting for ``done(sent)`` each."""
    for b0 in range(start, start + n, BATCH):
        for i in range(b0, min(b0 + BATCH, start + n)):
            sock.sendto(_crafted(i), ("127.0.0.1", port))
        sent = min(b0 + BATCH, start + n) - start
        wait_until(lambda s=sent: done(s), timeout=60.0, what=f"{what}: {sent} datagrams")


@pytest.mark.e2e
def test_udp_flood_memory_is_flat_when_rejected_and_bounded_when_allowed():
    port = free_port()
    cfg = parse_gateway_config(
        {
            "vehicle": "sec1",
            "devices": {
                "mbes": {
                    "format": "kongsberg",
                    "transport": {
                        "kind": "udp",
                        "host": "127.0.0.1",
                        "port": port,
                        "allowed_senders": ["127.0.0.1"],
                    },
                }
            },
        }
    )
    tracemalloc.start()
    try:
        with Gateway(cfg) as gw, _sender(ATTACKER) as bad, _sender("127.0.0.1") as good:
            st = lambda: gw.device_status("mbes")  # noqa: E731
            wait_until(lambda: st()["connected"], what="mbes socket open")
            # warm up the decode path (first tables, publishers, status) from the allowed sender
            _flood(good, port, 0, 300, lambda s: st()["frames"] >= s, "warm-up")
            frames0 = st()["frames"]
            m0 = _traced_mb()
            rejected = lambda s: st()["rejected_datagrams"] >= s  # noqa: E731
            _flood(bad, port, 1000, N_REJECTED, rejected, "rejects")
            m1 = _traced_mb()
            snap = st()
            assert snap["rejected_datagrams"] == N_REJECTED
            assert snap["last_rejected_sender"].startswith(f"{ATTACKER}:")
            assert snap["frames"] == frames0  # nothing from the attacker reached the framer
            assert m1 - m0 < 1.0, f"rejected flood grew traced memory by {m1 - m0:.2f} MB"
            # the allowed sender floods far above a multibeam's nominal ping rate (tens of Hz),
            # every datagram with a new resolution pair: the beam table cache stays bounded
            _flood(good, port, 300, N_ALLOWED, lambda s: st()["frames"] >= frames0 + s, "allowed")
            m2 = _traced_mb()
            assert st()["messages"]["Depth"] >= N_ALLOWED
            print(
                f"traced MB: start {m0:.2f}, after {N_REJECTED} rejected {m1:.2f}, "
                f"after {N_ALLOWED} allowed {m2:.2f}"
            )
            # unbounded, 300 new tables cost about 5.4 MB (18 kB each); measured growth: 0.0 MB
            assert m2 - m1 < 3.0, f"allowed flood grew traced memory by {m2 - m1:.2f} MB"
            assert kongsberg.depth_beam_table.cache_info().currsize <= (
                kongsberg.DEPTH_TABLE_CACHE_SIZE
            )
    finally:
        tracemalloc.stop()
