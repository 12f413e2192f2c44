"""The vehicle on ROS 2, live: the bus republished the way ``rmw_zenoh_cpp`` expects it.

:class:`Ros2Bridge` subscribes to the vehicle's decoded sensors, odometry, SLAM outputs and status
(``auv/<v>/{sensor,nav,slam,status}/**``, never the raw frames: it is off their path), turns each
sample into its ROS 2 messages (:func:`auvgw.recording.sample_to_ros`, the same mapping as the
MCAP recordings) and publishes them as a ROS 2 node would on ``rmw_zenoh_cpp``
(:mod:`auvgw.rmw_zenoh`): CDR on ``<domain>/<topic>/<DDS type>/<RIHS01 hash>`` with the
attachment (sequence number, source time, GID), and the liveliness tokens of the node and of
each publisher, so ``ros2 node list``, ``ros2 topic list / echo`` and ``ros2 bag record`` on
rmw_zenoh see them. Beside the vehicle's topics (``/<namespace>/<vehicle>/sensor/ins/imu``, ...):

* ``/tf``: ``odom`` -> ``base_link`` from every odometry sample, ``map`` -> ``odom`` from every
  SLAM pose (against the latest odometry at or before its time);
* ``/tf_static``: ``base_link`` -> each sensor's frame from the mounts in the configuration,
  published at start and again every ``static_period_s`` (rmw_zenoh's transient-local cache is a
  Zenoh publication cache this bridge does not keep: a late subscriber waits at most one period);
* ``/diagnostics``: every component's status as a ``diagnostic_msgs/DiagnosticArray``.

Commands the other way: for each device in ``commands`` (opt-in) the bridge is a ROS 2
subscription of ``<namespace>/<vehicle>/cmd/<device>`` (``auvgw_msgs/msg/ActuatorCommand``, its
``MS`` liveliness token and data key as rmw_zenoh writes them) and puts each message it takes on
the bus command key ``auv/<v>/cmd/<device>`` as the actuators' ``ActuatorCommand`` envelope, so the
gateway's :class:`~auvgw.drivers.actuators.CommandGate` checks it (ranges, sequence) like any
other; bytes that are no such message are counted (``bad_commands``) and dropped.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, cast

import zenoh

from auvgw import ros2, ros2_cdr
from auvgw.bus import Keys
from auvgw.config.ros2 import Mount, Ros2Config
from auvgw.decoding import kind_of, message_type
from auvgw.envelope import decode_envelope, encode_envelope
from auvgw.rmw_zenoh import (
    DEFAULT_QOS,
    SENSOR_QOS,
    STATIC_QOS,
    Qos,
    data_key,
    entity_gid,
    node_token,
    pack_attachment,
    topic_token,
)
from auvgw.stages import log_bad_payload
from auvgw.stages.base import DROP, BusCounters, OnPublish, Stage, StageConfig
from auvgw.subscribe import envelope_message

__all__ = ["Mount", "Ros2Bridge", "Ros2BridgeConfig", "RosStage"]

log = logging.getLogger(__name__)

class Ros2BridgeConfig(StageConfig, Ros2Config):
    """The bridge's settings: the gateway's ``[ros2]`` table (:class:`~auvgw.config.ros2.
    Ros2Config`: domain, namespace, node, mounts) and the stage's (vehicle, status period)."""


@dataclass
class Ros2Counters(BusCounters):
    """``received``: bus samples taken; ``published``: ROS 2 messages put; ``topics``: ROS 2
    publishers declared; ``tf``: transforms put on ``/tf``; ``unwatched``: samples not converted
    because no subscriber matched any of the topics they make (:meth:`RosStage.wanted`);
    ``commands``: ROS 2 commands put on the bus command key; ``bad_commands``: ROS 2 samples on a
    command topic that were no command (bad CDR), dropped."""

    published: int = 0
    topics: int = 0
    tf: int = 0
    unwatched: int = 0
    commands: int = 0
    bad_commands: int = 0


class _Endpoint:
    """One ROS 2 publisher: its Zenoh publisher, liveliness token, GID and sequence, and whether
    a subscriber matches it (kept by Zenoh's matching listener)."""

    __slots__ = ("gid", "listener", "matching", "pub", "seq", "token")

    def __init__(self, pub: zenoh.Publisher, token: zenoh.LivelinessToken, gid: bytes) -> None:
        self.pub, self.token, self.gid, self.seq = pub, token, gid, 0
        # zenoh's stubs type matching_status as a bool; it is a MatchingStatus
        self.matching = bool(cast("zenoh.MatchingStatus", pub.matching_status).matching)
        self.listener = pub.declare_matching_listener(self._matched)

    def _matched(self, status: zenoh.MatchingStatus) -> None:
        self.matching = bool(status.matching)


