"""Transports: where bytes come from, behind one small interface, chosen by configuration.

A transport moves bytes and stamps them with the host receive time; it never decodes. Every kind
has the same interface (:class:`Transport`): ``open()``, ``read(timeout_s) -> Chunk | None``,
``write(data)``, ``close()``, ``describe()``, and ``with`` support. Kinds:

* :class:`SerialTransport`: a serial device or any pyserial URL (``/dev/ttyUSB0``,
  ``/dev/pts/7``, ``socket://host:port``, ``loop://``); a chunk is whatever the OS had ready.
* :class:`CanTransport`: a python-can bus (``socketcan``, ``slcan``, ``virtual``,
  ``udp_multicast``, ...); a chunk is one CAN frame with its id.
* :class:`UdpTransport`: a bound UDP socket, optional multicast group; a chunk is one datagram.
* :class:`FileReplayTransport`: a capture file re-read in chunks, as fast as possible or paced.

Times: :attr:`Chunk.t_recv_ns` is ``time.time_ns()`` (UTC wall clock, ns) taken as soon as the
OS reports the data ready, so it is comparable across processes and hosts with synchronised
clocks. :attr:`Chunk.t_device_s` carries the interface's own timestamp where one exists (CAN).

Errors: :class:`TransportOpenError` (cannot open: the message names the port and what to check),
:class:`Disconnected` (alias :data:`TransportClosed`; the device went away while open; the
transport is then closed and ``open()`` may be called again to reconnect), :class:`EndOfStream`
(a finite replay is over). All derive from :class:`TransportError`, whose ``port`` names the device.

:func:`open_transport` builds and opens a transport from a ``auvgw.config.transport`` model or a
plain mapping (e.g. a TOML table).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import io
import ipaddress
import logging
import os
import select
import socket
import struct
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, NoReturn, Self, TypeVar

import can
import serial
from serial.urlhandler import protocol_socket

from auvgw.config.transport import (
    CAN_EXT_MAX,
    CAN_STD_MAX,
    MAX_RECEIVE_BUFFER_BYTES,
    CanTransportConfig,
    FileTransportConfig,
    SerialTransportConfig,
    TransportConfig,
    UdpTransportConfig,
    parse_transport_config,
)
from auvgw.drivers.emptyreads import EmptyReads
from auvgw.drivers.portlock import PortLockedError, lock_holder
from auvgw.drivers.slcanbus import BulkSlcanBus
from auvgw.ground.closing import Closing
from auvgw.ground.errors import TransportError

__all__ = [
    "CanTransport",
    "Chunk",
    "Disconnected",
    "EndOfStream",
    "FileReplayTransport",
    "SerialTransport",
    "Transport",
    "TransportClosed",
    "TransportError",
    "TransportOpenError",
    "UdpTransport",
    "make_transport",
    "open_transport",
    "replay_schedule",
    "udp_receive_buffer",
]

log = logging.getLogger(__name__)

#: largest UDP payload (IPv4: 65535 - 8 UDP - 20 IP header bytes); reads never truncate
UDP_MAX_DATAGRAM = 65535
#: largest payload of one IPv4 UDP datagram (65535 - 8 UDP - 20 IP header bytes)
UDP_MAX_PAYLOAD = 65507
#: how many of a device's largest datagrams its UDP socket holds by default while the reader
#: is starved of CPU (:func:`udp_receive_buffer`)
UDP_BUFFER_DEPTH = 32


@dataclass(frozen=True, slots=True)
class Chunk:
    """Bytes as received, with the host receive time.

    ``t_recv_ns``: ``time.time_ns()`` when the OS reported the data ready (UTC, ns).
    For CAN frames also ``can_id`` (11- or 29-bit arbitration id), ``is_extended_id``, and
    ``t_device_s``: the interface's timestamp in seconds (python-can ``Message.timestamp``: the
    kernel receive time for socketcan, the adapter's clock where it reports one, else the host
    time when the frame was parsed); None where the transport has no such clock.
    """

    data: bytes
    t_recv_ns: int
    can_id: int | None = None
    is_extended_id: bool = False
    t_device_s: float | None = None


class TransportOpenError(TransportError):
    """The transport could not be opened; the message says what to check."""


class Disconnected(TransportError):
    """The device went away while open (unplugged, pty writer closed, peer closed, link down).

    The transport is closed when this is raised; call ``open()`` again (with backoff) to
    reconnect.
    """


#: The same exception under the name the gateway uses.
TransportClosed = Disconnected


class EndOfStream(TransportError):
    """A finite source (a file replayed without ``loop``) has delivered all its bytes."""


def _chain(exc: BaseException) -> Iterator[BaseException]:
    """An exception and its causes (pyserial and python-can wrap the OSError)."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        yield cur
        cur = cur.__cause__ or cur.__context__


