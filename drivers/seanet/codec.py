"""Tritech SeaNet packets: the serial protocol of the Micron / SeaKing mechanical scanning
imaging sonars (MSIS), host side and head side.

Packet (all multi-byte integers little endian; offsets from the packet start)::

    0      '@'
    1..4   length L as 4 upper-case ASCII hex digits
    5..6   length L again, u16 binary            (whole packet = L + 6 bytes)
    7      Tx node   (host 255, sonar head 2)
    8      Rx node
    9      byte count: bytes after this one up to the LF (= L - 5), 0 in mtHeadData
    10     message type (mtHeadData = 2, ...)
    11     sequence: bit 7 set = last packet of the message (0x80 for single packets)
    12     node number of the device (copy of the head's node)
    13..   payload, one declarative table per message type below
    L+5    0x0A (LF)

SeaNet has no checksum. :class:`SeaNetFramer` therefore checks everything else: the hex length
parses, equals the binary length and is plausible, the byte count is consistent, the LF sits
where the length says, and no complete packet header starts inside the candidate (a truncated
packet must not swallow the valid packet after it). Any failure is a bad frame and the search
resumes at the next '@'.

Decoded messages are immutable and carry SI units: angles in radians (the wire's 1/16 gradian,
6400 per turn, stays available through :func:`~auvgw.drivers.spec.raw_value`), times in
seconds, frequencies in Hz, levels in dB. Bearings are the head's own transducer angle
(0 = the head's forward mark, increasing clockwise seen from above with the head upright); the
vehicle frame is applied downstream with the mounting (``invert`` flag, heading offset).

The exchange (see ``docs/protocols/seanet.md``): the head sends mtAlive about once a second after
power-up; the host sends mtReBoot / mtSendVersion (answer mtVersionData), then mtHeadCommand; once
the head's mtAlive reports its parameters, the host sends one mtSendData per ping and the head
answers with one mtHeadData scan line.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Sequence
from enum import IntEnum, IntFlag
from typing import Any, ClassVar

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import BadFrame, DecodeError, Framer
from auvgw.drivers.spec import (
    WireError,
    decode_block,
    encode_block,
    message,
    message_base,
    table_rows,
    wire,
)

__all__ = [
    "AD_INTERVAL_S",
    "ANGLE_UNITS_PER_TURN",
    "FORMAT",
    "HEAD_NODE",
    "HOST_NODE",
    "MAX_PACKET_SIZE",
    "RAD_PER_ANGLE_UNIT",
    "Alive",
    "HdCtrl",
    "HeadCommand",
    "HeadData",
    "HeadInf",
    "HeadStatus",
    "MessageType",
    "ReBoot",
    "SeaNetFramer",
    "SeaNetMessage",
    "SeaNetRaw",
    "SendBBUser",
    "SendData",
    "SendVersion",
    "SweepCode",
    "V3BGains",
    "VersionData",
    "alive",
    "angle_to_rad",
    "bin_length",
    "decode",
    "default_byte_count",
    "encode",
    "head_command",
    "head_data",
    "packet_length",
    "rad_to_angle",
    "reboot",
    "send_bb_user",
    "send_data",
    "send_version",
    "version_data",
]

#: node number of the host (PC / gateway) on a SeaNet line
HOST_NODE = 255
#: node number of an imaging sonar head (Micron, SeaKing) on a SeaNet line
HEAD_NODE = 2
#: wire angle units per turn (1/16 gradian)
ANGLE_UNITS_PER_TURN = 6400
#: radians per wire angle unit
RAD_PER_ANGLE_UNIT = 2.0 * math.pi / ANGLE_UNITS_PER_TURN
#: the ADInterval unit, seconds (640 ns)
AD_INTERVAL_S = 640e-9
#: transmitter / receiver "numbers" are F * 2**32 / 32 MHz: Hz per unit (exact in binary)
_HZ_PER_SYNTH_UNIT = 32e6 / 2**32
#: receiver intermediate frequency: RxN encodes TxN's frequency + 455 kHz
RX_IF_HZ = 455_000.0
#: largest packet the framer accepts (an 8-bit mtHeadData of 1500 bins is 1545 bytes)
MAX_PACKET_SIZE = 8192
MIN_PACKET_SIZE = 14  # header, type, sequence, node, LF

_SYNC = 0x40  # '@'
_LF = 0x0A
_HEX = frozenset(b"0123456789ABCDEF")
_GAIN_SCALE = 1.0 / 210.0  # receiver gain 0..210 = 0..100 % (= 0..80 dB)
_AD_DB_SCALE = 80.0 / 255.0  # ADSpan / ADLow 0..255 = 0..80 dB


class MessageType(IntEnum):
    """SeaNet message type codes (byte 10), with Tritech's names."""

    mtNull = 0
    mtVersionData = 1
    mtHeadData = 2
    mtSpectData = 3
    mtAlive = 4
    mtPrgAck = 5
    mtBBUserData = 6
    mtTestData = 7
    mtAuxData = 8
    mtAdcData = 9
    mtAdcReq = 10
    mtLanStatus = 13
    mtSetTime = 14
    mtTimeout = 15
    mtReBoot = 16
    mtPerformanceData = 17
    mtHeadCommand = 19
    mtEraseSector = 20
    mtProgBlock = 21
    mtCopyBootBlk = 22
    mtSendVersion = 23
    mtSendBBUser = 24
    mtSendData = 25
    mtSendPerformanceData = 26
    mtFpgaVersionData = 57
    mtFpgaCalibrationData = 63
    mtStopAlives = 66


