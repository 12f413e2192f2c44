"""Good frames of every registered format, as the codecs (or the real PD0 recording) make them:
shared by tests/test_codec_laws.py (every format of the device registry must have samples here),
tests/test_framers_never_stall.py and benchmarks/reliability.py."""

from __future__ import annotations

import struct
from pathlib import Path

from test_acoustic import LINE as ACOUSTIC_LINE
from test_hn100 import good_frames as hn100_frames
from test_kongsberg import G as KONGSBERG_FRAMES
from test_ms3a import L as MS3A_LINES
from test_pd6 import LINES as PD6_LINES
from test_seanet import sample_messages
from test_v4log import sample_items

from auvgw.drivers import seanet as sn
from auvgw.drivers.seanet import v4log as v4
from auvgw.testing import pd0_frames

STREAM_FORMATS = ("pd0", "pd6", "seanet", "kongsberg", "hn100", "ms3a", "acoustic")


def samples(fmt: str, shared_data: Path) -> list[bytes]:
    """Good frames of a byte-stream format (one of :data:`STREAM_FORMATS`)."""
    if fmt == "pd0":
        return pd0_frames(shared_data, 8)
    if fmt == "seanet":
        return [sn.encode(m) for m in sample_messages()]
    if fmt == "kongsberg":
        return list(KONGSBERG_FRAMES)
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


def _acoustic(i: int) -> bytes:
    from auvgw.drivers.acoustic import CODEC

    msg = CODEC.message_type(counter=i, range=10.0 + 37.25 * i, bearing=0.5 - 0.3 * i,
                             depression=0.1 * i, beacon=1 + i % 3)  # fmt: skip
    return CODEC.encode(msg)


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
