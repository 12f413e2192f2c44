"""ROS 2's names on Zenoh, the way ``rmw_zenoh_cpp`` writes them (no Zenoh session here).

The specification is rmw_zenoh's ``docs/design.md`` ("Topic and Service name mapping to Zenoh key
expressions", "Graph Cache") and its ``attachment_helpers.cpp``; what it leaves open is said
where it is decided. See docs/ros2.md.

* **Data**: ``<domain_id>/<fully qualified topic, no leading slash>/<DDS type>/<type hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``; the payload is the CDR
  message (little endian, with its 4-byte encapsulation header), the attachment
  :func:`pack_attachment`.
* **Type hash**: RIHS01 (REP 2016), the SHA-256 of the type's description, computed from the
  message definitions by ``rosbags`` (:func:`type_hash`), never written down here.
* **Liveliness tokens** (the ROS graph):
  ``@ros2_lv/<domain>/<session id>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>`` for a
  node, ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/MP/<enclave>/<namespace>/<node>/
  <topic>/<DDS type>/<type hash>/<qos>`` for a publisher (``MS`` subscription, ``SS`` / ``SC``
  services); names mangled (``/`` -> ``%``), ``%`` alone for an empty namespace or enclave.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from functools import cache
from typing import Any

__all__ = [
    "ADMIN_SPACE",
    "ENTITY_KINDS",
    "GID_SIZE",
    "Entity",
    "Qos",
    "data_key",
    "dds_type_name",
    "entity_gid",
    "mangle",
    "node_token",
    "pack_attachment",
    "parse_token",
    "ros_type_name",
    "topic_token",
    "type_hash",
    "unmangle",
    "unpack_attachment",
]

#: the hermetic prefix of the graph's liveliness tokens
ADMIN_SPACE = "@ros2_lv"
#: entity kinds of a token: node, message publisher / subscription, service server / client
ENTITY_KINDS = ("NN", "MP", "MS", "SS", "SC")
#: bytes of a GID (``RMW_GID_STORAGE_SIZE`` since ROS 2 Iron)
GID_SIZE = 16
#: the attachment: sequence number (int64), source timestamp (int64, ns), source GID (16 bytes),
#: as zenoh-ext's serializer writes them (integers little endian; a fixed-size array is its
#: elements with no length prefix, as a tuple is)
_ATTACHMENT = struct.Struct(f"<qq{GID_SIZE}s")


def mangle(name: str) -> str:
    """A ROS name in a token chunk: every ``/`` as ``%`` (``%`` alone for the empty name)."""
    return name.replace("/", "%") if name else "%"


def unmangle(chunk: str) -> str:
    """The inverse of :func:`mangle` (``%`` alone is the empty name)."""
    return "" if chunk == "%" else chunk.replace("%", "/")


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/Imu`` -> ``sensor_msgs::msg::dds_::Imu_`` (the name in DDS, which
    rmw_zenoh keeps in its keys)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> str:
    """The inverse of :func:`dds_type_name`."""
    pkg, kind, dds, name = dds_type.split("::")
    if dds != "dds_" or not name.endswith("_"):
        raise ValueError(f"not a DDS type name: {dds_type!r}")
    return f"{pkg}/{kind}/{name[:-1]}"


@cache
def _hash_store() -> Any:
    """The rosbags type store whose definitions give the hashes: ROS 2 Jazzy (the first release
    with rmw_zenoh), with auvgw's own types (:mod:`auvgw.ros2`) registered."""
    from rosbags.typesys import Stores, get_typestore

    from auvgw import ros2

    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(ros2.auvgw_types())
    return ts


@cache
def type_hash(ros_type: str) -> str:
    """The RIHS01 type hash of ``ros_type`` (``RIHS01_`` and 64 hex digits), computed from its
    type description (REP 2016) by ``rosbags``; a ``KeyError`` for a type it does not know."""
    return str(_hash_store().hash_rihs01(ros_type))


def data_key(domain_id: int, topic: str, ros_type: str) -> str:
    """The key expression of the data of ``topic`` (fully qualified, ``/`` first)."""
    if not topic.startswith("/"):
        raise ValueError(f"topic {topic!r} is not fully qualified (starts with /)")
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash(ros_type)}"


@dataclass(frozen=True)
class Qos:
    """The QoS of an endpoint as rmw_zenoh's token carries it (rmw enums: reliability 1
    reliable, 2 best effort; durability 1 transient local, 2 volatile; history 1 keep last,
    2 keep all); rmw_zenoh's defaults (reliable, volatile, keep last, depth 42) are written as
    empty fields."""

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 42

    def keyexpr(self) -> str:
        """``<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>``
        with each field equal to the default left empty (rmw_zenoh's ``qos_to_keyexpr``)."""
        d = Qos()

        def f(value: int, default: int) -> str:
            return "" if value == default else str(value)

        return (f"{f(self.reliability, d.reliability)}:{f(self.durability, d.durability)}:"
                f"{f(self.history, d.history)},{f(self.depth, d.depth)}:,:,:,,")  # fmt: skip

    @classmethod
    def parse(cls, text: str) -> Qos:
        """The inverse of :meth:`keyexpr` (deadline, lifespan and liveliness not kept)."""
        parts = text.split(":")
        if len(parts) != 6:
            raise ValueError(f"QoS {text!r}: expected 6 ':' fields")
        hist, _, depth = parts[2].partition(",")
        d = cls()
        return cls(int(parts[0] or d.reliability), int(parts[1] or d.durability),
                   int(hist or d.history), int(depth or d.depth))  # fmt: skip


