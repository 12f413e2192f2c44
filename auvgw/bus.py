"""The Zenoh bus: key space, session modes and payload encodings (documented in docs/bus.md).

Key space (``<v>`` is the vehicle name)::

    auv/<v>/raw/<device>                 raw frames: bytes, attachment = RAW_ATTACHMENT
    auv/<v>/sensor/<device>/<kind>       decoded messages: JSON, encoding schema auvgw/1/<Type>
    auv/<v>/nav/odometry                 fusion output (JSON)
    auv/<v>/slam/<pipeline>/{pose,landmarks,map}
    auv/<v>/status/<component>           periodic health (JSON); also a queryable
    auv/<v>/alive/<component>            liveliness tokens
    auv/<v>/config/<component>           queryable: the running configuration (JSON)
    auv/<v>/truth/<what>                 simulation ground truth (JSON)

The schema version (``SCHEMA_VERSION``) is carried in every JSON payload's encoding schema
(``auvgw/1/Ensemble``) and in the ``v`` key of the envelope, so consumers can reject payloads they
do not understand without guessing from the key.
"""

from __future__ import annotations

import contextlib
import json
import struct
import sys
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import zenoh

from auvgw.config.bus import BusConfig
from auvgw.drivers.spec import to_jsonable

__all__ = [
    "RAW_ATTACHMENT",
    "SCHEMA_VERSION",
    "BusConfig",
    "Envelope",
    "InputWatch",
    "Keys",
    "add_bus_arguments",
    "bus_from_args",
    "decode_envelope",
    "encode_envelope",
    "json_encoding",
    "open_session",
    "pack_raw_attachment",
    "raw_encoding",
    "undeclare",
    "unpack_raw_attachment",
    "wire_format_of",
]

SCHEMA_VERSION = 1
#: attachment of a raw frame: host receive time (ns since the Unix epoch), per-device sequence,
#: stream byte offset of the frame's first byte
RAW_ATTACHMENT = struct.Struct("<qQQ")


def undeclare(entities: Iterable[Any]) -> None:
    """Undeclare Zenoh entities (publishers, subscribers, queryables, tokens), ignoring the ones a
    closing session has already dropped."""
    for e in entities:
        with contextlib.suppress(zenoh.ZError):
            e.undeclare()


def open_session(cfg: BusConfig | None = None) -> zenoh.Session:
    """Open a Zenoh session; close it (``with`` or ``finally``) or the process hangs at exit."""
    conf = zenoh.Config()
    for key, value in (cfg or BusConfig()).zenoh_json5().items():
        conf.insert_json5(key, value)
    return zenoh.open(conf)


@dataclass(frozen=True)
class Keys:
    """Key expressions of one vehicle (see the module docstring)."""

    vehicle: str
    root: str = "auv"

    @property
    def base(self) -> str:
        return f"{self.root}/{self.vehicle}"

    def raw(self, device: str) -> str:
        return f"{self.base}/raw/{device}"

    def sensor(self, device: str, kind: str) -> str:
        return f"{self.base}/sensor/{device}/{kind}"

    def odometry(self) -> str:
        return f"{self.base}/nav/odometry"

    def slam(self, pipeline: str, what: str) -> str:
        return f"{self.base}/slam/{pipeline}/{what}"

    def status(self, component: str) -> str:
        return f"{self.base}/status/{component}"

    def alive(self, component: str) -> str:
        return f"{self.base}/alive/{component}"

    def config(self, component: str) -> str:
        return f"{self.base}/config/{component}"

    def truth(self, what: str) -> str:
        return f"{self.base}/truth/{what}"

    def all(self, section: str = "**") -> str:
        return f"{self.base}/{section}"


def pack_raw_attachment(t_recv_ns: int, seq: int, offset: int = 0) -> bytes:
    return RAW_ATTACHMENT.pack(t_recv_ns, seq, offset)


def unpack_raw_attachment(data: bytes) -> tuple[int, int, int]:
    """(t_recv_ns, seq, stream offset) of a raw frame's attachment."""
    return RAW_ATTACHMENT.unpack(data)


def raw_encoding(wire_format: str) -> zenoh.Encoding:
    """Encoding of a raw frame: octets, schema ``auvgw/<v>/raw/<wire format>`` (``pd0``,
    ``hn100``, ``can``, ...), so a consumer knows the bytes without the gateway configuration."""
    return zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(
        f"auvgw/{SCHEMA_VERSION}/raw/{wire_format}"
    )


def wire_format_of(encoding: str) -> str:
    """The wire format named by a raw frame's encoding string ('' when it names none)."""
    _, _, schema = encoding.partition(";")
    head, sep, fmt = schema.rpartition("/raw/")
    return fmt if sep and head.startswith("auvgw/") else ""


