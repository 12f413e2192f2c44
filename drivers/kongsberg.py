"""Kongsberg EM datagrams: XYZ 88 ('X') and Depth ('D') decoded, every other type kept raw.

The multibeam of this project (a GeoSwath-class swath bathymetry system) publishes its real-time
bathymetry as Kongsberg EM depth datagrams; see ``docs/protocols/kongsberg.md`` for the layout,
units, axes and sources. Every datagram, as stored in ``.all`` files and sent on the network::

    u32 length (bytes that follow this field, always even)
    STX 0x02 | u8 type | u16 EM model | u32 date YYYYMMDD | u32 ms since midnight
    | u16 ping counter | u16 serial number | ... body ... | [spare] | ETX 0x03 | u16 checksum

The checksum is the sum, modulo 65536, of the bytes between STX and ETX (both excluded): from the
type byte through the last spare byte. Little endian (the format allows big endian for some older
models; this codec reads and writes little endian only, a big-endian stream fails the length
check).

Beam axes (Kongsberg vessel frame, origin at the transmit transducer): x forward (alongtrack),
y starboard (acrosstrack), z down (depth). Angles are decoded to radians, sound speed to m/s,
distances to m, reflectivity in dB, frequencies in Hz, time of day in s.

Tables: one :func:`~auvgw.drivers.spec.message` table per header (offsets from the first byte of
the length field) and one per beam record (offsets inside one record; the records are walked as a
numpy structured array, so the per-beam values come out as read-only arrays of ``n_beams``).
The Depth datagram scales its beam depth and distances by resolutions carried in its own header
and stores the depth unsigned on EM 120 / EM 300; its beam table is therefore built per
(z resolution, xy resolution, signedness) by :func:`depth_beam_table` (bounded cache), so decoded
values are metres and :func:`~auvgw.drivers.spec.raw_value` still gives the wire counts.
"""

from __future__ import annotations

import datetime as _dt
import functools
import math
import re
import struct
from collections.abc import Collection, Mapping
from typing import Any, ClassVar

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import BadFrame, DecodeError, ErrorPolicy, Framer
from auvgw.drivers.spec import (
    TYPE_FACTORIES,
    Plan,
    WireError,
    decode_block,
    encode_block,
    message,
    plan,
    raw_value,
    wire,
)

__all__ = [
    "DATAGRAM_TYPES",
    "DEFAULT_MODEL",
    "FORMAT",
    "KNOWN_TYPES",
    "XYZ88",
    "Depth",
    "DepthBeams",
    "DepthTrailer",
    "KongsbergDatagram",
    "KongsbergFramer",
    "XYZ88Beams",
    "XYZ88Trailer",
    "check_datagram",
    "checksum",
    "datagram_from_packet",
    "decode",
    "depth_beam_table",
    "encode",
    "make_depth",
    "make_xyz88",
    "split_time",
]

STX = 0x02
ETX = 0x03
#: smallest length field: 16 header bytes (STX .. serial) + ETX + checksum = 19, made even
MIN_LENGTH = 20
#: bytes from the first byte of the length field to the end of the common header (serial number)
COMMON_SIZE = 20
#: a sender that has no EM model number of its own (the emulated GeoSwath) declares an EM 2040
DEFAULT_MODEL = 2040
#: EM models whose Depth ('D') datagram carries the beam depth unsigned (all others: signed)
UNSIGNED_DEPTH_MODELS = frozenset({120, 300})

XYZ88_ID = 0x58
DEPTH_ID = 0x44
XYZ88_BEAMS_AT = 40
XYZ88_BEAM_SIZE = 20
DEPTH_BEAMS_AT = 32
DEPTH_BEAM_SIZE = 16
#: no-detection code of XYZ 88 detection info: bit 7 (invalid) + bits 4-6 = 4 (no data, all zero)
NO_DETECTION = 0x80 | (4 << 4)

_DEG = math.pi / 180.0
_MS_PER_DAY = 86_400_000
_EPOCH_ORDINAL = _dt.date(1970, 1, 1).toordinal()

