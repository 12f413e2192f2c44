"""CAN forms of the HN-100 and MS3A: DBC files through cantools, and a python-can virtual bus."""

from __future__ import annotations

import dataclasses
import math
import random
import struct
import uuid
from pathlib import Path

import can
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.drivers.can_codec import CanCodecError, CanFrame, DbcCodec
from auvgw.drivers.ms3a import CODEC as MS3A_ASCII
from auvgw.drivers.spec import to_jsonable
from auvgw.ground.paths import config_file
from auvgw.testing.can_samples import HN, MAG, hn_sample

# -- the DBC files ------------------------------------------------------------------------------


def test_dbc_ids_lengths_and_named_values() -> None:
    db = cantools.database.load_file(str(config_file("hn100.dbc")))
    ids = {m.name: (m.frame_id, m.is_extended_frame, m.length) for m in db.messages}
    assert ids == {
        "HN100_Time": (0x0A100001, True, 7),
        "HN100_Attitude": (0x0A100002, True, 7),
        "HN100_Rates": (0x0A100003, True, 7),
        "HN100_Accel": (0x0A100004, True, 7),
        "HN100_Velocity": (0x0A100005, True, 7),
        "HN100_Position": (0x0A100006, True, 8),
        "HN100_Longitude": (0x0A100007, True, 5),
        "HN100_Status": (0x0A100008, True, 2),
    }
    status = db.get_message_by_name("HN100_Status")
    choices = status.get_signal_by_name("Alignment").choices
    assert {k: str(v) for k, v in choices.items()} == {
        0: "NOT_ALIGNED",
        1: "COARSE",
        2: "FINE",
        3: "FAULT",
    }
    mag = cantools.database.load_file(str(config_file("ms3a.dbc")))
    assert {m.name: (m.frame_id, m.is_extended_frame) for m in mag.messages} == {
        "MS3A_FieldXY": (0x310, False),
        "MS3A_FieldZ": (0x311, False),
    }
    # every bit of every message belongs to a signal, so frames re-encode identically
    for m in [*db.messages, *mag.messages]:
        assert sum(s.length for s in m.signals) == 8 * m.length, m.name


def test_decode_hand_built_frames_to_si() -> None:
    # HN100_Attitude: Seq u8 | Roll s16 1e-4 rad | Pitch s16 | Heading u16
    data = struct.pack("<BhhH", 9, 1000, -2000, 30000)
    att = HN.decode(0x0A100002, data, is_extended_id=True)
    assert type(att).__name__ == "HN100_Attitude"
    assert (att.seq, att.roll, att.pitch, att.heading) == (9, pytest.approx(0.1), -0.2, 3.0)
    # HN100_Position: Seq | Latitude s32 1e-7 deg | Depth s24 1 mm
    data = struct.pack("<Bi", 9, 431_234_567) + (-1500).to_bytes(3, "little", signed=True)
    pos = HN.decode(0x0A100006, data, is_extended_id=True)
    assert pos.latitude == pytest.approx(math.radians(43.1234567), abs=1e-12)
    assert pos.depth == pytest.approx(-1.5)
    assert HN.signal_units(type(pos)) == {"seq": "", "latitude": "rad", "depth": "m"}
    # HN100_Status: Alignment bits 0-1 of byte 1, GnssAided bit 2, DvlAided bit 3, Error bit 4
    st_ = HN.decode(0x0A100008, bytes([9, 0b10110]), is_extended_id=True)
    assert (st_.alignment, st_.gnss_aided, st_.dvl_aided, st_.error) == ("FINE", 1, 0, "FAULT")
    assert HN.raw_values(st_) == {
        "Seq": 9,
        "Alignment": 2,
        "GnssAided": 1,
        "DvlAided": 0,
        "Error": 1,
        "Reserved": 0,
    }
    assert to_jsonable(st_)["alignment"] == "FINE"
    # MS3A_FieldZ on a standard ID: Counter u16 | Bz s24 0.1 nT | Status u8
    data = struct.pack("<H", 700) + (-432_100).to_bytes(3, "little", signed=True) + b"\x02"
    z = MAG.decode(0x311, data, is_extended_id=False)
    assert (z.counter, z.bz) == (700, pytest.approx(-43210.0))
    assert z.status == "SENSOR_FAULT"
    with pytest.raises(dataclasses.FrozenInstanceError):
        z.bz = 0.0  # type: ignore[misc]


