"""Teledyne RDI PD0 binary ensembles (Pathfinder DVL, Workhorse, Ocean Surveyor): framer and codec.

One declarative table per data type (a :func:`~auvgw.drivers.spec.message` dataclass whose
fields carry ``wire(...)`` rows; offsets are 0-based from the first byte of the data type, i.e.
the manuals' 1-based "binary byte" minus one). The two ID bytes of each data type are written by
the codec from the class's ``ID`` and are not a table row.

Ensemble layout (Pathfinder DVL Guide, "PD0 Output Data Format", Table 32)::

    7F 7F | u16 nBytes | u8 spare | u8 N data types | N x u16 offset | data types ... | u16 checksum

``nBytes`` counts from the first 7F up to, not including, the checksum; the checksum is the sum
of those bytes modulo 65536, little endian. Data types are found only through the offset table:
a data type extends to the next offset (or to ``nBytes`` for the last one). Bytes of a data type
beyond its table are kept in the block's ``extra``; bytes after the table of the last data type
(the Workhorse's two reserved bytes before the checksum) are kept in :attr:`Ensemble.trailer`;
data types this module does not know (VmDas 0x2000, Ocean Surveyor 0x3000/0x30D8, ...) are kept
whole as :class:`RawBlock`. So ``encode(decode(frame)) == frame`` byte for byte.

Blocks shorter than their table (the Pathfinder fixed leader has no beam-angle byte, the Workhorse
variable leader stops after the Y2K clock, an Ocean Surveyor's after 60 bytes) decode with the
missing trailing fields set to ``None``; a block shorter than the table's documented core
(``MIN_SIZE``) is a :class:`~auvgw.drivers.framing.DecodeError` naming the data type, the field
and the byte offset.

:func:`decode` decodes one ensemble; :func:`decode_many` gives the same messages for a list of
ensembles (a file, a chunk of a stream) with one numpy pass per field over consecutive ensembles
that share a layout, several times faster. :func:`encode` computes the header, offsets and
checksum from the blocks.

Units: every field is SI (m, m/s, rad, Pa, V, A, ohm, s) except temperature (degrees Celsius),
salinity (ppt), counts and percentages, which keep the vendor's unit (stated per field). The raw
wire value of any field is :func:`~auvgw.drivers.spec.raw_value`.

Sign conventions (Pathfinder DVL Guide, "Special Output Data Formats"): the 0x0600 bottom-track
velocities are the *bottom moving relative to a stationary instrument*;
:attr:`BottomTrack.vehicle_velocity` negates them. The Pathfinder 0x5803 high-resolution
velocities are the *instrument moving over the bottom* (the PD6 convention) and need no negation.
The frame of both (beam, instrument, ship, earth) is the fixed leader's EX setting,
:attr:`FixedLeader.coordinate_frame`.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as dt
import math
import struct
from collections.abc import Mapping, Sequence
from enum import IntEnum
from typing import Any, ClassVar

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import BadFrame, DecodeError, Framer
from auvgw.drivers.spec import (
    Plan,
    Wire,
    WireError,
    WireLayout,
    block_size,
    encode_block,
    message,
    wire,
)
from auvgw.drivers.spec import (
    plan as table_plan,
)

__all__ = [
    "FORMAT",
    "ID_BOTTOM_TRACK",
    "ID_BT_HIGH_RES",
    "ID_BT_RANGE",
    "ID_CORRELATION",
    "ID_ECHO_INTENSITY",
    "ID_FIXED_LEADER",
    "ID_PERCENT_GOOD",
    "ID_VARIABLE_LEADER",
    "ID_VELOCITY",
    "BottomTrack",
    "BottomTrackHighRes",
    "BottomTrackRange",
    "CoordinateFrame",
    "Correlation",
    "EchoIntensity",
    "Ensemble",
    "FixedLeader",
    "Pd0Framer",
    "PercentGood",
    "RawBlock",
    "VariableLeader",
    "Velocity",
    "checksum",
    "decode",
    "decode_many",
    "encode",
    "wire_layout",
]

SYNC = b"\x7f\x7f"
HEADER_SIZE = 6

ID_FIXED_LEADER = 0x0000
ID_VARIABLE_LEADER = 0x0080
ID_VELOCITY = 0x0100
ID_CORRELATION = 0x0200
ID_ECHO_INTENSITY = 0x0300
ID_PERCENT_GOOD = 0x0400
ID_BOTTOM_TRACK = 0x0600
ID_BT_HIGH_RES = 0x5803
ID_BT_RANGE = 0x5804

_DEG = math.pi / 180.0
_CDEG = 0.01 * _DEG  # 0.01 degree in rad
_DDEG = 0.1 * _DEG  # 0.1 degree in rad
_S16_BAD = -32768
_S32_BAD = -(2**31)
_U16_NA = 0xFFFF


class CoordinateFrame(IntEnum):
    """Frame of PD0 velocities: fixed-leader EX byte (coordinate transformation), bits 3-4.

    BEAM: along beams 1-4. INSTRUMENT: X (beam 1 -> beam 2), Y (beam 4 -> beam 3), Z (toward
    the transducer face), error. SHIP: starboard, forward, mast (up), error. EARTH: east,
    north, up, error.
    """

    BEAM = 0
    INSTRUMENT = 1
    SHIP = 2
    EARTH = 3


#: ensembles up to this many bytes are summed by Python's ``sum`` (as fast as numpy's on a warm
#: core, and several times faster on a cold one: one ensemble at a time, the gateway's case);
#: larger ones by numpy
SUM_IN_PYTHON = 4096


def checksum(data: bytes | bytearray | memoryview) -> int:
    """PD0 checksum of ``data``: sum of the bytes modulo 65536."""
    if len(data) <= SUM_IN_PYTHON:
        return sum(data) & 0xFFFF
    return int(np.frombuffer(data, dtype=np.uint8).sum(dtype=np.uint64)) & 0xFFFF


# --------------------------------------------------------------------------------------------
# Tables (offsets from the first byte of the data type; bytes 0-1 are the ID)
# --------------------------------------------------------------------------------------------


@message
class FixedLeader:
    """Fixed leader 0x0000: configuration (Pathfinder 58 bytes, Workhorse 59, Ocean Surveyor 60).

    Fields beyond a short block (``beam_angle`` on a Pathfinder) are ``None``. Lengths in m,
    angles in rad, velocities in m/s.
    """

    ID: ClassVar[int] = ID_FIXED_LEADER
    TYPE: ClassVar[str] = "pd0.FixedLeader"
    MIN_SIZE: ClassVar[int] = 42

    firmware_version: int = wire("u8", 2, vendor="CPU F/W Ver.")
    firmware_revision: int = wire("u8", 3, vendor="CPU F/W Rev.")
    system_config: int = wire("u16", 4, vendor="System Configuration", doc="bit field, LSB first")
    real_sim_flag: int = wire("u8", 6, vendor="Real/Sim Flag")
    lag_length: int = wire("u8", 7, vendor="Lag Length")
    n_beams: int = wire("u8", 8, vendor="Number of Beams")
    n_cells: int = wire("u8", 9, vendor="Number of Cells (WN)")
    pings_per_ensemble: int = wire("u16", 10, vendor="Pings Per Ensemble (WP)")
    cell_size: float = wire("u16", 12, scale=0.01, units="m", vendor="Depth Cell Length (WS), cm")
    blank_after_transmit: float = wire(
        "u16", 14, scale=0.01, units="m", vendor="Blank after Transmit (WF), cm"
    )
    profiling_mode: int = wire("u8", 16, vendor="Profiling Mode (WM)")
    low_correlation_threshold: int = wire("u8", 17, units="counts", vendor="Low Corr Thresh (WC)")
    code_repeats: int = wire("u8", 18, vendor="No. Code Reps")
    percent_good_min: int = wire("u8", 19, units="%", vendor="%Gd Minimum (WG)")
    error_velocity_max: float = wire(
        "u16", 20, scale=1e-3, units="m/s", vendor="Error Velocity Maximum (WE), mm/s"
    )
    tpp_minutes: int = wire("u8", 22, units="min", vendor="TPP Minutes")
    tpp_seconds: int = wire("u8", 23, units="s", vendor="TPP Seconds")
    tpp_hundredths: int = wire("u8", 24, units="0.01 s", vendor="TPP Hundredths")
    coord_transform: int = wire(
        "u8", 25, vendor="Coord Transform (EX)",
        doc="bits 3-4 frame (see CoordinateFrame), bit 2 tilts used, bit 1 3-beam, bit 0 bin map",
    )
    heading_alignment: float = wire(
        "s16", 26, scale=_CDEG, units="rad", vendor="Heading Alignment (EA), 0.01 deg"
    )
    heading_bias: float = wire("s16", 28, scale=_CDEG, units="rad", vendor="Heading Bias (EB)")
    sensor_source: int = wire("u8", 30, vendor="Sensor Source (EZ)")
    sensors_available: int = wire("u8", 31, vendor="Sensors Available")
    bin1_distance: float = wire("u16", 32, scale=0.01, units="m", vendor="Bin 1 Distance, cm")
    transmit_pulse_length: float = wire(
        "u16", 34, scale=0.01, units="m", vendor="Xmit Pulse Length (WT), cm"
    )
    ref_layer_start: int = wire("u8", 36, units="cell", vendor="WP Ref Lyr Avg (WL) start")
    ref_layer_end: int = wire("u8", 37, units="cell", vendor="WP Ref Lyr Avg (WL) end")
    false_target_threshold: int = wire("u8", 38, units="counts", vendor="False Target Thresh (WA)")
    spare_39: int = wire("u8", 39, vendor="Spare (Pathfinder: CX setting)")
    transmit_lag_distance: float = wire(
        "u16", 40, scale=0.01, units="m", vendor="Transmit Lag Distance, cm"
    )
    cpu_board_serial: bytes = wire(
        "bytes", 42, size=8, vendor="CPU Board Serial Number (Pathfinder: spare)"
    )
    system_bandwidth: int = wire("u16", 50, vendor="System Bandwidth (WB)")
    system_power: int = wire("u8", 52, vendor="System Power (CQ) (Pathfinder: spare)")
    spare_53: int = wire("u8", 53, vendor="Spare")
    serial_number: int = wire("u32", 54, vendor="Instrument Serial Number")
    beam_angle: float | None = wire(
        "u8", 58, scale=_DEG, units="rad", vendor="Beam Angle, deg (Workhorse only)"
    )
    extra: bytes = b""

    @property
    def coordinate_frame(self) -> CoordinateFrame:
        """Frame of the velocities (EX bits 3-4)."""
        return CoordinateFrame((self.coord_transform >> 3) & 3)

    @property
    def tilts_used(self) -> bool:
        """EX bit 2: pitch and roll used in the transformation."""
        return bool(self.coord_transform & 0x04)

    @property
    def three_beam_solutions(self) -> bool:
        """EX bit 1: 3-beam solutions allowed."""
        return bool(self.coord_transform & 0x02)

    @property
    def time_per_ping(self) -> float:
        """Time between pings, s."""
        return self.tpp_minutes * 60.0 + self.tpp_seconds + self.tpp_hundredths * 0.01


@message
class VariableLeader:
    """Variable leader 0x0080 (Pathfinder 77 bytes, Workhorse 65, Ocean Surveyor 60).

    Attitude in rad (heading 0..2pi, pitch/roll signed), depth in m, pressure in Pa,
    temperature in degrees Celsius, salinity in ppt. Fields beyond a short block are ``None``.
    The Pathfinder guide marks bytes 56-65 spare; the Workhorse puts its Y2K clock at 57-64.
    """

    ID: ClassVar[int] = ID_VARIABLE_LEADER
    TYPE: ClassVar[str] = "pd0.VariableLeader"
    MIN_SIZE: ClassVar[int] = 42

    ensemble_number: int = wire("u16", 2, vendor="Ensemble Number (LSB word)")
    rtc: np.ndarray = wire(
        "u8", 4, shape=(7,), vendor="RTC", doc="year (2 digits), month, day, hour, min, s, 0.01 s"
    )
    ensemble_number_msb: int = wire("u8", 11, vendor="Ensemble # MSB")
    bit_result: int = wire("u16", 12, vendor="BIT Result")
    speed_of_sound: float = wire("u16", 14, units="m/s", vendor="Speed of Sound (EC)")
    depth: float = wire("u16", 16, scale=0.1, units="m", vendor="Depth of Transducer (ED), dm")
    heading: float = wire("u16", 18, scale=_CDEG, units="rad", vendor="Heading (EH), 0.01 deg")
    pitch: float = wire("s16", 20, scale=_CDEG, units="rad", vendor="Pitch (EP), 0.01 deg")
    roll: float = wire("s16", 22, scale=_CDEG, units="rad", vendor="Roll (ER), 0.01 deg")
    salinity: float = wire("u16", 24, units="ppt", vendor="Salinity (ES)")
    temperature: float = wire("s16", 26, scale=0.01, units="degC", vendor="Temperature (ET)")
    mpt_minutes: int = wire("u8", 28, units="min", vendor="MPT Minutes")
    mpt_seconds: int = wire("u8", 29, units="s", vendor="MPT Seconds")
    mpt_hundredths: int = wire("u8", 30, units="0.01 s", vendor="MPT Hundredths")
    heading_std: float = wire("u8", 31, scale=_DEG, units="rad", vendor="Hdg Std Dev, deg")
    pitch_std: float = wire("u8", 32, scale=_DDEG, units="rad", vendor="Pitch Std Dev, 0.1 deg")
    roll_std: float = wire("u8", 33, scale=_DDEG, units="rad", vendor="Roll Std Dev, 0.1 deg")
    adc: np.ndarray = wire("u8", 34, shape=(8,), units="counts", vendor="ADC Channels 0-7")
    error_status: int = wire("u32", 42, vendor="Error Status Word")
    reserved_46: int = wire("u16", 46, vendor="Reserved")
    pressure: float | None = wire("u32", 48, scale=10.0, units="Pa", vendor="Pressure, daPa")
    pressure_variance: float | None = wire(
        "u32", 52, scale=10.0, units="Pa", vendor="Pressure variance, daPa"
    )
    spare_56: int | None = wire("u8", 56, vendor="Spare")
    rtc_y2k: np.ndarray | None = wire(
        "u8", 57, shape=(8,), vendor="Y2K RTC (Workhorse; Pathfinder: spare)",
        doc="century, year, month, day, hour, min, s, 0.01 s",
    )
    spare_65: int | None = wire("u8", 65, vendor="Spare")
    health_status: int | None = wire("u8", 66, vendor="Health Status (Pathfinder)")
    leak_a_count: int | None = wire("u16", 67, units="counts", vendor="Leak A Count")
    leak_b_count: int | None = wire("u16", 69, units="counts", vendor="Leak B Count")
    tx_voltage: float | None = wire(
        "u16", 71, scale=1e-3, units="V", invalid=_U16_NA, vendor="Tx Voltage"
    )
    tx_current: float | None = wire(
        "u16", 73, scale=1e-3, units="A", invalid=_U16_NA, vendor="Tx Current"
    )
    transducer_impedance: float | None = wire(
        "u16", 75, scale=1e-3, units="ohm", invalid=_U16_NA, vendor="Transducer Impedance"
    )
    extra: bytes = b""

    @property
    def ensemble(self) -> int:
        """Full ensemble number (LSB word + 65536 x MSB byte)."""
        return self.ensemble_number + 65536 * self.ensemble_number_msb

    @property
    def device_time(self) -> dt.datetime | None:
        """Device clock at the ensemble (UTC assumed), from the Y2K clock when it agrees with the
        2-digit RTC, else the 2-digit RTC (years < 80 are 20xx). ``None`` if the clock is invalid.
        """
        yy, mo, dd, hh, mi, ss, cs = (int(v) for v in self.rtc)
        year = 2000 + yy if yy < 80 else 1900 + yy
        y2k = self.rtc_y2k
        if y2k is not None and int(y2k[1]) == yy and 19 <= int(y2k[0]) <= 21:
            year = int(y2k[0]) * 100 + yy
        try:
            return dt.datetime(year, mo, dd, hh, mi, ss, cs * 10000, tzinfo=dt.UTC)
        except ValueError:
            return None

    @property
    def device_time_s(self) -> float:
        """Device clock as POSIX seconds (NaN if the clock is invalid)."""
        t = self.device_time
        return math.nan if t is None else t.timestamp()


@message
class Velocity:
    """Velocity 0x0100: ``velocity[cell, beam]`` in m/s (NaN = bad, -32768 on the wire) in the
    fixed leader's coordinate frame. Water velocities are the water relative to the instrument.
    """

    ID: ClassVar[int] = ID_VELOCITY
    TYPE: ClassVar[str] = "pd0.Velocity"
    MIN_SIZE: ClassVar[int] = -1  # the whole table

    velocity: np.ndarray = wire(
        "s16", 2, shape=("n_cells", "n_beams"), scale=1e-3, units="m/s", invalid=_S16_BAD,
        vendor="Velocity, mm/s",
    )
    extra: bytes = b""


@message
class Correlation:
    """Correlation magnitude 0x0200: ``correlation[cell, beam]`` counts (0-255)."""

    ID: ClassVar[int] = ID_CORRELATION
    TYPE: ClassVar[str] = "pd0.Correlation"
    MIN_SIZE: ClassVar[int] = -1

    correlation: np.ndarray = wire(
        "u8", 2, shape=("n_cells", "n_beams"), units="counts", vendor="Correlation Magnitude"
    )
    extra: bytes = b""


@message
class EchoIntensity:
    """Echo intensity 0x0300: ``intensity[cell, beam]`` counts (about 0.45 dB per count)."""

    ID: ClassVar[int] = ID_ECHO_INTENSITY
    TYPE: ClassVar[str] = "pd0.EchoIntensity"
    MIN_SIZE: ClassVar[int] = -1

    intensity: np.ndarray = wire(
        "u8", 2, shape=("n_cells", "n_beams"), units="counts", vendor="Echo Intensity"
    )
    extra: bytes = b""


@message
class PercentGood:
    """Percent good 0x0400: ``percent_good[cell, beam]`` in % (meaning depends on the frame)."""

    ID: ClassVar[int] = ID_PERCENT_GOOD
    TYPE: ClassVar[str] = "pd0.PercentGood"
    MIN_SIZE: ClassVar[int] = -1

    percent_good: np.ndarray = wire(
        "u8", 2, shape=("n_cells", "n_beams"), units="%", vendor="Percent Good"
    )
    extra: bytes = b""


@message
class BottomTrack:
    """Bottom track 0x0600 (Pathfinder and Ocean Surveyor 81 bytes, Workhorse 85).

    ``velocity`` (m/s, NaN = bad) is the BOTTOM moving relative to a stationary instrument, in the
    fixed leader's frame (beam: beams 1-4; instrument: X, Y, Z, error; ship: starboard, forward,
    mast, error; earth: east, north, up, error). Use :attr:`vehicle_velocity` for the
    instrument's motion over the bottom. Per-beam vertical range to the bottom is
    :attr:`range` (m), from the 16-bit LSB words and the MSB bytes; 0 on the wire = bad (NaN).
    """

    ID: ClassVar[int] = ID_BOTTOM_TRACK
    TYPE: ClassVar[str] = "pd0.BottomTrack"
    MIN_SIZE: ClassVar[int] = 72

    pings_per_ensemble: int = wire("u16", 2, vendor="BT Pings per ensemble (BP)")
    delay_before_reacquire: int = wire("u16", 4, vendor="BT Delay before re-acquire (BD)")
    correlation_min: int = wire("u8", 6, units="counts", vendor="BT Corr Mag Min (BC)")
    amplitude_min: int = wire("u8", 7, units="counts", vendor="BT Eval Amp Min (BA)")
    percent_good_min: int = wire("u8", 8, units="%", vendor="BT Percent Good Min (BG)")
    mode: int = wire("u8", 9, vendor="BT Mode (BM)")
    error_velocity_max: float = wire(
        "u16", 10, scale=1e-3, units="m/s", vendor="BT Err Vel Max (BE), mm/s"
    )
    reserved_12: bytes = wire("bytes", 12, size=4, vendor="Reserved")
    range_lsb: np.ndarray = wire(
        "u16", 16, shape=(4,), scale=0.01, units="m", vendor="BT Range LSB beams 1-4, cm",
        doc="low 16 bits of the range; add range_msb (see BottomTrack.range)",
    )
    velocity: np.ndarray = wire(
        "s16", 24, shape=(4,), scale=1e-3, units="m/s", invalid=_S16_BAD,
        vendor="BT Velocity beams 1-4, mm/s", doc="bottom relative to the instrument",
    )
    correlation: np.ndarray = wire("u8", 32, shape=(4,), units="counts", vendor="BT Corr.")
    evaluation_amplitude: np.ndarray = wire(
        "u8", 36, shape=(4,), units="counts", vendor="BT Eval Amp"
    )
    percent_good: np.ndarray = wire("u8", 40, shape=(4,), units="%", vendor="BT %Good")
    ref_layer_min: float = wire("u16", 44, scale=0.1, units="m", vendor="Ref Layer Min (BL), dm")
    ref_layer_near: float = wire("u16", 46, scale=0.1, units="m", vendor="Ref Layer Near, dm")
    ref_layer_far: float = wire("u16", 48, scale=0.1, units="m", vendor="Ref Layer Far, dm")
    ref_velocity: np.ndarray = wire(
        "s16", 50, shape=(4,), scale=1e-3, units="m/s", invalid=_S16_BAD,
        vendor="Ref Layer Velocity beams 1-4, mm/s", doc="water layer relative to the instrument",
    )
    ref_correlation: np.ndarray = wire("u8", 58, shape=(4,), units="counts", vendor="Ref Corr")
    ref_intensity: np.ndarray = wire("u8", 62, shape=(4,), units="counts", vendor="Ref Int")
    ref_percent_good: np.ndarray = wire("u8", 66, shape=(4,), units="%", vendor="Ref %Good")
    max_depth: float = wire("u16", 70, scale=0.1, units="m", vendor="BT Max. Depth (BX), dm")
    rssi: np.ndarray | None = wire("u8", 72, shape=(4,), units="counts", vendor="RSSI Amp")
    gain: int | None = wire("u8", 76, vendor="Gain")
    range_msb: np.ndarray | None = wire(
        "u8", 77, shape=(4,), scale=655.36, units="m", vendor="BT Range MSB beams 1-4, 65536 cm"
    )
    reserved_81: bytes | None = wire("bytes", 81, size=4, vendor="Reserved (Workhorse)")
    extra: bytes = b""

    @property
    def range(self) -> np.ndarray:
        """Vertical range to the bottom per beam, m (LSB word + 65536 x MSB byte, in cm; 0 = bad
        -> NaN). Does not account for pitch and roll."""
        total = np.asarray(self.range_lsb, dtype=np.float64)
        if self.range_msb is not None:
            total = total + np.asarray(self.range_msb, dtype=np.float64)
        return np.where(total == 0.0, np.nan, total)

    @property
    def vehicle_velocity(self) -> np.ndarray:
        """Instrument velocity over the bottom, m/s: ``-velocity`` (same frame and components;
        the fourth component of a transformed solution is the error velocity, sign-flipped)."""
        return -np.asarray(self.velocity)


@message
class BottomTrackHighRes:
    """Pathfinder bottom-track high-resolution velocity 0x5803 (70 bytes), selected by #BJ.

    Velocities in m/s (0.01 mm/s on the wire) and distances made good in m (0.01 mm), per axis
    of the EX frame. Sign: unlike 0x0600, these are the INSTRUMENT moving over the bottom (water
    mass: relative to the water), so :attr:`vehicle_velocity` is ``bt_velocity`` itself.
    ``speed_of_sound`` is the raw word (the guide does not state its unit in the consulted text).
    The -2**31 bad marker is this module's assumption, mirroring the 16-bit -32768.
    """

    ID: ClassVar[int] = ID_BT_HIGH_RES
    TYPE: ClassVar[str] = "pd0.BottomTrackHighRes"
    MIN_SIZE: ClassVar[int] = 66

    bt_velocity: np.ndarray = wire(
        "s32", 2, shape=(4,), scale=1e-5, units="m/s", invalid=_S32_BAD,
        vendor="BT Velocity axes 1-4, 0.01 mm/s",
    )
    bt_distance: np.ndarray = wire(
        "s32", 18, shape=(4,), scale=1e-5, units="m", vendor="BT DMG axes 1-4, 0.01 mm"
    )
    wm_velocity: np.ndarray = wire(
        "s32", 34, shape=(4,), scale=1e-5, units="m/s", invalid=_S32_BAD,
        vendor="WM Velocity axes 1-4, 0.01 mm/s",
    )
    wm_distance: np.ndarray = wire(
        "s32", 50, shape=(4,), scale=1e-5, units="m", vendor="WM DMG axes 1-4, 0.01 mm"
    )
    speed_of_sound: int | None = wire("s32", 66, vendor="Speed of Sound (raw)")
    extra: bytes = b""

    @property
    def vehicle_velocity(self) -> np.ndarray:
        """Instrument velocity over the bottom, m/s (= ``bt_velocity``, no negation)."""
        return np.asarray(self.bt_velocity)


@message
class BottomTrackRange:
    """Pathfinder bottom-track range 0x5804 (41 bytes), selected by #BJ.

    Ranges in m (0.1 mm on the wire). ``vertical_range`` is the altitude accounting for tilt;
    ``slant_range`` is along the instrument Z axis; both 0 on the wire = bad (NaN).
    ``raw_range`` per beam is the slant range times cos(Janus angle).
    """

    ID: ClassVar[int] = ID_BT_RANGE
    TYPE: ClassVar[str] = "pd0.BottomTrackRange"
    MIN_SIZE: ClassVar[int] = 17

    slant_range: float = wire("u32", 2, scale=1e-4, units="m", invalid=0, vendor="Slant Range")
    axis_delta_range: float = wire("s32", 6, scale=1e-4, units="m", vendor="Axis Delta Range")
    vertical_range: float = wire(
        "u32", 10, scale=1e-4, units="m", invalid=0, vendor="Vertical Range, 0.1 mm"
    )
    percent_good_4beam: int = wire("u8", 14, units="%", vendor="% Good 4 Bm")
    percent_good_beams12: int = wire("u8", 15, units="%", vendor="% Good Bm 1&2")
    percent_good_beams34: int = wire("u8", 16, units="%", vendor="% Good Bm 3&4")
    raw_range: np.ndarray | None = wire(
        "u32", 17, shape=(4,), scale=1e-4, units="m", vendor="BM 1-4 Raw Range, 0.1 mm"
    )
    max_filter: np.ndarray | None = wire(
        "u8", 33, shape=(4,), units="counts", vendor="BM 1-4 Raw Max BT Filter"
    )
    max_amplitude: np.ndarray | None = wire(
        "u8", 37, shape=(4,), units="counts", vendor="BM 1-4 Raw Max BT Amp"
    )
    extra: bytes = b""


@message
class RawBlock:
    """A data type this module does not decode, kept whole (ID bytes included) for re-encoding."""

    TYPE: ClassVar[str] = "pd0.RawBlock"

    data: bytes

    @property
    def id(self) -> int:
        """The data type ID (first two bytes, little endian)."""
        return int.from_bytes(self.data[:2], "little")


_TABLES: dict[int, type] = {
    cls.ID: cls
    for cls in (
        FixedLeader,
        VariableLeader,
        Velocity,
        Correlation,
        EchoIntensity,
        PercentGood,
        BottomTrack,
        BottomTrackHighRes,
        BottomTrackRange,
    )
}
#: Ensemble field name of each known data type, in the canonical (RDI) order
_FIELD_OF: dict[int, str] = {
    ID_FIXED_LEADER: "fixed_leader",
    ID_VARIABLE_LEADER: "variable_leader",
    ID_VELOCITY: "velocity",
    ID_CORRELATION: "correlation",
    ID_ECHO_INTENSITY: "echo_intensity",
    ID_PERCENT_GOOD: "percent_good",
    ID_BOTTOM_TRACK: "bottom_track",
    ID_BT_HIGH_RES: "bt_high_res",
    ID_BT_RANGE: "bt_range",
}
_CELL_TABLES = frozenset((ID_VELOCITY, ID_CORRELATION, ID_ECHO_INTENSITY, ID_PERCENT_GOOD))
_CELL_CLASSES = frozenset(_TABLES[i] for i in _CELL_TABLES)


@message
class Ensemble:
    """One PD0 ensemble: each known data type (``None`` when absent) plus what makes the bytes
    exact on re-encoding: ``order`` (data type IDs in offset-table order; empty = canonical),
    ``layout`` (offset-table indices in byte order when that differs from table order),
    ``unknown`` data types kept raw (in table order), header ``spare`` byte, ``gap`` bytes
    between the offset table and the first data type, ``trailer`` bytes between the last data
    type's table and the checksum (two reserved bytes on a Workhorse).
    """

    TYPE: ClassVar[str] = "pd0.Ensemble"

    fixed_leader: FixedLeader | None = None
    variable_leader: VariableLeader | None = None
    velocity: Velocity | None = None
    correlation: Correlation | None = None
    echo_intensity: EchoIntensity | None = None
    percent_good: PercentGood | None = None
    bottom_track: BottomTrack | None = None
    bt_high_res: BottomTrackHighRes | None = None
    bt_range: BottomTrackRange | None = None
    unknown: tuple[RawBlock, ...] = ()
    order: tuple[int, ...] = ()
    layout: tuple[int, ...] = ()
    spare: int = 0
    gap: bytes = b""
    trailer: bytes = b""

    @property
    def coordinate_frame(self) -> CoordinateFrame | None:
        """Frame of the velocities (fixed leader EX bits 3-4); ``None`` without a fixed leader."""
        return None if self.fixed_leader is None else self.fixed_leader.coordinate_frame

    @property
    def device_time(self) -> dt.datetime | None:
        """Device clock of the ensemble (variable leader RTC), UTC assumed."""
        return None if self.variable_leader is None else self.variable_leader.device_time

    @property
    def ids(self) -> tuple[int, ...]:
        """Data type IDs in offset-table order (as they will be encoded)."""
        return self.order or _canonical_order(self)


# --------------------------------------------------------------------------------------------
# Table helpers: short blocks (trailing fields None) and block tails
# --------------------------------------------------------------------------------------------

_WIRES: dict[type, list[tuple[str, Wire]]] = {}


def _wires(cls: type[Any]) -> list[tuple[str, Wire]]:
    rows = _WIRES.get(cls)
    if rows is None:
        rows = sorted(
            ((f.name, f.metadata["wire"]) for f in dataclasses.fields(cls) if "wire" in f.metadata),
            key=lambda r: r[1].offset,
        )
        _WIRES[cls] = rows
    return rows


def _plan(cls: type[Any], ctx: Mapping[str, int], avail: int) -> Plan:
    """The table's compiled plan (:func:`~auvgw.drivers.spec.plan`) for a block of ``avail``
    bytes: the trailing rows it is too short for are absent (``None``)."""
    return table_plan(cls, ctx if cls.ID in _CELL_TABLES else {}, avail)


def _decode(p: Plan, buf: bytes, start: int, extra: bytes) -> Any:
    """Decode the block at ``buf[start:]`` with plan ``p``; ``buf`` is ``bytes`` (immutable:
    unscaled arrays are read-only views of it). Every field is supplied, so the frozen message
    is filled without running its ``__init__``."""
    values = p.read(buf, start)  # type: ignore[misc]  # PD0 tables always compile
    values["extra"] = extra
    msg: Any = object.__new__(p.cls)
    msg.__dict__.update(values)
    return msg


def _decode_bulk(
    p: Plan, joined: bytes, n: int, length: int, start: int, extras: Sequence[bytes]
) -> list[Any]:
    """Decode the block at ``start`` of ``n`` ensembles of ``length`` bytes laid end to end in
    ``joined`` (padded by at least ``length`` bytes): the plan's columns, one record a row."""
    columns = p.columns(joined, start, n, length)
    names = [*columns, "extra", *p.absent]
    cols: list[Sequence[Any]] = []
    for r in p.rows:
        col = columns[r.name]
        cols.append(col if isinstance(col, list) else list(col) if r.shape else col.tolist())
    cols.append(extras)
    cols.extend([None] * n for _ in p.absent)
    new = object.__new__
    cls = p.cls
    out = []
    for row in zip(*cols, strict=True):
        msg: Any = new(cls)
        msg.__dict__.update(zip(names, row, strict=True))
        out.append(msg)
    return out


