"""Seanet .V4LOG container: layout, write -> read round trip, bad records, the decode CLI."""

from __future__ import annotations

import io
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from auvgw.drivers import seanet as sn
from auvgw.drivers.framing import ErrorPolicy
from auvgw.drivers.seanet import v4log as v4
from auvgw.drivers.spec import from_jsonable, to_jsonable
from auvgw.testing.format_samples import T0, sample_items


@pytest.fixture
def log_file(tmp_path: Path) -> Path:
    path = tmp_path / "scan.V4LOG"
    v4.write_v4log(path, sample_items())
    return path


def test_write_read_round_trip(log_file: Path) -> None:
    items = sample_items()
    got = list(v4.read_v4log(log_file, policy=ErrorPolicy.RAISE))
    assert [m for _, m in got] == [m for _, m in items]
    assert [t for t, _ in got] == pytest.approx([t for t, _ in items], abs=1e-5)
    hdr = v4.read_header(log_file)
    assert hdr.text == "SeaNetV4 Log File V1"
    assert hdr.n_records == len(items)
    assert hdr.data_offset == 80
    assert hdr.config_offset == log_file.stat().st_size
    assert hdr.open_time == pytest.approx(T0, abs=1e-5)
    assert hdr.close_time == pytest.approx(T0 + 1.4, abs=1e-5)


def test_file_layout_matches_the_documented_bytes(log_file: Path) -> None:
    data = log_file.read_bytes()
    assert data[:32] == b"SeaNetV4 Log File V1".ljust(32, b"\x00")
    version, reg, data_off, n, config = struct.unpack_from("<5I", data, 32)
    assert (version, reg, data_off, n, config) == (1, 0, 80, 10, len(data))
    # first record: the mtAlive packet
    packet = sn.encode(sample_items()[0][1])
    length, days = struct.unpack_from("<Hd", data, 80)
    assert length == len(packet) + 1 == 23
    assert days == pytest.approx(T0 / 86400 + 25569.0)  # TDateTime: days since 1899-12-30
    assert data[90:92] == bytes([2, 255])  # Tx, Rx
    assert data[92 : 80 + length] == packet[10:-1]  # from the type byte, without the LF


def hand_built_log(bins: bytes, bearing: int, days: float) -> bytes:
    """A .V4LOG with one mtHeadData record, built from the documented layout only."""
    rec = bytearray(46 + len(bins))
    struct.pack_into("<Hd", rec, 0, len(rec), days)
    rec[10], rec[11], rec[12], rec[13], rec[14] = 2, 255, 2, 0x80, 2  # Tx Rx type seq node
    struct.pack_into("<H", rec, 15, len(rec) - 15)  # bytes after the node (packet offset 13..)
    rec[17] = 11  # device type
    struct.pack_into("<H", rec, 20, 0x2301 | 2)  # HdCtrl: 8-bit, continuous
    struct.pack_into("<H", rec, 22, 150)  # range 15.0 m
    struct.pack_into("<H", rec, 35, 25)  # ADInterval
    rec[41] = 16  # step
    struct.pack_into("<HH", rec, 42, bearing, len(bins))
    rec[46:] = bins
    header = bytearray(80)
    header[:20] = b"SeaNetV4 Log File V1"
    struct.pack_into("<8I2d", header, 32, 1, 0, 80, 1, 80 + len(rec), 0, 0, 0, days, days)
    return bytes(header + rec)


def test_hand_built_record_decodes(tmp_path: Path) -> None:
    days = 45_000.5  # 2023-03-15 12:00
    path = tmp_path / "hand.V4LOG"
    path.write_bytes(hand_built_log(bytes([9, 8, 7, 200]), 4800, days))
    ((t, m),) = list(v4.read_v4log(path, policy=ErrorPolicy.RAISE))
    assert t == pytest.approx((45_000.5 - 25_569) * 86_400)
    assert isinstance(m, sn.HeadData)
    assert m.bins.tolist() == [9, 8, 7, 200]
    assert m.bearing == pytest.approx(3 * np.pi / 2)
    assert m.range_m == pytest.approx(15.0) and m.adc8on and m.continuous
    assert m.bin_length(1500.0) == pytest.approx(25 * 640e-9 * 750)
    assert (m.tx_node, m.rx_node, m.byte_count) == (2, 255, 0)


