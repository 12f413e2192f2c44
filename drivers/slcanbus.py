"""python-can's ``slcan`` interface, reading the adapter in bulk and counting its overruns.

python-can 4's :class:`can.interfaces.slcan.slcanBus` reads the adapter's serial port one byte
per ``read(1)`` call (a ``select`` and a ``read`` system call per byte, about 30 per frame):
about 1400 frames/s on this machine, fewer than an HN-100 sends at 10x (8000 frames/s), so
the emulated INS on CAN fell tens of vehicle seconds behind and its adapter dropped frames.
:class:`BulkSlcanBus` keeps everything of python-can's interface (the Lawicel commands on open,
the line parsing in ``_recv_internal``, ``send``, ``shutdown``) and replaces only ``_read``: it
takes what the port has ready in one call and hands out one line at a time from its buffer.

A read of the adapter that is readable but empty is counted
(:attr:`BulkSlcanBus.empty_reads`) and retried; the adapter is taken as gone only when that
persists (:mod:`~auvgw.drivers.emptyreads`). A line that is not a well-formed frame (a wrong
length for its DLC, a bad digit: bytes lost on the host link cut lines and join their ends)
is dropped and counted
(:attr:`BulkSlcanBus.malformed_lines`) instead of reaching python-can's parser, which would
raise on it or pass a frame with missing data bytes.

It also asks the adapter for its status flags (Lawicel ``F``, SJA1000 style) when
:meth:`BulkSlcanBus.poll_status` is called, and counts the flags set in each reply
(:attr:`BulkSlcanBus.flag_counts`): ``data_overrun`` (the adapter lost frames: its host link or
its buffer could not keep up) and ``rx_fifo_full`` among them. Adapters without ``F`` answer
BELL; polling stops after three.

The adapter's device is locked for exclusive use before python-can opens it
(:class:`~auvgw.drivers.portlock.PortLock`, pyserial's ``exclusive=True`` lock): a second
gateway (or any process taking that lock) opening the same adapter would otherwise share its
frames and close its channel (``C``) when it exits. A locked adapter raises
:class:`~auvgw.drivers.portlock.PortLockedError` naming the holder.
"""

from __future__ import annotations

import io
import os
import re
import select
from collections import Counter
from typing import Any

import serial
from can.interfaces.slcan import slcanBus

from auvgw.drivers.emptyreads import EmptyReads
from auvgw.drivers.portlock import PortLock

__all__ = ["SLCAN_FLAGS", "BulkSlcanBus"]

#: Lawicel ``F`` status bits (SJA1000) and the counter each one increments
SLCAN_FLAGS = {
    0x01: "rx_fifo_full",
    0x02: "tx_fifo_full",
    0x04: "error_warning",
    0x08: "data_overrun",
    0x20: "error_passive",
    0x40: "arbitration_lost",
    0x80: "bus_error",
}