def _placeholder(w: Wire, ctx: Mapping[str, int]) -> Any:
    if w.type == "bytes":
        return bytes(w.size)
    if w.shape:
        return np.zeros(w.resolve_shape(ctx))
    return 0


def _encode_table(msg: Any, ctx: Mapping[str, int]) -> bytes:
    """The bytes of one data type: ID, table (up to the last present field), ``extra``."""
    cls = type(msg)
    rows = _wires(cls)
    full = block_size(cls, ctx)
    absent = [(name, w) for name, w in rows if getattr(msg, name) is None]
    end = full
    if absent:
        first = absent[0][1].offset
        late = [name for name, w in rows if w.offset > first and getattr(msg, name) is not None]
        if late:
            raise WireError(
                f"{cls.__name__}: field {absent[0][0]} is None but later field {late[0]} is set "
                "(only trailing fields may be absent)"
            )
        min_size = full if cls.MIN_SIZE < 0 else cls.MIN_SIZE
        if first < min_size:
            raise WireError(f"{cls.__name__}: field {absent[0][0]} is required")
        msg = copy.copy(msg)
        for name, w in absent:
            object.__setattr__(msg, name, _placeholder(w, ctx))
        end = first
    buf = bytearray(full)
    struct.pack_into("<H", buf, 0, cls.ID)
    encode_block(msg, buf, 0, ctx)
    return bytes(buf[:end]) + msg.extra