class HdCtrl(IntFlag):
    """HdCtrl word of mtHeadCommand / mtHeadData: how the head scans and samples."""

    ADC8ON = 1 << 0  # 8-bit bins (else 4-bit, two per byte)
    CONTINUOUS = 1 << 1  # continuous rotation (else sector between the limits)
    SCAN_RIGHT = 1 << 2  # scan direction clockwise
    INVERT = 1 << 3  # head mounted inverted (reverses the rotation sense)
    MOTOR_OFF = 1 << 4
    TX_OFF = 1 << 5  # transmitter off (test)
    SPARE = 1 << 6
    CHAN2 = 1 << 7  # use channel 2 (dual-frequency heads)
    RAW = 1 << 8  # raw ADC data (always set)
    HAS_MOTOR = 1 << 9  # always set on a scanning sonar
    APPLY_OFFSET = 1 << 10  # apply the heading offset
    PING_PONG = 1 << 11  # alternate channels (side scan)
    STARE_LEFT_LIMIT = 1 << 12  # do not scan, point at the left limit
    REPLY_ASL = 1 << 13  # always set
    REPLY_THR = 1 << 14
    IGNORE_SENSOR = 1 << 15  # ignore the centre sensor (emergencies)


class HeadInf(IntFlag):
    """HeadInf byte of mtAlive: the head's state."""

    IN_CENTRE = 1 << 0  # re-centring the transducer
    CENTRED = 1 << 1  # transducer at centre, ready to scan
    MOTORING = 1 << 2
    MOTOR_ON = 1 << 3  # powered and motor primed
    DIR = 1 << 4  # transducer off centre
    IN_SCAN = 1 << 5  # performing a scan / ping
    NO_PARAMS = 1 << 6  # needs mtHeadCommand before it can ping
    SENT_CFG = 1 << 7  # acknowledges a received mtHeadCommand


class HeadStatus(IntFlag):
    """Head status byte of mtHeadData."""

    HEAD_POWER_LOSS = 1 << 0  # head is in reset condition
    MOTOR_ERROR = 1 << 1  # motor lost sync: send the parameters again
    PRF_SYNC_ERROR = 1 << 2
    PRF_PING_ERROR = 1 << 3
    BIT4 = 1 << 4
    BIT5 = 1 << 5
    BIT6 = 1 << 6
    APPENDED = 1 << 7  # extra data appended after the bins


class SweepCode(IntEnum):
    """Sweep code of mtHeadData: where the scan line sits in the sweep."""

    NORMAL = 0
    AT_LEFT_LIMIT = 1
    AT_RIGHT_LIMIT = 2
    AT_CENTRE = 5


#: range-scale unit codes (top 2 bits of RangeScale) -> (name, metres per unit)
RANGE_UNITS: dict[int, tuple[str, float]] = {
    0: ("m", 1.0),
    1: ("ft", 0.3048),
    2: ("fathom", 1.8288),
    3: ("yd", 0.9144),
}


# -- conversions ------------------------------------------------------------------------------
def angle_to_rad(units: int | float) -> float:
    """Wire angle (1/16 gradian, 6400 per turn) to radians (not wrapped)."""
    return float(units) * RAD_PER_ANGLE_UNIT


def rad_to_angle(rad: float) -> int:
    """Radians to the wire angle, rounded to the nearest 1/16 gradian and wrapped to 0..6399."""
    return round(rad / RAD_PER_ANGLE_UNIT) % ANGLE_UNITS_PER_TURN


def bin_length(ad_interval: float, sound_speed: float) -> float:
    """Range length of one bin in metres: ``ad_interval`` (s) * ``sound_speed`` (m/s) / 2.

    ``ad_interval`` is the sampling interval in seconds (ADInterval * 640 ns); halved because the
    sound travels out and back.
    """
    return ad_interval * sound_speed / 2.0


def _range_from_code(code: int) -> tuple[float, str, float]:
    name, per_unit = RANGE_UNITS[(code >> 14) & 3]
    value = (code & 0x3FFF) / 10.0
    return value, name, value * per_unit


# -- tables -----------------------------------------------------------------------------------
@message_base
class _Packet:
    """Fields every SeaNet packet carries (bytes 7..12); the type byte is the class's."""

    tx_node: int = wire("u8", 7, vendor="Tx Node", doc="sender node (host 255, head 2)")
    rx_node: int = wire("u8", 8, vendor="Rx Node", doc="destination node")
    byte_count: int = wire(
        "u8",
        9,
        vendor="Byte Count",
        doc="bytes after this one up to the LF (L - 5), 0 in mtHeadData (single-packet mode)",
    )
    sequence: int = wire("u8", 11, vendor="Msg Sequence", doc="bit 7: last packet (0x80)")
    node: int = wire("u8", 12, vendor="Node", doc="device node number (copy of the head's)")

    MSG_TYPE: ClassVar[int] = -1

    def __post_init__(self) -> None:
        # enum members (HdCtrl, HeadInf, MessageType, ...) are stored as plain ints
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, IntEnum | IntFlag):
                object.__setattr__(self, f.name, int(value))

    @property
    def is_last(self) -> bool:
        """Last packet of its message (sequence bit 7)."""
        return bool(self.sequence & 0x80)


@message
class VersionData(_Packet):
    """mtVersionData (1), head -> host: answer to mtSendVersion. Layout as the rock
    sonar_tritech driver decodes it (25-byte packet)."""

    TYPE: ClassVar[str] = "mtVersionData"
    MSG_TYPE: ClassVar[int] = MessageType.mtVersionData
    SIZE: ClassVar[int] = 25

    software_version: int = wire("u8", 13, vendor="Software version")
    info_bits: int = wire("u8", 14, vendor="Info bits")
    serial_number: int = wire("u16", 15, vendor="Serial number")
    program_length: int = wire("u32", 17, units="byte", vendor="Program length")
    program_checksum: int = wire("u16", 21, vendor="Program checksum")
    node_id: int = wire("u8", 23, vendor="Node ID")


