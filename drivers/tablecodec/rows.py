"""Field rows of a table: binary and ASCII fields, their common keys, required fields."""

from __future__ import annotations

import builtins
import keyword
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from auvgw.drivers.spec import (
    WIRE_TYPES,
    wire,
)
from auvgw.drivers.tablecodec.reading import _NAME_RE, TableError, _Section
from auvgw.drivers.tablecodec.units import UNITS


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


#: the most digits of an ASCII field (its value fits a signed 64-bit integer)
_MAX_DIGITS = 12