# --------------------------------------------------------------------------------------------
# Codec
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Header:
    """The validated header of one ensemble layout (a pure function of bytes 2..table end)."""

    nbytes: int
    spare: int
    table_end: int
    offsets: tuple[int, ...]
    ends: tuple[int, ...]
    positions: tuple[int, ...]


def _parse_header(frame: bytes) -> _Header:
    size = len(frame)
    if size < HEADER_SIZE + 2 or frame[:2] != SYNC:
        raise DecodeError(f"PD0: not an ensemble (starts {frame[:2].hex()}, {size} bytes)")
    nbytes, spare, ntypes = struct.unpack_from("<HBB", frame, 2)
    if nbytes + 2 != size:
        raise DecodeError(f"PD0 header byte 2: nBytes {nbytes} + 2 != frame length {size}")
    table_end = HEADER_SIZE + 2 * ntypes
    if ntypes == 0 or table_end > nbytes:
        raise DecodeError(f"PD0 header byte 5: {ntypes} data types do not fit in {nbytes} bytes")
    offsets = struct.unpack_from(f"<{ntypes}H", frame, HEADER_SIZE)
    for i, off in enumerate(offsets):
        if not table_end <= off <= nbytes - 2:
            raise DecodeError(
                f"PD0 offset table byte {HEADER_SIZE + 2 * i}: data type #{i + 1} offset {off} "
                f"outside the ensemble data (bytes {table_end}..{nbytes - 1})"
            )
    positions = sorted(range(ntypes), key=offsets.__getitem__)
    ends = [0] * ntypes
    for k, idx in enumerate(positions):
        ends[idx] = offsets[positions[k + 1]] if k + 1 < ntypes else nbytes
        if ends[idx] - offsets[idx] < 2:
            raise DecodeError(
                f"PD0 data type #{idx + 1} at byte {offsets[idx]}: block too short for its ID "
                f"({ends[idx] - offsets[idx]} bytes)"
            )
    return _Header(nbytes, spare, table_end, offsets, tuple(ends), tuple(positions))