@message
class Alive(_Packet):
    """mtAlive (4), head -> host, about once a second: clock, transducer angle, state."""

    TYPE: ClassVar[str] = "mtAlive"
    MSG_TYPE: ClassVar[int] = MessageType.mtAlive
    SIZE: ClassVar[int] = 22

    alive_info: int = wire(
        "u8", 13, doc="0x80 while the head has no parameters, 0x00 once configured (observed)"
    )
    head_time: float = wire(
        "u32",
        14,
        scale=1e-3,
        units="s",
        vendor="Head clock (ms)",
        doc="device clock: ms of day as last set by mtSendData, else since power-up",
    )
    transducer_bearing: float = wire(
        "u16", 18, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="Motor position (1/16 grad)"
    )
    head_inf: int = wire("u8", 20, vendor="HeadInf", doc="see HeadInf flags")

    @property
    def inf(self) -> HeadInf:
        """HeadInf as named flags."""
        return HeadInf(self.head_inf)

    @property
    def no_params(self) -> bool:
        """The head needs an mtHeadCommand before it can ping."""
        return bool(self.head_inf & HeadInf.NO_PARAMS)

    @property
    def sent_cfg(self) -> bool:
        """The head acknowledges an mtHeadCommand."""
        return bool(self.head_inf & HeadInf.SENT_CFG)

    @property
    def ready(self) -> bool:
        """Configured and ready for mtSendData (has params, motor on, centred or scanning)."""
        return not self.no_params and bool(self.head_inf & HeadInf.MOTOR_ON)


@message
class ReBoot(_Packet):
    """mtReBoot (16), host -> head: reset; the head answers with mtAlive."""

    TYPE: ClassVar[str] = "mtReBoot"
    MSG_TYPE: ClassVar[int] = MessageType.mtReBoot
    SIZE: ClassVar[int] = 14


@message
class SendVersion(_Packet):
    """mtSendVersion (23), host -> head: asks for mtVersionData."""

    TYPE: ClassVar[str] = "mtSendVersion"
    MSG_TYPE: ClassVar[int] = MessageType.mtSendVersion
    SIZE: ClassVar[int] = 14


@message
class SendBBUser(_Packet):
    """mtSendBBUser (24), host -> head: asks for mtBBUserData (decoded as :class:`SeaNetRaw`)."""

    TYPE: ClassVar[str] = "mtSendBBUser"
    MSG_TYPE: ClassVar[int] = MessageType.mtSendBBUser
    SIZE: ClassVar[int] = 14


@message
class SendData(_Packet):
    """mtSendData (25), host -> head: one ping; the head answers with one mtHeadData."""

    TYPE: ClassVar[str] = "mtSendData"
    MSG_TYPE: ClassVar[int] = MessageType.mtSendData
    SIZE: ClassVar[int] = 18

    time: float = wire(
        "u32",
        13,
        scale=1e-3,
        units="s",
        vendor="Current time (ms)",
        doc="host time of day (s since midnight, ms resolution); sets the head clock",
    )


@message
class V3BGains:
    """The 16-byte "V3B" per-channel gain block appended to a dual-channel mtHeadCommand
    (V3B Params byte 0x1D). Offsets from the packet start."""

    TYPE: ClassVar[str] = "mtHeadCommand.V3B"

    ad_span_ch1: float = wire("u8", 65, scale=_AD_DB_SCALE, units="dB", vendor="ADSpan Chn1")
    ad_span_ch2: float = wire("u8", 66, scale=_AD_DB_SCALE, units="dB", vendor="ADSpan Chn2")
    ad_low_ch1: float = wire("u8", 67, scale=_AD_DB_SCALE, units="dB", vendor="ADLow Chn1")
    ad_low_ch2: float = wire("u8", 68, scale=_AD_DB_SCALE, units="dB", vendor="ADLow Chn2")
    gain_ch1: float = wire("u8", 69, scale=_GAIN_SCALE, units="1", vendor="IGain Chn1")
    gain_ch2: float = wire("u8", 70, scale=_GAIN_SCALE, units="1", vendor="IGain Chn2")
    adc_setpoint_ch1: int = wire("u8", 71, vendor="ADC SetPoint Chn1")
    adc_setpoint_ch2: int = wire("u8", 72, vendor="ADC SetPoint Chn2")
    slope_ch1: int = wire("u16", 73, vendor="Slope Chn1")
    slope_ch2: int = wire("u16", 75, vendor="Slope Chn2")
    slope_delay_ch1: int = wire("u16", 77, vendor="Slope Delay Chn1")
    slope_delay_ch2: int = wire("u16", 79, vendor="Slope Delay Chn2")


