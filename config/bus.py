"""Zenoh session settings (mode and endpoints); used by the gateway and every bus stage."""

from __future__ import annotations

import json
import os
import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = [
    "DEFAULT_ENDPOINT",
    "ENDPOINT_ENV",
    "NO_PUBLISHER_AFTER_S",
    "STAGE_LISTEN",
    "BusConfig",
    "default_endpoint",
]

#: where ``auvgw run`` listens and every other command connects when told nothing (one machine)
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: environment variable replacing :data:`DEFAULT_ENDPOINT` (e.g. two vehicles on one desk, tests)
ENDPOINT_ENV = "AUVGW_BUS_ENDPOINT"
#: a stage's own listen endpoint by default: loopback, any free port, so the gateway's gossip
#: lets the stages reach each other directly (Zenoh peers do not route between other peers)
STAGE_LISTEN = "tcp/127.0.0.1:0"
#: seconds without a sample on an input before a command says "no publisher" on stderr
NO_PUBLISHER_AFTER_S = 5.0


def default_endpoint() -> str:
    """The one-machine rendezvous endpoint: ``$AUVGW_BUS_ENDPOINT`` or :data:`DEFAULT_ENDPOINT`."""
    return os.environ.get(ENDPOINT_ENV) or DEFAULT_ENDPOINT


_ENDPOINT = re.compile(r"^[a-z][a-z0-9-]*/\S+$")


class BusConfig(BaseModel):
    """How this process joins the Zenoh network.

    ``peer`` (default) with explicit ``listen``/``connect`` endpoints; ``client`` connects to a
    router (``connect`` must name it); ``router`` is what ``auvgw router`` runs. Multicast scouting
    is off unless asked for; gossip is on so peers behind a router find each other. Endpoints are
    Zenoh locators, ``<protocol>/<address>``: ``tcp/127.0.0.1:7447``, ``tcp/[::1]:7447``,
    ``udp/10.0.0.2:7447``. A peer told no endpoint meets the others on one machine through
    :func:`default_endpoint` (:meth:`as_hub` for the gateway, :meth:`as_spoke` for the rest;
    docs/bus.md#finding-each-other).
    """

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=list, description="e.g. tcp/127.0.0.1:7447")
    connect: list[str] = Field(default_factory=list, description="e.g. tcp/192.168.1.10:7447")
    multicast_scouting: bool = False
    gossip: bool = True
    no_publisher_after_s: float = Field(
        NO_PUBLISHER_AFTER_S, gt=0, description="say 'no publisher' after this many seconds"
    )

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

    @property
    def has_endpoints(self) -> bool:
        """Whether any listen or connect endpoint is configured."""
        return bool(self.listen or self.connect)

    def as_hub(self) -> BusConfig:
        """This configuration, or where it names no endpoint (a peer told nothing), a peer
        listening on :func:`default_endpoint`: what ``auvgw run`` and ``auvgw replay`` use."""
        if self.has_endpoints or self.mode != "peer":
            return self
        return self.model_copy(update={"listen": [default_endpoint()]})

    def as_spoke(self) -> BusConfig:
        """This configuration, or where it names no endpoint, a peer connecting to
        :func:`default_endpoint` (and listening on :data:`STAGE_LISTEN`): every other command."""
        if self.has_endpoints or self.mode != "peer":
            return self
        return self.model_copy(update={"connect": [default_endpoint()], "listen": [STAGE_LISTEN]})

    def describe(self) -> str:
        """One line: mode and endpoints, for messages."""
        parts = [f"mode {self.mode}"]
        if self.connect:
            parts.append("connect " + ", ".join(self.connect))
        if self.listen:
            parts.append("listen " + ", ".join(self.listen))
        return "; ".join(parts)

    def zenoh_json5(self) -> dict[str, str]:
        """Zenoh configuration entries (key path -> JSON5 value)."""
        return {
            "mode": json.dumps(self.mode),
            "listen/endpoints": json.dumps(self.listen),
            "connect/endpoints": json.dumps(self.connect),
            "scouting/multicast/enabled": json.dumps(self.multicast_scouting),
            "scouting/gossip/enabled": json.dumps(self.gossip),
        }
