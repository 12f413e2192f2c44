"""GeoSwath Plus RDF / broadcast pings: table, codec round trip, framer under corruption."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.drivers.geoswath import (
    GeoSwathCodec,
    GeoSwathFramer,
    GeoSwathPing,
    RdfFileHeader,
    default_codec,
    read_rdf,
)
from auvgw.drivers.tablecodec import TableError
from auvgw.ground.errors import DataError
from auvgw.ground.paths import config_file

CODEC = default_codec()
LAY = CODEC.layout
HSIZE = LAY.ping_header.itemsize
DT = {name: dt for name, _, dt in LAY.arrays}
N_STRINGS = len(LAY.strings)


def make_ping(rng: np.random.Generator, number: int, prev: int, n: int = 40) -> GeoSwathPing:
    raa = np.zeros(n, DT["raa"])
    raa["time"] = np.arange(n) * 7 + 20
    raa["sine"] = rng.integers(-32767, 32768, n)
    raa["amplitude"] = rng.integers(0, 65536, n)
    mru = np.zeros(2, DT["mru"])
    mru["roll"], mru["pitch"], mru["heave"], mru["time_stamp"] = 1.5, -0.5, 0.1, 100.0 + number
    nav = np.zeros(1, DT["nav"])
    nav["x"], nav["y"], nav["quality"] = 500123.25, 6201234.5, 4
    svs = np.zeros(1, DT["minisvs"])
    svs["velocity"] = 1493.5
    strings = [b"$GPGGA,1*00\r\n", b"", b"$HEHDT,12.0,T*00\r\n", b"", b"", b"", b""]
    return CODEC.make_ping(
        {
            "ping_number": number,
            "ping_time": 100.0 + 0.5 * number,
            "side": number % 2,
            "previous_ping_position": prev,
            "ping_length": 400,
            "sample_interval": 12,
        },
        {"raa": raa, "mru": mru, "nav": nav, "minisvs": svs},
        strings,
    )


def file_header() -> RdfFileHeader:
    fields = {n: 0 for n in LAY.file_header.names or ()}
    fields.update(
        creation=1_700_000_000,
        raw_header_size=LAY.file_header.itemsize,
        raw_ping_header_size=HSIZE,
        filename=b"survey_001.rdf".ljust(512, b"\0"),
        frequency=250_000,
        version=b"3.20\0\0\0\0",
        spare=bytes(8),
    )
    return RdfFileHeader(fields)


def rdf_bytes(n_pings: int = 6, seed: int = 1) -> tuple[bytes, list[bytes]]:
    """A whole RDF file and its pings' bytes (each linking to the previous ping's offset)."""
    rng = np.random.default_rng(seed)
    out = CODEC.encode_file_header(file_header())
    pings, prev = [], -1
    for k in range(n_pings):
        p = CODEC.encode(make_ping(rng, k, prev, n=30 + 5 * k))
        prev = len(out)
        out += p
        pings.append(p)
    return out, pings


def frame_all(data: bytes, file_mode: bool, chunk: int = 97) -> tuple[GeoSwathFramer, list[bytes]]:
    fr = GeoSwathFramer(CODEC, file_mode=file_mode)
    recs = []
    for i in range(0, len(data), chunk):
        recs += fr.feed(data[i : i + chunk])
    recs += fr.finish()
    return fr, [r.data for r in recs]


def test_table_sizes_follow_rdf_h() -> None:
    assert LAY.file_header.itemsize == 544 and HSIZE == 64
    assert [(n, d.itemsize) for n, d in DT.items()] == [
        ("raa", 6),
        ("nav", 37),
        ("mru", 20),
        ("gyro", 12),
        ("echo", 16),
        ("minisvs", 12),
        ("aux1", 8),
        ("aux2", 8),
    ]
    assert LAY.arrays[0][1] == "sample_number"


def test_ping_decodes_known_bytes_and_round_trips() -> None:
    rng = np.random.default_rng(3)
    ping = make_ping(rng, 7, 1234, n=3)
    data = CODEC.encode(ping)
    assert len(data) == HSIZE + int(ping.header["ping_size"])
    # hand-read the header: ping_number at 0, ping_time at 4, previous at 12, ping_size at 16
    assert struct.unpack_from("<idii", data, 0) == (7, 103.5, 1234, len(data) - HSIZE)
    # the RAA samples start right after the header: time u16, sine s16, amplitude u16
    t0, s0, a0 = struct.unpack_from("<HhH", data, HSIZE)
    assert (t0, s0, a0) == (
        20,
        int(ping.arrays["raa"]["sine"][0]),
        int(ping.arrays["raa"]["amplitude"][0]),
    )
    back = CODEC.decode(data)
    assert back == ping and CODEC.encode(back) == data
    assert back.arrays["minisvs"]["velocity"][0] == pytest.approx(1493.5)
    assert back.strings[2] == b"$HEHDT,12.0,T*00\r\n"
    with pytest.raises(ValueError):
        back.arrays["raa"]["sine"][0] = 1


def test_file_round_trip_byte_for_byte(tmp_path: Path) -> None:
    data, pings = rdf_bytes()
    path = tmp_path / "x.rdf"
    path.write_bytes(data)
    recs = list(read_rdf(path))
    assert isinstance(recs[0], RdfFileHeader)
    assert recs[0].fields["frequency"] == 250_000
    again = CODEC.encode_file_header(recs[0]) + b"".join(CODEC.encode(p) for p in recs[1:])  # type: ignore[arg-type]
    assert again == data and len(recs) == 1 + len(pings)


def test_broadcast_stream_round_trip_any_chunking() -> None:
    _, pings = rdf_bytes()
    stream = b"".join(pings)
    for chunk in (1, 13, 4096):
        fr = GeoSwathFramer(CODEC, file_mode=False)
        got = [f.data for i in range(0, len(stream), chunk) for f in fr.feed(stream[i : i + chunk])]
        got += [f.data for f in fr.finish()]  # the last ping waits for the stream's end
        assert got == pings and fr.stats.bad_frames == 0 and fr.stats.skipped_bytes == 0


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(1, 300),
    seed=st.integers(0, 2**32 - 1),
    side=st.sampled_from([0, 1]),
    strings=st.lists(st.binary(max_size=40), min_size=N_STRINGS, max_size=N_STRINGS),
)
def test_random_pings_round_trip(n: int, seed: int, side: int, strings: list[bytes]) -> None:
    rng = np.random.default_rng(seed)
    raa = np.frombuffer(rng.bytes(6 * n), DT["raa"])
    ping = CODEC.make_ping(
        {"ping_time": 1.0 + seed, "side": side, "ping_number": seed % 2**31}, {"raa": raa}, strings
    )
    data = CODEC.encode(ping)
    back = CODEC.decode(data)
    assert back == ping and CODEC.encode(back) == data
    fr = GeoSwathFramer(CODEC)
    assert [fr_.data for fr_ in fr.feed(data) + fr.finish()] == [data]


def test_huge_claimed_size_rejected_at_once() -> None:
    _, pings = rdf_bytes(3)
    bad = bytearray(pings[0])
    struct.pack_into("<i", bad, 16, LAY.max_ping_size + 1)
    fr = GeoSwathFramer(CODEC)
    got = [f.data for f in fr.feed(bytes(bad[:HSIZE]))]  # the header alone is enough to refuse it
    assert got == [] and fr.stats.bad_frames == 1 and fr.stats.reasons["ping_size"] == 1
    got += [fr_.data for fr_ in fr.feed(bytes(bad[HSIZE:]) + pings[1] + pings[2])]
    assert got == pings[1:2]  # the last one waits for the bytes after it (or the end)
    assert [fr_.data for fr_ in fr.finish()] == pings[2:]


@pytest.mark.parametrize("file_mode", [True, False])
def test_bit_flips_in_headers_cost_that_ping_only(file_mode: bool) -> None:
    data, pings = rdf_bytes(8)
    rng = np.random.default_rng(11)
    starts = [data.index(p) for p in pings]
    victims = {2, 5}
    buf = bytearray(data)
    # flip a bit of ping_size, a count (nav, miniSVS) or sample_number: the ping no longer adds
    # up (a flip in a sample value or a code goes unseen: the format has no checksum)
    for v in victims:
        field = int(rng.choice([16, 17, 20, 24, 32, 33]))
        buf[starts[v] + field] ^= 1 << int(rng.integers(0, 8))
    if not file_mode:
        buf = buf[LAY.file_header.itemsize :]
    fr, got = frame_all(bytes(buf), file_mode)
    want = [p for k, p in enumerate(pings) if k not in victims]
    assert [r for r in got if r in pings] == want  # intact pings lost: 0
    assert all(r in pings for r in got[1 if file_mode else 0 :])  # nothing false delivered
    assert fr.stats.bad_frames >= len(victims)


def test_garbage_between_pings_and_truncation() -> None:
    data, pings = rdf_bytes(5)
    rng = np.random.default_rng(5)
    fh = data[: LAY.file_header.itemsize]
    stream = b"".join(rng.bytes(int(rng.integers(1, 300))) + p for p in pings)
    fr, got = frame_all(stream + pings[0][:50], file_mode=False)
    assert got == pings
    assert fr.stats.reasons["truncated"] == 1 and fr.stats.bad_frames >= 2
    fr, got = frame_all(fh + b"".join(pings[:3]) + pings[3][: HSIZE + 10], file_mode=True)
    assert got == [fh, *pings[:3]] and fr.stats.reasons["truncated"] == 1


def test_bad_ping_and_bad_table_errors_name_the_problem(tmp_path: Path) -> None:
    _, pings = rdf_bytes(1)
    with pytest.raises(DataError, match=r"ping_size \d+ but the counts give"):
        bad = bytearray(pings[0])
        bad[32] += 1  # sample_number + 1
        CODEC.decode(bytes(bad))
    with pytest.raises(DataError, match="shorter than the 64-byte ping header"):
        CODEC.decode(pings[0][:10])
    site = tmp_path / "site.toml"
    site.write_text(
        config_file("geoswath.toml")
        .read_text()
        .replace(
            'type = "s32", source = "rdf.h", description = "RAA',
            'type = "s64", source = "rdf.h", description = "RAA',
        )
    )
    with pytest.raises(
        TableError, match=r"site.toml: ping_header.fields\[15\] \(sample_number\): type 's64'"
    ):
        GeoSwathCodec.from_toml(site)


def test_site_table_changes_the_layout(tmp_path: Path) -> None:
    # a site that finds the file header's version before echo_type: same size, other order
    text = config_file("geoswath.toml").read_text()
    a = next(ln for ln in text.splitlines(keepends=True) if '"echo_type"' in ln)
    b = next(ln for ln in text.splitlines(keepends=True) if '"version"' in ln)
    assert a in text and b in text
    site = tmp_path / "site.toml"
    site.write_text(text.replace(a + b, b + a))
    codec = GeoSwathCodec.from_toml(site)
    raw = codec.encode_file_header(file_header())
    assert raw[524:532] == b"3.20\0\0\0\0" and codec.decode_file_header(raw) == file_header()


def test_datagrams_frame_alone() -> None:
    _, pings = rdf_bytes(4)
    fr = GeoSwathFramer(CODEC)
    got = [fr_.data for fr_ in fr.feed_datagram(pings[0] + pings[1])]
    got += [fr_.data for fr_ in fr.feed_datagram(pings[2][:-5])]  # cut short: counted, not carried
    got += [fr_.data for fr_ in fr.feed_datagram(pings[3])]
    assert got == [pings[0], pings[1], pings[3]]
    assert fr.stats.reasons["truncated"] == 1 and fr.stats.frames == 3


@pytest.mark.parametrize("file_mode", [True, False])
def test_any_chunking_same_records_and_counters(file_mode: bool) -> None:
    data, pings = rdf_bytes(5)
    fh_len = LAY.file_header.itemsize
    if file_mode:  # (garbage would move the pings off their file offsets: a flipped count)
        stream = bytearray(data)
        stream[data.index(pings[2]) + 32] ^= 4  # sample_number
        want = [p for k, p in enumerate(pings) if k != 2]
    else:
        rng = np.random.default_rng(9)
        stream = bytearray(b"".join(rng.bytes(int(rng.integers(1, 90))) + p for p in pings))
        want = pings
    results = set()
    for chunk in (1, 7, 64, 1 << 16):
        fr, got = frame_all(bytes(stream), file_mode, chunk)
        s = fr.stats
        results.add((tuple(got), s.frames, s.bad_frames, s.skipped_bytes))
    assert len(results) == 1
    ((got, *_),) = results
    assert [r for r in got if len(r) != fh_len] == want


def test_cut_ping_in_a_stream_costs_itself_only() -> None:
    """A broadcast ping cut short (sender restarted) whose claimed size swallows the next
    ping: the complete ping starting inside it proves it cut (reason ``inner_frame``), and the
    search resumes at that ping's header; whatever the chunking."""
    _, pings = rdf_bytes(6)
    cut = pings[2][: HSIZE + 20]
    stream = b"".join(pings[:2]) + cut + b"".join(pings[3:])
    for chunk in (1, 33, 1 << 16):
        fr, got = frame_all(stream, file_mode=False, chunk=chunk)
        assert got == [p for k, p in enumerate(pings) if k != 2]
        assert fr.stats.bad_frames == 1 and fr.stats.reasons["inner_frame"] == 1
        assert fr.stats.skipped_bytes == len(cut)


