"""Recordings of the raw bus traffic in MCAP files (``auvgw record`` / ``auvgw replay``).

MCAP (https://mcap.dev) is the log container Foxglove Studio opens directly and ROS 2's rosbag2
reads through its default ``mcap`` storage plugin; it is indexed (seek by time, per-channel
counts without a full scan), chunked and compressed, and its records are documented, so a
recording outlives this project. Layout of an auvgw recording:

* one channel per Zenoh key (``auv/<v>/raw/<device>``, ``auv/<v>/truth/<what>``); the channel's
  metadata holds the key and the payload's Zenoh encoding.
* raw channels (message encoding :data:`RAW_ENCODING`): each message's data is
  ``u16 attachment length (LE) | attachment | frame bytes exactly as received``, so the
  gateway's attachment (receive time, sequence, stream offset) is kept byte for byte;
  ``log_time`` = the host receive time from the attachment (ns since the Unix epoch),
  ``publish_time`` = when the recorder got it, ``sequence`` = the frame's sequence (mod 2^32).
* other channels: the payload as published (message encoding ``json`` for JSON payloads), log
  time = when the recorder got it.
* a metadata record :data:`GATEWAY_METADATA` with the vehicle name and the running gateway
  configuration (device -> format, DBC, table), so a replay needs nothing else; and a closing
  metadata record :data:`RECORDING_METADATA` (keys, start/stop times, message counts).

:func:`iter_recording` decodes a recording offline through the same
:meth:`~auvgw.decoding.DeviceDecoder.decode_raw` as the gateway and ``auvgw replay``.
"""

from __future__ import annotations

import json
import logging
import queue
import struct
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer
from pydantic import ValidationError

from auvgw.bus import RAW_ATTACHMENT, SCHEMA_VERSION, unpack_raw_attachment
from auvgw.config.gateway import ConfigError, GatewayConfig, format_validation_error
from auvgw.decoding import DeviceDecoder, make_decoders
from auvgw.paths import config_file

log = logging.getLogger(__name__)

__all__ = [
    "GATEWAY_METADATA",
    "RAW_ENCODING",
    "RECORDING_METADATA",
    "McapRecorder",
    "Recorded",
    "RecordedSample",
    "RecordingError",
    "RecordingInfo",
    "iter_recording",
    "iter_samples",
    "key_section",
    "read_info",
    "recorded_paths",
]

#: MCAP message encoding of raw channels (see the module docstring for the layout)
RAW_ENCODING = "auvgw.raw.v1"
#: MCAP metadata record holding the vehicle and the gateway configuration
GATEWAY_METADATA = "auvgw.gateway"
#: MCAP metadata record written when a recording is closed
RECORDING_METADATA = "auvgw.recording"
_ATT_LEN = struct.Struct("<H")
_STOP = "stop"


class RecordingError(ValueError):
    """A recording that cannot be read or used; the message names the file."""


def key_section(key: str) -> tuple[str, str, str]:
    """(vehicle, section, rest) of ``auv/<vehicle>/<section>/<rest>``."""
    parts = key.split("/", 3)
    if len(parts) < 4 or parts[0] != "auv":
        raise ValueError(f"{key!r} is not an auvgw key (auv/<vehicle>/<section>/...)")
    return parts[1], parts[2], parts[3]


def pack_raw_record(attachment: bytes, payload: bytes) -> bytes:
    """MCAP data of a raw channel message: ``u16 len | attachment | payload``."""
    return _ATT_LEN.pack(len(attachment)) + attachment + payload


def unpack_raw_record(data: bytes) -> tuple[bytes, bytes]:
    """(attachment, payload) of a raw channel message."""
    (n,) = _ATT_LEN.unpack_from(data)
    return data[2 : 2 + n], data[2 + n :]


# -- writing -----------------------------------------------------------------------------------


@dataclass
class _Pending:
    key: str
    payload: bytes
    attachment: bytes | None
    encoding: str
    t_rx_ns: int


