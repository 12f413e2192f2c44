"""Virtual ports for the emulators: pty pairs paced at a baud rate, and UDP on loopback.

:class:`PtyPort` owns one pseudo-terminal. The emulator writes frames with :meth:`PtyPort.write`
(never blocks); an I/O thread feeds them into the pty master at the configured baud (a pty
ignores baud: ``bits_per_byte`` per byte, 10 for 8N1) scaled by the simulation clock's speed
factor (k x real time sends k x faster; speed 0 sends as fast as the reader takes). The host
opens the slave side, or better the stable symlink :attr:`PtyPort.link`, with pyserial.
Bytes the host writes arrive through ``on_receive`` (called in the I/O thread) or
:meth:`PtyPort.read`.

Pacing (:class:`Pacer`): a write starts on the line when it was made or when the line frees
from the previous one, whichever is later, and byte ``k`` of ``n`` is due ``k / n`` of its line
time after that start. The I/O thread does not write byte by byte: it writes in chunks of at
most :attr:`PtyPort.PACING_QUANTUM_S` real seconds of line time, each chunk as one write when
its last byte is due. So no byte reaches the host before its time on a real line, none later
than one quantum (plus thread scheduling) after it, a frame shorter than the quantum arrives in
one piece (an INS frame at 10 x real time: one write instead of one per byte), the line rate
over any stretch is the baud's, and a thread that wakes late catches up with one bigger write
(due times follow the write times, not the thread's wake-ups). The emulator's
:meth:`PtyPort.write` wakes the I/O thread only when it is idle; a busy thread takes the next
write when the current one is on the line.

pty facts this module is built around (Linux):

* ``tty.setraw`` on the slave: no echo, no line editing, 8-bit clean. The port keeps its own
  slave fd open, so the pty survives a client closing and reopening it.
* pyserial's ``open()`` flushes the input queue: bytes written before a client opens are lost,
  as on a real line with nobody listening.
* An unread pty holds about 16 KiB (4 KiB line discipline + flip buffers), then the master
  blocks. The port never blocks the emulator: the master is non-blocking; when the pty is
  full the current write waits up to ``block_timeout_s`` (real seconds) for the reader, then
  the rest of it is dropped and, while the pty stays full, whole writes are dropped. Every
  dropped byte and write is counted in :attr:`PtyPort.stats` (a UART overrun, in effect).
  The queue between the emulator and the I/O thread is bounded by ``max_queue_bytes`` (a
  device producing more than its baud carries loses writes, counted too).
* Unplug closes the master (and the slave): a client reading gets ``SerialException`` (EOF on
  a hung-up tty), and the ``/dev/pts/N`` path disappears, so does the symlink. Replug creates a
  new pty (it may get another number) and re-points the symlink atomically, so a gateway
  configured with the symlink finds the device again by reopening it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import select
import socket
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from auvgw.ground.closing import Closing
from auvgw.sim_devices.clock import SimClock, thread_cpu_s

__all__ = ["Pacer", "PortStats", "PtyPort", "UdpSender"]

log = logging.getLogger(__name__)


@dataclass
class PortStats:
    """Counters of one port since it was created."""

    writes: int = 0  # write() calls accepted into the queue
    bytes_written: int = 0  # bytes delivered into the pty / socket
    chunks: int = 0  # writes into the pty (or datagrams) that delivered bytes
    bytes_dropped: int = 0  # bytes never delivered (full pty, full queue, unplugged)
    writes_dropped: int = 0  # writes of which nothing was delivered
    writes_cut: int = 0  # writes cut short because the reader stalled mid-write
    bytes_received: int = 0  # host -> device
    unplugs: int = 0
    replugs: int = 0

    @property
    def writes_lost(self) -> int:
        """Writes the reader did not get whole: cut short or dropped."""
        return self.writes_cut + self.writes_dropped

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class Pacer:
    """When each byte of a write may go on the line (host monotonic seconds).

    A write of ``n`` bytes taking ``line_s`` real seconds starts when the line is free (or
    now); byte ``k`` is due at ``start + k * line_s / n``. ``line_s`` 0 means unpaced.
    """

    def __init__(self) -> None:
        self.line_free = 0.0
        self.start = 0.0
        self.per_byte = 0.0
        self.size = 0

    def begin(self, now: float, size: int, line_s: float) -> None:
        """A new write of ``size`` bytes starts (at ``now`` or when the line frees)."""
        self.start = max(now, self.line_free)
        self.size = size
        self.per_byte = line_s / size if size else 0.0
        self.line_free = self.start + line_s

    def due(self, now: float) -> int:
        """How many bytes of the current write may have been sent by ``now``."""
        if self.per_byte <= 0:
            return self.size
        if now < self.start:
            return 0
        return min(self.size, int((now - self.start) / self.per_byte) + 1)

    def when(self, k: int) -> float:
        """Host time at which byte ``k`` is due."""
        return self.start + k * self.per_byte

    def delay(self, seconds: float) -> None:
        """The line was held up (reader stalled): everything later shifts by ``seconds``."""
        self.start += seconds
        self.line_free += seconds


class PtyPort(Closing):
    """A device's serial port: a pty pair, paced writes, host bytes in, unplug and replug.

    ``baud`` None means unpaced (USB adapters); a write can also give its own line time.
    ``clock`` supplies the speed factor (vehicle seconds per real second); without one,
    ``speed`` is used. ``link`` is the stable symlink path (created, re-pointed on replug).
    """

    #: most real seconds of line time written as one chunk (see the module docstring)
    PACING_QUANTUM_S = 0.002

    def __init__(
        self,
        name: str,
        baud: int | None = 115200,
        *,
        clock: SimClock | None = None,
        speed: float = 1.0,
        link: str | Path | None = None,
        bits_per_byte: int = 10,
        on_receive: Callable[[bytes], object] | None = None,
        max_queue_bytes: int = 1 << 20,
        block_timeout_s: float = 0.5,
    ) -> None:
        self.name = name
        self.baud = baud
        self.clock = clock
        self._speed = speed
        self.link = Path(link) if link is not None else None
        self.bits_per_byte = bits_per_byte
        self.on_receive = on_receive
        self.max_queue_bytes = max_queue_bytes
        self.block_timeout_s = block_timeout_s
        self.stats = PortStats()
        self._cv = threading.Condition()
        # (data, line time in vehicle s, host time of the write)
        self._queue: deque[tuple[bytes, float, float]] = deque()
        self._queued = 0
        self._busy = False  # the I/O thread holds a write in progress
        self._idle = False  # the I/O thread may be asleep with nothing to send: wake it
        self._io_cpu_s = 0.0  # CPU of the I/O threads that have ended (unplugs)
        self._io_tid: int | None = None
        self._rx = bytearray()
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
        self._master = -1
        self._slave = -1
        self._path = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self._plug()

    # -- state --------------------------------------------------------------------------------
    @property
    def path(self) -> str:
        """The current ``/dev/pts/N`` (empty while unplugged)."""
        return self._path

    @property
    def device(self) -> str:
        """What a client should open: the symlink if there is one, else the pty path."""
        return str(self.link) if self.link is not None else self._path

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    @property
    def speed(self) -> float:
        return self.clock.speed if self.clock is not None else self._speed

    @property
    def io_cpu_s(self) -> float:
        """CPU seconds the port's I/O thread(s) used so far (pacing, writes, host bytes and
        the ``on_receive`` work done in that thread)."""
        return self._io_cpu_s + thread_cpu_s(self._io_tid)

    def line_time(self, nbytes: int) -> float:
        """Vehicle seconds ``nbytes`` take on the line at the port's baud (0 if unpaced)."""
        return nbytes * self.bits_per_byte / self.baud if self.baud else 0.0

    # -- plug / unplug ------------------------------------------------------------------------
    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._path = os.ttyname(slave)
        if self.link is not None:
            self.link.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.symlink(self._path, tmp)
            os.replace(tmp, self.link)
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._io_loop,
            args=(master, self._stop),
            name=f"pty-{self.name}",
            daemon=True,
        )
        self._thread.start()

    def _unplug(self) -> None:
        self._stop.set()
        self._kick()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._thread = None
        if self.link is not None and self.link.is_symlink():
            with contextlib.suppress(OSError):
                if os.readlink(self.link) == self._path:
                    self.link.unlink()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1
        self._path = ""
        with self._cv:
            dropped = sum(len(d) for d, _, _ in self._queue)
            if dropped:
                self.stats.bytes_dropped += dropped
                self.stats.writes_dropped += len(self._queue)
            self._queue.clear()
            self._queued = 0
            self._busy = False
            self._cv.notify_all()

    def unplug(self) -> None:
        """Pull the cable: the pty and its symlink disappear, a reader gets an error, queued
        and further writes are dropped (counted) until :meth:`replug`."""
        if self._closed or not self.plugged:
            return
        self._unplug()
        self.stats.unplugs += 1

    def replug(self) -> None:
        """Plug back in: a new pty, the symlink re-pointed to it."""
        if self._closed or self.plugged:
            return
        self._plug()
        self.stats.replugs += 1

    def close(self) -> None:
        """Unplug for good and release every resource."""
        if self._closed:
            return
        if self.plugged:
            self._unplug()
        self._closed = True
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)


    # -- device side API ----------------------------------------------------------------------
    def write(
        self, data: bytes, line_time_s: float | None = None, at: float | None = None
    ) -> bool:
        """Queue ``data`` for the host; False (and counted) if it was dropped because the port
        is unplugged or the queue is full. ``line_time_s`` overrides the baud-derived line
        time in vehicle seconds (e.g. a CAN frame's bus time); ``at`` (host
        ``time.monotonic()`` seconds, default now) holds the write back until then, e.g. a
        reply that leaves after a ping (later writes queue behind it)."""
        if not data:
            return True
        line = self.line_time(len(data)) if line_time_s is None else line_time_s
        now = time.monotonic() if at is None else at
        with self._cv:
            if not self.plugged or self._queued + len(data) > self.max_queue_bytes:
                self.stats.bytes_dropped += len(data)
                self.stats.writes_dropped += 1
                return False
            self._queue.append((bytes(data), line, now))
            self._queued += len(data)
            self.stats.writes += 1
            wake, self._idle = self._idle, False
        if wake:
            self._kick()
        return True

    def read(self, size: int = -1, timeout: float | None = 0.0) -> bytes:
        """Host -> device bytes received so far (up to ``size``), waiting up to ``timeout``
        real seconds for at least one (None: forever). Only without ``on_receive``."""
        with self._cv:
            if not self._rx and timeout != 0:
                self._cv.wait_for(lambda: bool(self._rx) or self._closed, timeout)
            n = len(self._rx) if size < 0 else min(size, len(self._rx))
            out = bytes(self._rx[:n])
            del self._rx[:n]
            return out

    def wait_drained(self, timeout: float | None = None) -> bool:
        """Wait (real seconds) until every queued write has been delivered or dropped."""
        with self._cv:
            return self._cv.wait_for(lambda: not self._queue and not self._busy, timeout)

    @property
    def queued_bytes(self) -> int:
        return self._queued

    # -- I/O thread ---------------------------------------------------------------------------
    def _kick(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"\0")

    def _receive(self, master: int) -> None:
        try:
            data = os.read(master, 4096)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return
            raise
        if not data:
            return
        with self._cv:
            self.stats.bytes_received += len(data)
        if self.on_receive is not None:
            try:
                self.on_receive(data)
            except Exception:
                log.exception("%s: on_receive failed", self.name)
        else:
            with self._cv:
                self._rx += data
                self._cv.notify_all()

    def _io_loop(self, master: int, stop: threading.Event) -> None:
        self._io_tid = threading.get_native_id()
        try:
            self._pace(master, stop)
        finally:
            self._io_cpu_s += time.thread_time()
            self._io_tid = None

    def _pace(self, master: int, stop: threading.Event) -> None:
        """The I/O thread: take writes one by one, put each on the line in chunks (module
        docstring), wait for host bytes, the next chunk or a wake-up in between."""
        pacer = Pacer()
        rlist = [master, self._wake_r]
        cur: bytes | None = None
        pos = 0
        chunk = 1  # bytes per chunk of the current write
        blocked_since: float | None = None  # the pty has been full since then
        overflow = False  # a write was dropped and the pty has not taken a byte since
        finished = False  # the previous write is done: tell wait_drained
        while not stop.is_set():
            if cur is None:
                with self._cv:
                    if finished:
                        finished = self._busy = False
                        self._cv.notify_all()
                    if self._queue:
                        cur, line, t_write = self._queue.popleft()
                        self._queued -= len(cur)
                        self._busy = True
                    else:
                        self._idle = True
                if cur is not None:
                    speed = self.speed
                    pacer.begin(t_write, len(cur), 0.0 if speed == 0 else line / speed)
                    pos = 0
                    chunk = len(cur)
                    if pacer.per_byte > 0:
                        chunk = max(1, int(self.PACING_QUANTUM_S / pacer.per_byte))
            now = time.monotonic()
            timeout: float | None = None
            wlist: list[int] = []
            if cur is not None:
                if blocked_since is not None:  # wait for room, bounded
                    timeout = max(0.0, blocked_since + self.block_timeout_s - now)
                    wlist = rlist[:1]
                else:
                    last = min(pos + chunk, len(cur))  # the chunk goes when its last byte is due
                    if pacer.due(now) < last:
                        timeout = max(0.0, pacer.when(last - 1) - now)
            if timeout is not None or cur is None:
                try:
                    readable, writable, _ = select.select(rlist, wlist, [], timeout)
                except (OSError, ValueError):
                    return  # fds closed under us (unplug)
                if stop.is_set():
                    return
                self._idle = False
                if self._wake_r in readable:
                    with contextlib.suppress(OSError):
                        os.read(self._wake_r, 4096)
                if master in readable:
                    self._receive(master)
                if cur is None or blocked_since is None:
                    continue  # re-evaluate: the chunk may be due now
                now = time.monotonic()
                if not writable and now - blocked_since < self.block_timeout_s:
                    continue
            try:
                n = os.write(master, cur[pos : pacer.due(now)])
            except BlockingIOError:
                n = 0
            except OSError:
                return
            if n > 0:
                pos += n
                overflow = False
                if blocked_since is not None:
                    pacer.delay(now - blocked_since)
                blocked_since = None
                self.stats.bytes_written += n  # only this thread counts written bytes
                self.stats.chunks += 1
            elif overflow and pos == 0:  # still full since the last drop: drop it whole
                self._drop(cur, pos)
                cur, finished = None, True
                continue
            elif blocked_since is None:
                blocked_since = now
            elif now - blocked_since >= self.block_timeout_s:
                self._drop(cur, pos)
                cur, blocked_since, overflow, finished = None, None, True, True
                continue
            if pos >= len(cur):
                cur, finished = None, True

    def _drop(self, cur: bytes, pos: int) -> None:
        with self._cv:
            self.stats.bytes_dropped += len(cur) - pos
            if pos == 0:
                self.stats.writes_dropped += 1
            else:
                self.stats.writes_cut += 1


