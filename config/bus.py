"""Zenoh session settings (mode, endpoints, TLS, authentication, access control); used by the
gateway and every bus stage. Security settings are documented in docs/security.md."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from auvgw.ground.errors import ConfigError

__all__ = [
    "DEFAULT_ENDPOINT",
    "ENDPOINT_ENV",
    "NO_PUBLISHER_AFTER_S",
    "STAGE_LISTEN",
    "BusAuthConfig",
    "BusConfig",
    "BusTlsConfig",
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
#: strict types (no "yes" -> True), finite numbers, unknown keys refused
_STRICT = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)
_PATH = Field(None, max_length=4096)
#: most listen or connect endpoints of one session
MAX_ENDPOINTS = 32
#: Zenoh's transmission queue per link and data priority, in batches (Zenoh's default is 2:
#: 128 KiB, which a burst of multibeam pings overflows while its sending thread waits for a CPU,
#: and a ``CongestionControl.DROP`` sample then waits 1 ms and is dropped; 16 is 1 MiB, allocated
#: only when used). A subscriber that stops reading still costs its own link only.
TX_QUEUE_BATCHES = 16


def _rebase(value: str | None, base: Path) -> str | None:
    if value is None or Path(value).is_absolute():
        return value
    return str(base / value)


class BusTlsConfig(BaseModel):
    """TLS on ``tls/<host>:<port>`` endpoints (Zenoh ``transport/link/tls``). Paths are PEM files
    (relative ones resolve against the configuration file's folder). ``enable_mtls`` makes a
    listener demand a client certificate signed by ``root_ca_certificate``: the certificate's
    common name is then the identity access control rules match (``cert_common_names``)."""

    model_config = _STRICT

    root_ca_certificate: str = Field(
        max_length=4096, description="CA that signed the peers' certificates"
    )
    listen_certificate: str | None = _PATH
    listen_private_key: str | None = _PATH
    connect_certificate: str | None = _PATH
    connect_private_key: str | None = _PATH
    enable_mtls: bool = False
    verify_name_on_connect: bool = True

    @model_validator(mode="after")
    def _pairs(self) -> BusTlsConfig:
        for side in ("listen", "connect"):
            if (getattr(self, f"{side}_certificate") is None) != (
                getattr(self, f"{side}_private_key") is None
            ):
                raise ValueError(f"'{side}_certificate' and '{side}_private_key' go together")
        return self

    def rebased(self, base: Path) -> BusTlsConfig:
        return self.model_copy(
            update={k: _rebase(v, base) for k, v in self.model_dump().items() if isinstance(v, str)}
        )


class BusAuthConfig(BaseModel):
    """User/password authentication (Zenoh ``transport/auth/usrpwd``): ``user`` and ``password``
    (or ``password_file``, its first line) are what this session presents; ``dictionary_file``
    (``user:password`` lines) is what a listener accepts. The usernames are identities for access
    control (``usernames``). Passwords travel inside the link: use it with TLS."""

    model_config = _STRICT

    user: str | None = Field(None, max_length=256)
    password: str | None = Field(None, max_length=4096)
    password_file: str | None = _PATH
    dictionary_file: str | None = _PATH

    @model_validator(mode="after")
    def _one_password(self) -> BusAuthConfig:
        if self.password is not None and self.password_file is not None:
            raise ValueError("give 'password' or 'password_file', not both")
        if self.user is not None and self.password is None and self.password_file is None:
            raise ValueError(f"user {self.user!r} needs 'password' or 'password_file'")
        return self

    def rebased(self, base: Path) -> BusAuthConfig:
        return self.model_copy(
            update={
                "password_file": _rebase(self.password_file, base),
                "dictionary_file": _rebase(self.dictionary_file, base),
            }
        )

    def zenoh(self) -> dict[str, str]:
        out: dict[str, str] = {}
        password = self.password
        if self.password_file is not None:
            try:
                lines = Path(self.password_file).read_text().splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                why = exc.strerror if isinstance(exc, OSError) else "not a text (UTF-8) file"
                raise ConfigError(
                    f"bus.auth.password_file: {self.password_file}: cannot read: {why}"
                ) from None
            password = lines[0] if lines else ""
        if self.user is not None:
            out["user"] = self.user
            out["password"] = password or ""
        if self.dictionary_file is not None:
            out["dictionary_file"] = self.dictionary_file
        return out


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

    model_config = _STRICT

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(
        default_factory=list, max_length=MAX_ENDPOINTS, description="e.g. tcp/127.0.0.1:7447"
    )
    connect: list[str] = Field(
        default_factory=list, max_length=MAX_ENDPOINTS, description="e.g. tcp/192.168.1.10:7447"
    )
    multicast_scouting: bool = False
    gossip: bool = True
    tls: BusTlsConfig | None = None
    auth: BusAuthConfig | None = None
    access_control: dict[str, Any] | None = Field(
        None,
        description="Zenoh's access_control section (enabled, default_permission, rules, "
        "subjects, policies), passed as is; see docs/security.md",
    )
    tx_queue_batches: int = Field(
        TX_QUEUE_BATCHES, ge=1, le=64,
        description="Zenoh batches (64 KiB each) queued per link for each data priority before "
        "a DROP sample is dropped",
    )  # fmt: skip
    no_publisher_after_s: float = Field(
        NO_PUBLISHER_AFTER_S, ge=0.1, le=3600,
        description="say 'no publisher' after this many seconds",
    )  # fmt: skip

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for i, e in enumerate(v):
            if e in v[:i]:
                raise ValueError(f"endpoint {e!r} given twice")
            if len(e) > 512 or not _ENDPOINT.match(e):
                raise ValueError(
                    f"endpoint {e!r} is not '<protocol>/<address>' (e.g. 'tcp/127.0.0.1:7447')"
                )
        return v

    @model_validator(mode="after")
    def _reachable(self) -> BusConfig:
        secured = ("tls/", "quic/")
        if self.tls is not None and not any(e.startswith(secured)
                                            for e in (*self.listen, *self.connect)):  # fmt: skip
            raise ValueError(
                "[bus.tls] is set but no listen/connect endpoint uses tls/ (or quic/): the bus "
                "would run as plain TCP; give tls/<host>:<port> endpoints (docs/security.md)"
            )
        if self.mode == "client" and not self.connect and not self.multicast_scouting:
            raise ValueError(
                "mode 'client' needs the router's endpoint in 'connect' "
                '(e.g. connect = ["tcp/192.168.1.10:7447"])'
            )
        return self

    def rebased(self, base: Path) -> BusConfig:
        """This configuration with relative certificate, key and password paths resolved
        against ``base`` (the configuration file's folder)."""
        return self.model_copy(
            update={
                "tls": None if self.tls is None else self.tls.rebased(base),
                "auth": None if self.auth is None else self.auth.rebased(base),
            }
        )

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

    def open_beyond_loopback(self) -> list[str]:
        """The endpoints (and multicast scouting) through which a process on another machine
        could join this bus while it has neither TLS nor authentication: [] when it is safe."""
        if self.tls is not None or self.auth is not None:
            return []
        out = [e for e in (*self.listen, *self.connect) if not _loopback(e)]
        return out + (["multicast scouting"] if self.multicast_scouting else [])

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
        out = {
            "mode": json.dumps(self.mode),
            "listen/endpoints": json.dumps(self.listen),
            "connect/endpoints": json.dumps(self.connect),
            "scouting/multicast/enabled": json.dumps(self.multicast_scouting),
            "scouting/gossip/enabled": json.dumps(self.gossip),
        }
        for prio in ("data_high", "data", "data_low"):
            out[f"transport/link/tx/queue/size/{prio}"] = json.dumps(self.tx_queue_batches)
        if self.tls is not None:
            for k, v in self.tls.model_dump(exclude_none=True).items():
                out[f"transport/link/tls/{k}"] = json.dumps(v)
        if self.auth is not None:
            for k, v in self.auth.zenoh().items():
                out[f"transport/auth/usrpwd/{k}"] = json.dumps(v)
        if self.access_control is not None:
            out["access_control"] = json.dumps(self.access_control)
        return out


def _loopback(endpoint: str) -> bool:
    """Whether a Zenoh endpoint (``tcp/127.0.0.1:7447``, ``tcp/[::1]:7447``,
    ``tcp/localhost:7447``) is reachable from this machine only."""
    import ipaddress

    addr = endpoint.partition("/")[2].split("#", 1)[0]
    if addr.startswith("[") and "]" in addr:
        host = addr[1 : addr.index("]")]
    else:
        host = addr.rsplit(":", 1)[0]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may well be reachable from elsewhere