def _errnos(exc: BaseException) -> set[int]:
    """Every errno in an exception's chain."""
    return {e.errno for e in _chain(exc) if isinstance(e, OSError) and isinstance(e.errno, int)}


_OPEN_HINTS = {
    errno.ENOENT: "no such device or file: check the cable/adapter is plugged in, the path "
    "(ls /dev/serial/by-id/), or that the emulator owning the pty is running",
    errno.ENODEV: "no such device: check the adapter is plugged in and its driver loaded",
    errno.ENXIO: "device not configured: check the adapter is plugged in",
    errno.EACCES: "permission denied: add the user to the 'dialout' group or fix udev rules",
    errno.EPERM: "permission denied: add the user to the 'dialout' group or fix udev rules",
    errno.EBUSY: "device busy: another process holds it (lsof the path)",
    errno.EAGAIN: "port locked by another process (lsof the path); set exclusive = false to share",
    errno.ECONNREFUSED: "connection refused: nothing listens at that address; check the server",
    errno.EHOSTUNREACH: "host unreachable: check the network and address",
    errno.ETIMEDOUT: "connection timed out: check the network and address",
    errno.EADDRINUSE: "address in use: another process is bound to this port (ss -ulpn)",
    errno.EADDRNOTAVAIL: "address not available: the host is not an address of this machine",
    errno.EISDIR: "is a directory, not a file",
}


def _hint(exc: BaseException, default: str) -> str:
    for code in sorted(_errnos(exc)):
        if code in _OPEN_HINTS:
            return _OPEN_HINTS[code]
    return default


#: the open device a transport holds (a pyserial port, a python-can bus, a socket, a file)
H = TypeVar("H")


