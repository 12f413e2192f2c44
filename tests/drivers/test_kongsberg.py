"""Kongsberg EM datagrams: XYZ 88, Depth, generic types, framer, CLI."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import random
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.drivers import kongsberg as kb
from auvgw.drivers.framing import BadFrame, DecodeError, ErrorPolicy, FrameError
from auvgw.drivers.spec import WireError, raw_value, to_jsonable
from auvgw.testing.format_samples import KONGSBERG_FRAMES as G
from auvgw.testing.format_samples import T0, dep, xyz

AUVGW = Path(sys.executable).parent / "auvgw"
CLI = [str(AUVGW)] if AUVGW.exists() else [sys.executable, "-m", "auvgw.cli"]


def wire_of(cls: type, name: str):
    return next(f.metadata["wire"] for f in dataclasses.fields(cls) if f.name == name)


def cks(frame: bytes) -> int:
    """Independent checksum: bytes after STX (index 4) up to ETX (index -3), mod 65536."""
    return sum(frame[5:-3]) & 0xFFFF


def generic(type_id: int, body: bytes, counter: int = 1) -> bytes:
    msg = kb.KongsbergDatagram(
        model=2040, date=20231114, time_since_midnight=80000.0, counter=counter, serial=140,
        type_id=type_id, body=body,
    )
    return kb.encode(msg)


# -- round trips -----------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [0, 1, 2, 7, 8, 255, 256])
def test_xyz88_round_trip_odd_and_even_beam_counts(n: int) -> None:
    m = xyz(3, n)
    b = kb.encode(m)
    assert len(b) == 44 + 20 * n
    assert struct.unpack_from("<I", b, 0)[0] == 40 + 20 * n
    assert (40 + 20 * n) % 2 == 0
    assert b[40 + 20 * n] == 0  # the spare byte before ETX, present for every beam count
    assert b[-3] == 0x03 and struct.unpack_from("<H", b, len(b) - 2)[0] == cks(b)
    back = kb.decode(b)
    assert len(back) == 1 and back[0] == m
    assert kb.encode(back[0]) == b
    assert back[0].n_beams == n == back[0].beams.n_beams


@pytest.mark.parametrize("n", [0, 1, 2, 15, 16, 255])
def test_depth_round_trip_odd_and_even_beam_counts(n: int) -> None:
    m = dep(2, n, transducer_depth=700.25)
    b = kb.encode(m)
    assert len(b) == 36 + 16 * n
    assert struct.unpack_from("<I", b, 0)[0] == 32 + 16 * n  # always even, no spare needed
    assert struct.unpack_from("<b", b, 32 + 16 * n)[0] == 1  # offset multiplier
    assert b[-3] == 0x03 and struct.unpack_from("<H", b, len(b) - 2)[0] == cks(b)
    (back,) = kb.decode(b)
    assert back == m and kb.encode(back) == b
    assert back.transducer_depth == pytest.approx(700.25 - 655.36)
    assert back.transducer_depth_total == pytest.approx(700.25)


def test_depth_signedness_follows_model() -> None:
    deep = dep(0, 3, depth=[400.0, 500.0, 600.0], model=300)  # EM 300: unsigned depth
    (back,) = kb.decode(kb.encode(deep))
    np.testing.assert_allclose(back.beams.depth, [400.0, 500.0, 600.0])
    assert raw_value(back.beams, "depth").tolist() == [40000, 50000, 60000]
    up = dep(0, 2, depth=[-2.5, 3.0], model=3000)  # EM 3000: signed, a beam looking up
    (back,) = kb.decode(kb.encode(up))
    np.testing.assert_allclose(back.beams.depth, [-2.5, 3.0])
    with pytest.raises(WireError, match=r"depth: values outside s16"):
        dep(0, 1, depth=[600.0], model=3000)


def test_depth_resolution_scales_the_beam_table() -> None:
    m = dep(0, 3, depth=[10.0, 20.0, 30.1], across=[-4.0, 0.0, 4.2], z_resolution=0.1,
            xy_resolution=0.2)
    b = kb.encode(m)
    assert b[28] == 10 and b[29] == 20
    assert [struct.unpack_from("<h", b, 32 + 16 * i)[0] for i in range(3)] == [100, 200, 301]
    assert [struct.unpack_from("<h", b, 34 + 16 * i)[0] for i in range(3)] == [-20, 0, 21]
    (back,) = kb.decode(b)
    np.testing.assert_allclose(back.beams.depth, [10.0, 20.0, 30.1])
    np.testing.assert_allclose(back.beams.across, [-4.0, 0.0, 4.2])
    np.testing.assert_allclose(back.xyz[:, 2], [10.0, 20.0, 30.1])
    assert type(back.beams).__name__ == "DepthBeams_z10cm_xy20cm_s16"


def test_spare_bytes_are_kept_for_exact_re_encode() -> None:
    m = dataclasses.replace(xyz(0, 3), spare=b"\x01\x04\x09",
                            trailer=kb.XYZ88Trailer(spare=0x55))
    b = kb.encode(m)
    assert b[37:40] == b"\x01\x04\x09" and b[40 + 60] == 0x55
    (back,) = kb.decode(b)
    assert back.spare == b"\x01\x04\x09" and back.trailer.spare == 0x55
    assert kb.encode(back) == b


def test_generic_datagram_keeps_body_and_odd_payload_spare() -> None:
    nmea = b"$GPGGA,120000.00,5900.0000,N,01000.0000,E,1,08,0.9,10.0,M,,,,*47"
    # position-like body: fixed part + NMEA + the spare byte that makes the length even
    body = struct.pack("<iiHHHHBB", 59 * 20_000_000, 10 * 10_000_000, 50, 300, 9000, 9000,
                       0x81, len(nmea)) + nmea
    assert (16 + len(body) + 3) % 2 == 1
    body += b"\x00"
    b = generic(0x50, body)
    assert (len(b) - 4) % 2 == 0
    (m,) = kb.decode(b)
    assert isinstance(m, kb.KongsbergDatagram)
    assert m.type_id == 0x50 and m.type_name == "Position" and m.body == body
    assert m.model == 2040 and m.counter == 1
    assert m.device_time == T0  # 2023-11-14 + 80000 s = 22:13:20 UTC
    assert kb.encode(m) == b
    with pytest.raises(WireError, match="odd"):
        kb.encode(dataclasses.replace(m, body=body + b"\x00"))


def test_device_time_and_split_time() -> None:
    date, secs = kb.split_time(T0 + 0.1234)
    assert date == 20231114 and secs == pytest.approx(22 * 3600 + 13 * 60 + 20.123)
    m = xyz(0, 1, time=T0 + 0.1234)
    assert m.date == 20231114 and raw_value(m, "time_since_midnight") == 80000123
    assert m.device_time == pytest.approx(T0 + 0.123, abs=1e-9)
    assert math.isnan(dataclasses.replace(m, date=20231341).device_time)
    assert kb.split_time(86400.0 * 365 - 0.0006) == (19701231, 86399.999)
    assert kb.split_time(86400.0 * 365 - 0.0004) == (19710101, 0.0)


def test_raw_values_through_the_tables() -> None:
    m = xyz(0, 2, heading=math.radians(123.45), sound_speed=1501.7, reflectivity=[-12.3, 4.5],
            incidence_adjustment=[math.radians(-1.2), math.radians(3.4)])
    assert raw_value(m, "heading") == 12345
    assert raw_value(m, "sound_speed") == 15017
    assert raw_value(m.beams, "reflectivity").tolist() == [-123, 45]
    assert raw_value(m.beams, "incidence_adjustment").tolist() == [-12, 34]
    d = dep(0, 2, detection_window=[8, 12], reflectivity=[-10.5, -3.0], azimuth=[0.0, math.pi])
    assert raw_value(d.beams, "detection_window").tolist() == [2, 3]
    assert raw_value(d.beams, "reflectivity").tolist() == [-21, -6]
    assert raw_value(d.beams, "azimuth").tolist() == [0, 18000]


def test_nan_depth_marks_no_detection() -> None:
    m = xyz(0, 4, depth=[10.0, np.nan, 12.0, np.nan])
    assert m.beams.detection_info.tolist() == [0, 0xC0, 0, 0xC0]
    assert m.n_valid == 2
    assert m.beams.valid.tolist() == [True, False, True, False]
    assert m.beams.depth.tolist() == [10.0, 0.0, 12.0, 0.0]
    assert m.xyz.shape == (4, 3) and m.xyz[1].tolist() == [0.0, 0.0, 0.0]


def test_encode_rejects_inconsistent_messages() -> None:
    m = xyz(0, 3)
    with pytest.raises(WireError, match=r"n_beams is 4 but beams hold 3"):
        kb.encode(dataclasses.replace(m, n_beams=4))
    d = dep(0, 2)
    with pytest.raises(WireError, match=r"needs DepthBeams_z5cm"):
        kb.encode(dataclasses.replace(d, z_resolution=0.05))
    with pytest.raises(TypeError):
        kb.encode(object())


def test_decode_errors_name_field_and_offset() -> None:
    b = bytearray(kb.encode(xyz(0, 3)))
    struct.pack_into("<H", b, 28, 4)  # beam count no longer matches the length
    b[-2:] = struct.pack("<H", cks(b))
    with pytest.raises(DecodeError, match=r"XYZ88: beam count 4 \(byte offset 28\) needs 124"):
        kb.decode(bytes(b))
    d = bytearray(kb.encode(dep(0, 1)))
    d[28] = 0
    d[-2:] = struct.pack("<H", cks(d))
    with pytest.raises(DecodeError, match=r"zero resolution \(z 0 cm at byte 28"):
        kb.decode(bytes(d))
    bad = bytearray(kb.encode(xyz(0, 1)))
    bad[-1] ^= 0x10
    with pytest.raises(DecodeError, match="checksum"):
        kb.decode(bytes(bad))
    with pytest.raises(DecodeError, match="length field"):
        kb.decode(kb.encode(xyz(0, 1))[:-1])


# -- a hand-built XYZ 88, field by field at the documented offsets ---------------------------------
def hand_xyz88(head: dict, beams: list[tuple], spare_end: int = 0) -> bytes:
    n = len(beams)
    body = struct.pack(
        "<BBHIIHHHHfHHfB3s", 0x02, 0x58, head["model"], head["date"], head["ms"],
        head["counter"], head["serial"], head["heading"], head["ss"], head["txz"], n,
        head["valid"], head["fs"], head["scan"], head["spare"],
    )
    for beam in beams:
        body += struct.pack("<fffHBbBbh", *beam)
    body += bytes([spare_end, 0x03])
    frame = struct.pack("<I", len(body) + 2) + body
    return frame + struct.pack("<H", cks(frame + b"\x00\x00"))


HEAD = dict(model=2040, date=20240229, ms=43_200_500, counter=65535, serial=512,
            heading=35999, ss=14987, txz=3.25, valid=2, fs=31250.0, scan=0, spare=b"\0\0\0")
BEAMS = [
    (45.5, -60.25, 1.5, 120, 33, -7, 0x00, 0, -251),  # valid, amplitude detect
    (47.0, 0.0, -0.5, 80, 12, 15, 0x01, -128, 37),  # valid, phase detect, flagged by cleaning
    (0.0, 0.0, 0.0, 0, 0, 0, 0xC0, 0, 0),  # no detection
]


def test_hand_built_xyz88_decodes_field_by_field() -> None:
    frame = hand_xyz88(HEAD, BEAMS)
    assert len(frame) == 44 + 60
    (m,) = kb.decode(frame)
    assert isinstance(m, kb.XYZ88)
    assert (m.model, m.date, m.counter, m.serial) == (2040, 20240229, 65535, 512)
    assert m.time_since_midnight == pytest.approx(43200.5)
    assert m.device_time == pytest.approx(1709208000.5)  # 2024-02-29 12:00:00.5 UTC
    assert m.heading == pytest.approx(math.radians(359.99))
    assert m.sound_speed == pytest.approx(1498.7)
    assert m.transducer_depth == 3.25 and m.sampling_frequency == 31250.0
    assert (m.n_beams, m.n_valid, m.scanning_info) == (3, 2, 0)
    b = m.beams
    assert b.depth.dtype == np.float32 and b.depth.tolist() == [45.5, 47.0, 0.0]
    assert b.across.tolist() == [-60.25, 0.0, 0.0] and b.along.tolist() == [1.5, -0.5, 0.0]
    assert b.detection_window.tolist() == [120, 80, 0]
    assert b.quality.tolist() == [33, 12, 0]
    np.testing.assert_allclose(b.incidence_adjustment, np.radians([-0.7, 1.5, 0.0]))
    assert b.detection_info.tolist() == [0, 1, 0xC0] and b.valid.tolist() == [True, True, False]
    assert b.cleaning.tolist() == [0, -128, 0]
    np.testing.assert_allclose(b.reflectivity, [-25.1, 3.7, 0.0])
    assert not b.depth.flags.writeable
    np.testing.assert_array_equal(m.xyz[0], [1.5, -60.25, 45.5])  # x fwd, y stbd, z down
    assert kb.encode(m) == frame


def test_encoder_writes_documented_offsets() -> None:
    m = kb.make_xyz88(
        time=1709208000.5, depth=[45.5, 47.0, np.nan], across=[-60.25, 0.0, 9.0],
        along=[1.5, -0.5, 9.0], detection_window=[120, 80, 0], quality=[33, 12, 0],
        incidence_adjustment=np.radians([-0.7, 1.5, 0.0]), detection_info=[0, 1, 0],
        cleaning=[0, -128, 0], reflectivity=[-25.1, 3.7, 0.0], heading=math.radians(359.99),
        sound_speed=1498.7, transducer_depth=3.25, sampling_frequency=31250.0, ping_counter=65535,
        serial=512,
    )
    frame = kb.encode(m)
    assert frame == hand_xyz88(HEAD, BEAMS)
    assert struct.unpack_from("<I", frame, 0) == (100,)
    assert frame[4] == 0x02 and frame[5] == ord("X")
    assert struct.unpack_from("<HIIHH", frame, 6) == (2040, 20240229, 43_200_500, 65535, 512)
    assert struct.unpack_from("<HHfHHfB", frame, 20) == (35999, 14987, 3.25, 3, 2, 31250.0, 0)
    assert struct.unpack_from("<fffHBbBbh", frame, 40 + 20) == BEAMS[1]
    assert frame[100] == 0 and frame[101] == 0x03
    assert struct.unpack_from("<H", frame, 102)[0] == sum(frame[5:101]) & 0xFFFF


def test_hand_built_depth_decodes_field_by_field() -> None:
    beams = [(1500, -250, 12, 6000, 9000, 400, 80, 20, -41, 1),
             (1510, 260, -12, 5900, 27000, 410, 70, 22, -40, 2)]
    body = struct.pack("<BBHIIHHHHHBBBBH", 0x02, 0x44, 3020, 20231114, 1000, 9, 3, 27000, 15000,
                       250, 254, 2, 1, 2, 14293)
    for beam in beams:
        body += struct.pack("<hhhhHHBBbB", *beam)
    body += struct.pack("<bB", 0, 0x03)
    frame = struct.pack("<I", len(body) + 2) + body
    frame += struct.pack("<H", sum(frame[5:-1]) & 0xFFFF)  # type .. multiplier, not ETX
    (m,) = kb.decode(frame)
    assert isinstance(m, kb.Depth)
    assert (m.model, m.date, m.counter, m.serial) == (3020, 20231114, 9, 3)
    assert m.heading == pytest.approx(math.radians(270.0)) and m.sound_speed == 1500.0
    assert m.transducer_depth == pytest.approx(2.5) and m.transducer_depth_total == 2.5
    assert (m.max_beams, m.n_beams, m.sampling_rate) == (254, 2, 14293)
    assert m.z_resolution == pytest.approx(0.01) and m.xy_resolution == pytest.approx(0.02)
    b = m.beams
    np.testing.assert_allclose(b.depth, [15.0, 15.1])
    np.testing.assert_allclose(b.across, [-5.0, 5.2])
    np.testing.assert_allclose(b.along, [0.24, -0.24])
    np.testing.assert_allclose(b.depression, np.radians([60.0, 59.0]))
    np.testing.assert_allclose(b.azimuth, np.radians([90.0, 270.0]))
    assert b.range.tolist() == [400, 410] and b.quality.tolist() == [80, 70]
    assert b.detection_window.tolist() == [80.0, 88.0]
    assert b.reflectivity.tolist() == [-20.5, -20.0] and b.beam_number.tolist() == [1, 2]
    assert kb.encode(m) == frame


# -- Hypothesis properties -------------------------------------------------------------------------
u8, s8 = st.integers(0, 255), st.integers(-128, 127)
u16, s16 = st.integers(0, 65535), st.integers(-32768, 32767)
u32 = st.integers(0, 2**32 - 1)
f32 = st.floats(width=32, allow_nan=False)


def si(cls: type, name: str, raw):
    w = wire_of(cls, name)
    if isinstance(raw, np.ndarray):
        return raw.astype(np.float64) * w.scale + w.add if w.is_scaled else raw
    return raw * w.scale + w.add if w.is_scaled else raw


@st.composite
def xyz88_messages(draw) -> kb.XYZ88:
    n = draw(st.integers(0, 30))

    def arr(elems, dtype):
        return np.array(draw(st.lists(elems, min_size=n, max_size=n)), dtype=dtype)

    raw = dict(depth=arr(f32, np.float32), across=arr(f32, np.float32),
               along=arr(f32, np.float32), detection_window=arr(u16, np.uint16),
               quality=arr(u8, np.uint8), incidence_adjustment=arr(s8, np.int8),
               detection_info=arr(u8, np.uint8), cleaning=arr(s8, np.int8),
               reflectivity=arr(s16, np.int16))
    beams = kb.XYZ88Beams(**{k: si(kb.XYZ88Beams, k, v) for k, v in raw.items()})
    head = dict(model=draw(u16), date=draw(u32), time_since_midnight=draw(u32), counter=draw(u16),
                serial=draw(u16), heading=draw(u16), sound_speed=draw(u16),
                transducer_depth=draw(f32), n_valid=draw(u16), sampling_frequency=draw(f32),
                scanning_info=draw(u8))
    return kb.XYZ88(**{k: si(kb.XYZ88, k, v) for k, v in head.items()}, n_beams=n,
                    spare=draw(st.binary(min_size=3, max_size=3)), beams=beams,
                    trailer=kb.XYZ88Trailer(spare=draw(u8)))


@st.composite
def depth_messages(draw) -> kb.Depth:
    n = draw(st.integers(0, 40))
    model = draw(st.sampled_from([120, 300, 1002, 2000, 3000, 3020]))
    z_cm, xy_cm = draw(st.integers(1, 255)), draw(st.integers(1, 255))
    table = kb.depth_beam_table(z_cm, xy_cm, model in kb.UNSIGNED_DEPTH_MODELS)

    def arr(elems, dtype):
        return np.array(draw(st.lists(elems, min_size=n, max_size=n)), dtype=dtype)

    raw = dict(depth=arr(u16 if model in (120, 300) else s16, np.int32), across=arr(s16, np.int32),
               along=arr(s16, np.int32), depression=arr(s16, np.int32),
               azimuth=arr(u16, np.int32), range=arr(u16, np.uint16), quality=arr(u8, np.uint8),
               detection_window=arr(u8, np.int32), reflectivity=arr(s8, np.int32),
               beam_number=arr(u8, np.uint8))
    beams = table(**{k: si(table, k, v) for k, v in raw.items()})
    head = dict(date=draw(u32), time_since_midnight=draw(u32), counter=draw(u16),
                serial=draw(u16), heading=draw(u16), sound_speed=draw(u16),
                transducer_depth=draw(u16), max_beams=draw(u8), sampling_rate=draw(u16))
    return kb.Depth(**{k: si(kb.Depth, k, v) for k, v in head.items()}, model=model, n_beams=n,
                    z_resolution=z_cm * 0.01, xy_resolution=xy_cm * 0.01, beams=beams,
                    trailer=kb.DepthTrailer(depth_offset_multiplier=draw(s8)))


@settings(max_examples=150, deadline=None)
@given(st.one_of(xyz88_messages(), depth_messages()))
def test_property_message_bytes_message(m) -> None:
    b = kb.encode(m)
    (back,) = kb.decode(b)
    assert back == m
    assert kb.encode(back) == b


@st.composite
def valid_frames(draw) -> bytes:
    kind = draw(st.sampled_from(["X", "D", "other"]))
    common = struct.pack("<HIIHH", draw(u16), draw(u32), draw(u32), draw(u16), draw(u16))
    if kind == "X":
        n = draw(st.integers(0, 30))
        # header floats: any non-NaN bit pattern (a NaN's payload is not kept by Python floats)
        fz, fs = draw(f32), draw(f32)
        body = bytes([0x58]) + common + struct.pack(
            "<HHfHHfB", draw(u16), draw(u16), fz, n, draw(u16), fs, draw(u8)
        )
        # beam records: any bytes at all, NaN payloads included (kept bit for bit)
        body += draw(st.binary(min_size=3 + 20 * n, max_size=3 + 20 * n)) + draw(u8).to_bytes(1)
    elif kind == "D":
        n = draw(st.integers(0, 30))
        model = draw(st.sampled_from([120, 300, 3000, 3020]))
        common = struct.pack("<H", model) + common[2:]
        body = bytes([0x44]) + common + struct.pack(
            "<HHHBBBBH", draw(u16), draw(u16), draw(u16), draw(u8), n, draw(st.integers(1, 255)),
            draw(st.integers(1, 255)), draw(u16),
        )
        body += draw(st.binary(min_size=16 * n + 1, max_size=16 * n + 1))
    else:
        type_id = draw(st.sampled_from(sorted(kb.KNOWN_TYPES - {0x58, 0x44})))
        payload = draw(st.binary(min_size=0, max_size=300))
        if (len(payload) + 16 + 3) % 2:
            payload += b"\x00"
        body = bytes([type_id]) + common + payload
    frame = struct.pack("<I", len(body) + 4) + b"\x02" + body + b"\x03"
    return frame + struct.pack("<H", cks(frame + b"\x00\x00"))


@settings(max_examples=200, deadline=None)
@given(valid_frames())
def test_property_bytes_message_bytes(frame: bytes) -> None:
    kb.check_datagram(frame)
    (m,) = kb.decode(frame)
    assert kb.encode(m) == frame


@settings(max_examples=50, deadline=None)
@given(st.lists(valid_frames(), min_size=1, max_size=6), st.integers(1, 97))
def test_property_framer_finds_every_concatenated_datagram(frames: list[bytes], step: int) -> None:
    stream = b"".join(frames)
    f = kb.KongsbergFramer(policy=ErrorPolicy.IGNORE)
    got = list(f.frames(stream[i : i + step] for i in range(0, len(stream), step)))
    assert [g.data for g in got] == frames
    assert f.stats.bad_frames == 0 and f.stats.skipped_bytes == 0


# -- named corrupted fixtures ----------------------------------------------------------------------
def corrupt(frame: bytes, at: int, value: int) -> bytes:
    out = bytearray(frame)
    out[at] = value
    assert value != 0x02 and out != bytearray(frame)
    return bytes(out)


g0, g1, g2, g3 = G
L1 = len(g1)
FIXTURES = {
    # name: (stream, frames expected, bad_frames, skipped_bytes, reasons)
    "bad_checksum": (g0 + corrupt(g1, L1 - 1, g1[-1] ^ 0x40) + g2, [g0, g2], 1, L1,
                     {"checksum": 1}),
    "bad_length_odd": (g0 + corrupt(g1, 0, g1[0] + 1) + g2, [g0, g2], 1, L1, {"length": 1}),
    "bad_length_huge": (g0 + corrupt(g1, 3, 0x80) + g2 + g3, [g0, g2, g3], 1, L1, {"length": 1}),
    # a plausible length that would wait for 40 kB: abandoned when g2 is complete inside it
    "bad_length_plausible": (g0 + corrupt(g1, 1, 0x9C) + g2 + g3, [g0, g2, g3], 1, L1,
                             {"inner_frame": 1}),
    "missing_etx": (g0 + corrupt(g1, L1 - 3, 0x00) + g2, [g0, g2], 1, L1, {"ETX": 1}),
    "bad_type": (g0 + corrupt(g1, 5, 0x99) + g2, [g0, g2], 1, L1, {"type": 1}),
    "truncated_mid_stream": (g0 + g1[:30] + g2 + g3, [g0, g2, g3], 1, 30, {"ETX": 1}),
    "truncated_at_end": (g0 + g2 + g1[:30], [g0, g2], 1, 30, {"truncated": 1}),
    "garbage_between": (g0 + b"\x00\xff\x10garbage\x03\x03" + g1, [g0, g1], 0, 12, {}),
    "garbage_with_false_stx": (g0 + b"\xff\xff\xff\xff\x02\x58junk" + g1 + b"\x01\x02" + g2,
                               [g0, g1, g2], 1, 12, {"length": 1}),
    "starts_mid_datagram": (g1[10:] + g2 + g3, [g2, g3], 0, L1 - 10, {}),
    "starts_inside_length": (g1[2:] + g2, [g2], 0, L1 - 2, {}),
}


def test_fixture_preconditions() -> None:
    assert all(g.count(0x02) == 1 for g in G)
    assert struct.unpack_from("<I", corrupt(g1, 1, 0x9C), 0)[0] + 4 > len(
        FIXTURES["bad_length_plausible"][0]
    ) and struct.unpack_from("<I", corrupt(g1, 1, 0x9C), 0)[0] < 65532
    # the truncated datagram's declared end lands inside g2 on a byte that is not ETX
    assert (g2 + g3)[L1 - 3 - 30] != 0x03


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("chunk", [1, 3, 64, 100_000])
def test_corrupted_fixture_exact_counts(name: str, chunk: int) -> None:
    stream, expected, bad, skipped, reasons = FIXTURES[name]
    f = kb.KongsbergFramer(policy=ErrorPolicy.IGNORE)
    got = list(f.frames(stream[i : i + chunk] for i in range(0, len(stream), chunk)))
    assert [g.data for g in got] == expected
    assert [g.offset for g in got] == [stream.index(e) for e in expected]
    assert f.stats.frames == len(expected)
    assert f.stats.bad_frames == bad
    assert f.stats.skipped_bytes == skipped
    assert dict(f.stats.reasons) == reasons
    assert all(kb.decode(g.data) for g in got)


def test_raise_policy_names_offset_and_keeps_good_frames() -> None:
    stream = g0 + corrupt(g1, L1 - 1, g1[-1] ^ 0x40) + g2
    f = kb.KongsbergFramer(policy=ErrorPolicy.RAISE, source="mb.all")
    with pytest.raises(FrameError, match=rf"mb.all: bad frame at byte offset {len(g0)}: checksum"):
        f.feed(stream)
    assert [fr.data for fr in f.feed(b"")] == [g0, g2]


def test_type_filter_can_be_opened() -> None:
    odd_type = generic(0x99, b"\x00")
    assert list(kb.KongsbergFramer(policy="ignore").frames([odd_type])) == []
    f = kb.KongsbergFramer(policy="ignore", types=None)
    (fr,) = f.frames([odd_type])
    (m,) = kb.decode(fr.data)
    assert m.type_id == 0x99 and m.type_name == "unknown 0x99"


def test_udp_packets_in_both_network_forms() -> None:
    frame = kb.encode(xyz(0, 4))
    assert kb.datagram_from_packet(frame) == frame
    assert kb.datagram_from_packet(frame[4:]) == frame  # SIS-forwarded: starts at STX
    # a length field whose low byte is 0x02 (258 bytes) is still read as the .all form
    d258 = generic(0x50, bytes(258 - 19))
    assert d258[0] == 0x02 and kb.datagram_from_packet(d258) == d258
    with pytest.raises(BadFrame, match="checksum"):
        kb.datagram_from_packet(frame[4:-1] + bytes([frame[-1] ^ 1]))
    with pytest.raises(BadFrame, match="packet holds"):
        kb.datagram_from_packet(frame + b"\x00")
    with pytest.raises(BadFrame, match="truncated"):
        kb.datagram_from_packet(frame[:20])
    # one datagram per UDP packet through the framer, packets arriving one by one
    f = kb.KongsbergFramer(policy="ignore")
    packets = [kb.encode(xyz(i, 3 + i)) for i in range(5)]
    assert [fr.data for p in packets for fr in f.feed(p)] == packets


# -- fuzz ------------------------------------------------------------------------------------------
def chunked(data: bytes, rng: random.Random) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = rng.choice([1, 2, 5, 17, 64, 333, 4096])
        out.append(data[i : i + n])
        i += n
    return out


@pytest.mark.parametrize("seed", range(12))
def test_fuzz_random_bytes_never_raise(seed: int) -> None:
    rng = random.Random(seed)
    data = rng.randbytes(rng.randrange(1, 30_000))
    if seed % 2:  # bias towards STX and small lengths to reach the deeper checks
        data = bytes(b if rng.random() > 0.2 else rng.choice([0x02, 0x00, 0x58, 0x44, 0x03])
                     for b in data)
    f = kb.KongsbergFramer(policy=ErrorPolicy.LOG)
    frames = list(f.frames(chunked(data, rng)))
    for fr in frames:
        with contextlib.suppress(DecodeError):
            kb.decode(fr.data)
    assert f.stats.skipped_bytes + sum(len(fr.data) for fr in frames) == len(data)
    assert f.buffered == 0


@pytest.mark.parametrize("seed", range(16))
def test_fuzz_corrupted_stream_keeps_every_untouched_datagram(seed: int) -> None:
    rng = random.Random(1000 + seed)
    datagrams = []
    for i in range(30):
        kind = rng.randrange(3)
        if kind == 0:
            datagrams.append(kb.encode(xyz(i, rng.randrange(0, 60))))
        elif kind == 1:
            datagrams.append(kb.encode(dep(i, rng.randrange(0, 40))))
        else:
            datagrams.append(generic(rng.choice([0x41, 0x50, 0x52, 0x68]),
                                     rng.randbytes(2 * rng.randrange(0, 80) + 1), i))
    parts, untouched = [rng.randbytes(rng.randrange(0, 50))], []
    for d in datagrams:
        if rng.random() < 0.4:
            op, b = rng.randrange(5), bytearray(d)
            if op == 0:
                b[rng.randrange(len(b))] ^= rng.randrange(1, 256)
            elif op == 1:
                del b[rng.randrange(1, len(b)) :]
            elif op == 2:
                at = rng.randrange(len(b))
                b[at:at] = rng.randbytes(rng.randrange(1, 40))
            elif op == 3:
                b[0:4] = rng.randbytes(4)
            else:
                at = rng.randrange(len(b) - 1)
                del b[at : at + rng.randrange(1, 20)]
            parts.append(bytes(b))
        else:
            offset = sum(map(len, parts))
            untouched.append((offset, d))
            parts.append(d)
        if rng.random() < 0.2:
            parts.append(rng.randbytes(rng.randrange(1, 30)))
    stream = b"".join(parts)
    f = kb.KongsbergFramer(policy=ErrorPolicy.IGNORE)
    found = {(fr.offset, fr.data) for fr in f.frames(chunked(stream, rng))}
    assert set(untouched) <= found
    assert len(untouched) >= 10
    for _, data in untouched:
        assert len(kb.decode(data)) == 1
    for _, data in found - set(untouched):
        with contextlib.suppress(DecodeError):
            kb.decode(data)


# -- the CLI ---------------------------------------------------------------------------------------
@pytest.mark.e2e
def test_cli_decode_kongsberg_file(tmp_path: Path) -> None:
    x, d = xyz(1, 6), dep(2, 3)
    pos = generic(0x50, bytes(21), 5)
    path = tmp_path / "ping.all"
    path.write_bytes(b"\x00" * 5 + kb.encode(x) + kb.encode(d) + b"junk" + pos)
    run = subprocess.run(
        [*CLI, "decode", "--format", "kongsberg", str(path)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert [m["type"] for m in lines] == ["XYZ88", "Depth", "KongsbergDatagram"]
    assert lines[0] == json.loads(json.dumps(to_jsonable(x)))
    assert lines[0]["beams"]["depth"] == pytest.approx([20.0, 20.25, 20.5, 20.75, 21.0, 21.25])
    assert lines[1]["beams"]["type"] == "DepthBeams_z1cm_xy1cm_s16"
    assert lines[1]["beams"]["depth"] == pytest.approx([15.0, 15.5, 16.0])
    assert lines[2]["type_id"] == 0x50 and lines[2]["counter"] == 5
    summary = json.loads(run.stderr.strip().splitlines()[-1])
    assert summary["messages"] == {"Depth": 1, "KongsbergDatagram": 1, "XYZ88": 1}
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (3, 0, 9)
    assert summary["decode_errors"] == 0


@pytest.mark.e2e
def test_cli_rejects_a_file_that_is_not_kongsberg(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("depth 12.5 m at 12:00\n" * 200)
    run = subprocess.run(
        [*CLI, "decode", "--format", "kongsberg", str(path)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert run.returncode == 2
    assert run.stdout == ""
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("auvgw decode: error: ") and "no valid kongsberg frame" in last
    assert "Traceback" not in run.stderr