def test_records_decode_and_encode_exactly(log_file: Path) -> None:
    frames, framer = v4.read_file(log_file)
    frames = list(frames)
    assert framer.stats.frames == 10
    for fr in frames:
        (rec,) = v4.decode(fr.data)
        assert v4.encode(rec) == fr.data
        assert v4.FORMAT.decode(fr.data) == [rec]
        assert v4.packet_to_record(v4.record_to_packet(fr.data), rec.tdatetime) == fr.data
        assert rec.time == pytest.approx(v4.unix_from_tdatetime(rec.tdatetime))
        assert from_jsonable(to_jsonable(rec)) == rec


def test_record_packet_conversion_keeps_packets() -> None:
    for _, m in sample_items():
        packet = sn.encode(m)
        assert v4.record_to_packet(v4.packet_to_record(packet, 45_000.0)) == packet


def test_writer_exact_records(tmp_path: Path) -> None:
    path = tmp_path / "exact.V4LOG"
    recs = [v4.V4LogRecord.at(T0 + i, m) for i, (_, m) in enumerate(sample_items())]
    with v4.V4LogWriter(path) as w:
        for r in recs:
            w.write_record(r)
    frames, _ = v4.read_file(path)
    assert [v4.decode(fr.data)[0] for fr in frames] == recs


def _frames(data: bytes, chunk: int) -> tuple[list, v4.V4LogFramer]:
    f = v4.V4LogFramer(policy=ErrorPolicy.IGNORE)
    return list(f.frames(data[i : i + chunk] for i in range(0, len(data), chunk))), f


def test_any_chunking(log_file: Path) -> None:
    data = log_file.read_bytes()
    ref, _ = _frames(data, len(data))
    assert len(ref) == 10
    for chunk in (1, 2, 7, 13, 80, 1000):
        frames, f = _frames(data, chunk)
        assert frames == ref
        assert (f.stats.frames, f.stats.bad_frames, f.stats.skipped_bytes) == (10, 0, 80)


def _record_spans(data: bytes) -> list[tuple[int, int]]:
    spans, pos = [], 80
    while pos < len(data):
        (n,) = struct.unpack_from("<H", data, pos)
        spans.append((pos, n))
        pos += n
    return spans


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("length", struct.pack("<H", 3), "record_length"),
        ("length", struct.pack("<H", 60_000), "record_length"),
        ("time", struct.pack("<d", 0.0), "record_time"),
        ("time", struct.pack("<d", float("nan")), "record_time"),
    ],
)
def test_bad_record_is_skipped_and_the_rest_recovered(
    log_file: Path, field: str, value: bytes, reason: str
) -> None:
    data = bytearray(log_file.read_bytes())
    spans = _record_spans(bytes(data))
    pos, n = spans[4]  # the mtHeadCommand record
    at = pos if field == "length" else pos + 2
    data[at : at + len(value)] = value
    for chunk in (1, 5, 4096):
        frames, f = _frames(bytes(data), chunk)
        assert [fr.offset for fr in frames] == [p for p, _ in spans if p != pos]
        assert f.stats.bad_frames == 1 and dict(f.stats.reasons) == {reason: 1}
        assert f.stats.skipped_bytes == 80 + n
    kept = [type(m).__name__ for _, m in v4.read_v4log(_write(log_file, data))]
    assert "HeadCommand" not in kept and len(kept) == 9


def _write(path: Path, data: bytes | bytearray) -> Path:
    out = path.with_name("edited.V4LOG")
    out.write_bytes(bytes(data))
    return out


def test_truncated_file(log_file: Path) -> None:
    data = log_file.read_bytes()
    spans = _record_spans(data)
    pos, n = spans[-2]  # the 4-bit mtHeadData record loses its tail (and the record after it)
    assert n > 20
    cut = data[: pos + 20]
    frames, f = _frames(cut, 33)
    assert [fr.offset for fr in frames] == [p for p, _ in spans[:-2]]
    assert f.stats.bad_frames == 1 and dict(f.stats.reasons) == {"truncated": 1}
    assert f.stats.skipped_bytes == 80 + 20


