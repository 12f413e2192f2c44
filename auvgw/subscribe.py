"""Subscribe to a gateway's data as typed messages, from any process on the vehicle or on shore.

::

    from auvgw.subscribe import GatewaySubscriber
    from auvgw.config.bus import BusConfig

    bus = BusConfig(mode="client", connect=["tcp/192.168.1.10:7447"])
    with GatewaySubscriber("auv1", bus) as sub:
        for env in sub.messages(device="dvl", timeout=5.0):
            print(env.t_recv_ns, env.message.bottom_track)   # a typed, immutable pd0.Ensemble

How messages are rebuilt: from the envelope the gateway publishes
(``auv/<v>/sensor/<device>/<kind>``, MessagePack, docs/bus.md#payloads) by
:func:`auvgw.envelope.decode_envelope` (the positional body through the codec's table), not by
decoding the raw frame again. That needs no
device configuration, DBC or site table on the subscriber's side (a shore laptop only needs the
codec modules for the types), and it gives the same values the gateway decoded (floats and
arrays travel in binary, NaN included). A type no installed codec defines (e.g. a CAN message
built from a DBC the subscriber has not loaded) arrives with ``message = None`` and its fields
in ``body``.

Streams queue samples in the Zenoh callback and never block it: when a consumer falls behind by
more than ``queue_size`` samples, new ones are dropped and counted (``Stream.dropped``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import queue
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import zenoh

from auvgw.bus import Envelope, Keys, decode_envelope, open_session, unpack_raw_attachment
from auvgw.config.bus import BusConfig
from auvgw.drivers.spec import from_jsonable, to_jsonable
from auvgw.envelope import SchemaError, message_class, typed_body
from auvgw.ground.closing import Closing
from auvgw.ground.worker import Inbox

log = logging.getLogger(__name__)

__all__ = [
    "GatewaySubscriber",
    "RawFrame",
    "Stream",
    "envelope_message",
    "slam_output",
    "typed_message",
]


def typed_message(
    type_name: str, body: list[object] | Mapping[str, object], schema: int | None = None
) -> object:
    """The typed, immutable message of an envelope's body (by name, or positional with the
    envelope's ``schema``), or None for an unknown type or a body that does not fit."""
    cls = message_class(type_name)
    if cls is None:
        return None
    try:
        if isinstance(body, list):
            return typed_body(cls, type_name, -1 if schema is None else schema, body)
        return from_jsonable(body, cls)
    except (TypeError, ValueError, KeyError) as exc:
        log.warning("cannot rebuild a %s from its envelope body: %s", type_name, exc)
        return None


def envelope_message(env: Envelope) -> object:
    """The typed message of a decoded envelope (rebuilt now if its type was not known when the
    envelope was decoded), or None."""
    if env.message is not None:
        return env.message
    return typed_message(env.type, env.body, env.schema)


def slam_output(payload: bytes, key: str = "") -> dict[str, Any]:
    """A SLAM output (``auv/<v>/slam/<pipeline>/<what>``) as its field map: the envelope of a
    declared message (:mod:`auvgw.slam.outputs`) as :func:`~auvgw.drivers.spec.to_jsonable`
    gives it (NaN as None, with its ``type``), or a JSON object as it is (any producer of the
    JSON docs/viz.md accepts). A ``ValueError`` (naming ``key``) for anything else."""
    import auvgw.slam.outputs  # noqa: F401 - registers the SLAM output types

    if payload[:1] == b"{":
        try:
            body: dict[str, Any] = json.loads(payload)
        except ValueError as exc:
            raise ValueError(f"{key}: not a JSON object ({exc})") from None
        return body
    try:
        env = decode_envelope(payload, key)
    except ValueError as exc:
        raise ValueError(f"{key}: {exc}") from None
    msg = envelope_message(env)
    if msg is not None:
        out = to_jsonable(msg)
        if isinstance(out, dict):
            return out
    if isinstance(env.body, dict):
        return {"type": env.type, **env.body}
    raise ValueError(f"{key}: a {env.type} envelope is not a SLAM output")


@dataclass(frozen=True, slots=True)
class RawFrame:
    """A raw frame as the gateway published it: bytes exactly as received, host receive time
    (ns since the Unix epoch), per-device sequence and the stream byte offset of its first byte
    (since the device's connection opened)."""

    device: str
    t_recv_ns: int
    seq: int
    offset: int
    data: bytes
    key: str


