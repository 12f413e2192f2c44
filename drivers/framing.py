"""Framers: byte chunks of any size in, complete verified frames out.

A framer never reads a port. It is fed chunks, searches for the format's sync bytes, asks the
format's :meth:`Framer.check` whether a whole valid frame starts there, and yields it. Any failed
check (bad length, bad checksum, bad terminator) resumes the search at sync+1, never trusting a
corrupted length, so garbage, truncated and corrupted frames lose no valid frame around them.

A candidate waiting for bytes inside which a complete valid frame starts is abandoned at once
(reason ``inner_frame``): a corrupted length field claiming 65535 bytes must not delay every
later frame until they have arrived (with a checksum it could never complete anyway; formats
without one opt in to judging complete candidates the same way). And
:meth:`Framer.expire` drops one that has waited longer than a bound (reason ``stale``; the
gateway calls it with the host clock). Datagram transports frame each datagram on its own:
:meth:`Framer.feed_datagram`.

Counters (:class:`FramerStats`): ``frames`` delivered, ``bad_frames`` (sync candidates that
failed a check, including a frame still incomplete at end of stream), ``skipped_bytes`` (every
byte not delivered inside a valid frame). The error policy decides what a bad frame does besides
counting: raise :class:`FrameError`, log a warning, or nothing.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

from auvgw.ground.errors import DataError

__all__ = [
    "BadFrame",
    "DecodeError",
    "ErrorPolicy",
    "Frame",
    "FrameError",
    "Framer",
    "FramerStats",
    "read_file_frames",
]

log = logging.getLogger(__name__)


class ErrorPolicy(StrEnum):
    """What a framer does with a bad frame after counting it."""

    RAISE = "raise"
    LOG = "log"
    IGNORE = "ignore"


class BadFrame(Exception):
    """Raised by :meth:`Framer.check` when the candidate at the sync is not a valid frame."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class FrameError(DataError):
    """A bad frame under :attr:`ErrorPolicy.RAISE`; ``offset`` is the absolute stream offset."""

    def __init__(self, source: str, offset: int, reason: str) -> None:
        super().__init__(f"bad frame at byte offset {offset}: {reason}", source=source,
                         offset=offset)  # fmt: skip
        self.reason = reason


class DecodeError(DataError):
    """A frame passed its checksum but its content cannot be decoded (names field and offset:
    ``field`` and ``offset`` attributes where the decoder knows them)."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One verified frame: its bytes and the absolute stream offset of its first byte."""

    data: bytes
    offset: int


@dataclass
class FramerStats:
    """Counters of one framer since it was created."""

    frames: int = 0
    bad_frames: int = 0
    skipped_bytes: int = 0
    bytes_in: int = 0
    reasons: Counter[str] = field(default_factory=Counter)

    def as_dict(self) -> dict[str, object]:
        return {
            "frames": self.frames,
            "bad_frames": self.bad_frames,
            "skipped_bytes": self.skipped_bytes,
            "bytes_in": self.bytes_in,
            "reasons": dict(self.reasons),
        }