@message
class HeadCommand(_Packet):
    """mtHeadCommand (19), host -> head: the scan parameters ("Params", V3B layout).

    66-byte packet for single-channel heads (``v3b_params`` 0x01), 82 bytes with the
    :class:`V3BGains` block (``v3b_params`` 0x1D, ``v3b`` set). Other lengths (such as the
    1-byte "reverse direction" command) decode as :class:`SeaNetRaw`.
    """

    TYPE: ClassVar[str] = "mtHeadCommand"
    MSG_TYPE: ClassVar[int] = MessageType.mtHeadCommand
    SIZE: ClassVar[int] = 66
    SIZE_V3B: ClassVar[int] = 82

    v3b_params: int = wire("u8", 13, vendor="V3B Params", doc="0x01 normal, 0x1D V3B block")
    hd_ctrl: int = wire("u16", 14, vendor="HdCtrl", doc="see HdCtrl flags")
    head_type: int = wire("u8", 16, vendor="HdType", doc="device type (2 imaging, 11 DST)")
    tx_frequency_ch1: float = wire(
        "u32", 17, scale=_HZ_PER_SYNTH_UNIT, units="Hz", vendor="TxN Chn1 (F*2^32/32e6)"
    )
    tx_frequency_ch2: float = wire(
        "u32", 21, scale=_HZ_PER_SYNTH_UNIT, units="Hz", vendor="TxN Chn2 (F*2^32/32e6)"
    )
    rx_frequency_ch1: float = wire(
        "u32",
        25,
        scale=_HZ_PER_SYNTH_UNIT,
        units="Hz",
        vendor="RxN Chn1 ((F+455k)*2^32/32e6)",
        doc="receiver local oscillator = transmit frequency + 455 kHz",
    )
    rx_frequency_ch2: float = wire(
        "u32", 29, scale=_HZ_PER_SYNTH_UNIT, units="Hz", vendor="RxN Chn2 ((F+455k)*2^32/32e6)"
    )
    tx_pulse_length: float = wire("u16", 33, scale=1e-6, units="s", vendor="TxPulseLen (us)")
    range_scale_raw: int = wire(
        "u16",
        35,
        vendor="RangeScale",
        doc="low 14 bits: range x10 in the unit coded by the top 2 bits (0 m, 1 ft, 2 fathom, "
        "3 yd); informative only, ADInterval and NBins set the real range",
    )
    left_limit: float = wire(
        "u16", 37, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="LeftLim (1/16 grad)"
    )
    right_limit: float = wire(
        "u16", 39, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="RightLim (1/16 grad)"
    )
    ad_span: float = wire("u8", 41, scale=_AD_DB_SCALE, units="dB", vendor="ADSpan (255=80dB)")
    ad_low: float = wire("u8", 42, scale=_AD_DB_SCALE, units="dB", vendor="ADLow (255=80dB)")
    gain_ch1: float = wire(
        "u8",
        43,
        scale=_GAIN_SCALE,
        units="1",
        vendor="IGain Chn1 (0..210)",
        doc="initial receiver gain as a fraction (1 = 210 = +80 dB)",
    )
    gain_ch2: float = wire("u8", 44, scale=_GAIN_SCALE, units="1", vendor="IGain Chn2 (0..210)")
    slope_ch1: int = wire("u16", 45, vendor="Slope Chn1 (1/255)")
    slope_ch2: int = wire("u16", 47, vendor="Slope Chn2 (1/255)")
    motor_step_delay: float = wire(
        "u8", 49, scale=1e-5, units="s", vendor="MoTime (10 us)", doc="motor high-speed limit"
    )
    step: float = wire(
        "u8",
        50,
        scale=RAD_PER_ANGLE_UNIT,
        units="rad",
        vendor="StepAngleSize (1/16 grad)",
        doc="angle between pings: 32 low, 16 medium, 8 high, 4 ultimate resolution",
    )
    ad_interval: float = wire(
        "u16",
        51,
        scale=AD_INTERVAL_S,
        units="s",
        vendor="ADInterval (640 ns)",
        doc="sampling interval of one bin",
    )
    n_bins: int = wire("u16", 53, vendor="NBins")
    max_ad_buffer: int = wire("u16", 55, vendor="MaxADbuf")
    lockout: float = wire("u16", 57, scale=1e-6, units="s", vendor="Lockout (us)")
    minor_axis: float = wire(
        "u16",
        59,
        scale=RAD_PER_ANGLE_UNIT,
        units="rad",
        vendor="MinorAxisDir (1/16 grad)",
        doc="1600 (90 deg) for single-axis heads",
    )
    major_axis_pan: int = wire("u8", 61, vendor="MajorAxisPan", doc="1 for sonars")
    ctl2: int = wire("u8", 62, vendor="Ctl2")
    scan_z: int = wire("u16", 63, vendor="ScanZ")
    v3b: V3BGains | None = None

    @property
    def ctrl(self) -> HdCtrl:
        """HdCtrl as named flags."""
        return HdCtrl(self.hd_ctrl)

    adc8on = property(lambda self: bool(self.hd_ctrl & HdCtrl.ADC8ON), doc="8-bit bins")
    continuous = property(lambda self: bool(self.hd_ctrl & HdCtrl.CONTINUOUS), doc="continuous")
    scan_right = property(lambda self: bool(self.hd_ctrl & HdCtrl.SCAN_RIGHT), doc="clockwise")
    invert = property(lambda self: bool(self.hd_ctrl & HdCtrl.INVERT), doc="head inverted")

    @property
    def range_scale(self) -> tuple[float, str]:
        """Range scale as sent: (value, unit name)."""
        value, unit, _ = _range_from_code(self.range_scale_raw)
        return value, unit

    @property
    def range_m(self) -> float:
        """Range scale in metres."""
        return _range_from_code(self.range_scale_raw)[2]

    def bin_length(self, sound_speed: float) -> float:
        """Length of one bin in metres for ``sound_speed`` (m/s)."""
        return bin_length(self.ad_interval, sound_speed)


