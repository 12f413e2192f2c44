"""Framers: byte chunks of any size in, complete verified frames out.

A framer never reads a port. It is fed chunks, searches for the format's sync bytes, asks the
format's :meth:`Framer.check` whether a whole valid frame starts there, and yields it. Any failed
check (bad length, bad checksum, bad terminator) resumes the search at sync+1, never trusting a
corrupted length, so garbage, truncated and corrupted frames lose no valid frame around them.

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


class FrameError(ValueError):
    """A bad frame under :attr:`ErrorPolicy.RAISE`; ``offset`` is the absolute stream offset."""

    def __init__(self, source: str, offset: int, reason: str) -> None:
        super().__init__(f"{source}: bad frame at byte offset {offset}: {reason}")
        self.source = source
        self.offset = offset
        self.reason = reason


class DecodeError(ValueError):
    """A frame passed its checksum but its content cannot be decoded (names field and offset)."""


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

    # -- to implement -------------------------------------------------------------------------
    def check(self, buf: bytearray, start: int) -> int:
        """Length of the valid frame starting at ``buf[start]``; 0 if more bytes are needed.

        Raise :class:`BadFrame` with a short reason ("bad checksum", "bad length 70000", ...)
        when the bytes there cannot be a valid frame. Never read past ``len(buf)``.
        """
        raise NotImplementedError

    # -- driving ------------------------------------------------------------------------------
    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame]:
        """Add a chunk; return every frame completed by it, in stream order."""
        self.stats.bytes_in += len(chunk)
        self._buf += chunk
        return self._scan(eof=False)

    def finish(self) -> list[Frame]:
        """End of stream: judge what is left (an incomplete frame there is a bad frame)."""
        return self._scan(eof=True)

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
            if length == 0:
                break
            out.append(Frame(bytes(buf[start : start + length]), self._base + start))
            self.stats.frames += 1
            i = start + length
        del buf[:i]
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
