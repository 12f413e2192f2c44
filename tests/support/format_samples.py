"""Good frames of every registered format, as the codecs (or the real PD0 recording) make them,
and the reference builders they come from: shared by the format tests
(tests/drivers/test_<format>.py import their samples from here), tests/drivers/test_codec_laws.py
(every format of the device registry must have samples here),
tests/service/test_framers_never_stall.py and benchmarks/reliability.py."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from functools import reduce
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.drivers import kongsberg as kb
from auvgw.drivers import seanet as sn
from auvgw.drivers.seanet import v4log as v4
from auvgw.testing import pd0_frames

STREAM_FORMATS = ("pd0", "pd6", "seanet", "kongsberg", "geoswath", "hn100", "ms3a", "acoustic")

#: device time of the samples, s since the Unix epoch (2023-11-14 22:13:20 UTC)
T0 = 1_700_000_000.0

# -- acoustic beacon ---------------------------------------------------------------------------

#: a reference acoustic reply line (range 123.45 m, bearing -45.3 deg, depression 12.0 deg)
ACOUSTIC_LINE = b"$ACRB,000042,0123.45,-045.3,+12.0,1*11\r\n"


def _acoustic(i: int) -> bytes:
    from auvgw.drivers.acoustic import CODEC

    msg = CODEC.message_type(counter=i, range=10.0 + 37.25 * i, bearing=0.5 - 0.3 * i,
                             depression=0.1 * i, beacon=1 + i % 3)  # fmt: skip
    return CODEC.encode(msg)


# -- PD6 ---------------------------------------------------------------------------------------

#: one Pathfinder PD6 ensemble, fields at the widths of the guide's Table 50
PD6_LINES = [
    b":SA, -2.31, +1.92, 75.20\r\n",
    b":TS,04081111563644,35.0,+21.0,   0.0,1524.0,  0\r\n",
    b":WI,-32768,-32768,-32768,-32768,V\r\n",
    b":WS,-32768,-32768,-32768,V\r\n",
    b":WE,-32768,-32768,-32768,V\r\n",
    b":WD,       +0.00,       +0.00,       +0.00,  20.00,  0.00\r\n",
    b":BI,   +24,    -6,   -20,    -4,A\r\n",
    b":BS,   -13,   +21,   -20,A\r\n",
    b":BE,   +17,   +18,   -20,A\r\n",
    b":BD,       -0.02,       -0.03,       +0.02,   7.13,  0.21\r\n",
    b":HM,G,L, 123,   7,24.015,1.503,15.978\r\n",
]

# -- HN-100: independent reference implementation of the shipped layout (not the codec) --------


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF), bit by bit."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def ref_frame(seq: int, status: int, ticks: int, ints: list[int]) -> bytes:
    """sync AA 48 | u16 length 68 | u16 seq | u16 status | u32 time | 15 x s32 | crc16 LE."""
    body = struct.pack("<HHHI15i", 68, seq, status, ticks, *ints)
    return b"\xaa\x48" + body + struct.pack("<H", crc16_ccitt_false(body))


REF_INTS = [
    100_000,  # roll 0.1 rad
    -50_000,  # pitch -0.05 rad
    3_000_000,  # heading 3.0 rad
    10_000,  # rate_x 0.01 rad/s
    -20_000,
    30_000,
    10_000,  # accel_x 0.1 m/s^2
    20_000,
    -981_000,  # accel_z -9.81 m/s^2
    15_000,  # vel_n 1.5 m/s
    -2_000,
    100,
    431_234_567,  # latitude 43.1234567 deg
    -59_876_543,  # longitude -5.9876543 deg
    123_456,  # depth 123.456 m
]


def hn100_frames(n: int, start: int = 0) -> list[bytes]:
    """n valid HN-100 frames whose bytes contain no sync pair except at their start."""
    out = []
    for i in range(start, start + n):
        ints = [v + 7 * i for v in REF_INTS]
        f = ref_frame(i, 0b0101, 1000 + 100 * i, ints)
        assert f.find(b"\xaa\x48", 1) < 0
        out.append(f)
    return out


# -- MS3A: independent reference of the shipped line (not the codec) ---------------------------


def xor_hex(body: str) -> str:
    """NMEA-style checksum of ``body``: XOR of its characters, two upper-case hex digits."""
    return f"{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"


def nt_text(raw: int) -> str:
    """raw in 0.1 nT -> sign, 6 integer digits, point, 1 decimal."""
    sign = "-" if raw < 0 else "+"
    return f"{sign}{abs(raw) // 10:06d}.{abs(raw) % 10}"


def ref_line(counter: int, bx: int, by: int, bz: int, body: str | None = None) -> bytes:
    """An MS3A line (field values in 0.1 nT), or ``$body*checksum`` when ``body`` is given."""
    if body is None:
        body = f"MS3A,{counter:06d},{nt_text(bx)},{nt_text(by)},{nt_text(bz)}"
    return f"${body}*{xor_hex(body)}\r\n".encode()


MS3A_LINES = [ref_line(i, 213_456 + i, -12_345 - i, 432_100 + 3 * i) for i in range(4)]

# -- Kongsberg ---------------------------------------------------------------------------------


def xyz(i: int, n: int, **kw: Any) -> kb.XYZ88:
    """XYZ 88 datagram ``i`` (0.5 s apart from :data:`T0`) with ``n`` beams; ``kw`` overrides."""
    k = np.arange(n)
    args: dict[str, Any] = dict(
        time=T0 + i * 0.5,
        depth=20.0 + 0.25 * k,
        across=-30.0 + 2.5 * k,
        along=0.125 * (k % 3),
        quality=(k * 7) % 200,
        reflectivity=-25.0 + 0.1 * k,
        detection_window=8 + k,
        heading=math.radians(45.0),
        sound_speed=1490.0,
        transducer_depth=1.5,
        sampling_frequency=20000.0,
        ping_counter=i,
        serial=140,
    )
    args.update(kw)
    return kb.make_xyz88(**args)


def dep(i: int, n: int, **kw: Any) -> kb.Depth:
    """Depth datagram ``i`` (0.5 s apart from :data:`T0`) with ``n`` beams; ``kw`` overrides."""
    k = np.arange(n)
    args: dict[str, Any] = dict(
        time=T0 + i * 0.5,
        depth=15.0 + 0.5 * k,
        across=-10.0 + 1.0 * k,
        along=0.05 * k,
        depression=np.radians(60.0 + k),
        azimuth=np.radians(90.0 + 0 * k),
        range_samples=300 + k,
        quality=50,
        detection_window=16,
        reflectivity=-20.0,
        ping_counter=i,
        serial=7,
        sampling_rate=14293,
    )
    args.update(kw)
    return kb.make_depth(**args)


def clean(make: Callable[[int], Any], start: int) -> bytes:
    """The first datagram from ``make(counter)`` whose only 0x02 byte is its STX, so every
    expected count of a corrupted fixture follows from the fixture alone."""
    for counter in range(start, start + 500):
        b = kb.encode(make(counter))
        if b.count(0x02) == 1:
            return b
    raise AssertionError("no clean datagram")


KONGSBERG_FRAMES = [
    clean(lambda c: xyz(c, 5, ping_counter=c), 10),
    clean(lambda c: dep(c, 4, ping_counter=c, beam_number=[10, 11, 12, 13]), 20),
    clean(lambda c: xyz(c, 8, ping_counter=c), 30),
    clean(lambda c: dep(c, 3, ping_counter=c, beam_number=[20, 21, 22]), 40),
]

# -- SeaNet and its .V4LOG container -----------------------------------------------------------


def sample_messages() -> list[sn.SeaNetMessage]:
    """SeaNet messages of every kind the codec knows (8- and 4-bit head data, a raw aux)."""
    cfg8 = sn.head_command(range_m=10.0, n_bins=50)
    cfg4 = sn.head_command(range_m=10.0, n_bins=50, adc8on=False)
    return [
        sn.alive(12.345, head_inf=sn.HeadInf.NO_PARAMS | sn.HeadInf.MOTOR_ON),
        sn.reboot(),
        sn.send_version(),
        sn.version_data(software_version=3, serial_number=1234, program_length=65000),
        sn.send_bb_user(),
        cfg8,
        sn.alive(13.0, head_inf=sn.HeadInf.SENT_CFG | sn.HeadInf.MOTOR_ON | sn.HeadInf.CENTRED),
        sn.send_data(56_000_123),
        sn.head_data(np.arange(50) % 60, 0.25, config=cfg8),
        sn.send_data(56_000_300),
        sn.head_data(np.arange(50) % 16, 0.30, config=cfg4),
        sn.SeaNetRaw(
            tx_node=2,
            rx_node=255,
            byte_count=11,
            sequence=0x80,
            node=2,
            msg_type=sn.MessageType.mtAuxData,
            payload=b"\x01\x02\x03\x04\x05\x06\x07\x08",
        ),
    ]


def sample_items() -> list[tuple[float, sn.SeaNetMessage]]:
    """(host time s since the epoch, message) pairs of a .V4LOG, from :data:`T0` on."""
    cfg = sn.head_command(range_m=20.0, n_bins=40)
    cfg4 = sn.head_command(range_m=20.0, n_bins=40, adc8on=False)
    return [
        (T0 + 0.0, sn.alive(100.0, head_inf=sn.HeadInf.NO_PARAMS | sn.HeadInf.MOTOR_ON)),
        (T0 + 0.1, sn.reboot()),
        (T0 + 0.2, sn.send_version()),
        (T0 + 0.3, sn.version_data(serial_number=4321)),
        (T0 + 0.4, cfg),
        (T0 + 1.0, sn.send_data(80_001_000)),
        (T0 + 1.1, sn.head_data(np.arange(40) % 50, 1.0, config=cfg)),
        (T0 + 1.2, sn.send_data(80_001_200)),
        (T0 + 1.3, sn.head_data(np.arange(40) % 16, 1.1, config=cfg4)),
        (
            T0 + 1.4,
            sn.SeaNetRaw(
                tx_node=2,
                rx_node=255,
                byte_count=8,
                sequence=0x80,
                node=2,
                msg_type=8,
                payload=b"aux!\x01",
            ),
        ),
    ]


# -- GeoSwath Plus pings -----------------------------------------------------------------------


def geoswath_frames(n: int = 4) -> list[bytes]:
    """Broadcast pings, sides alternating, 0.25 s apart: RAA samples, MRU, NAV, GYRO, MINISVS,
    AUXDATA records and raw strings (the shipped table)."""
    from auvgw.drivers.geoswath import default_codec

    codec = default_codec()
    rng = np.random.default_rng(31)
    out = []
    for k in range(n):
        m = 40 + 17 * k
        raa = {"time": np.arange(m) * 3 + 50, "sine": rng.integers(-30000, 30000, m),
               "amplitude": rng.integers(0, 4000, m)}  # fmt: skip
        arrays = {
            "raa": raa,
            "mru": {"roll": [1.5, 1.25], "pitch": [-0.5, -0.25], "time_stamp": [T0 + k, T0 + k]},
            "nav": {"x": [500123.25 + k], "y": [6201234.5], "quality": [4], "time": [T0 + k]},
            "gyro": {"heading": [123.5], "time_stamp": [T0 + k]},
            "minisvs": {"velocity": [1493.5], "time_stamp": [T0 + k]},
            "aux1": {"type": [k], "spare": [[1, 2, 3]], "value": [0.5 * k]},
        }
        strings = [b"$GPGGA,1*00\r\n" * (k % 2), b"", b"$HEHDT,123.5,T*00\r\n", b"", b"", b"", b""]
        header = {"ping_number": k, "ping_time": T0 + 0.25 * k, "side": k % 2,
                  "previous_ping_position": -1, "ping_length": 400,
                  "sample_interval": 12}  # fmt: skip
        out.append(codec.encode(codec.make_ping(header, arrays, strings)))
    return out


# -- every format ------------------------------------------------------------------------------


def samples(fmt: str, shared_data: Path) -> list[bytes]:
    """Good frames of a byte-stream format (one of :data:`STREAM_FORMATS`)."""
    if fmt == "pd0":
        return pd0_frames(shared_data, 8)
    if fmt == "seanet":
        return [sn.encode(m) for m in sample_messages()]
    if fmt == "kongsberg":
        return list(KONGSBERG_FRAMES)
    if fmt == "geoswath":
        return geoswath_frames()
    if fmt == "hn100":
        return hn100_frames(8)
    if fmt == "ms3a":
        return list(MS3A_LINES)
    if fmt == "pd6":
        return list(PD6_LINES)
    if fmt == "acoustic":
        return [ACOUSTIC_LINE, *(_acoustic(i) for i in range(5))]
    raise KeyError(fmt)


def stream_samples(fmt: str, shared_data: Path | None, tmp: Path) -> tuple[bytes, list[bytes]]:
    """What every stream of ``fmt`` starts with (a container's file header, else nothing) and
    good frames of it: the samples of every format of the device registry."""
    if fmt == "v4log":
        head, records = v4log_records(tmp / "samples.V4LOG", repeats=1)
        # a log still being written: no config section, the records run to the end of the file
        return head[:48] + struct.pack("<I", 0) + head[52:], records
    return b"", samples(fmt, shared_data)  # type: ignore[arg-type]


def v4log_records(path: Path, repeats: int = 3) -> tuple[bytes, list[bytes]]:
    """A .V4LOG written at ``path`` (the sample items ``repeats`` times, 10 s apart): its header
    bytes (up to the first record) and its records."""
    v4.write_v4log(path, [(t + 10.0 * r, m) for r in range(repeats) for t, m in sample_items()])
    data = path.read_bytes()
    hdr = v4.read_header(path)
    end = hdr.config_offset if hdr.config_offset > hdr.data_offset else len(data)
    records, pos = [], hdr.data_offset
    while pos < end:
        (n,) = struct.unpack_from("<H", data, pos)
        records.append(data[pos : pos + n])
        pos += n
    return data[: hdr.data_offset], records