_ENSEMBLE_DEFAULTS: dict[str, Any] = {
    f.name: f.default for f in dataclasses.fields(Ensemble)
}


class _Template:
    """How to cut and decode every ensemble that shares one layout: header bytes, data type IDs
    and fixed-leader cell/beam counts. Built (and validated) from the first such ensemble."""

    def __init__(self, frame: bytes, hdr: _Header, ids: tuple[int, ...]) -> None:
        last_idx = hdr.positions[-1]
        fixed_ctx: dict[str, int] | None = None
        if ID_FIXED_LEADER in ids:  # first: its cell and beam counts size the profile tables
            i = ids.index(ID_FIXED_LEADER)
            plan = _plan(FixedLeader, {}, hdr.ends[i] - hdr.offsets[i])
            _check_plan(plan, hdr.offsets[i], hdr.ends[i])
            base = hdr.offsets[i]
            fixed_ctx = {"n_beams": frame[base + 8], "n_cells": frame[base + 9]}
        #: (ensemble field or None for a raw block, plan, start, table stop, end, last)
        self.steps: list[tuple[str, Plan | None, int, int, int, bool]] = []  # "": unknown ID
        self.trailer_start = hdr.nbytes
        seen: set[str] = set()
        for i, bid in enumerate(ids):
            start, end, last = hdr.offsets[i], hdr.ends[i], i == last_idx
            name = _FIELD_OF.get(bid)
            if name is None:
                self.steps.append(("", None, start, end, end, last))
                continue
            if name in seen:
                raise DecodeError(f"PD0 data type 0x{bid:04X} at byte {start}: appears twice")
            seen.add(name)
            ctx: dict[str, int] = {}
            if bid in _CELL_TABLES:
                if fixed_ctx is None:
                    raise DecodeError(
                        f"PD0 data type 0x{bid:04X} at byte {start}: needs the fixed leader for "
                        "the cell and beam counts, but the ensemble has none"
                    )
                ctx = fixed_ctx
            plan = _plan(_TABLES[bid], ctx, end - start)
            _check_plan(plan, start, end)
            stop = start + max(plan.end, 2)
            self.steps.append((name, plan, start, stop, end, last))
            if last:
                self.trailer_start = stop
        values = dict.fromkeys(seen, True)
        unknown_ids = [bid for bid in ids if bid not in _FIELD_OF]
        canonical = tuple(b for b, n in _FIELD_OF.items() if n in values) + tuple(unknown_ids)
        self.fixed = {
            "order": () if ids == canonical else ids,
            "layout": () if hdr.positions == tuple(range(len(ids))) else hdr.positions,
            "spare": hdr.spare,
        }
        self.gap = (hdr.table_end, hdr.offsets[hdr.positions[0]])
        self.nbytes = hdr.nbytes
        #: the last fixed leader decoded with this template, by its bytes (shared while equal)
        self.last_fixed: dict[bytes, FixedLeader] = {}
        self.ctx = fixed_ctx or {}
        self._layout: WireLayout | None = None

    @property
    def layout(self) -> WireLayout:
        """Where every field of this layout's ensembles sits (:func:`wire_layout`)."""
        if self._layout is None:
            fields: dict[str, Any] = dict.fromkeys(_FIELD_OF.values())
            unknown = []
            for name, plan, start, stop, end, last in self.steps:
                if plan is None:
                    unknown.append(WireLayout(RawBlock, start, fields={"data": slice(start, end)}))
                    continue
                extra = b"" if last else slice(stop, end)
                ctx = self.ctx if plan.cls in _CELL_CLASSES else {}
                fields[name] = WireLayout(
                    plan.cls, start, ctx, frozenset(plan.absent), {"extra": extra}
                )
            fields.update(self.fixed, unknown=tuple(unknown), gap=slice(*self.gap),
                          trailer=slice(self.trailer_start, self.nbytes))  # fmt: skip
            self._layout = WireLayout(Ensemble, 0, fields=fields)
        return self._layout

    def decode(self, frame: bytes) -> Ensemble:
        values = dict(_ENSEMBLE_DEFAULTS)
        values.update(self.fixed)
        unknown = []
        for name, plan, start, stop, end, last in self.steps:
            if plan is None:
                unknown.append(RawBlock(frame[start:end]))
            elif name == "fixed_leader":  # configuration: usually the same bytes every time
                key = frame[start : stop if last else end]
                msg = self.last_fixed.get(key)
                if msg is None:
                    msg = _decode(plan, frame, start, b"" if last else frame[stop:end])
                    self.last_fixed = {key: msg}
                values[name] = msg
            else:
                values[name] = _decode(plan, frame, start, b"" if last else frame[stop:end])
        values["unknown"] = tuple(unknown)
        values["gap"] = frame[self.gap[0] : self.gap[1]]
        values["trailer"] = frame[self.trailer_start : self.nbytes]
        ens = object.__new__(Ensemble)
        ens.__dict__.update(values)
        return ens

    def decode_bulk(self, frames: Sequence[bytes], joined: bytes) -> list[Ensemble]:
        """Decode ensembles of this layout together (one numpy pass per field); ``joined`` is
        the frames laid end to end plus at least one frame length of padding."""
        n = len(frames)
        length = self.nbytes + 2
        columns: dict[str, Sequence[Any]] = {}
        unknown: list[list[RawBlock]] = [[] for _ in range(n)]
        for name, plan, start, stop, end, last in self.steps:
            if plan is None:
                for i, f in enumerate(frames):
                    unknown[i].append(RawBlock(f[start:end]))
                continue
            hi = stop if last else end
            rows = np.frombuffer(joined, np.uint8, n * length).reshape(n, length)[:, start:hi]
            if (rows == rows[0]).all():  # the same bytes in every ensemble (a fixed leader):
                one = _decode(plan, frames[0], start, b"" if last else frames[0][stop:end])
                columns[name] = [one] * n  # one immutable message, shared
                continue
            extras = [b""] * n if last or stop == end else [f[stop:end] for f in frames]
            columns[name] = _decode_bulk(plan, joined, n, length, start, extras)
        a, b = self.gap
        t, nb = self.trailer_start, self.nbytes
        base = {**_ENSEMBLE_DEFAULTS, **self.fixed}
        names = [*columns, "unknown", "gap", "trailer"]
        cols = [
            *columns.values(),
            [tuple(u) for u in unknown],
            [f[a:b] for f in frames],
            [f[t:nb] for f in frames],
        ]
        new = object.__new__
        out = []
        for row in zip(*cols, strict=True):
            ens = new(Ensemble)
            d = ens.__dict__
            d.update(base)
            d.update(zip(names, row, strict=True))
            out.append(ens)
        return out