def test_frame_errors_name_message_and_signal() -> None:
    with pytest.raises(CanCodecError, match=r"hn100\.dbc: no message with standard ID 0xA100002"):
        HN.decode(0x0A100002, bytes(7), is_extended_id=False)
    with pytest.raises(
        CanCodecError, match=r"HN100_Attitude \(0xA100002 extended\): 6 data bytes, DBC says 7"
    ):
        HN.decode(0x0A100002, bytes(6), is_extended_id=True)
    with pytest.raises(
        CanCodecError, match=r"signal Roll = 3\.2767 outside the DBC range \[-3\.1416, 3\.1416\]"
    ):
        HN.decode(0x0A100002, struct.pack("<BhhH", 0, 32767, 0, 0), is_extended_id=True)
    att = HN.types["HN100_Attitude"]
    with pytest.raises(
        CanCodecError, match=r'Expected signal "Roll" value smaller than or equal to 3\.1416'
    ):
        HN.encode(att(seq=1, roll=4.0, pitch=0.0, heading=0.0))
    with pytest.raises(CanCodecError, match=r'"Latitude" value greater than or equal to -90'):
        HN.encode(HN.types["HN100_Position"](seq=1, latitude=-math.pi, depth=0.0))
    status = HN.types["HN100_Status"]
    with pytest.raises(
        CanCodecError, match=r"HN100_Status\.alignment \(signal Alignment\) = 'SUPER': expected"
    ):
        HN.encode(
            status(seq=1, alignment="SUPER", gnss_aided=0, dvl_aided=0, error="OK", reserved=0)
        )
    with pytest.raises(CanCodecError, match=r"HN100_Attitude\.pitch \(signal Pitch\) = nan"):
        HN.encode(att(seq=1, roll=0.0, pitch=math.nan, heading=0.0))
    with pytest.raises(CanCodecError, match="not a message of this DBC"):
        HN.encode(MAG.types["MS3A_FieldZ"](counter=1, bz=0.0, status="OK"))


# -- round trips --------------------------------------------------------------------------------


def _raw_strategy(sig) -> st.SearchStrategy[int]:
    lo = math.ceil(round((sig.minimum - sig.offset) / sig.scale, 6))
    hi = math.floor(round((sig.maximum - sig.offset) / sig.scale, 6))
    return st.integers(lo, hi)


@pytest.mark.parametrize("codec", [HN, MAG], ids=["hn100", "ms3a"])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_any_in_range_frame_roundtrips(codec: DbcCodec, data) -> None:
    for m in codec.db.messages:
        raw = {s.name: data.draw(_raw_strategy(s), label=s.name) for s in m.signals}
        payload = m.encode(raw, scaling=False)
        msg = codec.decode(m.frame_id, payload, m.is_extended_frame)
        frame = codec.encode(msg)
        assert frame == CanFrame(m.frame_id, payload, m.is_extended_frame)
        assert codec.raw_values(msg) == raw
        assert codec.decode_frame(frame) == msg


@settings(max_examples=80, deadline=None)
@given(
    seq=st.integers(0, 255),
    k=st.floats(-1.0, 1.0),
)
def test_sample_encode_decode_within_resolution(seq: int, k: float) -> None:
    s = dataclasses.replace(
        hn_sample(seq, abs(k)), roll=0.3 * k, pitch=0.1 * k, rate_z=-2.0 * k, vel_d=k
    )
    frames = HN.encode_sample(s)
    assert len(frames) == 8 and all(f.is_extended_id for f in frames)
    asm = HN.assembler()
    out = [asm.add(HN.decode_frame(f)) for f in frames]
    assert out[:-1] == [None] * 7
    got = out[-1]
    assert got.seq == seq and got.alignment == "FINE" and got.error == "OK"
    assert got.time == pytest.approx(s.time, abs=0.5e-6 + 1e-9)
    assert got.roll == pytest.approx(s.roll, abs=0.5e-4 + 1e-9)
    assert got.rate_z == pytest.approx(s.rate_z, abs=1e-4 + 1e-9)
    assert got.latitude == pytest.approx(s.latitude, abs=1e-9)
    assert got.depth == pytest.approx(s.depth, abs=0.5e-3 + 1e-9)
    assert HN.encode_sample(got) == frames  # decoded values are fixed points


@pytest.mark.parametrize("codec", [HN, MAG], ids=["hn100", "ms3a"])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_codec_checked_encode_equals_cantools_strict(codec: DbcCodec, data) -> None:
    for m in codec.db.messages:
        raw = {s.name: data.draw(_raw_strategy(s), label=s.name) for s in m.signals}
        msg = codec.decode(m.frame_id, m.encode(raw, scaling=False), m.is_extended_frame)
        assert codec.encode(msg, strict=False) == codec.encode(msg)