class BulkSlcanBus(slcanBus):
    """:class:`can.interfaces.slcan.slcanBus` with a bulk reader and status-flag counters."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self.flag_counts: Counter[str] = Counter()
        #: received lines dropped because they are not a well-formed classic frame
        self.malformed_lines = 0
        #: ``F`` requests not yet answered; None: the adapter has no ``F``
        self._status_pending: int | None = 0
        self._status_supported = False
        self._status_bells = 0
        #: the port's file descriptor to wait on (None: a URL handler without one: polled)
        self._fd: int | None = None
        #: the adapter's exclusive lock (None: a pyserial URL, nothing to lock)
        self._lock: PortLock | None = None
        path = channel.split("@", 1)[0]  # python-can's "port@baud"
        #: readable-but-empty reads of the adapter (:mod:`~auvgw.drivers.emptyreads`)
        self.empty_reads = EmptyReads(path if "://" not in path else None)
        if "://" not in path and os.path.exists(path):
            self._lock = PortLock(path)
        try:
            super().__init__(channel, **kwargs)
        except BaseException:
            self._release_lock()
            raise
        try:
            self._fd = self.serialPortOrig.fileno()
        except (AttributeError, io.UnsupportedOperation, OSError, NotImplementedError):
            self._fd = None

    def _release_lock(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def shutdown(self) -> None:
        """Close the channel and the port (python-can), then drop the adapter's lock."""
        try:
            super().shutdown()
        finally:
            self._release_lock()

    def poll_status(self) -> None:
        """Ask the adapter for its status flags; the reply is counted when it is read."""
        if self._status_pending is None or self._status_pending > 2:
            return  # unsupported, or the adapter is not answering: do not pile requests up
        self._status_pending += 1
        self._write("F")

    def has_line(self) -> bool:
        """A whole line (a frame, a reply) waits in the buffer: :meth:`recv` returns it without
        waiting on the port."""
        return b"\r" in self._buffer or b"\a" in self._buffer

    def _take_line(self) -> str | None:
        buf = self._buffer
        cr, bell = buf.find(b"\r"), buf.find(b"\a")  # CR: OK / end of line, BELL: error
        end = cr if bell < 0 or 0 <= cr < bell else bell
        if end < 0:
            return None
        line = bytes(buf[: end + 1]).decode("ascii", "replace")
        del buf[: end + 1]
        return line

    def _status_reply(self, line: str) -> bool:
        """Consume an answer to :meth:`poll_status`; True if ``line`` was one. ``Fxx`` is
        never a data frame; a BELL is taken as "no ``F`` here" only while no ``F`` was ever
        answered, three times (python-can's own open sequence draws BELLs too)."""
        if len(line) == 4 and line[0] == "F" and line[3] == "\r":
            try:
                flags = int(line[1:3], 16)
            except ValueError:
                return False
            self._status_supported = True
            if self._status_pending:
                self._status_pending -= 1
            for bit, name in SLCAN_FLAGS.items():
                if flags & bit:
                    self.flag_counts[name] += 1
            return True
        if line == "\a" and self._status_pending and not self._status_supported:
            self._status_pending -= 1
            self._status_bells += 1
            if self._status_bells >= 3:
                self._status_pending = None  # this adapter has no F: stop asking
            return True
        return False

    def _read(self, timeout: float | None) -> str | None:
        deadline = serial.Timeout(timeout)
        port = self.serialPortOrig
        while True:
            line = self._take_line()
            if line is not None:
                if self._status_reply(line):
                    continue
                if line[0] in "tTrR" and not _well_formed(line):
                    self.malformed_lines += 1
                    continue
                return line
            # in bulk what is there; else wait for the port to be readable (one wake per burst,
            # not python-can's 1 ms polls of ``read(1)``), or a byte up to the port's timeout
            if self._fd is not None:  # a device: wait, then one read of what is there
                ready, _, _ = select.select([self._fd], [], [], deadline.time_left())
                if not ready:
                    return None
                try:
                    data = os.read(self._fd, 65536)  # (pyserial opened it non-blocking)
                except (BlockingIOError, InterruptedError):
                    continue
                if not data:  # readable but empty: transient unless it persists
                    if (gone := self.empty_reads.empty()) is not None:
                        raise serial.SerialException(gone)
                    continue
                self.empty_reads.data()
                self._buffer.extend(data)
                continue
            waiting = port.in_waiting
            data = port.read(waiting if waiting else 1)
            if data:
                self._buffer.extend(data)
                continue
            if deadline.expired():
                return None


#: a classic frame line: type, 3 or 8 id digits, DLC, hex digits (data, timestamp), CR
_FRAME_LINE = re.compile(r"([tr][0-9A-Fa-f]{3}|[TR][0-9A-Fa-f]{8})([0-8])([0-9A-Fa-f]*)\r")


def _well_formed(line: str) -> bool:
    """A ``t T r R`` line (with its CR): id digits, a DLC 0-8, exactly its data digits, and
    optionally a 4-digit timestamp."""
    m = _FRAME_LINE.fullmatch(line)
    if m is None:
        return False
    n_data = 0 if line[0] in "rR" else 2 * int(m[2])
    return len(m[3]) in (n_data, n_data + 4)
