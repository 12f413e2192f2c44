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
def message(cls: type[T], /) -> type[T]: ...
@typing.overload
def message(*, endian: str = "<") -> Callable[[type[T]], type[T]]: ...
@typing.dataclass_transform(frozen_default=True, field_specifiers=(wire, dataclasses.field))
def message(cls: type[T] | None = None, *, endian: str = "<") -> Any:
    """Class decorator: a frozen, slotted dataclass with array-aware equality.

    ``endian`` is the default byte order of the table ("<" little, ">" big).
    """

    def wrap(c: type[T]) -> type[T]:
        c.__wire_endian__ = endian  # type: ignore[attr-defined]
        dc = dataclasses.dataclass(frozen=True, eq=False)(c)
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
    if not ctx:
        plan = _block_plan(cls)
        if plan is not None and base >= 0 and base + plan.end <= len(buf):
            return plan.decode(buf, base, extra)
    return _decode_block_fields(cls, buf, base, ctx, extra)


def _decode_block_fields(
    cls: type[T],
    buf: bytes | bytearray | memoryview,
    base: int,
    ctx: Mapping[str, int] | None,
    extra: Mapping[str, Any],
) -> T:
    """:func:`decode_block` field by field (shapes from ``ctx``; the precise short-buffer error)."""
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
    values.update(extra)
    return cls(**values)


@dataclasses.dataclass(frozen=True)
class _BlockPlan:
    """A fixed-size table compiled once: its bytes span ``end`` and ``decode(buf, base, extra)``
    reads every scalar with one ``struct`` call, with :func:`_decode_block_fields`' arithmetic."""

    end: int
    decode: Callable[[Any, int, Mapping[str, Any]], Any]


def _block_plan(cls: type) -> _BlockPlan | None:
    """The compiled decoder of ``cls`` (cached on the class), or None when a field's shape
    depends on a context or the scalar fields cannot share one ``struct`` layout."""
    cached = cls.__dict__.get("__wire_plan__", False)
    if cached is not False:
        return cached
    plan = _compile_block(cls)
    cls.__wire_plan__ = plan  # type: ignore[attr-defined]
    return plan


def _compile_block(cls: type) -> _BlockPlan | None:
    fields = _wire_fields(cls)
    if any(isinstance(d, str) for _, w in fields for d in w.shape):
        return None
    scalars = sorted(
        ((w.offset, name, w) for name, w in fields if w.type in WIRE_TYPES and not w.shape),
        key=lambda x: x[0],
    )
    endians = {_endian(cls, w) for _, _, w in scalars}
    if len(endians) > 1:
        return None
    fmt, pos = [next(iter(endians), "<")], 0
    for offset, _, w in scalars:
        if offset < pos:
            return None  # overlapping fields: left to the field-by-field path
        fmt.append(f"{offset - pos}x{WIRE_TYPES[w.type]}" if offset > pos else WIRE_TYPES[w.type])
        pos = offset + w.item_size()
    layout = struct.Struct("".join(fmt))
    slot = {name: i for i, (_, name, _) in enumerate(scalars)}
    ns: dict[str, Any] = {"unpack": layout.unpack_from, "cls": cls, "nan": math.nan}
    items = []
    for i, (name, w) in enumerate(fields):
        if name in slot:
            r = f"r[{slot[name]}]"
            if not w.is_scaled:
                expr = r
            else:
                ns[f"s{i}"], ns[f"a{i}"] = w.scale, w.add
                expr = f"{r} * s{i} + a{i}"
                if w.invalid is not None:
                    ns[f"n{i}"] = w.invalid
                    expr = f"(nan if {r} == n{i} else {expr})"
        else:
            ns[f"h{i}"] = _field_reader(cls, w)
            expr = f"h{i}(buf, base)"
        items.append(f"{name!r}: {expr}")
    src = (
        "def decode(buf, base, extra):\n"
        "    r = unpack(buf, base)\n"
        f"    values = {{{', '.join(items)}}}\n"
        "    if extra:\n"
        "        values.update(extra)\n"
        "    return cls(**values)\n"
    )
    exec(src, ns)  # the source holds only repr() of field names and generated identifiers
    end = max((w.offset + w.nbytes({}) for _, w in fields), default=0)
    return _BlockPlan(max(end, layout.size), ns["decode"])


def _field_reader(cls: type, w: Wire) -> Callable[[Any, int], Any]:
    """Reads one bytes, str or fixed-shape array field as :func:`_decode_block_fields` does."""
    size = w.nbytes({})
    if w.type == "bytes":
        return lambda buf, base: bytes(buf[base + w.offset : base + w.offset + size])
    if w.type == "str":
        return lambda buf, base: (
            bytes(buf[base + w.offset : base + w.offset + size])
            .rstrip(b"\x00")
            .decode("ascii", "replace")
        )
    dt = np.dtype(_endian(cls, w) + WIRE_TYPES[w.type])
    native, shape, count = dt.newbyteorder("="), w.resolve_shape({}), size // dt.itemsize

    def read_array(buf: Any, base: int) -> Any:
        raw = np.frombuffer(buf, dtype=dt, count=count, offset=base + w.offset)
        value = _to_si(w, raw.reshape(shape).astype(native))
        value.flags.writeable = False
        return value

    return read_array


def encode_block(
    msg: Any,
    buf: bytearray,
    base: int = 0,
    ctx: Mapping[str, int] | None = None,
) -> None:
    """Write the wire fields of ``msg`` into ``buf`` at ``base`` (``buf`` must be large enough)."""
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
