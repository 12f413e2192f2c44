"""MS3A magnetometer ASCII lines: table-driven codec, framer, site tables and the CLI."""

from __future__ import annotations

import dataclasses
import json
import random
import re
import subprocess
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import DecodeError, ErrorPolicy, FrameError
from auvgw.drivers.ms3a import CODEC, FORMAT, Ms3aCodec, Ms3aFramer, Ms3aSample
from auvgw.drivers.spec import WireError, raw_value, to_jsonable
from auvgw.drivers.tablecodec import TableError
from auvgw.ground.paths import REPO_ROOT, config_file
from auvgw.testing.format_samples import MS3A_LINES as L
from auvgw.testing.format_samples import crc16_ccitt_false, ref_line

SHIPPED_TEXT = config_file("ms3a.toml").read_text()
AUVGW = REPO_ROOT / ".venv" / "bin" / "auvgw"


N = len(L[0])


def test_reference_line_decodes() -> None:
    line = ref_line(123, 213_456, -12_345, 432_100)
    assert line == b"$MS3A,000123,+021345.6,-001234.5,+043210.0*5D\r\n"
    m = CODEC.decode(line)
    assert isinstance(m, Ms3aSample)
    assert m.counter == 123
    assert (m.bx, m.by, m.bz) == pytest.approx((21345.6, -1234.5, 43210.0))
    assert m.b_nt == pytest.approx([21345.6, -1234.5, 43210.0])
    assert m.b_tesla == pytest.approx([21345.6e-9, -1234.5e-9, 43210.0e-9])
    assert raw_value(m, "bx") == 213_456 and raw_value(m, "by") == -12_345
    assert raw_value(m, "counter") == 123
    assert CODEC.encode(m) == line
    assert to_jsonable(m) == {
        "type": "Ms3aSample",
        "counter": 123,
        "bx": pytest.approx(21345.6),
        "by": pytest.approx(-1234.5),
        "bz": pytest.approx(43210.0),
    }
    assert N == 47


def test_extremes_and_zero() -> None:
    for raws in [(0, 0, 0, 0), (999_999, 2_000_000, -2_000_000, 1)]:  # +-200000.0 nT: the table
        line = ref_line(*raws)
        m = CODEC.decode(line)
        assert [raw_value(m, n) for n in ("counter", "bx", "by", "bz")] == list(raws)
        assert CODEC.encode(m) == line
    assert ref_line(0, 0, 0, 0).startswith(b"$MS3A,000000,+000000.0,")


def test_values_outside_the_plausible_range_are_rejected_and_counted_as_range() -> None:
    """Well-formed lines with a good checksum but a field beyond the fluxgate's full scale
    (+-200 uT, the table's min/max) are bad frames of reason ``range``; the lines around them
    come through."""
    good = [ref_line(i, 200_000, -10_000, 430_000) for i in range(3)]
    high = ref_line(7, 2_000_001, 0, 0)  # +200000.1 nT
    low = ref_line(8, 0, 0, -9_999_999)
    with pytest.raises(
        DecodeError, match=r"range: field bx: 200000\.1 nT outside -200000 \.\. 200000$"
    ):
        CODEC.decode(high)
    f = Ms3aFramer(policy=ErrorPolicy.IGNORE)
    frames = f.feed(good[0] + high + good[1] + low + good[2])
    assert [fr.data for fr in frames] == good
    assert dict(f.stats.reasons) == {"range": 2}
    assert f.stats.bad_frames == 2


def test_encode_errors_name_field_and_form() -> None:
    m = CODEC.decode(L[0])
    with pytest.raises(WireError, match=r"Ms3aSample\.bx: 1000000\.0 nT does not fit .*width 9"):
        CODEC.encode(dataclasses.replace(m, bx=1_000_000.0))
    with pytest.raises(WireError, match=r"Ms3aSample\.counter: .*negative value"):
        CODEC.encode(dataclasses.replace(m, counter=-1))
    with pytest.raises(WireError, match=r"Ms3aSample\.bz: nan is not finite"):
        CODEC.encode(dataclasses.replace(m, bz=float("nan")))
    with pytest.raises(DecodeError, match="checksum: line says 00"):
        CODEC.decode(L[0][:-4] + b"00\r\n")


