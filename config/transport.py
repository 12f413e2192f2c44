"""Transport settings: where a device's bytes come from (serial, CAN, UDP or a replayed file).

One pydantic model per kind, joined in :data:`TransportConfig`, a union discriminated on
``kind``. In a gateway configuration the table sits under a device, for example::

    [devices.dvl.transport]
    kind = "serial"
    url = "/dev/ttyUSB0"
    baud = 115200

These models only describe settings (each has ``describe()``, the one-line summary used in logs
and status); ``auvgw.drivers.transports.open_transport`` turns one into an
open transport (config never imports drivers). :func:`parse_transport_config` validates a plain
mapping (e.g. a TOML table) and raises :class:`TransportConfigError` whose lines each name the
field, what was expected and what was given. Units are in the field names: ``_s`` seconds,
``baud`` bit/s, ``byte_rate`` byte/s, ``bitrate`` CAN bit/s.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)

from auvgw.ground.errors import ConfigError
from auvgw.ground.errors import format_validation_error as format_errors

__all__ = [
    "CanFilter",
    "CanTransportConfig",
    "FileTransportConfig",
    "SerialTransportConfig",
    "TransportConfig",
    "TransportConfigError",
    "UdpTransportConfig",
    "format_validation_error",
    "parse_transport_config",
]

#: largest 11-bit (standard) and 29-bit (extended) CAN identifiers
CAN_STD_MAX = 0x7FF
CAN_EXT_MAX = 0x1FFFFFFF

#: replay chunk when none is configured: 4096 bytes unpaced, 10 ms of bytes paced
DEFAULT_REPLAY_CHUNK = 4096
PACED_CHUNK_S = 0.010
#: python-can interfaces whose ``channel`` cannot be left out
_CHANNEL_REQUIRED = frozenset({"socketcan", "slcan", "udp_multicast", "serial", "socketcand"})
#: can.Bus arguments set by named fields; ``options`` may not override them
_CAN_RESERVED = frozenset(
    {"interface", "channel", "bitrate", "data_bitrate", "fd", "can_filters", "receive_own_messages"}
)


class TransportConfigError(ConfigError):
    """Invalid transport settings; one line per problem, each naming the field."""


#: upper bounds of values that reach a reader thread: a chunk or buffer this size is allocated
#: per read, a rate or timeout past them is a misprint (docs/gateway.md#limits)
MAX_CHUNK_BYTES = 1 << 20
MAX_RECEIVE_BUFFER_BYTES = 1 << 27
MAX_TIMEOUT_S = 3600.0
MAX_TEXT = 4096


class _Model(BaseModel):
    # strict: no "yes" -> True, "3" -> 3 or 3.0 -> 3; every number finite
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class SerialTransportConfig(_Model):
    """A serial port or any pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/7``, ``socket://h:p``,
    ``loop://``, ``rfc2217://h:p``), opened with ``serial.serial_for_url``.

    ``baud`` is the line rate in bit/s (ignored by ptys, sockets and ``loop://``).
    """

    kind: Literal["serial"] = "serial"
    url: str = Field(min_length=1, max_length=MAX_TEXT, description="device path or pyserial URL")
    baud: int = Field(115200, ge=50, le=20_000_000, description="line rate, bit/s")
    bytesize: Literal[5, 6, 7, 8] = 8
    parity: Literal["N", "E", "O", "M", "S"] = "N"
    stopbits: Literal[1, 1.5, 2] = 1  # type: ignore[valid-type]  # pydantic takes 1.5; PEP 586 not
    rtscts: bool = Field(False, description="RTS/CTS hardware flow control")
    xonxoff: bool = Field(False, description="XON/XOFF software flow control")
    exclusive: bool = Field(True, description="lock the port against other processes (POSIX)")
    write_timeout_s: float | None = Field(
        1.0, ge=0, le=MAX_TIMEOUT_S,
        description="a write blocked longer than this fails; None waits forever",
    )  # fmt: skip
    max_chunk: int = Field(
        65536, ge=1, le=MAX_CHUNK_BYTES, description="most bytes returned by one read"
    )

    @field_validator("url")
    @classmethod
    def _strip(cls, v: str) -> str:
        v = v.strip()
        if not v:
            raise ValueError("must name a device path or pyserial URL, e.g. '/dev/ttyUSB0'")
        return v

    def describe(self) -> str:
        """One line for logs and status, e.g. ``serial /dev/ttyUSB0 115200 baud 8N1``."""
        stop = int(self.stopbits) if self.stopbits in (1, 2) else self.stopbits
        return f"serial {self.url} {self.baud} baud {self.bytesize}{self.parity}{stop}"


class CanFilter(_Model):
    """Accept frames whose ``arbitration_id & can_mask == can_id & can_mask``.

    ``extended`` True/False also requires the frame's id type; None accepts both. The default
    mask compares every id bit (``0x7FF`` for standard ids, ``0x1FFFFFFF`` otherwise).
    """

    can_id: int = Field(ge=0, le=CAN_EXT_MAX)
    can_mask: int | None = Field(None, ge=0, le=CAN_EXT_MAX)
    extended: bool | None = None

    @model_validator(mode="after")
    def _id_fits(self) -> CanFilter:
        if self.extended is False and self.can_id > CAN_STD_MAX:
            raise ValueError(
                f"can_id 0x{self.can_id:X} does not fit an 11-bit standard id "
                f"(max 0x{CAN_STD_MAX:X}); set extended = true"
            )
        return self

    def as_python_can(self) -> dict[str, Any]:
        """The filter as python-can's ``can_filters`` entry."""
        mask = self.can_mask
        if mask is None:
            mask = CAN_STD_MAX if self.extended is False else CAN_EXT_MAX
        out: dict[str, Any] = {"can_id": self.can_id, "can_mask": mask}
        if self.extended is not None:
            out["extended"] = self.extended
        return out


class CanTransportConfig(_Model):
    """A python-can bus: ``can.Bus(interface=..., channel=..., bitrate=...)``.

    Examples: ``socketcan``/``vcan0``, ``slcan``/``/dev/pts/8`` (a USB-CAN adapter speaking
    Lawicel ASCII), ``virtual`` (in-process), ``udp_multicast``/``239.74.163.2``. ``bitrate`` is
    the CAN bit rate in bit/s. ``tx_id``/``tx_extended`` give the identifier used by plain
    ``write(data)``. ``options`` are passed to ``can.Bus`` unchanged (e.g. ``sleep_after_open``
    or ``tty_baudrate`` for slcan, ``port`` for udp_multicast).
    """

    kind: Literal["can"] = "can"
    interface: str = Field(min_length=1, max_length=64, description="python-can interface name")
    channel: (
        Annotated[str, Field(max_length=MAX_TEXT)] | Annotated[int, Field(ge=0, le=1 << 16)] | None
    ) = None
    bitrate: int | None = Field(None, ge=1000, le=1_000_000, description="CAN bit rate, bit/s")
    fd: bool = Field(False, description="CAN FD frames (up to 64 data bytes)")
    data_bitrate: int | None = Field(
        None, ge=1000, le=16_000_000, description="CAN FD data phase bit rate, bit/s"
    )
    filters: list[CanFilter] = Field(default_factory=list, max_length=64)
    receive_own_messages: bool = False
    tx_id: int | None = Field(None, ge=0, le=CAN_EXT_MAX, description="id used by write(data)")
    tx_extended: bool | None = Field(None, description="whether tx_id is a 29-bit id")
    send_timeout_s: float | None = Field(
        1.0, ge=0, le=MAX_TIMEOUT_S,
        description="a send blocked longer than this fails; None waits forever",
    )  # fmt: skip
    options: dict[str, Annotated[str, Field(max_length=MAX_TEXT)] | int | float | bool] = Field(
        default_factory=dict, max_length=32
    )

    @field_validator("interface")
    @classmethod
    def _known_interface(cls, v: str) -> str:
        import can  # python-can; imported here so loading config stays light

        if v not in can.VALID_INTERFACES:
            known = ", ".join(sorted(can.VALID_INTERFACES))
            raise ValueError(f"unknown python-can interface {v!r}; known: {known}")
        return v

    @field_validator("options")
    @classmethod
    def _no_reserved(cls, v: dict[str, Any]) -> dict[str, Any]:
        clash = sorted(_CAN_RESERVED & v.keys())
        if clash:
            raise ValueError(f"set {', '.join(clash)} as transport fields, not in options")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> CanTransportConfig:
        if self.interface in _CHANNEL_REQUIRED and self.channel in (None, ""):
            raise ValueError(
                f"'channel' is required for interface {self.interface!r} "
                "(e.g. 'vcan0', '/dev/ttyACM0', a multicast group)"
            )
        if self.data_bitrate is not None and not self.fd:
            raise ValueError("'data_bitrate' needs fd = true")
        if (self.tx_id is None) != (self.tx_extended is None):
            raise ValueError("'tx_id' and 'tx_extended' go together (is_extended_id is explicit)")
        if self.tx_id is not None and self.tx_extended is False and self.tx_id > CAN_STD_MAX:
            raise ValueError(
                f"'tx_id' 0x{self.tx_id:X} does not fit an 11-bit standard id; "
                "set tx_extended = true"
            )
        return self

    @property
    def port(self) -> str:
        """``interface:channel`` (or the interface alone without a channel)."""
        return self.interface if self.channel is None else f"{self.interface}:{self.channel}"

    def describe(self) -> str:
        """One line for logs and status, e.g. ``can slcan:/dev/pts/8 500000 bit/s``."""
        out = f"can {self.port}"
        if self.bitrate:
            out += f" {self.bitrate} bit/s"
        if self.fd:
            out += " FD"
        if self.filters:
            out += f" {len(self.filters)} filter(s)"
        return out


_HOSTNAME = re.compile(r"[A-Za-z0-9_-]{1,63}(\.[A-Za-z0-9_-]{1,63})*\.?")


def _ipv4(v: str, what: str) -> ipaddress.IPv4Address:
    try:
        return ipaddress.IPv4Address(v)
    except ValueError:
        raise ValueError(f"{what} must be an IPv4 address, got {v!r}") from None


class UdpTransportConfig(_Model):
    """A UDP socket bound to ``host:port``; one datagram is one chunk.

    ``multicast_group`` joins an IPv4 multicast group on ``multicast_interface`` (the address of
    the local interface; ``0.0.0.0`` lets the kernel choose). Writes go to ``remote_host:
    remote_port`` if set, else to the sender of the last datagram received. ``port = 0`` binds
    an ephemeral port.
    """

    kind: Literal["udp"] = "udp"
    host: str = Field("0.0.0.0", min_length=1, max_length=255, description="local address to bind")
    port: int = Field(ge=0, le=65535, description="local port to bind")
    multicast_group: str | None = Field(None, max_length=64)
    multicast_interface: str = Field("0.0.0.0", max_length=64)
    reuse_address: bool | None = Field(
        None, description="SO_REUSEADDR; default on when joining a multicast group"
    )
    remote_host: str | None = Field(None, max_length=255)
    remote_port: int | None = Field(None, ge=1, le=65535)
    receive_buffer_bytes: int | None = Field(
        None,
        ge=1024,
        le=MAX_RECEIVE_BUFFER_BYTES,
        description="SO_RCVBUF, bytes; the kernel caps it at net.core.rmem_max",
    )
    allowed_senders: list[Annotated[str, Field(max_length=64)]] | None = Field(
        None,
        max_length=256,
        description="addresses or networks (10.0.0.5, 10.0.0.0/24, ::1) whose datagrams are "
        "read, or ['any']; default: remote_host if set, else any sender",
    )

    @field_validator("host", "remote_host")
    @classmethod
    def _host(cls, v: str | None) -> str | None:
        if v is None:
            return v
        try:
            ipaddress.ip_address(v)
        except ValueError:
            if len(v) > 253 or not _HOSTNAME.fullmatch(v):
                raise ValueError(
                    f"{v!r:.60} is neither an IP address nor a host name (ASCII labels of 1-63 "
                    "letters, digits or '-', joined by '.')"
                ) from None
        return v

    @field_validator("multicast_group")
    @classmethod
    def _multicast(cls, v: str | None) -> str | None:
        if v is not None and not _ipv4(v, "multicast_group").is_multicast:
            raise ValueError(f"{v!r} is not an IPv4 multicast address (224.0.0.0/4)")
        return v

    @field_validator("multicast_interface")
    @classmethod
    def _iface(cls, v: str) -> str:
        _ipv4(v, "multicast_interface")
        return v

    @field_validator("allowed_senders")
    @classmethod
    def _senders(cls, v: list[str] | None) -> list[str] | None:
        for s in v or []:
            if s == "any":
                continue
            try:
                ipaddress.ip_network(s, strict=False)
            except ValueError as exc:
                raise ValueError(
                    f"allowed sender {s!r} is not an IP address, a network (10.0.0.0/24) or 'any'"
                ) from exc
        return v

    def sender_filter(self) -> list[str] | None:
        """The sender addresses/networks to accept, or None for any sender (``allowed_senders``,
        else ``[remote_host]`` when set)."""
        if self.allowed_senders is not None:
            return None if "any" in self.allowed_senders else list(self.allowed_senders)
        return None if self.remote_host is None else [self.remote_host]

    @model_validator(mode="after")
    def _remote_pair(self) -> UdpTransportConfig:
        if (self.remote_host is None) != (self.remote_port is None):
            raise ValueError("'remote_host' and 'remote_port' go together")
        return self

    def describe(self) -> str:
        """One line for logs and status, e.g. ``udp 0.0.0.0:4001 group 239.1.2.3 on 0.0.0.0``."""
        out = f"udp {self.host}:{self.port}"
        if self.multicast_group:
            out += f" group {self.multicast_group} on {self.multicast_interface}"
        if self.remote_host is not None:
            out += f" -> {self.remote_host}:{self.remote_port}"
        senders = self.sender_filter()
        if senders is not None:
            out += f" from {', '.join(senders)}"
        return out


class FileTransportConfig(_Model):
    """A capture file replayed as chunks (bytes as they came off the wire, no container).

    Without a rate the file is read as fast as possible. ``byte_rate`` (byte/s) or ``baud``
    (bit/s, ``bits_per_byte`` on the wire, 10 for 8N1) paces it as the line would deliver it, and
    ``speed`` runs that pace k times faster (2.0 = twice real time). ``chunk_size`` defaults to
    4096 bytes unpaced and to 10 ms of bytes when paced. ``loop`` restarts at the end of the file.
    """

    kind: Literal["file"] = "file"
    path: Annotated[Path, Strict(False)]  # a TOML string
    chunk_size: int | None = Field(None, ge=1, le=MAX_CHUNK_BYTES, description="bytes per chunk")
    byte_rate: float | None = Field(None, ge=1, le=1e9, description="pace, byte/s")
    baud: int | None = Field(
        None, ge=50, le=20_000_000, description="pace as a line of this rate, bit/s"
    )
    bits_per_byte: float = Field(
        10.0, ge=5, le=16, description="bits on the wire per byte (8N1: 10)"
    )
    speed: float = Field(1.0, ge=0.001, le=1000, description="k x real time")
    loop: bool = False

    @model_validator(mode="after")
    def _pacing(self) -> FileTransportConfig:
        if self.byte_rate is not None and self.baud is not None:
            raise ValueError("set either 'byte_rate' or 'baud', not both")
        if self.speed != 1.0 and self.byte_rate is None and self.baud is None:
            raise ValueError("'speed' needs a real-time pace: set 'byte_rate' or 'baud'")
        if self.loop and self.byte_rate is None and self.baud is None:
            raise ValueError(
                "'loop' needs a pace: set 'byte_rate' or 'baud' (an unpaced loop replays for "
                "ever as fast as the CPU allows, a whole core)"
            )
        return self

    @property
    def bytes_per_s(self) -> float | None:
        """Replay pace in byte/s including ``speed``; None means as fast as possible."""
        if self.byte_rate is not None:
            return self.byte_rate * self.speed
        if self.baud is not None:
            return self.baud / self.bits_per_byte * self.speed
        return None

    @property
    def chunk_bytes(self) -> int:
        """``chunk_size``, or by default 4096 unpaced and 10 ms of bytes (1 to 4096) paced."""
        if self.chunk_size is not None:
            return self.chunk_size
        rate = self.bytes_per_s
        if rate is None:
            return DEFAULT_REPLAY_CHUNK
        return max(1, min(DEFAULT_REPLAY_CHUNK, round(rate * PACED_CHUNK_S)))

    def describe(self) -> str:
        """One line for logs and status, e.g. ``file ins.bin (paced as 115200 baud ...)``."""
        rate = self.bytes_per_s
        if rate is None:
            pace = "as fast as possible"
        elif self.baud is not None:
            pace = f"paced as {self.baud} baud ({rate:g} B/s)"
        else:
            pace = f"paced {rate:g} B/s"
        if self.speed != 1.0:
            pace += f" at {self.speed:g}x real time"
        loop = ", loop" if self.loop else ""
        return f"file {self.path} ({pace}, {self.chunk_bytes} B chunks{loop})"


#: Transport settings of any kind, chosen by the ``kind`` key.
TransportConfig = Annotated[
    SerialTransportConfig | CanTransportConfig | UdpTransportConfig | FileTransportConfig,
    Field(discriminator="kind"),
]

KINDS = ("serial", "can", "udp", "file")
_ADAPTER: TypeAdapter[Any] = TypeAdapter(TransportConfig)


def format_validation_error(exc: ValidationError, where: str = "transport") -> str:
    """One line per error: ``where.field: what is wrong (got value)``
    (:func:`auvgw.ground.errors.format_validation_error`, the union's tag dropped from the path).

    ``where`` ending in ``:`` (``"vehicle.toml:"``) names a file instead of a field path; a
    larger model that embeds :data:`TransportConfig` in a field named ``transport`` reads the
    same way.
    """
    file = where[:-1] if where.endswith(":") else ""
    return format_errors(exc, file, prefix="" if file else where, tags=KINDS, tagged=("transport",))


def parse_transport_config(data: Mapping[str, Any], where: str = "transport") -> TransportConfig:
    """Validate a mapping (e.g. a TOML table) into a transport model.

    ``where`` prefixes every error's field path (e.g. ``devices.dvl.transport``, or
    ``vehicle.toml: devices.dvl.transport`` to name the file too).
    """
    try:
        return _ADAPTER.validate_python(dict(data))
    except ValidationError as exc:
        raise TransportConfigError(format_validation_error(exc, where)) from exc
