"""Frame tables loaded from TOML: a site replaces the file, not the code.

Two table kinds, both compiled into a project message class (``drivers/spec.py``: one
``wire(...)`` field per row, ``@message``) so that decode and encode walk exactly one table:

* :class:`BinaryFrameSpec` -- a fixed-size binary frame: sync bytes, optional length field,
  byte order, a checksum of a named kind over a declared byte range, and the fields (name, wire
  type, byte offset from the frame start, scale, units, description). Every byte of the frame
  must belong to the sync, the length field, a field or the checksum, so
  ``encode(decode(frame)) == frame`` holds for every valid frame.
* :class:`AsciiLineSpec` -- an ASCII line ``<start><header><sep><f1><sep>...<delim>HH<term>``
  whose numeric fields have a declared width, number of decimals and sign rule, so the text
  form of each value is unique and ``encode(decode(line)) == line``.

Table units are those of ``raw * scale`` as the vendor manual states them (``deg``, ``mg``,
``0.1 ms`` = ``scale = 0.1, units = "ms"``); decoded messages carry SI (see :data:`UNITS`).
Every error in a table is a :class:`TableError` naming the file, the entry and what is expected.
"""

from __future__ import annotations

import binascii
import builtins
import dataclasses
import functools
import keyword
import math
import re
import struct
import tomllib
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Generic, Protocol, Self, TypeVar

from auvgw.drivers import registry
from auvgw.drivers.framing import BadFrame, DecodeError, ErrorPolicy, Framer
from auvgw.drivers.spec import (
    LAZY_TYPES,
    WIRE_TYPES,
    WireError,
    WireLayout,
    decode_block,
    encode_block,
    message,
    wire,
)
from auvgw.ground.errors import ConfigError, DataError
from auvgw.ground.paths import config_file

__all__ = [
    "CHECKSUMS",
    "UNITS",
    "AsciiFieldSpec",
    "AsciiLineCodec",
    "AsciiLineFramer",
    "AsciiLineSpec",
    "BinaryFrameCodec",
    "BinaryFrameFramer",
    "BinaryFrameSpec",
    "ChecksumKind",
    "FieldSpec",
    "FlagsSpec",
    "TableCodec",
    "TableError",
    "TableFramer",
    "load_toml",
    "parse_ascii_table",
    "parse_binary_table",
    "si_units",
]


class TableError(ConfigError):
    """A frame table that cannot be used; the message names the file, the entry and the fix."""


# -- units ------------------------------------------------------------------------------------

_G0 = 9.80665
_DEG = math.pi / 180.0

#: table units -> (decoded units, factor). Decoded units are SI, except magnetic flux density,
#: which the project carries in nT.
UNITS: dict[str, tuple[str, float]] = {
    "": ("", 1.0),
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "us": ("s", 1e-6),
    "rad": ("rad", 1.0),
    "mrad": ("rad", 1e-3),
    "urad": ("rad", 1e-6),
    "deg": ("rad", _DEG),
    "rad/s": ("rad/s", 1.0),
    "mrad/s": ("rad/s", 1e-3),
    "deg/s": ("rad/s", _DEG),
    "m/s^2": ("m/s^2", 1.0),
    "mm/s^2": ("m/s^2", 1e-3),
    "g": ("m/s^2", _G0),
    "mg": ("m/s^2", _G0 * 1e-3),
    "m/s": ("m/s", 1.0),
    "cm/s": ("m/s", 1e-2),
    "mm/s": ("m/s", 1e-3),
    "m": ("m", 1.0),
    "cm": ("m", 1e-2),
    "mm": ("m", 1e-3),
    "nT": ("nT", 1.0),
    "uT": ("nT", 1e3),
    "T": ("nT", 1e9),
    "G": ("nT", 1e5),
    "mG": ("nT", 1e2),
}


def si_units(units: str) -> tuple[str, float]:
    """``(decoded units, factor)`` for table units ``units``; KeyError when unknown."""
    return UNITS[units]


# -- checksums --------------------------------------------------------------------------------


def _ubx_fletcher(data: bytes | bytearray | memoryview) -> int:
    a = b = 0
    for byte in data:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return (a << 8) | b


def _xor8(data: bytes | bytearray | memoryview) -> int:
    x = 0
    for byte in data:
        x ^= byte
    return x


@dataclass(frozen=True)
class ChecksumKind:
    """A checksum algorithm: ``compute(covered bytes) -> int`` written in ``size`` bytes.

    ``byte_order`` fixes the order of the written bytes when the algorithm defines it
    (Fletcher: CK_A then CK_B); otherwise the table's byte order applies.
    """

    name: str
    size: int
    compute: Callable[[bytes | bytearray | memoryview], int]
    doc: str
    byte_order: str | None = None


#: checksum kind name -> algorithm
CHECKSUMS: dict[str, ChecksumKind] = {
    k.name: k
    for k in (
        ChecksumKind(
            "crc16-ccitt-false",
            2,
            lambda d: binascii.crc_hqx(d, 0xFFFF),
            "CRC-16, poly 0x1021, init 0xFFFF, no reflection, no final XOR (check 0x29B1)",
        ),
        ChecksumKind(
            "crc16-xmodem",
            2,
            lambda d: binascii.crc_hqx(d, 0),
            "CRC-16, poly 0x1021, init 0x0000, no reflection (XMODEM; check 0x31C3)",
        ),
        ChecksumKind("crc32", 4, zlib.crc32, "CRC-32 (ISO-HDLC/zlib; check 0xCBF43926)"),
        ChecksumKind(
            "ubx-fletcher",
            2,
            _ubx_fletcher,
            "u-blox UBX 8-bit Fletcher: CK_A = sum of bytes, CK_B = sum of CK_A, both mod 256; "
            "written CK_A then CK_B",
            ">",
        ),
        ChecksumKind("xor8", 1, _xor8, "XOR of the bytes (NMEA 0183)"),
        ChecksumKind("sum8", 1, lambda d: sum(d) & 0xFF, "sum of the bytes modulo 256"),
    )
}


# -- TOML reading -----------------------------------------------------------------------------

_MISSING: Any = object()
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_INT_TYPES = {t: struct.calcsize(c) for t, c in WIRE_TYPES.items() if not t.startswith("f")}


def _int_limits(wire_type: str) -> tuple[int, int]:
    bits = 8 * _INT_TYPES[wire_type]
    if wire_type.startswith("u"):
        return 0, 2**bits - 1
    return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1


