"""PD6 ASCII lines: tables, exact round trips, Hypothesis, corrupted streams, fuzzing, CLI."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.drivers import pd6
from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import DecodeError, ErrorPolicy, FrameError
from auvgw.drivers.spec import WireError, to_jsonable
from auvgw.testing.format_samples import PD6_LINES as LINES

STREAM = b"".join(LINES)


def columns(cls):
    return pd6._columns(cls)


def run_framer(stream: bytes, chunk: int, policy: str = "ignore"):
    f = pd6.Pd6Framer(policy=policy)
    chunks = (stream[i : i + chunk] for i in range(0, len(stream), chunk))
    return [fr.data for fr in f.frames(chunks)], f.stats


# --------------------------------------------------------------------------------------------
# Tables and exact round trips
# --------------------------------------------------------------------------------------------


def test_every_sentence_round_trips_exactly() -> None:
    assert {line[1:3].decode() for line in LINES} == set(pd6.SENTENCES)
    for line in LINES:
        msg = pd6.decode(line)
        assert line[1:3].decode() == msg.SENTENCE
        assert pd6.encode(msg) == line
        json.dumps(to_jsonable(msg))


def test_decoded_values_in_si_units() -> None:
    sa, ts, wi, _, _, wd, bi, bs, be, bd, hm = (pd6.decode(line) for line in LINES)
    assert math.degrees(sa.pitch) == pytest.approx(-2.31)
    assert math.degrees(sa.roll) == pytest.approx(1.92)
    assert math.degrees(sa.heading) == pytest.approx(75.20)
    assert (ts.salinity, ts.temperature, ts.depth, ts.speed_of_sound, ts.bit) == (
        pytest.approx(35.0), pytest.approx(21.0), 0.0, pytest.approx(1524.0), "0",
    )
    assert ts.device_time == dt.datetime(2004, 8, 11, 11, 56, 36, 440000, tzinfo=dt.UTC)
    assert all(math.isnan(v) for v in (wi.x, wi.y, wi.z, wi.error)) and wi.status == "V"
    assert (bi.x, bi.y, bi.z, bi.error, bi.status) == (
        pytest.approx(0.024), pytest.approx(-0.006), pytest.approx(-0.020),
        pytest.approx(-0.004), "A",
    )
    assert (bs.transverse, bs.longitudinal, bs.normal) == (
        pytest.approx(-0.013), pytest.approx(0.021), pytest.approx(-0.020),
    )
    assert (be.east, be.north, be.up) == (
        pytest.approx(0.017), pytest.approx(0.018), pytest.approx(-0.020),
    )
    assert (bd.east, bd.north, bd.up, bd.range_to_bottom, bd.time_since_good) == (
        pytest.approx(-0.02), pytest.approx(-0.03), pytest.approx(0.02), pytest.approx(7.13),
        pytest.approx(0.21),
    )
    assert wd.range_to_bottom == pytest.approx(20.0)
    assert (hm.leak_a, hm.leak_b, hm.leak_a_count, hm.tx_voltage, hm.impedance) == (
        "G", "L", 123.0, pytest.approx(24.015), pytest.approx(15.978),
    )


def test_negative_zero_and_invalid_markers_survive() -> None:
    line = b":BD,       -0.00,       +0.00,       -0.01,   0.00,  0.00\r\n"
    bd = pd6.decode(line)
    assert math.copysign(1.0, bd.east) == -1.0 and math.copysign(1.0, bd.north) == 1.0
    assert pd6.encode(bd) == line
    bi = pd6.BottomInstrumentVelocity(x=math.nan, y=0.0, z=-0.0, error=32.767, status="V")
    assert pd6.encode(bi) == b":BI,-32768,    +0,    -0,+32767,V\r\n"


def test_malformed_lines_raise_decode_error_naming_field_and_byte() -> None:
    cases = [
        (b":BI,  +24,    -6,   -20,    -4,A\r\n", r":BI field x at byte 4: '  \+24'"),
        (b":BI,   +24,    -6,   -20,    -4,X\r\n", r":BI field status at byte 32"),
        (b":SA, -2.31, +1.92, 75.2 \r\n", r":SA field heading at byte 18"),
        (b":SA,+-2.31, +1.92, 75.20\r\n", r":SA field pitch at byte 4"),
        (b":SA, -2.31, +1.92\r\n", r":SA: 2 fields, the table has 3"),
        (b":ZZ,1\r\n", r"byte 1: unknown sentence ':ZZ'"),
        (b":TS,0408111156364,35.0,+21.0,   0.0,1524.0,  0\r\n", r":TS field timestamp at byte 4"),
        (b":BE,   +17,   +18,   -20,A\n", r"end with CR LF"),
    ]
    for line, match in cases:
        with pytest.raises(DecodeError, match=match):
            pd6.decode(line)


def test_encode_rejects_values_that_do_not_fit() -> None:
    with pytest.raises(WireError, match=r"BottomInstrumentVelocity.status"):
        pd6.encode(pd6.BottomInstrumentVelocity(x=0.0, y=0.0, z=0.0, error=0.0, status="Q"))
    with pytest.raises(WireError, match=r"TimingScaling.timestamp"):
        pd6.encode(dataclasses.replace(pd6.decode(LINES[1]), timestamp="12"))
    with pytest.raises(WireError, match="no invalid marker"):
        pd6.encode(dataclasses.replace(pd6.decode(LINES[0]), heading=math.nan))


def test_format_registry() -> None:
    fmt = get_format("pd6")
    assert fmt is pd6.FORMAT and isinstance(fmt.framer(), pd6.Pd6Framer)
    (msg,) = fmt.decode(LINES[6])
    assert fmt.encode(msg) == LINES[6]


# --------------------------------------------------------------------------------------------
# Hypothesis
# --------------------------------------------------------------------------------------------


def column_st(col: pd6.Column):
    if col.kind == "char":
        return st.sampled_from(col.choices)
    if col.kind == "digits":  # the :TS timestamp: a real date and time (YYMMDDHHmmsshh)
        when = st.datetimes(dt.datetime(1980, 1, 1), dt.datetime(2079, 12, 31, 23, 59, 59))
        return when.map(lambda t: t.strftime("%y%m%d%H%M%S") + f"{t.microsecond // 10000:02d}")
    if col.kind == "text":
        return st.text("0123456789ABCDEF", min_size=1, max_size=col.width)
    digits = col.width - col.signed - (1 if col.decimals else 0)
    top = 10**digits - 1
    lo, hi = -top if col.signed else 0, top
    if col.low is not None:  # plausible values only: the framer rejects the others (range)
        lo = max(lo, math.ceil(col.low / col.scale - 1e-9))
    if col.high is not None:
        hi = min(hi, math.floor(col.high / col.scale + 1e-9))
    raw = st.integers(lo, hi)
    if col.invalid is not None:
        raw = st.one_of(raw, st.just(col.invalid))
    return raw.map(lambda r, c=col: math.nan if r == c.invalid else r * c.scale)


@st.composite
def message_st(draw):
    cls = draw(st.sampled_from(list(pd6.SENTENCES.values())))
    return cls(**{name: draw(column_st(col)) for name, col in columns(cls)})


@settings(max_examples=200, deadline=None)
@given(message_st())
def test_property_message_encode_decode_identity(msg) -> None:
    line = pd6.encode(msg)
    back = pd6.decode(line)
    assert back == msg
    assert pd6.encode(back) == line
    assert [fr.data for fr in pd6.Pd6Framer(policy="raise").feed(line)] == [line]


@settings(max_examples=200, deadline=None)
@given(message_st(), st.lists(st.tuples(st.integers(0, 200), st.sampled_from(b" +-.,019AV"))))
def test_property_line_decode_encode_identity(msg, edits) -> None:
    """Any line that decodes (here: valid lines with random characters replaced) re-encodes to
    the very same bytes: decoding accepts only the table's exact text."""
    line = bytearray(pd6.encode(msg))
    for pos, ch in edits:
        if 4 <= pos < len(line) - 2:
            line[pos] = ch
    try:
        back = pd6.decode(bytes(line))
    except DecodeError:
        return
    assert pd6.encode(back) == bytes(line)