class RosStage(Stage):
    """The bus as ROS 2 messages: every decoded sensor, odometry, SLAM output and status sample
    turned into its ROS 2 messages (the recordings' mapping) plus ``/tf`` (``map`` -> ``odom``
    from SLAM poses, besides the mapping's ``odom`` -> ``base_link``) and ``/tf_static`` (the
    mounts, at start and every ``static_period_s``), each handed to :meth:`put`, which a
    subclass gives: :class:`Ros2Bridge` (rmw_zenoh), :class:`~auvgw.stages.foxglove.
    FoxgloveStage` (the Foxglove WebSocket protocol)."""

    #: every section of the bus the stage can take
    SECTIONS: ClassVar[tuple[str, ...]] = ("sensor", "nav", "slam", "status")

    def __init__(self, config: Ros2BridgeConfig, session: zenoh.Session | None = None, *,
                 sections: tuple[str, ...] = SECTIONS, on_publish: OnPublish | None = None,
                 keys: Keys | None = None) -> None:  # fmt: skip
        super().__init__(config, Ros2Counters(), session, on_publish=on_publish, keys=keys)
        self.config = config
        #: the sections taken from the bus (in the gateway, the sensors come in-process:
        #: :meth:`post`, from the gateway's listeners, no envelope round trip)
        self.sections = sections
        self.batch_s = config.batch_ms / 1000  # Stage.post: one worker call per batch
        self.stats: Ros2Counters = self.stats  # type: ignore[assignment]
        self._static_lock = threading.Lock()
        self._static_at = -float("inf")  # monotonic s of the last /tf_static
        self._tf = ros2.TfTracker()  # map -> odom
        self._topics: dict[str, str] = {}
        #: (device, type name) -> (bus key, kind): sensor_key
        self._sensor_keys: dict[tuple[str, str], tuple[str, str]] = {}

    def input_keys(self) -> list[str]:
        return [self.keys.all(f"{s}/**") for s in self.sections]

    def accepts(self, device: str, message: object) -> bool:
        """:meth:`Stage.post` queues a message somebody would see (:meth:`wanted`), in batches
        of ``batch_s`` (``[ros2] batch_ms``: the puts of a batch go out together,
        :meth:`_work_item`)."""
        return self.wanted(self.sensor_key(device, message)[0])

    def sensor_key(self, device: str, message: object) -> tuple[str, str]:
        """The bus key and kind of a decoded sensor message of ``device``, remembered per device
        and type (up to 4096): :meth:`accepts` and :meth:`feed` key a posted message twice at
        the cost of two look-ups."""
        type_name = message_type(message)
        hit = self._sensor_keys.get((device, type_name))
        if hit is None:
            if len(self._sensor_keys) >= 4096:
                self._sensor_keys.clear()
            kind = kind_of(type_name)
            hit = self._sensor_keys[(device, type_name)] = (self.keys.sensor(device, kind), kind)
        return hit

    def feed(self, device: str, t_recv_ns: int, message: object) -> object:
        """One decoded sensor message in-process (the gateway's listener, via :meth:`post`)."""
        key, kind = self.sensor_key(device, message)
        with self._lock:
            self.stats.received += 1
        if self.wanted(key):
            self.emit_sensor(key, device, message, t_recv_ns, kind)
        return None

    def emit_sensor(self, key: str, device: str, message: object, t_ns: int, kind: str) -> None:
        """:meth:`emit` the ROS 2 messages of a decoded sensor message (device ``device``,
        stamp ``t_ns``, bus key ``key``: its ``kind``)."""
        self.emit(key, ros2.to_ros("sensor", device, message, t_ns, kind=kind), t_ns)

    def emit(self, key: str, msgs: list[ros2.RosMessage], t_ns: int) -> None:
        """:meth:`put` each of ``msgs``, made from a sample on bus key ``key``."""
        for m in msgs:
            self.put(m, t_ns)

    def put(self, m: ros2.RosMessage, t_ns: int) -> object:
        """Send ROS 2 message ``m`` stamped ``t_ns`` (the subclass's sink; what it returns is
        the subclass's)."""
        raise NotImplementedError

    def topic(self, rel_topic: str) -> str:
        """The fully qualified topic of a :class:`~auvgw.ros2.RosMessage` topic
        (:func:`auvgw.ros2.ros_topic` under the namespace; remembered, up to 4096 names)."""
        full = self._topics.get(rel_topic)
        if full is None:
            if len(self._topics) >= 4096:
                self._topics.clear()
            full = ros2.ros_topic(self.config.namespace, self.keys.vehicle, rel_topic)
            self._topics[rel_topic] = full
        return full

    # -- bus side ---------------------------------------------------------------------------
    def read_payload(self, key: str, payload: bytes, t_arrival_ns: int | None) -> object:
        """One bus sample as its ROS 2 messages (a sample with no ROS form is counted as a bad
        payload, never raised)."""
        from auvgw.recording import sample_to_ros

        base = self.keys.base + "/"
        if not key.startswith(base):
            return None
        section, _, rest = key[len(base):].partition("/")
        try:
            msgs, t_ns, _ = sample_to_ros(section, rest, payload, t_arrival_ns or 0)
            if section in ("sensor", "nav") and not self._stamps.accept(t_ns):
                raise ValueError(f"stamp {t_ns} ns implausible against the stage's clock")
            self.emit(key, list(msgs) + self._tf.feed(msgs, t_ns), t_ns)
        except Exception as exc:  # one sample must never stop the bridge
            self._bad_payload(key, exc)
            return None
        with self._lock:
            self.stats.received += 1
        return None

    def on_start(self, subscribe: bool) -> None:
        """``/tf_static`` once the outputs are up (then every ``static_period_s``)."""
        self.publish_static(time.time_ns())

    def publish_static(self, t_ns: int) -> None:
        """``/tf_static`` from the configured mounts (nothing without mounts)."""
        if self.config.mounts:
            with self._static_lock:
                self._static_at = time.monotonic()
                msg = ros2.static_tf(self.config.mounts, t_ns)
                self.put(ros2.RosMessage("/tf_static", ros2.TF_TYPE, msg), t_ns)

    def on_status(self) -> None:
        """After the status: ``/tf_static`` again once ``static_period_s`` has passed (checked at
        every status period: a late subscriber waits at most the longer of the two)."""
        if time.monotonic() - self._static_at >= self.config.static_period_s:
            self.publish_static(time.time_ns())

    def count(self, m: ros2.RosMessage | None, topic: str) -> None:
        """Count one message put on ``topic`` (``m``: the message, None for CDR alone)."""
        with self._lock:
            self.stats.published += 1
            if m is not None and m.type == ros2.TF_TYPE and topic == "/tf":
                self.stats.tf += len(m.msg.transforms)