def _check_plan(p: Plan, start: int, end: int) -> None:
    """Refuse a block too short for a required row (below the table's ``MIN_SIZE``)."""
    if not p.absent:
        return
    cls: Any = p.cls
    name = p.absent[0]
    w = dict(_wires(cls))[name]
    a, b = w.offset, w.offset + w.nbytes(p.ctx)
    if b <= (cls.MIN_SIZE if cls.MIN_SIZE >= 0 else block_size(cls, p.ctx)):
        raise DecodeError(
            f"PD0 data type 0x{cls.ID:04X} ({cls.__name__}) at byte {start}: block too short "
            f"({end - start} bytes): field {name} needs bytes {start + a}..{start + b - 1} but "
            f"the block ends at byte {end}"
        )


_HEADERS: dict[bytes, _Header] = {}
_TEMPLATES: dict[tuple[bytes, tuple[int, ...], bytes], _Template] = {}


def _template(frame: bytes) -> _Template:
    """The (cached) template of ``frame``'s layout; validates the header and block sizes."""
    key_hdr = frame[: HEADER_SIZE + 2 * frame[5]] if len(frame) > 5 else frame
    hdr = _HEADERS.get(key_hdr)
    if hdr is None or len(frame) != hdr.nbytes + 2:
        hdr = _parse_header(frame)
        if len(_HEADERS) > 4096:
            _HEADERS.clear()
        _HEADERS[key_hdr] = hdr
    ids = tuple(frame[o] | frame[o + 1] << 8 for o in hdr.offsets)
    counts = b""
    if ID_FIXED_LEADER in ids:
        i = ids.index(ID_FIXED_LEADER)
        counts = frame[hdr.offsets[i] + 8 : min(hdr.offsets[i] + 10, hdr.ends[i])]
    key = (key_hdr, ids, counts)
    tpl = _TEMPLATES.get(key)
    if tpl is None:
        tpl = _Template(frame, hdr, ids)
        if len(_TEMPLATES) > 4096:
            _TEMPLATES.clear()
        _TEMPLATES[key] = tpl
    return tpl