@message
class HeadData(_Packet):
    """mtHeadData (2), head -> host: one scan line (one ping at one bearing).

    ``bins`` holds one amplitude per bin: 0..255 with 8-bit ADC (``hd_ctrl`` bit 0), else
    0..15 (the wire packs two 4-bit bins per byte, high nibble first). ``appended`` keeps any
    bytes after the bins (head status bit 7) so that encoding is exact.
    """

    TYPE: ClassVar[str] = "mtHeadData"
    MSG_TYPE: ClassVar[int] = MessageType.mtHeadData
    HEADER_SIZE: ClassVar[int] = 44  # bins start here

    device_type: int = wire("u8", 15, vendor="Device type", doc="11 = Micron DST imaging")
    head_status: int = wire("u8", 16, vendor="Head status", doc="see HeadStatus flags")
    sweep_code: int = wire("u8", 17, vendor="Sweep code", doc="see SweepCode")
    hd_ctrl: int = wire("u16", 18, vendor="HdCtrl", doc="see HdCtrl flags")
    range_scale_raw: int = wire(
        "u16", 20, vendor="RangeScale", doc="low 14 bits range x10; top 2 bits unit code"
    )
    tx_frequency: float = wire(
        "u32", 22, scale=_HZ_PER_SYNTH_UNIT, units="Hz", vendor="TxN (F*2^32/32e6)"
    )
    gain: float = wire("u8", 26, scale=_GAIN_SCALE, units="1", vendor="Gain (0..210)")
    slope: int = wire("u16", 27, vendor="Slope (1/255)")
    ad_span: float = wire("u8", 29, scale=_AD_DB_SCALE, units="dB", vendor="ADSpan (255=80dB)")
    ad_low: float = wire("u8", 30, scale=_AD_DB_SCALE, units="dB", vendor="ADLow (255=80dB)")
    heading_offset: float = wire(
        "u16", 31, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="HeadingOffset (1/16 grad)"
    )
    ad_interval: float = wire(
        "u16",
        33,
        scale=AD_INTERVAL_S,
        units="s",
        vendor="ADInterval (640 ns)",
        doc="sampling interval of one bin; bin length = ad_interval * c / 2",
    )
    left_limit: float = wire(
        "u16", 35, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="LeftLim (1/16 grad)"
    )
    right_limit: float = wire(
        "u16", 37, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="RightLim (1/16 grad)"
    )
    step: float = wire("u8", 39, scale=RAD_PER_ANGLE_UNIT, units="rad", vendor="Steps (1/16 grad)")
    bearing: float = wire(
        "u16",
        40,
        scale=RAD_PER_ANGLE_UNIT,
        units="rad",
        vendor="Bearing (1/16 grad)",
        doc="transducer angle of this scan line (0..2pi)",
    )
    bins: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.uint8))
    appended: bytes = b""

    def __post_init__(self) -> None:
        super().__post_init__()
        arr = np.asarray(self.bins)
        if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "iu"):
            raise WireError(f"HeadData.bins: a 1-D integer array, got {arr.dtype}{arr.shape}")
        if arr.size and arr.dtype != np.uint8 and (int(arr.min()) < 0 or int(arr.max()) > 255):
            raise WireError("HeadData.bins: amplitudes must be 0..255")
        out = arr.astype(np.uint8)
        out.flags.writeable = False
        object.__setattr__(self, "bins", out)
        object.__setattr__(self, "appended", bytes(self.appended))

    @property
    def ctrl(self) -> HdCtrl:
        """HdCtrl as named flags."""
        return HdCtrl(self.hd_ctrl)

    @property
    def status(self) -> HeadStatus:
        """Head status as named flags."""
        return HeadStatus(self.head_status)

    adc8on = property(lambda self: bool(self.hd_ctrl & HdCtrl.ADC8ON), doc="8-bit bins")
    continuous = property(lambda self: bool(self.hd_ctrl & HdCtrl.CONTINUOUS), doc="continuous")
    scan_right = property(lambda self: bool(self.hd_ctrl & HdCtrl.SCAN_RIGHT), doc="clockwise")
    invert = property(lambda self: bool(self.hd_ctrl & HdCtrl.INVERT), doc="head inverted")

    @property
    def data_bytes(self) -> int:
        """Bytes the bins take on the wire."""
        return len(self.bins) if self.adc8on else (len(self.bins) + 1) // 2

    @property
    def range_m(self) -> float:
        """Range scale as reported, in metres."""
        return _range_from_code(self.range_scale_raw)[2]

    def bin_length(self, sound_speed: float) -> float:
        """Length of one bin in metres for ``sound_speed`` (m/s)."""
        return bin_length(self.ad_interval, sound_speed)


@message
class SeaNetRaw(_Packet):
    """A SeaNet packet of a type without a table here (mtBBUserData, mtAuxData, ...), or of a
    known type in a layout not tabled (short mtHeadCommand). ``payload`` is every byte from
    offset 13 up to the LF, so encoding gives the packet back exactly."""

    TYPE: ClassVar[str] = "SeaNetRaw"

    msg_type: int = wire("u8", 10, vendor="Message type")
    payload: bytes = b""

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "payload", bytes(self.payload))

    @property
    def type_name(self) -> str:
        """Tritech's name of the message type (``mtType<n>`` when unknown)."""
        try:
            return MessageType(self.msg_type).name
        except ValueError:
            return f"mtType{self.msg_type}"


SeaNetMessage = (
    VersionData
    | HeadData
    | Alive
    | ReBoot
    | HeadCommand
    | SendVersion
    | SendBBUser
    | SendData
    | SeaNetRaw
)

#: message type code -> table
_TABLES: dict[int, type[Any]] = {
    cls.MSG_TYPE: cls
    for cls in (
        VersionData,
        HeadData,
        Alive,
        ReBoot,
        HeadCommand,
        SendVersion,
        SendBBUser,
        SendData,
    )
}


# -- framing ----------------------------------------------------------------------------------
def default_byte_count(msg_type: int, length: int) -> int:
    """The byte-count field (byte 9) for a packet of ``length`` L: 0 in mtHeadData (Tritech's
    single-packet mode marker), else L - 5 (kept to 8 bits)."""
    if msg_type == MessageType.mtHeadData:
        return 0
    return (length - 5) & 0xFF


def _header(buf: bytes | bytearray, start: int, max_size: int) -> int:
    """Judge the header bytes at ``start`` that are present: the packet's total size once
    bytes 0..9 are there, 0 before; :class:`BadFrame` as soon as something is wrong."""
    avail = len(buf) - start
    for k in range(1, min(avail, 5)):
        if buf[start + k] not in _HEX:
            raise BadFrame(
                f"hex_length: {bytes(buf[start + 1 : start + 5])!r} is not 4 upper-case hex digits"
            )
    if avail < 7:
        return 0
    length = int(buf[start + 1 : start + 5], 16)
    binary = buf[start + 5] | buf[start + 6] << 8
    if binary != length:
        raise BadFrame(f"length_mismatch: hex length {length} != binary length {binary}")
    total = length + 6
    if total < MIN_PACKET_SIZE or total > max_size:
        raise BadFrame(f"length: {length} gives a {total}-byte packet (allowed 14..{max_size})")
    if avail < 10:
        return 0
    count = buf[start + 9]
    if count != 0 and count != (length - 5) & 0xFF:
        raise BadFrame(f"byte_count: {count} for length {length} (expected {length - 5} or 0)")
    return total


#: angles on the wire are 1/16 gradian: a full turn is 6400 units
_FULL_TURN = 6400