#: datagram type byte -> name (EM Series datagram formats, Rev. U, and MB-System's EM readers)
DATAGRAM_TYPES: Mapping[int, str] = {
    0x30: "PU ID output",
    0x31: "PU status output",
    0x33: "Extra parameters",
    0x41: "Attitude",
    0x42: "PU BIST result",
    0x43: "Clock",
    0x44: "Depth",
    0x45: "Single beam echo sounder depth",
    0x46: "Raw range and beam angle (F)",
    0x47: "Surface sound speed",
    0x48: "Heading",
    0x49: "Installation parameters (start)",
    0x4A: "Mechanical transducer tilt",
    0x4B: "Central beams echogram",
    0x4E: "Raw range and angle 78",
    0x4F: "Quality factor",
    0x50: "Position",
    0x52: "Runtime parameters",
    0x53: "Seabed image",
    0x54: "Tide",
    0x55: "Sound speed profile",
    0x56: "Sound speed profile (old)",
    0x57: "SSP output",
    0x58: "XYZ 88",
    0x59: "Seabed image data 89",
    0x65: "Raw range and beam angle (e)",
    0x66: "Raw range and beam angle (f)",
    0x68: "Depth (pressure) or height",
    0x69: "Installation parameters (stop)",
    0x6B: "Water column",
    0x6C: "Extra detections",
    0x6E: "Network attitude velocity",
    0x70: "Installation parameters (remote)",
    0x73: "Sound speed profile (remote)",
}
#: the type bytes :class:`KongsbergFramer` accepts by default
KNOWN_TYPES = frozenset(DATAGRAM_TYPES)


# -- checksum and datagram checks ------------------------------------------------------------------
def checksum(buf: bytes | bytearray | memoryview, start: int = 0, end: int | None = None) -> int:
    """Kongsberg checksum of a whole datagram ``buf[start:end]`` (starting at its length field):
    the sum of the bytes after STX up to, not including, ETX, modulo 65536."""
    end = len(buf) if end is None else end
    n = end - start - 8  # minus length field, STX, ETX, checksum
    if n <= 0:
        return 0
    view = np.frombuffer(buf, dtype=np.uint8, count=n, offset=start + 5)
    total = int(view.sum(dtype=np.uint64))
    del view  # release the buffer export before a bytearray caller resizes
    return total & 0xFFFF


def _check(
    buf: bytes | bytearray, start: int, max_size: int, types: frozenset[int] | None
) -> int:
    """Total size of the valid datagram at ``buf[start]`` (length field first); 0 if incomplete.

    Raises :class:`BadFrame` with a reason whose first word names the failed check.
    """
    avail = len(buf) - start
    if avail < 6:
        return 0
    (length,) = struct.unpack_from("<I", buf, start)
    if length < MIN_LENGTH or length & 1 or length + 4 > max_size:
        raise BadFrame(f"length {length} invalid (must be even, {MIN_LENGTH}..{max_size - 4})")
    if buf[start + 4] != STX:
        raise BadFrame(f"STX missing: 0x{buf[start + 4]:02x} at byte 4")
    kind = buf[start + 5]
    if types is not None and kind not in types:
        raise BadFrame(f"type 0x{kind:02x} unknown")
    total = length + 4
    if avail < total:
        return 0
    end = start + total
    if buf[end - 3] != ETX:
        raise BadFrame(f"ETX missing: 0x{buf[end - 3]:02x} at byte {total - 3}")
    (want,) = struct.unpack_from("<H", buf, end - 2)
    got = checksum(buf, start, end)
    if got != want:
        raise BadFrame(f"checksum 0x{got:04x} computed, 0x{want:04x} on the wire")
    return total


def check_datagram(
    data: bytes | bytearray,
    max_size: int = Framer.max_frame_size,
    types: Collection[int] | None = None,
) -> None:
    """Verify that ``data`` is exactly one datagram (length, STX, type, ETX, checksum).

    Raises :class:`~auvgw.drivers.framing.BadFrame` naming the failed check.
    """
    allowed = frozenset(types) if types is not None else None
    total = _check(data, 0, max_size, allowed)
    if total == 0:
        raise BadFrame(f"truncated: {len(data)} bytes, datagram incomplete")
    if total != len(data):
        raise BadFrame(f"length field says {total} bytes, packet holds {len(data)}")


def datagram_from_packet(packet: bytes | bytearray) -> bytes:
    """One UDP packet -> the canonical datagram (with its u32 length prefix), verified.

    Accepts both network forms: the ``.all`` form (length first) and the form that starts at STX
    (datagrams forwarded by SIS carry no length field). Raises
    :class:`~auvgw.drivers.framing.BadFrame` if the packet is not one valid datagram.
    """
    data = bytes(packet)
    prefixed = (
        len(data) >= 6
        and data[4] == STX
        and struct.unpack_from("<I", data, 0)[0] + 4 == len(data)
    )
    if not prefixed and data[:1] == bytes([STX]):
        data = struct.pack("<I", len(data)) + data
    check_datagram(data)
    return data


# -- device time -----------------------------------------------------------------------------------
def split_time(t: float) -> tuple[int, float]:
    """UTC POSIX time (s) -> (date YYYYMMDD, time since midnight in s rounded to the ms)."""
    days, ms = divmod(round(t * 1000.0), _MS_PER_DAY)
    d = _dt.date.fromordinal(_EPOCH_ORDINAL + days)
    return d.year * 10000 + d.month * 100 + d.day, ms / 1000.0


