"""The gateway daemon: one reader thread per device, raw then decoded on Zenoh, health, liveliness.

Per device: open the transport (retrying with exponential backoff while it is missing), feed every
chunk to the format's framer, publish each verified frame raw (bytes + attachment: receive time,
sequence, stream offset), then its decoded messages as envelopes (auvgw.envelope; PD0 and HN-100
envelopes read straight from the frame's bytes, the frame decoded after both puts). A device
that disappears is reported (status ``connected: false``, its liveliness token withdrawn) and
picked up again when it returns, while the other devices keep flowing. A finite source (a file
replayed without ``loop``) ends its device cleanly (status ``ended: true``).
Receive times are the host clock, or with a ``[clock]`` section (``time_scale`` != 1, an
emulated vehicle faster than real time) the vehicle-paced ``epoch + (t_recv - epoch) *
time_scale``, on envelopes and raw attachments alike; health keeps the host clock.
Sensor data uses ``CongestionControl.DROP`` so a subscriber that stops reading never stalls the
gateway. Behaviour and payloads are documented in docs/gateway.md and docs/bus.md.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import logging
import os
import socket
import statistics
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from auvgw.bus import (
    SCHEMA_VERSION,
    Keys,
    Undeclarable,
    encode_envelope,
    envelope_encoding,
    json_encoding,
    open_session,
    pack_raw_attachment,
    raw_encoding,
)
from auvgw.config.gateway import DeviceConfig, GatewayConfig
from auvgw.decoding import DecodedItem, DeviceDecoder, kind_of, make_decoders, message_type
from auvgw.drivers.framing import Frame
from auvgw.drivers.transports import (
    Disconnected,
    EndOfStream,
    SerialTransport,
    Transport,
    TransportError,
    make_transport,
    udp_receive_buffer,
)
from auvgw.envelope import decode_envelope, pack_envelope
from auvgw.ground.errors import UserError
from auvgw.health import Backoff, DeviceHealth, device_time_s
from auvgw.hostdrivers import HostDriver, make_host_driver
from auvgw.notify import Notifier

if TYPE_CHECKING:
    from auvgw.drivers.actuators import CommandGate

log = logging.getLogger(__name__)

__all__ = [
    "CLAIM_TIMEOUT_S",
    "READ_TIMEOUT_S",
    "Gateway",
    "GatewayRunning",
    "probe_running_gateway",
]

#: how long a starting gateway asks the bus for another gateway of its vehicle, and then for
#: that one's status (s; a lone peer's liveliness get returns at once)
CLAIM_TIMEOUT_S = 2.0

#: how long a reader waits for data before checking for stop and calling the host driver (s)
READ_TIMEOUT_S = 0.05
#: how often a reader refreshes its transport's loss counters (s; an SLCAN adapter is asked)
LOSS_POLL_S = 0.5
#: frames whose envelopes went out straight from their bytes are decoded (health, listeners)
#: once the line has been quiet this long, or the oldest of them is this old (s)
SETTLE_S = 0.002
#: while bytes keep coming, a device's framing counters reach its health at most this often (s;
#: and once the line is quiet)
FRAMING_PERIOD_S = 0.05
_DROP = zenoh.CongestionControl.DROP
_HOST = socket.gethostname()
#: reads that brought frames, kept per device to learn its period (the median interval)
PERIOD_READS = 33
#: a silent device reopened again and again without a frame waits this many times longer at most
MAX_SILENT_BACKOFF = 16


class GatewayRunning(UserError):
    """Another gateway already serves this vehicle on the bus (its ``auv/<v>/alive/gateway``
    token is there); the message names it (host, pid, Zenoh id). ``auvgw run`` exits 2."""


def _describe_holder(vehicle: str, status: dict[str, Any] | None) -> str:
    """The one line of :class:`GatewayRunning`, from the running gateway's status (or None)."""
    head = f"vehicle {vehicle!r} already has a gateway on this bus"
    if status is None:
        return (
            f"{head} (its liveliness token auv/{vehicle}/alive/gateway is there; it did not "
            "answer a status query, so its host and pid are unknown); one gateway per vehicle: "
            "stop it first"
        )
    zid = (status.get("bus") or {}).get("zid", "?")
    return (
        f"{head}: pid {status.get('pid', '?')} on host {status.get('host', '?')} (Zenoh id "
        f"{zid}, up {status.get('uptime_s', '?')} s); one gateway per vehicle: stop it first"
    )


