"""An emulated USB-CAN adapter speaking SLCAN (Lawicel ASCII) on a pty.

The host opens the adapter's pty with python-can's own interface,
``can.Bus(interface="slcan", channel=adapter.device, sleep_after_open=0)``: python-can then
sends ``C``, ``Sn``, an empty line and ``O`` (each ended by CR) when a bitrate is given, or
just ``O``; the adapter answers like a CANUSB / CAN232: CR for OK, BELL (``\\a``) for an error
or a command not valid in the current state. Once open, frames the emulated devices
:meth:`SlcanAdapter.send` (or :meth:`SlcanAdapter.send_many`, a burst as one write) go to the
host as ``tIIILDD..`` / ``TIIIIIIIILDD..`` lines (plus a 4-hex-digit millisecond timestamp
0-59999 after ``Z1``), paced at the CAN bitrate (nominal frame bits, no stuffing) scaled by the
clock's speed; frames the host sends arrive through
:meth:`SlcanAdapter.recv` or ``on_frame``, and are acknowledged with ``z`` / ``Z``.

Commands: ``Sn`` (n 0-8: 10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k, 1M; closed only),
``sxxyy`` (BTR0/BTR1, closed only), ``O`` open, ``L`` open listen-only, ``C`` close, ``t T r
R`` transmit, ``F`` status flags (open only; cleared when read), ``V`` hardware/software
version, ``v`` firmware version, ``N`` serial number, ``Zn`` timestamps on/off (closed only).
Anything else gets BELL.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import can

from auvgw.ground.closing import Closing
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.ports import PtyPort

__all__ = ["BITRATES", "SlcanAdapter", "SlcanStats", "can_frame_bits", "encode_frame"]

OK = b"\r"
BELL = b"\a"

#: Lawicel ``Sn`` bitrate codes, bit/s
BITRATES = {
    "0": 10_000,
    "1": 20_000,
    "2": 50_000,
    "3": 100_000,
    "4": 125_000,
    "5": 250_000,
    "6": 500_000,
    "7": 800_000,
    "8": 1_000_000,
}

# status flag bits of the F command (SJA1000-style)
FLAG_RX_FIFO_FULL = 0x01
FLAG_DATA_OVERRUN = 0x08


@dataclass
class SlcanStats:
    """Counters of one adapter."""

    frames_to_host: int = 0
    frames_from_host: int = 0
    dropped_closed: int = 0  # device frames while the channel was closed (not on the bus)
    dropped_port: int = 0  # device frames the pty could not take
    commands: int = 0
    errors: int = 0  # BELL answers

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def can_frame_bits(dlc: int, extended: bool, remote: bool = False) -> int:
    """Nominal bits of a classic CAN frame on the bus (SOF to IFS, without bit stuffing)."""
    return (67 if extended else 47) + (0 if remote else 8 * dlc)


def encode_frame(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """The SLCAN line (with CR) of a classic CAN frame, optionally with a timestamp."""
    dlc = msg.dlc
    if dlc > 8 or msg.is_fd:
        raise ValueError("SLCAN carries classic CAN frames of at most 8 bytes")
    if msg.is_extended_id:
        head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id:08X}{dlc:d}"
    else:
        if msg.arbitration_id > 0x7FF:
            raise ValueError(f"standard id {msg.arbitration_id:#x} exceeds 11 bits")
        head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id:03X}{dlc:d}"
    body = "" if msg.is_remote_frame else bytes(msg.data[:dlc]).hex().upper()
    ts = "" if timestamp_ms is None else f"{timestamp_ms % 60000:04X}"
    return (head + body + ts).encode("ascii") + OK


def _parse_frame(line: str) -> can.Message | None:
    """A ``t T r R`` command line (without CR) as a message, or None if malformed."""
    kind = line[0]
    extended = kind in "TR"
    n_id = 8 if extended else 3
    try:
        ident = int(line[1 : 1 + n_id], 16)
        dlc = int(line[1 + n_id], 10)
    except (ValueError, IndexError):
        return None
    if len(line[1 : 1 + n_id]) != n_id or dlc > 8 or ident > (0x1FFFFFFF if extended else 0x7FF):
        return None
    remote = kind in "rR"
    hexdata = line[2 + n_id :]
    if remote:
        if hexdata:
            return None
        data = b""
    else:
        if len(hexdata) != 2 * dlc:
            return None
        try:
            data = bytes.fromhex(hexdata)
        except ValueError:
            return None
    return can.Message(
        arbitration_id=ident,
        is_extended_id=extended,
        is_remote_frame=remote,
        dlc=dlc,
        data=data,
        timestamp=time.time(),
    )


class SlcanAdapter(Closing):
    """A USB-CAN adapter on a pty (see the module docstring). ``clock`` gives the speed factor
    for bus pacing and the vehicle time for ``Z1`` timestamps; ``link`` a stable symlink."""

    def __init__(
        self,
        name: str = "slcan",
        *,
        clock: SimClock | None = None,
        speed: float = 1.0,
        link: str | Path | None = None,
        bitrate: int = 500_000,
        hw_version: str = "10",
        sw_version: str = "13",
        serial_number: str = "AUV1",
        on_frame: Callable[[can.Message], object] | None = None,
        max_rx: int = 10_000,
    ) -> None:
        self.name = name
        self.clock = clock
        self.bitrate = bitrate
        self.btr: str | None = None
        self.hw_version = hw_version
        self.sw_version = sw_version
        self.serial_number = serial_number
        self.on_frame = on_frame
        self.is_open = False
        self.listen_only = False
        self.timestamps = False
        self.stats = SlcanStats()
        self._flags = 0
        self._port_dropped = 0  # the port's dropped bytes last seen (a full pty cuts lines)
        self._lock = threading.Condition()
        self._line = bytearray()
        self._rx: deque[can.Message] = deque(maxlen=max_rx)
        self.port = PtyPort(
            name, None, clock=clock, speed=speed, link=link, on_receive=self._on_bytes
        )

    # -- port passthrough ---------------------------------------------------------------------
    @property
    def device(self) -> str:
        """What the host opens (the symlink if any, else the pty path)."""
        return self.port.device

    @property
    def path(self) -> str:
        return self.port.path

    @property
    def plugged(self) -> bool:
        return self.port.plugged

    def unplug(self) -> None:
        """Pull the USB cable: the pty disappears, the channel closes."""
        with self._lock:
            self.is_open = False
            self._line.clear()
        self.port.unplug()

    def replug(self) -> None:
        """Plug back in: a fresh adapter, channel closed, timestamps off."""
        with self._lock:
            self.timestamps = False
            self._flags = 0
        self.port.replug()

    def reset(self) -> None:
        """The adapter's firmware restarts (a brown-out, a watchdog; or another host closing
        the channel with ``C``): the channel closes, the USB link (the pty) stays. Device
        frames are dropped (``dropped_closed``) until the host opens the channel again."""
        with self._lock:
            self.is_open = False
            self.timestamps = False
            self._flags = 0
            self._line.clear()

    def close(self) -> None:
        self.port.close()


    # -- device side --------------------------------------------------------------------------
    def send(self, msg: can.Message) -> bool:
        """Put a device's frame on the bus towards the host. False (counted) if the channel
        is closed (nobody receives it) or the pty could not take it."""
        return self.send_many((msg,))

    def send_many(self, msgs: Sequence[can.Message]) -> bool:
        """Put a burst of frames on the bus back to back (e.g. one sample's epoch), as one
        write of their lines to the host, paced at the sum of their bus times; with ``Z1``
        each frame is stamped when it ends on the bus. All or nothing: False (each frame
        counted) if the channel is closed or the pty could not take the burst."""
        n = len(msgs)
        if not n:
            return True
        bits = [can_frame_bits(m.dlc, m.is_extended_id, m.is_remote_frame) for m in msgs]
        with self._lock:
            dropped = self.port.stats.bytes_dropped
            if dropped != self._port_dropped:  # the host link lost bytes: the adapter overran
                self._port_dropped = dropped
                self._flags |= FLAG_DATA_OVERRUN
            if not self.is_open:
                self.stats.dropped_closed += n
                return False
            if self.timestamps:
                t = self.clock.now() if self.clock is not None else time.monotonic()
                lines, on_bus = [], 0
                for m, b in zip(msgs, bits, strict=True):
                    on_bus += b
                    lines.append(encode_frame(m, int((t + on_bus / self.bitrate) * 1000)))
            else:
                lines = [encode_frame(m) for m in msgs]
            line_s = sum(bits) / self.bitrate
        ok = self.port.write(b"".join(lines), line_time_s=line_s)
        with self._lock:
            if ok:
                self.stats.frames_to_host += n
            else:
                self.stats.dropped_port += n
                self._flags |= FLAG_DATA_OVERRUN
        return ok

    def recv(self, timeout: float | None = 0.0) -> can.Message | None:
        """Next frame the host transmitted (None after ``timeout`` real seconds)."""
        with self._lock:
            if not self._rx and timeout != 0:
                self._lock.wait_for(lambda: bool(self._rx), timeout)
            return self._rx.popleft() if self._rx else None

    # -- host side: command interpreter -------------------------------------------------------
    def _on_bytes(self, data: bytes) -> None:
        replies = bytearray()
        with self._lock:
            for b in data:
                if b == 0x0D:
                    line = self._line.decode("ascii", "replace")
                    self._line.clear()
                    replies += self._command(line)
                elif b != 0x0A:
                    self._line.append(b)
                    if len(self._line) > 64:  # no valid command is this long
                        self._line.clear()
                        replies += BELL
                        self.stats.errors += 1
        if replies:
            self.port.write(bytes(replies), line_time_s=0.0)

    def _command(self, line: str) -> bytes:
        self.stats.commands += 1
        reply = self._dispatch(line)
        if reply == BELL:
            self.stats.errors += 1
        return reply

    def _dispatch(self, line: str) -> bytes:
        if not line:
            return OK
        c, arg = line[0], line[1:]
        if c == "S":
            if self.is_open or arg not in BITRATES:
                return BELL
            self.bitrate, self.btr = BITRATES[arg], None
            return OK
        if c == "s":
            hexdigits = "0123456789abcdefABCDEF"
            if self.is_open or len(arg) != 4 or not all(ch in hexdigits for ch in arg):
                return BELL
            self.btr = arg.upper()
            return OK
        if c in "OL":
            if self.is_open or arg:
                return BELL
            self.is_open, self.listen_only = True, c == "L"
            return OK
        if c == "C":
            if not self.is_open or arg:
                return BELL
            self.is_open = False
            return OK
        if c in "tTrR":
            if not self.is_open or self.listen_only:
                return BELL
            msg = _parse_frame(line)
            if msg is None:
                return BELL
            self.stats.frames_from_host += 1
            if len(self._rx) == self._rx.maxlen:
                self._flags |= FLAG_RX_FIFO_FULL
            self._rx.append(msg)
            self._lock.notify_all()
            if self.on_frame is not None:
                self.on_frame(msg)
            return (b"Z" if c in "TR" else b"z") + OK
        if c == "F":
            if not self.is_open or arg:
                return BELL
            flags, self._flags = self._flags, 0
            return f"F{flags:02X}".encode() + OK
        if c == "V" and not arg:
            return f"V{self.hw_version}{self.sw_version}".encode() + OK
        if c == "v" and not arg:
            return f"v{self.sw_version.zfill(4)}".encode() + OK
        if c == "N" and not arg:
            return f"N{self.serial_number}".encode() + OK
        if c == "Z":
            if self.is_open or arg not in ("0", "1"):
                return BELL
            self.timestamps = arg == "1"
            return OK
        return BELL