def _device_time(date: int, seconds: float) -> float:
    try:
        day = _dt.date(date // 10000, date // 100 % 100, date % 100)
    except ValueError:
        return math.nan
    return (day.toordinal() - _EPOCH_ORDINAL) * 86400.0 + seconds


# -- tables ----------------------------------------------------------------------------------------
@message
class CommonHeader:
    """The header every EM datagram starts with (offsets from the first byte of the length field;
    bytes 0-3 length, 4 STX and 5 type are structural and written by :func:`encode`)."""

    model: int = wire("u16", 6, vendor="EM model number", doc="e.g. 2040 = EM 2040")
    date: int = wire("u32", 8, units="YYYYMMDD", vendor="Date", doc="year*10000+month*100+day, UTC")
    time_since_midnight: float = wire(
        "u32", 12, scale=1e-3, units="s", vendor="Time since midnight in milliseconds", doc="UTC"
    )
    counter: int = wire(
        "u16", 16, vendor="Ping counter", doc="ping counter (depth datagrams) or sequential counter"
    )
    serial: int = wire("u16", 18, vendor="System serial number")

    @property
    def device_time(self) -> float:
        """Device clock as UTC POSIX time (s); NaN when the date field is not a calendar date."""
        return _device_time(self.date, self.time_since_midnight)


@message
class XYZ88Beams:
    """XYZ 88 beam records: 20 bytes a beam, offsets inside one record, arrays of ``n_beams``.

    Axes from the transmit transducer: ``along`` x forward, ``across`` y starboard, ``depth`` z
    down (heave, roll, pitch, sound speed and ray bending applied by the sonar).
    """

    TYPE: ClassVar[str] = "XYZ88Beams"

    depth: np.ndarray = wire(
        "f32", 0, shape=("n_beams",), units="m", vendor="Depth (z) from transmit transducer",
        doc="z, positive down",
    )
    across: np.ndarray = wire(
        "f32", 4, shape=("n_beams",), units="m", vendor="Acrosstrack distance (y)",
        doc="y, positive starboard",
    )
    along: np.ndarray = wire(
        "f32", 8, shape=("n_beams",), units="m", vendor="Alongtrack distance (x)",
        doc="x, positive forward",
    )
    detection_window: np.ndarray = wire(
        "u16", 12, shape=("n_beams",), units="samples", vendor="Detection window length"
    )
    quality: np.ndarray = wire(
        "u8", 14, shape=("n_beams",), vendor="Quality factor",
        doc="250 * sd(range) / range, 0-254",
    )
    incidence_adjustment: np.ndarray = wire(
        "s8", 15, shape=("n_beams",), scale=0.1 * _DEG, units="rad",
        vendor="Beam incidence angle adjustment (IBA) in 0.1 deg",
        doc="incidence re horizontal = atan(z/|y|) + IBA; positive when bending towards bottom",
    )
    detection_info: np.ndarray = wire(
        "u8", 16, shape=("n_beams",), vendor="Detection information",
        doc="bit 7 = 0 valid (bits 0-3: 0 amplitude, 1 phase detect); bit 7 = 1 invalid "
        "(bits 4-6: 0 normal, 1 interpolated, 2 estimated, 3 rejected, 4 no detection)",
    )
    cleaning: np.ndarray = wire(
        "s8", 17, shape=("n_beams",), vendor="Real time cleaning information",
        doc="bit 7 set: beam flagged out, bits 0-6 the reason",
    )
    reflectivity: np.ndarray = wire(
        "s16", 18, shape=("n_beams",), scale=0.1, units="dB", vendor="Reflectivity (BS) in 0.1 dB"
    )

    @property
    def n_beams(self) -> int:
        """Number of beam records."""
        return len(self.depth)

    @property
    def valid(self) -> np.ndarray:
        """True where the beam holds a valid detection (detection info bit 7 clear)."""
        return (np.asarray(self.detection_info) & 0x80) == 0


@message
class XYZ88Trailer:
    """XYZ 88 bytes after the beam records, before ETX (offset from the end of the records)."""

    TYPE: ClassVar[str] = "XYZ88Trailer"

    spare: int = wire("u8", 0, vendor="Spare (always 0)")


@message
class XYZ88(CommonHeader):
    """XYZ 88 datagram ('X', 0x58): one ping's soundings in metres re the transmit transducer.

    Header at offsets 20-39 (heading, sound speed, transducer depth, beam counts, sampling
    frequency, scanning info, 3 spare bytes), then ``n_beams`` 20-byte records, a spare byte,
    ETX and checksum: 44 + 20 * n_beams bytes in all.
    """

    TYPE: ClassVar[str] = "XYZ88"
    TYPE_ID: ClassVar[int] = XYZ88_ID

    heading: float = wire(
        "u16", 20, scale=0.01 * _DEG, units="rad", vendor="Heading of vessel in 0.01 deg",
        doc="clockwise from true north",
    )
    sound_speed: float = wire(
        "u16", 22, scale=0.1, units="m/s", vendor="Sound speed at transducer in dm/s"
    )
    transducer_depth: float = wire(
        "f32", 24, units="m", vendor="Transmit transducer depth re water level at time of ping",
        doc="add to beam depths for depths re the water level",
    )
    n_beams: int = wire("u16", 28, vendor="Number of beams in datagram")
    n_valid: int = wire("u16", 30, vendor="Number of valid detections")
    sampling_frequency: float = wire("f32", 32, units="Hz", vendor="Sampling frequency in Hz")
    scanning_info: int = wire("u8", 36, vendor="Scanning info", doc="EM 2040 only; 0 = no scanning")
    spare: bytes = wire("bytes", 37, size=3, vendor="Spare")
    beams: XYZ88Beams
    trailer: XYZ88Trailer

    @property
    def xyz(self) -> np.ndarray:
        """Soundings as an (n_beams, 3) float64 array: x forward, y starboard, z down (m),
        origin at the transmit transducer."""
        b = self.beams
        return np.column_stack([b.along, b.across, b.depth]).astype(np.float64)


class DepthBeams:
    """Base of the Depth ('D') beam tables built by :func:`depth_beam_table` (16 bytes a beam)."""

    TYPE: ClassVar[str] = "DepthBeams"

    depth: np.ndarray
    across: np.ndarray
    along: np.ndarray

    @property
    def n_beams(self) -> int:
        """Number of beam records."""
        return len(self.depth)


#: Depth beam tables kept (one per resolution pair and signedness seen). The resolutions come off
#: the wire, so the cache is bounded: a flood of crafted datagrams must not grow memory (with an
#: unbounded cache 30,000 of them cost 18 kB each). A table rebuilt after eviction is a new class,
#: so messages decoded before and after compare unequal; real sonars use one or two resolutions.
DEPTH_TABLE_CACHE_SIZE = 32


@functools.lru_cache(maxsize=DEPTH_TABLE_CACHE_SIZE)
def depth_beam_table(z_resolution_cm: int, xy_resolution_cm: int, unsigned_depth: bool) -> type:
    """The Depth beam table for one header's resolutions (cm) and depth signedness (cached).

    ``depth`` scales by the z resolution, ``across``/``along`` by the x/y resolution, so their
    decoded values are metres; :func:`~auvgw.drivers.spec.raw_value` gives the wire counts.
    """
    if z_resolution_cm <= 0 or xy_resolution_cm <= 0:
        raise WireError(
            f"Depth resolutions must be positive, got z {z_resolution_cm} cm, "
            f"xy {xy_resolution_cm} cm"
        )
    z, xy = z_resolution_cm * 0.01, xy_resolution_cm * 0.01
    shape = ("n_beams",)
    rows: dict[str, Any] = {
        "depth": wire(
            "u16" if unsigned_depth else "s16", 0, shape=shape, scale=z, units="m",
            vendor=f"Depth (z) from transmit transducer in {z_resolution_cm} cm",
            doc="z, positive down; unsigned on EM 120 and EM 300",
        ),
        "across": wire(
            "s16", 2, shape=shape, scale=xy, units="m",
            vendor=f"Acrosstrack distance (y) in {xy_resolution_cm} cm",
            doc="y, positive starboard",
        ),
        "along": wire(
            "s16", 4, shape=shape, scale=xy, units="m",
            vendor=f"Alongtrack distance (x) in {xy_resolution_cm} cm", doc="x, positive forward",
        ),
        "depression": wire(
            "s16", 6, shape=shape, scale=0.01 * _DEG, units="rad",
            vendor="Beam depression angle in 0.01 deg", doc="positive down, 90 deg = vertical",
        ),
        "azimuth": wire(
            "u16", 8, shape=shape, scale=0.01 * _DEG, units="rad",
            vendor="Beam azimuth angle in 0.01 deg",
            doc="re vessel heading; raw > 35999 flags uncorrected (raw) range and angle mode",
        ),
        "range": wire(
            "u16", 10, shape=shape, units="samples", vendor="Range (one-way travel time)",
            doc="in sample periods; see the protocol page on its time unit",
        ),
        "quality": wire("u8", 12, shape=shape, vendor="Quality factor"),
        "detection_window": wire(
            "u8", 13, shape=shape, scale=4.0, units="samples",
            vendor="Length of detection window in samples/4",
        ),
        "reflectivity": wire(
            "s8", 14, shape=shape, scale=0.5, units="dB", vendor="Reflectivity (BS) in 0.5 dB"
        ),
        "beam_number": wire("u8", 15, shape=shape, vendor="Beam number", doc="1-based"),
    }
    sign = "u" if unsigned_depth else "s"
    name = f"DepthBeams_z{z_resolution_cm}cm_xy{xy_resolution_cm}cm_{sign}16"
    ns: dict[str, Any] = {
        "__annotations__": dict.fromkeys(rows, "np.ndarray"),
        "__module__": __name__,
        "__qualname__": name,
        "__doc__": f"Depth beam records, z {z_resolution_cm} cm, x/y {xy_resolution_cm} cm.",
        "TYPE": name,  # each resolution its own registered type (the base's name is shared)
        **rows,
    }
    # found by name through TYPE_FACTORIES (this cache, bounded), never held by the registry:
    # a sender choosing a new resolution per datagram must not grow memory
    return message(type(name, (DepthBeams,), ns), register=False)


_DEPTH_TABLE_NAME = re.compile(r"DepthBeams_z(\d+)cm_xy(\d+)cm_([us])16")


def _depth_table_of_name(name: str) -> type | None:
    """The Depth beam table a :func:`depth_beam_table` class name stands for (readers of
    envelopes rebuild the table from its name)."""
    m = _DEPTH_TABLE_NAME.fullmatch(name)
    if m is None or int(m[1]) == 0 or int(m[2]) == 0:
        return None
    return depth_beam_table(int(m[1]), int(m[2]), m[3] == "u")


TYPE_FACTORIES.append(_depth_table_of_name)


@message
class DepthTrailer:
    """Depth ('D') bytes after the beam records, before ETX (offset from the end of the records)."""

    TYPE: ClassVar[str] = "DepthTrailer"

    depth_offset_multiplier: int = wire(
        "s8", 0, vendor="Transducer depth offset multiplier",
        doc="transducer depth += multiplier * 65536 cm",
    )


@message
class Depth(CommonHeader):
    """Depth datagram ('D', 0x44), the older scaled-integer form of a ping's soundings.

    Header at offsets 20-31, then ``n_beams`` 16-byte records, the transducer depth offset
    multiplier, ETX and checksum: 36 + 16 * n_beams bytes in all (always even, no spare).
    """

    TYPE: ClassVar[str] = "Depth"
    TYPE_ID: ClassVar[int] = DEPTH_ID

    heading: float = wire(
        "u16", 20, scale=0.01 * _DEG, units="rad", vendor="Heading of vessel in 0.01 deg"
    )
    sound_speed: float = wire(
        "u16", 22, scale=0.1, units="m/s", vendor="Sound speed at transducer in dm/s"
    )
    transducer_depth: float = wire(
        "u16", 24, scale=0.01, units="m", vendor="Transmit transducer depth in cm",
        doc="see transducer_depth_total for the offset multiplier",
    )
    max_beams: int = wire("u8", 26, vendor="Maximum number of beams possible")
    n_beams: int = wire("u8", 27, vendor="Number of valid beams (N)")
    z_resolution: float = wire("u8", 28, scale=0.01, units="m", vendor="z resolution in cm")
    xy_resolution: float = wire("u8", 29, scale=0.01, units="m", vendor="x and y resolution in cm")
    sampling_rate: int = wire(
        "u16", 30, units="Hz", vendor="Sampling rate (f) in Hz",
        doc="EM 3000D: depth difference between the sonar heads instead",
    )
    beams: DepthBeams
    trailer: DepthTrailer

    @property
    def transducer_depth_total(self) -> float:
        """Transmit transducer depth (m) including the offset multiplier x 655.36 m."""
        return self.transducer_depth + self.trailer.depth_offset_multiplier * 655.36

    @property
    def xyz(self) -> np.ndarray:
        """Soundings as an (n_beams, 3) float64 array: x forward, y starboard, z down (m),
        origin at the transmit transducer."""
        b = self.beams
        return np.column_stack([b.along, b.across, b.depth]).astype(np.float64)


@message
class KongsbergDatagram(CommonHeader):
    """Any other datagram type: the common header decoded, the rest kept raw for exact re-encode.

    ``body`` is every byte after the serial number up to, not including, ETX (spare included).
    """

    TYPE: ClassVar[str] = "KongsbergDatagram"

    type_id: int = wire("u8", 5, vendor="Type of datagram")
    body: bytes

    @property
    def type_name(self) -> str:
        """The datagram's name from :data:`DATAGRAM_TYPES` (or "unknown 0x..")."""
        return DATAGRAM_TYPES.get(self.type_id, f"unknown 0x{self.type_id:02x}")


# -- beam records: a record table's columns (spec.Plan.columns) -----------------------------------
_ONE_BEAM = {"n_beams": 1}


def _beams(cls: type) -> Plan:
    """The plan of one beam record of table ``cls`` (rows ``shape=("n_beams",)``: one item per
    record)."""
    return plan(cls, _ONE_BEAM)


def _decode_records(cls: type, buf: bytes, base: int, n: int, itemsize: int) -> Any:
    return cls(**_beams(cls).columns(buf, base, n, itemsize, "n_beams"))


def _encode_records(records: Any, buf: bytearray, base: int, n: int, itemsize: int) -> None:
    values = {r.name: getattr(records, r.name) for r in _beams(type(records)).rows}
    _beams(type(records)).write_columns(values, buf, base, n, itemsize, "n_beams", "beams")


# -- decode / encode -------------------------------------------------------------------------------
def _structure(frame: bytes) -> None:
    if len(frame) < MIN_LENGTH + 4:
        raise DecodeError(f"datagram of {len(frame)} bytes, shorter than {MIN_LENGTH + 4}")
    (length,) = struct.unpack_from("<I", frame, 0)
    if length + 4 != len(frame):
        raise DecodeError(f"length field (byte 0) says {length + 4} bytes, frame has {len(frame)}")
    if frame[4] != STX or frame[-3] != ETX:
        raise DecodeError("STX (byte 4) or ETX (3 bytes from the end) missing")


def _expect(frame: bytes, name: str, n: int, at: int, size: int) -> None:
    if len(frame) != size:
        raise DecodeError(
            f"{name}: beam count {n} (byte offset {at}) needs {size} bytes, datagram has "
            f"{len(frame)}"
        )


def _decode_xyz88(frame: bytes) -> XYZ88:
    (n,) = struct.unpack_from("<H", frame, 28)
    end = XYZ88_BEAMS_AT + XYZ88_BEAM_SIZE * n
    _expect(frame, "XYZ88", n, 28, end + 4)
    beams = _decode_records(XYZ88Beams, frame, XYZ88_BEAMS_AT, n, XYZ88_BEAM_SIZE)
    trailer = decode_block(XYZ88Trailer, frame, base=end)
    return decode_block(XYZ88, frame, beams=beams, trailer=trailer)


def _decode_depth(frame: bytes) -> Depth:
    model, n, z_cm, xy_cm = (
        struct.unpack_from("<H", frame, 6)[0], frame[27], frame[28], frame[29],
    )
    end = DEPTH_BEAMS_AT + DEPTH_BEAM_SIZE * n
    _expect(frame, "Depth", n, 27, end + 4)
    if z_cm == 0 or xy_cm == 0:
        raise DecodeError(f"Depth: zero resolution (z {z_cm} cm at byte 28, xy {xy_cm} cm at 29)")
    table = depth_beam_table(z_cm, xy_cm, model in UNSIGNED_DEPTH_MODELS)
    beams = _decode_records(table, frame, DEPTH_BEAMS_AT, n, DEPTH_BEAM_SIZE)
    trailer = decode_block(DepthTrailer, frame, base=end)
    return decode_block(Depth, frame, beams=beams, trailer=trailer)


def decode(frame: bytes | bytearray | memoryview, verified: bool = False) -> list[Any]:
    """One datagram (from its length field to its checksum) -> [message].

    XYZ 88 and Depth decode to :class:`XYZ88` and :class:`Depth`; every other type to
    :class:`KongsbergDatagram`. The checksum is verified here too, so the function is safe on
    bytes that did not come through :class:`KongsbergFramer`, unless ``verified`` says that
    framer has just checked it. Raises :class:`~auvgw.drivers.framing.DecodeError` naming the
    field and byte offset.
    """
    data = bytes(frame)
    _structure(data)
    if not verified:
        (want,) = struct.unpack_from("<H", data, len(data) - 2)
        got = checksum(data)
        if got != want:
            raise DecodeError(f"checksum 0x{got:04x} computed, 0x{want:04x} on the wire")
    kind = data[5]
    try:
        if kind == XYZ88_ID:
            return [_decode_xyz88(data)]
        if kind == DEPTH_ID:
            return [_decode_depth(data)]
        return [decode_block(KongsbergDatagram, data, body=data[COMMON_SIZE:-3])]
    except WireError as exc:
        raise DecodeError(str(exc)) from exc


def _seal(buf: bytearray, type_id: int) -> bytes:
    struct.pack_into("<IBB", buf, 0, len(buf) - 4, STX, type_id)
    buf[-3] = ETX
    struct.pack_into("<H", buf, len(buf) - 2, checksum(buf))
    return bytes(buf)


def _check_count(msg: Any, n: int) -> None:
    if msg.n_beams != n:
        raise WireError(
            f"{type(msg).__name__}.n_beams is {msg.n_beams} but beams hold {n} records"
        )


def encode(msg: Any) -> bytes:
    """Message -> datagram bytes (length field, STX, ETX and checksum computed here)."""
    if isinstance(msg, XYZ88):
        n = msg.beams.n_beams
        _check_count(msg, n)
        end = XYZ88_BEAMS_AT + XYZ88_BEAM_SIZE * n
        buf = bytearray(end + 4)
        encode_block(msg, buf)
        _encode_records(msg.beams, buf, XYZ88_BEAMS_AT, n, XYZ88_BEAM_SIZE)
        encode_block(msg.trailer, buf, end)
        return _seal(buf, XYZ88_ID)
    if isinstance(msg, Depth):
        n = msg.beams.n_beams
        _check_count(msg, n)
        z_cm, xy_cm = raw_value(msg, "z_resolution"), raw_value(msg, "xy_resolution")
        table = depth_beam_table(z_cm, xy_cm, msg.model in UNSIGNED_DEPTH_MODELS)
        if type(msg.beams) is not table:
            raise WireError(
                f"Depth.beams is a {type(msg.beams).__name__}, the header (model {msg.model}, "
                f"z {z_cm} cm, xy {xy_cm} cm) needs {table.__name__}"
            )
        end = DEPTH_BEAMS_AT + DEPTH_BEAM_SIZE * n
        buf = bytearray(end + 4)
        encode_block(msg, buf)
        _encode_records(msg.beams, buf, DEPTH_BEAMS_AT, n, DEPTH_BEAM_SIZE)
        encode_block(msg.trailer, buf, end)
        return _seal(buf, DEPTH_ID)
    if isinstance(msg, KongsbergDatagram):
        total = COMMON_SIZE + len(msg.body) + 3
        if (total - 4) % 2:
            raise WireError(
                f"KongsbergDatagram.body of {len(msg.body)} bytes makes the length odd "
                "(append the spare byte)"
            )
        buf = bytearray(total)
        encode_block(msg, buf)
        buf[COMMON_SIZE : total - 3] = msg.body
        return _seal(buf, msg.type_id)
    raise TypeError(f"not a Kongsberg message: {type(msg).__name__}")


# -- constructors (used by the emulator) -----------------------------------------------------------
def _array(value: Any, n: int, name: str, dtype: Any = np.float64) -> np.ndarray:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=dtype), (n,)).copy()
    except ValueError as exc:
        raise ValueError(f"{name}: expected a scalar or {n} values ({exc})") from None
    arr.flags.writeable = False
    return arr


