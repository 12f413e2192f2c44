"""A ROS 2 graph reader for ``rmw_zenoh_cpp``, written from its design document alone.

:class:`Ros2Graph` asks the Zenoh session for the ``@ros2_lv`` liveliness tokens of a domain and
parses them (:func:`auvgw.rmw_zenoh.parse_token`) into nodes and their publishers and
subscriptions (topic, type, RIHS01 hash, QoS); :meth:`Ros2Graph.echo` subscribes to a topic's data
key (``<domain>/<topic>/<DDS type>/<hash>``, the hash the publisher's token gave) and decodes each
message's CDR with the ROS 2 type definitions (``rosbags``) and its attachment (sequence, source
time, GID). It is what ``ros2 node list``, ``ros2 topic list -t`` and ``ros2 topic echo`` do on
rmw_zenoh, and it is how the tests see the bridge as a ROS 2 user would
(``auvgw ros2 list``, ``auvgw ros2 echo``).
"""

from __future__ import annotations

import queue
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from auvgw.rmw_zenoh import (
    ADMIN_SPACE,
    Entity,
    dds_type_name,
    parse_token,
    unpack_attachment,
)

__all__ = ["Echoed", "Ros2Graph"]


@dataclass(frozen=True)
class Echoed:
    """One message taken off a topic: the decoded ROS 2 message, its attachment's sequence
    number, source time (ns) and publisher GID, and the key it came on."""

    msg: Any
    seq: int
    source_timestamp_ns: int
    gid: bytes
    key: str


class Ros2Graph:
    """The ROS 2 graph of ``domain_id`` seen through ``session`` (any Zenoh session that reaches
    the ROS 2 nodes' router or peers)."""

    def __init__(self, session: zenoh.Session, domain_id: int = 0) -> None:
        self.session = session
        self.domain_id = domain_id
        #: tokens that did not parse: (key, reason)
        self.unparsed: list[tuple[str, str]] = []

    def entities(self, timeout_s: float = 2.0) -> list[Entity]:
        """Every entity whose token is alive now (a liveliness query)."""
        out: list[Entity] = []
        self.unparsed.clear()
        replies = self.session.liveliness().get(f"{ADMIN_SPACE}/{self.domain_id}/**",
                                                timeout=timeout_s)  # fmt: skip
        for reply in replies:
            if reply.ok is None:
                continue
            key = str(reply.ok.key_expr)
            try:
                out.append(parse_token(key))
            except ValueError as exc:
                self.unparsed.append((key, str(exc)))
        return sorted(out, key=lambda e: (e.node_name, e.kind, e.topic))

    def nodes(self, timeout_s: float = 2.0) -> list[str]:
        """Fully qualified node names."""
        return sorted({e.node_name for e in self.entities(timeout_s) if e.kind == "NN"})

    def topics(self, timeout_s: float = 2.0) -> dict[str, tuple[str, str]]:
        """Topic -> (ROS type, type hash) of every publisher."""
        return {e.topic: (e.type, e.type_hash)
                for e in self.entities(timeout_s) if e.kind == "MP"}  # fmt: skip

    def echo(self, topic: str, count: int = 1, timeout_s: float = 10.0,
             graph_timeout_s: float = 2.0) -> list[Echoed]:  # fmt: skip
        """Up to ``count`` messages of ``topic`` within ``timeout_s`` (waits for the topic to
        appear in the graph first, within the same time); a ``LookupError`` if it never does."""
        from rosbags.typesys import Stores, get_typestore

        deadline = time.monotonic() + timeout_s
        found: tuple[str, str] | None = None
        while found is None:
            found = self.topics(graph_timeout_s).get(topic)
            if found is None:
                if time.monotonic() > deadline:
                    raise LookupError(f"no publisher of {topic} in ROS domain {self.domain_id}")
                time.sleep(0.1)
        ros_type, type_hash = found
        key = f"{self.domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"
        store = get_typestore(Stores.ROS2_JAZZY)
        q: queue.Queue[zenoh.Sample] = queue.Queue()
        sub = self.session.declare_subscriber(key, q.put)
        out: list[Echoed] = []
        try:
            while len(out) < count:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                try:
                    s = q.get(timeout=left)
                except queue.Empty:
                    break
                att = s.attachment.to_bytes() if s.attachment is not None else b""
                seq, t_ns, gid = unpack_attachment(att)
                msg = store.deserialize_cdr(s.payload.to_bytes(), ros_type)
                out.append(Echoed(msg, seq, t_ns, gid, str(s.key_expr)))
        finally:
            sub.undeclare()
        return out
