"""The bus served to the Foxglove app, live, over the Foxglove WebSocket protocol.

:class:`FoxgloveStage` is a :class:`~auvgw.stages.ros2.RosStage` whose sink is a Foxglove
WebSocket server (the ``foxglove-sdk`` package: its server speaks the protocol, advertises
channels, answers subscriptions): one channel per ROS 2 topic, with the same schemas as the MCAP
recordings (``ros2msg`` definitions, ``cdr`` messages), so the Foxglove app decodes them with its
ROS 2 decoder and ``config/foxglove-layout.json`` opens the same views on a file and on the live
vehicle. Messages are logged with their stamps (``log_time``: the gateway's receive time,
vehicle-paced under a ``[clock]``).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, ClassVar

import zenoh

from auvgw import ros2
from auvgw.bus import Keys
from auvgw.stages.base import OnPublish
from auvgw.stages.ros2 import Ros2BridgeConfig, RosStage

if TYPE_CHECKING:
    import foxglove

__all__ = ["FoxgloveStage"]

log = logging.getLogger(__name__)


class FoxgloveStage(RosStage):
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free one, see :attr:`port`)
    fed from the bus (``session``) or in-process (:meth:`handle_sample`)."""

    name: ClassVar[str] = "foxglove"
    status_schema: ClassVar[str | None] = "FoxgloveStatus"

    def __init__(self, config: Ros2BridgeConfig, session: zenoh.Session | None = None, *,
                 host: str = "127.0.0.1", port: int = 8765,
                 sections: tuple[str, ...] = RosStage.SECTIONS, on_publish: OnPublish | None = None,
                 keys: Keys | None = None) -> None:  # fmt: skip
        import foxglove

        super().__init__(config, session, sections=sections, on_publish=on_publish, keys=keys)
        self._fg = foxglove
        self._context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self._server: foxglove.WebSocketServer | None = None
        self.host, self.port = host, port

    def status_fields(self) -> dict[str, object]:
        return {"host": self.host, "port": self.port, "topics": sorted(self._channels)}

    def put(self, m: ros2.RosMessage, t_ns: int) -> None:
        """Log ``m`` on its topic's channel (declared, with its ``ros2msg`` schema, the first
        time)."""
        topic = self.topic(m.topic)
        ch = self._channels.get(topic)
        if ch is None:
            schema = self._fg.Schema(name=m.type, encoding="ros2msg",
                                     data=ros2.msgdef(m.type).encode())  # fmt: skip
            ch = self._channels[topic] = self._fg.Channel(
                topic, schema=schema, message_encoding="cdr", context=self._context
            )
        ch.log(ros2.serialize(m), log_time=max(0, t_ns))
        self.count(m, topic)

    def on_start(self, subscribe: bool) -> None:
        """The server first (it takes clients from then on; stopped at :meth:`stop`, after the
        last status), then ``/tf_static``."""
        self.start_server()
        super().on_start(subscribe)

    def start_server(self) -> None:
        """Start the WebSocket server (idempotent; stopped at :meth:`stop`); :attr:`port` is then
        the bound port."""
        if self._server is None:
            self._server = self._fg.start_server(name=f"auvgw {self.keys.vehicle}",
                                                 host=self.host, port=self.port,
                                                 context=self._context)  # fmt: skip
            self.port = int(self._server.port)
            self.keep(_Stopping(self._server))


class _Stopping:
    """A server (anything with ``stop()``) as a declaration :meth:`Stage.keep` withdraws."""

    def __init__(self, server: foxglove.WebSocketServer) -> None:
        self.server = server

    def undeclare(self) -> None:
        self.server.stop()