class UdpSender(Closing):
    """Datagrams to ``host:port`` (loopback by default), e.g. the multibeam's XYZ 88 stream.

    Unplugging (the Ethernet cable pulled) drops datagrams, counted, until :meth:`replug`.
    """

    def __init__(self, port: int, host: str = "127.0.0.1", name: str = "udp") -> None:
        self.name = name
        self.address = (host, int(port))
        self.stats = PortStats()
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._plug()

    def _plug(self) -> None:
        family = socket.AF_INET6 if ":" in self.address[0] else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        fcntl.fcntl(self._sock.fileno(), fcntl.F_SETFD, fcntl.FD_CLOEXEC)

    @property
    def plugged(self) -> bool:
        return self._sock is not None

    def send(self, datagram: bytes) -> bool:
        """Send one datagram; False (and counted) if unplugged or the kernel refused it."""
        with self._lock:
            sock = self._sock
            if sock is None:
                self.stats.bytes_dropped += len(datagram)
                self.stats.writes_dropped += 1
                return False
            try:
                n = sock.sendto(datagram, self.address)
            except OSError:
                self.stats.bytes_dropped += len(datagram)
                self.stats.writes_dropped += 1
                return False
            self.stats.writes += 1
            self.stats.chunks += 1
            self.stats.bytes_written += n
            return True

    def unplug(self) -> None:
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None
                self.stats.unplugs += 1

    def replug(self) -> None:
        with self._lock:
            if self._sock is None:
                self._plug()
                self.stats.replugs += 1

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None