def test_codec_checked_encode_rejects_what_strict_rejects() -> None:
    att = HN.types["HN100_Attitude"]
    with pytest.raises(
        CanCodecError, match=r"HN100_Attitude: signal Roll = 4\.0 outside the DBC range \[-3\.1416"
    ):
        HN.encode(att(seq=1, roll=4.0, pitch=0.0, heading=0.0), strict=False)
    with pytest.raises(CanCodecError, match=r"signal Latitude = -180\.0 outside the DBC range"):
        HN.encode(HN.types["HN100_Position"](seq=1, latitude=-math.pi, depth=0.0), strict=False)
    with pytest.raises(CanCodecError, match=r"signal Seq = 256 outside the DBC range \[0, 255\]"):
        HN.encode(att(seq=256, roll=0.0, pitch=0.0, heading=0.0), strict=False)
    status = HN.types["HN100_Status"]
    with pytest.raises(CanCodecError, match=r"\(signal Alignment\) = 'SUPER': expected"):
        HN.encode(
            status(seq=1, alignment="SUPER", gnss_aided=0, dvl_aided=0, error="OK", reserved=0),
            strict=False,
        )
    assert HN.encode_sample(hn_sample(9), strict=False) == HN.encode_sample(hn_sample(9))


def test_assembler_groups_any_order_and_counts_incomplete() -> None:
    rnd = random.Random(7)
    samples = [hn_sample(seq) for seq in (250, 251, 252, 253, 254, 255, 0, 1)]
    bursts = [HN.encode_sample(s) for s in samples]
    for b in bursts:
        rnd.shuffle(b)
    del bursts[2][3]  # epoch 252 loses one frame
    # epochs 253 and 254 interleave
    mixed = [f for pair in zip(bursts[3], bursts[4], strict=True) for f in pair]
    stream = [*bursts[0], *bursts[1], *bursts[2], *mixed, *bursts[5], *bursts[6], *bursts[7]]
    asm = HN.assembler(max_pending=2)
    got = [s for f in stream if (s := asm.add(HN.decode_frame(f))) is not None]
    assert [s.seq for s in got] == [250, 251, 253, 254, 255, 0, 1]
    expected = [HN.split_sample(s) for s in samples]
    assert [HN.split_sample(s) for s in got] == [
        [HN.decode_frame(HN.encode(p)) for p in e] for i, e in enumerate(expected) if i != 2
    ]
    assert (asm.complete, asm.dropped, asm.pending) == (7, 1, 0)
    asm.add(HN.decode_frame(bursts[0][0]))
    asm.add(HN.decode_frame(bursts[0][0]))  # the same frame again: the open epoch restarts
    assert (asm.dropped, asm.pending) == (2, 1)


def test_ms3a_can_matches_ascii_sample() -> None:
    line = MS3A_ASCII.encode(
        MS3A_ASCII.message_type(counter=65537, bx=21345.6, by=-1234.5, bz=43210.0)
    )
    assert line.startswith(b"$MS3A,065537,+021345.6,")
    ascii_msg = MS3A_ASCII.decode(line)
    sample = MAG.sample_type(
        counter=ascii_msg.counter % 65536,
        bx=ascii_msg.bx,
        by=ascii_msg.by,
        bz=ascii_msg.bz,
        status="OK",
    )
    frames = MAG.encode_sample(sample)
    assert [(f.arbitration_id, f.is_extended_id, len(f.data)) for f in frames] == [
        (0x310, False, 8),
        (0x311, False, 6),
    ]
    assert str(frames[0]).startswith("310#0100")  # counter 65537 mod 65536 = 1
    asm = MAG.assembler()
    got = [asm.add(MAG.decode_frame(f)) for f in reversed(frames)][-1]
    assert got.counter == 1
    assert (got.bx, got.by, got.bz) == pytest.approx((21345.6, -1234.5, 43210.0))


# -- python-can virtual bus ---------------------------------------------------------------------