# -- properties ---------------------------------------------------------------------------------

raw_nt = st.integers(-2_000_000, 2_000_000)  # the table's plausible +-200000.0 nT


@settings(max_examples=200, deadline=None)
@given(counter=st.integers(0, 999_999), bx=raw_nt, by=raw_nt, bz=raw_nt)
def test_any_valid_line_roundtrips_exactly(counter: int, bx: int, by: int, bz: int) -> None:
    line = ref_line(counter, bx, by, bz)
    m = CODEC.decode(line)
    assert [raw_value(m, n) for n in ("counter", "bx", "by", "bz")] == [counter, bx, by, bz]
    assert m.bx == pytest.approx(bx / 10)
    assert CODEC.encode(m) == line
    assert Ms3aFramer(policy="raise").feed(line)[0].data == line


field_nt = st.floats(-200_000.0, 200_000.0)


@settings(max_examples=200, deadline=None)
@given(counter=st.integers(0, 999_999), b=st.tuples(field_nt, field_nt, field_nt))
def test_message_roundtrip_within_resolution(counter: int, b: tuple[float, ...]) -> None:
    line = CODEC.encode(Ms3aSample(counter=counter, bx=b[0], by=b[1], bz=b[2]))
    assert len(line) == N
    d = CODEC.decode(line)
    assert d.counter == counter
    assert d.b_nt == pytest.approx(list(b), abs=0.05 + 1e-9)
    assert CODEC.encode(d) == line


# -- named corrupted fixtures -----------------------------------------------------------------


def _bad_checksum() -> bytes:
    return L[1][:-4] + (b"00" if L[1][-4:-2] != b"00" else b"01") + b"\r\n"


FIXTURES = {
    # name: (stream, lines delivered, bad_frames, skipped_bytes)
    "bad_checksum": (L[0] + _bad_checksum() + L[2], [L[0], L[2]], 1, N),
    "bad_field_count": (
        L[0] + ref_line(0, 0, 0, 0, body="MS3A,000001,+000001.0,+000002.0") + L[2],
        [L[0], L[2]],
        1,
        len(ref_line(0, 0, 0, 0, body="MS3A,000001,+000001.0,+000002.0")),
    ),
    "non_numeric_field": (
        L[0] + ref_line(0, 0, 0, 0, body="MS3A,000001,+0000x1.0,+000002.0,+000003.0") + L[2],
        [L[0], L[2]],
        1,
        N,
    ),
    "wrong_width": (
        L[0] + ref_line(0, 0, 0, 0, body="MS3A,000001,+00001.0,+000002.0,+000003.0") + L[2],
        [L[0], L[2]],
        1,
        N - 1,
    ),
    "wrong_decimals": (
        L[0] + ref_line(0, 0, 0, 0, body="MS3A,000001,+00001.00,+000002.0,+000003.0") + L[2],
        [L[0], L[2]],
        1,
        N,
    ),
    "lower_case_checksum": (
        L[0]
        + ref_line(0, 0, 0, 0, body="MS3A,000002,+000001.0,+000002.0,+000003.0")[:-4]
        + b"5b\r\n"  # the right XOR (0x5B) in the wrong case
        + L[2],
        [L[0], L[2]],
        1,
        N,
    ),
    "non_ascii_byte": (L[0] + L[1].replace(b"MS3A", b"MS\xb3A") + L[2], [L[0], L[2]], 1, N),
    "overlong_line": (L[0] + b"$MS3A," + b"1" * 200 + b"\r\n" + L[1], [L[0], L[1]], 1, 208),
    "truncated_mid_stream": (L[0] + L[1][:20] + L[2], [L[0], L[2]], 1, 20),
    "truncated_at_end": (L[0] + L[1] + L[2][:30], [L[0], L[1]], 1, 30),
    "missing_terminator": (L[0] + L[1][:-2] + L[2], [L[0], L[2]], 1, N - 2),
    "garbage_between_lines": (
        L[0] + b"\r\n\x00noise*7F\r\n" + L[1] + b"\xff" * 50 + L[2],
        [L[0], L[1], L[2]],
        0,
        len(b"\r\n\x00noise*7F\r\n") + 50,
    ),
    "starts_mid_line": (L[0][10:] + L[1] + L[2], [L[1], L[2]], 0, N - 10),
}


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("chunk", [1, 5, 47, 10_000])
def test_corrupted_fixture_counts(name: str, chunk: int) -> None:
    stream, expected, bad, skipped = FIXTURES[name]
    f = Ms3aFramer(policy=ErrorPolicy.IGNORE)
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]
    frames = [fr.data for fr in f.frames(chunks)]
    assert frames == expected
    assert (f.stats.frames, f.stats.bad_frames, f.stats.skipped_bytes) == (
        len(expected),
        bad,
        skipped,
    )
    assert [CODEC.decode(fr).counter for fr in frames] == [
        CODEC.decode(e).counter for e in expected
    ]