def _running_gateway(
    session: zenoh.Session, keys: Keys, timeout_s: float
) -> tuple[bool, dict[str, Any] | None]:
    """(whether ``auv/<v>/alive/gateway`` is on the bus, that gateway's status if it answers)."""
    key = keys.alive("gateway")
    if not any(r.ok is not None for r in session.liveliness().get(key, timeout=timeout_s)):
        return False, None
    for reply in session.get(keys.status("gateway"), timeout=timeout_s):
        if reply.ok is not None:
            with contextlib.suppress(ValueError):
                return True, json.loads(reply.ok.payload.to_bytes())
            break
    return True, None


def _loopback(endpoint: str) -> str:
    """A listen endpoint as this host reaches it (``0.0.0.0`` / ``[::]`` -> loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def probe_running_gateway(
    cfg: GatewayConfig, timeout_s: float = CLAIM_TIMEOUT_S
) -> GatewayRunning | None:
    """When this gateway's session cannot open (a listen endpoint already taken, as by a
    gateway started twice from one file), ask whoever listens there, as a client, whether it
    is a gateway of this vehicle: the :class:`GatewayRunning` to raise, else None."""
    if not cfg.bus.listen:
        return None
    probe = cfg.bus.model_copy(
        update={"mode": "client", "connect": [_loopback(e) for e in cfg.bus.listen], "listen": []}
    )
    try:
        session = open_session(probe)
    except zenoh.ZError:
        return None
    try:
        found, status = _running_gateway(session, Keys(cfg.vehicle), timeout_s)
    except zenoh.ZError:
        return None
    finally:
        session.close()
    return GatewayRunning(_describe_holder(cfg.vehicle, status)) if found else None


@dataclass
class _Device:
    name: str
    cfg: DeviceConfig
    health: DeviceHealth
    decoder: DeviceDecoder
    thread: threading.Thread | None = None
    pubs: dict[str, zenoh.Publisher] = field(default_factory=dict)
    #: message type -> (its publisher, its envelope encoding)
    routes: dict[str, tuple[zenoh.Publisher, zenoh.Encoding]] = field(default_factory=dict)
    #: published frames waiting for their decode: (frame, receive time, stamp), ns
    deferred: list[tuple[Frame, int, int]] = field(default_factory=list)
    deferred_since: float = 0.0  # host monotonic s when the oldest of them was published
    framing_at: float = 0.0  # host monotonic s the framing counters last reached the health
    framed: bool = False  # frames or bytes came since then
    seq: int = 0
    reported_bad: int = 0
    rejected_before: int = 0  # datagrams rejected on earlier connections (allowed senders)
    reported_rejected: int = 0
    losses_before: Counter[str] = field(default_factory=Counter)  # earlier connections' losses
    reported_lost: int = 0
    #: a device that takes commands from the bus (the actuators): its gate, the transport of
    #: the connection being served (None between connections) and the lock of both
    gate: CommandGate | None = None
    transport: Transport | None = None
    cmd_lock: threading.Lock = field(default_factory=threading.Lock)
    #: host monotonic s of the last reads that brought frames (all connections): the period
    frame_reads: deque[float] = field(default_factory=lambda: deque(maxlen=PERIOD_READS))
    silent_reopens: int = 0  # reopens in a row that brought no frame
    reopen_now: bool = False  # the last connection was closed for silence: reopen at once


class Gateway:
    """Runs every enabled device of a configuration against one Zenoh session. ``session`` may be
    passed in (stages sharing one embedded peer); otherwise one is opened from ``cfg.bus`` and
    closed by :meth:`stop`. :attr:`listeners` (a :class:`~auvgw.notify.Notifier`; ``on_message``
    is subscribed to it) lets in-process stages see decoded messages without a Zenoh hop
    (``(device, t_recv_ns, message)`` on the device's reader thread: keep it short);
    ``t_recv_ns`` is the time published with the message (the host receive time, or the
    vehicle-paced time of ``cfg.clock``: :meth:`ClockConfig.stamp
    <auvgw.config.gateway.ClockConfig.stamp>`). Decoders are built first, so a format, table or DBC
    that cannot be loaded raises :class:`~auvgw.config.gateway.ConfigError` before any session is
    opened.
    """

    def __init__(
        self,
        cfg: GatewayConfig,
        session: zenoh.Session | None = None,
        on_message: Callable[[str, int, object], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.vehicle)
        decoders = make_decoders(cfg)
        self.devices: dict[str, _Device] = {
            name: _Device(
                name,
                cfg.devices[name],
                DeviceHealth(
                    name, cfg.devices[name].format, port=cfg.devices[name].transport.describe()
                ),
                decoder,
            )
            for name, decoder in decoders.items()
        }
        self.listeners = Notifier()
        if on_message is not None:
            self.listeners.subscribe(on_message)
        self.stop_event = threading.Event()
        self.finished = threading.Event()
        self._own_session = session is None
        self.session = session if session is not None else open_session(cfg.bus)
        self._t0_ns = time.time_ns()
        #: raw sequence numbers are ``session_id << 32 | n`` (n counts a device's frames from
        #: 1): unique across gateway restarts (the start second; restarts take longer than that)
        self.session_id = (self._t0_ns // 1_000_000_000) & 0xFFFFFFFF
        for dev in self.devices.values():
            dev.seq = self.session_id << 32
            can = dev.decoder.can
            if can is not None:  # a CAN device whose DBC has the actuator command takes it
                from auvgw.drivers.actuators import COMMAND_TYPE, CommandGate

                if COMMAND_TYPE in can.codec.types:
                    dev.gate = CommandGate(can.codec)
        self._stamp = cfg.clock.stamp
        self._paced = cfg.clock.paced_monotonic  # the silence watchdog's clock
        self._threads: list[threading.Thread] = []
        self._decls: list[Undeclarable] = []
        self._status_pubs: dict[str, zenoh.Publisher] = {}
        self._alone = False  # check_alone found no other gateway of this vehicle
        self._started = False
        self._stopped = False
        self._ended_lock = threading.Lock()
        self._ended = 0

    # -- lifecycle --------------------------------------------------------------------------
    def check_alone(self, timeout_s: float = CLAIM_TIMEOUT_S) -> None:
        """Raise :class:`GatewayRunning` (naming its host and pid, from its status queryable)
        when another gateway of this vehicle holds ``auv/<v>/alive/gateway`` on the bus. Done
        before any port is opened (by :meth:`start`, or earlier by the caller): a second
        gateway on one vehicle would share its SLCAN adapters and close their channels on exit.
        Two gateways started within the same instant can both pass (docs/gateway.md)."""
        if self._alone:
            return
        found, status = _running_gateway(self.session, self.keys, timeout_s)
        if found:
            raise GatewayRunning(_describe_holder(self.cfg.vehicle, status))
        self._alone = True

    def start(self) -> None:
        """Check that no other gateway serves this vehicle (:meth:`check_alone`), declare
        tokens, queryables and publishers, then start a reader thread per device."""
        if self._started:
            return
        self.check_alone()
        self._started = True
        s = self.session
        self._decls.append(s.liveliness().declare_token(self.keys.alive("gateway")))
        self._decls.append(s.declare_queryable(self.keys.config("gateway"), self._answer_config))
        for component in ("gateway", *self.devices):
            key = self.keys.status(component)
            answer = functools.partial(self._answer_status, component=component)
            self._decls.append(s.declare_queryable(key, answer))
            self._status_pubs[component] = s.declare_publisher(key, congestion_control=_DROP)
        for dev in self.devices.values():
            dev.pubs["raw"] = s.declare_publisher(
                self.keys.raw(dev.name),
                encoding=raw_encoding(dev.cfg.format),
                congestion_control=_DROP,
            )
            if dev.gate is not None:
                self._decls.append(
                    s.declare_subscriber(
                        self.keys.cmd(dev.name), functools.partial(self._on_command, dev)
                    )
                )
            dev.thread = threading.Thread(
                target=self._run_device, args=(dev,), name=f"dev-{dev.name}"
            )
            self._threads.append(dev.thread)
        self._threads.append(threading.Thread(target=self._run_status, name="status", daemon=True))
        if not self.devices:
            self.finished.set()
        log.info(
            "gateway for vehicle %r starting: %d device(s), bus %s, Zenoh id %s",
            self.cfg.vehicle,
            len(self.devices),
            self.cfg.bus.describe(),
            self.session.zid(),
        )
        for t in self._threads:
            t.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop readers, withdraw tokens and declarations, close the session if this gateway
        opened it. Safe to call more than once."""
        if self._stopped:
            return
        self._stopped = True
        self.stop_event.set()
        if not self._started:  # refused or never started: only the session to close
            if self._own_session:
                self.session.close()
            return
        for t in self._threads:
            t.join(timeout_s)
            if t.is_alive():
                log.warning("thread %s did not stop within %.1f s", t.name, timeout_s)
        for d in [*self._decls, *self._status_pubs.values()]:
            with contextlib.suppress(zenoh.ZError):
                d.undeclare()
        for dev in self.devices.values():
            for pub in dev.pubs.values():
                with contextlib.suppress(zenoh.ZError):
                    pub.undeclare()
        if self._own_session:
            self.session.close()
        log.info("gateway stopped")

    def __enter__(self) -> Gateway:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- status -----------------------------------------------------------------------------
    def device_status(self, name: str, now_ns: int | None = None) -> dict[str, Any]:
        """One device's status (JSON-ready, fields in docs/gateway.md)."""
        d = self.devices[name]
        now_ns = time.time_ns() if now_ns is None else now_ns
        # the stamp clock of the data ([clock]: vehicle-paced in emulation), so a viewer puts
        # the health next to the data it describes at any sim speed
        stamp = self._stamp(now_ns)
        snap = d.health.snapshot(now_ns, stale_after_s=d.cfg.stale_after_s, now_stamp_ns=stamp)
        snap["t_stamp_ns"] = stamp
        if d.gate is not None:
            with d.cmd_lock:
                snap["commands"] = d.gate.as_dict()
        return snap

    # -- commands ---------------------------------------------------------------------------
    def _on_command(self, dev: _Device, sample: zenoh.Sample) -> None:
        """A command envelope from ``auv/<v>/cmd/<device>`` (Zenoh's thread): checked by the
        device's gate and sent on its CAN bus, or refused and counted (docs/gateway.md)."""
        from auvgw.drivers.actuators import CommandRefused

        gate = dev.gate
        assert gate is not None
        with dev.cmd_lock:
            try:
                env = decode_envelope(sample.payload.to_bytes(), str(sample.key_expr))
                if env.message is None:
                    raise ValueError(f"{env.type}: not a message type this gateway knows")
                frame = gate.check(env.message, time.monotonic())
            except CommandRefused as exc:
                self._refused(dev, str(exc))
                return
            except (ValueError, KeyError, TypeError) as exc:  # not an envelope we can read
                self._refused(dev, str(gate.refuse("malformed", f"{type(exc).__name__}: {exc}")))
                return
            transport = dev.transport
            try:
                if transport is None:
                    raise TransportError(dev.name, "not connected")
                transport.send_frame(  # type: ignore[attr-defined]
                    frame.arbitration_id, frame.data, is_extended_id=frame.is_extended_id
                )
            except (TransportError, ValueError) as exc:
                self._refused(dev, str(gate.refuse("send_failed", str(exc))))
                return
            gate.sent(frame, time.monotonic())

    @staticmethod
    def _refused(dev: _Device, why: str) -> None:
        assert dev.gate is not None
        n = sum(v for k, v in dev.gate.counts.items() if k != "forwarded")
        if n & (n - 1) == 0:  # the 1st, 2nd, 4th, 8th ... refusal: a flood does not flood the log
            log.warning("%s: command refused (%d so far): %s", dev.name, n, why)

    def status(self) -> dict[str, Any]:
        """The gateway's status: vehicle, time, uptime and every device's status."""
        now = time.time_ns()
        return {
            "v": SCHEMA_VERSION,
            "vehicle": self.cfg.vehicle,
            "host": _HOST,
            "pid": os.getpid(),
            "t_ns": now,
            "t_stamp_ns": self._stamp(now),
            "uptime_s": round((now - self._t0_ns) / 1e9, 3),
            "session_id": self.session_id,
            "bus": self._bus_status(),
            "devices": {name: self.device_status(name, now) for name in self.devices},
        }

    def _bus_status(self) -> dict[str, Any]:
        """This session's Zenoh id, mode and the peers and routers it is connected to."""
        try:
            info = self.session.info
            return {
                "zid": str(self.session.zid()),
                "mode": self.cfg.bus.mode,
                "peers": sorted(str(z) for z in info.peers_zid()),
                "routers": sorted(str(z) for z in info.routers_zid()),
            }
        except zenoh.ZError:  # session closing
            return {"zid": "", "mode": self.cfg.bus.mode, "peers": [], "routers": []}

    def _run_status(self) -> None:
        period = self.cfg.status_period_s
        while not self.stop_event.wait(period):
            st = self.status()
            try:
                self._status_pubs["gateway"].put(
                    json.dumps(st).encode(), encoding=json_encoding("GatewayStatus")
                )
                for name, snap in st["devices"].items():
                    self._status_pubs[name].put(
                        json.dumps(snap).encode(), encoding=json_encoding("DeviceStatus")
                    )
            except zenoh.ZError:  # session closing
                return
            for dev in self.devices.values():
                self._log_bad_frames(dev, period)

    def _log_bad_frames(self, dev: _Device, period_s: float) -> None:
        h = dev.health
        rejected = h.rejected_datagrams - dev.reported_rejected
        if rejected > 0:
            dev.reported_rejected = h.rejected_datagrams
            log.warning(
                "%s: %d datagram(s) from senders not allowed in the last %.1f s (last from %s; "
                "allowed_senders in the device's transport)",
                dev.name,
                rejected,
                period_s,
                h.last_rejected_sender,
            )
        lost = sum(h.transport_losses.values())
        if lost > dev.reported_lost:
            log.warning(
                "%s: the transport lost data in the last %.1f s (totals %s): the reader or the "
                "host link does not keep up",
                dev.name,
                period_s,
                ", ".join(f"{k}: {n}" for k, n in sorted(h.transport_losses.items()) if n),
            )
            dev.reported_lost = lost
        new = h.bad_frames - dev.reported_bad
        if new > 0:
            dev.reported_bad = h.bad_frames
            reasons = ", ".join(f"{r}: {n}" for r, n in sorted(h.bad_frame_reasons.items()))
            log.warning(
                "%s: %d bad frame(s) in the last %.1f s (totals %s; %d bytes skipped)",
                dev.name,
                new,
                period_s,
                reasons,
                h.skipped_bytes,
            )

    def _answer_status(self, query: zenoh.Query, component: str) -> None:
        key = self.keys.status(component)
        if component == "gateway":
            query.reply(
                key, json.dumps(self.status()).encode(), encoding=json_encoding("GatewayStatus")
            )
        else:
            snap = self.device_status(component)
            query.reply(key, json.dumps(snap).encode(), encoding=json_encoding("DeviceStatus"))

    def _answer_config(self, query: zenoh.Query) -> None:
        query.reply(
            self.keys.config("gateway"),
            self.cfg.model_dump_json(exclude={"bus": {"auth": {"password"}}}).encode(),
            encoding=json_encoding("GatewayConfig"),
        )

    # -- one device -------------------------------------------------------------------------
    def _sensor_pub(self, dev: _Device, kind: str) -> zenoh.Publisher:
        pub = dev.pubs.get(kind)
        if pub is None:
            pub = dev.pubs[kind] = self.session.declare_publisher(
                self.keys.sensor(dev.name, kind), congestion_control=_DROP
            )
        return pub

    def _route(self, dev: _Device, type_name: str) -> tuple[zenoh.Publisher, zenoh.Encoding]:
        """The publisher and encoding of a message type's envelopes (made once per type)."""
        route = dev.routes.get(type_name)
        if route is None:
            pub = self._sensor_pub(dev, kind_of(type_name))
            route = dev.routes[type_name] = (pub, envelope_encoding(type_name))
        return route

    def _handle_frames(
        self,
        dev: _Device,
        frames: list[Frame],
        t_recv_ns: int,
        transport: Transport,
        host: HostDriver | None,
    ) -> None:
        """Publish, decode, count and hand on the frames of one read. Where the format reads
        the envelope straight from the frame's bytes (:meth:`DeviceDecoder.envelope_body`: the
        same bytes as the decoded message's envelope), the frame is decoded after the samples
        are put (:meth:`_settle`; with a host driver, right after them); otherwise it is decoded
        and its envelopes built before the puts. The samples of every frame of the read leave
        back to back (one wake of Zenoh's sender, each raw frame before its decoded samples);
        the health accounting, the in-process listeners and the host driver come after the
        puts, off the samples' latency."""
        t_ns = self._stamp(t_recv_ns)  # published time (vehicle-paced with [clock])
        raw_pub = dev.pubs["raw"]
        wire = dev.cfg.format
        decoder = dev.decoder
        verified = decoder.verified
        puts: list[tuple[zenoh.Publisher, bytes, bytes | None, zenoh.Encoding | None]] = []
        items: list[DecodedItem] = []
        try:
            for frame in frames:
                dev.seq += 1
                seq = dev.seq
                attachment = pack_raw_attachment(t_ns, seq, frame.offset)
                puts.append((raw_pub, frame.data, attachment, None))  # out whatever comes next
                fast = decoder.envelope_body(frame.data) if verified else None
                if fast is not None:
                    type_name, schema, body = fast
                    pub, enc = self._route(dev, type_name)
                    payload = pack_envelope(type_name, schema, wire, dev.name, t_ns, seq, body)
                    puts.append((pub, payload, None, enc))
                    if host is None:  # decoded once the samples are on their way (_settle)
                        if not dev.deferred:
                            dev.deferred_since = time.monotonic()
                        dev.deferred.append((frame, t_recv_ns, t_ns))
                    else:
                        items.append(decoder.item(frame.data, frame.offset, verified))
                    continue
                item = decoder.item(frame.data, frame.offset, verified)
                for msg in item.messages:
                    pub, enc = self._route(dev, message_type(msg))
                    payload = encode_envelope(msg, dev.name, t_ns, seq, wire=wire, decoded=True)[0]
                    puts.append((pub, payload, None, enc))
                items.append(item)
        finally:
            for out, data, att, encoding in puts:
                out.put(data, attachment=att, encoding=encoding)
        for item in items:
            self._decoded(dev, item, t_recv_ns, t_ns, transport, host)

    def _decoded(
        self,
        dev: _Device,
        item: DecodedItem,
        t_recv_ns: int,
        t_ns: int,
        transport: Transport,
        host: HostDriver | None,
    ) -> None:
        """A frame's decoded messages (published already) to the health accounting, the
        in-process listeners and the host driver."""
        if item.error is not None:
            dev.health.decode_error(item.error)
        for msg in item.messages:
            # rates on the host clock; lag from the device's own time against the stamp
            dev.health.seen(t_recv_ns, message_type(msg), t_ns, device_time_s(msg))
            self.listeners.notify(dev.name, t_ns, (msg,))
            if host is not None:
                host.on_message(msg, transport.write, time.monotonic())

    def _settle(self, dev: _Device, transport: Transport) -> None:
        """Decode the frames whose envelopes went out straight from their bytes (for the
        health, the listeners), then refresh the framing counters. Called once the line has
        been quiet for :data:`SETTLE_S` or the oldest such frame is that old: not while their
        samples travel (on a 2-core machine that work delayed them by tens of us)."""
        deferred, dev.deferred = dev.deferred, []
        decoder, verified = dev.decoder, dev.decoder.verified
        for frame, t_recv_ns, t_ns in deferred:
            item = decoder.item(frame.data, frame.offset, verified)
            self._decoded(dev, item, t_recv_ns, t_ns, transport, None)
        self._update_framing(dev)

    def _update_framing(self, dev: _Device) -> None:
        c = dev.decoder.counts()
        dev.health.set_framing(c.frames, c.bad_frames, c.skipped_bytes, c.reasons)
        dev.framing_at, dev.framed = time.monotonic(), False

    @staticmethod
    def _update_rejected(dev: _Device, transport: Transport) -> None:
        rejected = getattr(transport, "rejected_datagrams", 0)
        if rejected:
            dev.health.set_rejected(
                dev.rejected_before + rejected, getattr(transport, "last_rejected_sender", None)
            )

    @staticmethod
    def _update_losses(dev: _Device, transport: Transport) -> None:
        now = transport.losses()
        if now:  # a transport closing or without counters keeps the totals read so far
            total = Counter(dev.losses_before)
            total.update(now)  # (not +: that drops the zero counters)
            dev.health.set_transport_losses(total)

    @staticmethod
    def silence_limit(dev: _Device) -> float | None:
        """Host seconds without a frame after which an open device is closed and reopened
        (None: never; with a lock-step sim's clock, seconds of ``ClockConfig.paced_monotonic``,
        which stands still while the sim holds its vehicle time): ``reopen_silent_periods``
        times its period (``expected_period_s``, or the median interval of its recent
        frame-bearing reads), at least ``stale_after_s`` (the device is reported stale first),
        doubled for each reopen in a row that brought no frame (up to
        :data:`MAX_SILENT_BACKOFF` times). Never for a file replay or a UDP port."""
        cfg = dev.cfg
        period = cfg.expected_period_s
        if period is None and len(dev.frame_reads) >= 3:
            period = statistics.median(b - a for a, b in itertools.pairwise(dev.frame_reads))
        if not cfg.reopen_silent_periods or period is None or cfg.transport.kind in ("file", "udp"):
            # a file replayed again would repeat its data; a UDP socket has no link to renew
            # (reopening it only drops what is in flight)
            return None
        limit = max(cfg.reopen_silent_periods * period, cfg.stale_after_s)
        return limit * min(2**dev.silent_reopens, MAX_SILENT_BACKOFF)

    def _silent(self, dev: _Device, since: float | None, now: float) -> bool:
        """Whether the open device has been silent too long (``since``: host monotonic s of
        its last frame on this connection, or of the open after a silent reopen; None: it has
        not sent on this connection, so it is not judged)."""
        if since is None:
            return False
        limit = self.silence_limit(dev)
        if limit is None or now - since <= limit:
            return False
        reason = (
            f"no frame for {now - since:.1f} s while open (limit {limit:.2f} s: "
            f"reopen_silent_periods); closing and reopening"
        )
        dev.health.set_reopening(reason)
        # the first of a silence at INFO (a device at rest looks the same; status says stale),
        # the next ones at DEBUG; frames coming back after a reopen are the WARNING
        log.log(logging.DEBUG if dev.silent_reopens else logging.INFO, "%s: %s", dev.name, reason)
        dev.silent_reopens += 1
        dev.reopen_now = True
        return True

    def _serve(self, dev: _Device, transport: Transport) -> bool:
        """Read one connection until it drops, stays silent too long (:meth:`silence_limit`),
        or stop; True when a finite source has ended."""
        host = make_host_driver(dev.cfg)
        token = None
        with dev.cmd_lock:
            dev.transport = transport
        # judged silent from its last frame; from the open only after a silent reopen
        last_frame = self._paced() if dev.silent_reopens else None
        try:
            token = self.session.liveliness().declare_token(self.keys.alive(dev.name))
            if host is not None:
                host.on_connect(transport.write, time.monotonic())
            next_loss_poll = 0.0
            # a serial stream read at most every read_interval_s while bytes keep coming (a
            # polled device never: its next poll waits on the reply); a datagram comes one per
            # read, an SLCAN adapter's frames of one read of its port together (drain)
            if host is None and isinstance(transport, SerialTransport):
                transport.read_interval_s = dev.cfg.read_interval_s
            while not self.stop_event.is_set():
                chunk = transport.read(SETTLE_S if dev.deferred else READ_TIMEOUT_S)
                if chunk is not None:  # the data first, the bookkeeping after it
                    frames = dev.decoder.frames(chunk)
                    for more in transport.drain():  # a burst's other frames, read with it
                        frames += dev.decoder.frames(more)
                    self._handle_frames(dev, frames, chunk.t_recv_ns, transport, host)
                    dev.framed = True
                    now = time.monotonic()
                    if frames:
                        paced = self._paced()
                        dev.frame_reads.append(paced)
                        if dev.silent_reopens:
                            log.warning(
                                "%s: frames again after %d reopen(s) for silence: the "
                                "connection had stopped delivering while open",
                                dev.name,
                                dev.silent_reopens,
                            )
                        last_frame, dev.silent_reopens = paced, 0
                    if dev.deferred:
                        if now - dev.deferred_since >= SETTLE_S:
                            self._settle(dev, transport)
                    elif now - dev.framing_at >= FRAMING_PERIOD_S:
                        self._update_framing(dev)
                elif dev.deferred:  # the line is quiet: the samples are on their way
                    self._settle(dev, transport)
                elif dev.framed:
                    self._update_framing(dev)
                elif self._silent(dev, last_frame, self._paced()):
                    break
                self._update_rejected(dev, transport)
                if (now := time.monotonic()) >= next_loss_poll:
                    next_loss_poll = now + LOSS_POLL_S
                    self._update_losses(dev, transport)
                # a partial frame waited too long on a quiet line (never while bytes arrive: a
                # reader starved of CPU must not drop frames whose bytes wait in the port)
                if chunk is None and dev.decoder.has_stale(time.monotonic()):
                    stale = dev.decoder.expire(time.monotonic())
                    self._handle_frames(dev, stale, time.time_ns(), transport, host)
                    self._update_framing(dev)
                if host is not None:
                    host.on_idle(transport.write, time.monotonic())
        except EndOfStream as exc:
            self._handle_frames(dev, dev.decoder.finish(), time.time_ns(), transport, None)
            self._settle(dev, transport)
            dev.health.set_ended(str(exc))
            log.info("%s: end of stream (%s)", dev.name, exc)
            return True
        except Disconnected as exc:
            dev.health.set_connected(False, str(exc))
            log.warning("%s: disconnected (%s)", dev.name, exc)
        except TransportError as exc:  # e.g. a host driver's write timed out: reopen
            dev.health.set_connected(False, str(exc))
            log.warning("%s: transport error (%s); reopening", dev.name, exc)
        except zenoh.ZError as exc:
            if not self.stop_event.is_set():
                dev.health.set_connected(False, f"bus: {exc}")
                log.error("%s: bus error (%s)", dev.name, exc)
        except Exception as exc:  # a reader must never take the daemon down
            dev.health.set_connected(False, f"{type(exc).__name__}: {exc}")
            log.exception("%s: reader error; reopening", dev.name)
        finally:
            with dev.cmd_lock:
                dev.transport = None
            with contextlib.suppress(Exception):
                self._settle(dev, transport)
            self._update_framing(dev)
            with contextlib.suppress(Exception):  # counters of a connection that just failed
                self._update_losses(dev, transport)
            dev.losses_before = Counter(dev.health.transport_losses)
            dev.rejected_before += getattr(transport, "rejected_datagrams", 0)
            dev.decoder.reset()
            if token is not None:
                with contextlib.suppress(zenoh.ZError):
                    token.undeclare()
            transport.close()
        return False

    def _run_device(self, dev: _Device) -> None:
        cfg = dev.cfg
        backoff = Backoff(cfg.backoff_initial_s, cfg.backoff_max_s)
        failures = 0
        tcfg = cfg.transport
        fmt = dev.decoder.format
        if tcfg.kind == "udp" and tcfg.receive_buffer_bytes is None and fmt is not None:
            # a receive buffer for a burst of the format's largest datagrams while this thread
            # is starved (the kernel's default holds a few GeoSwath pings: issue 31)
            size = udp_receive_buffer(fmt.framer().max_frame_size)
            tcfg = tcfg.model_copy(update={"receive_buffer_bytes": size})
        while not self.stop_event.is_set():
            transport = make_transport(tcfg)
            try:
                transport.open()
            except TransportError as exc:
                delay = backoff.next_delay()
                dev.health.set_connected(False, str(exc), retry_in_s=delay)
                failures += 1
                level = logging.WARNING if failures == 1 else logging.DEBUG
                log.log(
                    level,
                    "%s: not available (%s); retrying every %.1f-%.1f s",
                    dev.name,
                    exc,
                    cfg.backoff_initial_s,
                    cfg.backoff_max_s,
                )
                self.stop_event.wait(delay)
                continue
            failures = 0
            backoff.reset()
            dev.health.set_connected(True)
            log.info("%s: connected on %s", dev.name, transport.describe())
            if self._serve(dev, transport):
                with self._ended_lock:
                    self._ended += 1
                    if self._ended == len(self.devices):
                        self.finished.set()
                return
            if dev.reopen_now:  # closed for silence: reopen at once
                dev.reopen_now = False
                continue
            if not self.stop_event.is_set():
                delay = backoff.next_delay()
                dev.health.set_retry(delay)
                self.stop_event.wait(delay)
