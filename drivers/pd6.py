"""Teledyne RDI PD6 ASCII output (Pathfinder / Workhorse speed-log lines): framer and codec.

Every ensemble is a group of lines ``:ID,field,field,...<CR><LF>``; this module treats each line
as one message. One declarative table per sentence: each dataclass field carries a
:class:`Column` (position after the ID, width, decimals, sign, scale to SI, units, invalid
marker). Numbers are fixed-point text right-justified in their width; a decoded number is
``raw * scale`` where ``raw`` is the integer of its digits without the decimal point
(``"-2.31"`` -> -231), so ``encode(decode(line)) == line`` exactly. Decoding rejects a field
whose text is not exactly what the table prints (wrong width, sign or decimals).

PD6 carries NO checksum. The framer checks what it can, and counts each rejection under its
reason: structure (``:`` + a known two-letter ID, the table's number of commas, printable
characters and CR LF within 128 bytes: ``sentence``, ``fields``, ``character``, ``length``,
``terminator``), then every field's text against its column (``syntax``: width, sign, decimals,
status letters, a real date and time in ``:TS``) and its physically plausible values
(``range``: each column's ``low`` .. ``high`` in SI, e.g. pitch and roll within +-90 deg,
heading below 360 deg, velocities within +-10 m/s, sound speed 1400..1600 m/s). A corrupted
digit that keeps the form and a plausible value is still not detectable.

Sign convention (Pathfinder DVL Guide, Table 50): unlike PD0's 0x0600 block, PD6 velocities are
the INSTRUMENT (vehicle) moving relative to the bottom (B*) or the water mass (W*): :BI/:WI X
is + from beam 1 to beam 2, Y + from beam 4 to beam 3, Z + away from the bottom; :BS/:WS
transverse + to starboard, longitudinal + forward, normal + away from the bottom; :BE/:WE east,
north, up. Units: m/s, m, s, rad; temperature degC, salinity ppt.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import re
from typing import Any, ClassVar

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import BadFrame, DecodeError, Framer
from auvgw.drivers.spec import WireError, message

__all__ = [
    "FORMAT",
    "SENTENCES",
    "BottomEarthDistance",
    "BottomEarthVelocity",
    "BottomInstrumentVelocity",
    "BottomShipVelocity",
    "Column",
    "FieldRejected",
    "HealthMonitor",
    "Pd6Framer",
    "SystemAttitude",
    "TimingScaling",
    "WaterEarthDistance",
    "WaterEarthVelocity",
    "WaterInstrumentVelocity",
    "WaterShipVelocity",
    "column",
    "decode",
    "encode",
]

_CDEG = 0.01 * math.pi / 180.0
_BAD = -32768
MAX_LINE = 128


@dataclasses.dataclass(frozen=True)
class Column:
    """One row of a PD6 table.

    ``kind``: ``"num"`` (fixed-point number: ``width`` characters right-justified, ``decimals``
    digits after the point, a ``+``/``-`` sign always printed when ``signed``; SI value =
    integer of the digits x ``scale``; raw ``invalid`` -> NaN), ``"char"`` (one character of
    ``choices``), ``"digits"`` (exactly ``width`` decimal digits, kept as text) or ``"text"``
    (kept as text, right-justified in ``width``).
    """

    position: int
    kind: str = "num"
    width: int = 1
    decimals: int = 0
    signed: bool = False
    scale: float = 1.0
    units: str = ""
    invalid: int | None = None
    choices: str = ""
    vendor: str = ""
    #: physically plausible decoded values (SI, inclusive; None: no bound; NaN always passes)
    low: float | None = None
    high: float | None = None

    def out_of_range(self, value: Any) -> str | None:
        """Why a decoded ``value`` is not plausible, or None."""
        if not isinstance(value, float) or math.isnan(value):
            return None
        if (self.low is not None and value < self.low) or (
            self.high is not None and value > self.high
        ):
            return f"{value:.6g} {self.units} outside {self.low:.6g} .. {self.high:.6g}"
        return None

    def parse(self, text: str) -> Any:
        """Value of ``text``; raises ValueError when it is not exactly this column's format."""
        if self.kind == "char":
            if len(text) != 1 or text not in self.choices:
                raise ValueError(f"expected one of {self.choices!r}")
            return text
        if self.kind == "digits":
            if len(text) != self.width or not text.isdigit():
                raise ValueError(f"expected {self.width} digits")
            return text
        if self.kind == "text":
            value = text.strip(" ")
            if text != value.rjust(self.width) or not value.isalnum():
                raise ValueError(f"expected text right-justified in {self.width} characters")
            return value
        m = _number_re(self.decimals).fullmatch(text)
        if m is None:
            raise ValueError(f"expected a number with {self.decimals} decimals")
        sign, digits = m.group(1), m.group(2) + (m.group(3) or "")
        raw = int(digits)
        if sign == "-":
            raw = -raw
        number: float
        if self.invalid is not None and raw == self.invalid:
            number = math.nan
        elif raw == 0 and sign == "-":
            number = -0.0
        else:
            number = raw * self.scale
        if self.format(number) != text:
            raise ValueError(f"not in the table's format ({self.describe()})")
        return number

    def format(self, value: Any) -> str:
        """The text of ``value`` in this column's format."""
        if self.kind == "char":
            if not isinstance(value, str) or len(value) != 1 or value not in self.choices:
                raise WireError(f"{value!r} is not one of {self.choices!r}")
            return value
        if self.kind == "digits":
            if not isinstance(value, str) or len(value) != self.width or not value.isdigit():
                raise WireError(f"{value!r} is not {self.width} digits")
            return value
        if self.kind == "text":
            return str(value).rjust(self.width)
        if isinstance(value, float) and math.isnan(value):
            if self.invalid is None:
                raise WireError("NaN but the column has no invalid marker")
            raw, negative = self.invalid, self.invalid < 0
        else:
            raw = round(value / self.scale)
            negative = raw < 0 or (raw == 0 and math.copysign(1.0, value) < 0)
        digits = str(abs(raw)).rjust(self.decimals + 1, "0")
        if self.decimals:
            digits = f"{digits[: -self.decimals]}.{digits[-self.decimals :]}"
        sign = "-" if negative else ("+" if self.signed else "")
        return (sign + digits).rjust(self.width)

    def describe(self) -> str:
        if self.kind != "num":
            return f"{self.kind} width {self.width}"
        body = "N" * (self.width - self.decimals - (1 if self.decimals else 0) - self.signed)
        body += "." + "N" * self.decimals if self.decimals else ""
        return ("±" if self.signed else "") + body