# --------------------------------------------------------------------------------------------
# Named corrupted fixtures (exact counts, every chunk size)
# --------------------------------------------------------------------------------------------

CHUNKS = (1, 5, 64, 10_000)


@pytest.mark.parametrize("chunk", CHUNKS)
def test_clean_stream(chunk: int) -> None:
    frames, s = run_framer(STREAM, chunk)
    assert frames == LINES
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (len(LINES), 0, 0)


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_unknown_sentence(chunk: int) -> None:
    bad = b":RA,  0.00,  71.31,  71.32,  71.32,  71.31\r\n"  # PD13 only: not PD6
    frames, s = run_framer(LINES[0] + bad + LINES[1], chunk)
    assert frames == LINES[:2]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (2, 1, len(bad))
    assert dict(s.reasons) == {"sentence": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_truncated_line(chunk: int) -> None:
    trunc = LINES[6][:17]  # ":BI,   +24,    -6" and no CR LF
    frames, s = run_framer(LINES[5] + trunc + LINES[7] + LINES[8][:20], chunk)
    assert frames == [LINES[5], LINES[7]]
    # mid-stream: its CR LF search reaches the next line's ':' ; at the end: stream ends
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (2, 2, len(trunc) + 20)
    assert dict(s.reasons) == {"character": 1, "truncated": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_bad_length_and_terminator(chunk: int) -> None:
    long = b":BI," + b"1" * 200 + b"\r\n"
    lf_only = LINES[7][:-2] + b"\n"
    frames, s = run_framer(LINES[0] + long + LINES[1] + lf_only + LINES[2], chunk)
    assert frames == LINES[:3]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (3, 2, len(long) + len(lf_only))
    assert dict(s.reasons) == {"length": 1, "terminator": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_wrong_field_count(chunk: int) -> None:
    bad = b":BS,   -13,   +21,A\r\n"
    frames, s = run_framer(bad + LINES[8], chunk)
    assert frames == [LINES[8]]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (1, 1, len(bad))
    assert dict(s.reasons) == {"fields": 1}


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_garbage_between_lines(chunk: int) -> None:
    garbage = b"\x00\xff>?\r\nBREAK Wakeup A\r\n\x13\x11"  # prompt noise, no ':'
    stream = garbage + LINES[0] + garbage + LINES[1] + LINES[2] + garbage
    frames, s = run_framer(stream, chunk)
    assert frames == LINES[:3]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (3, 0, 3 * len(garbage))


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_stream_starting_mid_line(chunk: int) -> None:
    stream = LINES[9][12:] + b"".join(LINES[:3])
    frames, s = run_framer(stream, chunk)
    assert frames == LINES[:3]
    assert (s.frames, s.bad_frames, s.skipped_bytes) == (3, 0, len(LINES[9]) - 12)


def test_bad_sentence_rejected_at_once() -> None:
    f = pd6.Pd6Framer(policy=ErrorPolicy.RAISE, source="log.pd6")
    with pytest.raises(FrameError, match=r"log.pd6: bad frame at byte offset 0: sentence"):
        f.feed(b":QQ,")  # judged on the ID, before any CR LF


# --------------------------------------------------------------------------------------------
# Fuzz
# --------------------------------------------------------------------------------------------


def feed_random(f, stream: bytes, rng) -> list[bytes]:
    out, i = [], 0
    while i < len(stream):
        n = int(rng.integers(1, 40))
        out += [fr.data for fr in f.feed(stream[i : i + n])]
        i += n
    return out + [fr.data for fr in f.finish()]


@pytest.mark.parametrize("policy", ["ignore", "log"])
@pytest.mark.parametrize("seed", range(3))
def test_fuzz_random_bytes(policy: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    alphabet = np.frombuffer(b":BISTWDEHMA0123456789+-., \r\n\x00\xff", dtype=np.uint8)
    noise = rng.choice(alphabet, 30_000).tobytes()
    f = pd6.Pd6Framer(policy=policy)
    frames = feed_random(f, noise, rng)
    for fr in frames:
        with contextlib.suppress(DecodeError):
            assert pd6.encode(pd6.decode(fr)) == fr
    assert f.stats.skipped_bytes + sum(map(len, frames)) == len(noise)


@pytest.mark.parametrize("policy", ["ignore", "log"])
@pytest.mark.parametrize("seed", range(3))
def test_fuzz_corrupted_stream_keeps_untouched_lines(policy: str, seed: int) -> None:
    rng = np.random.default_rng(50 + seed)
    stream = bytearray()
    untouched = []
    for k in range(300):
        line = LINES[k % len(LINES)]
        if rng.random() < 0.3:
            buf = bytearray(line)
            for _ in range(int(rng.integers(1, 3))):
                kind, pos = rng.integers(0, 3), int(rng.integers(0, len(buf)))
                if kind == 0:
                    buf[pos] ^= 1 << int(rng.integers(0, 8))
                elif kind == 1:
                    del buf[pos : pos + int(rng.integers(1, 4))]
                else:
                    n = int(rng.integers(1, 4))
                    buf[pos:pos] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            stream += buf
        else:
            stream += line
            untouched.append(line)
    f = pd6.Pd6Framer(policy=policy)
    got = feed_random(f, bytes(stream), rng)
    it = iter(got)
    assert all(any(g == u for g in it) for u in untouched)  # in order, none lost
    assert f.stats.bad_frames >= 1
    for fr in got:  # a corrupted digit that keeps the structure passes (no checksum in PD6)
        with contextlib.suppress(DecodeError):
            pd6.decode(fr)


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def auvgw_cmd() -> list[str]:
    exe = Path(sys.executable).parent / "auvgw"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "auvgw.cli"]


@pytest.mark.e2e
def test_cli_decode_pd6(tmp_path: Path) -> None:
    path = tmp_path / "dvl.pd6"
    path.write_bytes(b"noise\r\n" + STREAM * 3 + b":XX,1\r\n")
    out = subprocess.run(
        [*auvgw_cmd(), "decode", "--format", "pd6", str(path)],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stderr
    msgs = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(msgs) == 3 * len(LINES)
    assert msgs[6]["type"] == "pd6.BI" and msgs[6]["x"] == pytest.approx(0.024)
    summary = json.loads(out.stderr.strip().splitlines()[-1])
    assert summary["messages"]["pd6.BI"] == 3
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (33, 1, 7 + 7)


@pytest.mark.e2e
def test_cli_decode_not_pd6(tmp_path: Path) -> None:
    path = tmp_path / "x.bin"
    path.write_bytes(bytes(range(256)) * 8)
    out = subprocess.run(
        [*auvgw_cmd(), "decode", "--format", "pd6", str(path)],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].startswith("auvgw decode: error: ")


@pytest.mark.parametrize("chunk", CHUNKS)
def test_fixture_field_syntax_and_range_rejections_are_counted_per_reason(chunk: int) -> None:
    """PD6 has no checksum: a line whose structure holds but whose field text is not the
    table's form (``syntax``) or whose value is not physically plausible (``range``) is a bad
    frame, counted under its reason; the lines around it come through."""
    bad = [
        b":SA,+95.00, +1.92, 75.20\r\n",  # pitch 95 deg: range
        b":BI,+12000,    -6,   -20,    -4,A\r\n",  # 12 m/s over the bottom: range
        b":TS,04081111563644,35.0,+21.0,   0.0,1924.0,  0\r\n",  # sound speed 1924 m/s: range
        b":TS,04131111563644,35.0,+21.0,   0.0,1524.0,  0\r\n",  # month 13: syntax
        b":BS,   -13,   +2x,   -20,A\r\n",  # not a number: syntax
        b":BE,   +17,   +18,   -20,X\r\n",  # status not A/V: syntax
    ]
    stream = LINES[0] + b"".join(b + LINES[i + 1] for i, b in enumerate(bad))
    frames, s = run_framer(stream, chunk)
    assert frames == LINES[: len(bad) + 1]
    assert (s.bad_frames, s.skipped_bytes) == (len(bad), sum(map(len, bad)))
    assert dict(s.reasons) == {"range": 3, "syntax": 3}
    with pytest.raises(pd6.FieldRejected, match=r":SA field pitch at byte 4: '\+95\.00': 1\.65"):
        pd6.decode(bad[0])