def test_header_search_is_vectorised_and_exact() -> None:
    """``plausible`` finds every ping header in a stream of pings and garbage, and the
    offsets ``check_header`` accepts one by one."""
    _, pings = rdf_bytes(4)
    rng = np.random.default_rng(2)
    stream = b"".join(rng.bytes(50) + p for p in pings)
    q, size, t = CODEC.plausible(stream, 0, len(stream) - HSIZE + 1)
    one_by_one = [
        i for i in range(len(stream) - HSIZE + 1)
        if CODEC.check_header(CODEC.decode_header(stream, i)) is None
    ]  # fmt: skip
    assert q.tolist() == one_by_one
    starts = [stream.index(p) for p in pings]
    assert set(starts) <= set(q.tolist())
    assert [int(size[q.tolist().index(s)]) for s in starts] == [len(p) - HSIZE for p in pings]
    assert t[q.tolist().index(starts[1])] == 100.5


def test_zero_runs_and_small_times_never_make_a_ping() -> None:
    """Pings whose data end in zeros (empty MRU, NAV records) and whose times are small: a
    header read across the last random samples and the zeros (a time from the samples, all
    counts 0, ping_size 0) is not a ping (at least one RAA sample), so no good ping is refused
    as cut and no bogus one is delivered."""
    rng = np.random.default_rng(0)
    pings = [
        CODEC.encode(CODEC.make_ping(
            {"ping_number": k, "ping_time": 1.0 + k, "side": k % 2},
            {"raa": np.frombuffer(rng.bytes(6 * 500), DT["raa"]),
             "mru": np.zeros(2, DT["mru"]), "nav": np.zeros(1, DT["nav"])},
        ))
        for k in range(20)
    ]  # fmt: skip
    fr, got = frame_all(b"".join(pings), file_mode=False, chunk=4096)
    assert got == pings and fr.stats.bad_frames == 0 and fr.stats.skipped_bytes == 0