def make_xyz88(
    *,
    time: float,
    depth: Any,
    across: Any,
    along: Any,
    quality: Any = 0,
    reflectivity: Any = 0.0,
    detection_window: Any = 0,
    incidence_adjustment: Any = 0.0,
    detection_info: Any = None,
    cleaning: Any = 0,
    heading: float = 0.0,
    sound_speed: float = 1500.0,
    transducer_depth: float = 0.0,
    sampling_frequency: float = 0.0,
    scanning_info: int = 0,
    model: int = DEFAULT_MODEL,
    ping_counter: int = 0,
    serial: int = 0,
) -> XYZ88:
    """An XYZ 88 message from per-beam arrays and header values, in SI units.

    ``time`` is UTC POSIX seconds (split into date and ms since midnight); ``depth``/``across``/
    ``along`` are z down / y starboard / x forward in m from the transmit transducer (stored as
    float32); ``heading`` and ``incidence_adjustment`` in rad, ``reflectivity`` in dB,
    ``sound_speed`` in m/s. A NaN depth marks a beam without detection: its x, y, z are set to 0
    and its detection info to 0xC0 (invalid, no detection data), as the sonar does.
    ``detection_info`` defaults to 0 (valid, amplitude detect) elsewhere; ``n_valid`` is counted.
    Values are rounded to the wire resolution, so ``decode(encode(m)) == m``.
    """
    z = np.atleast_1d(np.asarray(depth, dtype=np.float64))
    n = len(z)
    missing = np.isnan(z)
    info = _array(0 if detection_info is None else detection_info, n, "detection_info", np.uint8)
    info = np.where(missing, NO_DETECTION, info).astype(np.uint8)

    def metres(v: Any, name: str) -> np.ndarray:
        arr = np.where(missing, 0.0, _array(v, n, name)).astype(np.float32)
        arr.flags.writeable = False
        return arr

    draft: XYZ88Beams = XYZ88Beams(
        depth=metres(z, "depth"),
        across=metres(across, "across"),
        along=metres(along, "along"),
        detection_window=_array(detection_window, n, "detection_window", np.uint16),
        quality=_array(quality, n, "quality", np.uint8),
        incidence_adjustment=_array(incidence_adjustment, n, "incidence_adjustment"),
        detection_info=_array(info, n, "detection_info", np.uint8),
        cleaning=_array(cleaning, n, "cleaning", np.int8),
        reflectivity=_array(reflectivity, n, "reflectivity"),
    )
    date, seconds = split_time(time)
    draft_msg = XYZ88(
        model=model, date=date, time_since_midnight=seconds, counter=ping_counter,
        serial=serial, heading=heading % (2 * math.pi), sound_speed=sound_speed,
        transducer_depth=transducer_depth, n_beams=n,
        n_valid=int(np.count_nonzero((info & 0x80) == 0)),
        sampling_frequency=sampling_frequency, scanning_info=scanning_info,
        spare=b"\x00\x00\x00", beams=draft, trailer=XYZ88Trailer(spare=0),
    )
    return decode(encode(draft_msg))[0]