def _verify_checksum(frame: bytes, nbytes: int) -> None:
    stored = frame[nbytes] | frame[nbytes + 1] << 8
    if checksum(frame[:nbytes]) != stored:
        raise DecodeError(f"PD0 checksum at byte {nbytes}: stored 0x{stored:04X} does not match")


def decode(frame: bytes | bytearray | memoryview, verified: bool = False) -> Ensemble:
    """Decode one whole PD0 ensemble (sync to checksum) into an :class:`Ensemble`.

    Raises :class:`DecodeError` naming the data type, field and byte offset when the content is
    inconsistent (length, checksum, offsets outside the ensemble, blocks too short).
    ``verified``: :class:`Pd0Framer` has just checked this frame's checksum (not checked again).
    """
    frame = bytes(frame)
    tpl = _template(frame)
    if not verified:
        _verify_checksum(frame, tpl.nbytes)
    return tpl.decode(frame)


def wire_layout(frame: bytes) -> WireLayout:
    """Where every field of the ensemble in ``frame`` (delivered by :class:`Pd0Framer`) sits
    (:class:`~auvgw.drivers.spec.WireLayout`; one object per layout, cached); raises the
    :class:`DecodeError` :func:`decode` raises for a layout it cannot decode, and a frame whose
    layout it returns decodes without error."""
    return _template(frame).layout