def test_a_partial_ping_expires_as_every_framer_s() -> None:
    """The gateway's stale-partial rule (``expire``) works on this framer as on the others."""
    _, pings = rdf_bytes(3)
    fr = GeoSwathFramer(CODEC, file_mode=False)
    assert fr.feed(pings[0][:200], now=10.0) == [] and fr.waiting_s == 10.0
    assert fr.expire(10.5, 1.0) == []  # not old enough
    assert fr.expire(12.0, 1.0) == [] and fr.stats.reasons["stale"] == 1
    got = fr.feed(pings[1] + pings[2], now=12.5)
    assert [f.data for f in got] == pings[1:2] and fr.waiting_s == 12.5  # pings[2] is held
    assert [f.data for f in fr.finish()] == pings[2:] and fr.waiting_s is None
    assert fr.stats.skipped_bytes == 200 and fr.stats.bad_frames == 1


OPS = st.sampled_from(["keep", "keep", "flip", "truncate", "garbage"])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(OPS, min_size=1, max_size=10), data=st.data(),
       chunk=st.integers(1, 400))  # fmt: skip
def test_fuzz_corrupted_stream_keeps_every_untouched_ping(ops, data, chunk: int) -> None:
    """The broadcast stream, each ping kept, bit-flipped anywhere (header or samples), cut
    short anywhere (its claim then takes the next bytes) or after garbage, in random chunks:
    every untouched ping comes out, in order, and whatever comes out is a ping that decodes
    and re-encodes to its bytes (a flip inside a sample or a time goes unseen: no checksum)."""
    _, pings = rdf_bytes(len(ops), seed=len(ops))
    stream, kept = bytearray(), []
    for op, p in zip(ops, pings, strict=True):
        if op == "keep":
            stream += p
            kept.append(p)
        elif op == "flip":
            b = bytearray(p)
            b[data.draw(st.integers(0, len(p) - 1))] ^= 1 << data.draw(st.integers(0, 7))
            stream += b
        elif op == "truncate":  # cut anywhere: inside its header, its data, its last bytes
            stream += p[: data.draw(st.integers(1, len(p) - 1))]
        else:
            stream += data.draw(st.binary(max_size=200)) + p
            kept.append(p)
    _, out = frame_all(bytes(stream), file_mode=False, chunk=chunk)
    it = iter(out)
    assert all(any(k == o for o in it) for k in kept)  # intact pings lost: 0
    assert all(CODEC.encode(CODEC.decode(o)) == o for o in out)


