"""Every compiled plan against the reference walker, on every table the registry ships.

``spec.plan(cls, ctx, avail)`` compiles a message table once (decode, encode, bulk / record
columns); ``spec._decode_block_fields`` and ``spec._encode_block_fields`` walk the same table one
row at a time and stay the reference. For every binary table of every registered format (and a
Kongsberg Depth beam table, built from header values), Hypothesis draws the array
dimensions, the base, the block bytes and the block length: both paths must give the same values
(same types, dtypes, NaNs, read-only arrays) or the same error, and the same bytes on encoding.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.drivers import kongsberg
from auvgw.drivers.spec import (
    _INT_LIMITS,
    LAZY_TYPES,
    MESSAGE_TYPES,
    WireError,
    _decode_block_fields,
    _encode_block_fields,
    _walk_values,
    _wire_fields,
    block_size,
    decode_block,
    encode_block,
    message,
    plan,
    resolve_type,
    wire,
)
from auvgw.envelope import message_class
from auvgw.testing import format_samples


@message(endian=">")
class Toy:
    """Every row kind in one table: big-endian, out of byte order, invalid codes, an N-D array,
    str, bytes, a scaled float, a gap."""

    temp: float = wire("s16", 1, scale=0.01, add=-5.0)
    code: int = wire("u8", 0, invalid=0xFF)
    vel: np.ndarray = wire("s16", 3, shape=(2, 2), scale=1e-3, invalid=-32768)
    tag: str = wire("str", 11, size=3)
    blob: bytes = wire("bytes", 14, size=2)
    gain: float = wire("f32", 17, scale=2.0)
    raw: np.ndarray = wire("u16", 21, shape=("n",))


def _shipped_tables() -> list[type]:
    message_class("no such type")  # loads every codec of the registry: every table registered
    for name in list(LAZY_TYPES):  # the TOML tables (HN-100, ...) are built on first use
        resolve_type(name)
    depth = [type(format_samples.dep(0, 3).beams)]  # built from a header's resolutions
    tables = {c for c in [*MESSAGE_TYPES.values(), *depth]  # not a test module's toy table
              if _wire_fields(c) and c.__module__.startswith("auvgw.")}
    return [Toy, *sorted(tables, key=lambda c: f"{c.__module__}.{c.__name__}")]


TABLES = _shipped_tables()
def dims(cls: type) -> list[str]:
    return sorted({d for _, w in _wire_fields(cls) for d in w.shape if isinstance(d, str)})


#: record tables: every row one item per record, the named dimension counting the records
RECORD_COUNT = {c: "n_beams" for c in TABLES if c is kongsberg.XYZ88Beams
                or issubclass(c, kongsberg.DepthBeams)}  # fmt: skip
#: tables walked as one block (an ASCII line table's rows are field positions, not bytes)
BLOCK_TABLES = [c for c in TABLES if c not in RECORD_COUNT and plan(
    c, dict.fromkeys(dims(c), 1)).read is not None]  # fmt: skip


def same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and not a.flags.writeable
            and not b.flags.writeable
            and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
        )
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return type(a) is type(b) and a == b


def outcome(f: Any, *args: Any, **kw: Any) -> tuple[str, Any]:
    try:
        return "ok", f(*args, **kw)
    except Exception as exc:  # the two paths must fail alike
        return "error", (type(exc), str(exc))


def extras(cls: type) -> dict[str, Any]:
    wired = {n for n, _ in _wire_fields(cls)}
    return {f.name: None for f in dataclasses.fields(cls) if f.name not in wired}


def test_every_registered_format_has_its_tables_here() -> None:
    """The walk covers the binary tables of the formats (PD0, SeaNet, .V4LOG, Kongsberg,
    HN-100) and leaves out only the ASCII line tables."""
    names = {c.__name__ for c in BLOCK_TABLES} | {c.__name__ for c in RECORD_COUNT}
    assert {"FixedLeader", "Velocity", "BottomTrack", "HeadData", "V4LogHeader", "XYZ88",
            "XYZ88Beams", "Hn100Nav"} <= names  # fmt: skip
    assert len(BLOCK_TABLES) >= 25
    left_out = {c.__name__ for c in TABLES} - names - {"Toy"}
    assert left_out == {"Ms3aSample", "AcousticReply"}


@pytest.mark.parametrize("cls", BLOCK_TABLES, ids=lambda c: c.__name__)
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          derandomize=True)  # fmt: skip
@given(data=st.data())
def test_plan_decodes_and_encodes_as_the_walker(cls: type, data: st.DataObject) -> None:
    ctx = {d: data.draw(st.integers(0, 5), label=d) for d in dims(cls)}
    base = data.draw(st.integers(0, 3), label="base")
    size = block_size(cls, ctx)
    short = data.draw(st.integers(0, 2), label="short") == 0 and size > 0
    n = base + size - (1 if short else 0)
    raw = data.draw(st.binary(min_size=n, max_size=n), label="bytes")
    extra = extras(cls)
    want = outcome(_decode_block_fields, cls, raw, base, ctx, extra)
    for buf in (raw, bytearray(raw), memoryview(raw)):  # decode_block: the walker's outcome
        got = outcome(decode_block, cls, buf, base, ctx, **extra)
        assert got[0] == want[0], (cls, got, want)
        if want[0] == "error":
            assert got[1] == want[1]
        else:
            for name, _ in _wire_fields(cls):
                assert same(getattr(got[1], name), getattr(want[1], name)), (cls, name)
    if short:  # the walker's precise short-buffer error, through decode_block above
        return
    ref_values = _walk_values(cls, raw, base, ctx)  # the plan's reader: the walker's values
    p = plan(cls, ctx)
    assert p.read is not None
    for buf in (raw, bytearray(raw), memoryview(raw)):
        values = p.read(buf, base)
        assert set(values) == set(ref_values)
        for name, value in values.items():
            assert same(value, ref_values[name]), (cls, name)
    msg = object.__new__(cls)  # the rows' values, whatever the class's own checks say
    msg.__dict__.update(extra, **ref_values)
    # encode: the same bytes from the plan and the walker (gaps keep what the buffer held)
    fill = data.draw(st.binary(min_size=base + size, max_size=base + size), label="fill")
    ref, out = bytearray(fill), bytearray(fill)
    w = outcome(_encode_block_fields, msg, ref, base, ctx)
    g = outcome(encode_block, msg, out, base, ctx)
    assert g[0] == w[0] and (g[0] == "ok" or g[1] == w[1]), (g, w)
    assert out == ref
    # an integer row out of its range: the walker's error, named alike
    ints = [(n, w) for n, w in _wire_fields(cls)
            if w.type in _INT_LIMITS and not w.shape and not w.is_scaled]  # fmt: skip
    if ints:
        name, row = data.draw(st.sampled_from(ints), label="bad row")
        bad = object.__new__(cls)
        bad.__dict__.update(msg.__dict__, **{name: _INT_LIMITS[row.type][1] + 1})
        w = outcome(_encode_block_fields, bad, bytearray(fill), base, ctx)
        g = outcome(encode_block, bad, bytearray(fill), base, ctx)
        assert w[0] == g[0] == "error" and g[1] == w[1]


@pytest.mark.parametrize("cls", BLOCK_TABLES, ids=lambda c: c.__name__)
@settings(max_examples=8, deadline=None, derandomize=True)
@given(data=st.data())
def test_short_block_plan_is_the_walk_of_its_present_rows(cls: type, data: st.DataObject) -> None:
    """``plan(cls, ctx, avail)`` (PD0's short blocks): the rows that end within ``avail`` bytes
    have the walker's values; every later row (in byte order) is absent."""
    ctx = {d: data.draw(st.integers(0, 4), label=d) for d in dims(cls)}
    size = block_size(cls, ctx)
    avail = data.draw(st.integers(0, size), label="avail")
    raw = data.draw(st.binary(min_size=size, max_size=size), label="bytes")
    p = plan(cls, ctx, avail)
    rows = sorted(_wire_fields(cls), key=lambda r: r[1].offset)
    present = []
    for name, w in rows:
        if w.offset + w.nbytes(ctx) > avail:
            break
        present.append(name)
    assert [r.name for r in p.rows] == [n for n, _ in _wire_fields(cls) if n in present]
    assert list(p.absent) == [n for n, _ in rows if n not in present]
    assert p.read is not None
    got = p.read(raw, 0)
    want = _walk_values(cls, raw, 0, ctx)
    assert set(got) == set(present) | set(p.absent)
    assert all(got[name] is None for name in p.absent)
    for name in present:
        assert same(got[name], want[name]), (cls, name)


COLUMN_TABLES = [c for c in BLOCK_TABLES if not dims(c)] + list(RECORD_COUNT)


@pytest.mark.parametrize("cls", COLUMN_TABLES, ids=lambda c: c.__name__)
@settings(max_examples=6, deadline=None, derandomize=True)
@given(data=st.data())
def test_columns_are_the_walk_of_each_record(cls: type, data: st.DataObject) -> None:
    """Bulk decode (PD0 ensembles of one layout) and record tables (Kongsberg beams): record
    ``i`` of every column is the walker's value of the record ``i * stride`` bytes on; writing
    the columns back gives the records' bytes."""
    count = RECORD_COUNT.get(cls)
    ctx = {count: 1} if count else {}
    size = block_size(cls, ctx)
    stride = size + data.draw(st.integers(0, 3), label="pad")
    n = data.draw(st.integers(0, 6), label="n")
    base = data.draw(st.integers(0, 3), label="base")
    raw = data.draw(st.binary(min_size=base + n * stride, max_size=base + n * stride))
    p = plan(cls, ctx)
    cols = p.columns(raw, base, n, stride, count)
    for i in range(n):
        want = _walk_values(cls, raw, base + i * stride, ctx)
        for r in p.rows:
            ref = want[r.name]
            got = cols[r.name][i]
            if isinstance(ref, np.ndarray):
                ref = ref.reshape(r.record_shape(count))
                got = np.asarray(got)
                assert got.dtype == ref.dtype and not cols[r.name].flags.writeable
                if not got.shape:
                    got, ref = got.item(), ref.item()
            elif isinstance(got, np.generic):  # a scalar row's column: its Python value
                got = got.item()
            assert same(got, ref) or (
                isinstance(ref, np.ndarray) and np.array_equal(got, ref, equal_nan=True)
            ), (cls, r.name, i)
    if n and not any(r.wire.type in ("bytes", "str") for r in p.rows):
        try:
            back = bytearray(base + n * stride)
            p.write_columns(cols, back, base, n, stride, count)
        except WireError:
            return  # a NaN without an invalid code (a float row's NaN payload): not a record
        for i in range(n):
            rec = bytearray(base + n * stride)
            msg = object.__new__(cls)
            msg.__dict__.update(_walk_values(cls, raw, base + i * stride, ctx))
            _encode_block_fields(msg, rec, base + i * stride, ctx)
            a = base + i * stride
            assert back[a : a + size] == rec[a : a + size], (cls, i)