def decode_many(frames: Sequence[bytes | bytearray | memoryview]) -> list[Ensemble]:
    """``[decode(f) for f in frames]``, vectorised over runs of consecutive ensembles that share a
    layout (as a file's ensembles do): checksums and every field are computed with one numpy
    pass per run. Raises the same :class:`DecodeError` as :func:`decode` for a bad frame.
    """
    data = [bytes(f) for f in frames]
    out: list[Ensemble] = []
    i = 0
    while i < len(data):
        tpl = _template(data[i])
        key = data[i][: tpl.gap[0]]
        j = i + 1
        while j < len(data) and len(data[j]) == len(data[i]) and data[j][: tpl.gap[0]] == key:
            j += 1
        run = data[i:j]
        joined = b"".join([*run, bytes(len(run[0]))])  # padding: records may overrun the end
        if len(run) < 4 or not _bulk_ok(tpl, run, joined):
            out.extend(decode(f) for f in run)  # small run or an odd one inside: one by one
        else:
            out.extend(tpl.decode_bulk(run, joined))
        i = j
    return out


def _bulk_ok(tpl: _Template, run: Sequence[bytes], joined: bytes) -> bool:
    """Same IDs and cell/beam counts as the template, and every checksum good."""
    length = tpl.nbytes + 2
    arr = np.frombuffer(joined, dtype=np.uint8, count=len(run) * length).reshape(-1, length)
    first = arr[0]
    for name, _, start, *_ in tpl.steps:
        cols = [start, start + 1]
        if name == "fixed_leader":
            cols += [start + 8, start + 9]
        if not (arr[:, cols] == first[cols]).all():
            return False
    sums = arr[:, : tpl.nbytes].sum(axis=1, dtype=np.uint64) & 0xFFFF
    stored = arr[:, tpl.nbytes].astype(np.uint64) | arr[:, tpl.nbytes + 1].astype(np.uint64) << 8
    return bool((sums == stored).all())