@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("bad_checksum", r"checksum: line says 00, computed [0-9A-F]{2}"),
        ("bad_field_count", r"fields: 4, expected 5"),
        ("non_numeric_field", r"syntax: field bx: '\+0000x1\.0' is not a number"),
        ("wrong_width", r"syntax: field bx: '\+00001\.0', expected '\+000001\.0'"),
        ("wrong_decimals", r"syntax: field bx: '\+00001\.00' has 2 decimals, table says 1"),
        ("lower_case_checksum", r"checksum: digits '5b'"),
        ("non_ascii_byte", r"character: byte 0xb3 is not ASCII"),
        ("overlong_line", r"overlong line: no terminator within 82 bytes"),
        ("truncated_mid_stream", r"truncated line: new start character 20 bytes in"),
    ],
)
def test_bad_line_reasons(name: str, reason: str) -> None:
    f = Ms3aFramer(policy=ErrorPolicy.RAISE, source="mag.log")
    with pytest.raises(FrameError, match=rf"mag\.log: bad frame at byte offset {N}: {reason}"):
        f.feed(FIXTURES[name][0])


# -- fuzz ---------------------------------------------------------------------------------------

ALPHABET = st.sampled_from(list(b"$MS3A,+-.0123456789*\r\nx\xff"))


def _chunks(data: bytes, rnd: random.Random) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = rnd.choice((1, 2, 3, 10, 47, 48, 100, 500))
        out.append(data[i : i + n])
        i += n
    return out


@settings(max_examples=80, deadline=None)
@given(
    data=st.one_of(st.binary(max_size=2000), st.lists(ALPHABET, max_size=2000).map(bytes)),
    seed=st.integers(0, 2**32 - 1),
)
def test_fuzz_random_bytes(data: bytes, seed: int) -> None:
    f = Ms3aFramer(policy=ErrorPolicy.IGNORE)
    out = [fr.data for fr in f.frames(_chunks(data, random.Random(seed)))]
    for line in out:  # anything delivered is a valid line that re-encodes identically
        assert CODEC.encode(CODEC.decode(line)) == line
    assert f.stats.skipped_bytes == len(data) - sum(map(len, out))


OPS = st.sampled_from(["keep", "keep", "flip", "truncate", "garbage", "drop_start", "drop_cr"])


