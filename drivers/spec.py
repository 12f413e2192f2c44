"""Declarative wire tables: one table per message, walked by both decode and encode.

A message is a frozen dataclass whose fields carry a :class:`Wire` entry in their metadata (the
vendor's field name, wire type, byte offset inside the block, scale to SI, units, description).
The dataclass *is* the table::

    @message(endian="<")
    class Example:
        depth: float = wire("u16", 4, scale=0.1, units="m", vendor="Depth (dm)")
        beams: np.ndarray = wire("s16", 6, shape=("n_beams",), scale=1e-3, units="m/s",
                                 invalid=-32768)

Decoding converts each raw wire value to SI (``raw * scale + add``); a raw value equal to
``invalid`` becomes NaN. Encoding inverts that with rounding, so ``encode(decode(b)) == b`` for
every valid block. Array shapes may name keys of a context dict (``n_beams`` above) so a table
can describe blocks whose size depends on another block (PD0 cell counts, SeaNet bin counts).

Fields without a :class:`Wire` entry are ordinary dataclass fields that the codec supplies
(derived or structural values such as a block ID list); they are not walked by this module.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import struct
import sys
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from auvgw.ground.errors import DataError

__all__ = [
    "Wire",
    "WireError",
    "WireLayout",
    "block_size",
    "decode_block",
    "encode_block",
    "from_jsonable",
    "message",
    "message_class",
    "raw_value",
    "resolve_type",
    "table_rows",
    "to_jsonable",
    "wire",
]

#: wire type name -> struct code
WIRE_TYPES: dict[str, str] = {
    "u8": "B",
    "s8": "b",
    "u16": "H",
    "s16": "h",
    "u32": "I",
    "s32": "i",
    "u64": "Q",
    "s64": "q",
    "f32": "f",
    "f64": "d",
}
_INT_LIMITS: dict[str, tuple[int, int]] = {
    t: (0, 2 ** (8 * struct.calcsize(c)) - 1)
    if t.startswith("u")
    else (-(2 ** (8 * struct.calcsize(c) - 1)), 2 ** (8 * struct.calcsize(c) - 1) - 1)
    for t, c in WIRE_TYPES.items()
    if not t.startswith("f")
}

T = TypeVar("T")

#: every class made with :func:`message`, by type name (``TYPE`` class attribute or class name);
#: used to rebuild typed messages from their JSON form (:func:`from_jsonable`)
MESSAGE_TYPES: dict[str, type] = {}
#: makers of message classes built from wire values (e.g. Kongsberg Depth beam tables): each
#: takes a type name and returns its class, or None if the name is not one of its kind
TYPE_FACTORIES: list[Callable[[str], type | None]] = []
#: message classes built on first use (a codec whose table is read lazily registers its type
#: name here at import; the class joins :data:`MESSAGE_TYPES` when built): name -> builder
LAZY_TYPES: dict[str, Callable[[], type]] = {}
#: message classes whose field names / type hints are cached (bounded: classes made from wire
#: values, e.g. Kongsberg Depth beam tables, must not pin memory)
CLASS_CACHE_SIZE = 256


class WireError(DataError):
    """A value cannot be decoded from or encoded to the wire (names message, field, offset)."""


@dataclasses.dataclass(frozen=True)
class Wire:
    """One row of a declarative table.

    ``type`` is a :data:`WIRE_TYPES` name, or ``"bytes"``/``"str"`` with ``size`` bytes
    (``str`` is ASCII, NUL/space padded on encode and stripped of trailing NULs on decode).
    ``offset`` is the byte offset from the start of the block. SI value = raw * scale + add.
    """

    type: str
    offset: int
    scale: float = 1.0
    add: float = 0.0
    units: str = ""
    vendor: str = ""
    doc: str = ""
    invalid: int | None = None
    shape: tuple[int | str, ...] = ()
    size: int = 0
    endian: str | None = None

    @property
    def is_array(self) -> bool:
        return bool(self.shape)

    @property
    def is_scaled(self) -> bool:
        return self.scale != 1.0 or self.add != 0.0 or self.invalid is not None

    def item_size(self) -> int:
        if self.type in ("bytes", "str"):
            return self.size
        return struct.calcsize(WIRE_TYPES[self.type])

    def resolve_shape(self, ctx: Mapping[str, int]) -> tuple[int, ...]:
        out = []
        for dim in self.shape:
            if isinstance(dim, str):
                if dim not in ctx:
                    raise WireError(f"array dimension {dim!r} missing from context")
                out.append(int(ctx[dim]))
            else:
                out.append(int(dim))
        return tuple(out)

    def nbytes(self, ctx: Mapping[str, int]) -> int:
        n = math.prod(self.resolve_shape(ctx)) if self.shape else 1
        return n * self.item_size()


@dataclasses.dataclass(frozen=True, eq=False)
class WireLayout:
    """Where a decoded message's fields sit in the bytes of one frame layout, for a reader that
    takes the wire values straight from the frame (the gateway's envelope:
    :func:`auvgw.envelope.layout_body`). A codec gives it only for a frame it decodes without
    error, and it holds for every frame of that layout (same length, same block positions).

    ``cls`` the message class; its wire fields sit at ``base + offset`` of their table rows,
    array shapes resolved with ``ctx``; ``absent`` the trailing wire fields the block is too
    short for (``None``); ``fields`` the value of every other field (except derived flags): a
    nested :class:`WireLayout`, a ``slice`` of the frame (bytes), ``None``, a tuple of those,
    or a constant. Compared by identity (a codec caches one per layout).
    """

    cls: type
    base: int = 0
    ctx: Mapping[str, int] = dataclasses.field(default_factory=dict)
    absent: frozenset[str] = frozenset()
    fields: Mapping[str, Any] = dataclasses.field(default_factory=dict)


def wire(
    type: str,
    offset: int,
    *,
    scale: float = 1.0,
    add: float = 0.0,
    units: str = "",
    vendor: str = "",
    doc: str = "",
    invalid: int | None = None,
    shape: tuple[int | str, ...] = (),
    size: int = 0,
    endian: str | None = None,
) -> Any:
    """Declare a dataclass field as a wire field (see :class:`Wire`)."""
    if type not in WIRE_TYPES and type not in ("bytes", "str"):
        raise ValueError(f"unknown wire type {type!r}")
    if type in ("bytes", "str") and size <= 0:
        raise ValueError(f"wire type {type!r} needs size > 0")
    w = Wire(type, offset, scale, add, units, vendor, doc, invalid, tuple(shape), size, endian)
    return dataclasses.field(metadata={"wire": w})


def _wire_fields(cls: type) -> list[tuple[str, Wire]]:
    cached = cls.__dict__.get("__wire_fields__")
    if cached is not None:
        return cached
    out = [(f.name, f.metadata["wire"]) for f in dataclasses.fields(cls) if "wire" in f.metadata]
    cls.__wire_fields__ = out  # type: ignore[attr-defined]
    return out


def resolve_type(name: str) -> type | None:
    """The message class of a type name: registered, built on first use (:data:`LAZY_TYPES`), or
    made by a :data:`TYPE_FACTORIES` entry; None when no codec knows it."""
    if (build := LAZY_TYPES.get(name)) is not None:
        # a table-driven type: the name belongs to the shipped table's class (a site table's own
        # class of that name serves its codec, and never shadows the shipped one for readers)
        return build()
    cls = MESSAGE_TYPES.get(name)
    if cls is not None:
        return cls
    for make in TYPE_FACTORIES:
        cls = make(name)
        if cls is not None:
            return cls
    return None


#: the name the bus readers use for :func:`resolve_type`
message_class = resolve_type


def _eq(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if a_arr.shape != b_arr.shape:
            return False
        if a_arr.dtype.kind in "fc" or b_arr.dtype.kind in "fc":
            return bool(np.array_equal(a_arr, b_arr, equal_nan=True))
        return bool(np.array_equal(a_arr, b_arr))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(_eq(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


@typing.dataclass_transform(frozen_default=True, field_specifiers=(wire, dataclasses.field))
def message_base(cls: type[T]) -> type[T]:
    """Class decorator for a table shared by several messages (fields only, not registered)."""
    return dataclasses.dataclass(frozen=True, eq=False)(cls)


@typing.overload
def message(cls: type[T], /, *, register: bool = True) -> type[T]: ...
@typing.overload
def message(*, endian: str = "<", register: bool = True) -> Callable[[type[T]], type[T]]: ...
@typing.dataclass_transform(frozen_default=True, field_specifiers=(wire, dataclasses.field))
def message(cls: type[T] | None = None, *, endian: str = "<", register: bool = True) -> Any:
    """Class decorator: a frozen, slotted dataclass with array-aware equality.

    ``endian`` is the default byte order of the table ("<" little, ">" big). ``register``:
    False for a table built on demand and found by name through :data:`TYPE_FACTORIES` (kept
    out of :data:`MESSAGE_TYPES`, so the factory's own cache bounds how many live).
    """

    def wrap(c: type[T]) -> type[T]:
        c.__wire_endian__ = endian  # type: ignore[attr-defined]
        dc = dataclasses.dataclass(frozen=True, eq=False)(c)
        if register:
            MESSAGE_TYPES[getattr(dc, "TYPE", dc.__name__)] = dc

        def __eq__(self: Any, other: object) -> bool:
            if type(other) is not type(self):
                return NotImplemented
            return all(
                _eq(getattr(self, f.name), getattr(other, f.name))
                for f in dataclasses.fields(self)  # type: ignore[arg-type]
            )

        dc.__eq__ = __eq__  # type: ignore[method-assign]
        dc.__hash__ = None  # type: ignore[assignment]
        return dc

    return wrap(cls) if cls is not None else wrap


def _endian(cls: type, w: Wire) -> str:
    return str(w.endian or getattr(cls, "__wire_endian__", "<"))


def block_size(cls: type, ctx: Mapping[str, int] | None = None) -> int:
    """Bytes spanned by the table: the end of its last field (offsets are from block start)."""
    ctx = ctx or {}
    return max((w.offset + w.nbytes(ctx) for _, w in _wire_fields(cls)), default=0)


def _to_si(w: Wire, raw: Any) -> Any:
    if not w.is_scaled:
        return raw
    if isinstance(raw, np.ndarray):
        out = raw.astype(np.float64) * w.scale + w.add
        if w.invalid is not None:
            out[raw == w.invalid] = np.nan
        return out
    if w.invalid is not None and raw == w.invalid:
        return math.nan
    return raw * w.scale + w.add


def _from_si(cls: type, name: str, w: Wire, value: Any) -> Any:
    """SI value -> raw wire value, rounded for integer types, range-checked."""
    if w.type in ("bytes", "str"):
        return value
    is_int = not w.type.startswith("f")
    if isinstance(value, np.ndarray) or w.is_array:
        arr = np.asarray(value, dtype=np.float64 if w.is_scaled else None)
        if w.is_scaled:
            bad = np.isnan(arr)
            raw = (arr - w.add) / w.scale
            if is_int:
                raw = np.rint(np.where(bad, 0.0, raw))
            if w.invalid is not None:
                raw = np.where(bad, w.invalid, raw)
            elif bad.any():
                raise WireError(
                    "NaN but the field has no invalid code", field=f"{cls.__name__}.{name}"
                )
        else:
            raw = arr
        if is_int:
            lo, hi = _INT_LIMITS[w.type]
            if raw.size and (raw.min() < lo or raw.max() > hi):
                raise WireError(
                    f"{cls.__name__}.{name}: values outside {w.type} range [{lo}, {hi}] "
                    f"after scaling by {w.scale} {w.units}"
                )
        return raw
    if w.is_scaled:
        if isinstance(value, float) and math.isnan(value):
            if w.invalid is None:
                raise WireError(
                    "NaN but the field has no invalid code", field=f"{cls.__name__}.{name}"
                )
            return w.invalid
        raw = (value - w.add) / w.scale
        value = round(raw) if is_int else raw
    if is_int:
        value = int(value)
        lo, hi = _INT_LIMITS[w.type]
        if not lo <= value <= hi:
            raise WireError(
                f"{cls.__name__}.{name}: raw value {value} outside {w.type} range [{lo}, {hi}]"
            )
    return value


def decode_block(
    cls: type[T],
    buf: bytes | bytearray | memoryview,
    base: int = 0,
    ctx: Mapping[str, int] | None = None,
    **extra: Any,
) -> T:
    """Decode the table ``cls`` from ``buf`` starting at ``base``; ``extra`` fills non-wire fields.

    Raises :class:`WireError` naming the message, field and absolute offset when ``buf`` is short.
    """
    p = cls.__dict__.get("__wire_plan__") if not ctx else None  # the common case: no context
    if p is None:
        p = _plan_or_none(cls, ctx)
    if p is not None and p.read is not None and base >= 0 and base + p.end <= len(buf):
        values = p.read(buf, base)
        if extra:
            values.update(extra)
        return cls(**values)
    return _decode_block_fields(cls, buf, base, ctx, extra)


def _decode_block_fields(
    cls: type[T],
    buf: bytes | bytearray | memoryview,
    base: int,
    ctx: Mapping[str, int] | None,
    extra: Mapping[str, Any],
) -> T:
    """The reference walker: :func:`decode_block` field by field, every plan is tested against
    it (shapes from ``ctx``; the precise short-buffer error)."""
    values = _walk_values(cls, buf, base, ctx)
    values.update(extra)
    return cls(**values)


def _walk_values(
    cls: type, buf: bytes | bytearray | memoryview, base: int, ctx: Mapping[str, int] | None
) -> dict[str, Any]:
    """The SI value of every wire row of ``cls`` in ``buf`` at ``base``, one row at a time."""
    ctx = ctx or {}
    values: dict[str, Any] = {}
    n = len(buf)
    for name, w in _wire_fields(cls):
        start = base + w.offset
        size = w.nbytes(ctx)
        if start + size > n:
            raise WireError(
                f"needs bytes {start}..{start + size - 1}, block ends at {n}",
                field=f"{cls.__name__}.{name}", offset=start,
            )  # fmt: skip
        if w.type == "bytes":
            raw: Any = bytes(buf[start : start + size])
        elif w.type == "str":
            raw = bytes(buf[start : start + size]).rstrip(b"\x00").decode("ascii", "replace")
        elif w.is_array:
            dt = np.dtype(_endian(cls, w) + WIRE_TYPES[w.type])
            raw = np.frombuffer(buf, dtype=dt, count=size // dt.itemsize, offset=start)
            raw = raw.reshape(w.resolve_shape(ctx)).astype(dt.newbyteorder("="))
        else:
            (raw,) = struct.unpack_from(_endian(cls, w) + WIRE_TYPES[w.type], buf, start)
        value = _to_si(w, raw)
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        values[name] = value
    return values


# -- compiled plans -----------------------------------------------------------------------------

#: plans kept per message class (one per context and block length; fuzzed input stays bounded)
PLANS_PER_CLASS = 256
#: scaled arrays up to this many elements are converted in Python from the plan's one ``struct``
#: call: cheaper than numpy's calls for a few elements on a warm core, and on a cold one (one
#: frame at a time, the gateway's case) for a few hundred
SMALL_ARRAY = 128
_NATIVE = "<" if sys.byteorder == "little" else ">"


@dataclasses.dataclass(frozen=True, eq=False)
class Row:
    """One wire row of a :class:`Plan`: the field ``name``, its :class:`Wire`, its shape resolved
    with the plan's context, its byte count and its byte order (``"<"``/``">"``)."""

    name: str
    wire: Wire
    shape: tuple[int, ...]
    nbytes: int
    endian: str

    @property
    def count(self) -> int:
        """Wire items of the row (1 for a scalar, a bytes or a str row)."""
        return math.prod(self.shape) if self.shape else 1

    def record_shape(self, count: str | None) -> tuple[int, ...]:
        """The row's shape in one record (:meth:`Plan.columns`): without its first dimension
        when that is the record ``count``."""
        if count is not None and self.wire.shape[:1] == (count,):
            return self.shape[1:]
        return self.shape

    def dtype(self) -> np.dtype:
        """The numpy dtype of one wire item (``bytes``/``str`` rows: ``u1`` x size)."""
        w = self.wire
        if w.type in ("bytes", "str"):
            return np.dtype((np.uint8, (w.size,)))
        return np.dtype(self.endian + WIRE_TYPES[w.type])


class Plan:
    """One message table compiled for one context (array shapes) and, optionally, one block
    length ``avail`` (rows that end past it are absent: ``None``). Built once by :func:`plan`
    and cached on the class; the walker (:func:`_decode_block_fields`, :func:`encode_block`
    field by field) is the reference it is tested against on every shipped table
    (``tests/service/test_plans.py``).

    * :attr:`read` ``(buf, base) -> {field: value}``: every wire row's SI value (None for an
      absent row) from one
      ``struct`` call (scalars, bytes, small scaled arrays) plus one ``numpy.frombuffer`` per
      other array (read-only views of ``buf`` when it is ``bytes``, copies otherwise); None when
      the rows cannot share one ``struct`` layout (mixed byte orders, overlapping rows).
    * :meth:`encode` ``(msg, buf, base)``: every row's raw value (range-checked and rounded as the
      walker does) written with one ``struct`` call.
    * :meth:`columns` ``(buf, base, n, stride)``: the rows of ``n`` records ``stride`` bytes
      apart (Kongsberg beams, PD0 ensembles of one layout) as SI columns, one numpy record view;
      :meth:`write_columns` the inverse.
    """

    __slots__ = ("_pack", "_records", "absent", "cls", "ctx", "end", "read", "rows")

    def __init__(self, cls: type, ctx: Mapping[str, int], avail: int | None) -> None:
        self.cls = cls
        self.ctx = dict(ctx)
        rows: list[Row] = []
        absent: list[str] = []
        for name, w in sorted(_wire_fields(cls), key=lambda r: r[1].offset):
            shape = w.resolve_shape(ctx)
            n = w.nbytes(ctx)
            if avail is not None and (absent or w.offset + n > avail):
                absent.append(name)
                continue
            rows.append(Row(name, w, shape, n, _endian(cls, w)))
        order = {name: i for i, (name, _) in enumerate(_wire_fields(cls))}
        #: the present rows, in table (declaration) order
        self.rows = tuple(sorted(rows, key=lambda r: order[r.name]))
        #: the rows the block is too short for (``avail``), in offset order
        self.absent = tuple(absent)
        #: bytes spanned by the present rows (from the block start)
        self.end = max((r.wire.offset + r.nbytes for r in rows), default=0)
        self._records: dict[tuple[int, str | None], np.dtype] = {}
        self.read, self._pack = _compile_plan(self)

    def encode(self, msg: Any, buf: bytearray, base: int = 0) -> None:
        """Write the present rows of ``msg`` into ``buf`` at ``base`` (:func:`encode_block`)."""
        if self._pack is not None:
            try:
                self._pack(msg, buf, base)
                return
            except Exception:  # the walker raises exactly what it always did
                pass
        _encode_block_fields(msg, buf, base, self.ctx)

    def record_dtype(self, stride: int, count: str | None = None) -> np.dtype:
        """The present rows as one numpy record of ``stride`` bytes (offsets from its start;
        ``count``: see :meth:`columns`)."""
        key = (stride, count)
        dt = self._records.get(key)
        if dt is None:
            formats: list[Any] = []
            for r in self.rows:
                shape = r.record_shape(count)
                formats.append((r.dtype(), shape) if shape else r.dtype())
            dt = self._records[key] = np.dtype(
                {
                    "names": [r.name for r in self.rows],
                    "formats": formats,
                    "offsets": [r.wire.offset for r in self.rows],
                    "itemsize": stride,
                }
            )
        return dt

    def columns(
        self, buf: bytes, base: int, n: int, stride: int, count: str | None = None
    ) -> dict[str, Any]:
        """SI columns of ``n`` records ``stride`` bytes apart from ``base`` in ``buf``: an array
        of shape ``(n, *record shape)`` per numeric row (read-only; float64 where the row is
        scaled, the native wire type otherwise), a list per bytes / str row; each record's values
        are those :func:`decode_block` gives it. ``count`` names the dimension that counts the
        records of a record table (Kongsberg beams: every row ``shape=("n_beams",)``, one item
        per record; its plan is built with that dimension 1): it is left out of the record."""
        rec = np.frombuffer(buf, dtype=self.record_dtype(stride, count), count=n, offset=base)
        out: dict[str, Any] = {}
        for r in self.rows:
            raw = rec[r.name]
            w = r.wire
            if w.type in ("bytes", "str"):
                flat = np.ascontiguousarray(raw).tobytes()
                items: list[Any] = [flat[k * w.size : (k + 1) * w.size] for k in range(n)]
                if w.type == "str":
                    items = [b.rstrip(b"\x00").decode("ascii", "replace") for b in items]
                out[r.name] = items
                continue
            if w.is_scaled:
                value = _si_array(raw, w.scale, w.add, w.invalid)
            elif raw.dtype.isnative and type(buf) is bytes:
                value = raw  # read-only: a view of immutable bytes
            else:
                value = raw.astype(raw.dtype.newbyteorder("="))
            value.flags.writeable = False
            out[r.name] = value
        return out

    def write_columns(
        self,
        columns: Mapping[str, Any],
        buf: bytearray,
        base: int,
        n: int,
        stride: int,
        count: str | None = None,
        unit: str = "records",
    ) -> None:
        """Write ``n`` records ``stride`` bytes apart from SI columns (:meth:`columns`' form;
        bytes between the rows are zero); :class:`WireError` naming the row whose values do not
        fit or whose shape is not ``(n, *record shape)`` (``unit``: what a record is)."""
        rec = np.zeros(n, dtype=self.record_dtype(stride, count))
        for r in self.rows:
            if r.wire.type in ("bytes", "str"):
                raise WireError(f"{r.wire.type} rows are not written as columns", field=r.name)
            raw = np.asarray(_from_si(self.cls, r.name, _column_wire(r.wire), columns[r.name]))
            if raw.shape != (n, *r.record_shape(count)):
                raise WireError(
                    f"{self.cls.__name__}.{r.name}: shape {raw.shape}, header says ({n},) {unit}"
                )
            rec[r.name] = raw
        buf[base : base + n * stride] = rec.tobytes()


def _column_wire(w: Wire) -> Wire:
    """``w`` as an array row (a column of a scalar row is an array)."""
    return w if w.shape else dataclasses.replace(w, shape=(-1,))


def plan(cls: type, ctx: Mapping[str, int] | None = None, avail: int | None = None) -> Plan:
    """The compiled :class:`Plan` of table ``cls`` for the array dimensions its shapes name in
    ``ctx`` and, when given, the block length ``avail``: built on first use, then cached on the
    class (:data:`PLANS_PER_CLASS` at most). Raises :class:`WireError` when ``ctx`` lacks a
    dimension."""
    plans = cls.__dict__.get("__wire_plans__")
    if plans is None:
        dims = tuple(
            sorted({d for _, w in _wire_fields(cls) for d in w.shape if isinstance(d, str)})
        )
        plans = {"dims": dims}
        cls.__wire_plans__ = plans  # type: ignore[attr-defined]
    dims = plans["dims"]
    key = (tuple(ctx.get(d) for d in dims) if ctx else (None,) * len(dims), avail)
    p = plans.get(key)
    if p is None:
        if len(plans) > PLANS_PER_CLASS:
            plans.clear()
            plans["dims"] = dims
        p = plans[key] = Plan(cls, ctx or {}, avail)
        if not dims and avail is None:
            cls.__wire_plan__ = p  # type: ignore[attr-defined]  # decode_block's fast path
    return p


def _plan_or_none(cls: type, ctx: Mapping[str, int] | None) -> Plan | None:
    try:
        return plan(cls, ctx)
    except WireError:  # a dimension missing from the context: the walker's error
        return None


def _compile_plan(
    p: Plan,
) -> tuple[Callable[[Any, int], dict[str, Any]] | None, Callable[..., None] | None]:
    """Generate the plan's reader and its packer (None, None: the rows cannot share one
    ``struct`` layout)."""
    endians = {r.endian for r in p.rows if r.wire.type in WIRE_TYPES}
    if len(endians) > 1:
        return None, None
    endian = next(iter(endians), "<")
    fmt, pos, k = [endian], 0, 0
    runs: list[tuple[int, list[str]]] = []  # (offset, struct codes) of each contiguous run
    ns: dict[str, Any] = {"nan": math.nan}
    items: list[str] = []
    for i, r in enumerate(sorted(p.rows, key=lambda r: r.wire.offset)):
        w, at, name = r.wire, r.wire.offset, repr(r.name)
        if at < pos:
            return None, None  # overlapping rows (an ASCII table's field positions)
        pad = f"{at - pos}x" if at > pos else ""
        code = WIRE_TYPES.get(w.type, "")
        if not runs or at > pos:
            runs.append((at, []))  # the packer writes no gap (sync, checksum: not rows)
        runs[-1][1].append(code if code and not w.shape else f"{r.nbytes}s")
        pos = at + r.nbytes
        if not code:  # bytes, str
            fmt.append(f"{pad}{w.size}s")
            strip = ".rstrip(b'\\x00').decode('ascii', 'replace')" if w.type == "str" else ""
            items.append(f"{name}: r[{k}]{strip}")
            k += 1
        elif not w.shape:
            fmt.append(pad + code)
            item = f"r[{k}]"
            if w.is_scaled:
                ns[f"s{i}"], ns[f"a{i}"] = w.scale, w.add
                item = f"{item} * s{i} + a{i}"
                if w.invalid is not None:
                    ns[f"n{i}"] = w.invalid
                    item = f"(nan if r[{k}] == n{i} else {item})"
            items.append(f"{name}: {item}")
            k += 1
        elif w.is_scaled and 0 < r.count <= SMALL_ARRAY:
            fmt.append(f"{pad}{r.count}{code}")
            ns[f"h{i}"] = _small_array(w, r.shape)
            items.append(f"{name}: h{i}(r[{k}:{k + r.count}])")
            k += r.count
        else:
            fmt.append(f"{pad}{r.nbytes}x")
            ns[f"h{i}"] = _array_reader(r)
            items.append(f"{name}: h{i}(buf, base)")
    items += [f"{name!r}: None" for name in p.absent]  # the rows the block is too short for
    ns["unpack"] = struct.Struct("".join(fmt)).unpack_from
    src = f"def read(buf, base):\n    r = unpack(buf, base)\n    return {{{', '.join(items)}}}\n"
    exec(src, ns)  # the source holds only repr() of field names and generated identifiers
    # the packer: every row's raw value converted and checked in table order (the walker's),
    # then written in offset order with one call
    convs = [_row_writer(p.cls, r) for r in p.rows]
    getters = [r.name for r in p.rows]
    by_offset = sorted(range(len(p.rows)), key=lambda j: p.rows[j].wire.offset)
    packers, first = [], 0
    for at, codes in runs:
        packers.append((struct.Struct(endian + "".join(codes)).pack_into, at, first, len(codes)))
        first += len(codes)

    def pack(msg: Any, buf: bytearray, base: int) -> None:
        raws = [conv(getattr(msg, name)) for conv, name in zip(convs, getters, strict=True)]
        ordered = [raws[j] for j in by_offset]
        for pack_into, at, a, n in packers:
            pack_into(buf, base + at, *ordered[a : a + n])

    return ns["read"], pack


def _row_writer(cls: type, r: Row) -> Callable[[Any], Any]:
    """SI value -> what the plan's ``struct`` packs for row ``r``, with the walker's conversion
    (:func:`_from_si`) and checks (bytes size, str length, array shape)."""
    w, label = r.wire, f"{cls.__name__}.{r.name}"
    if w.type == "bytes":

        def write_bytes(value: Any) -> Any:
            if len(value) != w.size:
                raise WireError(f"needs {w.size} bytes, got {len(value)}", field=label)
            return bytes(value)

        return write_bytes
    if w.type == "str":

        def write_str(value: Any) -> Any:
            data = str(value).encode("ascii")
            if len(data) > w.size:
                raise WireError(f"{value!r} longer than {w.size} bytes", field=label)
            return data

        return write_str
    if w.shape:
        dt = r.dtype()

        def write_array(value: Any) -> Any:
            arr = np.asarray(_from_si(cls, r.name, w, value))
            if arr.shape != r.shape:
                raise WireError(f"shape {arr.shape}, table says {r.shape}", field=label)
            return arr.astype(dt).tobytes()

        return write_array
    return functools.partial(_from_si, cls, r.name, w)


def _small_array(w: Wire, shape: tuple[int, ...]) -> Callable[[tuple[Any, ...]], np.ndarray]:
    """A short scaled array from its unpacked raw items, with :func:`_to_si`'s arithmetic."""
    scale, add, invalid = w.scale, w.add, w.invalid
    nd = shape if len(shape) > 1 else None

    def small(raws: tuple[Any, ...]) -> np.ndarray:
        if invalid is None:
            arr = np.array([x * scale + add for x in raws], dtype=np.float64)
        else:
            arr = np.array(
                [math.nan if x == invalid else x * scale + add for x in raws], dtype=np.float64
            )
        arr.flags.writeable = False  # (its reshaped view is read-only too)
        return arr if nd is None else arr.reshape(nd)

    return small


def _si_array(raw: np.ndarray, scale: float, add: float, invalid: int | None) -> np.ndarray:
    """:func:`_to_si`'s values of a raw array (float64 ``raw * scale + add``, NaN where ``raw ==
    invalid``) with one multiply, the offset only when non-zero and ``copyto`` for NaN."""
    value = np.multiply(raw, scale, dtype=np.float64)
    if add:
        value += add
    if invalid is not None:
        np.copyto(value, math.nan, where=raw == invalid)
    return value


def _array_reader(r: Row) -> Callable[[Any, int], np.ndarray]:
    """One array row read with ``numpy.frombuffer``: a read-only view of a ``bytes`` buffer when
    the row is unscaled and native, else a converted copy (:func:`_to_si`'s values: float64
    ``raw * scale + add``, NaN where ``raw == invalid``)."""
    w, dt, count, at = r.wire, r.dtype(), r.count, r.wire.offset
    shape = r.shape if len(r.shape) > 1 else None
    native = dt.newbyteorder("=")
    frombuffer = np.frombuffer
    if w.is_scaled:
        scale, add, invalid = w.scale, w.add, w.invalid

        def read_scaled(buf: Any, base: int) -> np.ndarray:
            raw = frombuffer(buf, dtype=dt, count=count, offset=base + at)
            value = _si_array(raw if shape is None else raw.reshape(shape), scale, add, invalid)
            value.flags.writeable = False
            return value

        return read_scaled
    view_ok = r.endian == _NATIVE or dt.itemsize == 1

    def read_raw(buf: Any, base: int) -> np.ndarray:
        raw = frombuffer(buf, dtype=dt, count=count, offset=base + at)
        if shape is not None:
            raw = raw.reshape(shape)
        if view_ok and type(buf) is bytes:
            return raw  # read-only: a view of immutable bytes
        value = raw.astype(native)
        value.flags.writeable = False
        return value

    return read_raw


def encode_block(
    msg: Any,
    buf: bytearray,
    base: int = 0,
    ctx: Mapping[str, int] | None = None,
) -> None:
    """Write the wire fields of ``msg`` into ``buf`` at ``base`` (``buf`` must be large enough)."""
    cls = type(msg)
    p = cls.__dict__.get("__wire_plan__") if not ctx else None
    if p is None:
        p = _plan_or_none(cls, ctx)
    if p is None:
        _encode_block_fields(msg, buf, base, ctx)
    else:
        p.encode(msg, buf, base)


def _encode_block_fields(
    msg: Any, buf: bytearray, base: int, ctx: Mapping[str, int] | None
) -> None:
    """The reference walker of :func:`encode_block`: one field at a time."""
    cls = type(msg)
    ctx = ctx or {}
    for name, w in _wire_fields(cls):
        start = base + w.offset
        raw = _from_si(cls, name, w, getattr(msg, name))
        if w.type == "bytes":
            if len(raw) != w.size:
                raise WireError(
                    f"needs {w.size} bytes, got {len(raw)}", field=f"{cls.__name__}.{name}"
                )
            buf[start : start + w.size] = raw
        elif w.type == "str":
            data = str(raw).encode("ascii")
            if len(data) > w.size:
                raise WireError(
                    f"{raw!r} longer than {w.size} bytes", field=f"{cls.__name__}.{name}"
                )
            buf[start : start + w.size] = data.ljust(w.size, b"\x00")
        elif w.is_array:
            shape = w.resolve_shape(ctx)
            arr = np.asarray(raw)
            if arr.shape != shape:
                raise WireError(
                    f"shape {arr.shape}, table says {shape}", field=f"{cls.__name__}.{name}"
                )
            dt = np.dtype(_endian(cls, w) + WIRE_TYPES[w.type])
            data = arr.astype(dt).tobytes()
            buf[start : start + len(data)] = data
        else:
            struct.pack_into(_endian(cls, w) + WIRE_TYPES[w.type], buf, start, raw)


def raw_value(msg: Any, name: str) -> Any:
    """The wire (raw, unscaled) value of field ``name`` of ``msg``."""
    cls = type(msg)
    for fname, w in _wire_fields(cls):
        if fname == name:
            return _from_si(cls, name, w, getattr(msg, name))
    raise KeyError(f"{cls.__name__} has no wire field {name!r}")


def table_rows(cls: type) -> list[dict[str, Any]]:
    """The table as rows (for docs and ``--describe``): name, vendor, type, offset, scale, units."""
    return [
        {
            "name": name,
            "vendor": w.vendor,
            "type": w.type if not w.shape else f"{w.type}[{','.join(map(str, w.shape))}]",
            "offset": w.offset,
            "scale": w.scale,
            "add": w.add,
            "units": w.units,
            "invalid": w.invalid,
            "doc": w.doc,
        }
        for name, w in _wire_fields(cls)
    ]


def _nan_to_none(value: Any) -> Any:
    """Nested lists of floats with NaN/inf replaced by None (JSON has no NaN)."""
    if type(value) is list:
        return [_nan_to_none(v) for v in value]
    return None if value != value or value in (math.inf, -math.inf) else value


def _jsonable(value: Any) -> Any:
    t = type(value)
    if t is int or t is str or t is bool or value is None:  # most fields: nothing to convert
        return value
    if t is float:
        return None if math.isnan(value) or math.isinf(value) else value
    if hasattr(t, "__dataclass_fields__"):  # a nested message (an instance, t is its class)
        return to_jsonable(value)
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            return _nan_to_none(value.tolist())
        return value.tolist()
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float):
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(value, bytes | bytearray):
        return value.hex()
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if hasattr(value, "name") and hasattr(value, "value"):  # enum
        return value.name
    return value


