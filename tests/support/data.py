"""Test data: the real PD0 recording's frames, what the gateway should publish for them, JSON
lines, raw sequence numbers."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["frame_counters", "local_decoded", "pd0_frames", "read_jsonl"]


def read_jsonl(path: Path) -> list[dict]:
    """The JSON objects of a JSON-lines file (blank lines skipped)."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def pd0_frames(shared_data: Path, n: int | None = None) -> list[bytes]:
    """Verified PD0 ensembles of the real Workhorse file, as bytes."""
    from auvgw.drivers.formats import get_format

    frames, _ = get_format("pd0").frames_of_file(shared_data / "pd0" / "RDI_withBT.000")
    out = [f.data for f in frames]
    return out[:n] if n is not None else out


def local_decoded(frames: list[bytes]) -> list[dict]:
    """What the gateway should publish for these frames, decoded here (JSON-normalised)."""
    from auvgw.drivers.formats import get_format
    from auvgw.drivers.spec import to_jsonable

    fmt = get_format("pd0")
    return [json.loads(json.dumps(to_jsonable(m))) for f in frames for m in fmt.decode(f)]


def frame_counters(seqs: list[int]) -> list[int]:
    """The per-device frame counters of raw sequence numbers (``session_id << 32 | n``), after
    checking they all carry the same non-zero gateway session id."""
    sessions = {s >> 32 for s in seqs}
    assert len(sessions) <= 1 and 0 not in sessions, sessions
    return [s & 0xFFFFFFFF for s in seqs]