@settings(max_examples=100, deadline=None)
@given(ops=st.lists(OPS, min_size=1, max_size=25), data=st.data(), seed=st.integers(0, 2**31))
def test_fuzz_corrupted_stream_keeps_every_untouched_line(ops, data, seed) -> None:
    lines = [ref_line(i, 1000 * i - 5000, -7 * i, 31 * i) for i in range(len(ops))]
    stream = bytearray()
    kept = []
    for op, line in zip(ops, lines, strict=True):
        if op == "keep":
            stream += line
            kept.append(line)
        elif op == "flip":
            b = bytearray(line)
            pos = data.draw(st.integers(1, len(b) - 3))
            b[pos] ^= data.draw(st.integers(1, 255))
            stream += b
        elif op == "truncate":
            stream += line[: data.draw(st.integers(1, len(line) - 1))]
        elif op == "garbage":
            stream += data.draw(st.binary(max_size=100)) + line
            kept.append(line)
        elif op == "drop_start":
            stream += line[1:]
        else:
            stream += line[:-2] + b"\n"
    f = Ms3aFramer(policy=ErrorPolicy.IGNORE)
    out = [fr.data for fr in f.frames(_chunks(bytes(stream), random.Random(seed)))]
    it = iter(out)
    assert all(any(k == o for o in it) for k in kept)  # kept lines, in order
    assert all(CODEC.encode(CODEC.decode(line)) == line for line in out)
    assert f.stats.skipped_bytes == len(stream) - sum(map(len, out))


# -- site tables -------------------------------------------------------------------------------

SITE_TOML = """
[line]
start = "#"
header = "MAG"
separator = ";"
terminator = "\\n"
max_length = 60

[line.checksum]
kind = "crc16-ccitt-false"
delimiter = "|"
hex_case = "lower"

[[fields]]
name = "bz"
decimals = 3
units = "uT"
[[fields]]
name = "by"
decimals = 3
units = "uT"
[[fields]]
name = "bx"
decimals = 3
units = "uT"
[[fields]]
name = "temperature"
decimals = 1
description = "sensor temperature, deg C"
[[fields]]
name = "counter"
"""


def test_site_table_changes_line_without_code(tmp_path: Path) -> None:
    path = tmp_path / "site_mag.toml"
    path.write_text(SITE_TOML)
    codec = Ms3aCodec.from_toml(path)
    body = "MAG;-43.210;0.005;21.345;-2.5;17"
    line = f"#{body}|{crc16_ccitt_false(body.encode()):04x}\n".encode()
    m = codec.decode(line)
    assert type(m).__name__ == "Ms3aSample" and type(m) is not Ms3aSample
    assert (m.bx, m.by, m.bz) == pytest.approx((21345.0, 5.0, -43210.0))
    assert m.temperature == pytest.approx(-2.5) and m.counter == 17
    assert raw_value(m, "bz") == -43210
    assert codec.encode(m) == line
    # free-width fields have one canonical text: leading zeros or '+' are rejected
    for body in ["MAG;-43.210;0.005;021.345;-2.5;17", "MAG;+43.210;0.005;21.345;-2.5;17"]:
        bad = f"#{body}|{crc16_ccitt_false(body.encode()):04x}\n".encode()
        with pytest.raises(DecodeError, match="syntax: field"):
            codec.decode(bad)
    f = codec.framer(policy=ErrorPolicy.IGNORE)
    stream = L[0] + line + b"#MAG;1" + line + L[1]
    assert [fr.data for fr in f.frames([stream[i : i + 3] for i in range(0, len(stream), 3)])] == [
        line,
        line,
    ]
    assert f.stats.bad_frames == 1  # "#MAG;1" cut short by the next '#'
    assert CODEC.decode(L[0]).counter == 0  # shipped codec untouched


def test_site_table_without_checksum_and_header(tmp_path: Path) -> None:
    text = (
        SHIPPED_TEXT.replace('kind = "xor8"', 'kind = "none"')
        .replace('header = "MS3A"', 'header = ""')
        .replace('separator = ","', 'separator = " "')
    )
    path = tmp_path / "plain.toml"
    path.write_text(text)
    codec = Ms3aCodec.from_toml(path)
    line = b"$000007 +000001.5 -000002.0 +000003.0\r\n"
    m = codec.decode(line)
    assert (m.counter, m.bx, m.by, m.bz) == (7, 1.5, -2.0, 3.0)
    assert raw_value(m, "counter") == 7 and codec.spec.fields[0].offset == 0
    assert codec.encode(m) == line
    with pytest.raises(DecodeError, match="fields: 3, expected 4"):
        codec.decode(b"$000007 +000001.5 -000002.0\r\n")