def make_depth(
    *,
    time: float,
    depth: Any,
    across: Any,
    along: Any,
    depression: Any = 0.0,
    azimuth: Any = 0.0,
    range_samples: Any = 0,
    quality: Any = 0,
    detection_window: Any = 0,
    reflectivity: Any = 0.0,
    beam_number: Any = None,
    z_resolution: float = 0.01,
    xy_resolution: float = 0.01,
    heading: float = 0.0,
    sound_speed: float = 1500.0,
    transducer_depth: float = 0.0,
    max_beams: int | None = None,
    sampling_rate: int = 0,
    model: int = 3000,
    ping_counter: int = 0,
    serial: int = 0,
) -> Depth:
    """A Depth ('D') message from per-beam arrays (m, rad, dB) and header values (SI).

    Resolutions are in m (whole cm on the wire); ``transducer_depth`` beyond 655.35 m uses the
    offset multiplier. Beam numbers default to 1..n. Values are rounded to the wire resolution,
    so ``decode(encode(m)) == m``.
    """
    z = np.atleast_1d(np.asarray(depth, dtype=np.float64))
    n = len(z)
    z_cm, xy_cm = round(z_resolution * 100), round(xy_resolution * 100)
    table = depth_beam_table(z_cm, xy_cm, model in UNSIGNED_DEPTH_MODELS)
    numbers = np.arange(1, n + 1) if beam_number is None else beam_number
    draft = table(
        depth=_array(z, n, "depth"),
        across=_array(across, n, "across"),
        along=_array(along, n, "along"),
        depression=_array(depression, n, "depression"),
        azimuth=_array(azimuth, n, "azimuth"),
        range=_array(range_samples, n, "range", np.uint16),
        quality=_array(quality, n, "quality", np.uint8),
        detection_window=_array(detection_window, n, "detection_window"),
        reflectivity=_array(reflectivity, n, "reflectivity"),
        beam_number=_array(numbers, n, "beam_number", np.uint8),
    )
    multiplier, rest_cm = divmod(round(transducer_depth * 100), 65536)
    date, seconds = split_time(time)
    draft_msg = Depth(
        model=model, date=date, time_since_midnight=seconds, counter=ping_counter, serial=serial,
        heading=heading % (2 * math.pi), sound_speed=sound_speed,
        transducer_depth=rest_cm / 100, max_beams=n if max_beams is None else max_beams,
        n_beams=n, z_resolution=z_cm / 100, xy_resolution=xy_cm / 100,
        sampling_rate=sampling_rate, beams=draft,
        trailer=DepthTrailer(depth_offset_multiplier=multiplier),
    )
    return decode(encode(draft_msg))[0]


