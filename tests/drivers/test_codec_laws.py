"""The codec and framer laws, for every format of the device registry (a new device gets them by
being registered and giving its sample frames in tests/support/format_samples.py):

* round trip: ``encode(decode(b)) == b`` on sample frames and ``decode(encode(m)) == m``;
* garbage between frames loses no frame (and is counted as skipped bytes);
* a frame with a corrupted byte is dropped and counted (formats with a checksum), the others
  come through;
* resync at sync + 1: a truncated frame whose length claim swallows the next frames costs
  itself only;
* chunking invariance: any chunking of a stream gives the same frames, offsets and counters;
* checksum once: a frame its framer delivered decodes the same without a second checksum
  (``decode_frame(b, verified=True)``), and ``decode`` alone still refuses a bad checksum.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from auvgw.drivers import registry
from auvgw.drivers.formats import format_from_table, get_format
from auvgw.drivers.framing import DecodeError, ErrorPolicy, Frame
from auvgw.drivers.spec import MESSAGE_TYPES, to_jsonable
from auvgw.ground.paths import config_file
from auvgw.testing.format_samples import stream_samples

FORMATS = [d.format for d in registry.DEVICES if d.codec is not None]  # CAN-only: their DBC
#: formats whose frames carry no checksum (a corrupted payload byte is still a valid frame):
#: SeaNet packets end in LF, a .V4LOG record is length-prefixed, a GeoSwath ping is judged by
#: its header's self-consistency
NO_CHECKSUM = {"seanet": "SeaNet packets carry no checksum", "v4log": "V4LOG records neither",
               "geoswath": "GeoSwath pings have neither sync nor checksum"}


@pytest.fixture
def sample(
    request: pytest.FixtureRequest, fmt: str, tmp_path: Path
) -> tuple[bytes, list[bytes]]:
    """(stream head, good sample frames) of ``fmt`` (PD0's come from the real recording)."""
    shared = request.getfixturevalue("shared_data") if fmt == "pd0" else None
    head, out = stream_samples(fmt, shared, tmp_path)
    assert len(out) >= 3, f"{fmt}: give at least 3 sample frames in tests/support/format_samples.py"
    return head, out


@pytest.fixture
def frames(sample: tuple[bytes, list[bytes]]) -> list[bytes]:
    return sample[1]


@pytest.fixture
def run(fmt: str, sample: tuple[bytes, list[bytes]]) -> Callable[..., Any]:
    """Frame ``chunks`` after the format's stream head: (frames with offsets counted from the
    end of the head, (frames, bad frames, skipped bytes))."""
    f = get_format(fmt)
    head = sample[0]

    def _run(chunks: list[bytes]) -> tuple[list[Frame], tuple[int, int, int]]:
        framer = f.framer(policy=ErrorPolicy.IGNORE, source="laws")
        out = [fr for c in [head, *chunks] for fr in framer.feed(c)]
        out += framer.finish()
        s = framer.stats
        out = [Frame(fr.data, fr.offset - len(head)) for fr in out]
        return out, (s.frames, s.bad_frames, s.skipped_bytes)

    return _run


def _garbage(n: int, seed: int) -> bytes:
    """``n`` random bytes (seeded): they may hold sync bytes, but no whole valid frame."""
    rng = np.random.default_rng(seed)
    return bytes(rng.integers(0, 256, n, dtype=np.uint8))


@pytest.mark.parametrize("fmt", [d.format for d in registry.DEVICES if d.table])
def test_shipped_table_is_the_default(fmt: str, frames: list[bytes]) -> None:
    """A format with a replaceable table decodes its samples the same through its shipped
    table loaded as a site table (the registry's ``table`` and ``table_codec``)."""
    base = get_format(fmt)
    shipped = dict(MESSAGE_TYPES)  # a site table registers its own class under the type name
    try:
        site = format_from_table(fmt, config_file(registry.device(fmt).table or ""))
        for b in frames:
            got, want = site.decode(b), base.decode(b)
            assert [to_jsonable(m) for m in got] == [to_jsonable(m) for m in want]
            assert site.encode is not None and site.encode(got[0]) == b
    finally:  # the rest of the session rebuilds envelopes with the shipped classes
        MESSAGE_TYPES.clear()
        MESSAGE_TYPES.update(shipped)


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip(fmt: str, frames: list[bytes]) -> None:
    f = get_format(fmt)
    assert f.name == fmt and f.encode is not None
    for b in frames:
        msgs = f.decode(b)
        assert len(msgs) == 1, f"{fmt}: one message per frame"
        assert f.encode(msgs[0]) == b
        again = f.decode(f.encode(msgs[0]))
        assert [to_jsonable(m) for m in again] == [to_jsonable(m) for m in msgs]
        assert type(again[0]) is type(msgs[0])


@pytest.mark.parametrize("fmt", FORMATS)
def test_garbage_between_frames_loses_no_frame(
    fmt: str, frames: list[bytes], run: Callable[..., Any]
) -> None:
    head = frames[0][: max(2, len(frames[0]) // 3)]  # a sync and a start of header, cut short
    junk = [_garbage(5 + 11 * i, i) + (head if i % 2 else b"") for i in range(len(frames))]
    stream = b"".join(j + fr for j, fr in zip(junk, frames, strict=True)) + junk[0]
    out, (n, _, skipped) = run([stream])
    assert [fr.data for fr in out] == frames
    assert n == len(frames)
    assert skipped >= sum(len(j) for j in junk[1:])  # garbage is counted, never a frame
    pos = 0
    for j, fr, got in zip(junk, frames, out, strict=True):
        pos += len(j)
        assert got.offset == pos
        pos += len(fr)


@pytest.mark.parametrize("fmt", FORMATS)
def test_corrupted_frame_is_dropped_and_counted(
    fmt: str, frames: list[bytes], run: Callable[..., Any]
) -> None:
    if fmt in NO_CHECKSUM:
        pytest.skip(NO_CHECKSUM[fmt])
    bad = bytearray(frames[1])
    i = len(bad) // 2
    bad[i] ^= 0x01 if bad[i] not in b"\r\n$:@" else 0x00
    bad[i + 1] ^= 0x02 if bad[i + 1] not in b"\r\n$:@,*" else 0x00
    assert bytes(bad) != frames[1]
    out, (n, n_bad, _) = run([frames[0], bytes(bad), *frames[2:]])
    assert [fr.data for fr in out] == [frames[0], *frames[2:]]
    assert n_bad >= 1 and n == len(frames) - 1


@pytest.mark.parametrize("fmt", FORMATS)
def test_checksum_verified_once(fmt: str, frames: list[bytes], run: Callable[..., Any]) -> None:
    f = get_format(fmt)
    out, _ = run(frames)
    assert [fr.data for fr in out] == frames
    for b in frames:
        want = [to_jsonable(m) for m in f.decode(b)]
        assert [to_jsonable(m) for m in f.decode_frame(b, verified=True)] == want
        assert [to_jsonable(m) for m in f.decode_frame(b)] == want
    if fmt in NO_CHECKSUM:
        return
    # right after the good frame was decoded (a text line's parse is remembered), a corrupted
    # copy is still refused
    corrupted = bytearray(frames[0])
    i = len(corrupted) // 2
    corrupted[i] ^= 0x01 if corrupted[i] not in b"\r\n$:@" else 0x00
    corrupted[i + 1] ^= 0x02 if corrupted[i + 1] not in b"\r\n$:@,*" else 0x00
    f.decode(frames[0])
    with pytest.raises(DecodeError):
        f.decode(bytes(corrupted))
    if f.decode_verified is None:  # (text lines: parsed once by the framer, remembered)
        return
    bad = bytearray(frames[0])
    bad[-1] ^= 0x5A  # the formats that skip it end in their checksum
    with pytest.raises(DecodeError, match="checksum"):
        f.decode(bytes(bad))
    with pytest.raises(DecodeError, match="checksum"):
        f.decode_frame(bytes(bad))
    # trusted to the framer, which refuses it (test_corrupted_frame_is_dropped_and_counted)
    assert len(f.decode_frame(bytes(bad), verified=True)) == 1


@pytest.mark.parametrize("fmt", FORMATS)
def test_resync_at_sync_plus_one(
    fmt: str, frames: list[bytes], run: Callable[..., Any]
) -> None:
    """A frame cut after its header claims the bytes of the next frames: the framer must
    resume the search one byte after the bad frame's sync, never after its claimed length."""
    cut = frames[0][: max(8, len(frames[0]) // 2)]
    out, (n, n_bad, skipped) = run([cut + b"".join(frames[1:])])
    assert [fr.data for fr in out] == frames[1:]
    assert out[0].offset == len(cut)
    assert n == len(frames) - 1 and skipped >= len(cut) - 1 and n_bad >= 1


@pytest.mark.parametrize("fmt", FORMATS)
def test_chunking_invariance(
    fmt: str, frames: list[bytes], run: Callable[..., Any]
) -> None:
    """Any chunking gives the same frames, offsets and counters: byte by byte, 7 bytes, at
    random, and chunks that start at a frame (taken as whole frames first: Framer's
    ``_whole_frames``): one frame each, a frame with the garbage after it, three frames
    with a cut one among them."""
    bad = bytearray(frames[1])
    bad[len(bad) // 2] ^= 0x01 if bad[len(bad) // 2] not in b"\r\n$:@" else 0x00
    parts = [_garbage(13, 7)]
    for i, fr in enumerate([*frames, bytes(bad), frames[0][: len(frames[0]) // 2], *frames]):
        parts += [fr, _garbage(3, i)]
    stream = b"".join(parts)
    whole, stats = run([stream])
    assert len(whole) >= 2 * len(frames)
    rng = np.random.default_rng(1)
    cuts = sorted(rng.choice(np.arange(1, len(stream)), size=min(40, len(stream) - 1),
                             replace=False).tolist())  # fmt: skip
    splits = {
        "bytes": [stream[i : i + 1] for i in range(len(stream))],
        "sevens": [stream[i : i + 7] for i in range(0, len(stream), 7)],
        "random": [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)],
        "frames": parts,
        "frame and garbage": [parts[0], *map(bytes.__add__, parts[1::2], parts[2::2])],
        "three": [b"".join(parts[i : i + 6]) for i in range(1, len(parts), 6)],
    }
    splits["three"][0] = parts[0] + splits["three"][0]
    for name, chunks in splits.items():
        assert b"".join(chunks) == stream
        got, got_stats = run(chunks)
        assert [(fr.data, fr.offset) for fr in got] == [(fr.data, fr.offset) for fr in whole], name
        assert got_stats == stats, name
    # back to back, as a device writes them: several whole frames per chunk, a bad one inside
    tight = [*frames, bytes(bad), *frames]
    stream = b"".join(tight)
    whole, stats = run([stream])
    assert 0 <= len(whole) - 2 * len(frames) <= (fmt in NO_CHECKSUM)  # (the bad one: no sum)
    cut = len(stream) - len(frames[-1]) // 2
    for name, chunks in {
        "pairs": [b"".join(tight[i : i + 2]) for i in range(0, len(tight), 2)],
        "one frame cut": [stream[:cut], stream[cut:]],
        "frames": tight,
    }.items():
        got, got_stats = run(chunks)
        assert [(fr.data, fr.offset) for fr in got] == [(fr.data, fr.offset) for fr in whole], name
        assert got_stats == stats, name
