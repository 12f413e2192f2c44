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

import json
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from auvgw.drivers.spec import to_jsonable

__all__ = [
    "RAW_ATTACHMENT",
    "SCHEMA_VERSION",
    "BusConfig",
    "Keys",
    "decode_envelope",
    "encode_envelope",
    "json_encoding",
    "open_session",
    "pack_raw_attachment",
    "unpack_raw_attachment",
]

SCHEMA_VERSION = 1
#: attachment of a raw frame: host receive time (ns since the Unix epoch), per-device sequence,
#: stream byte offset of the frame's first byte
RAW_ATTACHMENT = struct.Struct("<qQQ")


class BusConfig(BaseModel):
    """How this process joins the Zenoh network.

    ``peer`` (default) with explicit ``listen``/``connect`` endpoints; ``client`` connects to a
    router (``connect`` must name it); ``router`` is what ``auvgw router`` runs. Multicast scouting
    is off unless asked for; gossip is on so peers behind a router find each other.
    """

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=list, description="e.g. tcp/127.0.0.1:7447")
    connect: list[str] = Field(default_factory=list, description="e.g. tcp/192.168.1.10:7447")
    multicast_scouting: bool = False
    gossip: bool = True

    def zenoh_config(self) -> zenoh.Config:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        conf.insert_json5("scouting/gossip/enabled", json.dumps(self.gossip))
        return conf


def open_session(cfg: BusConfig | None = None) -> zenoh.Session:
    """Open a Zenoh session; close it (``with`` or ``finally``) or the process hangs at exit."""
    return zenoh.open((cfg or BusConfig()).zenoh_config())


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
    """A decoded message as it travels: source device, receive time, sequence, device message."""

    type: str
    device: str
    t_recv_ns: int
    seq: int
    body: Mapping[str, Any] = field(default_factory=dict)
    message: Any = None


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


def decode_envelope(payload: bytes) -> Envelope:
    """Parse a JSON envelope; raises ValueError on another schema version."""
    env = json.loads(payload)
    if env.get("v") != SCHEMA_VERSION:
        raise ValueError(f"payload schema version {env.get('v')!r}, expected {SCHEMA_VERSION}")
    return Envelope(env["type"], env["device"], env["t_recv_ns"], env["seq"], env["msg"])