class Stream(Closing):
    """A declared subscription whose samples queue up until iterated (see :meth:`get`): the
    consumer's own thread takes them from an :class:`~auvgw.ground.worker.Inbox` (bounded, never
    blocking the Zenoh callback, counting what it refuses)."""

    def __init__(self, session: zenoh.Session, key: str, raw: bool, queue_size: int) -> None:
        self.key = key
        self.raw = raw
        self._inbox: Inbox[tuple[str, bytes, bytes | None]] = Inbox(queue_size)
        self._sub = session.declare_subscriber(key, self._on_sample)

    @property
    def dropped(self) -> int:
        """Samples dropped because the consumer fell ``queue_size`` behind."""
        return self._inbox.dropped

    def _on_sample(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        item = (
            str(sample.key_expr),
            sample.payload.to_bytes(),
            None if att is None else att.to_bytes(),
        )
        self._inbox.put(item)

    def _convert(self, item: tuple[str, bytes, bytes | None]) -> Envelope | RawFrame | None:
        key, payload, att = item
        if self.raw:
            if att is None:
                return None
            t_ns, seq, offset = unpack_raw_attachment(att)
            return RawFrame(key.rsplit("/", 1)[-1], t_ns, seq, offset, payload, key)
        try:
            env = decode_envelope(payload, key)
        except SchemaError as exc:  # another table than ours: the body as it came
            log.warning("%s: %s", key, exc)
            return decode_envelope(payload, key, typed=False)
        except (ValueError, KeyError) as exc:
            log.warning("%s: not a gateway envelope: %s", key, exc)
            return None
        if env.message is not None:
            return env
        return dataclasses.replace(env, message=typed_message(env.type, env.body, env.schema))

    def get(self, timeout: float | None = None) -> Envelope | RawFrame | None:
        """The next envelope (or raw frame), or None when nothing arrives within ``timeout`` s."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                item = self._inbox.get(left)
            except queue.Empty:
                return None
            out = self._convert(item)
            if out is not None:
                return out

    def __iter__(self) -> Iterator[Envelope | RawFrame]:
        return self.iter()

    def iter(self, timeout: float | None = None) -> Iterator[Envelope | RawFrame]:
        """Items until none arrives for ``timeout`` seconds (None: until closed)."""
        while (item := self.get(timeout)) is not None:
            yield item

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._sub.undeclare()



class GatewaySubscriber(Closing):
    """A Zenoh session joined to a vehicle's bus, with typed access to the gateway's data.

    ``vehicle`` is the gateway's ``vehicle`` name; ``bus`` how to join (e.g. a client of the
    vehicle's router). Close it (``with``) or the process hangs at exit.
    """

    def __init__(
        self,
        vehicle: str = "auv1",
        bus: BusConfig | None = None,
        session: zenoh.Session | None = None,
        queue_size: int = 100_000,
    ) -> None:
        self.keys = Keys(vehicle)
        self.queue_size = queue_size
        self._own = session is None
        self.session = session if session is not None else open_session(bus)
        self._streams: list[Stream] = []
        self._tokens: list[zenoh.LivelinessToken] = []

    # -- data -------------------------------------------------------------------------------
    def stream(
        self, device: str | None = None, kind: str | None = None, raw: bool = False
    ) -> Stream:
        """Declare a subscription now (decoded envelopes, or raw frames with ``raw=True``).

        ``device``/``kind`` None mean all. Samples published before the declaration reaches the
        gateway are not seen: call :meth:`wait_ready` after declaring.
        """
        key = self.keys.raw(device or "*") if raw else self.keys.sensor(device or "*", kind or "*")
        s = Stream(self.session, key, raw, self.queue_size)
        self._streams.append(s)
        return s

    def messages(
        self, device: str | None = None, kind: str | None = None, timeout: float | None = None
    ) -> Iterator[Envelope]:
        """Decoded envelopes (``.message`` typed) until none arrives for ``timeout`` seconds."""
        with self.stream(device, kind) as s:
            yield from (e for e in s.iter(timeout) if isinstance(e, Envelope))

    def frames(self, device: str | None = None, timeout: float | None = None) -> Iterator[RawFrame]:
        """Raw frames with their attachments until none arrives for ``timeout`` seconds."""
        with self.stream(device, raw=True) as s:
            yield from (f for f in s.iter(timeout) if isinstance(f, RawFrame))

    def wait_ready(self, timeout: float = 10.0) -> bool:
        """Wait for a gateway status sample; True once one arrived.

        The status subscription is declared after every stream declared so far, and Zenoh keeps
        declarations in order, so a status sample arriving proves those streams reached the
        gateway too: data published from then on is delivered.
        """
        got = threading.Event()
        sub = self.session.declare_subscriber(self.keys.status("gateway"), lambda _s: got.set())
        try:
            return got.wait(timeout)
        finally:
            sub.undeclare()

    # -- health -----------------------------------------------------------------------------
    def _get_json(self, key: str, timeout: float) -> dict[str, Any] | None:
        for reply in self.session.get(key, timeout=timeout):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def status(self, device: str | None = None, timeout: float = 2.0) -> dict[str, Any] | None:
        """The gateway's status (``device=None``) or one device's, from the status queryable;
        None when no gateway answers within ``timeout`` seconds."""
        return self._get_json(self.keys.status(device or "gateway"), timeout)

    def config(self, timeout: float = 2.0) -> dict[str, Any] | None:
        """The running gateway configuration (JSON), or None when no gateway answers."""
        return self._get_json(self.keys.config("gateway"), timeout)

    def alive(self, timeout: float = 2.0) -> set[str]:
        """Components with a liveliness token: ``gateway`` and each connected device."""
        out = set()
        for reply in self.session.liveliness().get(self.keys.alive("*"), timeout=timeout):
            if reply.ok is not None:
                out.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        return out

    def announce(self, name: str) -> None:
        """Declare the liveliness token ``auv/<v>/alive/<name>`` until closed (e.g. so
        ``auvgw replay --wait-for <name>`` starts once this subscriber's streams are declared)."""
        self._tokens.append(self.session.liveliness().declare_token(self.keys.alive(name)))

    # -- lifecycle --------------------------------------------------------------------------
    def close(self) -> None:
        for s in self._streams:
            s.close()
        for t in self._tokens:
            with contextlib.suppress(zenoh.ZError):
                t.undeclare()
        if self._own:
            self.session.close()