_NUMBER_RES: dict[int, re.Pattern[str]] = {}


def _number_re(decimals: int) -> re.Pattern[str]:
    pat = _NUMBER_RES.get(decimals)
    if pat is None:
        frac = rf"\.(\d{{{decimals}}})" if decimals else "()"
        pat = _NUMBER_RES[decimals] = re.compile(rf" *([+-]?)(\d+){frac}")
    return pat


def column(
    position: int,
    width: int = 1,
    decimals: int = 0,
    *,
    kind: str = "num",
    signed: bool = False,
    scale: float = 1.0,
    units: str = "",
    invalid: int | None = None,
    choices: str = "",
    vendor: str = "",
    low: float | None = None,
    high: float | None = None,
) -> Any:
    """Declare a dataclass field as column ``position`` (1 = first field after the ID);
    ``low`` / ``high``: the plausible decoded values (SI)."""
    c = Column(
        position, kind, width, decimals, signed, scale, units, invalid, choices, vendor, low, high
    )
    return dataclasses.field(metadata={"pd6": c})


def _columns(cls: type) -> list[tuple[str, Column]]:
    cached = cls.__dict__.get("__pd6_columns__")
    if cached is None:
        cached = sorted(
            ((f.name, f.metadata["pd6"]) for f in dataclasses.fields(cls) if "pd6" in f.metadata),
            key=lambda r: r[1].position,
        )
        if [c.position for _, c in cached] != list(range(1, len(cached) + 1)):
            raise TypeError(f"{cls.__name__}: PD6 columns must be numbered 1..n")
        cls.__pd6_columns__ = cached  # type: ignore[attr-defined]
    return cached


#: plausible velocity magnitude (m/s): a Pathfinder's velocity range is +-10 m/s
_VMAX = 10.0


def _velocity(position: int, vendor: str) -> Any:
    return column(
        position, 6, signed=True, scale=1e-3, units="m/s", invalid=_BAD,
        vendor=vendor + ", mm/s", low=-_VMAX, high=_VMAX,
    )  # fmt: skip


def _status(position: int) -> Any:
    return column(position, kind="char", choices="AV", vendor="Status (A = good, V = bad)")


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


