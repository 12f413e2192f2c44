"""ASCII line tables (:class:`AsciiLineSpec`), their parser, framer and codec."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from auvgw.drivers.framing import BadFrame, DecodeError
from auvgw.drivers.spec import (
    WireError,
)
from auvgw.drivers.tablecodec.checksums import CHECKSUMS, ChecksumKind
from auvgw.drivers.tablecodec.codec import TableCodec, TableFramer
from auvgw.drivers.tablecodec.reading import _MISSING, _Section
from auvgw.drivers.tablecodec.rows import (
    _MAX_DIGITS,
    AsciiFieldSpec,
    _check_required,
    _parse_field_common,
)
from auvgw.drivers.tablecodec.units import UNITS
from auvgw.ground.errors import DataError

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