def _plausible(buf: bytes | bytearray, start: int, total: int) -> None:
    """No checksum on the wire: refuse a whole packet whose fields contradict each other.
    The node byte (12) names the sender (replies) or the addressee (commands), so it is the
    Tx or the Rx node, and the two differ; an mtHeadData's byte count (offset 13) is the
    packet's size less 14, its data bytes (42) fit in it, and its bearing and scan limits are
    angles below a full turn. Reasons: ``node``, ``byte_count``, ``data_bytes``, ``bearing``."""
    tx, rx, node = buf[start + 7], buf[start + 8], buf[start + 12]
    if tx == rx or node not in (tx, rx):
        raise BadFrame(f"node: node {node} with Tx {tx}, Rx {rx}")
    if buf[start + 10] != MessageType.mtHeadData or total < HeadData.HEADER_SIZE + 1:
        return
    count, left, right, bearing, n_data = (
        struct.unpack_from("<H", buf, start + off)[0] for off in (13, 35, 37, 40, 42)
    )
    if count != total - 14:
        raise BadFrame(f"byte_count: mtHeadData count {count}, packet holds {total - 14}")
    if HeadData.HEADER_SIZE + n_data > total - 1:
        raise BadFrame(f"data_bytes: {n_data} data bytes in a {total}-byte mtHeadData")
    if max(left, right, bearing) >= _FULL_TURN:
        raise BadFrame(f"bearing: bearing {bearing}, limits {left}..{right} (1/16 grad)")


def check_plausible(packet: bytes | bytearray) -> None:
    """:class:`BadFrame` when a whole packet's fields contradict each other (see
    :func:`_plausible`; the V4LOG framer judges its records' packets the same way)."""
    _plausible(packet, 0, len(packet))


def _check(buf: bytes | bytearray, start: int, max_size: int, plausible: bool = False) -> int:
    """Total size of the valid packet at ``start``, 0 if more bytes are needed, or BadFrame.

    What can be judged is judged as soon as it arrives, so garbage never holds the search.
    """
    total = _header(buf, start, max_size)
    if total == 0 or len(buf) - start < total:
        return 0
    if buf[start + total - 1] != _LF:
        raise BadFrame(f"terminator: byte {total - 1} is {buf[start + total - 1]:#04x}, not LF")
    if plausible:
        _plausible(buf, start, total)
    # No checksum: a truncated packet followed by another can look complete. Refuse a candidate
    # inside which a whole packet header starts (real bins practically never hold one).
    stop = start + total - 9
    q = buf.find(b"@", start + 1, stop)
    while q >= 0:
        try:
            _header(buf, q, max_size)
        except BadFrame:
            q = buf.find(b"@", q + 1, stop)
            continue
        raise BadFrame(f"overlap: a packet header starts {q - start} bytes into this one")
    return total


def packet_length(frame: bytes | bytearray) -> int:
    """Total size of the valid SeaNet packet at the start of ``frame`` (DecodeError if none)."""
    if len(frame) < MIN_PACKET_SIZE or frame[0] != _SYNC:
        raise DecodeError(f"not a SeaNet packet: {len(frame)} bytes starting {bytes(frame[:5])!r}")
    try:
        total = _check(frame, 0, max(MAX_PACKET_SIZE, len(frame)))
    except BadFrame as exc:
        raise DecodeError(f"bad SeaNet packet: {exc.reason}") from None
    if total == 0 or total != len(frame):
        raise DecodeError(f"SeaNet packet of {len(frame)} bytes declares {total or 'more'} bytes")
    return total


class SeaNetFramer(Framer):
    """Finds SeaNet packets in a byte stream ('@' sync; see the module doc for the checks)."""

    name = "seanet"
    sync = b"@"
    max_frame_size = MAX_PACKET_SIZE
    #: refuse packets whose fields contradict each other (:func:`_plausible`); off: only the
    #: structure (lengths, terminator) is judged, as :func:`packet_length` does
    plausibility = True

    def check(self, buf: bytearray, start: int) -> int:
        return _check(buf, start, self.max_frame_size, plausible=self.plausibility)


# -- codec ------------------------------------------------------------------------------------
def decode(frame: bytes | bytearray | memoryview) -> list[SeaNetMessage]:
    """One SeaNet packet (as the framer delivers it) -> [message].

    Raises :class:`~auvgw.drivers.framing.DecodeError` naming the field and offset when the
    packet's content contradicts its length.
    """
    buf = bytes(frame)
    total = packet_length(buf)
    msg_type = buf[10]
    cls = _TABLES.get(msg_type)
    try:
        if cls is HeadData:
            return [_decode_head_data(buf, total)]
        if cls is HeadCommand and total in (HeadCommand.SIZE, HeadCommand.SIZE_V3B):
            v3b = decode_block(V3BGains, buf) if total == HeadCommand.SIZE_V3B else None
            return [decode_block(HeadCommand, buf, v3b=v3b)]
        if cls is not None and cls is not HeadCommand:
            if total != cls.SIZE:
                raise DecodeError(f"{cls.TYPE}: packet of {total} bytes, the table has {cls.SIZE}")
            return [decode_block(cls, buf)]
        return [decode_block(SeaNetRaw, buf, payload=buf[13 : total - 1])]
    except WireError as exc:
        raise DecodeError(str(exc)) from None


def _decode_head_data(buf: bytes, total: int) -> HeadData:
    if total < HeadData.HEADER_SIZE + 1:
        raise DecodeError(f"mtHeadData: packet of {total} bytes, the header alone needs 45")
    (count,) = struct.unpack_from("<H", buf, 13)
    if count != total - 14:
        raise DecodeError(
            f"mtHeadData: total byte count (offset 13) is {count}, the packet holds {total - 14}"
        )
    (n_data,) = struct.unpack_from("<H", buf, 42)
    end = HeadData.HEADER_SIZE + n_data
    if end > total - 1:
        raise DecodeError(
            f"mtHeadData: data bytes (offset 42) = {n_data}, only {total - 45} bytes in the packet"
        )
    data = np.frombuffer(buf, np.uint8, n_data, HeadData.HEADER_SIZE)
    hd_ctrl = buf[18] | buf[19] << 8
    if hd_ctrl & HdCtrl.ADC8ON:
        bins = data.copy()
    else:
        bins = np.empty(2 * n_data, np.uint8)
        bins[0::2] = data >> 4
        bins[1::2] = data & 0x0F
    return decode_block(HeadData, buf, bins=bins, appended=buf[end : total - 1])