class Ros2Bridge(RosStage):
    """The ROS 2 face of the bus on rmw_zenoh (module docstring). ``session``: the bus session
    (the one the ROS 2 keys are published on too); in-process (no session) the ROS 2 messages go
    to ``on_publish(data key, CDR, t_ns)``."""

    name: ClassVar[str] = "ros2"
    status_schema: ClassVar[str | None] = "Ros2BridgeStatus"

    def __init__(self, config: Ros2BridgeConfig, session: zenoh.Session | None = None, *,
                 sections: tuple[str, ...] = RosStage.SECTIONS, on_publish: OnPublish | None = None,
                 keys: Keys | None = None) -> None:  # fmt: skip
        super().__init__(config, session, sections=sections, on_publish=on_publish, keys=keys)
        self._endpoints: dict[str, _Endpoint] = {}
        self._keys: dict[tuple[str, str], str] = {}
        self._session_id = str(session.info.zid()) if session is not None else "0" * 32
        self._next_entity = 1
        #: the publishers each bus key's samples went to (:meth:`wanted`; a tuple replaced, never
        #: changed in place: the Zenoh callbacks and the gateway's listeners read it)
        self._made: dict[str, tuple[_Endpoint, ...]] = {}
        #: (RosMessage topic, ROS type) -> its publisher once declared: the sensors' puts
        #: (:meth:`_put_all`) take it in one look-up instead of :meth:`put_cdr`'s three
        self._routes: dict[tuple[str, str], _Endpoint] = {}
        #: puts held back on the worker (:meth:`_work_item`): (endpoint, CDR, attachment)
        self._held: list[tuple[_Endpoint, bytes, bytes]] = []
        self._holder: int | None = None  # the thread whose puts are held (the worker, in a call)
        self._sensor_base = self.keys.base + "/sensor/"

    def status_fields(self) -> dict[str, object]:
        return {"domain_id": self.config.domain_id, "namespace": self.config.namespace,
                "node": self.config.node, "ros_topics": sorted(self._endpoints)}  # fmt: skip

    def put(self, m: ros2.RosMessage, t_ns: int) -> _Endpoint | None:
        """Publish ROS 2 message ``m`` (stamp ``t_ns``) on its topic, declaring the publisher and
        its liveliness token the first time; its endpoint (None in-process)."""
        return self.put_cdr(m.topic, m.type, ros2.serialize(m), t_ns, m)

    #: the sensors' CDR from :mod:`auvgw.ros2_cdr`'s compiled writers (:meth:`emit_sensor`);
    #: False: rosbags objects and ``serialize_cdr`` for every message (the same bytes, slower:
    #: ``benchmarks/bench_ros2_bridge.py`` measures one against the other)
    compiled = True
    #: the Zenoh priority of the ROS 2 publishers: below the bus's own data (the raw frames,
    #: the decoded envelopes, the stages' outputs: ``DATA``), a copy of which they are. Zenoh
    #: keeps a transmission queue per priority, so a group of held puts (up to
    #: :attr:`MAX_HELD`) never waits in front of a raw frame; CPU-neutral (docs/ros2.md, Cost)
    priority = zenoh.Priority.DATA_LOW

    def emit_sensor(self, key: str, device: str, message: object, t_ns: int, kind: str) -> None:
        """A decoded sensor message's ROS 2 messages (:meth:`_write_sensor`)."""
        n = self._write_sensor(key, device, message, t_ns, kind,
                               self._holder == threading.get_ident())  # fmt: skip
        with self._lock:
            self.stats.published += n

    def _write_sensor(self, key: str, device: str, message: object, t_ns: int, kind: str,
                      hold: bool) -> int:  # fmt: skip
        """Put a decoded sensor message's ROS 2 messages written by :func:`auvgw.ros2_cdr.
        sensor_cdr` (no rosbags objects), or, for one with no standard form (or with
        :attr:`compiled` off), by :func:`auvgw.ros2.to_ros` (:meth:`RosStage.emit_sensor`);
        what :meth:`_put_all` put for the caller to count."""
        out = ros2_cdr.sensor_cdr(device, message, t_ns) if self.compiled else None
        if out is None:
            super().emit_sensor(key, device, message, t_ns, kind)
            return 0
        return self._put_all(key, out, t_ns, hold)

    def feed_batch(self, batch: deque[tuple[str, int, object]]) -> None:
        """A batch of the gateway's decoded sensor messages in one pass (each was
        :meth:`wanted` when posted): the stamp clock, :meth:`_write_sensor`, the puts held,
        the counts once per batch. One whose conversion raises is counted (``bad_payloads``)
        and logged, and the rest of the batch goes on."""
        accept, key_of, write = self._stamps.accept, self.sensor_key, self._write_sensor
        hold = self._holder == threading.get_ident()
        taken = put = 0
        while batch:
            device, t_ns, message = batch.popleft()
            accept(t_ns)  # in-process, from a trusted source: moves the clock, never refused
            key, kind = key_of(device, message)
            taken += 1
            try:
                put += write(key, device, message, t_ns, kind, hold)
            except Exception as exc:  # one message must never cost the batch
                self._bad_payload(key, exc)
        with self._lock:
            self.stats.received += taken
            self.stats.published += put

    def _put_all(self, key: str, out: list[tuple[str, str, bytes]], t_ns: int,
                 hold: bool) -> int:  # fmt: skip
        """Put each (topic, ROS type, CDR) of a sample on bus key ``key`` (``hold``: on the
        worker, in a call): on a declared publisher straight away (its sequence number and
        attachment); the first of a topic, or in-process (``on_publish``), through
        :meth:`put_cdr` (which counts it). What was put on a declared publisher: the caller
        counts it in ``published``."""
        routes, made = self._routes, self._made.get(key, ())
        new: list[_Endpoint | None] = []
        n = 0
        for topic, ros_type, cdr in out:
            ep = routes.get((topic, ros_type)) if self.on_publish is None else None
            if ep is None:
                new.append(self.put_cdr(topic, ros_type, cdr, t_ns))
                continue
            self._out(ep, cdr, t_ns, hold)
            n += 1
            if ep not in made:
                new.append(ep)
        if new:
            self._remember(key, new)
        return n

    def read_payload(self, key: str, payload: bytes, t_arrival_ns: int | None) -> object:
        """A decoded sensor sample of a standard ROS 2 form straight from its envelope to the
        compiled writers (``auvgw ros2 bridge`` takes the gateway's sensors this way: no
        rosbags objects); every other sample, and one whose envelope or conversion fails, as
        :meth:`RosStage.read_payload` takes it (which counts what is wrong)."""
        if not (self.compiled and key.startswith(self._sensor_base)):
            return super().read_payload(key, payload, t_arrival_ns)
        try:
            env = decode_envelope(payload)
            msg = envelope_message(env)
            device = key[len(self._sensor_base):].partition("/")[0]
            out = None if msg is None else ros2_cdr.sensor_cdr(device, msg, env.t_recv_ns)
        except Exception:  # RosStage.read_payload takes it again and counts what is wrong
            out = None
        if out is None:
            return super().read_payload(key, payload, t_arrival_ns)
        if not self._stamps.accept(env.t_recv_ns):
            self._bad_payload(key, ValueError(
                f"stamp {env.t_recv_ns} ns implausible against the stage's clock"))
            return None
        n = self._put_all(key, out, env.t_recv_ns, self._holder == threading.get_ident())
        with self._lock:
            self.stats.received += 1
            self.stats.published += n
        return None

    def put_cdr(self, rel_topic: str, ros_type: str, cdr: bytes, t_ns: int,
                m: ros2.RosMessage | None = None) -> _Endpoint | None:  # fmt: skip
        """Publish the CDR bytes of a ``ros_type`` message on topic ``rel_topic`` (a
        :class:`~auvgw.ros2.RosMessage` topic), stamped ``t_ns``, declaring the publisher and
        its liveliness token the first time; its endpoint (None in-process). ``m``: the message
        itself, when there is one (``/tf`` counts its transforms)."""
        topic = self.topic(rel_topic)
        key = self._keys.get((topic, ros_type))
        if key is None:
            key = self._keys[(topic, ros_type)] = data_key(self.config.domain_id, topic, ros_type)
        ep = self._endpoints.get(key)
        if ep is None and self.session is not None:
            ep = self._routes[(rel_topic, ros_type)] = self._declare(topic, ros_type, key)
        if ep is not None:
            self._out(ep, cdr, t_ns, self._holder == threading.get_ident())
        self.count(m, topic)
        if self.on_publish is not None:
            self.on_publish(key, cdr, t_ns)
        return ep

    def _out(self, ep: _Endpoint, cdr: bytes, t_ns: int, hold: bool) -> None:
        """The next sample of ``ep`` (its sequence number and attachment): held back for
        :meth:`_send_held` (``hold``: on the worker, in a call) or put now."""
        ep.seq += 1
        att = pack_attachment(ep.seq, t_ns, ep.gid)
        if hold:
            self._held.append((ep, cdr, att))
        else:
            self._send(ep, cdr, att)

    @staticmethod
    def _send(ep: _Endpoint, cdr: bytes, att: bytes) -> None:
        try:
            ep.pub.put(cdr, attachment=att)
        except zenoh.ZError as exc:
            log.warning("ros2: cannot publish on %s: %s", ep.pub.key_expr, exc)

    def _send_held(self) -> None:
        held, self._held = self._held, []
        for item in held:
            self._send(*item)

    #: puts held back at most (:meth:`_work_item`)
    MAX_HELD = 64

    def _work_item(self, item: tuple[Callable[..., object], tuple[object, ...]]) -> None:
        """Run a queued call (a batch of sensor messages, a bus sample) with the puts it makes
        held back, and send what is held once the queue is empty (or :attr:`MAX_HELD` are held):
        Zenoh's sender then wakes once per group of messages, not once per message (measured
        here: a put between conversions costs about 60 us of CPU, one of a group of 8 about
        15; docs/ros2.md)."""
        self._holder = threading.get_ident()
        try:
            super()._work_item(item)
        finally:
            self._holder = None
        if len(self._held) >= self.MAX_HELD or self._w_inbox.queue.empty():
            self._send_held()

    def wanted(self, key: str) -> bool:
        """Take a sample on bus ``key`` only if a subscriber matches one of the topics that key's
        samples went to (Zenoh's matching status, kept per publisher): with nobody listening,
        the bridge costs next to nothing. A key's first sample is always taken (it declares the
        publishers, so ``ros2 topic list`` shows them); in-process (no session) every one is."""
        made = self._made.get(key)
        if self.session is None or not made:
            return True
        for ep in made:
            if ep.matching:
                return True
        with self._lock:
            self.stats.unwatched += 1
        return False

    def emit(self, key: str, msgs: list[ros2.RosMessage], t_ns: int) -> None:
        self._remember(key, [self.put(m, t_ns) for m in msgs])

    def _remember(self, key: str, eps: list[_Endpoint | None]) -> None:
        """Note the publishers a sample on bus ``key`` went to (:meth:`wanted`)."""
        made = self._made.get(key, ())
        if any(ep is not None and ep not in made for ep in eps):
            self._made[key] = tuple({*made, *(ep for ep in eps if ep is not None)})

    def _declare(self, topic: str, ros_type: str, key: str) -> _Endpoint:
        assert self.session is not None
        qos = _qos(topic)
        token_key = topic_token(self.config.domain_id, self._session_id, 0, self._next_entity,
                                "MP", self.config.namespace, self.config.node, topic,
                                ros_type, qos)  # fmt: skip
        self._next_entity += 1
        pub = self.session.declare_publisher(key, congestion_control=DROP, priority=self.priority)
        token = self.session.liveliness().declare_token(token_key)
        ep = self._endpoints[key] = _Endpoint(pub, token, entity_gid(token_key))
        for d in (pub, token, ep.listener):  # withdrawn at stop, the listener first
            self.keep(d)
        with self._lock:
            self.stats.topics += 1
        return ep

    # -- commands from ROS 2 -----------------------------------------------------------------
    def command_topic(self, device: str) -> str:
        """The ROS 2 topic of ``device``'s commands: ``<namespace>/<vehicle>/cmd/<device>``."""
        return ros2.ros_topic(self.config.namespace, self.keys.vehicle, f"cmd/{device}")

    def on_ros_command(self, device: str, cdr: bytes) -> bytes | None:
        """A ROS 2 command message (CDR ``auvgw_msgs/msg/ActuatorCommand``) for ``device`` as the
        bus's command envelope (the actuators' ``ActuatorCommand``, source ``ros2``, stamped
        with the message's header or, unset, now), counted in ``commands``; bytes that are no
        such message are counted in ``bad_commands`` (logged: the first and every 100th), None.
        """
        try:
            cmd, stamp = ros2.actuator_command(cdr)
            payload, _ = encode_envelope(cmd, "ros2", stamp or time.time_ns(), int(cmd.seq))
        except ValueError as exc:
            with self._lock:
                seen = self.stats.bad_commands
                self.stats.bad_commands += 1
            log_bad_payload(self.name, self.command_topic(device), exc, seen)
            return None
        with self._lock:
            self.stats.commands += 1
        return payload

    def _declare_commands(self) -> None:
        """One ROS 2 subscription (data key and ``MS`` token) per ``commands`` device, whose
        messages go to the bus command key (in the Zenoh callback: a command is small and late
        is worse than a short callback)."""
        assert self.session is not None
        s, c = self.session, self.config
        for device in c.commands:
            topic = self.command_topic(device)
            key = data_key(c.domain_id, topic, ros2.ACTUATOR_COMMAND_TYPE)
            token = topic_token(c.domain_id, self._session_id, 0, self._next_entity, "MS",
                                c.namespace, c.node, topic, ros2.ACTUATOR_COMMAND_TYPE,
                                DEFAULT_QOS)  # fmt: skip
            self._next_entity += 1
            pub = s.declare_publisher(self.keys.cmd(device))

            def take(sample: zenoh.Sample, device: str = device,
                     pub: zenoh.Publisher = pub) -> None:  # fmt: skip
                payload = self.on_ros_command(device, sample.payload.to_bytes())
                if payload is not None:
                    with contextlib.suppress(zenoh.ZError):
                        pub.put(payload)

            for d in (pub, s.liveliness().declare_token(token), s.declare_subscriber(key, take)):
                self.keep(d)  # withdrawn at stop: the subscription first, no command after it

    def on_start(self, subscribe: bool) -> None:
        """The node's token first (a ROS graph shows the node before its publishers; withdrawn
        last), the command subscriptions, then ``/tf_static``."""
        if self.session is not None:
            self.keep(self.session.liveliness().declare_token(
                node_token(self.config.domain_id, self._session_id, 0, self.config.namespace,
                           self.config.node)))  # fmt: skip
            self._declare_commands()
        super().on_start(subscribe)

    def _work_finished(self) -> None:
        self._send_held()  # the worker's last call saw its stop mark still queued


def _qos(topic: str) -> Qos:
    if topic == "/tf_static":
        return STATIC_QOS
    return SENSOR_QOS if "/sensor/" in topic else DEFAULT_QOS
