"""HN-100 INS binary frame: the table-driven codec, its framer, site tables and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import random
import re
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import DecodeError, ErrorPolicy, FrameError
from auvgw.drivers.hn100 import CODEC, FORMAT, Hn100Codec, Hn100Framer, Hn100Nav
from auvgw.drivers.spec import WireError, raw_value, to_jsonable
from auvgw.drivers.tablecodec import CHECKSUMS, TableError
from auvgw.ground.paths import REPO_ROOT, config_file
from auvgw.testing.format_samples import REF_INTS, crc16_ccitt_false, ref_frame
from auvgw.testing.format_samples import hn100_frames as good_frames

SHIPPED = config_file("hn100.toml")
SHIPPED_TEXT = SHIPPED.read_text()
AUVGW = REPO_ROOT / ".venv" / "bin" / "auvgw"
SIZE = 74


def test_shipped_table_decodes_reference_frame() -> None:
    frame = ref_frame(42, 0b1011, 123_456, REF_INTS)
    assert len(frame) == SIZE == CODEC.spec.size
    m = CODEC.decode(frame)
    assert isinstance(m, Hn100Nav)
    assert m.seq == 42 and m.status == 0b1011
    assert (m.aligned, m.gnss_aided, m.dvl_aided, m.error) == (True, True, False, True)
    assert m.time == pytest.approx(12.3456)
    assert (m.roll, m.pitch, m.heading) == pytest.approx((0.1, -0.05, 3.0))
    assert m.rates == pytest.approx([0.01, -0.02, 0.03])
    assert m.accel == pytest.approx([0.1, 0.2, -9.81])
    assert m.vel_ned == pytest.approx([1.5, -0.2, 0.01])
    assert m.latitude == pytest.approx(math.radians(43.1234567), abs=1e-12)
    assert m.longitude == pytest.approx(math.radians(-5.9876543), abs=1e-12)
    assert m.depth == pytest.approx(123.456)
    assert raw_value(m, "roll") == 100_000
    assert raw_value(m, "latitude") == 431_234_567
    assert raw_value(m, "time") == 123_456
    assert CODEC.encode(m) == frame
    d = to_jsonable(m)
    assert d["type"] == "Hn100Nav" and d["aligned"] is True and d["dvl_aided"] is False
    assert d["heading"] == pytest.approx(3.0)
    with pytest.raises(AttributeError):
        m.roll = 0.0  # type: ignore[misc]


def test_invalid_position_is_nan_and_reencodes() -> None:
    ints = list(REF_INTS)
    ints[12] = ints[13] = ints[14] = -(2**31)
    frame = ref_frame(1, 0, 5, ints)
    m = CODEC.decode(frame)
    assert math.isnan(m.latitude) and math.isnan(m.longitude) and math.isnan(m.depth)
    assert to_jsonable(m)["latitude"] is None
    assert CODEC.encode(m) == frame


def test_checksum_kind_check_values() -> None:
    data = b"123456789"
    expected = {
        "crc16-ccitt-false": 0x29B1,
        "crc16-xmodem": 0x31C3,
        "crc32": 0xCBF43926,
        "ubx-fletcher": 0xDD15,  # CK_A 0xDD, CK_B 0x15
        "xor8": 0x31,
        "sum8": 0xDD,
    }
    assert {k: v.compute(data) for k, v in CHECKSUMS.items()} == expected


def test_flags_and_status_word() -> None:
    m = CODEC.decode(ref_frame(1, 0, 0, REF_INTS))
    assert not (m.aligned or m.gnss_aided or m.dvl_aided or m.error)
    word = CODEC.status_word(aligned=True, error=True)
    assert word == 0b1001
    values = {f: getattr(m, f) for f in ("seq", "time", "roll", "pitch", "heading")}
    values |= {f: getattr(m, f) for f in ("rate_x", "rate_y", "rate_z", "accel_x", "accel_y")}
    values |= {f: getattr(m, f) for f in ("accel_z", "vel_n", "vel_e", "vel_d", "latitude")}
    values |= {"longitude": m.longitude, "depth": m.depth}
    ok = Hn100Nav(status=word, aligned=True, error=True, **values)
    assert ok.gnss_aided is False
    with pytest.raises(ValueError, match=r"Hn100Nav\.gnss_aided=True disagrees with bit 1"):
        Hn100Nav(status=word, gnss_aided=True, **values)
    with pytest.raises(KeyError, match="unknown flag"):
        CODEC.status_word(sonar=True)


def test_decode_and_encode_errors_name_the_problem() -> None:
    frame = ref_frame(1, 0, 0, REF_INTS)
    with pytest.raises(DecodeError, match=r"frame is 73 bytes; table .*hn100\.toml says 74"):
        CODEC.decode(frame[:-1])
    bad = bytearray(frame)
    bad[20] ^= 0x01
    with pytest.raises(DecodeError, match="bad checksum crc16-ccitt-false"):
        CODEC.decode(bytes(bad))
    m = CODEC.decode(frame)
    with pytest.raises(WireError, match=r"Hn100Nav\.roll: raw value .* outside s32 range"):
        CODEC.encode(dataclasses.replace(m, roll=1e4))
    with pytest.raises(WireError, match="cannot encode str"):
        CODEC.encode("not a message")


# -- properties ---------------------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(payload=st.binary(min_size=68, max_size=68))
def test_any_valid_frame_reencodes_identically(payload: bytes) -> None:
    body = struct.pack("<H", 68) + payload
    frame = b"\xaa\x48" + body + struct.pack("<H", crc16_ccitt_false(body))
    m = CODEC.decode(frame)
    assert CODEC.encode(m) == frame
    assert CODEC.decode(CODEC.encode(m)) == m  # NaN-aware message equality


angle = st.floats(-math.pi, math.pi)
small = st.floats(-100.0, 100.0)


@settings(max_examples=150, deadline=None)
@given(
    seq=st.integers(0, 65535),
    flags=st.lists(st.booleans(), min_size=4, max_size=4),
    time=st.floats(0, 429_000),
    att=st.tuples(angle, angle, st.floats(0, 2 * math.pi)),
    vecs=st.lists(small, min_size=9, max_size=9),
    lat=st.one_of(st.just(math.nan), st.floats(-math.pi / 2, math.pi / 2)),
    lon=st.floats(-math.pi, math.pi),
    depth=st.floats(-10, 11_000),
)
def test_message_roundtrip_within_resolution(seq, flags, time, att, vecs, lat, lon, depth) -> None:
    names = ("aligned", "gnss_aided", "dvl_aided", "error")
    vec_names = ["rate_x", "rate_y", "rate_z", "accel_x", "accel_y", "accel_z"]
    vec_names += ["vel_n", "vel_e", "vel_d"]
    m = Hn100Nav(
        seq=seq,
        status=CODEC.status_word(**dict(zip(names, flags, strict=True))),
        time=time,
        roll=att[0],
        pitch=att[1],
        heading=att[2],
        latitude=lat,
        longitude=lon,
        depth=depth,
        **dict(zip(vec_names, vecs, strict=True)),
    )
    frame = CODEC.encode(m)
    assert len(frame) == SIZE and frame[:2] == b"\xaa\x48"
    d = CODEC.decode(frame)
    assert [getattr(d, n) for n in names] == flags
    assert d.time == pytest.approx(time, abs=0.5e-4)
    assert [d.roll, d.pitch, d.heading] == pytest.approx(list(att), abs=0.5e-6)
    assert d.rates == pytest.approx(vecs[:3], abs=0.5e-6)
    assert d.accel == pytest.approx(vecs[3:6], abs=0.5e-5)
    assert d.vel_ned == pytest.approx(vecs[6:], abs=0.5e-4)
    assert (math.isnan(d.latitude) and math.isnan(lat)) or d.latitude == pytest.approx(
        lat, abs=1e-9
    )
    assert d.depth == pytest.approx(depth, abs=0.5e-3)
    assert CODEC.encode(d) == frame  # decoded values are fixed points of the quantisation


# -- named corrupted fixtures -----------------------------------------------------------------


def _run(stream: bytes, chunk: int) -> tuple[list[bytes], Hn100Framer]:
    f = Hn100Framer(policy=ErrorPolicy.IGNORE)
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]
    return [fr.data for fr in f.frames(chunks)], f


G = good_frames(4)
BAD_CRC = bytearray(G[1])
BAD_CRC[-1] ^= 0x40
BAD_LEN = bytearray(G[1])
BAD_LEN[2] = 0x45  # length 69 instead of 68
FAKE_SYNC_GARBAGE = b"\x00\x13\x37\xaa\x48\x00\x00junk\xaa\x99"

FIXTURES = {
    # name: (stream, frames delivered, bad_frames, skipped_bytes)
    "bad_checksum": (G[0] + bytes(BAD_CRC) + G[2], [G[0], G[2]], 1, SIZE),
    "bad_length": (G[0] + bytes(BAD_LEN) + G[2], [G[0], G[2]], 1, SIZE),
    "truncated_mid_stream": (G[0] + G[1][:40] + G[2], [G[0], G[2]], 1, 40),
    "truncated_at_end": (G[0] + G[1] + G[2][:50], [G[0], G[1]], 1, 50),
    "garbage_between_frames": (
        G[0] + FAKE_SYNC_GARBAGE + G[1] + b"\x01" * 100 + G[2],
        [G[0], G[1], G[2]],
        1,  # the fake sync AA 48 with length 0
        len(FAKE_SYNC_GARBAGE) + 100,
    ),
    "starts_mid_frame": (G[0][30:] + G[1] + G[2], [G[1], G[2]], 0, SIZE - 30),
    "starts_mid_sync": (G[0][1:] + G[1], [G[1]], 0, SIZE - 1),
}


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("chunk", [1, 3, 74, 10_000])
def test_corrupted_fixture_counts(name: str, chunk: int) -> None:
    stream, expected, bad, skipped = FIXTURES[name]
    frames, f = _run(stream, chunk)
    assert frames == expected
    assert (f.stats.frames, f.stats.bad_frames, f.stats.skipped_bytes) == (
        len(expected),
        bad,
        skipped,
    )
    assert [CODEC.decode(fr).seq for fr in frames] == [CODEC.decode(e).seq for e in expected]


def test_raise_policy_reports_offset_and_reason() -> None:
    f = Hn100Framer(policy=ErrorPolicy.RAISE, source="ins.bin")
    with pytest.raises(FrameError, match=r"ins\.bin: bad frame at byte offset 74: bad checksum"):
        f.feed(G[0] + bytes(BAD_CRC) + G[2])
    assert [fr.data for fr in f.feed(b"")] == [G[0], G[2]]
    f = Hn100Framer(policy=ErrorPolicy.RAISE, source="ins.bin")
    with pytest.raises(FrameError, match=r"offset 74: bad length 69 at \+2: table .* says 68"):
        f.feed(G[0] + bytes(BAD_LEN))


# -- fuzz ---------------------------------------------------------------------------------------


def _chunks(data: bytes, rnd: random.Random) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = rnd.choice((1, 2, 5, 13, 74, 75, 200, 1000))
        out.append(data[i : i + n])
        i += n
    return out


@settings(max_examples=60, deadline=None)
@given(data=st.binary(max_size=3000), seed=st.integers(0, 2**32 - 1))
def test_fuzz_random_bytes(data: bytes, seed: int) -> None:
    f = Hn100Framer(policy=ErrorPolicy.IGNORE)
    frames = list(f.frames(_chunks(data, random.Random(seed))))
    assert frames == []
    assert f.stats.skipped_bytes == len(data)


OPS = st.sampled_from(["keep", "keep", "flip", "truncate", "garbage", "drop_sync"])


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(OPS, min_size=1, max_size=25), data=st.data(), seed=st.integers(0, 2**31))
def test_fuzz_corrupted_stream_keeps_every_untouched_frame(ops, data, seed) -> None:
    frames = good_frames(len(ops), start=100)
    stream = bytearray()
    kept = []
    for op, fr in zip(ops, frames, strict=True):
        if op == "keep":
            stream += fr
            kept.append(fr)
        elif op == "flip":
            b = bytearray(fr)
            pos = data.draw(st.integers(2, SIZE - 1))
            b[pos] ^= data.draw(st.integers(1, 255))
            stream += b
        elif op == "truncate":
            stream += fr[: data.draw(st.integers(1, SIZE - 1))]
        elif op == "garbage":
            stream += data.draw(st.binary(max_size=200)) + fr
            kept.append(fr)
        else:  # second sync byte lost
            stream += fr[:1] + fr[2:]
    f = Hn100Framer(policy=ErrorPolicy.IGNORE)
    out = [fr.data for fr in f.frames(_chunks(bytes(stream), random.Random(seed)))]
    assert is_subsequence(kept, out)
    # pieces of corrupted frames may join into a valid frame (a 1-byte truncation followed by a
    # frame whose first byte was lost); whatever is delivered is valid
    assert all(CODEC.encode(CODEC.decode(fr)) == fr for fr in out)
    assert f.stats.frames == len(out)
    assert f.stats.skipped_bytes == len(stream) - SIZE * len(out)


def is_subsequence(needles: list[bytes], haystack: list[bytes]) -> bool:
    it = iter(haystack)
    return all(any(n == h for h in it) for n in needles)


# -- site tables -------------------------------------------------------------------------------

SITE_TOML = """
# a site's own firmware: other sync, big endian, u-blox Fletcher, deg/mg/mm/s units
[frame]
sync = "55 AA 10"
size = 42
byte_order = "big"