def test_virtual_bus_roundtrip_both_devices() -> None:
    channel = f"auvgw-{uuid.uuid4().hex}"
    samples = [hn_sample(s, k=0.5 + 0.1 * s) for s in range(3)]
    mag = MAG.sample_type(counter=42, bx=21345.6, by=-1234.5, bz=43210.0, status="STARTUP")
    sent = [f for s in samples for f in HN.encode_sample(s)] + MAG.encode_sample(mag)
    with (
        can.Bus(interface="virtual", channel=channel) as tx,
        can.Bus(interface="virtual", channel=channel) as rx,
    ):
        for f in sent:
            tx.send(
                can.Message(
                    arbitration_id=f.arbitration_id,
                    data=f.data,
                    is_extended_id=f.is_extended_id,
                )
            )
        received = []
        while (msg := rx.recv(timeout=1.0)) is not None:
            received.append(msg)
            if len(received) == len(sent):
                break
    assert len(received) == len(sent) == 3 * 8 + 2
    assert [m.is_extended_id for m in received] == [True] * 24 + [False] * 2
    hn_asm, mag_asm = HN.assembler(), MAG.assembler()
    ins, magn = [], []
    for m in received:
        codec, asm, out = (HN, hn_asm, ins) if m.is_extended_id else (MAG, mag_asm, magn)
        done = asm.add(codec.decode_frame(m))
        if done is not None:
            out.append(done)
    assert [s.seq for s in ins] == [0, 1, 2]
    for got, want in zip(ins, samples, strict=True):
        assert got.heading == pytest.approx(want.heading, abs=0.5e-4 + 1e-9)
        assert got.longitude == pytest.approx(want.longitude, abs=1e-9)
        assert got.accel_z == pytest.approx(want.accel_z, abs=1e-3 + 1e-9)
    assert len(magn) == 1 and magn[0].status == "STARTUP"
    assert magn[0].bz == pytest.approx(43210.0)


# -- site DBCs -------------------------------------------------------------------------------

SITE_DBC = """VERSION ""

NS_ :

BS_:

BU_: INS GW

BO_ 1280 INS_Att: 4 INS
 SG_ Cnt : 0|4@1+ (1,0) [0|15] "" GW
 SG_ Mode : 4|4@1+ (1,0) [0|15] "" GW
 SG_ Yaw : 8|16@1+ (0.01,0) [0|359.99] "deg" GW
 SG_ Spare : 24|8@1+ (1,0) [0|255] "" GW

BO_ 1281 INS_Depth: 3 INS
 SG_ Cnt : 0|4@1+ (1,0) [0|15] "" GW
 SG_ Pad : 4|4@1+ (1,0) [0|15] "" GW
 SG_ DepthCm : 8|16@1+ (1,0) [0|65535] "cm" GW

BA_DEF_  "AuvgwSequenceSignal" STRING ;
BA_DEF_DEF_  "AuvgwSequenceSignal" "";
BA_ "AuvgwSequenceSignal" "Cnt";
VAL_ 1280 Mode 0 "IDLE" 5 "NAV" ;
"""


def test_site_dbc_without_code_changes(tmp_path: Path) -> None:
    path = tmp_path / "site.dbc"
    path.write_text(SITE_DBC)
    codec = DbcCodec(path)
    assert codec.sequence_signal == "Cnt"
    assert codec.sample_type is not None and codec.sample_type.__name__ == "SITE_Sample"
    att = codec.decode(0x500, bytes([0x53, 0x28, 0x23, 0]), is_extended_id=False)
    assert (att.cnt, att.mode, att.spare) == (3, "NAV", 0)
    assert att.yaw == pytest.approx(math.radians(90.0))  # 9000 * 0.01 deg
    depth = codec.decode(0x501, bytes([0x13, 0x10, 0x27]), is_extended_id=False)
    assert depth.depth_cm == pytest.approx(100.0)  # 10000 cm -> m
    assert codec.signal_units(type(depth))["depth_cm"] == "m"
    asm = codec.assembler()
    assert asm.add(att) is None
    sample = asm.add(depth)
    assert (sample.cnt, sample.mode, sample.pad) == (3, "NAV", 1)
    assert [codec.encode(p) for p in codec.split_sample(sample)] == [
        CanFrame(0x500, bytes([0x53, 0x28, 0x23, 0]), False),
        CanFrame(0x501, bytes([0x13, 0x10, 0x27]), False),
    ]


def test_dbc_without_sequence_and_broken_files(tmp_path: Path) -> None:
    path = tmp_path / "plain.dbc"
    path.write_text(SITE_DBC.split("BA_DEF_")[0])
    codec = DbcCodec(path)
    assert codec.sample_type is None and codec.sequence_signal is None
    with pytest.raises(CanCodecError, match="the DBC names no sequence signal"):
        codec.assembler()
    grouped = DbcCodec(path, sequence_signal="Cnt", sample_name="Site")
    assert grouped.sample_type.__name__ == "Site"
    with pytest.raises(CanCodecError, match="no message carries the sequence signal 'Nope'"):
        DbcCodec(path, sequence_signal="Nope")
    bad = tmp_path / "bad.dbc"
    bad.write_text("hello world\n")
    # the position, never the file's text (a DBC path may name any file: docs/security.md)
    with pytest.raises(CanCodecError, match=r"bad\.dbc: cannot load DBC: invalid DBC syntax at "):
        DbcCodec(bad)
    with pytest.raises(CanCodecError, match=r"missing\.dbc: cannot load DBC"):
        DbcCodec(tmp_path / "missing.dbc")