def _canonical_order_of(values: Mapping[str, Any], unknown: Sequence[RawBlock]) -> tuple[int, ...]:
    known = tuple(bid for bid, name in _FIELD_OF.items() if values.get(name) is not None)
    return known + tuple(b.id for b in unknown)


def _canonical_order(ens: Ensemble) -> tuple[int, ...]:
    values = {name: getattr(ens, name) for name in _FIELD_OF.values()}
    return _canonical_order_of(values, ens.unknown)


def encode(ens: Ensemble) -> bytes:
    """The bytes of ``ens``: header and offset table computed from the blocks, checksum appended.

    Raises :class:`~auvgw.drivers.spec.WireError` when a value does not fit its wire field or
    ``order``/``layout`` do not match the blocks present.
    """
    order = ens.ids
    ctx: dict[str, int] = {}
    if ens.fixed_leader is not None:
        ctx = {"n_cells": ens.fixed_leader.n_cells, "n_beams": ens.fixed_leader.n_beams}
    unknown = list(ens.unknown)
    blocks: list[bytes] = []
    seen: set[str] = set()
    for bid in order:
        name = _FIELD_OF.get(bid)
        if name is None:  # the first raw block with that ID not used yet
            k = next((k for k, b in enumerate(unknown) if b.id == bid), None)
            if k is None:
                raise WireError(f"Ensemble.order lists 0x{bid:04X} but no matching raw block")
            blocks.append(unknown.pop(k).data)
            continue
        msg = getattr(ens, name)
        if msg is None or name in seen:
            raise WireError(f"Ensemble.order lists 0x{bid:04X} but {name} is absent or repeated")
        if bid in _CELL_TABLES and not ctx:
            raise WireError(f"Ensemble.{name} needs a fixed leader for its cell and beam counts")
        seen.add(name)
        blocks.append(_encode_table(msg, ctx))
    missing = [n for n in _FIELD_OF.values() if getattr(ens, n) is not None and n not in seen]
    if missing or unknown:
        raise WireError(f"Ensemble.order omits blocks: {missing or [hex(b.id) for b in unknown]}")
    n = len(order)
    layout = ens.layout or tuple(range(n))
    if sorted(layout) != list(range(n)):
        raise WireError(f"Ensemble.layout {layout} is not a permutation of {n} data types")
    table_end = HEADER_SIZE + 2 * n
    offsets = [0] * n
    pos = table_end + len(ens.gap)
    for idx in layout:
        offsets[idx] = pos
        pos += len(blocks[idx])
    nbytes = pos + len(ens.trailer)
    if nbytes > 0xFFFF:
        raise WireError(f"Ensemble: {nbytes} bytes do not fit the u16 nBytes field")
    out = bytearray(nbytes + 2)
    struct.pack_into(f"<2sHBB{n}H", out, 0, SYNC, nbytes, ens.spare, n, *offsets)
    out[table_end : table_end + len(ens.gap)] = ens.gap
    for idx in layout:
        out[offsets[idx] : offsets[idx] + len(blocks[idx])] = blocks[idx]
    out[nbytes - len(ens.trailer) : nbytes] = ens.trailer
    struct.pack_into("<H", out, nbytes, checksum(out[:nbytes]))
    return bytes(out)


# --------------------------------------------------------------------------------------------
# Framer
# --------------------------------------------------------------------------------------------


class Pd0Framer(Framer):
    """PD0 ensembles out of a byte stream: sync 7F 7F, header plausibility, checksum.

    The header is judged as soon as its bytes are there, before waiting for the rest of the
    ensemble: ``nBytes`` must hold the header and offset table, the number of data types must be
    1..``max_data_types``, and every offset must point inside the ensemble after the offset
    table. Then the checksum (sum of bytes 0..nBytes-1 mod 65536) must match the u16 after them.
    """

    name = "pd0"
    sync = SYNC
    max_frame_size = 0xFFFF + 2
    #: more data types than this in one ensemble is implausible (real files carry 6-12)
    max_data_types = 32

    def check(self, buf: bytearray, start: int) -> int:
        avail = len(buf) - start
        if avail < HEADER_SIZE:
            if avail >= 4:
                self._check_nbytes(buf[start + 2] | buf[start + 3] << 8, 1)
            return 0
        nbytes = buf[start + 2] | buf[start + 3] << 8
        ntypes = buf[start + 5]
        if not 1 <= ntypes <= self.max_data_types:
            raise BadFrame(f"data_types: {ntypes} (allowed 1..{self.max_data_types})")
        self._check_nbytes(nbytes, ntypes)
        table_end = HEADER_SIZE + 2 * ntypes
        if avail < table_end:
            return 0
        for i, off in enumerate(struct.unpack_from(f"<{ntypes}H", buf, start + HEADER_SIZE)):
            if not table_end <= off <= nbytes - 2:
                raise BadFrame(
                    f"offset: data type #{i + 1} at {off}, outside {table_end}..{nbytes - 2}"
                )
        if avail < nbytes + 2:
            return 0
        stored = buf[start + nbytes] | buf[start + nbytes + 1] << 8
        total = checksum(buf[start : start + nbytes])
        if total != stored:
            raise BadFrame(f"checksum: 0x{total:04X} computed, 0x{stored:04X} stored")
        return nbytes + 2

    @staticmethod
    def _check_nbytes(nbytes: int, ntypes: int) -> None:
        if nbytes < HEADER_SIZE + 4 * ntypes:  # header, offsets, at least an ID per data type
            raise BadFrame(f"length: nBytes {nbytes} cannot hold the header and {ntypes} offsets")


FORMAT = Format.one_per_frame(
    "pd0",
    "Teledyne RDI PD0 binary ensembles (7F 7F ... checksum)",
    Pd0Framer,
    decode,
    encode,
    skips_checksum=True,
    layout=wire_layout,
)