def to_jsonable(msg: Any) -> dict[str, Any]:
    """A JSON-ready dict of a message: ``type`` (class name) then every field in SI units.

    NaN (invalid on the wire) becomes ``null``; bytes become hex strings; nested messages nest.
    """
    out: dict[str, Any] = {"type": getattr(msg, "TYPE", type(msg).__name__)}
    for name in _field_names(type(msg)):  # type: ignore[arg-type]  # classes are hashable
        out[name] = _jsonable(getattr(msg, name))
    return out


@functools.lru_cache(maxsize=CLASS_CACHE_SIZE)
def _field_names(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


def _from_json_value(tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if value is None:
        if tp is float:
            return math.nan
        return None
    if tp is np.ndarray:
        arr = np.asarray(
            value if not _has_none(value) else _none_to_nan(value),
        )
        arr.flags.writeable = False
        return arr
    if isinstance(tp, type) and dataclasses.is_dataclass(tp) and isinstance(value, Mapping):
        return from_jsonable(value, tp)
    if tp is bytes and isinstance(value, str):
        return bytes.fromhex(value)
    if isinstance(tp, type) and issubclass(tp, enum.Enum) and isinstance(value, str):
        return tp[value]
    if origin in (types.UnionType, typing.Union):
        for a in args:
            if a is type(None):
                continue
            try:
                return _from_json_value(a, value)
            except (TypeError, ValueError, KeyError):
                continue
        return value
    if origin is tuple and isinstance(value, list):
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_from_json_value(args[0], v) for v in value)
        if args:
            return tuple(_from_json_value(a, v) for a, v in zip(args, value, strict=False))
        return tuple(value)
    if tp is float and isinstance(value, int):
        return float(value)
    return value


def _has_none(value: Any) -> bool:
    if isinstance(value, list):
        return any(_has_none(v) for v in value)
    return value is None


def _none_to_nan(value: Any) -> Any:
    if isinstance(value, list):
        return [_none_to_nan(v) for v in value]
    return math.nan if value is None else value


#: resolved annotations per message class (evaluating them dominates from_jsonable otherwise)
_type_hints = functools.lru_cache(maxsize=CLASS_CACHE_SIZE)(typing.get_type_hints)


def from_jsonable(data: Mapping[str, Any], cls: type | None = None) -> Any:
    """Rebuild a typed message from :func:`to_jsonable` output (inverse up to JSON's limits:
    NaN travels as null, arrays as lists; integer arrays come back as int64)."""
    if cls is None:
        name = data.get("type")
        cls = message_class(name) if isinstance(name, str) else None
        if cls is None:
            raise KeyError(f"unknown message type {name!r}")
    hints = _type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in data:
            kwargs[f.name] = _from_json_value(hints.get(f.name, Any), data[f.name])
    return cls(**kwargs)