def _packet_size(msg: SeaNetMessage) -> int:
    if isinstance(msg, HeadData):
        return HeadData.HEADER_SIZE + msg.data_bytes + len(msg.appended) + 1
    if isinstance(msg, HeadCommand):
        return HeadCommand.SIZE_V3B if msg.v3b is not None else HeadCommand.SIZE
    if isinstance(msg, SeaNetRaw):
        return 13 + len(msg.payload) + 1
    return type(msg).SIZE


def encode(msg: SeaNetMessage) -> bytes:
    """A message -> the whole SeaNet packet ('@', both lengths, header, payload, LF)."""
    total = _packet_size(msg)
    length = total - 6
    if length > 0xFFFF:
        raise WireError(f"{msg.TYPE}: packet of {total} bytes exceeds the 16-bit length")
    buf = bytearray(total)
    buf[0] = _SYNC
    buf[1:5] = b"%04X" % length
    struct.pack_into("<H", buf, 5, length)
    if not isinstance(msg, SeaNetRaw):
        buf[10] = type(msg).MSG_TYPE
    encode_block(msg, buf)
    if isinstance(msg, HeadData):
        _encode_bins(msg, buf)
    elif isinstance(msg, HeadCommand) and msg.v3b is not None:
        encode_block(msg.v3b, buf)
    elif isinstance(msg, SeaNetRaw):
        buf[13 : total - 1] = msg.payload
    buf[-1] = _LF
    return bytes(buf)


def _encode_bins(msg: HeadData, buf: bytearray) -> None:
    struct.pack_into("<H", buf, 13, len(buf) - 14)
    struct.pack_into("<H", buf, 42, msg.data_bytes)
    bins = msg.bins
    start = HeadData.HEADER_SIZE
    if msg.adc8on:
        data = bins
    else:
        if len(bins) % 2 or (bins.size and int(bins.max()) > 15):
            raise WireError(
                "HeadData.bins: 4-bit mode (HdCtrl bit 0 clear) needs an even number of bins, "
                f"each 0..15 (got {len(bins)}, max {int(bins.max()) if bins.size else 0})"
            )
        data = (bins[0::2] << 4) | bins[1::2]
    buf[start : start + len(data)] = data.tobytes()
    end = start + len(data)
    buf[end : end + len(msg.appended)] = msg.appended


# -- builders (what a host and an emulated head send) -----------------------------------------
_SCALES: dict[type, dict[str, tuple[float, float]]] = {}


def _from_raw(cls: type[Any], raw: dict[str, Any], extra: dict[str, Any]) -> Any:
    """Build ``cls`` from raw wire values (SI = raw * scale + add, exactly as decoding does),
    so a built message equals its own decode."""
    scales = _SCALES.get(cls)
    if scales is None:
        scales = _SCALES[cls] = {r["name"]: (r["scale"], r["add"]) for r in table_rows(cls)}
    values = {}
    for name, value in raw.items():
        scale, add = scales[name]
        values[name] = value * scale + add if (scale != 1.0 or add != 0.0) else value
    return cls(**values, **extra)


def _fill(cls: type[Any], size: int, tx: int, rx: int, raw: dict[str, Any], **extra: Any) -> Any:
    header = {
        "tx_node": tx,
        "rx_node": rx,
        "byte_count": default_byte_count(cls.MSG_TYPE, size - 6),
        "sequence": 0x80,
        "node": rx if tx == HOST_NODE else tx,
    }
    return _from_raw(cls, header | raw, extra)


def reboot(*, tx: int = HOST_NODE, rx: int = HEAD_NODE) -> ReBoot:
    """mtReBoot from the host to a head."""
    return _fill(ReBoot, ReBoot.SIZE, tx, rx, {})


def send_version(*, tx: int = HOST_NODE, rx: int = HEAD_NODE) -> SendVersion:
    """mtSendVersion from the host to a head."""
    return _fill(SendVersion, SendVersion.SIZE, tx, rx, {})


def send_bb_user(*, tx: int = HOST_NODE, rx: int = HEAD_NODE) -> SendBBUser:
    """mtSendBBUser from the host to a head."""
    return _fill(SendBBUser, SendBBUser.SIZE, tx, rx, {})


def send_data(time_ms: int, *, tx: int = HOST_NODE, rx: int = HEAD_NODE) -> SendData:
    """mtSendData: ask for one ping; ``time_ms`` is the host time of day in ms (0 allowed)."""
    return _fill(SendData, SendData.SIZE, tx, rx, {"time": int(time_ms) & 0xFFFFFFFF})


def alive(
    head_time: float,
    *,
    head_inf: int = HeadInf.CENTRED | HeadInf.MOTOR_ON,
    transducer_bearing: float = 0.0,
    alive_info: int | None = None,
    tx: int = HEAD_NODE,
    rx: int = HOST_NODE,
) -> Alive:
    """mtAlive from a head: ``head_time`` s on its clock (ms resolution), ``transducer_bearing``
    in rad. ``alive_info`` defaults to 0x80 while ``head_inf`` says NO_PARAMS, else 0."""
    if alive_info is None:
        alive_info = 0x80 if head_inf & HeadInf.NO_PARAMS else 0
    return _fill(
        Alive,
        Alive.SIZE,
        tx,
        rx,
        {
            "alive_info": alive_info,
            "head_time": round(head_time * 1e3) & 0xFFFFFFFF,
            "transducer_bearing": rad_to_angle(transducer_bearing),
            "head_inf": int(head_inf),
        },
    )


def version_data(
    *,
    software_version: int = 1,
    info_bits: int = 0,
    serial_number: int = 0,
    program_length: int = 0,
    program_checksum: int = 0,
    tx: int = HEAD_NODE,
    rx: int = HOST_NODE,
) -> VersionData:
    """mtVersionData from a head."""
    return _fill(
        VersionData,
        VersionData.SIZE,
        tx,
        rx,
        {
            "software_version": software_version,
            "info_bits": info_bits,
            "serial_number": serial_number,
            "program_length": program_length,
            "program_checksum": program_checksum,
            "node_id": tx,
        },
    )


