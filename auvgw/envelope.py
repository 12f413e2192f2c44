"""The decoded-message envelope (docs/bus.md#payloads): compact, positional, self-describing.

Version 3, one MessagePack array per sample::

    [3, type, schema, wire, device, t, seq, body]

``type`` is the message type the codec registers (:data:`auvgw.drivers.spec.MESSAGE_TYPES`),
``schema`` a 16-bit fingerprint of its table (field names, wire types, scales, shapes, nested
tables: :func:`schema_id`), ``body`` the message's fields **by position** in the table's order,
so the names are not repeated in every sample. Values travel as the wire carried them:

* a scaled integer field (``raw * scale + add`` in SI) as its raw integer, the ``invalid`` code
  for NaN; a reader applies the table's scale (the same float operations as the codec, so the
  value is identical); a value the raw integer cannot give exactly travels as a float (SI);
* a wire array as MessagePack bin of its raw values (1-D, little endian, the table's dtype) or
  extension 1 (``<dtype>;<shape>`` NUL bytes) in the wire dtype when it has several dimensions;
  an array the wire dtype cannot give exactly travels in its own dtype (SI);
* a float as float32 when float32 holds it exactly (every f32 wire value does), else float64;
* derived fields (status flag bits) are left out and recomputed; nested messages nest as
  positional arrays, or as extension 2 (``<type>`` NUL MessagePack array) when the table does
  not fix their type.

Versions 2 (a MessagePack map with field names) and 1 (JSON) are still read, for one release.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import json
import keyword
import logging
import math
import struct
import sys
import threading
import types
import typing
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeAlias, TypeGuard

import msgspec
import numpy as np
import zenoh

from auvgw.drivers.spec import (
    CLASS_CACHE_SIZE,
    WIRE_TYPES,
    Row,
    Wire,
    WireError,
    WireLayout,
    resolve_type,
)
from auvgw.drivers.spec import plan as table_plan

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

__all__ = [
    "ENVELOPE_VERSION",
    "EXT_NDARRAY",
    "EXT_TYPED",
    "Envelope",
    "SchemaError",
    "decode_envelope",
    "encode_envelope",
    "envelope_encoding",
    "layout_body",
    "message_fields",
    "pack_body",
    "pack_envelope",
    "schema_id",
    "unpack_body",
]

log = logging.getLogger(__name__)

#: version of the decoded-message envelope; 2 (MessagePack map) and 1 (JSON) are still read
ENVELOPE_VERSION = 3
#: MessagePack extension code of a numpy array: ``<dtype.str>;<d0,d1,...>`` NUL then the bytes
EXT_NDARRAY = 1
#: MessagePack extension code of a nested message whose type the table does not fix:
#: ``<type>`` NUL then its positional body (MessagePack)
EXT_TYPED = 2

_F32 = struct.Struct(">f")
#: wire arrays of a codec's output up to this many elements are packed in Python (cheaper than
#: numpy's calls, most of all on a cold core)
SMALL_ARRAY = 128
_F32_NAN = msgspec.Raw(b"\xca\x7f\xc0\x00\x00")

#: a value ready for MessagePack, as an encoder gives it (msgspec packs it as it is: a numpy
#: array through :func:`_enc_hook`, ``Raw`` bytes verbatim, an ``Ext`` as an extension)
Packed: TypeAlias = (
    bool | int | float | str | bytes | np.ndarray | msgspec.Raw | msgspec.msgpack.Ext
    | list["Packed"] | dict[str, "Packed"] | None
)  # fmt: skip
#: a field's encoder: (its SI value, as the message holds it; trusted) -> what travels
Encoder: TypeAlias = Callable[[Any, bool], Packed]
#: a field's decoder: what MessagePack gave back -> the SI value
Decoder: TypeAlias = Callable[[object], object]
#: what a field-by-field walk of a table gives: (encode or None, decode, schema text)
Coders: TypeAlias = tuple[Encoder | None, Decoder, str]


class SchemaError(ValueError):
    """An envelope's body does not fit the reader's table of its type (names type and field)."""


@dataclass(frozen=True)
class Envelope:
    """A decoded message as it travels: its type name, source device, host receive time (ns
    since the Unix epoch), the sequence of the raw frame it came from, the message's fields
    (``body``: by name, SI units; a positional list when the reader does not know the type),
    the typed immutable ``message`` where the reader knows the type, ``wire`` the gateway format
    it was decoded from (``hn100``, ``can``, ...; empty for derived messages such as odometry)
    and ``schema`` the table fingerprint (0 before version 3)."""

    type: str
    device: str
    t_recv_ns: int
    seq: int
    body: Any = field(default_factory=dict)
    message: object = None
    key: str = ""
    wire: str = ""
    schema: int = 0


def _enc_float(v: float) -> Packed:
    """float32 when it holds ``v`` exactly (MessagePack 0xca, 5 bytes), else float64."""
    if v != v:
        return _F32_NAN
    try:
        b = _F32.pack(v)
    except OverflowError:
        return v
    return msgspec.Raw(b"\xca" + b) if _F32.unpack(b)[0] == v else v


def _enc_number(v: Any, trusted: bool) -> Packed:
    return _enc_float(v) if type(v) is float else v


def _enc_any(v: Any, trusted: bool = False) -> Packed:
    """A value with no table row to guide it."""
    t = type(v)
    if t is float:
        return _enc_float(v)
    if t is int or t is str or t is bool or v is None or t is bytes or t is np.ndarray:
        return v
    if dataclasses.is_dataclass(v):
        return _typed_ext(v, trusted)
    if isinstance(v, tuple | list):
        return [_enc_any(x, trusted) for x in v]
    if isinstance(v, Mapping):
        return {k: _enc_any(x, trusted) for k, x in v.items()}
    if isinstance(v, float):
        return _enc_float(float(v))
    return v


def _typed_ext(v: object, trusted: bool = False) -> msgspec.msgpack.Ext:
    name = str(getattr(v, "TYPE", type(v).__name__))
    body = _ENCODER.encode(pack_body(v, trusted))
    return msgspec.msgpack.Ext(EXT_TYPED, name.encode() + b"\0" + body)


@dataclass(frozen=True)
class _Typed:
    """Extension 2 as read: a nested message's type name and positional body."""

    name: str
    body: list[Packed]


