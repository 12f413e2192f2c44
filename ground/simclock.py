"""The simulation's vehicle clock shared between processes on one host, through a small file.

A lock-step simulation (``auvgw sim --lockstep``) holds its vehicle time back while the
controller under test has not answered, so vehicle time no longer follows the host clock. The
processes that stamp or judge time by it (the gateway's receive stamps, the pilot's
no-odometry timer) read it here instead of scaling the host clock. The file holds the clock's
*anchor*, written only when it changes (the sim's clock is re-anchored each time its hold limit
moves), and every reader computes the current time itself from the host's monotonic clock,
which all processes of one host share::

    vehicle s = min(limit, t_anchor + (time.monotonic() - mono_anchor) * speed)
    stamp ns  = epoch_ns + vehicle s * 1e9       (the gateway's [clock] stamp clock)

Layout (little endian, 64 bytes): ``u64 seq | f64 t_anchor | f64 mono_anchor | f64 speed |
f64 limit | i64 epoch_ns | u64 seq`` then padding. A writer bumps both sequence numbers around
an update (seqlock); a reader retries while they differ or are odd.

An elastic sim (``auvgw sim``'s default pacing, :meth:`auvgw.sim_devices.clock.SimClock.elastic`)
holds its vehicle time on its devices' dispatch: with one process per device
(``--processes``) each device process reports, through a :class:`DispatchBoard` beside the
clock file, the vehicle time of its earliest tick not dispatched yet, and the process that
writes the clock file holds at the least of them plus the lag; the device processes read their
vehicle time from the clock file.
"""

from __future__ import annotations

import math
import mmap
import os
import struct
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

__all__ = ["ClockFileReader", "ClockFileWriter", "ClockState", "DispatchBoard"]

_BODY = struct.Struct("<ddddq")
_SEQ = struct.Struct("<Q")
_SIZE = 64
_END = _SEQ.size + _BODY.size


class ClockState(tuple[float, float, float, float, int]):
    """``(t_anchor, mono_anchor, speed, limit, epoch_ns)``: vehicle s at host monotonic s,
    vehicle s per host s, the hold limit (vehicle s, inf: none), vehicle time 0 on the stamp
    clock (ns since the Unix epoch)."""

    __slots__ = ()

    def vehicle_s(self, mono: float) -> float:
        """Vehicle time (s) at host monotonic time ``mono`` (s); before the anchor's host time,
        the anchor's vehicle time (the clock may have been held then: no extrapolation back)."""
        t_anchor, mono_anchor, speed, limit, _ = self
        return min(limit, t_anchor + max(0.0, mono - mono_anchor) * speed)


def _read_seqlocked(m: mmap.mmap, at: int, body: struct.Struct) -> tuple[Any, ...] | None:
    """``u64 seq | body | u64 seq`` at offset ``at``: ``(seq, *body)`` once both numbers agree
    and are even (seq 0: never written); None when a writer stayed in the middle of an update
    for the whole try (about 0.1 s: a writer process the host does not schedule), and the
    caller keeps the last value it read."""
    end = at + _SEQ.size + body.size
    for i in range(200):
        (a,) = _SEQ.unpack_from(m, at)
        values = body.unpack_from(m, at + _SEQ.size)
        (b,) = _SEQ.unpack_from(m, end)
        (c,) = _SEQ.unpack_from(m, at)
        if a == b == c and a % 2 == 0:
            return (a, *values)
        if i >= 10:
            time.sleep(0.0005)
    return None