class Transport(Closing, ABC, Generic[H]):
    """Bytes in and out of one device, with receive timestamps; no decoding.

    ``read`` returns one :class:`Chunk` or None when nothing arrived within ``timeout_s``
    (seconds; None waits indefinitely). Counters: ``chunks_read``, ``bytes_read``,
    ``bytes_written``. Opening an open transport and closing a closed one do nothing.
    A subclass holds its open device in ``_handle`` (None: closed) and opens it in
    :meth:`_open`.
    """

    kind: ClassVar[str]

    def __init__(self) -> None:
        self.chunks_read = 0
        self.bytes_read = 0
        self.bytes_written = 0
        self._handle: H | None = None

    @property
    @abstractmethod
    def port(self) -> str:
        """The device path, URL, channel, address or file this transport uses."""

    @property
    def is_open(self) -> bool:
        """Whether the transport is open."""
        return self._handle is not None

    def open(self) -> None:
        """Open the device (if closed); raises :class:`TransportOpenError` naming the port."""
        if self._handle is None:
            self._open()

    @abstractmethod
    def _open(self) -> None:
        """Open the device and set ``_handle``; raises :class:`TransportOpenError`."""

    @abstractmethod
    def read(self, timeout_s: float | None) -> Chunk | None:
        """Next chunk, or None if nothing arrived within ``timeout_s`` seconds."""

    def drain(self) -> list[Chunk]:
        """The chunks already received with the last read's, taken without waiting (CAN over
        SLCAN: the rest of a burst read in one go); none by default."""
        return []

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send bytes to the device."""

    def close(self) -> None:
        """Release the device; safe to call more than once and after :class:`Disconnected`."""
        handle, self._handle = self._handle, None
        if handle is not None:
            self._release(handle)

    @abstractmethod
    def _release(self, handle: H) -> None:
        """Close the device :meth:`close` took from ``_handle``."""

    @abstractmethod
    def describe(self) -> str:
        """One line naming the kind, the port and its settings (for logs and status)."""

    def __enter__(self) -> Self:
        self.open()
        return self


    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"<{type(self).__name__} {self.describe()} ({state})>"

    # helpers for subclasses -------------------------------------------------------------------

    def _name(self) -> str:
        return f"{self.kind} {self.port}"

    def _device(self) -> H:
        """The open device; raises :class:`TransportError` if the transport is closed."""
        if self._handle is None:
            raise TransportError(self._name(), "not open; call open() first")
        return self._handle

    def _gone(self, exc: BaseException) -> NoReturn:
        self.close()
        reasons: list[str] = []
        for e in _chain(exc):  # wrapped errors: keep each distinct message once
            text = str(e)
            if text and not any(text in r for r in reasons):
                reasons.append(text)
        raise Disconnected(
            self._name(),
            f"disconnected ({': '.join(reasons)}); transport closed, open() again to reconnect",
        ) from exc

    def losses(self) -> dict[str, int]:
        """Data lost below the framer on this connection, per counter (none known: empty).
        Serial: the UART's and the driver's overruns; CAN over SLCAN: the adapter's overrun
        flags; UDP: datagrams the kernel dropped on a full receive buffer."""
        return {}

    def _chunk(self, chunk: Chunk) -> Chunk:
        self.chunks_read += 1
        self.bytes_read += len(chunk.data)
        return chunk

    @staticmethod
    def _check_timeout(timeout_s: float | None) -> None:
        if timeout_s is not None and timeout_s < 0:
            raise ValueError(f"timeout_s must be >= 0 or None, got {timeout_s}")


class SerialTransport(Transport[serial.SerialBase]):
    """A serial port or pyserial URL; each chunk is the bytes the OS had ready (up to
    ``max_chunk``).

    Device files (``/dev/tty*``, ``/dev/pts/N``) are waited on with ``select`` and read without
    blocking; other URL handlers use pyserial timeouts. A pty whose writer closed, an unplugged
    USB adapter and a closed socket peer all raise :class:`Disconnected`. A device readable but
    empty is read again on its next readiness (counted in :attr:`empty_reads`) and only taken
    as gone when that persists (:mod:`~auvgw.drivers.emptyreads`).

    :attr:`read_interval_s` (s, default 0: every write read at once) reads the port at most
    that often: bytes that arrive sooner after the previous read wait for the rest of the
    interval (and are stamped when read), so writes closer together are read together. While
    reads come closer than 1.5 intervals the reader sleeps out the interval before it waits
    on the port (the bytes are usually there by then: one wake per read); otherwise it waits
    on the port first and sleeps only if the bytes came early (a device writing less often
    costs no wake more than one per write).
    """

    kind = "serial"

    def __init__(self, cfg: SerialTransportConfig) -> None:
        super().__init__()
        self.cfg = cfg
        #: read the port at most this often (s; 0: as bytes come)
        self.read_interval_s = 0.0
        self._last_read = -1e9  # host monotonic s of the last read
        self._busy = False  # reads come closer than 1.5 intervals: sleep before waiting
        self._fd: int | None = None
        self._socket_like = False
        self._posix = False
        self._icount0: tuple[int, ...] | None = None  # driver counters at open (None: no ioctl)
        #: readable-but-empty reads of the device on this connection (transient until they
        #: persist; see :mod:`~auvgw.drivers.emptyreads`)
        self.empty_reads = EmptyReads(None)

    @property
    def port(self) -> str:
        return self.cfg.url

    def _open(self) -> None:
        c = self.cfg
        try:
            ser = serial.serial_for_url(
                c.url,
                baudrate=c.baud,
                bytesize=c.bytesize,
                parity=c.parity,
                stopbits=c.stopbits,
                rtscts=c.rtscts,
                xonxoff=c.xonxoff,
                exclusive=c.exclusive,
                write_timeout=c.write_timeout_s,
                timeout=0,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            hint = _hint(exc, "check the path or URL and the device")
            if _errnos(exc) & {errno.EAGAIN, errno.EWOULDBLOCK} and (who := lock_holder(c.url)):
                hint = f"port locked for exclusive use by {who}; set exclusive = false to share"
            raise TransportOpenError(self._name(), f"cannot open: {hint} ({exc})") from exc
        try:
            self._fd = ser.fileno()
        except (AttributeError, io.UnsupportedOperation, OSError, NotImplementedError):
            self._fd = None
        self._socket_like = isinstance(ser, protocol_socket.Serial)
        #: a local serial device or pty (pyserial's POSIX class, non-blocking fd): read directly
        self._posix = self._fd is not None and type(ser) is serial.Serial
        self._handle = ser
        self._icount0 = self._icount()
        self.empty_reads = EmptyReads(c.url if "://" not in c.url else None)

    def _icount(self) -> tuple[int, ...] | None:
        """The serial driver's (frame, overrun, parity, buffer overrun) error counters
        (``TIOCGICOUNT``; None where the device has none, e.g. a pty)."""
        if self._fd is None:
            return None
        try:
            raw = fcntl.ioctl(self._fd, _TIOCGICOUNT, bytes(_ICOUNT.size))
        except OSError:
            return None
        v = _ICOUNT.unpack(raw)
        return (v[6], v[7], v[8], v[10])

    def losses(self) -> dict[str, int]:
        """The driver's error counters (a real UART) and ``empty_reads`` (readable but empty on
        this connection; no data lost, the port was read again)."""
        empty = {"empty_reads": self.empty_reads.total} if self.empty_reads.total else {}
        now, base = self._icount(), self._icount0
        if now is None or base is None:
            return empty
        names = ("framing_errors", "uart_overruns", "parity_errors", "buffer_overruns")
        return {**{n: a - b for n, a, b in zip(names, now, base, strict=True)}, **empty}

    def _set_timeout(self, ser: serial.SerialBase, timeout_s: float | None) -> None:
        if ser.timeout != timeout_s:
            ser.timeout = timeout_s

    def read(self, timeout_s: float | None) -> Chunk | None:
        self._check_timeout(timeout_s)
        ser = self._device()
        limit = self.cfg.max_chunk
        interval = self.read_interval_s
        busy = interval and (self._busy or self._fd is None)
        if busy and (wait := self._last_read + interval - time.monotonic()) > 0:
            time.sleep(wait)
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], timeout_s)
                if not ready:
                    return None
                early = interval and not busy
                if early and (wait := self._last_read + interval - time.monotonic()) > 0:
                    time.sleep(wait)  # bytes sooner than the interval: read them later
                t_recv = time.time_ns()
                if self._posix:  # what is ready, one syscall (pyserial's read selects again)
                    try:
                        data = os.read(self._fd, limit)
                    except (BlockingIOError, InterruptedError):
                        return None
                    if not data:  # ready but empty: transient unless it persists
                        if (gone := self.empty_reads.empty()) is not None:
                            raise serial.SerialException(gone)
                        return None
                    self.empty_reads.data()
                else:
                    data = ser.read(limit)  # timeout 0: what is ready; b"" ready = gone (raises)
                    if not data:
                        return None
            else:
                self._set_timeout(ser, timeout_s)
                first = ser.read(1)
                if not first:
                    return None
                t_recv = time.time_ns()
                rest = b""
                if limit > 1:
                    if self._socket_like:  # in_waiting is only 0/1 there; timeouts are free
                        self._set_timeout(ser, 0)
                        rest = ser.read(limit - 1)
                    else:
                        n = min(ser.in_waiting, limit - 1)
                        rest = ser.read(n) if n else b""
                data = first + rest
        except (serial.SerialException, OSError) as exc:  # SerialException is an OSError
            self._gone(exc)
        if interval:
            now = time.monotonic()
            self._busy, self._last_read = now - self._last_read < 1.5 * interval, now
        return self._chunk(Chunk(bytes(data), t_recv))

    def write(self, data: bytes) -> None:
        ser = self._device()
        try:
            sent = 0
            if self._posix:  # what the port takes now, one syscall (pyserial's selects first)
                with contextlib.suppress(BlockingIOError, InterruptedError):
                    sent = os.write(ser.fileno(), data)
            if sent < len(data):  # the rest waits for the port, up to write_timeout_s
                ser.write(data[sent:])
        except serial.SerialTimeoutException as exc:
            raise TransportError(
                self._name(),
                f"write of {len(data)} bytes timed out after {self.cfg.write_timeout_s} s; "
                "is the other end reading?",
            ) from exc
        except (serial.SerialException, OSError) as exc:
            self._gone(exc)
        self.bytes_written += len(data)

    def _release(self, handle: serial.SerialBase) -> None:
        self._fd = None
        with contextlib.suppress(serial.SerialException, OSError):  # already gone
            handle.close()

    def describe(self) -> str:
        return self.cfg.describe()


#: Linux ``TIOCGICOUNT`` and ``struct serial_icounter_struct`` (cts dsr rng dcd rx tx frame
#: overrun parity brk buf_overrun reserved[9])
_TIOCGICOUNT = 0x545D
_ICOUNT = struct.Struct("20i")

_CAN_HINTS = {
    "socketcan": "check the interface exists and is up (ip link show {ch}); a vcan needs "
    "'modprobe vcan', which not every kernel has",
    "slcan": "check the adapter's serial path exists (ls /dev/serial/by-id/) and that the "
    "bitrate is one slcan supports",
    "udp_multicast": "needs the msgpack package and a multicast group as channel "
    "(e.g. 239.74.163.2)",
}


class CanTransport(Transport[can.BusABC]):
    """A python-can bus; each chunk is one data frame with its id and the interface timestamp.

    Error and remote frames carry no payload and are skipped (counted in ``frames_skipped``).
    ``write(data)`` sends with the configured ``tx_id``/``tx_extended``; :meth:`send_frame` takes
    the id explicitly.
    """

    kind = "can"

    def __init__(self, cfg: CanTransportConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.frames_skipped = 0

    @property
    def port(self) -> str:
        return self.cfg.port

    def _open(self) -> None:
        c = self.cfg
        kwargs: dict[str, Any] = dict(c.options)
        kwargs["interface"] = c.interface
        if c.channel is not None:
            kwargs["channel"] = c.channel
        if c.bitrate is not None:
            kwargs["bitrate"] = c.bitrate
        if c.fd:
            kwargs["fd"] = True
            if c.data_bitrate is not None:
                kwargs["data_bitrate"] = c.data_bitrate
        if c.filters:
            kwargs["can_filters"] = [f.as_python_can() for f in c.filters]
        kwargs["receive_own_messages"] = c.receive_own_messages
        try:
            if c.interface == "slcan":  # python-can's slcan, read in bulk (drivers/slcanbus.py)
                del kwargs["interface"]
                self._handle = BulkSlcanBus(**kwargs)
            else:
                self._handle = can.Bus(**kwargs)
        except PortLockedError as exc:  # another gateway (or tool) has the adapter
            raise TransportOpenError(
                self._name(), f"cannot open: {exc}; one process per adapter"
            ) from exc
        except (can.CanError, OSError, ValueError, ImportError, serial.SerialException) as exc:
            hint = _CAN_HINTS.get(c.interface)
            if hint is None:
                hint = _hint(exc, "check the interface driver is installed and the channel")
            hint = hint.format(ch=c.channel)
            raise TransportOpenError(self._name(), f"cannot open: {hint} ({exc})") from exc

    def read(self, timeout_s: float | None) -> Chunk | None:
        self._check_timeout(timeout_s)
        bus = self._device()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                msg = bus.recv(left)
            except (can.CanError, OSError, serial.SerialException) as exc:
                self._gone(exc)
            if msg is None:
                return None
            t_recv = time.time_ns()
            if msg.is_error_frame or msg.is_remote_frame:
                self.frames_skipped += 1
                if deadline is not None and time.monotonic() >= deadline:
                    return None
                continue
            return self._chunk(
                Chunk(
                    data=bytes(msg.data),
                    t_recv_ns=t_recv,
                    can_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id,
                    t_device_s=msg.timestamp or None,
                )
            )

    def drain(self) -> list[Chunk]:
        """The frames whose lines the SLCAN adapter delivered with the last one's (other
        buses: none; each read waits on the bus)."""
        bus = self._handle
        out: list[Chunk] = []
        if isinstance(bus, BulkSlcanBus):
            while bus.has_line() and (chunk := self.read(0.0)) is not None:
                out.append(chunk)
        return out

    def losses(self) -> dict[str, int]:
        bus = self._handle
        if not isinstance(bus, BulkSlcanBus):
            return {}
        # the reply is counted when read; a gone adapter shows on the next read
        with contextlib.suppress(can.CanError, OSError, serial.SerialException):
            bus.poll_status()
        out = {f"adapter_{k}": bus.flag_counts[k] for k in ("data_overrun", "rx_fifo_full")}
        out["malformed_lines"] = bus.malformed_lines
        if bus.empty_reads.total:
            out["empty_reads"] = bus.empty_reads.total
        return out

    def send_frame(self, can_id: int, data: bytes, *, is_extended_id: bool) -> None:
        """Send one frame; ``is_extended_id`` is required (29-bit when True, 11-bit when False)."""
        bus = self._device()
        top = CAN_EXT_MAX if is_extended_id else CAN_STD_MAX
        if not 0 <= can_id <= top:
            kind = "extended 29-bit" if is_extended_id else "standard 11-bit"
            raise ValueError(f"can_id 0x{can_id:X} out of range for a {kind} id (max 0x{top:X})")
        limit = 64 if self.cfg.fd else 8
        if len(data) > limit:
            raise ValueError(f"{len(data)} data bytes exceed the frame's {limit}")
        msg = can.Message(
            arbitration_id=can_id, data=data, is_extended_id=is_extended_id, is_fd=self.cfg.fd
        )
        try:
            bus.send(msg, timeout=self.cfg.send_timeout_s)
        except (can.CanError, OSError, serial.SerialException) as exc:
            busy = _errnos(exc) & {errno.ENOBUFS, errno.EAGAIN} or any(
                isinstance(e, serial.SerialTimeoutException) for e in _chain(exc)
            )
            if busy or "buffer full" in str(exc).lower():  # socketcan: "Transmit buffer full"
                raise TransportError(
                    self._name(), f"send of id 0x{can_id:X} timed out: bus busy or no ack ({exc})"
                ) from exc
            self._gone(exc)
        self.bytes_written += len(data)

    def write(self, data: bytes) -> None:
        """Send ``data`` as one frame with the configured ``tx_id`` / ``tx_extended``."""
        c = self.cfg
        if c.tx_id is None or c.tx_extended is None:
            raise TransportError(
                self._name(),
                "write(data) needs tx_id and tx_extended in the config; "
                "or call send_frame(can_id, data, is_extended_id=...)",
            )
        self.send_frame(c.tx_id, data, is_extended_id=c.tx_extended)

    def _release(self, handle: can.BusABC) -> None:
        # an adapter already gone fails here (slcan writes 'C' on shutdown)
        with contextlib.suppress(can.CanError, OSError, serial.SerialException):
            handle.shutdown()

    def describe(self) -> str:
        return self.cfg.describe()


def _net_core(name: str) -> int | None:
    """``/proc/sys/net/core/<name>`` (Linux: ``rmem_default``, ``rmem_max``, bytes), or None."""
    try:
        with open(f"/proc/sys/net/core/{name}") as f:
            return int(f.read())
    except (OSError, ValueError):
        return None


def udp_receive_buffer(largest_frame: int, depth: int = UDP_BUFFER_DEPTH) -> int:
    """``SO_RCVBUF`` (bytes) to ask for a UDP device whose frames are at most ``largest_frame``
    bytes: ``depth`` of its largest datagrams (a frame, at most a UDP payload), never less than
    the kernel's default (``net.core.rmem_default``), within the configuration's bound. The
    gateway asks it for a UDP device without ``receive_buffer_bytes``; the kernel then caps it
    at ``net.core.rmem_max`` (:attr:`UdpTransport.receive_buffer_granted` says)."""
    want = min(largest_frame, UDP_MAX_PAYLOAD) * depth
    return min(max(want, _net_core("rmem_default") or 0, 1024), MAX_RECEIVE_BUFFER_BYTES)


#: Linux SO_RXQ_OVFL: a u32 ancillary count of datagrams dropped on this socket so far
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
_ANC_SPACE = socket.CMSG_SPACE(4)

#: send errors meaning the network itself is gone (interface down, no route)
_LINK_GONE = frozenset({errno.ENETDOWN, errno.ENETUNREACH, errno.EHOSTUNREACH, errno.ENODEV})


class UdpTransport(Transport[socket.socket]):
    """A UDP socket bound to ``host:port``; one datagram per chunk (boundaries preserved).

    With ``multicast_group`` it joins that IPv4 group on ``multicast_interface``. ``write`` sends
    to ``remote_host:remote_port``, or back to the sender of the last datagram read. Datagrams
    from a sender outside ``cfg.sender_filter()`` are dropped unread and counted
    (``rejected_datagrams``, ``rejected_bytes``, ``last_rejected_sender``).
    """

    kind = "udp"

    def __init__(self, cfg: UdpTransportConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.last_sender: tuple[str, int] | None = None
        #: datagrams (and their bytes) dropped because their sender is not allowed
        self.rejected_datagrams = 0
        self.rejected_bytes = 0
        self.last_rejected_sender: str | None = None
        #: datagrams the kernel dropped because the receive buffer was full (SO_RXQ_OVFL; Linux
        #: reports the count with the next datagram it queues after the drops)
        self.kernel_drops = 0
        #: the receive buffer the kernel granted (``SO_RCVBUF`` read back after open, bytes;
        #: Linux doubles what is asked, for its bookkeeping, up to twice ``net.core.rmem_max``)
        self.receive_buffer_granted: int | None = None
        self._allowed: list[ipaddress.IPv4Network | ipaddress.IPv6Network] | None = None

    @property
    def port(self) -> str:
        return f"{self.cfg.host}:{self.cfg.port}"

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port); shows the real port when ``port = 0``."""
        host, port = self._device().getsockname()[:2]
        return host, port

    def _open(self) -> None:
        c = self.cfg
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            reuse = c.reuse_address if c.reuse_address is not None else bool(c.multicast_group)
            if reuse:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            with contextlib.suppress(OSError):  # Linux: drop counts on every datagram read
                sock.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
            if c.receive_buffer_bytes is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, c.receive_buffer_bytes)
            sock.bind((c.host, c.port))
            if c.multicast_group:
                mreq = socket.inet_aton(c.multicast_group) + socket.inet_aton(c.multicast_interface)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
                sock.setsockopt(
                    socket.IPPROTO_IP,
                    socket.IP_MULTICAST_IF,
                    socket.inet_aton(c.multicast_interface),
                )
        except socket.gaierror as exc:
            sock.close()
            raise TransportOpenError(
                self._name(), f"cannot open: cannot resolve host {c.host!r} ({exc})"
            ) from exc
        except OSError as exc:
            sock.close()
            hint = _hint(exc, "check host, port and multicast settings")
            raise TransportOpenError(self._name(), f"cannot open: {hint} ({exc})") from exc
        try:
            self._allowed = _sender_networks(c.sender_filter())
        except OSError as exc:
            sock.close()
            raise TransportOpenError(
                self._name(), f"cannot open: cannot resolve an allowed sender ({exc})"
            ) from exc
        self._handle = sock
        self.receive_buffer_granted = granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        asked = c.receive_buffer_bytes
        if asked is not None and granted < 2 * asked:  # Linux grants 2 x min(asked, rmem_max)
            rmem_max = _net_core("rmem_max")
            log.warning(
                "%s: receive buffer of %d B asked, the kernel granted %d B: capped by "
                "net.core.rmem_max = %s B (raise it: sysctl -w net.core.rmem_max=%d)",
                self._name(), asked, granted, rmem_max, asked,
            )  # fmt: skip
        else:
            log.info("%s: receive buffer %d B (asked %s)", self._name(), granted, asked)

    def read(self, timeout_s: float | None) -> Chunk | None:
        self._check_timeout(timeout_s)
        sock = self._device()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0 and self.rejected_datagrams:
                return None  # only rejected datagrams arrived within timeout_s
            try:
                sock.settimeout(None if left is None else max(left, 1e-6))
                data, anc, _, addr = sock.recvmsg(UDP_MAX_DATAGRAM, _ANC_SPACE)
            except (TimeoutError, BlockingIOError):
                return None
            except OSError as exc:
                self._gone(exc)
            t_recv = time.time_ns()
            for level, kind, value in anc:
                if level == socket.SOL_SOCKET and kind == _SO_RXQ_OVFL and len(value) >= 4:
                    self.kernel_drops = struct.unpack_from("=I", value)[0]
            if self._allowed is None or _sender_allowed(addr[0], self._allowed):
                self.last_sender = (addr[0], addr[1])
                return self._chunk(Chunk(data, t_recv))
            self.rejected_datagrams += 1
            self.rejected_bytes += len(data)
            self.last_rejected_sender = f"{addr[0]}:{addr[1]}"

    def losses(self) -> dict[str, int]:
        return {"kernel_drops": self.kernel_drops}

    def write(self, data: bytes) -> None:
        """Send ``data`` as one datagram."""
        sock = self._device()
        c = self.cfg
        if c.remote_host is not None and c.remote_port is not None:
            target: tuple[str, int] = (c.remote_host, c.remote_port)
        elif self.last_sender is not None:
            target = self.last_sender
        else:
            raise TransportError(
                self._name(),
                "no destination: set remote_host/remote_port, or read a datagram first",
            )
        try:
            sock.settimeout(None)
            sock.sendto(data, target)
        except OSError as exc:
            if _errnos(exc) & _LINK_GONE:
                self._gone(exc)
            raise TransportError(
                self._name(), f"send to {target[0]}:{target[1]} failed ({exc})"
            ) from exc
        self.bytes_written += len(data)

    def _release(self, handle: socket.socket) -> None:
        handle.close()

    def describe(self) -> str:
        out = self.cfg.describe()
        if self._handle is not None and self.cfg.port == 0:
            out += f" (bound port {self.local_address[1]})"
        if self._handle is not None and self.receive_buffer_granted is not None:
            out += f" (receive buffer {self.receive_buffer_granted} B)"
        return out