# -- framer and format -----------------------------------------------------------------------------
class KongsbergFramer(Framer):
    """Datagrams out of byte chunks of any size (files, serial, one or many UDP packets).

    Sync is STX at offset 4 (after the u32 length). A candidate must have an even length field
    in ``MIN_LENGTH .. max_frame_size - 4``, STX, a type byte in ``types`` (default
    :data:`DATAGRAM_TYPES`; ``None`` accepts any), ETX where the length puts it and a matching
    checksum. Reasons counted in ``stats.reasons``: ``length``, ``STX``, ``type``, ``ETX``,
    ``checksum``, ``truncated:``.
    """

    name = "kongsberg"
    sync = bytes([STX])
    sync_offset = 4

    def __init__(
        self,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        max_frame_size: int | None = None,
        types: Collection[int] | None = KNOWN_TYPES,
    ) -> None:
        super().__init__(policy=policy, source=source, max_frame_size=max_frame_size)
        self.types = frozenset(types) if types is not None else None

    def check(self, buf: bytearray, start: int) -> int:
        return _check(buf, start, self.max_frame_size, self.types)


FORMAT = Format(
    name="kongsberg",
    summary="a stream of Kongsberg EM datagrams (u32 length, STX, type ... ETX, u16 checksum)",
    framer=KongsbergFramer,
    decode=decode,
    encode=encode,
    decode_verified=lambda frame: decode(frame, verified=True),
)