class McapRecorder:
    """Writes samples to an MCAP file from a background thread.

    :meth:`add` is cheap and thread-safe (it only queues), so it can be called from Zenoh
    callbacks; :meth:`close` drains the queue, writes the closing metadata and the MCAP summary.
    """

    def __init__(self, path: str | Path, vehicle: str, chunk_size: int = 256 * 1024) -> None:
        self.path = Path(path)
        self.vehicle = vehicle
        self.counts: Counter[str] = Counter()
        self.t_start_ns = time.time_ns()
        self._f: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._w = Writer(self._f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"auvgw (schema {SCHEMA_VERSION})")
        self._channels: dict[str, int] = {}
        self._q: queue.SimpleQueue[_Pending | str] = queue.SimpleQueue()
        self._config_written = False
        self._closed = False
        self._thread = threading.Thread(target=self._drain, name="mcap-writer", daemon=True)
        self._thread.start()

    def add(self, key: str, payload: bytes, attachment: bytes | None, encoding: str = "") -> None:
        """Queue one sample (``encoding`` is the Zenoh encoding string of the payload)."""
        self._q.put(_Pending(key, payload, attachment, encoding, time.time_ns()))

    def set_gateway_config(self, config_json: str) -> None:
        """Write the gateway configuration record (once; later calls are ignored)."""
        if self._config_written:
            return
        self._config_written = True
        meta = {
            "vehicle": self.vehicle,
            "schema_version": str(SCHEMA_VERSION),
            "config": config_json,
        }
        self._q.put(json.dumps(meta))  # written in order, after the samples queued before it

    @property
    def has_config(self) -> bool:
        return self._config_written

    def _channel(self, p: _Pending) -> int:
        cid = self._channels.get(p.key)
        if cid is None:
            raw = key_section(p.key)[1] == "raw"
            if raw:
                encoding = RAW_ENCODING
            elif p.encoding.startswith("application/json"):
                encoding = "json"
            else:
                encoding = "auvgw.bytes"
            meta = {"key": p.key, "zenoh_encoding": p.encoding}
            if raw:
                meta["attachment"] = f"struct {RAW_ATTACHMENT.format}: t_recv_ns, seq, offset"
            cid = self._w.register_channel(p.key, encoding, schema_id=0, metadata=meta)
            self._channels[p.key] = cid
        return cid

    def _write(self, p: _Pending) -> None:
        cid = self._channel(p)
        log_time, seq, data = p.t_rx_ns, 0, p.payload
        if key_section(p.key)[1] == "raw":
            att = p.attachment or b""
            if len(att) == RAW_ATTACHMENT.size:
                log_time, seq, _ = unpack_raw_attachment(att)
            data = pack_raw_record(att, p.payload)
        self._w.add_message(
            channel_id=cid,
            log_time=log_time,
            data=data,
            publish_time=p.t_rx_ns,
            sequence=seq & 0xFFFFFFFF,
        )
        self.counts[p.key] += 1

    def _drain(self) -> None:
        while True:
            p = self._q.get()
            if p == _STOP:
                return
            if isinstance(p, str):
                self._w.add_metadata(GATEWAY_METADATA, json.loads(p))
                continue
            try:
                self._write(p)
            except (ValueError, struct.error) as exc:
                log.warning("%s: sample not recorded: %s", p.key, exc)

    def close(self) -> None:
        """Flush everything, write the closing metadata and the summary, close the file."""
        if self._closed:
            return
        self._closed = True
        self._q.put(_STOP)
        self._thread.join()
        self._w.add_metadata(
            RECORDING_METADATA,
            {
                "vehicle": self.vehicle,
                "t_start_ns": str(self.t_start_ns),
                "t_stop_ns": str(time.time_ns()),
                "counts": json.dumps(dict(self.counts)),
            },
        )
        self._w.finish()
        self._f.close()


# -- reading -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RecordedSample:
    """One recorded message: key, log time (ns; host receive time for raw frames), the original
    attachment (None if there was none) and the payload bytes."""

    key: str
    log_time_ns: int
    attachment: bytes | None
    payload: bytes
    message_encoding: str
    zenoh_encoding: str = ""


@dataclass
class RecordingInfo:
    """What a recording holds: vehicle, gateway configuration (None if the recorder never got
    it), message counts per key."""

    path: Path
    vehicle: str | None = None
    config: GatewayConfig | None = None
    config_json: str | None = None
    counts: dict[str, int] = field(default_factory=dict)


class Recorded(NamedTuple):
    """A raw frame of a recording with what the gateway's decoder makes of it."""

    key: str
    t_recv_ns: int
    raw: bytes
    messages: tuple[Any, ...]


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from exc


def _check_magic(path: Path, f: IO[bytes]) -> None:
    if f.read(8) != b"\x89MCAP0\r\n":
        raise RecordingError(f"{path}: not an MCAP file (no MCAP magic at the start)")
    f.seek(0)


def read_info(path: str | Path) -> RecordingInfo:
    """Vehicle, gateway configuration and counts of a recording (reads the index where the
    file was closed properly, else scans it)."""
    path = Path(path)
    info = RecordingInfo(path)
    with _open(path) as f:
        _check_magic(path, f)
        try:
            reader = make_reader(f)
            metas = list(reader.iter_metadata())
            summary = reader.get_summary()
        except (McapError, struct.error, ValueError, EOFError):  # not closed: scan what is there
            f.seek(0)
            metas, summary = [], None
            try:
                for rec in NonSeekingReader(f).iter_metadata():
                    metas.append(rec)
            except (McapError, struct.error, ValueError, EOFError):
                log.warning("%s: recording truncated (was the recorder killed?)", path)
    for m in metas:
        if m.name == GATEWAY_METADATA:
            info.vehicle = m.metadata.get("vehicle")
            info.config_json = m.metadata.get("config")
    if info.config_json:
        try:
            info.config = GatewayConfig.model_validate_json(info.config_json)
        except ValidationError as exc:
            raise RecordingError(
                f"{path}: recorded gateway configuration is not valid here:\n"
                + format_validation_error(f"{path} (recorded config)", exc)
            ) from exc
        info.config.source = f"{path} (recorded config)"
    if summary is not None and summary.statistics is not None:
        channels = summary.channels
        info.counts = {
            channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()
        }
    return info