[frame.length]
offset = 3
type = "u8"
adjust = 6

[frame.checksum]
kind = "ubx-fletcher"
start = 3

[status]
field = "flags"
bits = { error = 7, aligned = 4, gnss_aided = 5, dvl_aided = 6 }

[[fields]]
name = "flags"
type = "u8"
offset = 4
[[fields]]
name = "heading"
type = "u16"
offset = 5
scale = 0.01
units = "deg"
[[fields]]
name = "pitch"
type = "s16"
offset = 7
scale = 0.01
units = "deg"
[[fields]]
name = "roll"
type = "s16"
offset = 9
scale = 0.01
units = "deg"
[[fields]]
name = "rate_x"
type = "s16"
offset = 11
scale = 0.01
units = "deg/s"
[[fields]]
name = "rate_y"
type = "s16"
offset = 13
scale = 0.01
units = "deg/s"
[[fields]]
name = "rate_z"
type = "s16"
offset = 15
scale = 0.01
units = "deg/s"
[[fields]]
name = "accel_x"
type = "s16"
offset = 17
units = "mg"
[[fields]]
name = "accel_y"
type = "s16"
offset = 19
units = "mg"
[[fields]]
name = "accel_z"
type = "s16"
offset = 21
units = "mg"
[[fields]]
name = "vel_n"
type = "s16"
offset = 23
units = "mm/s"
[[fields]]
name = "vel_e"
type = "s16"
offset = 25
units = "mm/s"
[[fields]]
name = "vel_d"
type = "s16"
offset = 27
units = "mm/s"
[[fields]]
name = "latitude"
type = "f32"
offset = 29
units = "rad"
[[fields]]
name = "longitude"
type = "f32"
offset = 33
units = "rad"
[[fields]]
name = "depth"
type = "u8"
offset = 37
scale = 0.5
units = "m"
[[fields]]
name = "time"
type = "u8"
offset = 38
scale = 10
units = "ms"
description = "10 ms ticks, wraps every 2.56 s"
[[fields]]
name = "reserved_39"
type = "bytes"
offset = 39
size = 1
"""


def ubx_fletcher(data: bytes) -> bytes:
    a = b = 0
    for x in data:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes([a, b])


def site_frame(heading: int, roll: int, ticks: int) -> bytes:
    body = struct.pack(
        ">BBHhh3h3h3hffBBB",
        36,
        0b1011_0000,  # aligned, gnss, error
        heading,
        -150,
        roll,
        100,
        -100,
        4500,
        0,
        0,
        -1000,
        1500,
        -20,
        3,
        0.75,
        -0.1,
        42,
        ticks,
        0xEE,
    )
    # sync 3 | length 1 | fields 4..39 | checksum 40..41 = 42 bytes
    frame_wo_cs = b"\x55\xaa\x10" + body
    return frame_wo_cs + ubx_fletcher(frame_wo_cs[3:])


def test_site_table_changes_layout_without_code(tmp_path: Path) -> None:
    path = tmp_path / "site_ins.toml"
    path.write_text(SITE_TOML)
    codec = Hn100Codec.from_toml(path)
    frame = site_frame(heading=27_000, roll=-1234, ticks=77)
    assert len(frame) == 42 == codec.spec.size
    m = codec.decode(frame)
    assert type(m).__name__ == "Hn100Nav" and type(m) is not Hn100Nav
    assert m.heading == pytest.approx(math.radians(270.0))
    assert m.roll == pytest.approx(math.radians(-12.34))
    assert m.pitch == pytest.approx(math.radians(-1.5))
    assert m.rates == pytest.approx(np.radians([1.0, -1.0, 45.0]))
    assert m.accel_z == pytest.approx(-9.80665)
    assert m.vel_ned == pytest.approx([1.5, -0.02, 0.003])
    assert m.latitude == pytest.approx(0.75) and m.longitude == pytest.approx(-0.1)
    assert m.depth == 21.0 and m.time == pytest.approx(0.77)
    assert m.reserved_39 == b"\xee"
    assert (m.aligned, m.gnss_aided, m.dvl_aided, m.error) == (True, True, False, True)
    assert raw_value(m, "heading") == 27_000
    assert codec.encode(m) == frame
    # its framer finds site frames among shipped-format frames and garbage
    stream = G[0] + frame + b"\x55\xaa" + G[1] + frame + frame[:20]
    f = codec.framer(policy=ErrorPolicy.IGNORE)
    out = [fr.data for fr in f.frames([stream[i : i + 5] for i in range(0, len(stream), 5)])]
    assert out == [frame, frame]
    assert f.stats.bad_frames == 1  # the truncated site frame at the end
    # the shipped codec is untouched
    assert CODEC.decode(G[0]).seq == 0


@pytest.mark.parametrize("kind", sorted(CHECKSUMS))
@pytest.mark.parametrize("order", ["little", "big"])
def test_site_can_switch_checksum_kind_and_byte_order(kind: str, order: str, tmp_path) -> None:
    n = CHECKSUMS[kind].size
    text = (
        SHIPPED_TEXT.replace('kind = "crc16-ccitt-false"', f'kind = "{kind}"')
        .replace("size = 74", f"size = {72 + n}")
        .replace("adjust = 6", f"adjust = {4 + n}")
        .replace('byte_order = "little"', f'byte_order = "{order}"')
    )
    path = tmp_path / "kind.toml"
    path.write_text(text)
    codec = Hn100Codec.from_toml(path)
    m = CODEC.decode(G[1])
    values = {f.name: getattr(m, f.name) for f in CODEC.spec.fields}
    frame = codec.encode(codec.message_type(**values))
    assert len(frame) == 72 + n
    e = "<" if order == "little" else ">"
    assert struct.unpack_from(e + "H", frame, 2)[0] == 68
    assert struct.unpack_from(e + "i", frame, 12)[0] == 100_007  # roll, raw
    covered = frame[2:72]
    expected = CHECKSUMS[kind].compute(covered)
    byteorder = "big" if kind == "ubx-fletcher" else order
    assert frame[72:] == expected.to_bytes(n, byteorder)
    d = codec.decode(frame)
    assert d.roll == m.roll and d.seq == 1 and d.dvl_aided
    assert codec.encode(d) == frame
    corrupt = bytearray(frame)
    corrupt[40] ^= 0x01
    f = codec.framer(policy=ErrorPolicy.IGNORE)
    out = f.feed(frame + bytes(corrupt) + frame) + f.finish()
    assert [fr.data for fr in out] == [frame, frame]
    assert f.stats.bad_frames == 1


def test_table_without_length_field(tmp_path: Path) -> None:
    text, n = re.subn(r"\[frame\.length\]\n(?:.+\n)+\n", "", SHIPPED_TEXT)
    assert n == 1
    text += '\n[[fields]]\nname = "word_2"\ntype = "u16"\noffset = 2\n'
    path = tmp_path / "nolength.toml"
    path.write_text(text)
    codec = Hn100Codec.from_toml(path)
    assert codec.spec.length_offset is None
    m = codec.decode(G[2])  # the length bytes are now an ordinary field
    assert m.word_2 == 68 and m.seq == 2
    assert codec.encode(m) == G[2]
    f = codec.framer(policy=ErrorPolicy.IGNORE)
    assert [fr.data for fr in f.feed(b"\xaa\x48" + G[2])] == [G[2]]
    assert f.stats.bad_frames == 1  # the lone sync fails only on its checksum


def _edit(old: str, new: str, text: str = SHIPPED_TEXT) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


ROLL = 'name = "roll"\ntype = "s32"\noffset = 12'
BAD_TABLES = {
    "unknown_type": (
        _edit(ROLL, 'name = "roll"\ntype = "i32"\noffset = 12'),
        r"fields\[3\] \(roll\): unknown wire type 'i32'; expected one of u8, s8",
    ),
    "overlap": (
        _edit(ROLL, 'name = "roll"\ntype = "s32"\noffset = 14'),
        r"fields\[4\] \(pitch\): field 'pitch' at bytes 16\.\.19 overlaps field 'roll' at byte 16",
    ),
    "overlaps_length": (
        _edit('name = "seq"\ntype = "u16"\noffset = 4', 'name = "seq"\ntype = "u16"\noffset = 3'),
        r"fields\[0\] \(seq\): field 'seq' at bytes 3\.\.4 overlaps length field at byte 3",
    ),
    "beyond_frame": (
        _edit('type = "s32"\noffset = 68', 'type = "s32"\noffset = 70'),
        r"fields\[17\] \(depth\): field 'depth' spans bytes 70\.\.73, beyond the frame's field "
        r"area 2\.\.71 \(size 74, checksum at 72\)",
    ),
    "bad_checksum_kind": (
        _edit('kind = "crc16-ccitt-false"', 'kind = "crc-16"'),
        r"\[frame\.checksum\]: unknown checksum kind 'crc-16'; expected one of "
        r"crc16-ccitt-false, crc16-xmodem, crc32, ubx-fletcher, xor8, sum8",
    ),
    "missing_required": (
        _edit('name = "pitch"', 'name = "pitch_deg"'),
        r"missing required field\(s\) pitch",
    ),
    "wrong_units": (
        _edit('units = "rad"\ndescription = "roll', 'units = "m/s"\ndescription = "roll'),
        r"fields\[3\] \(roll\): units 'm/s' give m/s; "
        r"expected table units 'rad', 'mrad', 'urad', 'deg'",
    ),
    "unknown_units": (
        _edit('units = "mm"', 'units = "fathom"'),
        r"fields\[17\] \(depth\): unknown units 'fathom'",
    ),
    "gap": (
        _edit("size = 74", "size = 78").replace("adjust = 6", "adjust = 10"),
        r"bytes 72\.\.75 are covered by no field;.*name = \"reserved_72\", type = \"bytes\", "
        r"offset = 72, size = 4",
    ),
    "typo_key": (
        _edit('name = "seq"\ntype = "u16"\noffset = 4', 'name = "seq"\ntype = "u16"\noffest = 4'),
        r"fields\[0\] \(seq\): missing 'offset'",
    ),
    "unknown_key": (
        _edit('name = "seq"', 'name = "seq"\nsigned = true'),
        r"fields\[0\] \(seq\): unknown key\(s\) signed",
    ),
    "status_bit_range": (
        _edit("error = 3 }", "error = 16 }"),
        r"\[status\.bits\]: error = 16; expected a bit number 0\.\.15",
    ),
    "missing_flag": (
        _edit("dvl_aided = 2, ", ""),
        r"\[status\.bits\]: missing required flag\(s\) dvl_aided",
    ),
    "reserved_name": (
        _edit('name = "seq"', 'name = "rates"'),
        r"field name\(s\) rates are reserved by Hn100Nav \(reserved: accel, rates, vel_ned\)",
    ),
    "bad_name": (
        _edit('name = "seq"', 'name = "__init__"'),
        r"fields\[0\]: name '__init__' is not a lower-case Python identifier",
    ),
    "not_toml": ("[frame\nsync = ", r"not valid TOML"),
    "bad_sync": (
        _edit('sync = "AA 48"', 'sync = "AZ"'),
        r"\[frame\]: sync = 'AZ'; expected hex bytes",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_TABLES))
def test_bad_site_table_errors_name_file_field_and_fix(name: str, tmp_path: Path) -> None:
    text, pattern = BAD_TABLES[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    with pytest.raises(TableError) as info:
        Hn100Codec.from_toml(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: "), msg
    assert re.search(pattern, msg), msg
    assert "\n" not in msg


def test_missing_table_file(tmp_path: Path) -> None:
    with pytest.raises(TableError, match=r"nope\.toml: cannot read table"):
        Hn100Codec.from_toml(tmp_path / "nope.toml")


# -- registry, docs, CLI --------------------------------------------------------------------------


def test_format_registry_and_doc_layout_match_table() -> None:
    assert get_format("hn100") is FORMAT
    fr = FORMAT.framer(policy="ignore", source="x")
    assert [f.data for f in fr.feed(G[0] + G[1])] == G[:2]
    assert FORMAT.decode(G[0])[0] == CODEC.decode(G[0])
    doc = (REPO_ROOT / "docs" / "protocols" / "hn100.md").read_text()
    assert "assumed layout" in doc.lower()
    for f in CODEC.spec.fields:
        row = rf"\|\s*{f.offset}\s*\|\s*`{f.name}`\s*\|\s*{f.type}\s*\|"
        assert re.search(row, doc), f"docs/protocols/hn100.md lacks the row for {f.name}"


@pytest.mark.e2e
def test_cli_decode_json_lines_and_summary(tmp_path: Path) -> None:
    path = tmp_path / "ins.bin"
    path.write_bytes(b"\x00" * 10 + G[0] + bytes(BAD_CRC) + G[2] + G[3])
    r = subprocess.run(
        [str(AUVGW), "decode", "--format", "hn100", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [d["seq"] for d in lines] == [0, 2, 3]
    assert lines[0]["type"] == "Hn100Nav"
    assert lines[0]["roll"] == pytest.approx(0.1)
    assert lines[1]["dvl_aided"] is True
    summary = json.loads(r.stderr.strip().splitlines()[-1])
    assert summary["messages"] == {"Hn100Nav": 3}
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (3, 1, 84)


@pytest.mark.e2e
def test_cli_wrong_file_is_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "mag.txt"
    path.write_bytes(b"$MS3A,000001,+000001.0,+000002.0,+000003.0*5D\r\n" * 20)
    r = subprocess.run(
        [str(AUVGW), "decode", "--format", "hn100", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stdout == ""
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("auvgw decode: error: ") and "no valid hn100 frame" in last
    assert "Traceback" not in r.stderr