@pytest.mark.parametrize("cut", [1, 20, HSIZE - 1])
def test_a_ping_cut_in_its_last_header_length_costs_itself_only_over_udp(cut: int) -> None:
    """A ping missing its last ``cut`` bytes (< a header) before an intact one: each UDP
    datagram is framed alone, so the cut ping is refused (truncated) and the next comes out."""
    _, pings = rdf_bytes(3, seed=4)
    fr = GeoSwathFramer(CODEC, file_mode=False)
    got = [f.data for d in (pings[0][:-cut], pings[1], pings[2]) for f in fr.feed_datagram(d)]
    assert got == pings[1:] and fr.stats.reasons["truncated"] == 1


@pytest.mark.parametrize("cut", [1, 20, HSIZE - 1])
@pytest.mark.parametrize("chunk", [1, 64, 1 << 16])
def test_a_ping_cut_in_its_last_header_length_in_a_byte_stream(cut: int, chunk: int) -> None:
    """A ping missing its last ``cut`` bytes (< a header) before an intact one, in a byte
    stream: the bytes at its claimed end start no ping and the next ping's header starts inside
    its claim, so it is refused (``cut``) and the search resumes at that header, whatever the
    chunking."""
    _, pings = rdf_bytes(3, seed=4)
    fr, got = frame_all(pings[0][:-cut] + pings[1] + pings[2], file_mode=False, chunk=chunk)
    assert got == pings[1:]
    assert fr.stats.reasons == {"cut": 1} and fr.stats.skipped_bytes == len(pings[0]) - cut


