"""The Zenoh bus: key space, session modes and payload encodings (documented in docs/bus.md).

Key space (``<v>`` is the vehicle name)::

    auv/<v>/raw/<device>                 raw frames: bytes, attachment = RAW_ATTACHMENT
    auv/<v>/sensor/<device>/<kind>       decoded messages: envelopes (auvgw.envelope)
    auv/<v>/nav/odometry                 fusion output (envelope)
    auv/<v>/slam/<pipeline>/{pose,landmarks,map}
    auv/<v>/status/<component>           periodic health (JSON); also a queryable
    auv/<v>/alive/<component>            liveliness tokens
    auv/<v>/config/<component>           queryable: the running configuration (JSON)
    auv/<v>/truth/<what>                 simulation ground truth (JSON)

The schema version (``SCHEMA_VERSION``) of the JSON documents is carried in their encoding
schema (``auvgw/1/...``); the envelope's version (``ENVELOPE_VERSION``) in its encoding
(``application/msgpack;auvgw/3/<Type>``) and its first element, so consumers can reject payloads
they do not understand without guessing from the key.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import struct
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import zenoh

from auvgw.config.bus import BusConfig
from auvgw.envelope import (
    ENVELOPE_VERSION,
    Envelope,
    decode_envelope,
    encode_envelope,
    envelope_encoding,
)
from auvgw.ground.errors import UserError, format_validation_error

log = logging.getLogger(__name__)

__all__ = [
    "ENVELOPE_VERSION",
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
    "envelope_encoding",
    "json_encoding",
    "load_bus_table",
    "open_cli_session",
    "open_session",
    "pack_raw_attachment",
    "raw_encoding",
    "undeclare",
    "unpack_raw_attachment",
    "wire_format_of",
    "zenoh_config",
]

#: version of the JSON documents (status, configuration, SLAM outputs, truth)
SCHEMA_VERSION = 1
#: attachment of a raw frame: host receive time (ns since the Unix epoch), per-device sequence,
#: stream byte offset of the frame's first byte
RAW_ATTACHMENT = struct.Struct("<qQQ")


class Undeclarable(Protocol):
    """A Zenoh declaration (publisher, subscriber, queryable, liveliness token)."""

    def undeclare(self) -> object: ...


def undeclare(entities: Iterable[Undeclarable]) -> None:
    """Undeclare Zenoh entities (publishers, subscribers, queryables, tokens), ignoring the ones a
    closing session has already dropped."""
    for e in entities:
        with contextlib.suppress(zenoh.ZError):
            e.undeclare()


def open_session(cfg: BusConfig | None = None) -> zenoh.Session:
    """Open a Zenoh session; close it (``with`` or ``finally``) or the process hangs at exit.
    On a bus without TLS or authentication that another machine could reach, every process
    says so once at start-up (a warning naming the endpoints): any process that reaches such a
    bus can publish sensor data the vehicle will use."""
    cfg = cfg or BusConfig()
    open_to = cfg.open_beyond_loopback()
    if open_to:
        log.warning("bus: no TLS and no authentication, and reachable beyond this machine through "
                    "%s: any process that reaches it can publish sensor data the vehicle uses; "
                    "see docs/security.md ([bus.tls], [bus.auth], access control)",
                    ", ".join(open_to))  # fmt: skip
    return zenoh.open(zenoh_config(cfg))


def zenoh_config(cfg: BusConfig) -> zenoh.Config:
    """The Zenoh configuration of ``cfg`` (:meth:`BusConfig.zenoh_json5`'s entries)."""
    conf = zenoh.Config()
    for key, value in cfg.zenoh_json5().items():
        conf.insert_json5(key, value)
    return conf


def open_cli_session(
    cfg: BusConfig,
    what: str = "cannot open the Zenoh session",
    hint: str = "; check --connect/--listen",
) -> zenoh.Session:
    """:func:`open_session` for a command: a Zenoh error becomes a :class:`UserError`
    ``"<what> (<error>)<hint>"``."""
    try:
        return open_session(cfg)
    except zenoh.ZError as exc:
        raise UserError(f"{what} ({exc}){hint}") from exc


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

    def cmd(self, device: str) -> str:
        """Commands to a device (``auv/<v>/cmd/<device>``: envelopes of its command message)."""
        return f"{self.base}/cmd/{device}"

    def all(self, section: str = "**") -> str:
        return f"{self.base}/{section}"

    def split(self, key: str) -> tuple[str, str] | None:
        """``(section, rest)`` of a key of this vehicle, ``auv/<v>/<section>/<rest>`` (``rest``
        empty when the key ends at the section); None for any other key."""
        base = self.base + "/"
        if not key.startswith(base):
            return None
        section, _, rest = key[len(base) :].partition("/")
        return section, rest


def parse_key(key: str, root: str = "auv") -> tuple[str, str, str]:
    """``(vehicle, section, rest)`` of any vehicle's key ``auv/<vehicle>/<section>/<rest>``; a
    ``ValueError`` for anything else (a recording's channels, replay, export)."""
    parts = key.split("/", 3)
    if len(parts) < 4 or parts[0] != root:
        raise ValueError(f"{key!r} is not an auvgw key ({root}/<vehicle>/<section>/...)")
    return parts[1], parts[2], parts[3]


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


class InputWatch:
    """Says on stderr, once per key, when no sample arrived on an input key expression within
    ``bus.no_publisher_after_s`` seconds (naming the key and the bus endpoints), so a stage
    started without a gateway does not wait silently, and once more when such a key's first
    sample arrives. :attr:`silent` lists the keys that never had one."""

    def __init__(
        self, session: zenoh.Session, keys: Iterable[str], what: str, bus: BusConfig
    ) -> None:
        self.what = what
        self.bus = bus
        wanted = list(dict.fromkeys(keys))
        self.silent: set[str] = set(wanted)
        self._lock = threading.Lock()
        self._reported: set[str] = set()
        # over the list, not the set: a sample may arrive (and empty the set) while declaring
        self._subs = {k: session.declare_subscriber(k, self._seen(k)) for k in wanted}
        self._timer = threading.Timer(bus.no_publisher_after_s, self._report)
        self._timer.daemon = True
        self._timer.start()

    def _seen(self, key: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(_s: zenoh.Sample) -> None:
            with self._lock:
                if key not in self.silent:
                    return
                self.silent.discard(key)
                late = key in self._reported
            if late:  # said "no publisher" before: say it is fine now
                print(f"{self.what}: {key}: receiving now", file=sys.stderr, flush=True)

        return on_sample

    def _report(self) -> None:
        with self._lock:
            silent = sorted(self.silent)
            self._reported.update(silent)
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


def add_bus_arguments(
    parser: argparse.ArgumentParser, title: str | None = None, mode: bool = True
) -> None:
    """``--mode/--connect/--listen`` options of a command that joins the bus (``mode=False``:
    no ``--mode``, e.g. ``auvgw run`` whose configuration has it)."""
    from auvgw.config.bus import DEFAULT_ENDPOINT, ENDPOINT_ENV

    g = parser.add_argument_group(
        title
        or (
            f"Zenoh bus (default: a peer meeting the gateway at {DEFAULT_ENDPOINT}, "
            f"or ${ENDPOINT_ENV}; docs/bus.md)"
        )
    )
    g.add_argument(
        "--bus-config",
        type=Path,
        default=None,
        metavar="TOML",
        help="take the [bus] table (endpoints, tls, auth, access_control) of this file, e.g. "
        "the gateway's configuration; --mode/--connect/--listen override it (docs/security.md)",
    )
    if mode:
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


def bus_from_args(args: argparse.Namespace, hub: bool = False) -> BusConfig:
    """The :class:`BusConfig` of :func:`add_bus_arguments` options (raises ValueError, one line
    per problem). With no endpoint given, the one-machine default: listen on the default
    endpoint (``hub``: the gateway's role, e.g. ``auvgw replay``) or connect to it."""
    from pydantic import ValidationError

    base: dict[str, Any] = {}
    path: Path | None = getattr(args, "bus_config", None)
    if path is not None:
        base = load_bus_table(path)
    given = {"mode": getattr(args, "mode", None), "connect": args.connect, "listen": args.listen}
    try:
        bus = BusConfig(**{**base, **{k: v for k, v in given.items() if v}})
        if path is not None:
            bus = bus.rebased(path.resolve().parent)
        return bus.as_hub() if hub else bus.as_spoke()
    except ValidationError as exc:
        raise ValueError(format_validation_error(exc, rename=lambda f: f"--{f}")) from exc
