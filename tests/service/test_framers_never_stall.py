"""No byte can silence a sensor: per format, a frame whose length field claims the most the
format allows, followed by good frames fed one per chunk, costs that frame only (the next good
frame comes out with the chunk that completes it); a partial frame that waits too long is
dropped and counted; over UDP a bad datagram costs that datagram only (real sockets)."""

from __future__ import annotations

import socket
import struct
import time
from pathlib import Path

import pytest

from auvgw.config.transport import UdpTransportConfig
from auvgw.decoding import DeviceDecoder
from auvgw.drivers import kongsberg as kb
from auvgw.drivers import seanet as sn
from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import ErrorPolicy, Framer
from auvgw.drivers.seanet import v4log as v4
from auvgw.drivers.transports import Chunk, make_transport
from auvgw.testing.format_samples import KONGSBERG_FRAMES, pd0_frames, samples, v4log_records


def _max_pd0(frame: bytes) -> bytes:
    out = bytearray(frame)
    struct.pack_into("<H", out, 2, 0xFFFF)  # nBytes: the most a u16 holds
    return bytes(out)


def _max_seanet(frame: bytes) -> bytes:
    n = sn.MAX_PACKET_SIZE - 6  # hex and binary lengths agree: the header passes
    return b"@" + b"%04X" % n + struct.pack("<H", n) + frame[7:]


def _max_kongsberg(frame: bytes) -> bytes:
    return struct.pack("<I", kb.KongsbergFramer.max_frame_size - 4) + frame[4:]


def _max_hn100(frame: bytes) -> bytes:
    return frame[:2] + struct.pack("<H", 0xFFFF) + frame[4:]


def _max_geoswath(ping: bytes) -> bytes:
    """The most RAA samples the table allows, ``ping_size`` raised to match (no sync, no
    checksum: the header is self-consistent and claims about 200 kB)."""
    from auvgw.drivers.geoswath import default_codec

    lay = default_codec().layout
    out = bytearray(ping)
    n, size = struct.unpack_from("<i", out, 32)[0], struct.unpack_from("<i", out, 16)[0]
    struct.pack_into("<i", out, 32, lay.max_samples)
    struct.pack_into("<i", out, 16, size + (lay.max_samples - n) * 6)
    return bytes(out)


def _unterminated(line: bytes) -> bytes:
    return line.rstrip(b"\r\n")  # a line claims everything up to its terminator


MAXIMAL = {
    "pd0": _max_pd0,
    "seanet": _max_seanet,
    "kongsberg": _max_kongsberg,
    "hn100": _max_hn100,
    "geoswath": _max_geoswath,
    "ms3a": _unterminated,
    "pd6": _unterminated,
}


def lag_of(framer: Framer) -> int:
    """1 for a framer that delivers a complete frame with the chunk bringing the next frame's
    header (GeoSwath: it checks that a ping ends where one starts, docs/protocols/geoswath.md),
    else 0."""
    return int(hasattr(framer, "held"))


def feed_one_per_chunk(
    framer: Framer, head: bytes, good: list[bytes], before: list[bytes] | None = None
) -> None:
    """Feed ``head`` (``before``: the frames it releases, none by default) then each good frame
    as its own chunk; each must come out with its chunk (with a lag, :func:`lag_of`, with the
    next chunk; the last one at the end)."""
    lag = lag_of(framer)
    assert [f.data for f in framer.feed(head)] == (before or [])
    for i, g in enumerate(good):
        got = [f.data for f in framer.feed(g)]
        assert got == good[max(i - lag, 0) : i + 1 - lag], f"good frame #{i - lag} held back"
    if lag:
        assert [f.data for f in framer.finish()] == good[-lag:]


@pytest.mark.parametrize("fmt", sorted(MAXIMAL))
def test_maximal_claimed_length_costs_that_frame_only(fmt: str, shared_data: Path) -> None:
    good = samples(fmt, shared_data)
    bad = MAXIMAL[fmt](good[0])
    framer = get_format(fmt).framer(policy=ErrorPolicy.IGNORE)
    lag = lag_of(framer)
    assert [f.data for f in framer.feed(good[0])] == good[: 1 - lag]
    feed_one_per_chunk(framer, bad, good[1:], before=good[1 - lag : 1])
    s = framer.stats
    assert s.frames == len(good) and s.bad_frames == 1, s.as_dict()
    assert s.skipped_bytes == len(bad)


def test_v4log_maximal_record_length_costs_that_record_only(tmp_path: Path) -> None:
    """V4LOG records have no sync: the records after a maximal length field are found inside
    it and come out at once; every intact record is kept."""
    head, spans = v4log_records(tmp_path / "a.V4LOG")
    bad = bytearray(spans[1])
    struct.pack_into("<H", bad, 0, v4.V4LogFramer.max_frame_size)
    framer = v4.V4LogFramer(policy=ErrorPolicy.IGNORE)
    assert [f.data for f in framer.feed(head + spans[0])] == [spans[0]]
    feed_one_per_chunk(framer, bytes(bad), spans[2:])
    assert framer.stats.frames == len(spans) - 1 and framer.stats.bad_frames == 1