@pytest.mark.parametrize("kept", [13, 51, HSIZE - 1])
def test_a_ping_cut_inside_its_header_in_a_byte_stream(kept: int) -> None:
    """A ping cut inside its own header (``kept`` of 64 bytes) before an intact ping: a header
    spliced from both may pass every header check (no checksum), but its claimed end starts no
    ping and the next ping's header starts inside it: only the cut ping is lost."""
    _, pings = rdf_bytes(2, seed=2)
    for chunk in (1, 1 << 16):
        fr, got = frame_all(pings[0][:kept] + pings[1], file_mode=False, chunk=chunk)
        assert got == pings[1:] and fr.stats.bad_frames == 1
        assert fr.stats.skipped_bytes == kept


def test_a_complete_ping_waits_for_the_next_header_then_expires_to_delivery() -> None:
    """The cost of the rule: in a byte stream a complete ping comes out when a header's worth
    of the next bytes shows it ended where a ping starts (or at :meth:`finish`); an idle
    stream's last ping is delivered, not dropped, when it has waited ``max_age_s``."""
    _, pings = rdf_bytes(3, seed=5)
    fr = GeoSwathFramer(CODEC, file_mode=False)
    assert fr.feed(pings[0], now=1.0) == [] and fr.waiting_s == 1.0
    assert [f.data for f in fr.feed(pings[1][: HSIZE - 1], now=1.2)] == []
    assert [f.data for f in fr.feed(pings[1][HSIZE - 1 :], now=1.3)] == pings[:1]
    assert fr.expire(3.0, 2.0) == []  # pings[1] held since 1.2 s: not old enough
    got = fr.expire(3.5, 2.0)
    assert [f.data for f in got] == [pings[1]] and fr.waiting_s is None
    assert [f.data for f in fr.feed(pings[2]) + fr.finish()] == [pings[2]]
    assert fr.stats.bad_frames == 0 and fr.stats.skipped_bytes == 0
