"""Fixed-size binary frame tables (:class:`BinaryFrameSpec`), their framer and codec."""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from auvgw.drivers.framing import BadFrame, DecodeError, ErrorPolicy
from auvgw.drivers.spec import (
    WIRE_TYPES,
    WireError,
    WireLayout,
    decode_block,
    encode_block,
)
from auvgw.drivers.tablecodec.checksums import CHECKSUMS, ChecksumKind
from auvgw.drivers.tablecodec.codec import TableCodec, TableFramer
from auvgw.drivers.tablecodec.flags import FlagsSpec, _parse_flags
from auvgw.drivers.tablecodec.reading import _INT_TYPES, TableError, _int_limits, _Section
from auvgw.drivers.tablecodec.rows import FieldSpec, _check_required, _parse_field_common


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