def load_toml(path: str | Path) -> dict[str, Any]:
    """The parsed TOML document at ``path`` (:class:`TableError` naming the file on failure)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise TableError(f"{path}: cannot read table: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TableError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TableError(f"{path}: not valid TOML: {exc}") from None


class _Section:
    """One TOML table under validation: typed lookups, then a check for unknown keys."""

    def __init__(self, source: str, where: str, data: Any) -> None:
        if not isinstance(data, dict):
            raise TableError(f"{source}: {where}: expected a table, got {data!r}")
        self.source = source
        self.where = where
        self.data = data
        self.known: list[str] = []

    def error(self, problem: str) -> TableError:
        return TableError(f"{self.source}: {self.where}: {problem}")

    def get(self, key: str, kinds: tuple[type, ...], expected: str, default: Any = _MISSING) -> Any:
        self.known.append(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(f"missing {key!r}; expected {expected}")
            return default
        value = self.data[key]
        if (isinstance(value, bool) and bool not in kinds) or not isinstance(value, kinds):
            raise self.error(f"{key} = {value!r}; expected {expected}")
        return value

    def section(self, key: str) -> _Section:
        """The required sub-table ``[key]``."""
        sub = self.optional_section(key)
        if sub is None:
            raise self.error(f"missing table [{key}]")
        return sub

    def optional_section(self, key: str) -> _Section | None:
        """The sub-table ``[key]``, or None when absent."""
        self.known.append(key)
        if key not in self.data:
            return None
        where = f"{self.where[:-1]}.{key}]" if self.where.startswith("[") else f"[{key}]"
        return _Section(self.source, where, self.data[key])

    def finish(self) -> None:
        extra = sorted(set(self.data) - set(self.known))
        if extra:
            raise self.error(
                f"unknown key(s) {', '.join(extra)}; expected only {', '.join(self.known)}"
            )


# -- field rows -------------------------------------------------------------------------------


@dataclass(frozen=True)
class FieldSpec:
    """One row of a table, resolved: ``scale``/``add`` convert raw to the decoded ``units``.

    ``offset`` is the byte offset from the frame start (binary) or the field's position in the
    line, header = 0 (ASCII). ``table_units`` / ``table_scale`` are as written in the table.
    """

    name: str
    type: str
    offset: int
    scale: float
    add: float
    units: str
    table_units: str
    table_scale: float
    description: str
    vendor: str
    invalid: int | None
    size: int

    @property
    def is_scaled(self) -> bool:
        return self.scale != 1.0 or self.add != 0.0 or self.invalid is not None

    @property
    def nbytes(self) -> int:
        return self.size if self.type == "bytes" else struct.calcsize(WIRE_TYPES[self.type])

    def python_type(self) -> builtins.type:
        if self.type == "bytes":
            return bytes
        if self.is_scaled or self.type.startswith("f"):
            return float
        return int

    def wire(self) -> Any:
        """The ``dataclasses.field`` carrying this row as a :class:`~auvgw.drivers.spec.Wire`."""
        return wire(
            self.type,
            self.offset,
            scale=self.scale,
            add=self.add,
            units=self.units,
            vendor=self.vendor,
            doc=self.description,
            invalid=self.invalid,
            size=self.size,
        )


@dataclass(frozen=True)
class AsciiFieldSpec(FieldSpec):
    """An ASCII numeric field: ``width`` characters (0 = no padding), ``decimals`` after the
    point, ``sign`` one of ``always`` (+/-), ``negative`` (only -), ``never`` (unsigned);
    ``low`` .. ``high``: the physically plausible decoded values (decoded units, inclusive;
    None: no bound), from the table's ``min`` / ``max``."""

    width: int = 0
    decimals: int = 0
    sign: str = "negative"
    low: float | None = None
    high: float | None = None

    def value(self, raw: int) -> float | int:
        """The decoded value (decoded units) of raw value ``raw``."""
        return raw * self.scale + self.add if self.is_scaled else raw

    def out_of_range(self, raw: int) -> str | None:
        """Why ``raw`` is not plausible (its value outside ``low .. high``), or None."""
        v = self.value(raw)
        if (self.low is not None and v < self.low) or (self.high is not None and v > self.high):
            lo = "-inf" if self.low is None else f"{self.low:.10g}"
            hi = "inf" if self.high is None else f"{self.high:.10g}"
            return f"{v:.10g} {self.units} outside {lo} .. {hi}".replace("  ", " ")
        return None

    def format(self, raw: int) -> str:
        """The text of raw value ``raw``; ValueError when it does not fit the declared form."""
        if raw < 0 and self.sign == "never":
            raise ValueError(f"negative value {raw} in an unsigned field")
        digits = str(abs(raw))
        if self.decimals:
            digits = digits.rjust(self.decimals + 1, "0")
            digits = f"{digits[: -self.decimals]}.{digits[-self.decimals :]}"
        prefix = "-" if raw < 0 else ("+" if self.sign == "always" else "")
        if self.width:
            pad = self.width - len(prefix) - len(digits)
            if pad < 0:
                raise ValueError(f"{prefix}{digits} is wider than {self.width} characters")
            digits = "0" * pad + digits
        elif len(digits) - (1 if self.decimals else 0) > _MAX_DIGITS:
            raise ValueError(f"more than {_MAX_DIGITS} digits")
        return prefix + digits

    def example(self) -> str:
        return self.format(5 if self.sign == "never" else -5)

    def form(self) -> str:
        width = f"width {self.width}" if self.width else "no padding"
        return f"{width}, {self.decimals} decimals, sign {self.sign}, e.g. {self.example()!r}"


def _parse_field_common(sec: _Section) -> dict[str, Any]:
    name = sec.get("name", (str,), "a lower-case identifier such as 'roll'")
    if not _NAME_RE.match(name) or keyword.iskeyword(name):
        raise sec.error(f"name {name!r} is not a lower-case Python identifier")
    sec.where = f"{sec.where} ({name})"
    units = sec.get("units", (str,), f"one of {', '.join(repr(u) for u in UNITS)}", "")
    if units not in UNITS:
        raise sec.error(f"unknown units {units!r}; expected one of {', '.join(map(repr, UNITS))}")
    si, factor = UNITS[units]
    scale = float(sec.get("scale", (int, float), "a non-zero number (raw * scale = units)", 1))
    if scale == 0 or not math.isfinite(scale):
        raise sec.error(f"scale = {scale!r}; expected a finite non-zero number")
    add = float(sec.get("add", (int, float), "a number (added after scale, in units)", 0.0))
    description = sec.get("description", (str,), "a string", "")
    vendor = sec.get("vendor", (str,), "the vendor manual's name of the field", "")
    return {
        "name": name,
        "scale": scale * factor,
        "add": add * factor,
        "units": si,
        "table_units": units,
        "table_scale": scale,
        "description": description,
        "vendor": vendor,
    }