def _dec_typed(v: object) -> object:
    if isinstance(v, _Typed):
        cls = resolve_type(v.name)
        if cls is None:
            raise SchemaError(f"nested message type {v.name!r} is not known here")
        return unpack_body(cls, v.body)
    return v


def _is_message_class(tp: object) -> TypeGuard[type[DataclassInstance]]:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _hint_coders(tp: object) -> Coders:
    """(encode, decode, schema text) of a field with no wire row, from its type hint."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (types.UnionType, typing.Union):
        real = [a for a in args if a is not type(None)]
        if len(real) == 1 and len(args) == 2:
            enc, dec, desc = _hint_coders(real[0])
            return (
                None if enc is None else (lambda v, t: None if v is None else enc(v, t)),
                (lambda v: None if v is None else dec(v)),
                f"{desc}?",
            )
        return _enc_any, _dec_typed, "any"
    if _is_message_class(tp):
        cls: type = tp
        pack_nested = _plan(cls).pack
        #: (message, its body) of the last codec output packed here: a codec shares one
        #: immutable nested message while its bytes repeat (a PD0 fixed leader), so the body
        #: is packed once, not per frame (one tuple, replaced whole: safe across threads)
        last: tuple[object, list[Packed] | None] = (None, None)

        def enc_msg(v: object, t: bool) -> Packed:
            nonlocal last
            if type(v) is not cls:
                return _typed_ext(v, t)
            if not t:
                return pack_nested(v, t)
            seen, body = last
            if seen is not v or body is None:
                body = pack_nested(v, t)
                last = (v, body)
            return body

        def dec_msg(v: object) -> object:
            return unpack_body(cls, v) if isinstance(v, list) else _dec_typed(v)

        return enc_msg, dec_msg, f"{cls.__name__}#{schema_id(cls):04x}"
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        enc_el, dec_el, desc = _hint_coders(args[0])
        return (
            None if enc_el is None else (lambda v, t: [enc_el(x, t) for x in v]),
            (lambda v: tuple(dec_el(x) for x in v)),
            f"tuple[{desc}]",
        )
    if origin is tuple and args:
        coders = [_hint_coders(a) for a in args]
        encs = [c[0] or _enc_number for c in coders]
        return (
            (lambda v, t: [e(x, t) for e, x in zip(encs, v, strict=True)]),
            (lambda v: tuple(c[1](x) for c, x in zip(coders, v, strict=True))),
            f"tuple[{','.join(c[2] for c in coders)}]",
        )
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        enum_cls: type[enum.Enum] = tp
        return (
            (lambda v, t: v if v is None else v.value),
            (lambda v: v if v is None else enum_cls(v)),
            enum_cls.__name__,
        )
    if tp is float:
        return (lambda v, t: _enc_float(v) if type(v) is float else _enc_any(v, t)), _dec_typed, "f"
    if tp is bytes:
        return None, (lambda v: v if v is None else bytes(v)), "bytes"
    name = getattr(tp, "__name__", repr(tp))
    return _enc_any, _dec_typed, name


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _wire_coders(w: Wire) -> Coders:
    """(encode, decode, schema text) of a wire row: raw wire values where they give the exact
    SI value back (the codec's own ``raw * scale + add``), else the SI value itself."""
    desc = f"{w.type}{list(w.shape) if w.shape else ''}*{w.scale!r}+{w.add!r}!{w.invalid}"
    if w.type in ("bytes", "str"):
        return None, (lambda v: v), desc
    is_int = not w.type.startswith("f")
    scale, add, invalid = w.scale, w.add, w.invalid
    if not w.is_array:
        if not (is_int and w.is_scaled):
            return _enc_number, (lambda v: v), desc
        info = np.iinfo(np.dtype(WIRE_TYPES[w.type]))
        lo, hi = int(info.min), int(info.max)

        def enc_scalar(v: Any, t: bool) -> Packed:
            if v is None or type(v) is bool:
                return v
            try:
                raw = round((v - add) / scale)
            except (ValueError, OverflowError):  # NaN, +-inf (Python's and numpy's floats)
                if v != v:
                    return invalid if invalid is not None else _F32_NAN
                return _enc_float(float(v))
            if raw * scale + add == v and lo <= raw <= hi and raw != invalid:
                return raw
            return _enc_float(float(v))

        def dec_scalar(v: object) -> object:
            if type(v) is not int:
                return v
            return math.nan if v == invalid else v * scale + add

        return enc_scalar, dec_scalar, desc
    wdt = np.dtype("<" + WIRE_TYPES[w.type])
    native = wdt.newbyteorder("=")
    to_si = is_int and w.is_scaled
    limits: Any = np.iinfo(native) if is_int else None
    code = "%d" + WIRE_TYPES[w.type]

    def enc_small(a: np.ndarray) -> Packed:
        """A short array of the codec's ``raw * scale + add`` as its raw values, in Python
        (numpy's calls cost more below a few hundred elements, most of all on a cold core: one
        frame at a time): the numpy path's float operations, rounding (half to even) and output
        (1-D: little-endian bytes; more dimensions: extension 1 in the native dtype); None
        where that path has a case of its own (NaN without an invalid code)."""
        vals = a.ravel().tolist()
        raw = [(x - add) / scale for x in vals] if add else [x / scale for x in vals]
        if invalid is None:
            if any(r != r for r in raw):
                return None
            ints = list(map(round, raw))
        else:
            ints = [invalid if r != r else round(r) for r in raw]
        if a.ndim == 1:
            return struct.pack("<" + code % len(ints), *ints)
        head = _array_head(native, a.shape)
        return msgspec.msgpack.Ext(EXT_NDARRAY, head + struct.pack("=" + code % len(ints), *ints))

    def enc_array(v: Any, trusted: bool) -> Packed:
        if v is None:
            return None
        a = v if type(v) is np.ndarray else np.asarray(v)
        if trusted and to_si and a.size <= SMALL_ARRAY and a.dtype == np.float64:
            small = enc_small(a)
            if small is not None:
                return small
        if to_si and a.dtype == np.float64:
            raw = a - add if add else a / scale
            if add:
                raw /= scale
            np.rint(raw, out=raw)
            if invalid is not None:
                raw[np.isnan(raw)] = invalid
            if not trusted:
                if (invalid is None and np.isnan(raw).any()) or (
                    raw.size and (raw.min() < limits.min or raw.max() > limits.max)
                ):
                    return a
                rawi = raw.astype(native)
                back = rawi * scale + add
                if invalid is not None:
                    back[rawi == invalid] = np.nan
                if back.tobytes() != a.tobytes():  # exact, NaN as the codec makes it
                    return a
                a = rawi
            else:
                a = raw.astype(native)
        elif a.dtype != native:
            return a
        return a.astype(wdt, copy=False).tobytes() if a.ndim == 1 else a

    def dec_array(v: object) -> object:
        if v is None:
            return None
        if isinstance(v, bytes | bytearray | memoryview):
            raw = np.frombuffer(v, dtype=wdt)
        elif isinstance(v, np.ndarray) and v.dtype == native:
            raw = v
        else:
            return v  # SI, in its own dtype
        if not to_si:
            return _readonly(raw.astype(native, copy=False))
        out = raw.astype(np.float64) * scale + add
        if invalid is not None:
            out[raw == invalid] = np.nan
        return _readonly(out)

    return enc_array, dec_array, desc


def _linear_coders(
    scale: float, offset: float, factor: float
) -> tuple[Encoder, Decoder, str]:
    """A CAN signal decoded as ``float(raw * scale + offset) * factor`` (cantools, then the
    codec's unit factor): its raw integer where that gives the value back exactly."""

    def enc(v: object, t: bool) -> Packed:
        if type(v) is not float:
            return _enc_any(v, t)
        if not math.isfinite(v):
            return _enc_float(v)
        raw = round((v / factor - offset) / scale)
        return raw if float(raw * scale + offset) * factor == v else _enc_float(v)

    def dec(v: object) -> object:
        return float(v * scale + offset) * factor if type(v) is int else v

    return enc, dec, f"lin*{scale!r}+{offset!r}*{factor!r}"


@dataclass(frozen=True)
class _Plan:
    """How one message class travels: a (name, encode, decode) per transmitted field."""

    cls: type
    names: tuple[str, ...]
    #: None where the value travels as it is (integers, strings, bytes)
    encoders: tuple[Encoder | None, ...]
    decoders: tuple[Decoder, ...]
    schema: int
    #: ``pack(msg, trusted) -> body``, generated for the class (see :func:`_packer`)
    pack: Callable[[object, bool], list[Packed]]


def _packer(
    names: tuple[str, ...], encoders: tuple[Encoder | None, ...]
) -> Callable[[object, bool], list[Packed]]:
    """A function building the positional body of one class: one list display of attribute
    reads and encoder calls (no loop, no zip, no per-field lookup)."""
    ns: dict[str, Any] = {}
    items = []
    for i, (name, enc) in enumerate(zip(names, encoders, strict=True)):
        ok = name.isidentifier() and not keyword.iskeyword(name)
        get = f"msg.{name}" if ok else f"getattr(msg, {name!r})"  # a site table's odd name
        if enc is None:
            items.append(get)
            continue
        ns[f"e{i}"] = enc
        items.append(f"e{i}({get}, trusted)")
    src = f"def pack(msg, trusted):\n    return [{', '.join(items)}]\n"
    exec(src, ns)  # the source holds only identifiers and repr() of names
    return ns["pack"]  # type: ignore[no-any-return]


_type_hints = functools.lru_cache(maxsize=CLASS_CACHE_SIZE)(typing.get_type_hints)


@functools.lru_cache(maxsize=CLASS_CACHE_SIZE)
def _plan(cls: type) -> _Plan:
    hints = _type_hints(cls)
    names, encs, decs, descs = [], [], [], []
    for f in dataclasses.fields(cls):
        if "flag_bit" in f.metadata:  # derived from the status word on construction
            continue
        w, linear = f.metadata.get("wire"), f.metadata.get("linear")
        if w is not None:
            enc, dec, desc = _wire_coders(w)
        elif linear is not None:
            enc, dec, desc = _linear_coders(*linear)
        else:
            enc, dec, desc = _hint_coders(hints.get(f.name, Any))
        names.append(f.name)
        encs.append(enc)
        decs.append(dec)
        descs.append(f"{f.name}:{desc}")
    text = f"{getattr(cls, 'TYPE', cls.__name__)}({';'.join(descs)})"
    schema = zlib.crc32(text.encode()) & 0xFFFF
    return _Plan(
        cls, tuple(names), tuple(encs), tuple(decs), schema, _packer(tuple(names), tuple(encs))
    )


def layout_body(layout: WireLayout, frame: bytes) -> tuple[str, int, list[Packed]] | None:
    """(type, schema, body) of the envelope of the message ``layout`` places in ``frame``, read
    straight from the frame's bytes (the gateway's hot path: no message, no numpy), by a
    function generated once per layout from the codec's tables (:func:`_layout_reader`). The
    body is the one :func:`pack_body` gives for the decoded message
    (tests/service/test_envelope_bytes.py: every ensemble of the real PD0 files, emulated PD0
    and HN-100 frames); None where a field has no such form (an ASCII ``str`` row, a float
    scaled by the table: decode, then pack)."""
    got = _layout_reader(layout)
    if got is None:
        return None
    type_name, schema, read = got
    return type_name, schema, read(frame)


def _hint_names(hint: object, cls: type) -> bool:
    """``hint`` is ``cls`` or ``cls | None`` (the envelope nests ``cls`` untyped there)."""
    if hint is cls:
        return True
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    return origin in (types.UnionType, typing.Union) and set(args) == {cls, type(None)}


@functools.lru_cache(maxsize=4096)  # one per layout a codec serves; fuzzed ones stay bounded
def _layout_reader(
    layout: WireLayout,
) -> tuple[str, int, Callable[[bytes], list[Packed]]] | None:
    """Generate ``read(frame) -> body`` for one layout: one ``struct`` unpack of every wire field
    of every nested table (integers as the raw integers the envelope sends for them, integer
    arrays as their little-endian wire bytes, N-D ones as extension 1 with a constant head,
    floats through :func:`_enc_float`), frame slices for bytes fields, constants encoded once
    by the field's encoder, and one nested list display in the plans' field order."""
    ns: dict[str, Any] = {"_ext": msgspec.msgpack.Ext, "_f": _enc_float}
    slots: list[tuple[int, str, int]] = []  # (frame offset, struct code, bytes): item "@k@"
    endians: set[str] = set()

    def const(v: object) -> str:
        name = f"c{len(ns)}"
        ns[name] = v
        return name

    def slot(at: int, code: str, size: int) -> str:
        slots.append((at, code, size))
        return f"@{len(slots) - 1}@"

    def wire_item(node: WireLayout, r: Row) -> str | None:
        w = r.wire
        at = node.base + w.offset
        if w.type == "bytes":
            return slot(at, f"{w.size}s", w.size)
        if w.type not in WIRE_TYPES:  # "str": decoded with its NULs stripped
            return None
        code = WIRE_TYPES[w.type]
        size = struct.calcsize(code)
        endian = r.endian
        if w.shape:  # 1-D: bin of the little-endian wire bytes; N-D: extension 1, native
            if w.type.startswith("f") or endian != "<" or sys.byteorder != "little":
                return None
            shape = r.shape
            n = r.nbytes
            item = slot(at, f"{n}s", n)
            if len(shape) == 1:
                return item
            head = const(_array_head(np.dtype("=" + code), shape))
            return f"_ext({EXT_NDARRAY}, {head} + {item})"
        endians.add(endian)
        item = slot(at, code, size)
        if w.type.startswith("f"):
            return None if w.is_scaled else f"_f({item})"
        # a scaled integer travels as its raw integer: round((raw * scale + add - add) / scale)
        # gives raw back exactly for 32-bit integers and a sane offset (not so for 64-bit)
        if w.is_scaled and (size > 4 or (w.add and abs(w.add / w.scale) >= 2.0**40)):
            return None
        return item

    def value(v: object, hint: object, enc: Encoder | None) -> str | None:
        if v is None:
            return "None"
        if isinstance(v, WireLayout):
            return message(v) if _hint_names(hint, v.cls) else None
        if isinstance(v, slice):
            return f"buf[{int(v.start)}:{int(v.stop)}]" if enc is None else None
        if isinstance(v, tuple) and any(isinstance(x, WireLayout | slice) for x in v):
            args = typing.get_args(hint)
            if typing.get_origin(hint) is not tuple or len(args) != 2 or args[1] is not Ellipsis:
                return None
            items = [value(x, args[0], None) for x in v]
            return None if None in items else f"[{', '.join(items)}]"  # type: ignore[arg-type]
        return const(v if enc is None else enc(v, True))  # a constant, encoded once

    def message(node: WireLayout) -> str | None:
        p = _plan(node.cls)
        try:  # where the table's rows sit: its compiled plan for the layout's context
            rows = {r.name: r for r in table_plan(node.cls, node.ctx).rows}
        except WireError:
            return None
        wired = {f.name for f in dataclasses.fields(node.cls) if "wire" in f.metadata}
        hints = _type_hints(node.cls)
        items = []
        for name, enc in zip(p.names, p.encoders, strict=True):
            item: str | None
            if name in wired:
                row = rows.get(name)
                if name in node.absent:
                    item = "None"
                else:
                    item = None if row is None else wire_item(node, row)
            elif name in node.fields:
                item = value(node.fields[name], hints.get(name, Any), enc)
            else:
                item = None
            if item is None:
                return None
            items.append(item)
        return f"[{', '.join(items)}]"

    body = message(layout)
    if body is None or len(endians) > 1:
        return None
    order = sorted(range(len(slots)), key=lambda k: slots[k][0])
    fmt, pos, index = [next(iter(endians), "<")], 0, {}
    for i, k in enumerate(order):
        at, code, size = slots[k]
        if at < pos:
            return None  # overlapping fields
        fmt.append(f"{at - pos}x{code}" if at > pos else code)
        pos, index[k] = at + size, i
    ns["_unpack"] = struct.Struct("".join(fmt)).unpack_from
    for k, i in index.items():
        body = body.replace(f"@{k}@", f"r[{i}]")
    if body == f"[{', '.join(f'r[{i}]' for i in range(len(slots)))}]":
        body = "list(r)"  # a flat table in wire order
    src = f"def read(buf):\n    r = _unpack(buf)\n    return {body}\n"
    exec(src, ns)  # the source holds only generated identifiers and integers
    cls = layout.cls
    return str(getattr(cls, "TYPE", cls.__name__)), _plan(cls).schema, ns["read"]


def schema_id(cls: type) -> int:
    """16-bit fingerprint of a message class's table as the envelope carries it: field order,
    names, wire types, scales, invalid codes, shapes and nested tables. A reader whose table
    differs (another firmware's site table, another release) refuses the body."""
    return _plan(cls).schema


def pack_body(msg: object, trusted: bool = False) -> list[Packed]:
    """The positional body of a message (its class's table order; see the module docstring).
    ``trusted``: the message comes straight from its codec's decode, so every scaled array is
    ``raw * scale + add`` of integers and its raw values are recovered without checking."""
    cls: type = type(msg)
    return _plan(cls).pack(msg, trusted)


def unpack_body(cls: type, body: Sequence[object]) -> DataclassInstance:
    """The typed, immutable message of a positional body (inverse of :func:`pack_body`)."""
    p = _plan(cls)
    if len(body) != len(p.names):
        raise SchemaError(
            f"{getattr(cls, 'TYPE', cls.__name__)}: body has {len(body)} fields, this reader's "
            f"table {len(p.names)}"
        )
    kwargs = {}
    for name, dec, v in zip(p.names, p.decoders, body, strict=True):
        try:
            kwargs[name] = dec(v)
        except SchemaError:
            raise
        except (TypeError, ValueError) as exc:
            raise SchemaError(f"{cls.__name__}.{name}: {exc}") from None
    return cls(**kwargs)


def message_fields(msg: DataclassInstance) -> dict[str, object]:
    """A message's fields by name (shallow: nested messages stay typed)."""
    return {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}


_ARRAY_HEADS: dict[tuple[np.dtype, tuple[int, ...]], bytes] = {}


def _array_head(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """``<dtype.str>;<d0,d1,...>`` NUL: the head of extension 1 (cached: a few per codec)."""
    key = (dtype, shape)
    head = _ARRAY_HEADS.get(key)
    if head is None:
        head = f"{dtype.str};{','.join(map(str, shape))}".encode() + b"\0"
        if len(_ARRAY_HEADS) < 4096:
            _ARRAY_HEADS[key] = head
    return head


def _enc_hook(obj: object) -> Packed:
    if isinstance(obj, np.ndarray):
        return msgspec.msgpack.Ext(EXT_NDARRAY, _array_head(obj.dtype, obj.shape) + obj.tobytes())
    if isinstance(obj, np.generic):
        item = obj.item()
        return _enc_float(item) if type(item) is float else item
    if dataclasses.is_dataclass(obj):
        return _typed_ext(obj)
    raise NotImplementedError(f"cannot encode a {type(obj).__name__} in an envelope")


def _ext_hook(code: int, data: memoryview) -> object:
    if code == EXT_NDARRAY:
        raw = bytes(data)
        head, _, body = raw.partition(b"\0")
        dtype, _, shape = head.decode().partition(";")
        dims = tuple(int(x) for x in shape.split(",") if x)
        return np.frombuffer(body, dtype=np.dtype(dtype)).reshape(dims)  # read-only
    if code == EXT_TYPED:
        raw = bytes(data)
        name, _, body = raw.partition(b"\0")
        return _Typed(name.decode(), _DECODER.decode(body))
    raise ValueError(f"unknown MessagePack extension {code} in an envelope")


_ENCODER = msgspec.msgpack.Encoder(enc_hook=_enc_hook)
_DECODER = msgspec.msgpack.Decoder(ext_hook=_ext_hook)


@functools.lru_cache(maxsize=CLASS_CACHE_SIZE)
def envelope_encoding(type_name: str) -> zenoh.Encoding:
    """``application/msgpack;auvgw/3/<Type>``: the encoding of every envelope sample (one
    immutable object per type, made once: parsing the text cost about 2 us per frame)."""
    return zenoh.Encoding(f"application/msgpack;auvgw/{ENVELOPE_VERSION}/{type_name}")


def pack_envelope(
    type_name: str, schema: int, wire: str, device: str, t_ns: int, seq: int, body: Packed
) -> bytes:
    """The envelope bytes (module docstring) of a positional ``body`` (:func:`pack_body`,
    :func:`layout_body`) or a map of fields (schema 0)."""
    return _ENCODER.encode([ENVELOPE_VERSION, type_name, schema, wire, device, t_ns, seq, body])


def encode_envelope(
    msg: object,
    device: str,
    t_recv_ns: int,
    seq: int,
    body: Mapping[str, object] | None = None,
    wire: str = "",
    decoded: bool = False,
) -> tuple[bytes, zenoh.Encoding]:
    """The envelope (module docstring) of a decoded message and its encoding; ``body``, a map
    of fields with a ``type`` entry, replaces the message (schema 0: sent by name);
    ``wire``: the gateway format it came from; ``decoded``: ``msg`` is a codec's output as it
    decoded it (the gateway's hot path; see :func:`pack_body`)."""
    if body is not None:
        named = dict(body)
        type_name = str(named.pop("type", None) or getattr(msg, "TYPE", type(msg).__name__))
        payload = pack_envelope(type_name, 0, wire, device, t_recv_ns, seq, _enc_any(named))
    else:
        type_name = str(getattr(msg, "TYPE", type(msg).__name__))
        cls: type = type(msg)
        p = _plan(cls)
        payload = pack_envelope(
            type_name, p.schema, wire, device, t_recv_ns, seq, p.pack(msg, decoded)
        )
    return payload, envelope_encoding(type_name)


_codecs_loaded = False
_codecs_lock = threading.Lock()


def message_class(type_name: str) -> type | None:
    """The class of a message type name, loading once, if needed, every codec module, the
    shipped CAN DBCs (``HN100_Sample``, ``MS3A_Sample``, ``ActuatorState``, ...), the
    fusion ``Odometry`` and the SLAM outputs (:mod:`auvgw.slam.outputs`)."""
    cls = resolve_type(type_name)
    if cls is not None:
        return cls
    global _codecs_loaded
    with _codecs_lock:
        if not _codecs_loaded:
            _codecs_loaded = True
            from auvgw.drivers.formats import FORMATS, get_format

            for name in FORMATS:
                try:
                    get_format(name)
                except Exception as exc:  # a codec that cannot load only loses its own types
                    log.debug("codec %s not loaded: %s", name, exc)
            try:
                import auvgw.fusion.odometry
                import auvgw.slam.outputs  # noqa: F401 - registers the SLAM outputs
                from auvgw.drivers.can_codec import shipped_can_types

                shipped_can_types()
            except Exception as exc:  # cantools or a DBC missing: those types stay unknown
                log.debug("CAN sample types not loaded: %s", exc)
    return resolve_type(type_name)


#: bounds of an envelope's header fields, every version: a stamp is int64 ns since the Unix
#: epoch (the gateway's, or the vehicle-paced ``[clock]``'s, never negative), a sequence the
#: u64 the gateway counts in, names what a key segment holds
T_NS_MAX = 2**63 - 1
SEQ_MAX = 2**64 - 1
NAME_MAX = 256
SCHEMA_MAX = 0xFFFF
#: deepest nesting of a message body (a decoded message is a few levels: a table of records of
#: arrays); MessagePack and JSON parsers recurse, so a hostile body is refused before that
BODY_DEPTH_MAX = 32


def _check_header(version: int, type_name: object, device: object, t_ns: object, seq: object,
                  wire: object = "", schema: object = 0) -> None:  # fmt: skip
    """Every header field at the edges of its type (module docstring); a ValueError naming the
    version, the field and the value otherwise. ``bool`` is no integer here."""
    if (type(t_ns) is int and 0 <= t_ns <= T_NS_MAX and type(seq) is int
            and 0 <= seq <= SEQ_MAX and type(schema) is int and 0 <= schema <= SCHEMA_MAX
            and type(type_name) is str and type(device) is str and type(wire) is str
            and len(type_name) <= NAME_MAX and len(device) <= NAME_MAX
            and len(wire) <= NAME_MAX):  # fmt: skip
        return  # the usual case, at sensor rate: one expression

    def name(field: str, v: object) -> None:
        if type(v) is not str or len(v) > NAME_MAX:
            raise ValueError(f"envelope v{version}: {field} must be a string of at most "
                             f"{NAME_MAX} characters, got {_short(v)}")  # fmt: skip

    def integer(field: str, v: object, hi: int) -> None:
        if type(v) is not int or not 0 <= v <= hi:
            raise ValueError(f"envelope v{version}: {field} must be an integer in 0..{hi}, "
                             f"got {_short(v)}")  # fmt: skip

    name("type", type_name)
    name("device", device)
    name("wire", wire)
    integer("t_recv_ns", t_ns, T_NS_MAX)
    integer("seq", seq, SEQ_MAX)
    integer("schema", schema, SCHEMA_MAX)


def _short(v: object) -> str:
    text = repr(v)
    return f"{type(v).__name__} {text[:40]}{'...' if len(text) > 40 else ''}"


def _depth_ok(v: object, left: int = BODY_DEPTH_MAX) -> bool:
    """Whether ``v`` nests at most ``left`` containers deep (iterative: no recursion limit)."""
    stack = [(v, left)]
    while stack:
        x, d = stack.pop()
        if isinstance(x, dict):
            if d <= 0:
                return False
            stack.extend((y, d - 1) for y in x.values())
        elif isinstance(x, list | tuple):
            if d <= 0:
                return False
            stack.extend((y, d - 1) for y in x)
    return True


def _raw_depth_ok(payload: bytes) -> bool:
    """Bracket / container depth of a JSON text, counted before it is parsed (the parser
    recurses); a MessagePack payload's depth is checked by msgspec's own decoder."""
    depth = 0
    for b in payload:
        if b in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > BODY_DEPTH_MAX + 2:
                return False
        elif b in (0x5D, 0x7D):
            depth -= 1
    return True


def decode_envelope(payload: bytes, key: str = "", typed: bool = True) -> Envelope:
    """Parse an envelope (version 3; 2 and 1 of the previous releases are still read, a replay
    of an old recording needs them); with ``typed``, rebuild the message when its type is known
    here. Every header field is checked at the edges of its type in every version (a stamp an
    int64 of ns, a sequence a u64, names short strings; ``bool`` and ``float`` are no integers)
    and a body nests at most :data:`BODY_DEPTH_MAX` deep. Raises ValueError naming the field (a
    :class:`SchemaError` when the body does not fit this reader's table of its type)."""
    if payload[:1] == b"{":  # v1: JSON
        if not _raw_depth_ok(payload):
            raise ValueError(f"envelope v1: nested deeper than {BODY_DEPTH_MAX}")
        try:
            env = json.loads(payload)
        except (ValueError, RecursionError) as exc:
            raise ValueError(f"envelope v1: not JSON: {exc}") from None
        if not isinstance(env, dict) or env.get("v") != 1:
            v = env.get("v") if isinstance(env, dict) else None
            raise ValueError(f"JSON envelope version {v!r}, expected 1")
        for f in ("type", "device", "t_recv_ns", "seq", "msg"):
            if f not in env:
                raise ValueError(f"envelope v1: no {f!r} field")
        _check_header(1, env["type"], env["device"], env["t_recv_ns"], env["seq"])
        if not isinstance(env["msg"], dict | list):
            got = _short(env["msg"])
            raise ValueError(f"envelope v1: msg must be an object or array, got {got}")
        return Envelope(
            env["type"], env["device"], env["t_recv_ns"], env["seq"], env["msg"], key=key
        )
    try:
        env = _DECODER.decode(payload)
    except (msgspec.DecodeError, RecursionError) as exc:
        raise ValueError(f"not an envelope: {exc}") from None
    if isinstance(env, dict):
        if env.get("v") != 2:
            raise ValueError(f"envelope version {env.get('v')!r}, expected {ENVELOPE_VERSION}")
        for f in ("type", "device", "t", "seq", "msg", "wire"):
            if f not in env:
                raise ValueError(f"envelope v2: no {f!r} field")
        _check_header(2, env["type"], env["device"], env["t"], env["seq"], env["wire"])
        if not isinstance(env["msg"], dict | list) or not _depth_ok(env["msg"]):
            raise ValueError(f"envelope v2: msg must be a map or array nested at most "
                             f"{BODY_DEPTH_MAX} deep")  # fmt: skip
        return Envelope(
            env["type"], env["device"], env["t"], env["seq"], env["msg"], key=key, wire=env["wire"]
        )
    if not isinstance(env, list) or not env or env[0] != ENVELOPE_VERSION or len(env) != 8:
        v = env[0] if isinstance(env, list) and env else None
        raise ValueError(f"envelope version {v!r}, expected {ENVELOPE_VERSION}")
    _, type_name, schema, wire, device, t_ns, seq, body = env
    _check_header(3, type_name, device, t_ns, seq, wire, schema)
    # a positional body is checked against its table (typed_body); one sent by name is free
    if not isinstance(body, list | dict) or (isinstance(body, dict) and not _depth_ok(body)):
        raise ValueError(f"malformed envelope of type {type_name!r}: the body must be a map or "
                         f"array nested at most {BODY_DEPTH_MAX} deep")  # fmt: skip
    if isinstance(body, dict):
        return Envelope(type_name, device, t_ns, seq, body, key=key, wire=wire, schema=schema)
    message = None
    if typed:
        cls = message_class(type_name)
        if cls is not None:
            message = typed_body(cls, type_name, schema, body)
    named = message_fields(message) if message is not None else body
    return Envelope(type_name, device, t_ns, seq, named, message, key, wire, schema)


def typed_body(
    cls: type, type_name: str, schema: int, body: Sequence[object]
) -> DataclassInstance:
    """The message of a positional body, after checking the schema fingerprint."""
    mine = schema_id(cls)
    if schema != mine:
        raise SchemaError(
            f"{type_name}: envelope schema {schema:04x}, this reader's table {mine:04x} "
            "(the gateway's table or release differs from this reader's)"
        )
    return unpack_body(cls, body)
