"""Zenoh session settings (mode and endpoints); used by the gateway and every bus stage."""

from __future__ import annotations

import json
import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = ["BusConfig"]

_ENDPOINT = re.compile(r"^[a-z][a-z0-9-]*/\S+$")


class BusConfig(BaseModel):
    """How this process joins the Zenoh network.

    ``peer`` (default) with explicit ``listen``/``connect`` endpoints; ``client`` connects to a
    router (``connect`` must name it); ``router`` is what ``auvgw router`` runs. Multicast scouting
    is off unless asked for; gossip is on so peers behind a router find each other. Endpoints are
    Zenoh locators, ``<protocol>/<address>``: ``tcp/127.0.0.1:7447``, ``tcp/[::1]:7447``,
    ``udp/10.0.0.2:7447``.
    """

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=list, description="e.g. tcp/127.0.0.1:7447")
    connect: list[str] = Field(default_factory=list, description="e.g. tcp/192.168.1.10:7447")
    multicast_scouting: bool = False
    gossip: bool = True

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for e in v:
            if not _ENDPOINT.match(e):
                raise ValueError(
                    f"endpoint {e!r} is not '<protocol>/<address>' (e.g. 'tcp/127.0.0.1:7447')"
                )
        return v

    @model_validator(mode="after")
    def _reachable(self) -> BusConfig:
        if self.mode == "client" and not self.connect and not self.multicast_scouting:
            raise ValueError(
                "mode 'client' needs the router's endpoint in 'connect' "
                '(e.g. connect = ["tcp/192.168.1.10:7447"])'
            )
        return self

    def zenoh_json5(self) -> dict[str, str]:
        """Zenoh configuration entries (key path -> JSON5 value)."""
        return {
            "mode": json.dumps(self.mode),
            "listen/endpoints": json.dumps(self.listen),
            "connect/endpoints": json.dumps(self.connect),
            "scouting/multicast/enabled": json.dumps(self.multicast_scouting),
            "scouting/gossip/enabled": json.dumps(self.gossip),
        }