def _sender_networks(
    senders: list[str] | None,
) -> list[ipaddress.IPv4Network | ipaddress.IPv6Network] | None:
    """Networks of the allowed senders (host names resolved now), or None for any sender."""
    if senders is None:
        return None
    out: list[ipaddress.IPv4Network | ipaddress.IPv6Network] = []
    for s in senders:
        try:
            out.append(ipaddress.ip_network(s, strict=False))
        except ValueError:  # a host name (remote_host): every address it resolves to
            for info in socket.getaddrinfo(s, None, type=socket.SOCK_DGRAM):
                out.append(ipaddress.ip_network(info[4][0]))
    return out


def _sender_allowed(
    host: str, allowed: list[ipaddress.IPv4Network | ipaddress.IPv6Network]
) -> bool:
    addr = ipaddress.ip_address(host)
    return any(addr in net for net in allowed)


def replay_schedule(
    total_bytes: int, chunk_size: int, bytes_per_s: float
) -> list[tuple[int, int, float]]:
    """When a paced replay releases each chunk: ``(offset, length, due_s)`` per chunk.

    A chunk is due when its last byte would have arrived on a line delivering ``bytes_per_s``
    (byte/s), counted in seconds from ``open()``. :class:`FileReplayTransport` uses exactly
    this rule (offsets keep counting across loops).
    """
    out = []
    for off in range(0, total_bytes, chunk_size):
        n = min(chunk_size, total_bytes - off)
        out.append((off, n, (off + n) / bytes_per_s))
    return out