#: sensor data: best effort, volatile, keep last 5 (rclcpp's SensorDataQoS)
SENSOR_QOS = Qos(reliability=2, depth=5)
#: ``/tf_static``: reliable, transient local, keep last 1 (tf2's StaticTransformBroadcaster)
STATIC_QOS = Qos(durability=1, depth=1)
#: everything else: reliable, volatile, keep last 10 (rclcpp's default)
DEFAULT_QOS = Qos(depth=10)


def node_token(domain_id: int, session_id: str, node_id: int, namespace: str, node: str,
               enclave: str = "") -> str:  # fmt: skip
    """The liveliness token of a node."""
    return (f"{ADMIN_SPACE}/{domain_id}/{session_id}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
            f"{mangle(namespace)}/{node}")  # fmt: skip


def topic_token(domain_id: int, session_id: str, node_id: int, entity_id: int, kind: str,
                namespace: str, node: str, topic: str, ros_type: str, qos: Qos,
                enclave: str = "") -> str:  # fmt: skip
    """The liveliness token of a publisher (``kind`` ``MP``) or subscription (``MS``) of ``topic``
    (fully qualified)."""
    if kind not in ("MP", "MS"):
        raise ValueError(f"entity kind {kind!r}: MP or MS")
    return (f"{ADMIN_SPACE}/{domain_id}/{session_id}/{node_id}/{entity_id}/{kind}/"
            f"{mangle(enclave)}/{mangle(namespace)}/{node}/{mangle(topic)}/"
            f"{dds_type_name(ros_type)}/{type_hash(ros_type)}/{qos.keyexpr()}")  # fmt: skip


@dataclass(frozen=True)
class Entity:
    """One entity of the graph, parsed from its liveliness token (:func:`parse_token`)."""

    domain_id: int
    session_id: str
    node_id: int
    entity_id: int
    kind: str  #: NN, MP, MS, SS or SC
    enclave: str
    namespace: str
    node: str
    topic: str = ""  #: fully qualified topic or service ("" for a node)
    type: str = ""  #: ROS type name (``sensor_msgs/msg/Imu``)
    type_hash: str = ""
    qos: Qos | None = None

    @property
    def node_name(self) -> str:
        """The node's fully qualified name (``/ns/node``)."""
        return f"{self.namespace.rstrip('/')}/{self.node}" if self.namespace else f"/{self.node}"


def parse_token(key: str) -> Entity:
    """The entity a liveliness token names; a ``ValueError`` naming what is wrong."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        raise ValueError(f"{key!r}: not an {ADMIN_SPACE} token of at least 9 chunks")
    kind = parts[5]
    if kind not in ENTITY_KINDS:
        raise ValueError(f"{key!r}: entity kind {kind!r} is not one of {ENTITY_KINDS}")
    try:
        domain, node_id, entity_id = int(parts[1]), int(parts[3]), int(parts[4])
    except ValueError:
        raise ValueError(f"{key!r}: domain, node and entity ids must be integers") from None
    base = dict(domain_id=domain, session_id=parts[2], node_id=node_id, entity_id=entity_id,
                kind=kind, enclave=unmangle(parts[6]), namespace=unmangle(parts[7]),
                node=parts[8])  # fmt: skip
    if kind == "NN":
        if len(parts) != 9:
            raise ValueError(f"{key!r}: a node token has 9 chunks, not {len(parts)}")
        return Entity(**base)  # type: ignore[arg-type]
    if len(parts) != 13:
        raise ValueError(f"{key!r}: an endpoint token has 13 chunks, not {len(parts)}")
    return Entity(**base, topic=unmangle(parts[9]), type=ros_type_name(parts[10]),  # type: ignore[arg-type]
                  type_hash=parts[11], qos=Qos.parse(parts[12]))  # fmt: skip


def entity_gid(token: str) -> bytes:
    """A GID for the endpoint of ``token`` (its first 16 SHA-256 bytes: unique per session,
    node and entity, stable for a run)."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


def pack_attachment(seq: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The attachment of a published message: sequence number, source time (ns), GID."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return _ATTACHMENT.pack(seq, source_timestamp_ns, gid)


def unpack_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns, GID) of an attachment; a ``ValueError`` if it is
    not the 32 bytes of :func:`pack_attachment`."""
    if len(data) != _ATTACHMENT.size:
        raise ValueError(f"attachment of {len(data)} bytes, expected {_ATTACHMENT.size}")
    seq, t_ns, gid = _ATTACHMENT.unpack(data)
    return int(seq), int(t_ns), bytes(gid)
