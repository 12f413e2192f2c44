"""Status flags: named bits of an integer field (the ``[status]`` table)."""

from __future__ import annotations

import keyword
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from auvgw.drivers.tablecodec.reading import _INT_TYPES, _NAME_RE, TableError, _Section
from auvgw.drivers.tablecodec.rows import FieldSpec


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
