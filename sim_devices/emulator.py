"""Common base of the emulated devices: encoder + schedule + fault injector + port.

One :class:`Emulator` is one device of a scenario (``kind`` is its key in the scenario's
``devices`` section). It is built from a :class:`SimContext` (world, ground truth, the one
simulation clock, where port symlinks go, seeded generators) and the device's
:class:`~auvgw.config.scenario.DeviceSettings`. :meth:`Emulator.start` schedules
:meth:`Emulator.tick` on the clock at ``rate_hz`` (vehicle time, exact ``t0 + n / rate``);
``tick(t)`` samples the truth (:meth:`Emulator.truth`), adds noise (scaled by the VB noise-burst
multiplier, :meth:`Emulator.sigma_scale`), encodes with the project's codecs and sends on its
channels.

A :class:`Channel` is one wire of a device with its own :class:`FaultInjector`:

* :class:`SerialChannel`: a :class:`PtyPort` (paced at the baud); every byte-level fault
  (garbage, corrupted checksums, truncated frames, dropouts, stalls, unplug) with exact counts
  against the device's framer.
* :class:`CanChannel`: a :class:`SlcanAdapter` (USB-CAN adapter on a pty). CAN frames carry a
  controller-checked CRC, so a corrupted frame never reaches a host: on CAN only dropouts,
  stalls and unplug apply (to a whole sample's burst of frames); byte faults are masked.
* :class:`UdpChannel`: a :class:`UdpSender`; byte faults as on serial (a held-back bad
  datagram goes out in front of the next good one, in the same datagram).

Device-level fault state (:attr:`Emulator.faults`): noise bursts, clock jumps
(:meth:`Emulator.device_time`) and bottom-lock-loss windows. :meth:`Emulator.set_faults`
switches every knob at run time. Unplug windows are applied at each tick (the port disappears
at the first tick inside a window and comes back at the first tick after it).

Writing an emulator (the DVL, ``DvlEmulator(ctx, settings)``, plugs in like this; the runner
constructs every emulator as ``cls(ctx, settings)``)::

    class DvlEmulator(Emulator):
        kind = "dvl"                # its key in the scenario's devices section
        nominal_rate_hz = 5.0

        def __init__(self, ctx, settings=None, name=None):
            super().__init__(ctx, settings, name)
            # a pty paced at the baud, symlink <port_dir>/dvl, faults counted against the
            # framer; on_receive=... takes host commands
            self.serial = self.add_serial("pd0", Pd0Framer, self.option("baud", 115200))

        def tick(self, t):          # at vehicle time t = n / rate_hz
            s = self.truth(t)       # ground truth (TruthSample)
            k = self.sigma_scale()  # noise-burst multiplier
            lost = self.faults.bottom_lock_lost(t)
            self.serial.send(encode_pd0(..., time=self.device_time(t)), t)

A device that sends each sample on a serial line and on CAN (the INS, the magnetometer)
subclasses :class:`SerialCanEmulator` and implements ``measure``, ``encode_serial`` and
``encode_can``.

A device whose sample is numpy-heavy sets ``prefetch`` and implements ``prepare(t)`` (compute
the encoded sample, may run ahead in a worker thread) and ``send(prepared, t)`` instead of
``tick`` (the multibeam does).

A host-polled device (the MSIS head: a byte state machine with ``power_up(t)``,
``feed(host_bytes, t) -> bytes`` and ``tick(t) -> bytes``) is wrapped by :class:`PolledEmulator`.
"""

from __future__ import annotations

import logging
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import can
import numpy as np

from auvgw.config.scenario import DeviceSettings, FaultSettings, Scenario
from auvgw.drivers import registry
from auvgw.drivers.can_codec import CanFrame
from auvgw.drivers.framing import ErrorPolicy, Framer
from auvgw.sim_devices.clock import SimClock, Task, thread_cpu_s
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.faults import FaultInjector
from auvgw.sim_devices.ports import PtyPort, UdpSender
from auvgw.sim_devices.slcan import SlcanAdapter
from auvgw.sim_devices.vehicle import Truth, TruthSample
from auvgw.sim_devices.world import World

