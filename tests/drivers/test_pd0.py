"""PD0: tables, round trips, Hypothesis properties, corrupted streams, fuzzing, real files, CLI."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import json
import math
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from auvgw.drivers import pd0
from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import DecodeError, ErrorPolicy, FrameError, read_file_frames
from auvgw.drivers.spec import (
    WIRE_TYPES,
    Wire,
    block_size,
    decode_block,
    from_jsonable,
    raw_value,
    to_jsonable,
)

KNOWN = tuple(pd0._TABLES)  # data type IDs this module decodes
CELL_IDS = (pd0.ID_VELOCITY, pd0.ID_CORRELATION, pd0.ID_ECHO_INTENSITY, pd0.ID_PERCENT_GOOD)


# --------------------------------------------------------------------------------------------
# Building messages from raw wire values (the table's own metadata: type, scale, invalid)
# --------------------------------------------------------------------------------------------


def wires(cls: type) -> list[tuple[str, Wire]]:
    return [(f.name, f.metadata["wire"]) for f in dataclasses.fields(cls) if "wire" in f.metadata]


def to_si(w: Wire, raw):
    """SI value of a raw wire value, as the decoder computes it."""
    if w.type == "bytes" or not w.is_scaled:
        return raw
    if isinstance(raw, np.ndarray):
        out = raw.astype(np.float64) * w.scale + w.add
        if w.invalid is not None:
            out[raw == w.invalid] = np.nan
        return out
    return math.nan if raw == w.invalid else raw * w.scale + w.add


def int_range(t: str) -> tuple[int, int]:
    bits = 8 * struct.calcsize(WIRE_TYPES[t])
    return (0, 2**bits - 1) if t.startswith("u") else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


def required_fields(cls: type, ctx: dict[str, int]) -> int:
    """How many leading fields a block of ``cls`` must carry (its documented core)."""
    min_size = block_size(cls, ctx) if cls.MIN_SIZE < 0 else cls.MIN_SIZE
    return sum(1 for _, w in wires(cls) if w.offset + w.nbytes(ctx) <= min_size)


def random_block(cls, rng: np.random.Generator, ctx=None, n_present=None, extra=b""):
    """A message of ``cls`` with random raw values; fields after ``n_present`` are None."""
    ctx = ctx or {}
    rows = wires(cls)
    n_present = len(rows) if n_present is None else n_present
    values = {}
    for k, (name, w) in enumerate(rows):
        if k >= n_present:
            values[name] = None
        elif w.type == "bytes":
            values[name] = rng.integers(0, 256, w.size, dtype=np.uint8).tobytes()
        elif w.shape:
            lo, hi = int_range(w.type)
            raw = rng.integers(lo, hi, w.resolve_shape(ctx), endpoint=True, dtype=np.int64)
            values[name] = to_si(w, raw.astype(np.dtype(WIRE_TYPES[w.type])))
        else:
            lo, hi = int_range(w.type)
            values[name] = to_si(w, int(rng.integers(lo, hi, endpoint=True)))
    return cls(**values, extra=extra)


def pathfinder_ensemble(seed: int, n_cells: int = 0) -> pd0.Ensemble:
    """Pathfinder-like: fixed leader 58 B, variable leader 77 B, [profile], bottom track 81 B,
    0x5803 (70 B) and 0x5804 (41 B)."""
    rng = np.random.default_rng(seed)
    fl = random_block(pd0.FixedLeader, rng, n_present=len(wires(pd0.FixedLeader)) - 1)
    fl = dataclasses.replace(fl, n_beams=4, n_cells=n_cells, coord_transform=0x1F)
    ctx = {"n_cells": n_cells, "n_beams": 4}
    bt = random_block(pd0.BottomTrack, rng, n_present=len(wires(pd0.BottomTrack)) - 1)
    kw = {}
    if n_cells:
        kw = {"velocity": random_block(pd0.Velocity, rng, ctx)}
    return pd0.Ensemble(
        fixed_leader=fl,
        variable_leader=random_block(pd0.VariableLeader, rng),
        bottom_track=bt,
        bt_high_res=random_block(pd0.BottomTrackHighRes, rng),
        bt_range=random_block(pd0.BottomTrackRange, rng),
        **kw,
    )


def workhorse_ensemble(seed: int, n_cells: int = 5) -> pd0.Ensemble:
    """Workhorse-like: fixed leader 59 B, variable leader 65 B, velocity, correlation, echo,
    percent good, bottom track 85 B, two reserved bytes before the checksum."""
    rng = np.random.default_rng(seed)
    fl = dataclasses.replace(
        random_block(pd0.FixedLeader, rng), n_beams=4, n_cells=n_cells, coord_transform=0x08
    )
    ctx = {"n_cells": n_cells, "n_beams": 4}
    vl_fields = [name for name, _ in wires(pd0.VariableLeader)]
    return pd0.Ensemble(
        fixed_leader=fl,
        variable_leader=random_block(
            pd0.VariableLeader, rng, n_present=vl_fields.index("rtc_y2k") + 1
        ),
        velocity=random_block(pd0.Velocity, rng, ctx),
        correlation=random_block(pd0.Correlation, rng, ctx),
        echo_intensity=random_block(pd0.EchoIntensity, rng, ctx),
        percent_good=random_block(pd0.PercentGood, rng, ctx),
        bottom_track=random_block(pd0.BottomTrack, rng),
        trailer=b"\x12\x34",
    )


def block_extents(frame: bytes) -> dict[int, tuple[int, int]]:
    """Data type ID -> (offset, next offset or nBytes), read by hand from the header."""
    nbytes, n = struct.unpack_from("<H", frame, 2)[0], frame[5]
    offsets = struct.unpack_from(f"<{n}H", frame, 6)
    ends = [*sorted(offsets)[1:], nbytes]
    end_of = dict(zip(sorted(offsets), ends, strict=True))
    return {struct.unpack_from("<H", frame, o)[0]: (o, end_of[o]) for o in offsets}


def clean_frames(make, count: int, start_seed: int = 0) -> list[bytes]:
    """Encoded ensembles with no 7F 7F pair except their sync and not ending in 7F, so that a
    corrupted neighbour yields exactly one bad sync candidate (exact counts below)."""
    out = []
    seed = start_seed
    while len(out) < count:
        frame = pd0.encode(make(seed))
        seed += 1
        if frame.find(pd0.SYNC, 1) < 0 and frame[-1] != 0x7F:
            out.append(frame)
    return out


def run_framer(stream: bytes, chunk: int, policy: str = "ignore") -> tuple[list[bytes], object]:
    f = pd0.Pd0Framer(policy=policy)
    chunks = (stream[i : i + chunk] for i in range(0, len(stream), chunk))
    frames = [fr.data for fr in f.frames(chunks)]
    return frames, f.stats


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def test_tables_cover_every_byte_and_documented_sizes() -> None:
    ctx = {"n_cells": 3, "n_beams": 4}
    sizes = {cls.__name__: block_size(cls, ctx) for cls in pd0._TABLES.values()}
    assert sizes == {
        "FixedLeader": 59, "VariableLeader": 77, "Velocity": 2 + 2 * 12, "Correlation": 2 + 12,
        "EchoIntensity": 14, "PercentGood": 14, "BottomTrack": 85, "BottomTrackHighRes": 70,
        "BottomTrackRange": 41,
    }
    for cls in pd0._TABLES.values():  # contiguous tables: no gap, no overlap
        plan = pd0._plan(cls, {"n_cells": 3, "n_beams": 4}, 10_000)
        assert plan.end == block_size(cls, {"n_cells": 3, "n_beams": 4}) and not plan.absent
        pos = 2
        for _, w in wires(cls):
            assert w.offset == pos
            pos += w.nbytes({"n_cells": 3, "n_beams": 4})
    # the documented sizes of the real instruments are prefixes of the tables
    fl_names = [n for n, _ in wires(pd0.FixedLeader)]
    assert dict(wires(pd0.FixedLeader))["serial_number"].offset + 4 == 58  # Pathfinder
    assert fl_names[-1] == "beam_angle"  # byte 58: the Workhorse's 59th
    bt = dict(wires(pd0.BottomTrack))
    assert (bt["range_lsb"].offset, bt["velocity"].offset, bt["range_msb"].offset) == (16, 24, 77)
    assert bt["range_msb"].offset + 4 == 81


@pytest.mark.parametrize("cls", list(pd0._TABLES.values()), ids=lambda c: c.__name__)
def test_fast_plan_matches_decode_block(cls) -> None:
    ctx = {"n_cells": 3, "n_beams": 4} if cls.ID in CELL_IDS else {}
    rng = np.random.default_rng(cls.ID)
    size = block_size(cls, ctx)
    for _ in range(20):
        buf = rng.integers(0, 256, size + 5, dtype=np.uint8).tobytes()
        slow = decode_block(cls, buf, 0, ctx, extra=b"xy")
        fast = pd0._decode(pd0._plan(cls, ctx, size), buf, 0, b"xy")
        assert fast == slow
        joined = buf + bytes(size + 5)
        bulk = pd0._decode_bulk(pd0._plan(cls, ctx, size), joined, 1, size + 5, 0, [b"xy"])
        assert bulk == [slow]


# --------------------------------------------------------------------------------------------
# Round trips and conventions on synthetic ensembles
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_pathfinder_round_trip(seed: int) -> None:
    ens = pathfinder_ensemble(seed, n_cells=seed)
    frame = pd0.encode(ens)
    ext = block_extents(frame)
    assert {k: b - a for k, (a, b) in ext.items()} == {
        0x0000: 58, 0x0080: 77, 0x0600: 81, 0x5803: 70, 0x5804: 41,
        **({0x0100: 2 + 8 * seed} if seed else {}),
    }
    assert sum(frame[:-2]) & 0xFFFF == struct.unpack("<H", frame[-2:])[0]
    back = pd0.decode(frame)
    assert back == ens
    assert pd0.encode(back) == frame
    assert back.fixed_leader.beam_angle is None and back.bottom_track.reserved_81 is None
    assert back.variable_leader.transducer_impedance is not None
    assert back.coordinate_frame is pd0.CoordinateFrame.EARTH


@pytest.mark.parametrize("seed", range(5))
def test_workhorse_round_trip(seed: int) -> None:
    ens = workhorse_ensemble(seed, n_cells=1 + seed)
    frame = pd0.encode(ens)
    ext = block_extents(frame)
    nbytes = struct.unpack_from("<H", frame, 2)[0]
    assert ext[0x0000][1] - ext[0x0000][0] == 59
    assert ext[0x0080][1] - ext[0x0080][0] == 65
    assert ext[0x0600][1] - ext[0x0600][0] == 85 + 2  # the last block, then 2 reserved bytes
    assert frame[nbytes - 2 : nbytes] == b"\x12\x34"
    back = pd0.decode(frame)
    assert back == ens and pd0.encode(back) == frame
    assert back.trailer == b"\x12\x34" and back.bottom_track.extra == b""
    assert back.variable_leader.health_status is None
    assert back.velocity.velocity.shape == (1 + seed, 4)
    assert back.coordinate_frame is pd0.CoordinateFrame.INSTRUMENT


def test_sign_conventions_and_frames() -> None:
    ens = pathfinder_ensemble(3)
    bt, hr = ens.bottom_track, ens.bt_high_res
    np.testing.assert_array_equal(bt.vehicle_velocity, -bt.velocity)
    np.testing.assert_array_equal(hr.vehicle_velocity, hr.bt_velocity)
    for ex, frame in [(0x00, "BEAM"), (0x0C, "INSTRUMENT"), (0x17, "SHIP"), (0x1F, "EARTH")]:
        fl = dataclasses.replace(ens.fixed_leader, coord_transform=ex)
        assert fl.coordinate_frame.name == frame
    # BT range: LSB word in cm + MSB byte x 65536 cm; 0 = bad
    bt2 = dataclasses.replace(
        bt, range_lsb=np.array([0, 0.01, 655.35, 0.0]), range_msb=np.array([0, 0, 655.36, 655.36])
    )
    np.testing.assert_allclose(bt2.range, [np.nan, 0.01, 1310.71, 655.36], equal_nan=True)
    assert raw_value(bt2, "range_msb").tolist() == [0, 0, 1, 1]


def test_device_time_from_rtc_and_y2k() -> None:
    vl = random_block(pd0.VariableLeader, np.random.default_rng(1))
    vl = dataclasses.replace(
        vl,
        rtc=np.array([17, 5, 24, 11, 50, 13, 40]),
        rtc_y2k=np.array([20, 17, 5, 24, 11, 50, 13, 40]),
    )
    t = dt.datetime(2017, 5, 24, 11, 50, 13, 400000, tzinfo=dt.UTC)
    assert vl.device_time == t and vl.device_time_s == pytest.approx(t.timestamp())
    no_y2k = dataclasses.replace(vl, rtc=np.array([99, 12, 31, 23, 59, 59, 99]), rtc_y2k=None)
    assert no_y2k.device_time == dt.datetime(1999, 12, 31, 23, 59, 59, 990000, tzinfo=dt.UTC)
    bad = dataclasses.replace(vl, rtc=np.array([17, 13, 1, 0, 0, 0, 0]))
    assert bad.device_time is None and math.isnan(bad.device_time_s)


def test_unknown_blocks_order_layout_gap_kept_exactly() -> None:
    ens = pathfinder_ensemble(7)
    raw = (pd0.RawBlock(b"\x00\x30" + bytes(range(30))), pd0.RawBlock(b"\xd8\x30\x01\x02"))
    ens = dataclasses.replace(
        ens, unknown=raw, spare=9, gap=b"\xaa\xbb",
        order=(0x0000, 0x0080, 0x3000, 0x0600, 0x30D8, 0x5804, 0x5803),
        layout=(0, 1, 3, 2, 4, 6, 5), trailer=b"",
    )
    frame = pd0.encode(ens)
    assert frame[4] == 9 and frame[6 + 14 : 6 + 16] == b"\xaa\xbb"
    offsets = struct.unpack_from("<7H", frame, 6)
    assert offsets[3] < offsets[2]  # BT before 0x3000 in the bytes, after it in the table
    back = pd0.decode(frame)
    assert back == ens and pd0.encode(back) == frame
    assert [b.id for b in back.unknown] == [0x3000, 0x30D8]


def test_decode_errors_name_block_field_and_offset() -> None:
    frame = bytearray(pd0.encode(pathfinder_ensemble(4)))
    assert frame[5] == 5  # fixed and variable leader, bottom track, 0x5803, 0x5804

    def fixed(buf: bytearray) -> bytes:
        nb = struct.unpack_from("<H", buf, 2)[0]
        struct.pack_into("<H", buf, nb, sum(buf[:nb]) & 0xFFFF)
        return bytes(buf)

    bad = bytearray(frame)
    struct.pack_into("<H", bad, 6 + 2 * 2, 60000)  # third offset (bottom track) outside
    with pytest.raises(DecodeError, match=r"byte 10: data type #3 offset 60000 outside"):
        pd0.decode(fixed(bad))
    bad = bytearray(frame)
    bt_off = struct.unpack_from("<H", bad, 10)[0]
    struct.pack_into("<H", bad, 12, bt_off + 40)  # 0x5803 now starts inside the bottom track
    with pytest.raises(DecodeError, match=rf"0x0600 \(BottomTrack\) at byte {bt_off}: block too "
                       rf"short \(40 bytes\): field percent_good needs bytes {bt_off + 40}"):
        pd0.decode(fixed(bad))
    nofl = dataclasses.replace(workhorse_ensemble(1), fixed_leader=None)
    with pytest.raises(ValueError, match="needs a fixed leader"):
        pd0.encode(nofl)
    bad = bytearray(frame)
    bad[-1] ^= 1
    with pytest.raises(DecodeError, match="checksum"):
        pd0.decode(bytes(bad))


def test_decode_many_equals_decode_on_mixed_runs() -> None:
    wh = [pd0.encode(workhorse_ensemble(s, n_cells=3)) for s in range(6)]
    pf = [pd0.encode(pathfinder_ensemble(s, n_cells=2)) for s in range(5)]
    frames = [pf[0], *wh, pf[1], pf[2], *pf[3:], wh[0], wh[0], wh[0], wh[0]]
    got = pd0.decode_many(frames)
    assert got == [pd0.decode(f) for f in frames]
    assert [pd0.encode(e) for e in got] == frames
    assert got[-1].fixed_leader is got[-2].fixed_leader  # identical blocks are shared
    bad = bytearray(wh[2])
    bad[-1] ^= 0xFF
    with pytest.raises(DecodeError, match="checksum"):
        pd0.decode_many([*wh[:2], bytes(bad), *wh[3:]])


# --------------------------------------------------------------------------------------------
# Hypothesis
# --------------------------------------------------------------------------------------------


def field_strategy(w: Wire, ctx):
    if w.type == "bytes":
        return st.binary(min_size=w.size, max_size=w.size)
    lo, hi = int_range(w.type)
    if w.shape:
        dtype = np.dtype(WIRE_TYPES[w.type])
        return hnp.arrays(dtype, w.resolve_shape(ctx), elements=st.integers(lo, hi)).map(
            lambda a, w=w: to_si(w, a)
        )
    return st.integers(lo, hi).map(lambda r, w=w: to_si(w, r))


@st.composite
def block_st(draw, cls, ctx, may_have_extra: bool = True):
    rows = wires(cls)
    k = draw(st.integers(required_fields(cls, ctx), len(rows)))
    values = {
        name: draw(field_strategy(w, ctx)) if i < k else None for i, (name, w) in enumerate(rows)
    }
    # bytes after a short table would be read as its next field: only a full table has a tail
    extra = draw(st.binary(max_size=5)) if k == len(rows) and may_have_extra else b""
    return cls(**values, extra=extra)


@st.composite
def ensemble_st(draw):
    n_beams = draw(st.integers(1, 5))
    n_cells = draw(st.integers(0, 6))
    ctx = {"n_cells": n_cells, "n_beams": n_beams}
    present = draw(st.sets(st.sampled_from(KNOWN)))
    if present & set(CELL_IDS):
        present.add(pd0.ID_FIXED_LEADER)
    values = {}
    for bid in present:
        values[pd0._FIELD_OF[bid]] = draw(block_st(pd0._TABLES[bid], ctx))
    if pd0.ID_FIXED_LEADER in present:
        values["fixed_leader"] = dataclasses.replace(
            values["fixed_leader"], n_beams=n_beams, n_cells=n_cells
        )
    unknown_ids = draw(
        st.lists(st.integers(0, 0xFFFF).filter(lambda i: i not in KNOWN), max_size=2)
    )
    unknown = tuple(
        pd0.RawBlock(struct.pack("<H", i) + draw(st.binary(max_size=8))) for i in unknown_ids
    )
    if not present and not unknown:
        unknown = (pd0.RawBlock(b"\x34\x12"),)
    ens = pd0.Ensemble(**values, unknown=unknown, spare=draw(st.integers(0, 255)),
                       gap=draw(st.binary(max_size=3)))
    order = draw(st.permutations(ens.ids))
    layout = draw(st.permutations(range(len(order))))
    last = order[layout[-1]]  # the block at the end of the bytes
    trailer = draw(st.binary(max_size=4))
    if last in pd0._FIELD_OF:  # its tail is the ensemble's trailer, not the block's extra
        name = pd0._FIELD_OF[last]
        blk = getattr(ens, name)
        if any(getattr(blk, n) is None for n, _ in wires(type(blk))):
            trailer = b""  # after a short table, trailing bytes would be read as its next field
        ens = dataclasses.replace(ens, **{name: dataclasses.replace(blk, extra=b"")})
    else:
        trailer = b""  # a raw block runs to nBytes
    # decoding lists raw blocks in offset-table order
    rank = {}
    for k, bid in enumerate(order):
        rank.setdefault(bid, []).append(k)
    raw = sorted(ens.unknown, key=lambda b: rank[b.id].pop(0))
    ens = dataclasses.replace(ens, unknown=tuple(raw))
    return dataclasses.replace(
        ens,
        order=() if tuple(order) == ens.ids else tuple(order),
        layout=() if list(layout) == list(range(len(order))) else tuple(layout),
        trailer=trailer,
    )


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ensemble_st())
def test_property_message_encode_decode_identity(ens: pd0.Ensemble) -> None:
    frame = pd0.encode(ens)
    back = pd0.decode(frame)
    assert back == ens
    assert pd0.encode(back) == frame
    json.dumps(to_jsonable(back))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ensemble_st(), st.data())
def test_property_frame_decode_encode_identity(ens: pd0.Ensemble, data) -> None:
    """Any checksum-valid frame that decodes re-encodes to the same bytes, including frames
    whose block bytes were scrambled (then re-checksummed)."""
    frame = bytearray(pd0.encode(ens))
    nbytes = struct.unpack_from("<H", frame, 2)[0]
    start = 6 + 2 * frame[5]
    for _ in range(data.draw(st.integers(0, 6))):
        if nbytes > start:
            i = data.draw(st.integers(start, nbytes - 1))
            frame[i] = data.draw(st.integers(0, 255))
    struct.pack_into("<H", frame, nbytes, sum(frame[:nbytes]) & 0xFFFF)
    try:
        back = pd0.decode(bytes(frame))
    except DecodeError:
        return  # e.g. an ID byte scrambled into a known ID whose table does not fit
    assert pd0.encode(back) == bytes(frame)
    f = pd0.Pd0Framer(policy="raise")
    assert [fr.data for fr in f.feed(bytes(frame))] == [bytes(frame)]


# --------------------------------------------------------------------------------------------
# Named corrupted fixtures (exact counts, every chunk size)
# --------------------------------------------------------------------------------------------

CHUNKS = (1, 7, 64, 100_000)


@pytest.fixture(scope="module")
def good() -> list[bytes]:
    frames = clean_frames(lambda s: pathfinder_ensemble(s, n_cells=2), 3)
    frames += clean_frames(lambda s: workhorse_ensemble(s, n_cells=3), 2, start_seed=100)
    return frames


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_bad_checksum(good, chunk: int) -> None:
    bad = bytearray(good[1])
    bad[-2] ^= 0x01
    frames, s = run_framer(good[0] + bytes(bad) + good[2], chunk)
    assert frames == [good[0], good[2]]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (2, 1, len(bad))
    assert dict(s.reasons) == {"checksum": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_bad_length(good, chunk: int) -> None:
    short = bytearray(good[1])
    struct.pack_into("<H", short, 2, 5)  # smaller than a header
    cut = bytearray(good[3])
    struct.pack_into("<H", cut, 2, len(cut) - 60)  # the last offsets now lie beyond nBytes
    huge = bytearray(good[4])
    struct.pack_into("<H", huge, 2, 0xFFFF)  # plausible header, then the checksum fails
    stream = good[0] + bytes(short) + good[2] + bytes(cut) + bytes(huge) + good[1]
    frames, s = run_framer(stream, chunk)
    assert frames == [good[0], good[2], good[1]]
    assert (s.frames, s.bad_frames) == (3, 3)
    assert s.skipped_bytes == len(short) + len(cut) + len(huge)
    # nBytes 65535 passes the header checks, but the complete ensemble that starts inside it
    # ends the wait at once (it used to hold good[1] until the stream ended)
    assert dict(s.reasons) == {"length": 1, "checksum": 1, "inner_frame": 1}


def test_fixture_bad_length_rejected_before_waiting(good) -> None:
    """An implausible header is judged as soon as its bytes are there (no waiting for nBytes)."""
    short = bytearray(good[0][:8])
    struct.pack_into("<H", short, 2, 5)
    last_offset = max(block_extents(good[3]).values())[0]
    cut = bytearray(good[3][:40])
    struct.pack_into("<H", cut, 2, last_offset + 1)  # the last block would start past nBytes
    none = bytearray(good[0][:8])
    none[5] = 0
    for buf, reason in [
        (short, "length: nBytes 5 cannot hold the header and 6 offsets"),
        (cut, f"offset: data type #7 at {last_offset}, outside 20..{last_offset - 1}"),
        (none, r"data_types: 0 \(allowed 1..32\)"),
    ]:
        f = pd0.Pd0Framer(policy=ErrorPolicy.RAISE, source="cap.pd0")
        with pytest.raises(FrameError, match=rf"cap.pd0: bad frame at byte offset 0: {reason}"):
            f.feed(bytes(buf))
    f = pd0.Pd0Framer(policy=ErrorPolicy.RAISE)
    assert f.feed(good[0][:40]) == [] and f.buffered == 40  # a plausible header waits


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_truncated(good, chunk: int) -> None:
    trunc = good[1][: len(good[1]) // 2]
    frames, s = run_framer(good[0] + trunc + good[2] + good[3][:50], chunk)
    assert frames == [good[0], good[2]]
    # the truncated frame fails its checksum once the next frame's bytes arrive; the one cut at
    # the end of the stream is judged truncated at finish()
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (2, 2, len(trunc) + 50)
    assert dict(s.reasons) == {"checksum": 1, "truncated": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_garbage_between_frames(good, chunk: int) -> None:
    rng = np.random.default_rng(5)
    garbage = bytes(b for b in rng.integers(0, 256, 300, dtype=np.uint8).tobytes() if b != 0x7F)
    fake = b"\x7f\x7f\x40\x00\x00\x00junk"  # a sync with 0 data types
    stream = garbage + good[0] + garbage + fake + good[1] + good[2] + garbage
    frames, s = run_framer(stream, chunk)
    assert frames == good[:3]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (3, 1, 3 * len(garbage) + len(fake))
    assert dict(s.reasons) == {"data_types": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_file_starting_mid_frame(good, chunk: int) -> None:
    stream = good[3][37:] + good[0] + good[4]
    frames, s = run_framer(stream, chunk)
    assert frames == [good[0], good[4]]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (2, 0, len(good[3]) - 37)


# --------------------------------------------------------------------------------------------
# Fuzz
# --------------------------------------------------------------------------------------------


def feed_random_chunks(f: pd0.Pd0Framer, stream: bytes, rng: np.random.Generator) -> list[bytes]:
    out, i = [], 0
    while i < len(stream):
        n = int(rng.integers(1, 300))
        out += [fr.data for fr in f.feed(stream[i : i + n])]
        i += n
    return out + [fr.data for fr in f.finish()]


@pytest.mark.parametrize("policy", ["ignore", "log"])
@pytest.mark.parametrize("seed", range(3))
def test_fuzz_random_bytes(policy: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, 60_000, dtype=np.uint8)
    noise[rng.integers(0, noise.size, 600)] = 0x7F  # many sync candidates
    f = pd0.Pd0Framer(policy=policy)
    frames = feed_random_chunks(f, noise.tobytes(), rng)
    for fr in frames:  # whatever comes out has a valid checksum
        assert sum(fr[:-2]) & 0xFFFF == struct.unpack("<H", fr[-2:])[0]
    assert f.stats.bytes_in == 60_000
    assert f.stats.skipped_bytes + sum(map(len, frames)) == 60_000


@pytest.mark.parametrize("policy", ["ignore", "log"])
@pytest.mark.parametrize("seed", range(4))
def test_fuzz_corrupted_stream_keeps_untouched_frames(policy: str, seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    makers = [lambda s: pathfinder_ensemble(s, n_cells=s % 3), lambda s: workhorse_ensemble(s, 2)]
    frames = [pd0.encode(makers[i % 2](1000 * seed + i)) for i in range(60)]
    stream = bytearray()
    untouched = []
    for frame in frames:
        if rng.random() < 0.1:
            stream += rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        if rng.random() < 0.35:
            buf = bytearray(frame)
            for _ in range(int(rng.integers(1, 4))):
                kind, pos = rng.integers(0, 3), int(rng.integers(0, len(buf)))
                if kind == 0:
                    buf[pos] ^= 1 << int(rng.integers(0, 8))
                elif kind == 1:
                    del buf[pos : pos + int(rng.integers(1, 6))]
                else:
                    n = int(rng.integers(1, 6))
                    buf[pos:pos] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            stream += buf
        else:
            stream += frame
            untouched.append(frame)
    f = pd0.Pd0Framer(policy=policy)
    got = feed_random_chunks(f, bytes(stream), rng)
    it = iter(got)
    assert all(any(g == u for g in it) for u in untouched)  # in order, none lost
    assert len(untouched) >= 30 and f.stats.bad_frames >= 1
    for fr in got:
        with contextlib.suppress(DecodeError):
            pd0.decode(fr)


# --------------------------------------------------------------------------------------------
# Real files (../shared/data/pd0)
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rdi(shared_data: Path) -> tuple[list[bytes], object, bytes]:
    path = shared_data / "pd0" / "RDI_withBT.000"
    f = pd0.Pd0Framer(policy="ignore", source=str(path))
    frames = [fr.data for fr in read_file_frames(f, path)]
    return frames, f.stats, path.read_bytes()


@pytest.fixture(scope="module")
def enr(shared_data: Path) -> tuple[list[bytes], object, bytes]:
    path = shared_data / "pd0" / "vmdas02_os.ENR"
    f = pd0.Pd0Framer(policy="ignore", source=str(path))
    frames = [fr.data for fr in read_file_frames(f, path)]
    return frames, f.stats, path.read_bytes()


def test_real_workhorse_file(rdi) -> None:
    frames, stats, data = rdi
    assert len(data) == 1_000_000
    assert stats.frames == len(frames) == 1721
    # the file ends 99 bytes into an ensemble that declares 579 bytes + checksum: one bad
    # (truncated) candidate, its 99 bytes skipped; nothing else is skipped
    assert (stats.bad_frames, stats.skipped_bytes) == (1, 99)
    assert dict(stats.reasons) == {"truncated": 1}
    tail = data[-99:]
    assert tail[:2] == b"\x7f\x7f" and struct.unpack_from("<H", tail, 2)[0] + 2 > 99
    assert sum(map(len, frames)) == 1_000_000 - 99
    for fr in frames:  # every checksum, independently
        assert sum(fr[:-2]) % 65536 == struct.unpack("<H", fr[-2:])[0]
    ens = pd0.decode_many(frames)
    assert ens == [pd0.decode(fr) for fr in frames]
    for e, fr in zip(ens, frames, strict=True):
        assert e.bottom_track is not None
        assert pd0.encode(e) == fr
        o, end = block_extents(fr)[pd0.ID_BOTTOM_TRACK]
        assert end - len(e.trailer) - o == 85  # 85-byte Workhorse bottom track
    assert {e.trailer.__len__() for e in ens} == {2}
    assert all(e.fixed_leader.beam_angle is not None for e in ens)


def test_real_workhorse_values_by_hand(rdi) -> None:
    frames, _, _ = rdi
    first = pd0.decode(frames[0])
    fr = frames[0]
    fl_off, vl_off = struct.unpack_from("<2H", fr, 6)
    assert first.fixed_leader.n_cells == fr[fl_off + 9] == 17
    assert first.fixed_leader.n_beams == fr[fl_off + 8] == 4
    assert fr[fl_off + 25] == 0x1F and first.coordinate_frame is pd0.CoordinateFrame.EARTH
    cell_cm = struct.unpack_from("<H", fr, fl_off + 12)[0]
    assert first.fixed_leader.cell_size == pytest.approx(cell_cm / 100)
    assert first.fixed_leader.beam_angle == pytest.approx(math.radians(20))
    assert first.device_time == dt.datetime(2017, 5, 24, 11, 50, 13, 400000, tzinfo=dt.UTC)
    heading = struct.unpack_from("<H", fr, vl_off + 18)[0] * 0.01
    assert math.degrees(first.variable_leader.heading) == pytest.approx(heading)
    # first ensemble: bottom not found (ranges 0, velocities -32768) -> NaN
    assert np.isnan(first.bottom_track.range).all() and np.isnan(first.bottom_track.velocity).all()
    # first ensemble with a valid bottom: compare with the bytes at the documented offsets
    k = next(  # first ensemble whose four bottom velocities are good (506 has ranges only)
        i for i, f in enumerate(frames) if np.isfinite(pd0.decode(f).bottom_track.velocity).all()
    )
    fr = frames[k]
    bt_off = block_extents(fr)[pd0.ID_BOTTOM_TRACK][0]
    lsb = struct.unpack_from("<4H", fr, bt_off + 16)
    msb = struct.unpack_from("<4B", fr, bt_off + 77)
    vel = struct.unpack_from("<4h", fr, bt_off + 24)
    bt = pd0.decode(fr).bottom_track
    expect_range = [(lo + 65536 * hi) / 100 or np.nan for lo, hi in zip(lsb, msb, strict=True)]
    np.testing.assert_allclose(bt.range, expect_range, equal_nan=True)
    expect_vel = [v / 1000 if v != -32768 else np.nan for v in vel]
    np.testing.assert_allclose(bt.velocity, expect_vel, equal_nan=True)
    np.testing.assert_allclose(bt.vehicle_velocity, -bt.velocity, equal_nan=True)
    assert np.isfinite(bt.range).all() and k > 506


def test_real_ocean_surveyor_file(enr) -> None:
    frames, stats, data = enr
    assert (stats.frames, stats.bad_frames, stats.skipped_bytes) == (690, 0, 0)
    assert sum(map(len, frames)) == len(data)
    ens = pd0.decode_many(frames)
    assert ens == [pd0.decode(fr) for fr in frames]
    for e, fr in zip(ens, frames, strict=True):
        assert pd0.encode(e) == fr
        o, end = block_extents(fr)[pd0.ID_BOTTOM_TRACK]
        assert end - o == 81  # the Pathfinder-size bottom track, followed by 0x3000
        assert [b.id for b in e.unknown] == [0x3000, 0x30D8]
        assert e.variable_leader.rtc_y2k is None and len(e.variable_leader.extra) == 3
        assert e.bottom_track.reserved_81 is None and e.bottom_track.extra == b""
    first, fr = ens[0], frames[0]
    assert first.coordinate_frame is pd0.CoordinateFrame.BEAM
    assert first.fixed_leader.n_cells == 80
    bt_off = block_extents(fr)[pd0.ID_BOTTOM_TRACK][0]
    lsb = struct.unpack_from("<4H", fr, bt_off + 16)
    np.testing.assert_allclose(first.bottom_track.range, [x / 100 for x in lsb])
    np.testing.assert_allclose(first.bottom_track.range, [347.83, 334.45, 331.11, 341.14])
    np.testing.assert_allclose(first.bottom_track.velocity, [-0.049, 0.052, 0.037, -0.031])
    assert first.device_time == dt.datetime(2022, 3, 14, 19, 29, 10, 80000, tzinfo=dt.UTC)


def test_real_ensembles_survive_json(rdi, enr) -> None:
    """to_jsonable -> JSON -> from_jsonable gives a typed ensemble that re-encodes exactly (the
    bus carries decoded messages as JSON)."""
    for frames in (rdi[0][:: 200], enr[0][:: 100]):
        for fr in frames:
            d = json.loads(json.dumps(to_jsonable(pd0.decode(fr))))
            assert d["type"] == "pd0.Ensemble"
            back = from_jsonable(d)
            assert isinstance(back, pd0.Ensemble) and pd0.encode(back) == fr


def test_format_registry() -> None:
    fmt = get_format("pd0")
    assert fmt is pd0.FORMAT and isinstance(fmt.framer(), pd0.Pd0Framer)
    frame = pd0.encode(pathfinder_ensemble(1))
    (ens,) = fmt.decode(frame)
    assert fmt.encode(ens) == frame


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def auvgw_cmd() -> list[str]:
    exe = Path(sys.executable).parent / "auvgw"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "auvgw.cli"]


@pytest.mark.e2e
def test_cli_decode_real_file(shared_data: Path) -> None:
    path = shared_data / "pd0" / "RDI_withBT.000"
    out = subprocess.run(
        [*auvgw_cmd(), "decode", "--format", "pd0", str(path)],
        capture_output=True, text=True, timeout=240,
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 1721
    first = json.loads(lines[0])
    assert first["type"] == "pd0.Ensemble"
    assert first["fixed_leader"]["n_cells"] == 17
    assert first["bottom_track"]["velocity"] == [None] * 4
    summary = json.loads(out.stderr.strip().splitlines()[-1])
    assert summary["messages"] == {"pd0.Ensemble": 1721}
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (1721, 1, 99)
    assert summary["decode_errors"] == 0


@pytest.mark.e2e
def test_cli_decode_not_pd0(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_bytes(b"this is not a PD0 capture\n" * 200 + b"\x7f\x7f\x00\x00junk")
    out = subprocess.run(
        [*auvgw_cmd(), "decode", "--format", "pd0", str(path)],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 2
    assert out.stdout == ""
    err = out.stderr.strip().splitlines()
    assert "Traceback" not in out.stderr
    assert err[-1].startswith("auvgw decode: error: ") and "no valid pd0 frame" in err[-1]


def test_compiled_blocks_match_the_field_walk_on_real_ensembles(shared_data) -> None:
    """Every data type of every ensemble of both real files, as the gateway decodes it
    (compiled per table, cell and beam count), equals the table's field walk
    (``spec.decode_block``) field for field, wherever the block holds the whole table."""
    compared = 0
    for name in ("RDI_withBT.000", "vmdas02_os.ENR"):
        frames, _ = get_format("pd0").frames_of_file(shared_data / "pd0" / name)
        for f in frames:
            ens = pd0.decode(f.data, verified=True)
            fl = ens.fixed_leader
            ext = block_extents(f.data)
            last = max(a for a, _ in ext.values())
            for bid, (a, b) in ext.items():
                cls = pd0._TABLES.get(bid)
                if cls is None:
                    continue
                ctx = {"n_cells": fl.n_cells, "n_beams": fl.n_beams} if bid in CELL_IDS else {}
                size = block_size(cls, ctx)
                if b - a < size:
                    continue  # a short block (trailing fields None): the plan's own test
                extra = b"" if a == last else f.data[a + size : b]
                walked = decode_block(cls, f.data, a, ctx, extra=extra)
                got = getattr(ens, pd0._FIELD_OF[bid])
                for fld in dataclasses.fields(cls):
                    x, y = getattr(got, fld.name), getattr(walked, fld.name)
                    if isinstance(y, np.ndarray):
                        assert np.array_equal(x, y, equal_nan=True), (name, fld.name)
                    else:
                        assert x == y or (x != x and y != y), (name, fld.name)
                compared += 1
    assert compared > 1721 * 5