def json_encoding(type_name: str) -> zenoh.Encoding:
    return zenoh.Encoding.APPLICATION_JSON.with_schema(f"auvgw/{SCHEMA_VERSION}/{type_name}")


@dataclass(frozen=True)
class Envelope:
    """A decoded message as it travels: its type name, source device, host receive time (ns
    since the Unix epoch), the sequence of the raw frame it came from, the message's JSON body
    (SI units) and, where rebuilt (:mod:`auvgw.subscribe`), the typed immutable ``message``."""

    type: str
    device: str
    t_recv_ns: int
    seq: int
    body: Mapping[str, Any] = field(default_factory=dict)
    message: Any = None
    key: str = ""


def encode_envelope(
    msg: Any, device: str, t_recv_ns: int, seq: int, body: Mapping[str, Any] | None = None
) -> tuple[bytes, zenoh.Encoding]:
    """JSON payload and encoding of a decoded message (``body`` overrides the message dict)."""
    d = dict(body) if body is not None else to_jsonable(msg)
    type_name = d.pop("type", type(msg).__name__)
    env = {
        "v": SCHEMA_VERSION,
        "type": type_name,
        "device": device,
        "t_recv_ns": t_recv_ns,
        "seq": seq,
        "msg": d,
    }
    return json.dumps(env, separators=(",", ":")).encode(), json_encoding(type_name)


def decode_envelope(payload: bytes, key: str = "") -> Envelope:
    """Parse a JSON envelope; raises ValueError on another schema version."""
    env = json.loads(payload)
    if env.get("v") != SCHEMA_VERSION:
        raise ValueError(f"payload schema version {env.get('v')!r}, expected {SCHEMA_VERSION}")
    return Envelope(env["type"], env["device"], env["t_recv_ns"], env["seq"], env["msg"], key=key)


class InputWatch:
    """Says on stderr, once per key, when no sample arrived on an input key expression within
    ``bus.no_publisher_after_s`` seconds (naming the key and the bus endpoints), so a stage
    started without a gateway does not wait silently. A key's subscription is dropped at its
    first sample; :attr:`silent` lists the keys that never had one."""

    def __init__(
        self, session: zenoh.Session, keys: Iterable[str], what: str, bus: BusConfig
    ) -> None:
        self.what = what
        self.bus = bus
        self.silent: set[str] = set(keys)
        self._lock = threading.Lock()
        self._subs = {k: session.declare_subscriber(k, self._seen(k)) for k in self.silent}
        self._timer = threading.Timer(bus.no_publisher_after_s, self._report)
        self._timer.daemon = True
        self._timer.start()

    def _seen(self, key: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(_s: zenoh.Sample) -> None:
            with self._lock:
                self.silent.discard(key)

        return on_sample

    def _report(self) -> None:
        with self._lock:
            silent = sorted(self.silent)
        for key in silent:
            print(
                f"{self.what}: no publisher on {key} after {self.bus.no_publisher_after_s:g} s "
                f"(bus: {self.bus.describe()}); is the gateway (auvgw run) running there?",
                file=sys.stderr,
                flush=True,
            )
        with self._lock:
            heard = [k for k in self._subs if k not in self.silent]
        undeclare(self._subs.pop(k) for k in heard)

    def close(self) -> None:
        self._timer.cancel()
        undeclare(self._subs.values())
        self._subs.clear()


def add_bus_arguments(parser: Any) -> None:
    """``--mode/--connect/--listen`` options of a command that joins the bus."""
    from auvgw.config.bus import DEFAULT_ENDPOINT, ENDPOINT_ENV

    g = parser.add_argument_group(
        f"Zenoh bus (default: a peer meeting the gateway at {DEFAULT_ENDPOINT}, "
        f"or ${ENDPOINT_ENV}; docs/bus.md)"
    )
    g.add_argument("--mode", choices=("peer", "client"), default="peer", help="session mode")
    g.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable)",
    )


def bus_from_args(args: Any, hub: bool = False) -> BusConfig:
    """The :class:`BusConfig` of :func:`add_bus_arguments` options (raises ValueError, one line
    per problem). With no endpoint given, the one-machine default: listen on the default
    endpoint (``hub``: the gateway's role, e.g. ``auvgw replay``) or connect to it."""
    from pydantic import ValidationError

    try:
        bus = BusConfig(mode=args.mode, connect=args.connect, listen=args.listen)
        return bus.as_hub() if hub else bus.as_spoke()
    except ValidationError as exc:
        lines = []
        for e in exc.errors():
            opt = ".".join(str(p) for p in e["loc"]) or "bus"
            lines.append(f"--{opt}: {e['msg'].removeprefix('Value error, ')}")
        raise ValueError("\n".join(lines)) from exc