def _edit(old: str, new: str) -> str:
    assert old in SHIPPED_TEXT, old
    return SHIPPED_TEXT.replace(old, new, 1)


BAD_TABLES = {
    "checksum_kind": (
        _edit('kind = "xor8"', 'kind = "nmea"'),
        r"\[line\.checksum\]: unknown checksum kind 'nmea'; expected one of none, crc16",
    ),
    "missing_field": (_edit('name = "by"', 'name = "b_y"'), r"missing required field\(s\) by"),
    "wrong_units": (
        _edit('units = "nT"', 'units = "m"'),
        r"fields\[1\] \(bx\): units 'm' give m; expected table units 'nT', 'uT', 'T', 'G', 'mG'",
    ),
    "width_too_small": (
        _edit("width = 9", "width = 3"),
        r"fields\[1\] \(bx\): width = 3 leaves 1 digits; expected 2\.\.12 digits",
    ),
    "bad_sign": (_edit('sign = "always"', 'sign = "plus"'), r"fields\[1\] \(bx\): sign = 'plus'"),
    "max_length_short": (
        _edit("max_length = 82", "max_length = 40"),
        r"\[line\]: max_length = 40 but a full line is 47 bytes",
    ),
    "start_two_chars": (_edit('start = "$"', 'start = "$$"'), r"\[line\]: start = '\$\$'"),
    "unknown_key": (_edit("width = 6", "width = 6\npadding = 0"), r"unknown key\(s\) padding"),
    "counter_scaled": (
        _edit('name = "counter"', 'name = "counter"\nscale = 2'),
        r"fields\[0\] \(counter\): expected an unscaled integer count",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_TABLES))
def test_bad_site_table_errors(name: str, tmp_path: Path) -> None:
    text, pattern = BAD_TABLES[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    with pytest.raises(TableError) as info:
        Ms3aCodec.from_toml(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: "), msg
    assert re.search(pattern, msg), msg


# -- registry, docs, CLI ----------------------------------------------------------------------


def test_format_registry_and_doc() -> None:
    assert get_format("ms3a") is FORMAT
    assert FORMAT.decode(L[2])[0] == CODEC.decode(L[2])
    assert FORMAT.encode(CODEC.decode(L[2])) == L[2]
    doc = (REPO_ROOT / "docs" / "protocols" / "ms3a.md").read_text()
    assert "assumed layout" in doc.lower()
    assert "HMR2300" in doc and "15000 counts/gauss" in doc
    assert L[0].decode().strip() in doc or "$MS3A,000123,+021345.6,-001234.5,+043210.0*5D" in doc


@pytest.mark.e2e
def test_cli_decode_json_lines_and_summary(tmp_path: Path) -> None:
    path = tmp_path / "mag.log"
    path.write_bytes(L[0][20:] + L[1] + _bad_checksum() + L[2] + L[3])
    r = subprocess.run(
        [str(AUVGW), "decode", "--format", "ms3a", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [d["counter"] for d in lines] == [1, 2, 3]
    assert lines[0]["type"] == "Ms3aSample"
    assert lines[0]["bx"] == pytest.approx(21345.7)
    summary = json.loads(r.stderr.strip().splitlines()[-1])
    assert summary["messages"] == {"Ms3aSample": 3}
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (3, 1, 27 + N)


@pytest.mark.e2e
def test_cli_wrong_file_is_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "ins.bin"
    path.write_bytes(bytes(range(256)) * 8)
    r = subprocess.run(
        [str(AUVGW), "decode", "--format", "ms3a", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stdout == ""
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("auvgw decode: error: ") and "no valid ms3a frame" in last
    assert "Traceback" not in r.stderr