@message
class SystemAttitude:
    """``:SA,±PP.PP,±RR.RR,HHH.HH`` attitude, rad (heading 0..2pi)."""

    SENTENCE: ClassVar[str] = "SA"
    TYPE: ClassVar[str] = "pd6.SA"

    pitch: float = column(
        1, 6, 2, signed=True, scale=_CDEG, units="rad", vendor="Pitch, deg",
        low=-9000 * _CDEG, high=9000 * _CDEG,
    )  # fmt: skip
    roll: float = column(
        2, 6, 2, signed=True, scale=_CDEG, units="rad", vendor="Roll, deg",
        low=-9000 * _CDEG, high=9000 * _CDEG,
    )  # fmt: skip
    heading: float = column(
        3, 6, 2, scale=_CDEG, units="rad", vendor="Heading, deg", low=0.0, high=35999 * _CDEG
    )


@message
class TimingScaling:
    """``:TS,YYMMDDHHmmsshh,SS.S,±TT.T,DDDD.D,CCCC.C,BBB`` time, environment and BIT code."""

    SENTENCE: ClassVar[str] = "TS"
    TYPE: ClassVar[str] = "pd6.TS"

    timestamp: str = column(1, 14, kind="digits", vendor="YYMMDDHHmmsshh")
    salinity: float = column(
        2, 4, 1, scale=0.1, units="ppt", vendor="Salinity, ppt", low=0.0, high=45.0
    )
    temperature: float = column(
        3, 5, 1, signed=True, scale=0.1, units="degC", vendor="Temperature, C", low=-5.0,
        high=45.0,
    )  # fmt: skip
    depth: float = column(
        4, 6, 1, scale=0.1, units="m", vendor="Depth of transducer face, m", low=0.0, high=11000.0
    )
    speed_of_sound: float = column(
        5, 6, 1, scale=0.1, units="m/s", vendor="Speed of sound", low=1400.0, high=1600.0
    )
    bit: str = column(
        6, 3, kind="text", vendor="BIT result: number of errors then the 2-digit error code"
    )

    @property
    def device_time(self) -> dt.datetime | None:
        """The timestamp as a datetime (UTC assumed, years < 80 are 20xx); None if invalid."""
        yy, mo, dd, hh, mi, ss, cs = (int(self.timestamp[i : i + 2]) for i in range(0, 14, 2))
        try:
            return dt.datetime(
                (2000 if yy < 80 else 1900) + yy, mo, dd, hh, mi, ss, cs * 10000, tzinfo=dt.UTC
            )
        except ValueError:
            return None


@dataclasses.dataclass(frozen=True, eq=False)
class _InstrumentVelocity:
    """``:?I,±XXXXX,±YYYYY,±ZZZZZ,±EEEEE,S`` instrument-frame velocity of the instrument, m/s."""

    x: float = _velocity(1, "X (+ = Bm1 -> Bm2 xdcr movement)")
    y: float = _velocity(2, "Y (+ = Bm4 -> Bm3 xdcr movement)")
    z: float = _velocity(3, "Z (+ = transducer movement away from bottom)")
    error: float = _velocity(4, "Error velocity")
    status: str = _status(5)


@dataclasses.dataclass(frozen=True, eq=False)
class _ShipVelocity:
    """``:?S,±TTTTT,±LLLLL,±NNNNN,S`` ship-frame velocity of the ship, m/s."""

    transverse: float = _velocity(1, "Transverse (+ = Port -> Stbd ship movement)")
    longitudinal: float = _velocity(2, "Longitudinal (+ = Aft -> Fwd ship movement)")
    normal: float = _velocity(3, "Normal (+ = ship movement away from bottom)")
    status: str = _status(4)


@dataclasses.dataclass(frozen=True, eq=False)
class _EarthVelocity:
    """``:?E,±EEEEE,±NNNNN,±UUUUU,S`` earth-frame (ENU) velocity of the instrument, m/s."""

    east: float = _velocity(1, "East (+ = DVL movement to east)")
    north: float = _velocity(2, "North (+ = DVL movement to north)")
    up: float = _velocity(3, "Upward (+ = DVL movement to surface)")
    status: str = _status(4)


@dataclasses.dataclass(frozen=True, eq=False)
class _EarthDistance:
    """``:?D,±EEEEEEEE.EE,±NNNNNNNN.NN,±UUUUUUUU.UU,DDDD.DD,TTT.TT`` distance made good (ENU, m),
    range to the bottom (m) and time since the last good velocity (s)."""

    east: float = column(1, 12, 2, signed=True, scale=0.01, units="m", vendor="East distance")
    north: float = column(2, 12, 2, signed=True, scale=0.01, units="m", vendor="North distance")
    up: float = column(3, 12, 2, signed=True, scale=0.01, units="m", vendor="Upward distance")
    range_to_bottom: float = column(
        4, 7, 2, scale=0.01, units="m", vendor="Range to bottom", low=0.0, high=1000.0
    )
    time_since_good: float = column(
        5, 6, 2, scale=0.01, units="s", vendor="Time since last good-velocity estimate"
    )