def _check_required(
    source: str,
    fields: Sequence[FieldSpec],
    required: Mapping[str, str],
) -> None:
    """Required field name -> decoded units ('' = a dimensionless integer count)."""
    by_name = {f.name: f for f in fields}
    missing = [n for n in required if n not in by_name]
    if missing:
        raise TableError(
            f"{source}: [[fields]]: missing required field(s) {', '.join(missing)} "
            f"(the gateway reads them by name)"
        )
    for name, units in required.items():
        f = by_name[name]
        if f.units != units:
            accepted = ", ".join(repr(u) for u, (si, _) in UNITS.items() if si == units)
            raise TableError(
                f"{source}: fields[{fields.index(f)}] ({name}): units {f.table_units!r} give "
                f"{f.units or 'a dimensionless value'}; expected table units {accepted}"
            )
        if units == "" and (f.python_type() is not int):
            raise TableError(
                f"{source}: fields[{fields.index(f)}] ({name}): expected an unscaled integer "
                f"count (integer type, scale 1, no invalid code)"
            )


# -- status flags -----------------------------------------------------------------------------


@dataclass(frozen=True)
class FlagsSpec:
    """Boolean flags taken from bits of an integer ``field`` (bit 0 = least significant)."""

    field: str
    bits: tuple[tuple[str, int], ...]


def _parse_flags(
    doc: Mapping[str, Any],
    source: str,
    fields: Sequence[FieldSpec],
    required_flags: Sequence[str],
) -> FlagsSpec | None:
    if "status" not in doc:
        if required_flags:
            raise TableError(
                f"{source}: missing table [status] with bits {', '.join(required_flags)}"
            )
        return None
    sec = _Section(source, "[status]", doc["status"])
    field_name = sec.get("field", (str,), "the name of the integer field holding the bits")
    bits_sec = sec.section("bits")
    sec.finish()
    by_name = {f.name: f for f in fields}
    if field_name not in by_name:
        raise sec.error(f"field {field_name!r} is not in [[fields]]")
    f = by_name[field_name]
    if f.type not in _INT_TYPES or f.is_scaled:
        raise sec.error(
            f"field {field_name!r} is {f.type} scaled {f.table_scale}; expected an unscaled "
            f"integer field"
        )
    nbits = 8 * _INT_TYPES[f.type]
    bits: list[tuple[str, int]] = []
    for flag, bit in bits_sec.data.items():
        if not _NAME_RE.match(flag) or keyword.iskeyword(flag) or flag in by_name:
            raise bits_sec.error(f"flag name {flag!r} must be a new lower-case identifier")
        if isinstance(bit, bool) or not isinstance(bit, int) or not 0 <= bit < nbits:
            raise bits_sec.error(f"{flag} = {bit!r}; expected a bit number 0..{nbits - 1}")
        if any(b == bit for _, b in bits):
            raise bits_sec.error(f"{flag} = {bit}: bit {bit} is already used")
        bits.append((flag, bit))
    missing = [n for n in required_flags if n not in dict(bits)]
    if missing:
        raise bits_sec.error(f"missing required flag(s) {', '.join(missing)}")
    return FlagsSpec(field_name, tuple(bits))


# -- message classes --------------------------------------------------------------------------


def build_message_class(
    name: str,
    fields: Sequence[FieldSpec],
    *,
    byte_order: str = "<",
    doc: str = "",
    flags: FlagsSpec | None = None,
    module: str = __name__,
    namespace: Mapping[str, Any] | None = None,
    source: str = "",
) -> type:
    """A frozen ``@message`` dataclass with one ``wire(...)`` field per table row.

    Flags (if any) follow as ``bool`` fields derived from the status bits; passing a flag that
    disagrees with the status word raises ValueError.
    """
    extra = dict(namespace or {})
    names = [f.name for f in fields] + [flag for flag, _ in (flags.bits if flags else ())]
    clash = sorted(set(names) & set(extra))
    if clash:
        where = f"{source}: " if source else ""
        raise TableError(
            f"{where}field name(s) {', '.join(clash)} are reserved by {name} "
            f"(reserved: {', '.join(sorted(extra))})"
        )
    annotations: dict[str, Any] = {}
    ns: dict[str, Any] = {"__module__": module, "__qualname__": name}
    for f in fields:
        annotations[f.name] = f.python_type()
        ns[f.name] = f.wire()
    lines = [doc.strip(), "", "Fields [decoded units]:"]
    lines += [f"    {f.name} [{f.units or '1'}]: {f.description}" for f in fields]
    if flags is not None:
        bits = flags.bits
        status = flags.field
        for flag, bit in bits:
            annotations[flag] = bool
            ns[flag] = dataclasses.field(default=None, metadata={"flag_bit": bit})
            lines.append(f"    {flag} [bool]: bit {bit} of {status} (derived)")

        def __post_init__(self: Any) -> None:
            word = int(getattr(self, status))
            for flag, bit in bits:
                actual = bool((word >> bit) & 1)
                given = getattr(self, flag)
                if given is None:
                    object.__setattr__(self, flag, actual)
                elif bool(given) != actual:
                    raise ValueError(
                        f"{name}.{flag}={given!r} disagrees with bit {bit} of {status}=0x{word:x}"
                    )

        ns["__post_init__"] = __post_init__
    ns["__annotations__"] = annotations
    ns["__doc__"] = "\n".join(lines)
    ns.update(extra)
    cls = type(name, (), ns)
    return message(endian=byte_order)(cls)


# -- binary frames ----------------------------------------------------------------------------


@dataclass(frozen=True)
class BinaryFrameSpec:
    """A fixed-size binary frame table (see the module docstring)."""

    source: str
    sync: bytes
    size: int
    byte_order: str  # "<" or ">"
    length_offset: int | None
    length_type: str
    length_adjust: int
    checksum: ChecksumKind
    checksum_start: int
    checksum_byte_order: str
    fields: tuple[FieldSpec, ...]
    flags: FlagsSpec | None

    @property
    def checksum_offset(self) -> int:
        return self.size - self.checksum.size

    @property
    def length_value(self) -> int:
        return self.size - self.length_adjust