def iter_samples(path: str | Path) -> Iterator[RecordedSample]:
    """Every recorded message in file order (per key, the order the recorder received them).

    A recording cut short (recorder killed) yields what was written and logs a warning.
    """
    path = Path(path)
    with _open(path) as f:
        _check_magic(path, f)
        try:
            for _schema, channel, msg in NonSeekingReader(f).iter_messages(log_time_order=False):
                zenc = channel.metadata.get("zenoh_encoding", "")
                if channel.message_encoding == RAW_ENCODING:
                    att, payload = unpack_raw_record(msg.data)
                    yield RecordedSample(
                        channel.topic, msg.log_time, att or None, payload, RAW_ENCODING, zenc
                    )
                else:
                    yield RecordedSample(
                        channel.topic, msg.log_time, None, msg.data, channel.message_encoding, zenc
                    )
        except (McapError, struct.error, EOFError) as exc:
            log.warning("%s: recording truncated (%s); read up to there", path, exc)


def _shipped(name: str) -> bool:
    """Whether a recorded ``dbc``/``table`` names a file shipped in ``config/`` (a bare name, or
    a path inside the shipped folder), the only files a recorded configuration may open."""
    shipped_dir = config_file("").resolve()
    p = Path(name)
    if len(p.parts) == 1 and not name.startswith("."):
        return (shipped_dir / name).is_file()
    return p.is_absolute() and p.resolve().parent == shipped_dir and p.resolve().is_file()


def recorded_paths(cfg: GatewayConfig) -> dict[str, str]:
    """``device.field -> path`` of every file a (recorded) configuration would open to decode
    (site tables and DBCs) that is not a shipped one."""
    out: dict[str, str] = {}
    for name, dev in cfg.devices.items():
        for attr in ("dbc", "table"):
            value = getattr(dev, attr)
            if dev.enabled and value and not _shipped(value):
                out[f"{name}.{attr}"] = value
    return out


def decoders_for(
    info: RecordingInfo, config: GatewayConfig | None = None, *, trust_paths: bool = False
) -> dict[str, DeviceDecoder]:
    """Decoders of a recording's devices (from ``config`` if given, else the recorded one).

    A recording is data, not configuration: a table or DBC path in the *recorded* configuration is
    opened only with ``trust_paths`` (or when it names a shipped file); a device that needs one
    gets no decoder (its raw frames replay, undecoded) and one warning line names them.
    """
    cfg = config or info.config
    if cfg is None:
        raise RecordingError(
            f"{info.path}: no gateway configuration recorded (the recorder never reached the "
            "gateway's config queryable); pass the gateway's configuration file explicitly"
        )
    skipped = {} if config is not None or trust_paths else recorded_paths(cfg)
    if skipped:
        devices = {k.split(".", 1)[0] for k in skipped}
        cfg = cfg.model_copy(
            update={"devices": {n: d for n, d in cfg.devices.items() if n not in devices}}
        )
        log.warning(
            "%s: recorded configuration names files not opened (%s): %s replayed raw, not "
            "decoded; pass --config FILE or --trust-recorded-paths to decode them",
            info.path,
            ", ".join(f"{k}={v!r}" for k, v in sorted(skipped.items())),
            ", ".join(sorted(devices)),
        )
    try:
        return make_decoders(cfg)
    except ConfigError as exc:
        raise RecordingError(str(exc)) from exc


def iter_recording(
    path: str | Path,
    config: GatewayConfig | None = None,
    truth: bool = False,
    *,
    trust_paths: bool = False,
) -> Iterator[Recorded]:
    """Offline: every raw frame of a recording as ``(key, t_recv_ns, raw bytes, messages)``,
    decoded exactly as the gateway decodes live (a frame whose decoding fails has no messages and
    is logged). ``truth=True`` adds the ``truth/`` samples with their parsed JSON as the one
    message. ``config`` replaces the recorded gateway configuration; ``trust_paths`` lets the
    recorded one open its tables and DBCs (:func:`decoders_for`)."""
    info = read_info(path)
    decoders = decoders_for(info, config, trust_paths=trust_paths)
    unknown: set[str] = set()
    for s in iter_samples(path):
        _vehicle, section, rest = key_section(s.key)
        if section == "raw":
            dec = decoders.get(rest)
            if dec is None:
                if rest not in unknown:
                    unknown.add(rest)
                    log.warning("%s: device %r has no decoder; its frames skipped", path, rest)
                continue
            t_ns, offset = s.log_time_ns, 0
            if s.attachment is not None and len(s.attachment) == RAW_ATTACHMENT.size:
                t_ns, _seq, offset = unpack_raw_attachment(s.attachment)
            item = dec.item(s.payload, offset)
            if item.error is not None:
                log.warning("%s", item.error)
            yield Recorded(s.key, t_ns, s.payload, item.messages)
        elif section == "truth" and truth:
            try:
                msgs: tuple[Any, ...] = (json.loads(s.payload),)
            except ValueError:
                msgs = ()
            yield Recorded(s.key, s.log_time_ns, s.payload, msgs)