class ClockFileWriter:
    """Creates the clock file at ``path`` (a new file put in place whole: a reader of an older
    one keeps its own) and publishes anchors into it."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        tmp = self.path.with_name(self.path.name + ".new")
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.ftruncate(fd, _SIZE)
            self._map = mmap.mmap(fd, _SIZE)
        finally:
            os.close(fd)
        os.replace(tmp, self.path)
        self._seq = 0

    def publish(self, t_anchor: float, mono_anchor: float, speed: float, limit: float,
                epoch_ns: int) -> None:  # fmt: skip
        """Write a new anchor (see the module docstring for the fields and units)."""
        self._seq += 1  # odd: an update is under way
        _SEQ.pack_into(self._map, 0, self._seq)
        _BODY.pack_into(self._map, _SEQ.size, t_anchor, mono_anchor, speed, limit, epoch_ns)
        self._seq += 1
        _SEQ.pack_into(self._map, _END, self._seq)
        _SEQ.pack_into(self._map, 0, self._seq)

    def close(self) -> None:
        self._map.close()


class ClockFileReader:
    """Reads the clock file at ``path``; a file not written yet reads as None (it may appear
    later: the reader opens it on first use)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._map: mmap.mmap | None = None
        self._last: ClockState | None = None

    def _open(self) -> mmap.mmap | None:
        if self._map is None:
            try:
                fd = os.open(self.path, os.O_RDONLY)
            except FileNotFoundError:
                return None
            try:
                if os.fstat(fd).st_size < _SIZE:
                    return None
                self._map = mmap.mmap(fd, _SIZE, access=mmap.ACCESS_READ)
            finally:
                os.close(fd)
        return self._map

    def state(self) -> ClockState | None:
        """The current anchor, or None before the first one was written."""
        m = self._open()
        if m is None:
            return None
        got = _read_seqlocked(m, 0, _BODY)
        if got is None:  # the writer is stuck in an update: the anchor before it
            if self._last is None:
                raise RuntimeError(f"{self.path}: the clock file kept changing while read")
            return self._last
        seq, *body = got
        if seq:
            self._last = ClockState(body)
        return self._last

    def vehicle_s(self) -> float | None:
        """Vehicle time now (s), None before the clock was written."""
        st = self.state()
        return None if st is None else st.vehicle_s(time.monotonic())

    def stamp_ns(self, at_unix_ns: int | None = None) -> int | None:
        """Vehicle time on the stamp clock (``epoch_ns`` + vehicle ns) now, or at the host
        instant ``at_unix_ns`` (``time.time_ns()``, e.g. a receive time); None before the
        clock was written."""
        st = self.state()
        if st is None:
            return None
        mono = time.monotonic()
        if at_unix_ns is not None:
            mono -= (time.time_ns() - at_unix_ns) * 1e-9
        v = st.vehicle_s(mono)
        return st[4] + round(v * 1e9) if math.isfinite(v) else None

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None


_SLOT_BODY = struct.Struct("<d")
_SLOT = 2 * _SEQ.size + _SLOT_BODY.size


class DispatchBoard:
    """One slot per device process of an elastic sim (the file ``path``, ``u64 seq | f64 t |
    u64 seq`` per slot, seqlocked like the clock file, one writer per slot): the vehicle time
    (s) of the process's earliest tick not dispatched yet. ``slots``: create the file with that
    many slots, each at ``start`` (nothing dispatched); without it, open an existing one."""

    def __init__(self, path: str | Path, slots: int | None = None, start: float = 0.0) -> None:
        self.path = Path(path)
        if slots is not None:
            if slots < 1:
                raise ValueError(f"a dispatch board needs at least one slot, got {slots}")
            tmp = self.path.with_name(self.path.name + ".new")
            with tmp.open("wb") as f:
                f.write(b"".join(_SEQ.pack(2) + _SLOT_BODY.pack(start) + _SEQ.pack(2)
                                 for _ in range(slots)))  # fmt: skip
            os.replace(tmp, self.path)
        fd = os.open(self.path, os.O_RDWR)
        try:
            size = os.fstat(fd).st_size
            if size < _SLOT or size % _SLOT:
                raise ValueError(f"{self.path}: not a dispatch board ({size} bytes)")
            self._map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self.slots = size // _SLOT
        self._seqs = [2] * self.slots
        self._last = [start if slots is not None else -math.inf] * self.slots

    def _at(self, slot: int) -> int:
        if not 0 <= slot < self.slots:
            raise IndexError(f"{self.path}: no slot {slot} (it has {self.slots})")
        return slot * _SLOT

    def report(self, slot: int, t: float) -> None:
        """This slot's process has dispatched every tick before vehicle time ``t`` (s)."""
        at = self._at(slot)
        seq = self._seqs[slot] = self._seqs[slot] + 1  # odd: an update is under way
        _SEQ.pack_into(self._map, at, seq)
        _SLOT_BODY.pack_into(self._map, at + _SEQ.size, t)
        seq = self._seqs[slot] = seq + 1
        _SEQ.pack_into(self._map, at + _SEQ.size + _SLOT_BODY.size, seq)
        _SEQ.pack_into(self._map, at, seq)

    def pending(self, slot: int) -> float:
        """The vehicle time (s) reported in ``slot`` (while its writer is stuck in an update,
        the value before: it only grows, so an older one holds the clock back, never on)."""
        got = _read_seqlocked(self._map, self._at(slot), _SLOT_BODY)
        if got is not None:
            self._last[slot] = float(got[1])
        return self._last[slot]

    def least(self, slots: Iterable[int]) -> float:
        """The earliest pending vehicle time (s) over ``slots`` (inf: none)."""
        return min((self.pending(i) for i in slots), default=math.inf)

    def close(self) -> None:
        self._map.close()