_ORDERS = {"little": "<", "big": ">"}


def parse_binary_table(
    doc: Mapping[str, Any],
    source: str,
    required: Mapping[str, str] | None = None,
    required_flags: Sequence[str] = (),
) -> BinaryFrameSpec:
    """Validate a binary frame table (a parsed TOML document) read from ``source``."""
    top = _Section(source, "(top level)", dict(doc))
    frame = top.section("frame")
    fields_doc = top.get("fields", (list,), "an array of tables [[fields]]")
    top.known.append("status")
    top.finish()
    sync_hex = frame.get("sync", (str,), "hex bytes such as 'AA 48'")
    try:
        sync = bytes.fromhex(sync_hex)
    except ValueError:
        raise frame.error(f"sync = {sync_hex!r}; expected hex bytes such as 'AA 48'") from None
    if not sync:
        raise frame.error("sync is empty; expected at least one byte")
    size = frame.get("size", (int,), "the total frame size in bytes (sync to checksum)")
    order_name = frame.get("byte_order", (str,), "'little' or 'big'", "little")
    if order_name not in _ORDERS:
        raise frame.error(f"byte_order = {order_name!r}; expected 'little' or 'big'")
    order = _ORDERS[order_name]
    length = frame.optional_section("length")
    cs = frame.section("checksum")
    frame.finish()

    kind_name = cs.get("kind", (str,), f"one of {', '.join(CHECKSUMS)}")
    if kind_name not in CHECKSUMS:
        raise cs.error(
            f"unknown checksum kind {kind_name!r}; expected one of {', '.join(CHECKSUMS)}"
        )
    kind = CHECKSUMS[kind_name]
    cs_start = cs.get("start", (int,), "the first covered byte (offset from the frame start)")
    cs_order_name = cs.get("byte_order", (str,), "'little' or 'big'", order_name)
    if cs_order_name not in _ORDERS:
        raise cs.error(f"byte_order = {cs_order_name!r}; expected 'little' or 'big'")
    cs.finish()
    min_size = len(sync) + kind.size + 1
    if size < min_size or size > 65536:
        raise frame.error(f"size = {size}; expected {min_size}..65536 (sync + fields + checksum)")
    cs_offset = size - kind.size
    if not 0 <= cs_start < cs_offset:
        raise cs.error(f"start = {cs_start}; expected 0..{cs_offset - 1} (checksum at {cs_offset})")

    # byte ownership map: which entry owns each byte
    owner: list[str | None] = [None] * size
    owner[: len(sync)] = ["sync"] * len(sync)
    owner[cs_offset:] = ["checksum"] * kind.size

    def claim(sec: _Section, what: str, start: int, n: int) -> None:
        if start < 0 or start + n > cs_offset:
            raise sec.error(
                f"{what} spans bytes {start}..{start + n - 1}, beyond the frame's field area "
                f"{len(sync)}..{cs_offset - 1} (size {size}, checksum at {cs_offset})"
            )
        for i in range(start, start + n):
            if owner[i] is not None:
                raise sec.error(
                    f"{what} at bytes {start}..{start + n - 1} overlaps {owner[i]} at byte {i}"
                )
        owner[start : start + n] = [what] * n

    length_offset: int | None = None
    length_type = "u8"
    length_adjust = 0
    if length is not None:
        length_offset = length.get("offset", (int,), "the byte offset of the length field")
        length_type = length.get("type", (str,), f"one of {', '.join(_INT_TYPES)}")
        if length_type not in _INT_TYPES:
            raise length.error(f"type {length_type!r}; expected one of {', '.join(_INT_TYPES)}")
        length_adjust = length.get("adjust", (int,), "frame size - length value", 0)
        length.finish()
        lo, hi = _int_limits(length_type)
        if not lo <= size - length_adjust <= hi:
            raise length.error(
                f"length value size - adjust = {size - length_adjust} does not fit {length_type}"
            )
        claim(length, "length field", length_offset, _INT_TYPES[length_type])

    if not isinstance(fields_doc, list) or not fields_doc:
        raise top.error("fields: expected a non-empty array of tables [[fields]]")
    fields: list[FieldSpec] = []
    for i, row in enumerate(fields_doc):
        sec = _Section(source, f"fields[{i}]", row)
        common = _parse_field_common(sec)
        types = [*WIRE_TYPES, "bytes"]
        ftype = sec.get("type", (str,), f"one of {', '.join(types)}")
        if ftype not in types:
            raise sec.error(f"unknown wire type {ftype!r}; expected one of {', '.join(types)}")
        offset = sec.get("offset", (int,), "the byte offset from the frame start")
        nbytes = sec.get("size", (int,), "the byte count of a 'bytes' field", 0)
        if ftype == "bytes" and nbytes <= 0:
            raise sec.error("a 'bytes' field needs size = N > 0")
        if ftype != "bytes" and nbytes:
            raise sec.error(f"size applies to 'bytes' fields only, not {ftype}")
        invalid = sec.get("invalid", (int,), "a raw integer meaning 'no data' (decoded NaN)", None)
        sec.finish()
        if invalid is not None:
            if ftype not in _INT_TYPES:
                raise sec.error(f"invalid applies to integer types, not {ftype}")
            lo, hi = _int_limits(ftype)
            if not lo <= invalid <= hi:
                raise sec.error(f"invalid = {invalid} outside the {ftype} range [{lo}, {hi}]")
        if ftype == "bytes" and (common["scale"] != 1.0 or common["add"] != 0.0):
            raise sec.error("a 'bytes' field cannot be scaled")
        if any(f.name == common["name"] for f in fields):
            raise sec.error(f"duplicate field name {common['name']!r}")
        fs = FieldSpec(type=ftype, offset=offset, invalid=invalid, size=nbytes, **common)
        claim(sec, f"field {fs.name!r}", offset, fs.nbytes)
        fields.append(fs)

    gaps = _runs(i for i, o in enumerate(owner) if o is None)
    if gaps:
        a, b = gaps[0]
        raise TableError(
            f"{source}: [[fields]]: bytes {a}..{b} are covered by no field; every byte must be "
            f'declared so frames re-encode identically (e.g. name = "reserved_{a}", '
            f'type = "bytes", offset = {a}, size = {b - a + 1})'
        )
    _check_required(source, fields, required or {})
    flags = _parse_flags(doc, source, fields, required_flags)
    return BinaryFrameSpec(
        source=source,
        sync=sync,
        size=size,
        byte_order=order,
        length_offset=length_offset,
        length_type=length_type,
        length_adjust=length_adjust,
        checksum=kind,
        checksum_start=cs_start,
        checksum_byte_order=kind.byte_order or _ORDERS[cs_order_name],
        fields=tuple(fields),
        flags=flags,
    )


