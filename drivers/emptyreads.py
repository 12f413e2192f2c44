"""Empty reads from a port that reported readiness: transient until they persist.

A ``select`` that says a tty is readable and an ``os.read`` that then returns no bytes used to
mean "the device went away" in the gateway's readers (pyserial's own wording: "device reports
readiness to read but returned no data (device disconnected or multiple access on port?)").
Under load a pty whose other end is still open does that now and then, and closing and
reopening the port for it refused every command sent meanwhile (issue 30: 13-21 commands a
flight on the actuators' SLCAN port). A pty whose other end closed answers ``EIO`` (an
``OSError``, still fatal at once), and a hung-up tty reads empty on every try.

:class:`EmptyReads` is the readers' policy (:class:`~auvgw.drivers.transports.SerialTransport`,
:class:`~auvgw.drivers.slcanbus.BulkSlcanBus`): count each empty read, retry on the next
readiness, and call the port gone only when its device node has vanished or
:data:`EMPTY_READS_LIMIT` empty reads came in a row (no data between them).
"""

from __future__ import annotations

import os

__all__ = ["EMPTY_READS_LIMIT", "EmptyReads"]

#: empty reads in a row (no byte between them) after which a port is taken as gone
EMPTY_READS_LIMIT = 8


class EmptyReads:
    """The empty-read counters of one open port (``path``: its device node, checked on each
    empty read; None: a URL without one)."""

    def __init__(self, path: str | None, limit: int = EMPTY_READS_LIMIT) -> None:
        if limit < 1:
            raise ValueError(f"limit must be >= 1, got {limit}")
        self.path = path
        self.limit = limit
        self.total = 0  #: empty reads on this port, all told
        self.in_a_row = 0  #: empty reads since the last read that brought bytes

    def empty(self) -> str | None:
        """Count one empty read. Returns why the port is gone (the caller raises), or None:
        transient, wait for the next readiness."""
        self.total += 1
        self.in_a_row += 1
        if self.path is not None and not os.path.exists(self.path):
            return f"readable but empty, and {self.path} no longer exists"
        if self.in_a_row >= self.limit:
            return (f"device reports readiness to read but returned no data {self.in_a_row} "
                    "times in a row (device disconnected or multiple access on port?)")  # fmt: skip
        return None

    def data(self) -> None:
        """A read brought bytes: the run of empty reads is over."""
        self.in_a_row = 0
