"""Tritech SeaNet codec and framer: known bytes, round trips, corrupted streams, fuzz."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import random
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.drivers.framing import DecodeError, ErrorPolicy, FrameError
from auvgw.drivers.seanet import codec as sn
from auvgw.drivers.spec import WireError, from_jsonable, raw_value, table_rows, to_jsonable
from auvgw.testing.format_samples import sample_messages

# -- helpers ----------------------------------------------------------------------------------


def packet(
    msg_type: int,
    payload: bytes,
    tx: int = 2,
    rx: int = 255,
    count: int | None = None,
    seq: int = 0x80,
    node: int = 2,
) -> bytes:
    """A SeaNet packet built by hand from the protocol description (not by the codec)."""
    length = len(payload) + 8
    if count is None:
        count = 0 if msg_type == 2 else length - 5
    return (
        b"@"
        + f"{length:04X}".encode()
        + struct.pack("<H", length)
        + bytes([tx, rx, count, msg_type, seq, node])
        + payload
        + b"\n"
    )


def head_data_payload(
    hd_ctrl: int,
    data: bytes,
    bearing: int = 0,
    ad_interval: int = 20,
    left: int = 0,
    right: int = 0,
    step: int = 16,
    appended: bytes = b"",
) -> bytes:
    """mtHeadData payload (from offset 13) built by hand."""
    body = bytearray(31)  # offsets 13..43
    struct.pack_into("<H", body, 0, 31 + len(data) + len(appended))  # 13: bytes 13.. up to LF
    body[2] = 11  # 15 device type
    body[3] = 0  # 16 head status
    body[4] = 0  # 17 sweep code
    struct.pack_into("<H", body, 5, hd_ctrl)  # 18
    struct.pack_into("<H", body, 7, 300)  # 20 range scale: 30.0 m
    struct.pack_into("<I", body, 9, 0x05666666)  # 22 TxN (675 kHz)
    body[13] = 84  # 26 gain
    struct.pack_into("<H", body, 14, 125)  # 27 slope
    body[16], body[17] = 77, 40  # 29 ADSpan, 30 ADLow
    struct.pack_into("<H", body, 18, 0)  # 31 heading offset
    struct.pack_into("<H", body, 20, ad_interval)  # 33
    struct.pack_into("<H", body, 22, left)  # 35
    struct.pack_into("<H", body, 24, right)  # 37
    body[26] = step  # 39
    struct.pack_into("<H", body, 27, bearing)  # 40
    struct.pack_into("<H", body, 29, len(data))  # 42 data bytes
    return bytes(body) + data + appended


def feed(
    data: bytes, chunk: int, policy: ErrorPolicy = ErrorPolicy.IGNORE, plausibility: bool = True
):
    f = sn.SeaNetFramer(policy=policy)
    f.plausibility = plausibility
    chunks = [data[i : i + chunk] for i in range(0, len(data), chunk)]
    return list(f.frames(chunks)), f


CHUNKS = (1, 2, 3, 7, 64, 100_000)


# -- known bytes ------------------------------------------------------------------------------


def test_host_commands_match_published_bytes() -> None:
    # byte strings used by working Micron / MiniKing drivers (CAUV, ENSTA Bretagne)
    assert sn.encode(sn.send_version()) == bytes.fromhex("4030303038 0800 ff02 03 17 80 02 0a")
    assert sn.encode(sn.reboot()) == bytes.fromhex("4030303038 0800 ff02 03 10 80 02 0a")
    assert sn.encode(sn.send_bb_user()) == bytes.fromhex("4030303038 0800 ff02 03 18 80 02 0a")
    assert sn.encode(sn.send_data(0x03B064CA)) == bytes.fromhex(
        "4030303043 0c00 ff02 07 19 80 02 ca64b003 0a"
    )
    hc = sn.encode(sn.head_command())
    assert len(hc) == 66
    assert hc[:14] == bytes.fromhex("4030303343 3c00 ff02 37 13 80 02 01")


def test_send_data_time_and_units() -> None:
    m = sn.decode(sn.encode(sn.send_data(56_000_123)))[0]
    assert isinstance(m, sn.SendData)
    assert m.time == pytest.approx(56_000.123)
    assert raw_value(m, "time") == 56_000_123
    assert (m.tx_node, m.rx_node, m.node, m.byte_count, m.is_last) == (255, 2, 2, 7, True)


def test_alive_known_values() -> None:
    raw = packet(4, bytes([0x80]) + struct.pack("<IH", 3_600_250, 1600) + bytes([0x5D]))
    (m,) = sn.decode(raw)
    assert isinstance(m, sn.Alive)
    assert len(raw) == 22 and m.byte_count == 11
    assert m.head_time == pytest.approx(3600.25)
    assert m.transducer_bearing == pytest.approx(math.pi / 2)
    assert m.inf == (
        sn.HeadInf.IN_CENTRE
        | sn.HeadInf.MOTORING
        | sn.HeadInf.MOTOR_ON
        | sn.HeadInf.DIR
        | sn.HeadInf.NO_PARAMS
    )
    assert m.no_params and not m.sent_cfg and not m.ready
    assert m.alive_info == 0x80
    assert sn.encode(m) == raw
    ready = sn.decode(packet(4, bytes([0]) + struct.pack("<IH", 1, 0) + bytes([0x8A])))[0]
    assert ready.sent_cfg and ready.ready


def test_version_data_known_values() -> None:
    payload = bytes([7, 0x21]) + struct.pack("<HIH", 1234, 70_000, 0xBEEF) + bytes([2])
    (m,) = sn.decode(packet(1, payload))
    assert isinstance(m, sn.VersionData)
    assert (
        m.software_version,
        m.info_bits,
        m.serial_number,
        m.program_length,
        m.program_checksum,
        m.node_id,
    ) == (7, 0x21, 1234, 70_000, 0xBEEF, 2)
    assert sn.encode(m) == packet(1, payload)


def test_head_data_8bit_known_values() -> None:
    data = bytes([0, 1, 127, 128, 255, 64])
    hd_ctrl = 0x2301 | 0x0002 | 0x0004  # ADC8ON, CONTINUOUS, SCAN_RIGHT, RAW, HAS_MOTOR, ASL
    raw = packet(
        2,
        head_data_payload(
            hd_ctrl, data, bearing=3200, ad_interval=20, left=1600, right=4800, step=32
        ),
    )
    (m,) = sn.decode(raw)
    assert isinstance(m, sn.HeadData)
    assert m.bins.tolist() == [0, 1, 127, 128, 255, 64]
    assert m.bins.dtype == np.uint8 and not m.bins.flags.writeable
    assert m.adc8on and m.continuous and m.scan_right and not m.invert
    assert m.ctrl == (
        sn.HdCtrl.ADC8ON
        | sn.HdCtrl.CONTINUOUS
        | sn.HdCtrl.SCAN_RIGHT
        | sn.HdCtrl.RAW
        | sn.HdCtrl.HAS_MOTOR
        | sn.HdCtrl.REPLY_ASL
    )
    assert m.bearing == pytest.approx(math.pi)
    assert raw_value(m, "bearing") == 3200
    assert (m.left_limit, m.right_limit) == pytest.approx((math.pi / 2, 3 * math.pi / 2))
    assert m.step == pytest.approx(2 * math.pi * 32 / 6400)  # 1.8 deg
    assert m.ad_interval == pytest.approx(12.8e-6)
    assert m.bin_length(1500.0) == pytest.approx(12.8e-6 * 1500.0 / 2)  # 9.6 mm
    assert m.range_m == pytest.approx(30.0)
    assert m.tx_frequency == pytest.approx(675_000, abs=0.01)
    assert m.gain == pytest.approx(84 / 210)
    assert (m.ad_span, m.ad_low) == pytest.approx((77 * 80 / 255, 40 * 80 / 255))
    assert m.device_type == 11 and m.byte_count == 0 and m.appended == b""
    assert sn.encode(m) == raw


def test_head_data_4bit_high_nibble_first() -> None:
    hd_ctrl = 0x2302  # 4-bit: ADC8ON clear
    raw = packet(2, head_data_payload(hd_ctrl, bytes([0x12, 0xAB, 0xF0])))
    (m,) = sn.decode(raw)
    assert not m.adc8on
    assert m.bins.tolist() == [1, 2, 10, 11, 15, 0]
    assert m.data_bytes == 3
    assert sn.encode(m) == raw
    # the same bins rebuilt from values
    again = dataclasses.replace(m, bins=np.array([1, 2, 10, 11, 15, 0]))
    assert sn.encode(again) == raw


def test_head_data_4bit_encode_rejects_bad_bins() -> None:
    cfg = sn.head_command(adc8on=False)
    with pytest.raises(WireError, match=r"even number of bins"):
        sn.encode(sn.head_data([1, 2, 3], 0.0, config=cfg))
    with pytest.raises(WireError, match=r"each 0\.\.15"):
        sn.encode(sn.head_data([1, 16], 0.0, config=cfg))
    with pytest.raises(WireError, match=r"0\.\.255"):
        sn.head_data([1, 256], 0.0)


def test_head_data_appended_bytes_kept() -> None:
    raw = bytearray(packet(2, head_data_payload(0x2301, bytes([5, 6]), appended=b"XYZ")))
    (m,) = sn.decode(bytes(raw))
    assert m.bins.tolist() == [5, 6] and m.appended == b"XYZ"
    assert sn.encode(m) == bytes(raw)


def test_head_data_inconsistent_counts_are_decode_errors() -> None:
    good = packet(2, head_data_payload(0x2301, bytes(10)))
    bad_total = bytearray(good)
    bad_total[13] += 1
    with pytest.raises(DecodeError, match=r"total byte count \(offset 13\)"):
        sn.decode(bytes(bad_total))
    bad_n = bytearray(good)
    bad_n[42] = 200
    with pytest.raises(DecodeError, match=r"data bytes \(offset 42\) = 200"):
        sn.decode(bytes(bad_n))
    with pytest.raises(DecodeError, match=r"mtAlive: packet of 23 bytes, the table has 22"):
        sn.decode(packet(4, bytes(9)))
    with pytest.raises(DecodeError, match=r"not a SeaNet packet"):
        sn.decode(b"hello")
    with pytest.raises(DecodeError, match=r"terminator"):
        sn.decode(packet(23, b"")[:-1] + b"\r")


def test_plausibility_checks_name_their_reason() -> None:
    """No checksum: fields that contradict each other make a bad frame, counted per reason."""
    good = packet(2, head_data_payload(0x2301, bytes(10), bearing=3200))
    cases = {"node": (12, 7), "bearing": (41, 0x19), "byte_count": (13, 3)}
    wire = b""
    for at, value in cases.values():
        bad = bytearray(good)
        bad[at] = value
        wire += bytes(bad) + good
    f = sn.SeaNetFramer(policy=ErrorPolicy.IGNORE)
    got = [fr.data for fr in f.frames([wire[i : i + 7] for i in range(0, len(wire), 7)])]
    assert got == [good] * 3
    assert dict(f.stats.reasons) == {k: 1 for k in cases}


def test_head_command_layout_and_settings() -> None:
    hc = sn.head_command(
        range_m=5.0,
        n_bins=400,
        sound_speed=1500.0,
        adc8on=True,
        continuous=False,
        scan_right=True,
        invert=True,
        left_limit=math.radians(200),
        right_limit=math.radians(290),
        step=math.radians(1.8),
        gain=95 / 210,
    )
    raw = sn.encode(hc)
    assert len(raw) == 66 and raw[13] == 0x01
    assert struct.unpack_from("<H", raw, 14)[0] == 0x230D  # as the ENSTA MiniKing driver sends
    assert raw[16] == 11
    assert raw[17:21] == bytes.fromhex("66666605")  # 675 kHz * 2^32 / 32 MHz
    assert struct.unpack_from("<H", raw, 35)[0] == 50  # 5.0 m x10
    assert struct.unpack_from("<HH", raw, 37) == (3556, 5156)  # 200, 290 deg (rounded 1/16 grad)
    assert raw[43] == raw[44] == 95
    assert raw[50] == 32
    assert struct.unpack_from("<H", raw, 51)[0] == 26  # 2*5/1500/400/640ns = 26.04
    assert struct.unpack_from("<H", raw, 53)[0] == 400
    (m,) = sn.decode(raw)
    assert m == hc
    assert m.invert and m.scan_right and not m.continuous and m.adc8on
    assert m.range_scale == (5.0, "m") and m.range_m == 5.0
    assert m.bin_length(1500.0) == pytest.approx(5.0 / 400, rel=0.01)
    assert m.minor_axis == pytest.approx(math.pi / 2)
    assert m.v3b is None


def test_head_command_v3b_block_round_trip() -> None:
    db, g = 80 / 255, 1 / 210  # the table's scales: SI = raw * scale
    v3b = sn.V3BGains(
        ad_span_ch1=69 * db,
        ad_span_ch2=50 * db,
        ad_low_ch1=68 * db,
        ad_low_ch2=0.0,
        gain_ch1=90 * g,
        gain_ch2=100 * g,
        adc_setpoint_ch1=0,
        adc_setpoint_ch2=0,
        slope_ch1=0x6400,
        slope_ch2=0,
        slope_delay_ch1=0,
        slope_delay_ch2=0,
    )
    hc = sn.head_command(v3b=v3b)
    raw = sn.encode(hc)
    assert len(raw) == 82 and raw[13] == 0x1D and raw[9] == 82 - 6 - 5
    assert raw[65:69] == bytes([69, 50, 68, 0]) and raw[69:71] == bytes([90, 100])
    assert raw[73:75] == b"\x00\x64"
    (back,) = sn.decode(raw)
    assert back == hc and back.v3b.ad_span_ch1 == pytest.approx(21.647, abs=1e-3)
    assert sn.encode(back) == raw


def test_short_head_command_and_unknown_types_kept_raw() -> None:
    reverse = packet(19, b"\x0f", tx=255, rx=2)  # the 1-byte "reverse scan direction" command
    (m,) = sn.decode(reverse)
    assert isinstance(m, sn.SeaNetRaw)
    assert m.msg_type == 19 and m.payload == b"\x0f" and m.type_name == "mtHeadCommand"
    assert sn.encode(m) == reverse
    bb = packet(6, bytes(range(161)))  # mtBBUserData
    (m,) = sn.decode(bb)
    assert isinstance(m, sn.SeaNetRaw) and m.type_name == "mtBBUserData"
    assert sn.encode(m) == bb
    odd = packet(99, b"ab")
    assert sn.decode(odd)[0].type_name == "mtType99"


def test_range_scale_units() -> None:
    hd = sn.head_data([1, 2], 0.0)
    feet = dataclasses.replace(hd, range_scale_raw=(1 << 14) | 100)  # 10.0 ft
    assert feet.range_m == pytest.approx(3.048)
    yards = dataclasses.replace(hd, range_scale_raw=(3 << 14) | 55)  # 5.5 yd
    assert yards.range_m == pytest.approx(5.5 * 0.9144)


def test_angle_conversions() -> None:
    assert sn.ANGLE_UNITS_PER_TURN == 6400
    assert sn.angle_to_rad(1600) == pytest.approx(math.pi / 2)
    assert sn.angle_to_rad(3200) == pytest.approx(math.pi)
    assert sn.angle_to_rad(16) == pytest.approx(math.radians(0.9))  # 1 gradian
    assert sn.rad_to_angle(math.pi) == 3200
    assert sn.rad_to_angle(2 * math.pi) == 0
    assert sn.rad_to_angle(-math.pi / 2) == 4800
    assert sn.rad_to_angle(math.radians(1.8)) == 32
    for units in (0, 1, 4, 1599, 3200, 6399):
        assert sn.rad_to_angle(sn.angle_to_rad(units)) == units
    hd = sn.head_data([0, 0], math.radians(45))
    assert raw_value(hd, "bearing") == 800
    assert hd.bearing == pytest.approx(math.pi / 4)


def test_bin_length_helper() -> None:
    assert sn.bin_length(20 * 640e-9, 1500.0) == pytest.approx(0.0096)
    assert sn.bin_length(1e-3, 1450.0) == pytest.approx(0.725)


def test_json_round_trip() -> None:
    for m in sample_messages():
        d = to_jsonable(m)
        assert d["type"] == m.TYPE
        back = from_jsonable(d)
        assert back == m and sn.encode(back) == sn.encode(m)


@pytest.mark.parametrize("msg", sample_messages(), ids=lambda m: m.TYPE)
def test_every_message_type_round_trips(msg: sn.SeaNetMessage) -> None:
    raw = sn.encode(msg)
    assert raw[0] == 0x40 and raw[-1] == 0x0A
    assert int(raw[1:5], 16) == struct.unpack_from("<H", raw, 5)[0] == len(raw) - 6
    (back,) = sn.decode(raw)
    assert back == msg
    assert sn.encode(back) == raw
    assert sn.FORMAT.decode(raw) == [msg] and sn.FORMAT.encode(msg) == raw


# -- framing: named corrupted fixtures --------------------------------------------------------

GOOD = [sn.encode(m) for m in sample_messages()]
STREAM = b"".join(GOOD)


def test_clean_stream_any_chunking() -> None:
    for chunk in CHUNKS:
        frames, f = feed(STREAM, chunk)
        assert [fr.data for fr in frames] == GOOD
        assert (f.stats.frames, f.stats.bad_frames, f.stats.skipped_bytes) == (len(GOOD), 0, 0)
        assert frames[3].offset == sum(len(p) for p in GOOD[:3])


def _expect(stream: bytes, frames_out: list[bytes], bad: int, reasons: dict[str, int]) -> None:
    for chunk in CHUNKS:
        frames, f = feed(stream, chunk)
        assert [fr.data for fr in frames] == frames_out, chunk
        assert f.stats.frames == len(frames_out)
        assert f.stats.bad_frames == bad, (chunk, f.stats.reasons)
        assert f.stats.skipped_bytes == len(stream) - sum(map(len, frames_out))
        assert dict(f.stats.reasons) == reasons


def test_bad_hex_length() -> None:
    bad = bytearray(GOOD[2])  # mtSendVersion, no '@' inside
    bad[3] = ord("G")
    _expect(GOOD[0] + bytes(bad) + GOOD[1], [GOOD[0], GOOD[1]], 1, {"hex_length": 1})


def test_lower_case_hex_is_rejected() -> None:
    bad = GOOD[7].replace(b"@000C", b"@000c")  # mtSendData
    _expect(bad + GOOD[2], [GOOD[2]], 1, {"hex_length": 1})


def test_hex_binary_length_mismatch() -> None:
    bad = bytearray(GOOD[7])
    bad[5] += 1
    _expect(GOOD[2] + bytes(bad) + GOOD[2], [GOOD[2], GOOD[2]], 1, {"length_mismatch": 1})


def test_implausible_length() -> None:
    huge = b"@FFF0" + struct.pack("<H", 0xFFF0) + bytes([255, 2, 0]) + b"junk"
    tiny = b"@0004" + struct.pack("<H", 4) + bytes([255, 2, 0]) + b"\n"
    _expect(huge + GOOD[1] + tiny + GOOD[2], [GOOD[1], GOOD[2]], 2, {"length": 2})


def test_bad_byte_count() -> None:
    bad = bytearray(GOOD[7])
    bad[9] = 6  # should be 7 (or 0)
    _expect(bytes(bad) + GOOD[7], [GOOD[7]], 1, {"byte_count": 1})
    zero = bytearray(GOOD[7])
    zero[9] = 0  # 0 is accepted (the single-packet marker)
    frames, f = feed(bytes(zero), 5)
    assert [fr.data for fr in frames] == [bytes(zero)] and f.stats.bad_frames == 0


def test_missing_lf() -> None:
    bad = GOOD[3][:-1] + b"\r"  # mtVersionData
    _expect(GOOD[2] + bad + GOOD[5], [GOOD[2], GOOD[5]], 1, {"terminator": 1})


def test_truncated_packet_does_not_swallow_the_next() -> None:
    head = GOOD[8]  # 95-byte mtHeadData (bins 0..49, no '@')
    send = GOOD[7]  # 18-byte mtSendData
    assert b"@" not in head[1:]
    cut = head[: len(head) - len(send)]
    # cut + send is exactly as long as the head data claims and ends in send's LF
    assert len(cut + send) == len(head) and (cut + send)[-1] == 0x0A
    _expect(cut + send + GOOD[2], [send, GOOD[2]], 1, {"overlap": 1})
    # cut short with nothing after it: truncated at the end of the stream
    _expect(GOOD[2] + head[:40], [GOOD[2]], 1, {"truncated": 1})
    # cut short, declared end lands inside later bytes that are not LF
    assert head[34] != 0x0A
    _expect(head[:60] + GOOD[8] + GOOD[2], [GOOD[8], GOOD[2]], 1, {"terminator": 1})


def test_every_truncation_keeps_the_packets_after_it() -> None:
    # exhaustive: each packet cut at every length, followed by each intact packet and a marker
    for cut_from in GOOD:
        for cut in range(1, len(cut_from)):
            for nxt in GOOD:
                stream = cut_from[:cut] + nxt + GOOD[2]
                frames, _ = feed(stream, 4096)
                assert [fr.data for fr in frames][-2:] == [nxt, GOOD[2]], (cut_from[:12], cut)


def test_bins_that_look_like_a_sync_are_data() -> None:
    cfg = sn.head_command(n_bins=12)
    tricky = sn.encode(sn.head_data(list(b"@0010\x10\x00@000@\x0a"), 0.5, config=cfg))
    _expect(tricky + GOOD[2], [tricky, GOOD[2]], 0, {})


def test_garbage_between_packets() -> None:
    garbage = bytes(range(0x41, 0x41 + 30))  # no '@', no LF surprises
    _expect(garbage + GOOD[0] + garbage + GOOD[1] + garbage, [GOOD[0], GOOD[1]], 0, {})
    with_at = b"\x00@@\x99@0"  # three false syncs: '@@', '@\x99', '@0' then a real '@'
    _expect(GOOD[0] + with_at + GOOD[1], [GOOD[0], GOOD[1]], 3, {"hex_length": 3})


def test_stream_starting_mid_packet() -> None:
    head = GOOD[8]
    assert b"@" not in head[1:]
    _expect(head[20:] + GOOD[2] + GOOD[8], [GOOD[2], GOOD[8]], 0, {})
    _expect(head[3:] + GOOD[2], [GOOD[2]], 0, {})


def test_raise_policy_names_the_offset() -> None:
    bad = bytearray(GOOD[2])
    bad[-1] = 0x0D
    f = sn.SeaNetFramer(policy=ErrorPolicy.RAISE, source="cap.bin")
    with pytest.raises(FrameError, match=r"cap.bin: bad frame at byte offset 18: terminator"):
        f.feed(GOOD[7] + bytes(bad) + GOOD[1])
    assert [fr.data for fr in f.feed(b"") + f.finish()] == [GOOD[7], GOOD[1]]


def test_garbage_only_keeps_buffer_bounded() -> None:
    f = sn.SeaNetFramer(policy=ErrorPolicy.IGNORE)
    rng = np.random.default_rng(1)
    for _ in range(50):
        f.feed(rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
    assert f.buffered < sn.MAX_PACKET_SIZE
    f.finish()
    assert f.stats.frames == 0
    assert f.stats.skipped_bytes == 100_000


# -- Hypothesis properties --------------------------------------------------------------------

_RANGES = {"u8": 255, "u16": 0xFFFF, "u32": 0xFFFFFFFF}


def _raw_fields(cls: type, skip: tuple[str, ...] = ()) -> st.SearchStrategy[dict]:
    rows = [r for r in table_rows(cls) if r["name"] not in skip]
    return st.fixed_dictionaries({r["name"]: st.integers(0, _RANGES[r["type"]]) for r in rows})


def _si(cls: type, raw: dict) -> dict:
    rows = {r["name"]: r for r in table_rows(cls)}
    out = {}
    for k, v in raw.items():
        scale, add = rows[k]["scale"], rows[k]["add"]
        out[k] = v * scale + add if (scale != 1.0 or add != 0.0) else v
    return out


HEADER = ("tx_node", "rx_node", "byte_count", "sequence", "node")


@st.composite
def messages(draw: st.DrawFn) -> sn.SeaNetMessage:
    cls = draw(
        st.sampled_from(
            [
                sn.VersionData,
                sn.Alive,
                sn.ReBoot,
                sn.SendVersion,
                sn.SendBBUser,
                sn.SendData,
                sn.HeadCommand,
                sn.HeadData,
                sn.SeaNetRaw,
            ]
        )
    )
    raw = draw(_raw_fields(cls, skip=("byte_count", "msg_type")))
    extra: dict = {"byte_count": 0}
    if cls is sn.HeadCommand and draw(st.booleans()):
        extra["v3b"] = sn.V3BGains(**_si(sn.V3BGains, draw(_raw_fields(sn.V3BGains))))
    if cls is sn.HeadData:
        eight = raw["hd_ctrl"] & 1
        n = draw(st.integers(0, 120)) * (1 if eight else 2)
        extra["bins"] = np.array(
            draw(st.lists(st.integers(0, 255 if eight else 15), min_size=n, max_size=n)),
            dtype=np.uint8,
        )
        extra["appended"] = draw(st.binary(max_size=5))
    if cls is sn.SeaNetRaw:
        extra["msg_type"] = draw(st.integers(0, 255).filter(lambda t: t not in sn._TABLES))
        extra["payload"] = draw(st.binary(max_size=300))
    msg = cls(**_si(cls, raw), **extra)
    length = len(sn.encode(msg)) - 6
    count = draw(
        st.sampled_from(
            [
                0,
                sn.default_byte_count(
                    cls.MSG_TYPE if cls is not sn.SeaNetRaw else extra["msg_type"], length
                ),
            ]
        )
    )
    return dataclasses.replace(msg, byte_count=count)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_generated_messages_round_trip(msg: sn.SeaNetMessage) -> None:
    raw = sn.encode(msg)
    (back,) = sn.decode(raw)
    assert back == msg
    assert sn.encode(back) == raw


@st.composite
def raw_packets(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["fixed", "head_data", "other"]))
    if kind == "fixed":
        mtype, size = draw(
            st.sampled_from(
                [
                    (1, 25),
                    (4, 22),
                    (16, 14),
                    (23, 14),
                    (24, 14),
                    (25, 18),
                    (19, 66),
                    (19, 82),
                    (19, 15),
                ]
            )
        )
        return packet(
            mtype,
            draw(st.binary(min_size=size - 14, max_size=size - 14)),
            tx=draw(st.integers(0, 255)),
            rx=draw(st.integers(0, 255)),
            seq=draw(st.integers(0, 255)),
            node=draw(st.integers(0, 255)),
        )
    if kind == "head_data":
        n = draw(st.integers(0, 200))
        payload = bytearray(head_data_payload(0, draw(st.binary(min_size=n, max_size=n))))
        payload[2:29] = draw(st.binary(min_size=27, max_size=27))  # any header values ...
        payload += draw(st.binary(max_size=4))  # (appended bytes)
        struct.pack_into("<H", payload, 0, len(payload))  # ... but the counts right
        return packet(2, bytes(payload))
    mtype = draw(st.integers(0, 255).filter(lambda t: t not in sn._TABLES))
    return packet(mtype, draw(st.binary(max_size=200)), count=draw(st.sampled_from([0, None])))


@settings(max_examples=200, deadline=None)
@given(raw_packets())
def test_decode_then_encode_is_identity(raw: bytes) -> None:
    (m,) = sn.decode(raw)
    assert sn.encode(m) == raw


@settings(max_examples=60, deadline=None)
@given(st.lists(raw_packets(), min_size=1, max_size=8), st.integers(1, 50))
def test_framer_recovers_generated_streams(packets: list[bytes], chunk: int) -> None:
    # structure only: the generated packets carry arbitrary (implausible) node and angle fields
    frames, f = feed(b"".join(packets), chunk, plausibility=False)
    assert [fr.data for fr in frames] == packets
    assert f.stats.bad_frames == 0 and f.stats.skipped_bytes == 0


# -- fuzz -------------------------------------------------------------------------------------


def _corrupt(pkt: bytes, rng: random.Random) -> bytes:
    op = rng.choice(["flip", "truncate", "insert", "delete", "drop_lf", "drop_sync"])
    b = bytearray(pkt)
    if op == "flip":
        i = rng.randrange(len(b))
        b[i] ^= rng.randrange(1, 256)
    elif op == "truncate":
        del b[rng.randrange(1, len(b)) :]
    elif op == "insert":
        i = rng.randrange(len(b))
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20)))
    elif op == "delete":
        i = rng.randrange(len(b))
        del b[i : i + rng.randrange(1, 10)]
    elif op == "drop_lf":
        b[-1] = rng.randrange(0x0B, 256)
    else:
        b[0] = ord("#")
    return bytes(b)


def test_fuzz_random_bytes_never_raise() -> None:
    rng = random.Random(7)
    for _ in range(30):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 3000)))
        data += b"@0010" * rng.randrange(3)  # false starts at the end too
        frames, f = feed(data, rng.randrange(1, 400))
        for fr in frames:
            with contextlib.suppress(DecodeError):  # content errors are allowed, nothing else
                sn.decode(fr.data)
        assert f.stats.skipped_bytes + sum(len(fr.data) for fr in frames) == len(data)


def test_fuzz_corrupted_streams_keep_every_untouched_packet() -> None:
    rng = random.Random(2024)
    pool = [sn.encode(m) for m in sample_messages()]
    for trial in range(150):
        pkts = [rng.choice(pool) for _ in range(rng.randrange(5, 25))]
        stream = bytearray()
        untouched: list[tuple[int, bytes]] = []
        for p in pkts:
            if rng.random() < 0.1:
                stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
            if rng.random() < 0.3:
                stream += _corrupt(p, rng)
            else:
                untouched.append((len(stream), p))
                stream += p
        frames, f = feed(bytes(stream), rng.randrange(1, 200))
        got = {(fr.offset, fr.data) for fr in frames}
        missing = [u for u in untouched if u not in got]
        assert not missing, f"trial {trial}: lost {len(missing)} untouched packets"
        for fr in frames:
            with contextlib.suppress(DecodeError):  # content errors are allowed, nothing else
                sn.decode(fr.data)
        assert f.stats.skipped_bytes + sum(len(fr.data) for fr in frames) == len(stream)
