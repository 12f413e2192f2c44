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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from auvgw.config.bus import BusConfig
from auvgw.drivers.spec import to_jsonable

__all__ = [
    "RAW_ATTACHMENT",
    "SCHEMA_VERSION",
    "BusConfig",
    "Envelope",
    "Keys",
    "add_bus_arguments",
    "bus_from_args",
    "decode_envelope",
    "encode_envelope",
    "json_encoding",
    "load_bus_table",
    "open_session",
    "pack_raw_attachment",
    "undeclare",
    "unpack_raw_attachment",
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


def add_bus_arguments(parser: Any) -> None:
    """``--mode/--connect/--listen`` options of a command that joins the bus."""
    g = parser.add_argument_group("Zenoh bus (default: a peer with no endpoints)")
    g.add_argument(
        "--bus-config",
        type=Path,
        default=None,
        metavar="TOML",
        help="take the [bus] table (endpoints, tls, auth, access_control) of this file, e.g. "
        "the gateway's configuration; --mode/--connect/--listen override it",
    )
    g.add_argument("--mode", choices=("peer", "client"), default=None, help="session mode")
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


def load_bus_table(path: Path) -> dict[str, Any]:
    """The ``[bus]`` table of a TOML file (empty if it has none); ValueError names the file."""
    import tomllib

    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"--bus-config {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"--bus-config {path}: not valid TOML ({exc})") from None
    table = data.get("bus", {})
    if not isinstance(table, dict):
        raise ValueError(f"--bus-config {path}: 'bus' is not a table")
    return table


def bus_from_args(args: Any) -> BusConfig:
    """The :class:`BusConfig` of :func:`add_bus_arguments` options (raises ValueError, one line
    per problem)."""
    from pydantic import ValidationError

    base: dict[str, Any] = {}
    path: Path | None = getattr(args, "bus_config", None)
    if path is not None:
        base = load_bus_table(path)
    given = {"mode": args.mode, "connect": args.connect, "listen": args.listen}
    try:
        cfg = BusConfig(**{**base, **{k: v for k, v in given.items() if v}})
        return cfg if path is None else cfg.rebased(path.resolve().parent)
    except ValidationError as exc:
        lines = []
        for e in exc.errors():
            opt = ".".join(str(p) for p in e["loc"]) or "bus"
            lines.append(f"--{opt}: {e['msg'].removeprefix('Value error, ')}")
        raise ValueError("\n".join(lines)) from exc