def head_command(
    *,
    range_m: float = 30.0,
    n_bins: int = 300,
    sound_speed: float = 1500.0,
    adc8on: bool = True,
    continuous: bool = True,
    scan_right: bool = True,
    invert: bool = False,
    left_limit: float = 0.0,
    right_limit: float = 0.0,
    step: float = 32 * RAD_PER_ANGLE_UNIT,
    gain: float = 0.4,
    ad_span: float = 24.0,
    ad_low: float = 13.0,
    frequency_hz: float = 675_000.0,
    head_type: int = 11,
    hd_ctrl: int | None = None,
    v3b: V3BGains | None = None,
    tx: int = HOST_NODE,
    rx: int = HEAD_NODE,
) -> HeadCommand:
    """mtHeadCommand for an imaging head, from SI settings.

    ``range_m`` over ``n_bins`` at ``sound_speed`` (m/s) sets ADInterval = 2 * range / c / n_bins
    in 640 ns units (rounded, at least 1); angles in rad (rounded to 1/16 gradian; limits apply
    to sector scans only); ``gain`` 0..1 of the receiver's 80 dB; ``ad_span`` / ``ad_low`` in dB
    map the echo levels onto 4-bit bins; the transmit pulse is (range + 10 m) * 2.5 us/m, within
    50..350 us (Tritech's rule of thumb). ``hd_ctrl`` overrides the flag word built from the
    booleans (RAW, HAS_MOTOR and REPLY_ASL are always set, as Tritech asks).
    """
    if hd_ctrl is None:
        flags = HdCtrl.RAW | HdCtrl.HAS_MOTOR | HdCtrl.REPLY_ASL
        for on, flag in (
            (adc8on, HdCtrl.ADC8ON),
            (continuous, HdCtrl.CONTINUOUS),
            (scan_right, HdCtrl.SCAN_RIGHT),
            (invert, HdCtrl.INVERT),
        ):
            if on:
                flags |= flag
        hd_ctrl = int(flags)
    tx_n = round(frequency_hz / _HZ_PER_SYNTH_UNIT)
    rx_n = round((frequency_hz + RX_IF_HZ) / _HZ_PER_SYNTH_UNIT)
    gain_n = round(gain / _GAIN_SCALE)
    size = HeadCommand.SIZE_V3B if v3b is not None else HeadCommand.SIZE
    return _fill(
        HeadCommand,
        size,
        tx,
        rx,
        {
            "v3b_params": 0x1D if v3b is not None else 0x01,
            "hd_ctrl": hd_ctrl,
            "head_type": head_type,
            "tx_frequency_ch1": tx_n,
            "tx_frequency_ch2": tx_n,
            "rx_frequency_ch1": rx_n,
            "rx_frequency_ch2": rx_n,
            "tx_pulse_length": min(350, max(50, round((range_m + 10.0) * 2.5))),
            "range_scale_raw": round(range_m * 10.0) & 0x3FFF,
            "left_limit": rad_to_angle(left_limit),
            "right_limit": rad_to_angle(right_limit),
            "ad_span": round(ad_span / _AD_DB_SCALE),
            "ad_low": round(ad_low / _AD_DB_SCALE),
            "gain_ch1": gain_n,
            "gain_ch2": gain_n,
            "slope_ch1": 125,
            "slope_ch2": 125,
            "motor_step_delay": 25,
            "step": round(step / RAD_PER_ANGLE_UNIT),
            "ad_interval": max(1, round(2.0 * range_m / sound_speed / n_bins / AD_INTERVAL_S)),
            "n_bins": n_bins,
            "max_ad_buffer": 500,
            "lockout": 100,
            "minor_axis": 1600,
            "major_axis_pan": 1,
            "ctl2": 0,
            "scan_z": 0,
        },
        v3b=v3b,
    )


#: the mtHeadCommand settings a head repeats in every mtHeadData, under the same field names
HEAD_DATA_ECHOES = (
    "hd_ctrl", "range_scale_raw", "ad_span", "ad_low", "ad_interval", "left_limit", "right_limit",
    "step",
)  # fmt: skip
#: ... and those it repeats from the channel in use (mtHeadCommand's ``<name>_ch1``/``_ch2``)
HEAD_DATA_CHANNEL_ECHOES = ("tx_frequency", "gain", "slope")


def head_data(
    bins: Sequence[int] | np.ndarray,
    bearing: float,
    *,
    config: HeadCommand | None = None,
    head_status: int = 0,
    sweep_code: int = SweepCode.NORMAL,
    heading_offset: float = 0.0,
    device_type: int = 11,
    appended: bytes = b"",
    tx: int = HEAD_NODE,
    rx: int = HOST_NODE,
) -> HeadData:
    """mtHeadData a head sends for one ping at ``bearing`` (rad), echoing the settings of its
    last mtHeadCommand ``config`` (default :func:`head_command`). ``bins`` are amplitudes 0..255
    (8-bit) or 0..15 (4-bit, an even count), as ``config``'s HdCtrl bit 0 says."""
    cfg = config if config is not None else head_command()
    chan2 = bool(cfg.hd_ctrl & HdCtrl.CHAN2)
    ch = "ch2" if chan2 else "ch1"
    return _fill(
        HeadData,
        0,
        tx,
        rx,
        {
            "device_type": device_type,
            "head_status": head_status,
            "sweep_code": int(sweep_code),
            "heading_offset": rad_to_angle(heading_offset),
            "bearing": rad_to_angle(bearing),
        },
        bins=np.asarray(bins),
        appended=appended,
        # settings echoed from the command, already in SI
        **{name: getattr(cfg, name) for name in HEAD_DATA_ECHOES},
        **{name: getattr(cfg, f"{name}_{ch}") for name in HEAD_DATA_CHANNEL_ECHOES},
    )


FORMAT = Format(
    name="seanet",
    summary="Tritech SeaNet packets (Micron / SeaKing scanning sonar, '@' framed)",
    framer=SeaNetFramer,
    decode=decode,
    encode=encode,
)