def _runs(indices: Iterable[int]) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for i in indices:
        if out and out[-1][1] == i - 1:
            out[-1] = (out[-1][0], i)
        else:
            out.append((i, i))
    return out


class _Table(Protocol):
    @property
    def source(self) -> str: ...

    @property
    def fields(self) -> Sequence[FieldSpec]: ...


S = TypeVar("S", bound=_Table)
F = TypeVar("F", bound=Framer)


class TableCodec(Generic[S, F]):
    """What a table-driven codec shares: the table ``spec``, the message class built from it, a
    ``name`` (logs, errors) and :meth:`framer`.

    A device's codec subclasses :class:`BinaryFrameCodec` or :class:`AsciiLineCodec` with
    ``device=<format>``: its shipped table (:attr:`TABLE`) and the message class's name
    (:attr:`MESSAGE`, its registered stream message type) come from the device registry
    (:mod:`auvgw.drivers.registry`); it gives in class attributes the message class's docstring
    (:attr:`DOC`) and extra members (:attr:`EXTRA`), and the fields every table of the device
    must declare (:attr:`REQUIRED_FIELDS`); :meth:`from_toml` and :meth:`from_spec` build it
    from those. A device's framer class subclasses the table
    kind's framer with ``shipped=default_codec`` (the codec used when it is given none)."""

    #: the framer of this table kind: ``framer_type(spec, policy=, source=, name=)``
    framer_type: Callable[..., F]
    #: a device's shipped table under ``config/``; its stem names the codec
    TABLE: ClassVar[str] = ""
    #: the name of the message class built from a table
    MESSAGE: ClassVar[str] = ""
    #: the message class's docstring (the table's source is appended)
    DOC: ClassVar[str] = ""
    #: extra members of the message class (properties)
    EXTRA: ClassVar[Mapping[str, Any]] = {}
    #: fields every table of the device must declare: name -> decoded units ('' = a count)
    REQUIRED_FIELDS: ClassVar[Mapping[str, str]] = {}

    def __init_subclass__(cls, device: str | None = None, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if device is None:
            return
        d = registry.device(device)
        stream = [m.type for m in d.messages if m.wire == "stream"]
        if d.table is None or len(stream) != 1:
            raise TypeError(f"{cls.__name__}: format {device!r} registers no table and one type")
        cls.TABLE, cls.MESSAGE = d.table, stream[0]

    def __init__(self, spec: S, message_type: type, name: str = "frame") -> None:
        self.spec = spec
        self.message_type = message_type
        self.name = name

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> Self:
        """Load a table (default: the shipped ``config/<TABLE>``).

        Raises :class:`TableError` naming the file, the entry and what is expected (unknown
        type, overlapping fields, field beyond the frame, a required field missing, ...).
        """
        path = Path(path) if path is not None else config_file(cls.TABLE)
        return cls.from_spec(cls.parse_table(load_toml(path), str(path)))

    @classmethod
    def parse_table(cls, doc: Mapping[str, Any], source: str) -> S:
        """Validate a parsed TOML table of this kind read from ``source``."""
        raise NotImplementedError

    @classmethod
    def message_options(cls, spec: S) -> dict[str, Any]:
        """Keyword arguments of :func:`build_message_class` that the table kind adds."""
        return {}

    @classmethod
    def from_spec(cls, spec: S) -> Self:
        """The codec of a validated table, its message class (:attr:`MESSAGE`) built from it."""
        msg_type = build_message_class(
            cls.MESSAGE,
            spec.fields,
            doc=f"{cls.DOC}\n\nTable: {spec.source}",
            module=cls.__module__,
            namespace=cls.EXTRA,
            source=spec.source,
            **cls.message_options(spec),
        )
        return cls(spec, msg_type, name=Path(cls.TABLE).stem)

    def framer(
        self,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        **_ignored: Any,
    ) -> F:
        """A fresh framer for this table."""
        return self.framer_type(self.spec, policy=policy, source=source, name=self.name)


class TableFramer(Framer, Generic[S]):
    """A framer whose sync, size and checks come from a table: a spec, a codec's or (a device
    framer, declared ``class Hn100Framer(BinaryFrameFramer, shipped=default_codec)``) the
    shipped codec's when given none. ``name`` defaults to the codec's."""

    #: the codec whose table a device framer uses when given none
    shipped: ClassVar[Callable[[], TableCodec[Any, Any]] | None] = None
    spec: S

    def __init_subclass__(
        cls, shipped: Callable[[], TableCodec[Any, Any]] | None = None, **kw: Any
    ) -> None:
        super().__init_subclass__(**kw)
        cls.shipped = shipped or cls.shipped

    def __init__(
        self,
        table: S | TableCodec[S, Any] | None = None,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        name: str | None = None,
    ) -> None:
        shipped = type(self).shipped
        if table is None:
            if shipped is None:
                raise TypeError(f"{type(self).__name__} needs a table")
            table = shipped()
        if isinstance(table, TableCodec):
            name = name or table.name
            table = table.spec
        self.spec = table
        self.name = name or self.name
        super().__init__(policy=policy, source=source, max_frame_size=self.use_table(table))

    def use_table(self, spec: S) -> int:
        """Take the sync and what the checks need from ``spec``; the largest frame (bytes)."""
        raise NotImplementedError


class BinaryFrameFramer(TableFramer[BinaryFrameSpec]):
    """Framer whose sync, size, length field and checksum come from a :class:`BinaryFrameSpec`
    (see :class:`TableFramer`)."""

    def use_table(self, spec: BinaryFrameSpec) -> int:
        self.sync = spec.sync
        self._cs_struct = struct.Struct(
            spec.checksum_byte_order + ("B", "H", "", "I")[spec.checksum.size - 1]
        )
        self._len_struct = struct.Struct(spec.byte_order + WIRE_TYPES[spec.length_type])
        return spec.size

    def check(self, buf: bytearray, start: int) -> int:
        spec = self.spec
        avail = len(buf) - start
        if spec.length_offset is not None:
            end = spec.length_offset + self._len_struct.size
            if avail < end:
                return 0
            (value,) = self._len_struct.unpack_from(buf, start + spec.length_offset)
            if value != spec.length_value:
                raise BadFrame(
                    f"bad length {value} at +{spec.length_offset}: table {spec.source} "
                    f"says {spec.length_value}"
                )
        if avail < spec.size:
            return 0
        cs_at = start + spec.checksum_offset
        (stored,) = self._cs_struct.unpack_from(buf, cs_at)
        computed = spec.checksum.compute(memoryview(buf)[start + spec.checksum_start : cs_at])
        if stored != computed:
            w = 2 * spec.checksum.size
            raise BadFrame(
                f"bad checksum {spec.checksum.name}: frame says 0x{stored:0{w}x}, "
                f"computed 0x{computed:0{w}x}"
            )
        return spec.size


class BinaryFrameCodec(TableCodec[BinaryFrameSpec, BinaryFrameFramer]):
    """Decode/encode one :class:`BinaryFrameSpec` through a message class built from it; its
    framer takes sync, length and checksum from the table."""

    framer_type = BinaryFrameFramer
    #: status bits every table of the device must name (in its [status] table)
    REQUIRED_FLAGS: ClassVar[tuple[str, ...]] = ()

    def __init__(self, spec: BinaryFrameSpec, message_type: type, name: str = "frame") -> None:
        super().__init__(spec, message_type, name)
        self._checker = BinaryFrameFramer(spec, policy=ErrorPolicy.IGNORE, name=name)
        self._layout = WireLayout(message_type)

    def wire_layout(self, frame: bytes | bytearray | memoryview) -> WireLayout:
        """Where the fields of a frame this codec's framer delivered sit: the table itself
        (:class:`~auvgw.drivers.spec.WireLayout`; such a frame always decodes)."""
        return self._layout

    @classmethod
    def parse_table(cls, doc: Mapping[str, Any], source: str) -> BinaryFrameSpec:
        return parse_binary_table(doc, source, cls.REQUIRED_FIELDS, cls.REQUIRED_FLAGS)

    @classmethod
    def message_options(cls, spec: BinaryFrameSpec) -> dict[str, Any]:
        return {"byte_order": spec.byte_order, "flags": spec.flags}

    def verify(self, frame: bytes | bytearray | memoryview) -> None:
        """Raise :class:`DecodeError` unless ``frame`` is exactly one valid frame."""
        spec = self.spec
        if len(frame) != spec.size:
            raise DecodeError(
                f"{self.name}: frame is {len(frame)} bytes; table {spec.source} says {spec.size}"
            )
        head = bytes(frame[: len(spec.sync)])
        if head != spec.sync:
            raise DecodeError(
                f"{self.name}: bytes 0..{len(head) - 1} are {head.hex()}, not the sync "
                f"{spec.sync.hex()}"
            )
        try:
            self._checker.check(bytearray(frame), 0)
        except BadFrame as exc:
            raise DecodeError(f"{self.name}: {exc.reason}") from None

    def decode(self, frame: bytes | bytearray | memoryview, verified: bool = False) -> Any:
        """The message in ``frame`` (one whole frame, checksum verified), SI units;
        ``verified``: this codec's framer has just checked size, sync and checksum."""
        if not verified:
            self.verify(frame)
        return decode_block(self.message_type, frame)

    def encode(self, msg: Any) -> bytes:
        """The frame bytes of ``msg`` (sync, length and checksum filled in)."""
        if type(msg) is not self.message_type:
            raise WireError(
                f"{self.name}: cannot encode {type(msg).__name__}; expected "
                f"{self.message_type.__name__} of table {self.spec.source}"
            )
        spec = self.spec
        buf = bytearray(spec.size)
        buf[: len(spec.sync)] = spec.sync
        if spec.length_offset is not None:
            struct.pack_into(
                spec.byte_order + WIRE_TYPES[spec.length_type],
                buf,
                spec.length_offset,
                spec.length_value,
            )
        encode_block(msg, buf)
        cs_at = spec.checksum_offset
        value = spec.checksum.compute(memoryview(buf)[spec.checksum_start : cs_at])
        buf[cs_at:] = value.to_bytes(
            spec.checksum.size, "little" if spec.checksum_byte_order == "<" else "big"
        )
        return bytes(buf)

    def status_word(self, **flags: bool) -> int:
        """The status field value with the named flags set (others clear)."""
        if self.spec.flags is None:
            raise KeyError(f"table {self.spec.source} declares no [status] bits")
        bits = dict(self.spec.flags.bits)
        unknown = sorted(set(flags) - set(bits))
        if unknown:
            raise KeyError(f"unknown flag(s) {', '.join(unknown)}; table has {', '.join(bits)}")
        return sum(1 << bits[k] for k, v in flags.items() if v)


# -- ASCII lines ------------------------------------------------------------------------------

_MAX_DIGITS = 12
_NUMBER_RE = re.compile(r"^([+-]?)([0-9]+)(?:\.([0-9]+))?$")


class LineError(DataError):
    """A line that is not valid under its table (the reason is short, for framer counters)."""


@dataclass(frozen=True)
class AsciiLineSpec:
    """An ASCII line table (see the module docstring)."""

    source: str
    start: str
    header: str
    separator: str
    terminator: str
    checksum: ChecksumKind | None
    checksum_delimiter: str
    hex_upper: bool
    max_length: int
    fields: tuple[AsciiFieldSpec, ...]


def _text(sec: _Section, key: str, expected: str, default: Any = _MISSING) -> str:
    value = sec.get(key, (str,), expected, default)
    try:
        value.encode("ascii")
    except UnicodeEncodeError:
        raise sec.error(f"{key} = {value!r}; expected ASCII text") from None
    return value


def parse_ascii_table(
    doc: Mapping[str, Any], source: str, required: Mapping[str, str] | None = None
) -> AsciiLineSpec:
    """Validate an ASCII line table (a parsed TOML document) read from ``source``."""
    top = _Section(source, "(top level)", dict(doc))
    line = top.section("line")
    fields_doc = top.get("fields", (list,), "an array of tables [[fields]]")
    top.finish()
    start = _text(line, "start", "the start character, e.g. '$'")
    header = _text(line, "header", "the constant first field, e.g. 'MS3A' ('' for none)", "")
    sep = _text(line, "separator", "the field separator, e.g. ','", ",")
    term = _text(line, "terminator", "the line end, e.g. '\\r\\n'", "\r\n")
    max_length = line.get("max_length", (int,), "the longest line in bytes (start to end)", 82)
    cs = line.section("checksum")
    line.finish()
    kinds = ["none", *CHECKSUMS]
    kind_name = cs.get("kind", (str,), f"one of {', '.join(kinds)}")
    if kind_name not in kinds:
        raise cs.error(f"unknown checksum kind {kind_name!r}; expected one of {', '.join(kinds)}")
    delim = _text(cs, "delimiter", "the character before the hex checksum, e.g. '*'", "*")
    case = cs.get("hex_case", (str,), "'upper' or 'lower'", "upper")
    if case not in ("upper", "lower"):
        raise cs.error(f"hex_case = {case!r}; expected 'upper' or 'lower'")
    cs.finish()
    if len(start) != 1:
        raise line.error(f"start = {start!r}; expected exactly one character")
    if not sep or not term:
        raise line.error("separator and terminator must not be empty")
    for what, text in (("header", header), ("separator", sep), ("delimiter", delim)):
        if start in text or (term and term in text):
            raise line.error(f"{what} {text!r} contains the start character or terminator")
    if not isinstance(fields_doc, list) or not fields_doc:
        raise top.error("fields: expected a non-empty array of tables [[fields]]")
    fields: list[AsciiFieldSpec] = []
    first = 1 if header else 0
    for i, row in enumerate(fields_doc):
        sec = _Section(source, f"fields[{i}]", row)
        common = _parse_field_common(sec)
        width = sec.get("width", (int,), "the field width in characters (0: no padding)", 0)
        decimals = sec.get("decimals", (int,), "digits after the decimal point", 0)
        sign = sec.get("sign", (str,), "'always', 'negative' or 'never'", "negative")
        bounds = [
            sec.get(k, (int, float), f"the {k}imum plausible value, in the table's units", None)
            for k in ("min", "max")
        ]
        sec.finish()
        factor = UNITS[common["table_units"]][1]
        low, high = (None if b is None else float(b) * factor for b in bounds)
        if any(b is not None and not math.isfinite(b) for b in (low, high)):
            raise sec.error(f"min = {bounds[0]!r}, max = {bounds[1]!r}; expected finite numbers")
        if low is not None and high is not None and low > high:
            raise sec.error(f"min = {bounds[0]!r} is above max = {bounds[1]!r}")
        if sign not in ("always", "negative", "never"):
            raise sec.error(f"sign = {sign!r}; expected 'always', 'negative' or 'never'")
        if not 0 <= decimals <= 9:
            raise sec.error(f"decimals = {decimals}; expected 0..9")
        digits = width - (1 if sign != "never" else 0) - (1 if decimals else 0)
        if width and not decimals + 1 <= digits <= _MAX_DIGITS:
            raise sec.error(
                f"width = {width} leaves {digits} digits; expected {decimals + 1}.."
                f"{_MAX_DIGITS} digits (width counts the sign and the decimal point)"
            )
        if width < 0:
            raise sec.error(f"width = {width}; expected >= 0")
        if any(f.name == common["name"] for f in fields):
            raise sec.error(f"duplicate field name {common['name']!r}")
        scale = common.pop("scale") * 10.0**-decimals
        add = common.pop("add")
        is_scaled = scale != 1.0 or add != 0.0
        wire_type = "u64" if sign == "never" else "s64"
        fields.append(
            AsciiFieldSpec(
                type=wire_type,
                offset=first + i,
                scale=scale if is_scaled else 1.0,
                add=add,
                invalid=None,
                size=0,
                width=width,
                decimals=decimals,
                sign=sign,
                low=low,
                high=high,
                **common,
            )
        )
    spec = AsciiLineSpec(
        source=source,
        start=start,
        header=header,
        separator=sep,
        terminator=term,
        checksum=None if kind_name == "none" else CHECKSUMS[kind_name],
        checksum_delimiter=delim,
        hex_upper=case == "upper",
        max_length=max_length,
        fields=tuple(fields),
    )
    if all(f.width for f in fields):
        longest = len(_render(spec, [f.example() for f in fields], "0" * 8))
        if longest > max_length:
            raise line.error(f"max_length = {max_length} but a full line is {longest} bytes")
    _check_required(source, fields, required or {})
    return spec


def _render(spec: AsciiLineSpec, texts: Sequence[str], checksum_hex: str | None = None) -> str:
    parts = [spec.header, *texts] if spec.header else list(texts)
    body = spec.separator.join(parts)
    if spec.checksum is None:
        return f"{spec.start}{body}{spec.terminator}"
    if checksum_hex is None:
        value = spec.checksum.compute(body.encode("ascii"))
        checksum_hex = f"{value:0{2 * spec.checksum.size}{'X' if spec.hex_upper else 'x'}}"
    else:
        checksum_hex = checksum_hex[: 2 * spec.checksum.size]
    return f"{spec.start}{body}{spec.checksum_delimiter}{checksum_hex}{spec.terminator}"


#: (table, line, raw values) of the last valid line parsed: the framer parses every line it
#: delivers and the codec's decode then asks for the same line again (the checksum and every
#: field checked once, not twice); an exact match of table object and bytes, so the result is
#: the one a new parse gives (one tuple, replaced whole: safe across reader threads)
_LAST_LINE: tuple[AsciiLineSpec | None, bytes, tuple[int, ...]] = (None, b"", ())


def parse_line(spec: AsciiLineSpec, line: bytes | bytearray | memoryview) -> list[int]:
    """Raw integer values of every field of one whole line; :class:`LineError` if invalid.

    The error text starts with its reason, the key the framer counts it under: ``line``,
    ``overlong``, ``character``, ``checksum``, ``fields``, ``header``, ``syntax`` (a field's
    text is not the table's form) or ``range`` (a value outside the table's ``min`` .. ``max``).
    """
    global _LAST_LINE
    data = bytes(line)
    last_spec, last_data, last_raws = _LAST_LINE
    if last_spec is spec and last_data == data:
        return list(last_raws)
    raws = _parse_line(spec, data)
    _LAST_LINE = (spec, data, tuple(raws))
    return raws


def _parse_line(spec: AsciiLineSpec, data: bytes) -> list[int]:
    if len(data) > spec.max_length:
        raise LineError(f"overlong line: {len(data)} bytes > max_length {spec.max_length}")
    start, term = spec.start.encode(), spec.terminator.encode()
    if not data.startswith(start) or not data.endswith(term) or len(data) < 2:
        raise LineError("line: not start character .. terminator")
    try:
        body = data[len(start) : len(data) - len(term)].decode("ascii")
    except UnicodeDecodeError as exc:
        raise LineError(f"character: byte 0x{data[len(start) + exc.start]:02x} is not ASCII",
                        offset=len(start) + exc.start) from None  # fmt: skip
    if not body.isprintable():
        raise LineError("character: control character inside the line")
    if spec.checksum is not None:
        payload, delim, hex_text = body.rpartition(spec.checksum_delimiter)
        n = 2 * spec.checksum.size
        if not delim or len(hex_text) != n:
            raise LineError(f"checksum: expected {spec.checksum_delimiter} and {n} hex digits")
        allowed = "0123456789ABCDEF" if spec.hex_upper else "0123456789abcdef"
        if any(c not in allowed for c in hex_text):
            raise LineError(f"checksum: digits {hex_text!r}")
        computed = spec.checksum.compute(payload.encode("ascii"))
        if int(hex_text, 16) != computed:
            raise LineError(f"checksum: line says {hex_text}, computed {computed:0{n}X}")
        body = payload
    parts = body.split(spec.separator)
    expected = len(spec.fields) + (1 if spec.header else 0)
    if len(parts) != expected:
        raise LineError(f"fields: {len(parts)}, expected {expected}")
    if spec.header:
        if parts[0] != spec.header:
            raise LineError(f"header: {parts[0][:16]!r}, expected {spec.header!r}")
        parts = parts[1:]
    raws: list[int] = []
    for f, text in zip(spec.fields, parts, strict=True):
        m = _NUMBER_RE.match(text)
        if m is None:
            raise LineError(f"syntax: field {f.name}: {text[:16]!r} is not a number")
        frac = m.group(3) or ""
        if len(frac) != f.decimals:
            raise LineError(
                f"syntax: field {f.name}: {text!r} has {len(frac)} decimals, table says "
                f"{f.decimals}"
            )
        if len(m.group(2)) + len(frac) > _MAX_DIGITS:
            raise LineError(f"syntax: field {f.name}: too many digits")
        raw = int(m.group(1) + m.group(2) + frac)
        try:
            canonical = f.format(raw)
        except ValueError as exc:
            raise LineError(f"syntax: field {f.name}: {exc}") from None
        if canonical != text:
            raise LineError(f"syntax: field {f.name}: {text!r}, expected {canonical!r}")
        why = f.out_of_range(raw)
        if why is not None:
            raise LineError(f"range: field {f.name}: {why}")
        raws.append(raw)
    return raws


class AsciiLineFramer(TableFramer[AsciiLineSpec]):
    """Framer on the start character .. terminator; every line is fully validated
    (checksum, field count, numbers, widths), so a delivered line always decodes (see
    :class:`TableFramer`)."""

    name = "line"

    def use_table(self, spec: AsciiLineSpec) -> int:
        self.sync = spec.start.encode()
        self._term = spec.terminator.encode()
        return spec.max_length

    def check(self, buf: bytearray, start: int) -> int:
        limit = min(len(buf), start + self.spec.max_length)
        end = buf.find(self._term, start + 1, limit)
        scan_to = end if end >= 0 else limit
        restart = buf.find(self.sync, start + 1, scan_to)
        if restart >= 0:
            raise BadFrame(f"truncated line: new start character {restart - start} bytes in")
        if end < 0:
            if len(buf) - start >= self.spec.max_length:
                raise BadFrame(f"overlong line: no terminator within {self.spec.max_length} bytes")
            return 0
        length = end + len(self._term) - start
        try:
            parse_line(self.spec, memoryview(buf)[start : start + length])
        except LineError as exc:
            raise BadFrame(str(exc)) from None
        return length


class AsciiLineCodec(TableCodec[AsciiLineSpec, AsciiLineFramer]):
    """Decode/encode one :class:`AsciiLineSpec` through a message class built from it."""

    framer_type = AsciiLineFramer

    def __init__(self, spec: AsciiLineSpec, message_type: type, name: str = "line") -> None:
        super().__init__(spec, message_type, name)

    @classmethod
    def parse_table(cls, doc: Mapping[str, Any], source: str) -> AsciiLineSpec:
        return parse_ascii_table(doc, source, cls.REQUIRED_FIELDS)

    def decode(self, line: bytes | bytearray | memoryview) -> Any:
        """The message of one whole line (checksum and form verified), decoded units."""
        try:
            raws = parse_line(self.spec, line)
        except LineError as exc:
            raise DecodeError(exc.reason, source=self.name, field=exc.field,
                              offset=exc.offset) from None  # fmt: skip
        values: dict[str, Any] = {}
        for f, raw in zip(self.spec.fields, raws, strict=True):
            values[f.name] = f.value(raw)
        return self.message_type(**values)

    def encode(self, msg: Any) -> bytes:
        """The line of ``msg``, terminator included."""
        if type(msg) is not self.message_type:
            raise WireError(
                f"{self.name}: cannot encode {type(msg).__name__}; expected "
                f"{self.message_type.__name__} of table {self.spec.source}"
            )
        texts = []
        for f in self.spec.fields:
            value = getattr(msg, f.name)
            if f.is_scaled:
                if not math.isfinite(value):
                    raise WireError(f"{self.message_type.__name__}.{f.name}: {value} is not finite")
                raw = round((value - f.add) / f.scale)
            else:
                raw = int(value)
            try:
                texts.append(f.format(raw))
            except ValueError as exc:
                raise WireError(
                    f"{self.message_type.__name__}.{f.name}: {value} {f.units} does not fit "
                    f"the table's form ({f.form()}): {exc}"
                ) from None
        return _render(self.spec, texts).encode("ascii")


class _Codec(Protocol):
    message_type: type


C = TypeVar("C", bound=_Codec)


def shipped_codec(
    build: Callable[[], C], type_name: str
) -> tuple[Callable[[], C], Callable[[str], Any]]:
    """A table-driven driver's shipped codec, read on first use (importing the driver reads no
    file): ``default_codec()`` (built once) and the module ``__getattr__`` that serves ``CODEC``
    and ``type_name``, the shipped table's message class (a site table builds its own class of
    that name). ``type_name`` joins :data:`~auvgw.drivers.spec.LAZY_TYPES`, so a bus envelope
    naming it rebuilds the class."""
    codec = functools.cache(build)
    LAZY_TYPES[type_name] = lambda: codec().message_type

    def module_getattr(name: str) -> Any:
        if name == "CODEC":
            return codec()
        if name == type_name:
            return codec().message_type
        raise AttributeError(f"no attribute {name!r}")

    return codec, module_getattr
