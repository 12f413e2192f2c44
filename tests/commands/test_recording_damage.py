"""A damaged recording costs its damaged chunk only (issue 27): every single-byte flip over a
small recording, read in-process: never a traceback, never a changed sample delivered as valid,
damage reported by the reader and by ``auvgw verify``."""

from __future__ import annotations

import logging

import pytest

from auvgw.bus import pack_raw_attachment
from auvgw.cli import main
from auvgw.recording import McapRecorder, RecordingError, ScanReport, iter_samples


def _recording(path, n: int = 60):
    rec = McapRecorder(path, "v1", chunk_size=600)  # small chunks: several in a few kB
    rec.set_gateway_config('{"vehicle": "v1", "devices": {}}')
    for i in range(n):
        rec.add("auv/v1/raw/dvl", bytes([i % 256]) * 40, pack_raw_attachment(10**9 + i, i + 1, 0))
    rec.close()


def _samples(path, report=None):
    return [(s.key, s.log_time_ns, s.attachment, s.payload) for s in iter_samples(path, report)]


def test_every_single_byte_flip_costs_a_chunk_at_most_and_never_a_traceback(tmp_path):
    path = tmp_path / "small.mcap"
    _recording(path, 24)  # six chunks; each flip re-reads the file: cost ~ length squared
    good = _samples(path)
    assert len(good) == 24
    data = path.read_bytes()
    flipped = tmp_path / "flipped.mcap"
    outcome = {"refused (not a recording)": 0, "damage reported": 0, "no effect": 0}
    changed_undetected = 0
    logging.disable(logging.WARNING)
    try:
        for off in range(len(data)):
            bad = bytearray(data)
            bad[off] ^= 0xFF
            flipped.write_bytes(bytes(bad))
            report = ScanReport()
            try:
                got = _samples(flipped, report)
            except RecordingError:
                outcome["refused (not a recording)"] += 1
                continue
            extra = [s for s in got if s not in good]
            changed_undetected += len(extra)
            if report.damaged:
                outcome["damage reported"] += 1
            else:
                outcome["no effect"] += 1
                assert got == good, off  # an undetected flip changed nothing
    finally:
        logging.disable(logging.NOTSET)
    assert changed_undetected == 0, outcome  # no corrupted sample ever delivered
    assert outcome["damage reported"] > len(data) // 3, outcome
    assert outcome["refused (not a recording)"] == 8  # the leading magic


def test_verify_reports_the_damaged_chunk(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    _recording(path)
    assert main(["verify", str(path)]) == 0
    assert "clean" in capsys.readouterr().out
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        ci = sorted(make_reader(f).get_summary().chunk_indexes,
                    key=lambda c: c.chunk_start_offset)[3]  # fmt: skip
    data = bytearray(path.read_bytes())
    data[ci.chunk_start_offset + ci.chunk_length - 10] ^= 0x55  # in the 4th chunk's zstd data
    path.write_bytes(bytes(data))
    assert main(["verify", str(path)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert any("damaged chunk" in line and f"{path}: byte " in line for line in out), out
    assert "1 damaged" in out[-1]
    assert main(["verify", str(tmp_path / "none.mcap")]) == 2


@pytest.mark.parametrize("cut", [0.5, 0.9])
def test_a_truncated_recording_reads_up_to_the_cut(tmp_path, cut):
    path = tmp_path / "run.mcap"
    _recording(path)
    good = _samples(path)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * cut)])
    report = ScanReport()
    got = _samples(path, report)
    assert got == good[: len(got)] and len(got) > 0
    if cut < 0.8:  # cut in the data section: what is after the cut is gone
        assert len(got) < len(good)
    assert report.damaged  # the cut is reported