class FileReplayTransport(Transport[io.BufferedReader]):
    """A capture file of raw bytes replayed as chunks; see :class:`FileTransportConfig`.

    Unpaced, each read returns the next ``chunk_size`` bytes at once. Paced, a chunk is held
    until it is due (:func:`replay_schedule`); a consumer that reads late gets the overdue
    chunks back to back. Without ``loop`` the read after the last chunk raises
    :class:`EndOfStream`. Writes are accepted and discarded (counted in ``bytes_discarded``) so
    a host that polls its device (e.g. the MSIS) runs unchanged against a replay.
    """

    kind = "file"

    def __init__(self, cfg: FileTransportConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.bytes_per_s = cfg.bytes_per_s
        self.chunk_size = cfg.chunk_bytes
        self._pending: bytes | None = None
        self._delivered = 0
        self._t0_ns = 0
        self.loops = 0
        self.bytes_discarded = 0

    @property
    def port(self) -> str:
        return str(self.cfg.path)

    def _open(self) -> None:
        path = self.cfg.path
        try:
            f = open(path, "rb")  # noqa: SIM115 - held open across reads, closed by close()
            size = os.fstat(f.fileno()).st_size
        except OSError as exc:
            hint = _hint(exc, "check the path")
            if exc.errno == errno.ENOENT:
                hint = (
                    "no such file: check the path (relative paths start at the working "
                    f"directory {os.getcwd()})"
                )
            raise TransportOpenError(self._name(), f"cannot open: {hint} ({exc})") from exc
        if size == 0 and self.cfg.loop:
            f.close()
            raise TransportOpenError(self._name(), "cannot loop an empty file")
        self._handle = f
        self._pending = None
        self._delivered = 0
        self.loops = 0
        self._t0_ns = time.monotonic_ns()

    def _next_block(self, f: io.BufferedReader) -> bytes:
        data = f.read(self.chunk_size)
        if not data and self.cfg.loop:
            f.seek(0)
            self.loops += 1
            data = f.read(self.chunk_size)
        if not data:
            raise EndOfStream(
                self._name(), f"end of file after {self._delivered} bytes (loop = false)"
            )
        return data

    def read(self, timeout_s: float | None) -> Chunk | None:
        self._check_timeout(timeout_s)
        f = self._device()
        if self._pending is None:
            self._pending = self._next_block(f)
        data = self._pending
        if self.bytes_per_s is not None:
            due_ns = self._t0_ns + round((self._delivered + len(data)) / self.bytes_per_s * 1e9)
            wait_ns = due_ns - time.monotonic_ns()
            if wait_ns > 0:
                if timeout_s is not None and wait_ns > timeout_s * 1e9:
                    time.sleep(timeout_s)
                    return None
                time.sleep(wait_ns / 1e9)
        self._pending = None
        self._delivered += len(data)
        return self._chunk(Chunk(data, time.time_ns()))

    def write(self, data: bytes) -> None:
        """Discard ``data`` (a replay has no device to answer); counted in bytes_discarded."""
        self._device()  # raises if closed
        self.bytes_discarded += len(data)

    def _release(self, handle: io.BufferedReader) -> None:
        handle.close()

    def describe(self) -> str:
        return self.cfg.describe()


_KINDS: dict[type, type[Transport[Any]]] = {
    SerialTransportConfig: SerialTransport,
    CanTransportConfig: CanTransport,
    UdpTransportConfig: UdpTransport,
    FileTransportConfig: FileReplayTransport,
}


def make_transport(cfg: TransportConfig | Mapping[str, Any]) -> Transport[Any]:
    """The transport for a config model or mapping, not yet opened (for reconnect loops)."""
    if isinstance(cfg, Mapping):
        cfg = parse_transport_config(cfg)
    try:
        cls = _KINDS[type(cfg)]
    except KeyError:
        raise TypeError(f"not a transport config: {type(cfg).__name__}") from None
    return cls(cfg)  # type: ignore[call-arg]  # each kind takes its own config


def open_transport(cfg: TransportConfig | Mapping[str, Any]) -> Transport[Any]:
    """Build and open the transport a config describes; raises :class:`TransportOpenError`."""
    t = make_transport(cfg)
    t.open()
    return t