@message
class WaterInstrumentVelocity(_InstrumentVelocity):
    """``:WI`` water-mass, instrument-referenced velocity (instrument relative to the water)."""

    SENTENCE: ClassVar[str] = "WI"
    TYPE: ClassVar[str] = "pd6.WI"


@message
class BottomInstrumentVelocity(_InstrumentVelocity):
    """``:BI`` bottom-track, instrument-referenced velocity (instrument over the bottom)."""

    SENTENCE: ClassVar[str] = "BI"
    TYPE: ClassVar[str] = "pd6.BI"


@message
class WaterShipVelocity(_ShipVelocity):
    """``:WS`` water-mass, ship-referenced velocity (ship relative to the water)."""

    SENTENCE: ClassVar[str] = "WS"
    TYPE: ClassVar[str] = "pd6.WS"


@message
class BottomShipVelocity(_ShipVelocity):
    """``:BS`` bottom-track, ship-referenced velocity (ship over the bottom)."""

    SENTENCE: ClassVar[str] = "BS"
    TYPE: ClassVar[str] = "pd6.BS"


@message
class WaterEarthVelocity(_EarthVelocity):
    """``:WE`` water-mass, earth-referenced velocity (instrument relative to the water)."""

    SENTENCE: ClassVar[str] = "WE"
    TYPE: ClassVar[str] = "pd6.WE"


@message
class BottomEarthVelocity(_EarthVelocity):
    """``:BE`` bottom-track, earth-referenced velocity (instrument over the bottom)."""

    SENTENCE: ClassVar[str] = "BE"
    TYPE: ClassVar[str] = "pd6.BE"


@message
class WaterEarthDistance(_EarthDistance):
    """``:WD`` water-mass, earth-referenced distance made good."""

    SENTENCE: ClassVar[str] = "WD"
    TYPE: ClassVar[str] = "pd6.WD"


@message
class BottomEarthDistance(_EarthDistance):
    """``:BD`` bottom-track, earth-referenced distance made good and range to the bottom."""

    SENTENCE: ClassVar[str] = "BD"
    TYPE: ClassVar[str] = "pd6.BD"


@message
class HealthMonitor:
    """``:HM,A,B,AAAA,BBBB,VV.VVV,C.CCC,RR.RRR`` system health (Pathfinder PD6 line 11): leak
    sensor states (G good, L leak, D disconnected) and counts, transmit voltage (V), current (A),
    transducer impedance (ohm)."""

    SENTENCE: ClassVar[str] = "HM"
    TYPE: ClassVar[str] = "pd6.HM"

    leak_a: str = column(1, kind="char", choices="GLD", vendor="Leak sensor A status")
    leak_b: str = column(2, kind="char", choices="GLD", vendor="Leak sensor B status")
    leak_a_count: float = column(3, 4, units="counts", vendor="Leak A count")
    leak_b_count: float = column(4, 4, units="counts", vendor="Leak B count")
    tx_voltage: float = column(5, 6, 3, scale=1e-3, units="V", vendor="Transmit voltage")
    tx_current: float = column(6, 5, 3, scale=1e-3, units="A", vendor="Transmit current")
    impedance: float = column(7, 6, 3, scale=1e-3, units="ohm", vendor="Transducer impedance")


#: sentence ID -> table
SENTENCES: dict[str, type] = {
    cls.SENTENCE: cls
    for cls in (
        SystemAttitude,
        TimingScaling,
        WaterInstrumentVelocity,
        WaterShipVelocity,
        WaterEarthVelocity,
        WaterEarthDistance,
        BottomInstrumentVelocity,
        BottomShipVelocity,
        BottomEarthVelocity,
        BottomEarthDistance,
        HealthMonitor,
    )
}
_COMMAS = {sid: len(_columns(cls)) for sid, cls in SENTENCES.items()}
_ALLOWED = frozenset(b"0123456789+-. ,ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz")


# --------------------------------------------------------------------------------------------
# Codec
# --------------------------------------------------------------------------------------------


class FieldRejected(DecodeError):
    """A PD6 field whose text is not its column's form (``reason`` ``syntax``) or whose value
    is not plausible (``range``)."""

    def __init__(self, reason: str, text: str) -> None:
        super().__init__(text)
        self.reason = reason