def test_not_a_v4log_names_the_file(tmp_path: Path) -> None:
    raw = tmp_path / "capture.bin"
    raw.write_bytes(b"".join(sn.encode(m) for _, m in sample_items()))
    with pytest.raises(v4.V4LogError, match=r"capture\.bin: not a SeaNet \.V4LOG file"):
        list(v4.read_v4log(raw))
    with pytest.raises(v4.V4LogError, match=r"capture\.bin: not a SeaNet \.V4LOG file"):
        v4.read_header(raw)
    empty = tmp_path / "empty.V4LOG"
    empty.write_bytes(b"")
    with pytest.raises(v4.V4LogError, match=r"empty\.V4LOG: not a SeaNet \.V4LOG file"):
        list(v4.read_v4log(empty))
    short = tmp_path / "short.V4LOG"
    short.write_bytes(b"SeaNetV4 Log File V1\x00\x00")
    with pytest.raises(v4.V4LogError, match=r"truncated \.V4LOG header: 22 of 80 bytes"):
        list(v4.read_v4log(short))


def test_tdatetime_conversions() -> None:
    assert v4.unix_from_tdatetime(25569.0) == 0.0
    assert v4.unix_from_tdatetime(25569.5) == 43_200.0
    assert v4.tdatetime_from_unix(86_400.0) == 25570.0
    assert v4.unix_from_tdatetime(v4.tdatetime_from_unix(T0)) == pytest.approx(T0, abs=1e-6)


# -- the CLI ----------------------------------------------------------------------------------

AUVGW = Path(sys.executable).with_name("auvgw")


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [str(AUVGW)] if AUVGW.exists() else [sys.executable, "-m", "auvgw.cli"]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=120)


@pytest.mark.e2e
def test_cli_decodes_a_v4log(log_file: Path) -> None:
    res = run_cli("decode", "--format", "v4log", str(log_file))
    assert res.returncode == 0, res.stderr
    lines = [json.loads(x) for x in res.stdout.splitlines()]
    assert [d["type"] for d in lines] == ["V4LogRecord"] * 10
    assert [d["message"]["type"] for d in lines] == [m.TYPE for _, m in sample_items()]
    assert lines[6]["message"]["bins"] == list(range(40))
    assert lines[0]["time"] == pytest.approx(T0, abs=1e-5)
    summary = json.loads(res.stderr.strip().splitlines()[-1])
    assert summary["frames"] == 10 and summary["bad_frames"] == 0
    assert summary["messages"] == {"V4LogRecord": 10}


@pytest.mark.e2e
def test_cli_decodes_a_raw_seanet_capture(tmp_path: Path) -> None:
    raw = tmp_path / "capture.bin"
    items = sample_items()
    raw.write_bytes(b"\x00junk" + b"".join(sn.encode(m) for _, m in items))
    res = run_cli("decode", "--format", "seanet", str(raw))
    assert res.returncode == 0, res.stderr
    types = [json.loads(x)["type"] for x in res.stdout.splitlines()]
    assert types == [m.TYPE for _, m in items]
    summary = json.loads(res.stderr.strip().splitlines()[-1])
    assert summary["messages"]["mtHeadData"] == 2 and summary["messages"]["mtSendData"] == 2
    assert (summary["frames"], summary["bad_frames"], summary["skipped_bytes"]) == (10, 0, 5)


@pytest.mark.e2e
def test_cli_wrong_file_is_one_line_exit_2(tmp_path: Path, log_file: Path) -> None:
    raw = tmp_path / "capture.bin"
    raw.write_bytes(b"".join(sn.encode(m) for _, m in sample_items()))
    res = run_cli("decode", "--format", "v4log", str(raw))
    assert res.returncode == 2
    assert res.stdout == ""
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and "not a SeaNet .V4LOG file" in err[0] and "capture.bin" in err[0]
    assert "Traceback" not in res.stderr
    # a .V4LOG read as a raw SeaNet stream holds no packet
    res = run_cli("decode", "--format", "seanet", str(log_file))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "no valid seanet frame" in res.stderr.strip().splitlines()[-1]