class Framer:
    """Base framer. Subclasses set :attr:`sync` and implement :meth:`check`.

    ``sync_offset`` is the position of the sync bytes inside a frame (0 for most formats; 4 for
    Kongsberg, whose STX follows a 4-byte length). ``max_frame_size`` bounds how long a candidate
    may hold the search: a declared length above it is a bad frame.
    """

    name: str = "frame"
    sync: bytes = b""
    sync_offset: int = 0
    max_frame_size: int = 65536
    #: also refuse a complete candidate inside which a complete valid frame starts (for formats
    #: without a checksum; with one, a corrupted length cannot complete a valid frame)
    judge_inner_of_complete: bool = False

    def __init__(
        self,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        max_frame_size: int | None = None,
    ) -> None:
        if not self.sync:
            raise TypeError(f"{type(self).__name__} must define sync bytes")
        self.policy = ErrorPolicy(policy)
        self.source = source or self.name
        if max_frame_size is not None:
            self.max_frame_size = max_frame_size
        self.stats = FramerStats()
        self._buf = bytearray()
        self._base = 0  # absolute stream offset of _buf[0]
        self._pending: list[Frame] = []
        self._waiting: int | None = None  # absolute offset of the candidate waiting for bytes
        self._waiting_since: float | None = None  # host time (s) it started waiting
        self._probed = 0  # absolute offset up to which inner syncs of _waiting were judged
        #: abandon a waiting candidate when a complete frame starts inside it (off: wait for
        #: the claimed length as before; the fault injector verifies its faults that way, so
        #: they hold for any chunking)
        self.abandon_on_inner = True
        #: a chunk that starts the buffer is first taken as whole frames back to back
        #: (:meth:`_whole_frames`), the usual read of a device writing frame by frame
        self._whole_ok = self.sync_offset == 0 and not self.judge_inner_of_complete

    # -- to implement -------------------------------------------------------------------------
    def check(self, buf: bytearray, start: int) -> int:
        """Length of the valid frame starting at ``buf[start]``; 0 if more bytes are needed.

        Raise :class:`BadFrame` with a short reason ("bad checksum", "bad length 70000", ...)
        when the bytes there cannot be a valid frame. Never read past ``len(buf)``.
        """
        raise NotImplementedError

    # -- driving ------------------------------------------------------------------------------
    def feed(self, chunk: bytes | bytearray | memoryview, now: float | None = None) -> list[Frame]:
        """Add a chunk; return every frame completed by it, in stream order. ``now`` (host
        seconds, any monotonic clock) dates a frame left waiting for :meth:`expire`."""
        self.stats.bytes_in += len(chunk)
        whole = self._whole_ok and not self._buf and not self._pending
        self._buf += chunk
        if whole:
            self._pending = self._whole_frames()
            if not self._buf:  # nothing left: no candidate waits
                out, self._pending = self._pending, []
                self._waiting_since = None
                return out
        before = self._waiting
        try:
            return self._scan(eof=False)  # (from the frames _whole_frames found)
        finally:
            if self._waiting is None or self._waiting != before:
                self._waiting_since = now if self._waiting is not None else None

    def _whole_frames(self) -> list[Frame]:
        """The valid frames that follow each other from the buffer's first byte, taken out of
        it: what :meth:`_scan` delivers there, without its search (a sync right at each
        frame's end, no inner frame to judge), one frame at a time; it stops at the first
        byte that does not start a complete valid frame, for :meth:`_scan` to judge."""
        buf, sync, out, pos = self._buf, self.sync, [], 0
        n = len(buf)
        while pos < n and buf.startswith(sync, pos):
            try:
                length = self.check(buf, pos)
            except BadFrame:
                break
            if not 0 < length <= self.max_frame_size:
                break
            out.append(Frame(bytes(buf[pos : pos + length]), self._base + pos))
            pos += length
        if pos:
            self.stats.frames += len(out)
            del buf[:pos]
            self._base += pos
        return out

    def feed_datagram(self, datagram: bytes | bytearray | memoryview) -> list[Frame]:
        """One datagram framed on its own: what it leaves incomplete is a bad frame of that
        datagram, never prepended to the next one."""
        self.stats.bytes_in += len(datagram)
        self._buf += datagram
        return self._scan(eof=True)

    def finish(self) -> list[Frame]:
        """End of stream: judge what is left (an incomplete frame there is a bad frame)."""
        return self._scan(eof=True)

    @property
    def waiting_s(self) -> float | None:
        """Host time (as given to :meth:`feed`) since the frame now waiting for bytes started
        waiting; None when none waits."""
        return self._waiting_since

    def expire(self, now: float, max_age_s: float) -> list[Frame]:
        """Drop the frame waiting for bytes when it has waited more than ``max_age_s`` (counted
        as a bad frame, reason ``stale``) and resync one byte after its sync; the frames that
        follows in the buffer come out."""
        since = self._waiting_since
        if self._waiting is None or since is None or now - since <= max_age_s:
            return []
        assert self._waiting == self._base  # a waiting candidate is always at the buffer start
        self._waiting = self._waiting_since = None
        self.stats.skipped_bytes += 1
        del self._buf[:1]
        self._base += 1
        error = self._bad(0, f"stale: partial frame waited {now - since:.1f} s > {max_age_s} s")
        if error is not None:
            raise error
        return self.feed(b"", now)

    def _inner_frame(self, buf: bytearray, start: int, end: int | None = None) -> int | None:
        """Offset (in ``buf``) of a complete valid frame starting inside the candidate at
        ``start`` (``end``: its end when it is complete; None: it waits for bytes), or None;
        -1 when the candidate is complete but a frame starting inside it still waits for bytes
        (the candidate then waits too, so the outcome does not depend on the chunking). While
        the same candidate waits, each inner sync is judged once; those that need more bytes
        themselves are judged again later."""
        sync, so = self.sync, self.sync_offset
        waiting = end is None
        if waiting and self._waiting != self._base + start:
            self._probed = self._base + start + 1
        lo = max(self._probed - self._base, start + 1) if waiting else start + 1
        stop = len(buf) if end is None else end - 1 + so + len(sync)
        q = buf.find(sync, lo + so, stop)
        first_open: int | None = None
        while q >= 0:
            inner = q - so
            try:
                length = self.check(buf, inner)
            except BadFrame:
                length = -1
            if 0 < length <= self.max_frame_size:
                return inner
            if length == 0 and first_open is None:
                first_open = inner
            q = buf.find(sync, q + 1, stop)
        if waiting:
            last = max(start + 1, len(buf) - so - len(sync) + 1)  # a sync cut by the chunk end
            self._probed = self._base + (first_open if first_open is not None else last)
        elif first_open is not None:
            return -1  # complete, but a frame starting inside it is not judged yet: wait
        return None

    def frames(self, chunks: Iterable[bytes]) -> Iterator[Frame]:
        """Frames of a whole stream of chunks, finishing at its end."""
        for chunk in chunks:
            yield from self.feed(chunk)
        yield from self.finish()

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def _bad(self, pos: int, reason: str) -> FrameError | None:
        self.stats.bad_frames += 1
        self.stats.reasons[reason.split(" ")[0].rstrip(":") if reason else "bad"] += 1
        offset = self._base + pos
        if self.policy is ErrorPolicy.RAISE:
            return FrameError(self.source, offset, reason)
        if self.policy is ErrorPolicy.LOG:
            log.warning("%s: bad frame at byte offset %d: %s", self.source, offset, reason)
        return None

    def _scan(self, eof: bool) -> list[Frame]:
        buf = self._buf
        sync, so = self.sync, self.sync_offset
        out, self._pending = self._pending, []
        i = 0
        error: FrameError | None = None
        while True:
            j = buf.find(sync, i + so)
            if j < 0:
                keep = 0 if eof else so + len(sync) - 1
                new_i = max(i, len(buf) - keep)
                self.stats.skipped_bytes += new_i - i
                i = new_i
                break
            start = j - so
            self.stats.skipped_bytes += start - i
            i = start
            try:
                length = self.check(buf, start)
                if length == 0 and eof:
                    raise BadFrame(f"truncated: stream ends {len(buf) - start} bytes into frame")
                if length > self.max_frame_size:
                    raise BadFrame(f"bad length {length} > {self.max_frame_size}")
            except BadFrame as exc:
                self.stats.skipped_bytes += 1
                error = self._bad(start, exc.reason)
                i = start + 1
                if error is not None:
                    break
                continue
            inner = None
            if not self.abandon_on_inner:
                pass
            elif length == 0 and not eof:
                inner = self._inner_frame(buf, start)
            elif length > 0 and self.judge_inner_of_complete:
                inner = self._inner_frame(buf, start, start + length)
            if inner == -1 and not eof:
                length = 0
            elif inner is not None and inner >= 0:
                self.stats.skipped_bytes += 1
                error = self._bad(start, "inner_frame: a complete frame starts inside this one")
                self._waiting = None
                i = start + 1
                if error is not None:
                    break
                continue
            if length == 0:
                self._waiting = self._base + start
                break
            out.append(Frame(bytes(buf[start : start + length]), self._base + start))
            self.stats.frames += 1
            i = start + length
        return self._consumed(i, out, error)

    def _consumed(self, i: int, out: list[Frame], error: FrameError | None) -> list[Frame]:
        """The end of a scan: drop the ``i`` bytes scanned, then raise ``error`` (the frames
        found before it wait for the next call) or return the frames ``out``."""
        if self._waiting is not None and self._waiting != self._base + i:
            self._waiting = None
        del self._buf[:i]
        self._base += i
        if error is not None:
            self._pending = out
            raise error
        return out


def read_file_frames(
    framer: Framer, path: str | Path, chunk_size: int = 1 << 16
) -> Iterator[Frame]:
    """Frames of a whole file, read in chunks (the framer never sees the file itself)."""
    with open(path, "rb") as fh:
        while chunk := fh.read(chunk_size):
            yield from framer.feed(chunk)
    yield from framer.finish()