def test_v4log_corrupted_length_keeps_every_intact_record(tmp_path: Path) -> None:
    """A length field off by a plausible amount (a bit flip): the record it names would swallow
    its neighbours; the SeaNet content check refuses it and every other record is delivered."""
    head, intact = v4log_records(tmp_path / "b.V4LOG", repeats=4)
    data = head + b"".join(intact)
    assert [f.data for f in v4.V4LogFramer(policy="ignore").frames([data])] == intact
    starts, pos = [], len(head)
    for rec in intact:
        starts.append(pos)
        pos += len(rec)
    known = set(intact)
    assert len(known) == len(intact) > 30
    for k in range(1, len(intact) - 1):
        for bit in range(11):
            bad = bytearray(data)
            struct.pack_into("<H", bad, starts[k], len(intact[k]) ^ (1 << bit))
            got = [f.data for f in v4.V4LogFramer(policy="ignore").frames([bytes(bad)])]
            # the corrupted record may pass (a plausible length); no intact one is lost
            assert [g for g in got if g in known] == intact[:k] + intact[k + 1 :], (k, bit)
            assert len(got) <= len(intact)


def test_partial_frame_older_than_the_bound_is_dropped_and_counted(shared_data: Path) -> None:
    good = pd0_frames(shared_data, 3)
    framer = get_format("pd0").framer(policy=ErrorPolicy.IGNORE)
    assert framer.feed(good[0][:-40], now=100.0) == []  # cut: waits for 40 more bytes
    assert framer.expire(101.0, max_age_s=2.0) == [] and framer.stats.bad_frames == 0
    assert framer.feed(b"\x00", now=101.5) == []  # more bytes do not restart its clock
    assert framer.waiting_s == 100.0
    assert framer.expire(102.5, max_age_s=2.0) == []  # dropped; nothing queued behind it
    assert framer.stats.bad_frames == 1 and dict(framer.stats.reasons) == {"stale": 1}
    assert framer.waiting_s is None
    assert [f.data for f in framer.feed(good[1], now=104.0)] == [good[1]]
    assert framer.stats.skipped_bytes == len(good[0]) - 40 + 1


def test_device_decoder_expires_by_its_configured_age(shared_data: Path) -> None:
    good = pd0_frames(shared_data, 2)
    dec = DeviceDecoder("dvl", get_format("pd0"), max_partial_age_s=0.05)
    assert dec.feed(Chunk(good[0][:100], 0)) == []
    deadline = time.monotonic() + 30.0
    while not dec.has_stale(time.monotonic()):
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert dec.expire(time.monotonic()) == []
    assert dec.counts().reasons == {"stale": 1}
    assert [i.raw for i in dec.feed(Chunk(good[1], 0))] == [good[1]]


def test_one_bad_udp_datagram_costs_that_datagram_only() -> None:
    """Real UDP sockets: Kongsberg datagrams, one with a maximal length field among them."""
    good = list(KONGSBERG_FRAMES) * 3
    bad = _max_kongsberg(good[1])
    tr = make_transport(UdpTransportConfig(kind="udp", host="127.0.0.1", port=0))
    tr.open()
    try:
        port = tr.local_address[1]
        dec = DeviceDecoder("mbes", get_format("kongsberg"), datagrams=True)
        assert dec.datagrams
        wire = [good[0], bad, *good[1:]]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for d in wire:
                tx.sendto(d, ("127.0.0.1", port))
        out: list[bytes] = []
        for _ in wire:
            chunk = tr.read(30.0)
            assert chunk is not None
            out += [i.raw for i in dec.feed(chunk)]
    finally:
        tr.close()
    assert out == good
    c = dec.counts()
    assert (c.frames, c.bad_frames, c.skipped_bytes) == (len(good), 1, len(bad))


def test_v4log_corrupted_record_judged_the_same_whatever_the_chunk_split(tmp_path: Path) -> None:
    """Issue 18's reproducer (docs/reliability.md): record 9 with its length 20 -> 22 swallows
    the first bytes of record 10. With the chunk ending 7 bytes into record 10 (its length is
    in, its TDateTime is not), the framer must give what it gives fed whole: every intact
    record (record 9 passes, its content is plausible; record 10 is found in its last bytes)."""
    head, recs = v4log_records(tmp_path / "c.V4LOG")
    assert len(recs[9]) == 20
    bad = bytearray(recs[9])
    struct.pack_into("<H", bad, 0, 22)
    wire = head + b"".join(recs[:9]) + bytes(bad) + b"".join(recs[10:])
    framer = v4.V4LogFramer(policy="ignore")
    whole = [(f.data, f.offset) for f in framer.frames([wire])]
    assert [d for d, _ in whole if d in recs] == recs[:9] + recs[10:]
    cut = len(head) + sum(map(len, recs[:10])) + 7
    split = v4.V4LogFramer(policy="ignore")
    assert [(f.data, f.offset) for f in split.frames([wire[:cut], wire[cut:]])] == whole
    assert split.stats.as_dict() == framer.stats.as_dict() and framer.stats.bad_frames == 0