def decode(line: bytes | bytearray | memoryview) -> Any:
    """Decode one PD6 line (``:`` to CR LF inclusive) into its sentence's message.

    Raises :class:`DecodeError` naming the sentence, field and byte offset when the line does not
    match its table exactly (:class:`FieldRejected` when a field's text or value is wrong).
    """
    data = bytes(line)
    if not data.startswith(b":") or not data.endswith(b"\r\n"):
        raise DecodeError("PD6: a line must start with ':' and end with CR LF")
    try:
        text = data[1:-2].decode("ascii")
    except UnicodeDecodeError as exc:
        raise DecodeError(f"PD6 byte {exc.start + 1}: not ASCII") from None
    parts = text.split(",")
    sid = parts[0]
    cls = SENTENCES.get(sid)
    if cls is None:
        raise DecodeError(f"PD6 byte 1: unknown sentence ':{sid}'")
    cols = _columns(cls)
    if len(parts) != len(cols) + 1:
        raise DecodeError(f"PD6 :{sid}: {len(parts) - 1} fields, the table has {len(cols)}")
    values = {}
    pos = 1 + len(sid) + 1
    for (name, col), part in zip(cols, parts[1:], strict=True):
        where = f"PD6 :{sid} field {name} at byte {pos}: {part!r}"
        try:
            values[name] = col.parse(part)
        except ValueError as exc:
            raise FieldRejected("syntax", f"{where}: {exc}") from None
        why = col.out_of_range(values[name])
        if why is not None:
            raise FieldRejected("range", f"{where}: {why}")
        pos += len(part) + 1
    msg = cls(**values)
    if isinstance(msg, TimingScaling) and msg.device_time is None:
        raise FieldRejected("syntax", f"PD6 :TS field timestamp at byte 4: {msg.timestamp!r}: "
                            "not a date and time")  # fmt: skip
    return msg


def encode(msg: Any) -> bytes:
    """The PD6 line of ``msg`` (``:ID,...`` with CR LF)."""
    cls = type(msg)
    sid = getattr(cls, "SENTENCE", None)
    if sid not in SENTENCES:
        raise WireError(f"{cls.__name__} is not a PD6 sentence")
    fields = []
    for name, col in _columns(cls):
        try:
            fields.append(col.format(getattr(msg, name)))
        except WireError as exc:
            raise WireError(f"{cls.__name__}.{name}: {exc}") from None
    return f":{sid},{','.join(fields)}\r\n".encode("ascii")


class Pd6Framer(Framer):
    """PD6 lines out of a byte stream: ``:`` + known ID ... CR LF, structure checked (PD6 has no
    checksum): the sentence's number of commas, printable characters only, at most
    :data:`MAX_LINE` bytes."""

    name = "pd6"
    sync = b":"
    max_frame_size = MAX_LINE

    def check(self, buf: bytearray, start: int) -> int:
        avail = len(buf) - start
        if avail < 3:
            return 0
        sid = bytes(buf[start + 1 : start + 3]).decode("latin-1")
        if sid not in SENTENCES:
            raise BadFrame(f"sentence: {sid!r} is not a PD6 sentence ID")
        end = buf.find(b"\r\n", start + 3, start + MAX_LINE)
        stop = end if end >= 0 else min(len(buf), start + MAX_LINE)
        lf = buf.find(b"\n", start + 3, stop)
        if lf >= 0:  # a line ending without CR: cannot become valid by waiting
            raise BadFrame(f"terminator: LF without CR at byte {lf - start}")
        if end < 0:
            if avail >= MAX_LINE:
                raise BadFrame(f"length: no CR LF within {MAX_LINE} bytes")
            return 0
        body = buf[start + 3 : end]
        if not set(body) <= _ALLOWED:
            raise BadFrame("character: not allowed in a PD6 line (':' of a next line?)")
        if body.count(b",") != _COMMAS[sid]:
            raise BadFrame(f"fields: {body.count(b',')} for :{sid}, the table has {_COMMAS[sid]}")
        try:  # no checksum: every field's form and value is the only integrity there is
            decode(buf[start : end + 2])
        except DecodeError as exc:  # FieldRejected says syntax or range; the rest is syntax
            raise BadFrame(f"{getattr(exc, 'reason', 'syntax')}: {exc}") from None
        return end + 2 - start


FORMAT = Format.one_per_frame(
    "pd6",
    "Teledyne RDI PD6 ASCII lines (:SA :TS :BI :BS :BE :BD ...)",
    Pd6Framer,
    decode,
    encode,
)