def _log_bytes(items: list[tuple[float, sn.SeaNetMessage]]) -> tuple[bytes, list[bytes]]:
    """A .V4LOG of ``items`` in memory: its header and its records."""
    buf = io.BytesIO()
    with v4.V4LogWriter(buf) as writer:
        for t, m in items:
            writer.write(t, m)
    data = buf.getvalue()
    records, pos = [], v4.HEADER_SIZE
    while pos < len(data):
        (n,) = struct.unpack_from("<H", data, pos)
        records.append(data[pos : pos + n])
        pos += n
    return data[: v4.HEADER_SIZE], records


@st.composite
def _corrupted_logs(draw: st.DrawFn) -> tuple[bytes, list[bytes], int, bytes, list[int]]:
    """(header, good records, index of the corrupted one, the wire, chunk cuts)."""
    items = sample_items()
    picks = draw(st.lists(st.integers(0, len(items) - 1), min_size=3, max_size=12))
    head, records = _log_bytes([(T0 + 0.5 * j, items[i][1]) for j, i in enumerate(picks)])
    k = draw(st.integers(0, len(records) - 1))
    bad = bytearray(records[k])
    kind = draw(st.sampled_from(["length", "bits", "burst"]))
    if kind == "length":  # the length a few bytes off: the next record starts near its end
        struct.pack_into("<H", bad, 0, len(bad) + draw(st.integers(-8, 12)))
    elif kind == "bits":
        for pos in draw(st.lists(st.integers(0, 8 * len(bad) - 1), min_size=1, max_size=3)):
            bad[pos // 8] ^= 1 << (pos % 8)
    else:  # a burst of random bytes
        at = draw(st.integers(0, len(bad) - 2))
        burst = draw(st.binary(min_size=1, max_size=min(16, len(bad) - at)))
        bad[at : at + len(burst)] = burst
    assume(bytes(bad) != records[k])
    wire = head + b"".join(records[:k]) + bytes(bad) + b"".join(records[k + 1 :])
    end = len(head) + sum(map(len, records[: k + 1]))  # cuts anywhere, and near its end
    near = st.integers(max(1, end - 12), min(len(wire) - 1, end + 12))
    cuts = draw(st.lists(st.integers(1, len(wire) - 1), max_size=40))
    cuts = sorted(set(cuts + draw(st.lists(near, max_size=3))))
    return head, records, k, wire, cuts


@settings(max_examples=300, deadline=None)
@given(_corrupted_logs())
def test_one_corrupted_record_costs_at_most_itself_whatever_the_chunking(
    case: tuple[bytes, list[bytes], int, bytes, list[int]],
) -> None:
    """Random good records, one of them corrupted (bit flips or a burst), random chunk splits:
    every other record comes out at its offset, and the chunked stream gives exactly the frames
    and counters (frames, bad frames, skipped bytes) of the whole one (issue 18)."""
    head, records, k, wire, cuts = case
    whole = v4.V4LogFramer(policy="ignore")
    ref = [(f.data, f.offset) for f in whole.frames([wire])]
    starts = [len(head) + sum(map(len, records[:j])) for j in range(len(records))]
    intact = [(r, s) for j, (r, s) in enumerate(zip(records, starts, strict=True)) if j != k]
    assert [fr for fr in ref if fr in intact] == intact
    chunked = v4.V4LogFramer(policy="ignore")
    chunks = [wire[a:b] for a, b in zip([0, *cuts], [*cuts, len(wire)], strict=True)]
    assert [(f.data, f.offset) for f in chunked.frames(chunks)] == ref
    counts = [(f.stats.frames, f.stats.bad_frames, f.stats.skipped_bytes) for f in (chunked, whole)]
    assert counts[0] == counts[1]  # the reason may differ: a waiting record has no content yet