__all__ = [
    "DEFAULT_EPOCH",
    "CanChannel",
    "Channel",
    "Emulator",
    "Endpoint",
    "PolledEmulator",
    "PolledHead",
    "SerialCanEmulator",
    "SerialChannel",
    "SimContext",
    "UdpChannel",
    "device_option",
    "free_udp_port",
]

log = logging.getLogger(__name__)

#: UTC POSIX time of vehicle time 0 unless a run names another (2024-06-01 08:00:00 UTC)
DEFAULT_EPOCH = 1717228800.0

# -- the context every emulator is built from --------------------------------------------------


@dataclass
class SimContext:
    """What every emulator of one run shares: the scenario, its world and ground truth, the one
    simulation clock, the folder of stable port symlinks, the UTC time of vehicle time 0
    (``epoch``, s) and the host UDP streams go to. ``truth.at(t)`` samples the ground truth
    at any vehicle time, precomputed or (closed loop) integrated online (``sampler`` is the
    same object, kept for callers of that name)."""

    scenario: Scenario
    world: World
    truth: Truth | ClosedLoopTruth
    clock: SimClock
    port_dir: Path
    epoch: float = DEFAULT_EPOCH
    udp_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        self.port_dir = Path(self.port_dir)
        self.port_dir.mkdir(parents=True, exist_ok=True)
        self.truth.at(0.0)  # builds the sampling table now, not in the first tick of a run

    @property
    def sampler(self) -> Truth | ClosedLoopTruth:
        """The ground truth (:meth:`Truth.at` at any vehicle time)."""
        return self.truth

    def rng(self, name: str) -> np.random.Generator:
        """A generator seeded by the scenario seed and ``name`` (reproducible per device)."""
        return np.random.default_rng([self.scenario.seed, zlib.crc32(name.encode())])

    def link(self, name: str) -> Path:
        """The stable symlink path of port ``name``."""
        return self.port_dir / name


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port nobody is bound to on ``host`` right now (the kernel's pick)."""
    import socket

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


# -- endpoints (what a host opens) -------------------------------------------------------------


@dataclass(frozen=True)
class Endpoint:
    """One port a host opens: the gateway device ``name``, its wire ``format``, the transport
    ``kind`` (serial, can, udp), what to open (``target``: the stable symlink, or host:port
    for UDP), the current pty (``path``), and the gateway's transport and device tables."""

    name: str
    format: str
    kind: str
    target: str
    path: str
    transport: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)

    def gateway_device(self) -> dict[str, Any]:
        """This endpoint as a ``[devices.<name>]`` table of the gateway configuration."""
        return {"format": self.format, **self.extra, "transport": dict(self.transport)}


# -- channels ----------------------------------------------------------------------------------


class Channel:
    """One wire of a device with its own fault injector (see the module docstring)."""

    kind: ClassVar[str] = ""
    #: fault knobs that do not apply on this kind of wire (zeroed in its injector)
    masked: ClassVar[dict[str, float]] = {}

    def __init__(self, name: str, fmt: str, injector: FaultInjector) -> None:
        self.name = name
        self.format = fmt
        self.injector = injector
        self.injector.settings = self._mask(injector.settings)

    def _mask(self, settings: FaultSettings) -> FaultSettings:
        return settings.model_copy(update=self.masked) if self.masked else settings

    @property
    def port(self) -> Any:
        raise NotImplementedError

    def set_faults(self, settings: FaultSettings) -> None:
        """Replace this wire's fault knobs (masked knobs stay off)."""
        self.injector.settings = self._mask(settings)

    def sync(self, t: float) -> bool:
        """Unplug or replug the port to match the unplug windows at ``t``; True if plugged."""
        return self.injector.sync_port(self.port, t)

    def flush(self) -> None:
        """Send the held-back bad frames (end of stream)."""

    def endpoint(self) -> Endpoint:
        raise NotImplementedError

    def port_stats(self) -> dict[str, int]:
        return self.port.stats.as_dict()

    @property
    def io_cpu_s(self) -> float:
        """CPU seconds of this wire's own I/O thread (0 for a wire without one)."""
        port = getattr(self.port, "port", self.port)  # an SLCAN adapter's pty
        return float(getattr(port, "io_cpu_s", 0.0))

    def stats(self) -> dict[str, Any]:
        """Fault counts and port counters of this wire."""
        return {"faults": self.injector.counts.as_dict(), "port": self.port_stats()}

    def close(self) -> None:
        self.port.close()


