"""The declarative table engine and the framer base, on a toy format."""

from __future__ import annotations

import math

import numpy as np
import pytest

from auvgw.drivers.framing import BadFrame, ErrorPolicy, FrameError, Framer
from auvgw.drivers.spec import (
    WireError,
    block_size,
    decode_block,
    encode_block,
    from_jsonable,
    message,
    raw_value,
    to_jsonable,
    wire,
)


def test_decode_encode_roundtrip_and_raw() -> None:
    @message
    class T:
        depth: float = wire("u16", 0, scale=0.1, units="m")
        vel: np.ndarray = wire("s16", 2, shape=("n",), scale=1e-3, units="m/s", invalid=-32768)
        tag: str = wire("str", 8, size=4)
        temp: float = wire("s16", 12, scale=0.01, add=-5.0)

    raw = bytes.fromhex("e803") + bytes.fromhex("0a00" "0080" "f6ff") + b"AB\x00\x00" + b"\x10\x00"
    m = decode_block(T, raw, ctx={"n": 3})
    assert m.depth == pytest.approx(100.0)
    assert m.vel[0] == pytest.approx(0.010) and math.isnan(m.vel[1])
    assert m.vel[2] == pytest.approx(-0.010)
    assert m.tag == "AB"
    assert m.temp == pytest.approx(16 * 0.01 - 5.0)
    assert raw_value(m, "depth") == 1000
    assert block_size(T, {"n": 3}) == 14
    buf = bytearray(14)
    encode_block(m, buf, ctx={"n": 3})
    assert bytes(buf) == raw
    assert decode_block(T, bytes(buf), ctx={"n": 3}) == m
    with pytest.raises(AttributeError):
        m.depth = 3.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        m.vel[0] = 1.0
    d = to_jsonable(m)
    assert d["type"] == "T" and d["vel"][1] is None


def test_encode_range_error_names_field() -> None:
    @message
    class T:
        depth: float = wire("u16", 0, scale=0.1, units="m")

    with pytest.raises(WireError, match=r"T\.depth"):
        encode_block(T(depth=1e6), bytearray(2))


def test_short_block_error_names_offset() -> None:
    @message
    class T:
        a: int = wire("u32", 2)

    with pytest.raises(WireError, match=r"T\.a: needs bytes 2\.\.5"):
        decode_block(T, b"\x00\x00\x00")


class ToyFramer(Framer):
    """``AA 55 | u8 n | n payload bytes | u8 sum(payload) mod 256``."""

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


def toy(payload: bytes) -> bytes:
    return b"\xaa\x55" + bytes([len(payload)]) + payload + bytes([sum(payload) & 0xFF])


def test_framer_resyncs_and_counts_exactly() -> None:
    good = [toy(bytes([i, i + 1, i + 2])) for i in range(5)]
    bad_sum = bytearray(toy(b"xyz"))
    bad_sum[-1] ^= 0xFF
    garbage = b"\x01\x02\x03"
    truncated = toy(b"abcdef")[:5]
    stream = (
        garbage + good[0] + bytes(bad_sum) + good[1] + truncated + good[2] + b"\xaa" + good[3]
        + good[4] + truncated
    )
    for chunk_size in (1, 2, 3, 7, 1000):
        f = ToyFramer(policy=ErrorPolicy.IGNORE)
        chunks = [stream[i : i + chunk_size] for i in range(0, len(stream), chunk_size)]
        frames = list(f.frames(chunks))
        assert [fr.data for fr in frames] == good
        # bad checksum, truncated (mid-stream), truncated (at end of stream)
        assert f.stats.bad_frames == 3
        assert f.stats.skipped_bytes == len(stream) - sum(map(len, good))
        assert frames[0].offset == len(garbage)


def test_framer_raise_policy_keeps_state() -> None:
    bad = bytearray(toy(b"q"))
    bad[-1] ^= 1
    f = ToyFramer(policy=ErrorPolicy.RAISE, source="toy.bin")
    with pytest.raises(FrameError, match=r"toy.bin: bad frame at byte offset 4: bad checksum"):
        f.feed(toy(b"") + bytes(bad) + toy(b"ok"))
    out = f.feed(b"")
    assert [fr.data for fr in out] == [toy(b""), toy(b"ok")]


def test_framer_bounded_buffer_on_garbage() -> None:
    f = ToyFramer(policy=ErrorPolicy.IGNORE)
    for _ in range(100):
        f.feed(b"\x00" * 1000)
    assert f.buffered <= 1
    assert f.stats.skipped_bytes >= 99_999


@message
class _JsonToy:
    depth: float = wire("u16", 0, scale=0.1, units="m")
    vel: np.ndarray = wire("s16", 2, shape=(2,), scale=1e-3, invalid=-32768)
    tag: str = wire("str", 6, size=3)


def test_from_jsonable_rebuilds_typed_message() -> None:
    import json

    m = decode_block(_JsonToy, b"\x0a\x00\x01\x00\x00\x80abc")
    d = json.loads(json.dumps(to_jsonable(m)))
    back = from_jsonable(d)
    assert type(back) is _JsonToy
    assert back == m