class _ByteChannel(Channel):
    """A wire of bytes (serial, UDP): :meth:`send_raw` puts bytes on it as they are."""

    def send_raw(self, data: bytes) -> bool:
        """Bytes on the wire without fault injection; True if any went out."""
        raise NotImplementedError

    def flush(self) -> None:
        """Send the held-back bad frames (end of stream)."""
        self.send_raw(self.injector.flush())


class SerialChannel(_ByteChannel):
    """A serial line on a pty: ``send(frame, t)`` puts one encoded frame through the injector
    and on the line. ``extra`` adds keys to the gateway device table (``table``, ``msis``)."""

    kind = "serial"

    def __init__(
        self,
        name: str,
        fmt: str,
        port: PtyPort,
        injector: FaultInjector,
        extra: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(name, fmt, injector)
        self._port = port
        self.extra = dict(extra or {})

    @property
    def port(self) -> PtyPort:
        return self._port

    def send(self, frame: bytes, t: float, at: float | None = None) -> bool:
        """One frame at vehicle time ``t`` (on the line from host time ``at``, default now;
        see :meth:`PtyPort.write`); True if any byte went to the port."""
        data = self.injector.process(frame, t)
        return bool(data) and self._port.write(data, at=at)

    def send_raw(self, data: bytes) -> bool:
        """Bytes on the line without fault injection (replies already processed)."""
        return bool(data) and self._port.write(data)

    def endpoint(self) -> Endpoint:
        target = self._port.device
        transport = {"kind": "serial", "url": target, "baud": int(self._port.baud or 115200)}
        return Endpoint(
            self.name, self.format, "serial", target, self._port.path, transport, self.extra
        )


class CanChannel(Channel):
    """A CAN bus seen through an emulated USB-CAN adapter speaking SLCAN on a pty.

    ``send(frames, t)`` puts one sample's burst of frames on the bus; the injector decides for
    the whole burst (dropout, stall, unplug). Gateway transport: python-can ``slcan`` on the
    adapter's symlink at ``bitrate`` with ``sleep_after_open = 0``.
    """

    kind = "can"
    masked: ClassVar[dict[str, float]] = {"garbage_p": 0.0, "corrupt_p": 0.0, "truncate_p": 0.0}

    def __init__(self, name: str, adapter: SlcanAdapter, injector: FaultInjector, dbc: str) -> None:
        super().__init__(name, "can", injector)
        self.adapter = adapter
        self.dbc = dbc
        self.frames_sent = 0

    @property
    def port(self) -> SlcanAdapter:
        return self.adapter

    def send(self, frames: Sequence[CanFrame], t: float) -> bool:
        """One burst at vehicle time ``t``; True if the adapter took every frame.

        The burst goes to the adapter's pty as one write (:meth:`SlcanAdapter.send_many`):
        dropped (counted in the adapter's stats) while the host has not opened the channel
        or the pty cannot take it."""
        if not self.injector.process(b"\x00", t):  # one token per burst: the window/dropout draw
            return False
        msgs = [
            can.Message(
                arbitration_id=f.arbitration_id,
                data=f.data,
                dlc=len(f.data),
                is_extended_id=f.is_extended_id,
            )
            for f in frames
        ]
        if not self.adapter.send_many(msgs):
            return False
        self.frames_sent += len(frames)
        return True

    def endpoint(self) -> Endpoint:
        target = self.adapter.device
        transport = {
            "kind": "can",
            "interface": "slcan",
            "channel": target,
            "bitrate": int(self.adapter.bitrate),
            "options": {"sleep_after_open": 0},
        }
        return Endpoint(
            self.name, "can", "can", target, self.adapter.path, transport, {"dbc": self.dbc}
        )

    def port_stats(self) -> dict[str, int]:
        return {**self.adapter.port.stats.as_dict(), **self.adapter.stats.as_dict()}


class UdpChannel(_ByteChannel):
    """A UDP stream to ``host:port``: ``send(datagram, t)`` through the injector."""

    kind = "udp"

    def __init__(
        self,
        name: str,
        fmt: str,
        sender: UdpSender,
        injector: FaultInjector,
        extra: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(name, fmt, injector)
        self.sender = sender
        self.extra = dict(extra or {})

    @property
    def port(self) -> UdpSender:
        return self.sender

    def send(self, datagram: bytes, t: float) -> bool:
        return self.send_raw(self.injector.process(datagram, t))

    def send_raw(self, data: bytes) -> bool:
        return bool(data) and self.sender.send(data)

    def endpoint(self) -> Endpoint:
        host, port = self.sender.address
        transport = {"kind": "udp", "host": host, "port": int(port)}
        return Endpoint(self.name, self.format, "udp", f"{host}:{port}", "", transport, self.extra)


# -- the emulator base -------------------------------------------------------------------------


def device_option(settings: DeviceSettings, kind: str, key: str, default: Any) -> Any:
    """``settings.options[key]`` converted to the type of ``default`` (as is if ``default`` is
    None); a ValueError names ``devices.<kind>.options.<key>`` and what was expected."""
    if key not in settings.options:
        return default
    v = settings.options[key]
    if default is None:
        return v
    want = type(default)
    if want is bool and not isinstance(v, bool):
        raise ValueError(f"devices.{kind}.options.{key}: expected true/false, got {v!r}")
    if want in (int, float) and isinstance(v, bool | str):
        raise ValueError(f"devices.{kind}.options.{key}: expected {want.__name__}, got {v!r}")
    try:
        return want(v)
    except (TypeError, ValueError):
        raise ValueError(
            f"devices.{kind}.options.{key}: expected {want.__name__}, got {v!r}"
        ) from None


class Emulator:
    """One emulated device (see the module docstring). Subclasses set ``kind`` and
    ``nominal_rate_hz``, add their channels in ``__init__`` and implement :meth:`tick`."""

    kind: ClassVar[str] = ""
    nominal_rate_hz: ClassVar[float] = 1.0
    #: samples computed ahead of their tick in a worker thread (0: in the tick). For
    #: numpy-heavy devices (the multibeam): numpy releases the GIL, so that work overlaps the
    #: other devices' ticks on a second core. Such a device implements :meth:`prepare` and
    #: :meth:`send` (run-time fault changes reach samples prepared after them).
    prefetch: ClassVar[int] = 0

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        self.ctx = ctx
        if settings is None:
            settings = getattr(ctx.scenario.devices, self.kind, None) or DeviceSettings()
        self.settings = settings
        self.name = name or self.kind
        self.rate_hz = float(settings.rate_hz or self.nominal_rate_hz)
        self.rng = ctx.rng(self.name)
        #: device-level fault state: noise bursts, clock jumps, bottom-lock loss
        self.faults = FaultInjector(settings.faults, ctx.rng(self.name + "/noise"), name=self.name)
        self.channels: list[Channel] = []
        self.ticks = 0
        self.errors = 0
        #: CPU seconds spent producing samples (ticks, delayed replies), in whatever thread
        self.cpu_s = 0.0
        self._task: Task | None = None
        self._prefetcher: _Prefetcher | None = None
        self._lock = threading.RLock()

    # -- settings helpers -----------------------------------------------------------------------
    @property
    def clock(self) -> SimClock:
        return self.ctx.clock

    @property
    def period(self) -> float:
        """Seconds between ticks (vehicle time)."""
        return 1.0 / self.rate_hz

    def option(self, key: str, default: Any) -> Any:
        """``settings.options[key]`` converted to the type of ``default``; a clear error names
        the device and the option."""
        return device_option(self.settings, self.kind, key, default)

    def noise(self, key: str, default: float) -> float:
        """Noise figure ``settings.noise[key]`` (SI or ``*_deg``), else ``default``."""
        return float(self.settings.noise.get(key, default))

    def check_noise_keys(self, known: Iterable[str]) -> None:
        """A ValueError naming ``devices.<kind>.noise.<key>`` and the known keys when the
        scenario gives a noise figure this device does not have (a typo would otherwise be
        ignored silently)."""
        names = set(known)
        unknown = sorted(set(self.settings.noise) - names)
        if unknown:
            raise ValueError(
                f"devices.{self.kind}.noise.{unknown[0]}: unknown noise figure; this device "
                f"knows {', '.join(sorted(names))}"
            )

    # -- channels -------------------------------------------------------------------------------
    def injector(
        self, channel: str, framer: type[Framer] | Callable[[], Framer] | None
    ) -> FaultInjector:
        """A fault injector for one wire of this device (its own seeded generator)."""
        return FaultInjector(
            self.settings.faults, self.ctx.rng(f"{channel}/faults"), framer=framer, name=channel
        )

    def add_serial(
        self,
        fmt: str,
        framer: type[Framer] | Callable[[], Framer] | None,
        baud: int,
        name: str | None = None,
        on_receive: Callable[[bytes], object] | None = None,
        extra: dict[str, Any] | None = None,
    ) -> SerialChannel:
        """A pty paced at ``baud`` with a stable symlink ``<port_dir>/<name>``."""
        name = name or self.name
        port = PtyPort(
            name, baud, clock=self.clock, link=self.ctx.link(name), on_receive=on_receive
        )
        ch = SerialChannel(name, fmt, port, self.injector(name, framer), extra)
        self.channels.append(ch)
        return ch

    def add_can(self, dbc: str, bitrate: int, name: str | None = None) -> CanChannel:
        """An emulated SLCAN adapter at ``bitrate`` (bit/s) for frames of ``dbc``."""
        name = name or f"{self.name}_can"
        adapter = SlcanAdapter(name, clock=self.clock, link=self.ctx.link(name), bitrate=bitrate)
        ch = CanChannel(name, adapter, self.injector(name, None), dbc)
        self.channels.append(ch)
        return ch

    def add_udp(
        self,
        fmt: str,
        framer: type[Framer] | Callable[[], Framer] | None,
        port: int,
        host: str | None = None,
        name: str | None = None,
        extra: dict[str, Any] | None = None,
    ) -> UdpChannel:
        """Datagrams to ``host:port`` (``port`` 0: a free port picked now); ``extra``: keys of
        the gateway device table (the GeoSwath's ``geoswath`` model)."""
        name = name or self.name
        host = host or self.ctx.udp_host
        port = port or free_udp_port(host)
        sender = UdpSender(port, host, name=name)
        ch = UdpChannel(name, fmt, sender, self.injector(name, framer), extra)
        self.channels.append(ch)
        return ch

    def endpoints(self) -> list[Endpoint]:
        """What a host opens for this device, one per channel."""
        return [ch.endpoint() for ch in self.channels]

    # -- truth and noise ------------------------------------------------------------------------
    def truth(self, t: float) -> TruthSample:
        """Ground truth at vehicle time ``t``."""
        return self.ctx.truth.at(t)

    def sigma_scale(self) -> float:
        """Noise sigma multiplier of this sample: ``sqrt(n)`` in a noise burst, else 1."""
        return self.faults.sigma_multiplier()

    def device_time(self, t: float) -> float:
        """The device's own clock at vehicle time ``t`` (with its clock jumps), s."""
        return self.faults.device_time(t)

    # -- faults at run time ---------------------------------------------------------------------
    def set_faults(self, settings: FaultSettings | None = None, **changes: Any) -> FaultSettings:
        """Replace the fault knobs (``settings``) and/or change some (``changes``, validated
        like the scenario file) on the device and every wire; returns the new settings."""
        base = settings if settings is not None else self.faults.settings
        new = FaultSettings.model_validate({**base.model_dump(), **changes})
        with self._lock:
            self.faults.settings = new
            for ch in self.channels:
                ch.set_faults(new)
        return new

    # -- schedule -------------------------------------------------------------------------------
    def start(self, t0: float | None = None) -> None:
        """Tick at ``rate_hz`` on the clock from vehicle time ``t0`` (default: now)."""
        if self._task is not None and not self._task.cancelled:
            return
        t0 = self.clock.now() if t0 is None else float(t0)
        # a closed-loop truth is only known up to now: nothing is computed ahead of its tick
        if self.prefetch > 0 and not isinstance(self.ctx.truth, ClosedLoopTruth):
            self._prefetcher = _Prefetcher(self.prepare, t0, self.period, self.prefetch, self.name)
        self._task = self.clock.every(self.period, self._tick, start=t0, name=self.name)

    def stop(self) -> None:
        """No more ticks (a tick already running finishes)."""
        if self._task is not None:
            self._task.cancel()
        if self._prefetcher is not None:
            self._prefetcher.stop()

    def _tick(self, t: float) -> None:
        c0 = time.thread_time()
        with self._lock:
            try:
                for ch in self.channels:
                    ch.sync(t)
                # runs unplugged too: counters advance, the injector drops
                if self._prefetcher is not None:
                    self.send(self._prefetcher.take(t), t)
                else:
                    self.tick(t)
            except Exception:
                self.errors += 1
                if self.errors == 1:
                    log.exception("%s: tick at t=%.3f failed", self.name, t)
            self.ticks += 1
            self.cpu_s += time.thread_time() - c0

    def tick(self, t: float) -> None:
        """Produce and send one sample at vehicle time ``t``: ``send(prepare(t), t)``
        unless overridden."""
        self.send(self.prepare(t), t)

    def prepare(self, t: float) -> Any:
        """Compute the sample of vehicle time ``t`` (truth, noise, encoding); may run in a
        worker thread ahead of time (``prefetch``)."""
        raise NotImplementedError

    def send(self, prepared: Any, t: float) -> None:
        """Put a prepared sample on the wire(s) at vehicle time ``t``."""
        raise NotImplementedError

    def flush(self) -> None:
        """Send every wire's held-back bad frames (end of a run)."""
        with self._lock:
            for ch in self.channels:
                ch.flush()

    def close(self) -> None:
        """Stop and release every port."""
        self.stop()
        with self._lock:
            for ch in self.channels:
                ch.close()

    def stats(self) -> dict[str, Any]:
        """Ticks, errors, noise bursts, each wire's fault and port counters, and CPU seconds:
        producing samples (``samples``: ticks in the clock thread, delayed replies), the
        prefetch worker (``worker``) and the ports' I/O threads (``io``, with the host
        requests a polled device answers there)."""
        c = self.faults.counts
        worker = self._prefetcher.cpu_s if self._prefetcher is not None else 0.0
        return {
            "device": self.kind,
            "rate_hz": self.rate_hz,
            "ticks": self.ticks,
            "errors": self.errors,
            "noise_samples": c.noise_samples,
            "noise_bursts": c.noise_bursts,
            "cpu_s": {
                "samples": self.cpu_s,
                "worker": worker,
                "io": sum(ch.io_cpu_s for ch in self.channels),
            },
            "channels": {ch.name: ch.stats() for ch in self.channels},
        }


class SerialCanEmulator(Emulator):
    """A device that sends each sample on a serial line (a table codec) and on CAN (a DBC):
    the HN-100 INS, the MS3A magnetometer.

    Options: ``serial`` and ``can`` (true: open that wire), ``baud`` (:attr:`default_baud`),
    ``can_bitrate`` (500000), ``table`` (a site table replacing the shipped one of the serial
    codec, TOML; the gateway configuration then names it too). A subclass names its device
    (``class InsEmulator(SerialCanEmulator, device="hn100")``: its registry line gives
    :attr:`kind`, :attr:`serial_format` and :attr:`dbc`), sets :attr:`default_baud`, calls
    :meth:`add_wires` with its codecs, and implements ``measure(t)`` and the two encoders; each
    tick sends one sample on both wires.
    """

    serial_format: ClassVar[str] = ""
    default_baud: ClassVar[int] = 115200
    dbc: ClassVar[str] = ""

    def __init_subclass__(cls, device: str | None = None, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if device is None:
            return
        d = registry.device(device)
        if d.emulator is None or d.dbc is None:
            raise TypeError(f"{cls.__name__}: format {device!r} registers no emulator and DBC")
        cls.kind, cls.serial_format, cls.dbc = d.emulator.key, d.format, d.dbc

    def add_wires(self, codec_type: Any, default_codec: Any, can_codec: Callable[[], Any]) -> None:
        """Set :attr:`codec` (``codec_type.from_toml(table)`` or ``default_codec``) and open
        the wires the options ask for: :attr:`serial` and :attr:`can` (with
        :attr:`can_codec` from ``can_codec()``), None when off."""
        table = self.option("table", "")
        self.codec = codec_type.from_toml(table) if table else default_codec
        self.serial: SerialChannel | None = None
        self.can: CanChannel | None = None
        self.can_codec: Any = None
        if self.option("serial", True):
            extra = {"table": str(table)} if table else None
            baud = self.option("baud", self.default_baud)
            self.serial = self.add_serial(self.serial_format, self.codec.framer, baud, extra=extra)
        if self.option("can", True):
            self.can_codec = can_codec()
            self.can = self.add_can(self.dbc, self.option("can_bitrate", 500_000))

    def measure(self, t: float) -> Any:
        """The device's output at vehicle time ``t`` (truth plus noise)."""
        raise NotImplementedError

    def encode_serial(self, m: Any) -> bytes:
        """The serial frame of one sample."""
        raise NotImplementedError

    def encode_can(self, m: Any) -> list[CanFrame]:
        """The CAN frames of one sample."""
        raise NotImplementedError

    def tick(self, t: float) -> None:
        m = self.measure(t)
        if self.serial is not None:
            self.serial.send(self.encode_serial(m), t)
        if self.can is not None:
            self.can.send(self.encode_can(m), t)


class _Prefetcher:
    """Computes ``fn(t0 + k period)`` for k = 0, 1, ... in a worker thread, at most ``depth``
    ahead of :meth:`take` (the clock's tick times, bit for bit the same sums)."""

    def __init__(
        self, fn: Callable[[float], Any], t0: float, period: float, depth: int, name: str
    ) -> None:
        self._fn = fn
        self._t0 = t0
        self._period = period
        self._depth = depth
        self._queue: deque[tuple[float, Any, BaseException | None]] = deque()
        self._cv = threading.Condition()
        self._stopped = False
        self._tid: int | None = None
        self._cpu = 0.0
        self._thread = threading.Thread(target=self._run, name=f"prefetch-{name}", daemon=True)
        self._thread.start()

    @property
    def cpu_s(self) -> float:
        """CPU seconds of the worker thread so far."""
        return self._cpu + thread_cpu_s(self._tid)

    def _run(self) -> None:
        self._tid = threading.get_native_id()
        try:
            self._work()
        finally:
            self._cpu = time.thread_time()
            self._tid = None

    def _work(self) -> None:
        k = 0
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._stopped or len(self._queue) < self._depth)
                if self._stopped:
                    return
            t = self._t0 + k * self._period
            try:
                item, err = self._fn(t), None
            except Exception as exc:
                item, err = None, exc
            with self._cv:
                self._queue.append((t, item, err))
                self._cv.notify_all()
            k += 1

    def take(self, t: float) -> Any:
        """The sample of time ``t`` (waits for the worker; raises what ``fn`` raised)."""
        with self._cv:
            while True:
                while self._queue and self._queue[0][0] < t - 1e-9:
                    self._queue.popleft()
                if self._queue or self._stopped:
                    break
                self._cv.wait()
            if not self._queue:
                raise RuntimeError("prefetch stopped")
            tq, item, err = self._queue.popleft()
            self._cv.notify_all()
        if abs(tq - t) > 1e-9:
            raise RuntimeError(f"prefetch out of step: prepared t={tq}, tick t={t}")
        if err is not None:
            raise err
        return item

    def stop(self) -> None:
        with self._cv:
            self._stopped = True
            self._cv.notify_all()


# -- host-polled devices -----------------------------------------------------------------------


class PolledHead(Protocol):
    """A device as a byte-level state machine (the MSIS head): it speaks only when fed."""

    def power_up(self, t: float) -> Any: ...

    def feed(self, host_bytes: bytes, t: float) -> bytes: ...

    def tick(self, t: float) -> bytes: ...


@dataclass
class _PollStats:
    host_bytes: int = 0
    replies: int = 0
    reply_frames: int = 0


class PolledEmulator(Emulator):
    """Wraps a host-polled ``head`` on a serial channel: host bytes (pty I/O thread) go to
    ``head.feed(data, now)``, its reply frames go back through the fault injector; every tick
    (``rate_hz``, vehicle time) ``head.tick(t)`` may speak on its own (e.g. mtAlive).
    ``framer`` splits replies into frames, so each frame meets the injector alone.
    ``reply_delay()`` (vehicle s, e.g. the ping's duration) holds a reply back: in real time
    (``delay / speed``: the port starts writing it then, no extra thread), or on the clock when
    it runs as fast as possible;
    ``before_feed(t)`` is called with the vehicle time just before each ``feed``.
    A head with an ``attach(emulator)`` method is given this emulator once, when wrapped: the
    MSIS head takes its noise figures (``devices.msis.noise``), a generator and the per-ping
    noise-burst multiplier (:meth:`Emulator.sigma_scale`, counted in the fault counters)."""

    def __init__(
        self,
        ctx: SimContext,
        settings: DeviceSettings | None,
        head: PolledHead,
        *,
        kind: str,
        fmt: str,
        framer: type[Framer],
        baud: int,
        rate_hz: float = 10.0,
        name: str | None = None,
        extra: dict[str, Any] | None = None,
        reply_delay: Callable[[], float] | None = None,
    ) -> None:
        self.kind = kind  # type: ignore[misc]  # per instance: one wrapper class, many devices
        self.nominal_rate_hz = rate_hz  # type: ignore[misc]
        super().__init__(ctx, settings, name)
        self.head = head
        attach = getattr(head, "attach", None)
        if callable(attach):  # the head takes its noise figures and burst multiplier from us
            attach(self)
        self.reply_delay = reply_delay
        self.before_feed: Callable[[float], object] | None = None
        self.poll = _PollStats()
        self._splitter = framer(policy=ErrorPolicy.IGNORE)
        self.serial = self.add_serial(fmt, framer, baud, on_receive=self._on_host, extra=extra)
        self._powered = False

    def _send_reply(self, data: bytes, t: float, at: float | None = None) -> None:
        if not data:
            return
        self.poll.replies += 1
        for fr in self._splitter.feed(bytes(data)):
            self.poll.reply_frames += 1
            self.serial.send(fr.data, t, at)

    def _on_host(self, data: bytes) -> None:
        with self._lock:
            self.poll.host_bytes += len(data)
            t = self.clock.now()
            try:
                if self.before_feed is not None:
                    self.before_feed(t)
                reply = bytes(self.head.feed(bytes(data), t) or b"")
                delay = self.reply_delay() if reply and self.reply_delay is not None else 0.0
            except Exception:
                self.errors += 1
                log.exception("%s: head.feed failed", self.name)
                return
            if not reply:
                return
            if delay <= 0:
                self._send_reply(reply, t)
            elif self.clock.speed > 0:
                # real time, not the scheduler: a host waits in real time, and a scheduler
                # running behind must not hold the head's answers back
                self._send_reply(reply, t + delay, time.monotonic() + delay / self.clock.speed)
            else:
                self.clock.at(t + delay, lambda tr: self._send_later(reply, tr), name=self.name)

    def _send_later(self, reply: bytes, t: float) -> None:
        c0 = time.thread_time()
        with self._lock:
            self._send_reply(reply, t)
            self.cpu_s += time.thread_time() - c0

    def start(self, t0: float | None = None) -> None:
        t = self.clock.now() if t0 is None else t0
        with self._lock:
            if not self._powered:
                self._powered = True
                out = self.head.power_up(t)
                if isinstance(out, bytes | bytearray):
                    self._send_reply(bytes(out), t)
        super().start(t0)

    def tick(self, t: float) -> None:
        self._send_reply(bytes(self.head.tick(t) or b""), t)

    def stats(self) -> dict[str, Any]:
        """The base counters plus the host traffic (``poll``) and the head's own counters and
        ping duration (s), where the head offers them."""
        out = {**super().stats(), "poll": asdict(self.poll)}
        head_stats = getattr(self.head, "stats", None)
        if head_stats is not None and hasattr(head_stats, "as_dict"):
            out["head"] = head_stats.as_dict()
        ping = getattr(self.head, "ping_duration_s", None)
        if callable(ping):
            out["ping_duration_s"] = float(ping())
        return out
