"""Recordings of the bus in MCAP files with the ROS 2 profile (``auvgw record`` / ``replay``).

MCAP (https://mcap.dev) is the log container Foxglove opens directly and ROS 2's rosbag2 reads
through its default ``mcap`` storage plugin; it is indexed, chunked and compressed, and its
records are documented, so a recording outlives this project. An auvgw recording is written in
MCAP's **ROS 2 profile** (profile ``ros2``, schemas ``ros2msg``, messages ``cdr``), so
``ros2 bag``, ``rosbags`` and Foxglove decode every message:

* one channel per ROS 2 topic ``/<vehicle>/<section>/...`` (the mapping and frames are
  :mod:`auvgw.ros2`'s); the channel's metadata holds the Zenoh ``key`` it came from and the
  payload's ``zenoh_encoding``.
* raw frames: ``auvgw_msgs/msg/RawFrame`` (device, wire format, receive time, sequence, stream
  offset, the bytes exactly as received), so ``auvgw replay`` republishes and decodes them
  bit-exactly; ``log_time`` = the receive time, ``sequence`` = the frame's sequence (mod 2^32).
* decoded sensors, odometry, SLAM outputs: their standard ROS 2 types, ``log_time`` = the
  receive time they carry; status, truth and types with no standard counterpart:
  ``auvgw_msgs/msg/Decoded`` (type name + the JSON body, byte for byte).
* a metadata record :data:`GATEWAY_METADATA` with the vehicle name and the running gateway
  configuration (device -> format, DBC, table), so a replay needs nothing else; and a closing
  metadata record :data:`RECORDING_METADATA` (topics, start/stop times, message counts).

Recordings of earlier versions (no profile; raw channels in :data:`RAW_ENCODING`, the rest JSON)
are still read, and ``auvgw export --ros2`` converts them. :func:`iter_recording` decodes a
recording offline through the same :meth:`~auvgw.decoding.DeviceDecoder.decode_raw` as the
gateway and ``auvgw replay``.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import logging
import re
import struct
import threading
import time
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

from mcap.exceptions import EndOfFile, McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Chunk, Footer, McapRecord, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from pydantic import ValidationError

from auvgw import ros2
from auvgw.bus import (
    RAW_ATTACHMENT,
    SCHEMA_VERSION,
    decode_envelope,
    pack_raw_attachment,
    parse_key,
    unpack_raw_attachment,
    wire_format_of,
)
from auvgw.config.gateway import ConfigError, GatewayConfig, format_validation_error
from auvgw.decoding import DeviceDecoder, make_decoders
from auvgw.drivers.spec import to_jsonable
from auvgw.ground.errors import DataError
from auvgw.ground.paths import config_file
from auvgw.ground.worker import Worker

log = logging.getLogger(__name__)

__all__ = [
    "GATEWAY_METADATA",
    "MESSAGE_ENCODING",
    "PROFILE",
    "RAW_ENCODING",
    "RECORDING_METADATA",
    "McapRecorder",
    "Recorded",
    "RecordedSample",
    "RecordingError",
    "RecordingInfo",
    "Ros2McapWriter",
    "iter_recording",
    "iter_samples",
    "key_section",
    "read_info",
    "recorded_paths",
]

#: MCAP message encoding of raw channels in recordings of earlier versions (read, not written)
RAW_ENCODING = "auvgw.raw.v1"
#: MCAP profile, schema and message encodings of a recording
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: MCAP metadata record holding the vehicle and the gateway configuration
GATEWAY_METADATA = "auvgw.gateway"
#: MCAP metadata record written when a recording is closed
RECORDING_METADATA = "auvgw.recording"
_ATT_LEN = struct.Struct("<H")


class RecordingError(DataError):
    """A recording that cannot be read or used; the message names the file."""


#: (vehicle, section, rest) of ``auv/<vehicle>/<section>/<rest>`` (:func:`auvgw.bus.parse_key`)
key_section = parse_key


def pack_raw_record(attachment: bytes, payload: bytes) -> bytes:
    """MCAP data of a raw channel message: ``u16 len | attachment | payload``."""
    return _ATT_LEN.pack(len(attachment)) + attachment + payload


def unpack_raw_record(data: bytes) -> tuple[bytes, bytes]:
    """(attachment, payload) of a raw channel message."""
    (n,) = _ATT_LEN.unpack_from(data)
    return data[2 : 2 + n], data[2 + n :]


# -- writing -----------------------------------------------------------------------------------


class Ros2McapWriter:
    """Writes bus samples to an MCAP file in the ROS 2 profile, synchronously (one thread).

    :meth:`write` takes a Zenoh sample as published (key, payload, attachment, encoding) and
    writes its ROS 2 messages (:func:`sample_to_ros`); :meth:`write_ros` writes ready ones.
    ``wire_formats`` (device -> gateway format) names raw frames whose encoding does not.
    """

    def __init__(self, f: IO[bytes], vehicle: str, chunk_size: int = 256 * 1024) -> None:
        self.vehicle = vehicle
        self.counts: Counter[str] = Counter()
        self.wire_formats: dict[str, str] = {}
        self._w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile=PROFILE, library=f"auvgw (bus schema {SCHEMA_VERSION})")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._tf = ros2.TfTracker()  # map -> odom from the SLAM poses

    def _channel(self, topic: str, type_name: str, key: str, encoding: str) -> int:
        cid = self._channels.get((topic, type_name))
        if cid is None:
            sid = self._schemas.get(type_name)
            if sid is None:
                sid = self._w.register_schema(
                    type_name, SCHEMA_ENCODING, ros2.msgdef(type_name).encode()
                )
                self._schemas[type_name] = sid
            meta = {"key": key, "zenoh_encoding": encoding}
            cid = self._w.register_channel(topic, MESSAGE_ENCODING, schema_id=sid, metadata=meta)
            self._channels[(topic, type_name)] = cid
        return cid

    def write_ros(
        self,
        key: str,
        msgs: list[ros2.RosMessage],
        log_time: int,
        publish_time: int,
        sequence: int = 0,
        encoding: str = "",
    ) -> None:
        """Write ROS 2 messages that came from the Zenoh ``key``."""
        for m in msgs:
            topic = ros2.ros_topic("", self.vehicle, m.topic)
            # a standard ROS topic derived from the bus (/tf, /tf_static, /diagnostics) names
            # the ros2/ section as its source: a replay republishes none of it on a bus key
            src = f"auv/{self.vehicle}/ros2{topic}" if m.topic.startswith("/") else key
            self._w.add_message(
                channel_id=self._channel(topic, m.type, src, encoding),
                log_time=log_time,
                data=ros2.serialize(m),
                publish_time=publish_time,
                sequence=sequence & 0xFFFFFFFF,
            )
            self.counts[topic] += 1

    def write(
        self, key: str, payload: bytes, attachment: bytes | None, encoding: str, t_rx_ns: int
    ) -> None:
        """Write one bus sample (raises ValueError when it cannot be converted)."""
        _vehicle, section, rest = key_section(key)
        if section == "raw":
            wire = wire_format_of(encoding) or self.wire_formats.get(rest, "")
            t_ns, seq, offset = t_rx_ns, 0, 0
            if attachment is not None and len(attachment) == RAW_ATTACHMENT.size:
                t_ns, seq, offset = unpack_raw_attachment(attachment)
            msg = ros2.raw_frame_msg(rest, wire, t_ns, seq, offset, payload)
            self.write_ros(key, [msg], t_ns, t_rx_ns, seq, encoding)
            return
        msgs, t_ns, seq = sample_to_ros(section, rest, payload, t_rx_ns)
        self.write_ros(key, msgs + self._tf.feed(msgs, t_ns), t_ns, t_rx_ns, seq, encoding)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, data)

    def finish(self, t_start_ns: int) -> None:
        """Write the closing metadata record and the MCAP summary."""
        self._w.add_metadata(
            RECORDING_METADATA,
            {
                "vehicle": self.vehicle,
                "t_start_ns": str(t_start_ns),
                "t_stop_ns": str(time.time_ns()),
                "counts": json.dumps(dict(self.counts)),
            },
        )
        self._w.finish()


class _Fields:
    """Attribute access to a JSON body (a decoded message whose type is not loaded here)."""

    def __init__(self, type_name: str, body: Mapping[str, object]) -> None:
        self.TYPE = type_name
        self.__dict__.update(body)


def sample_to_ros(
    section: str, rest: str, payload: bytes, t_rx_ns: int
) -> tuple[list[ros2.RosMessage], int, int]:
    """(ROS 2 messages, stamp ns, sequence) of a non-raw bus sample: an envelope (``sensor/``,
    ``nav/``: stamped with its receive time; SLAM outputs, :mod:`auvgw.slam.outputs`, stamped
    with their ``t`` on the odometry clock) or a JSON document (status and truth with
    ``t_rx_ns``, when the recorder got it; a JSON SLAM output with its ``t``)."""
    from auvgw.subscribe import envelope_message

    if section in ("sensor", "nav"):
        env = decode_envelope(payload)
        _load_types()
        msg = envelope_message(env)
        if msg is None:  # a type this recorder does not know: its fields if sent by name
            msg = _Fields(env.type, env.body if isinstance(env.body, Mapping) else {})
        kind = rest.rpartition("/")[2]
        source = rest.partition("/")[0] if section == "sensor" else rest
        try:
            msgs = ros2.to_ros(section, source, msg, env.t_recv_ns, env.seq, kind)
        except (AttributeError, TypeError, ValueError) as exc:  # no standard form: keep the body
            log.debug("%s/%s: %s; recorded as %s", section, rest, exc, ros2.DECODED_TYPE)
            typed = hasattr(msg, "__dataclass_fields__")
            fields = (
                to_jsonable(msg) if typed else {k: v for k, v in vars(msg).items() if k != "TYPE"}
            )
            msgs = [ros2.decoded_msg(f"{section}/{rest}", source, env.type, env.t_recv_ns,
                                     env.seq, fields)]  # fmt: skip
        return msgs, env.t_recv_ns, env.seq
    if section == "slam" and payload[:1] != b"{":  # a declared SLAM output (auvgw.slam.outputs)
        from auvgw.subscribe import slam_output

        out = slam_output(payload, f"{section}/{rest}")
        t_ns = round(float(out["t"]) * 1e9)
        return ros2.to_ros(section, rest, out, t_ns), t_ns, 0
    text = payload.decode("utf-8", errors="replace")
    try:
        body: Any = json.loads(text)
    except ValueError:
        body = None
    t_ns = t_rx_ns
    if section == "slam" and isinstance(body, dict) and isinstance(body.get("t"), int | float):
        t_ns = round(body["t"] * 1e9)
        return ros2.to_ros(section, rest, body, t_ns), t_ns, 0
    type_name = body.get("type", section) if isinstance(body, dict) else section
    source = rest.rpartition("/")[2] if section == "status" else rest
    frame = "" if section == "status" else source  # health is not a place
    msgs = [ros2.decoded_msg(f"{section}/{rest}", source, str(type_name), t_ns, 0, text, frame)]
    if section == "status" and isinstance(body, dict):  # and the standard form of health
        msgs.append(ros2.RosMessage("/diagnostics", ros2.DIAGNOSTICS_TYPE,
                                    ros2.diagnostics_msg(body, t_ns)))  # fmt: skip
    return msgs, t_ns, 0


@functools.cache
def _load_types() -> None:
    """The fusion odometry type and the shipped HN-100 and MS3A DBCs' message types, so their
    envelopes become typed (once a process: it was half the cost of a sample's conversion)."""
    import auvgw.fusion.odometry  # noqa: F401 - registers Odometry
    from auvgw.drivers import registry
    from auvgw.drivers.spec import MESSAGE_TYPES

    if all(m.type in MESSAGE_TYPES for _, m in registry.message_types() if m.wire == "can"):
        return
    try:
        from auvgw.drivers.can_codec import shipped_can_types

        shipped_can_types()
    except Exception as exc:  # cantools or a DBC missing: CAN samples stay untyped
        log.debug("CAN message types not available: %s", exc)


@dataclass
class _Pending:
    key: str
    payload: bytes
    attachment: bytes | None
    encoding: str
    t_rx_ns: int


class McapRecorder(Worker[_Pending | str]):
    """Writes samples to an MCAP file (ROS 2 profile, :class:`Ros2McapWriter`) from a
    background thread (a :class:`~auvgw.ground.worker.Worker` with an unbounded queue: a
    recording never drops a sample to keep up).

    :meth:`add` is cheap and thread-safe (it only queues), so it can be called from Zenoh
    callbacks; :meth:`close` drains the queue, writes the closing metadata and the MCAP summary.
    A sample that cannot be converted is logged and skipped (:attr:`skipped`), never the file.
    """

    def __init__(
        self,
        path: str | Path,
        vehicle: str,
        chunk_size: int = 256 * 1024,
        file: IO[bytes] | None = None,
    ) -> None:
        self.path = Path(path)
        self.vehicle = vehicle
        self.t_start_ns = time.time_ns()
        #: the write error (disk full...) that stopped the recording; samples after it are
        #: counted in ``lost`` and the file stays readable up to its last complete chunk
        self.error: OSError | None = None
        self.lost = 0
        self.failed = threading.Event()
        self.skipped = 0
        self._f: IO[bytes] = file if file is not None else open(self.path, "wb")  # noqa: SIM115
        self._w = Ros2McapWriter(self._f, vehicle, chunk_size)
        self._config_written = False
        self._closed = False
        super().__init__(0, thread_name="mcap-writer")
        self.start_worker()

    @property
    def counts(self) -> Counter[str]:
        """Messages written per ROS 2 topic."""
        return self._w.counts

    def add(self, key: str, payload: bytes, attachment: bytes | None, encoding: str = "") -> None:
        """Queue one sample (``encoding`` is the Zenoh encoding string of the payload); after a
        write error it is only counted as lost (nothing piles up in memory)."""
        if self.failed.is_set():
            self.lost += 1
            return
        self.submit(_Pending(key, payload, attachment, encoding, time.time_ns()))

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
        self.submit(json.dumps(meta))  # written in order, after the samples queued before it

    @property
    def has_config(self) -> bool:
        return self._config_written

    def _work_describe(self, item: _Pending | str) -> str:
        return item.key if isinstance(item, _Pending) else "metadata"

    def _work_item(self, p: _Pending | str) -> None:
        if self.failed.is_set():
            self.lost += not isinstance(p, str)
            return
        try:
            if isinstance(p, str):
                meta = json.loads(p)
                with contextlib.suppress(ValueError, KeyError, AttributeError):
                    cfg = json.loads(meta["config"])
                    devices = cfg.get("devices", {})
                    self._w.wire_formats.update({k: d["format"] for k, d in devices.items()})
                    # every sensor frame placed under base_link (the configured mounts)
                    static = ros2.static_tf_for_config(cfg, self.t_start_ns)
                    if static is not None:
                        msg = ros2.RosMessage("/tf_static", ros2.TF_TYPE, static)
                        self._w.write_ros("", [msg], self.t_start_ns,
                                          self.t_start_ns)  # fmt: skip
                self._w.add_metadata(GATEWAY_METADATA, meta)
            else:
                self._w.write(p.key, p.payload, p.attachment, p.encoding, p.t_rx_ns)
        except (ValueError, KeyError, TypeError, struct.error) as exc:
            self.skipped += 1
            log.warning("%s: sample not recorded: %s", getattr(p, "key", "metadata"), exc)
        except OSError as exc:  # disk full, I/O error: stop writing, keep draining
            self.error = exc
            self.lost += not isinstance(p, str)
            self.failed.set()

    def close(self) -> None:
        """Flush everything, write the closing metadata and the summary, close the file."""
        if self._closed:
            return
        self._closed = True
        self.stop_worker(None)
        if self.failed.is_set():  # no summary: the file is read up to its last whole chunk
            with contextlib.suppress(OSError):
                self._f.close()
            return
        try:
            self._w.finish(self.t_start_ns)
            self._f.close()
        except OSError as exc:  # the summary did not fit: readable up to the last chunk
            self.error = exc
            self.failed.set()
            with contextlib.suppress(OSError):
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
    messages: tuple[object, ...]


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
            # a recorded configuration names decoders, it opens no port: one device per port
            # is the live gateway's rule (and older recordings shared /dev/null in tests)
            info.config = GatewayConfig.model_validate_json(
                info.config_json, context={"recorded": True}
            )
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


#: the keys the recorder gives the standard ROS topics it derives (``auv/<v>/ros2/...``)
_DERIVED = re.compile(r"^auv/[^/]+/ros2/")


@dataclass
class Damage:
    """One damaged part of a recording: its byte ``offset``, what is wrong, and the log-time
    range (ns) and message count it cost (0 when not known)."""

    offset: int
    what: str
    t_start_ns: int = 0
    t_end_ns: int = 0

    def line(self, path: Path) -> str:
        span = (f"; messages {self.t_start_ns / 1e9:.3f}-{self.t_end_ns / 1e9:.3f} s lost"
                if self.t_end_ns else "")  # fmt: skip
        return f"{path}: byte {self.offset}: {self.what}{span}"


@dataclass
class ScanReport:
    """What reading a recording found: chunks read and damaged, and each :class:`Damage`."""

    chunks: int = 0
    damaged: list[Damage] = field(default_factory=list)
    messages: int = 0
    indexed: bool = False  #: read through the summary's chunk index (else a linear scan)


#: a scanned message: its schema (None: schemaless), channel and the message record
_Scanned = tuple[Schema | None, Channel, Message]


def _all_records(data: bytes, emit_chunks: bool = False) -> list[McapRecord]:
    """Every record of ``data`` (records with no magic around them, as in a chunk); the mcap
    reader signals their end with ``EndOfFile``."""
    out: list[McapRecord] = []
    reader = StreamReader(io.BytesIO(data), skip_magic=True, emit_chunks=emit_chunks,
                          record_size_limit=len(data))  # fmt: skip
    try:
        for rec in reader.records:
            out.append(rec)
    except EndOfFile:
        pass
    except Exception as exc:  # a damaged record: any error of the mcap parser
        raise ValueError(f"unreadable record ({type(exc).__name__}: {exc})") from None
    return out


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size))  # fmt: skip
    if chunk.compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(chunk.data))
    if chunk.compression == "":
        return bytes(chunk.data)
    raise ValueError(f"compression {chunk.compression!r} unknown")


def _chunk_records(chunk: Chunk) -> list[McapRecord]:
    """The records of a chunk, after its CRC is checked (a ValueError naming what is wrong)."""
    import zlib

    try:
        data = _decompress(chunk)
    except Exception as exc:  # zstd / lz4 errors have no common base
        raise ValueError(f"chunk does not decompress ({type(exc).__name__}: {exc})") from None
    if len(data) != chunk.uncompressed_size:
        raise ValueError(f"chunk holds {len(data)} bytes, its header says "
                         f"{chunk.uncompressed_size}")  # fmt: skip
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError(f"chunk CRC {zlib.crc32(data):08x}, recorded "
                         f"{chunk.uncompressed_crc:08x}")  # fmt: skip
    return _all_records(data)


def scan_recording(
    path: str | Path, report: ScanReport | None = None
) -> Iterator[_Scanned]:
    """Every message of a recording as ``(schema, channel, message)`` records in file order,
    each chunk's CRC checked: a damaged chunk costs that chunk only (a :class:`Damage` in
    ``report`` and one warning line naming the file, the byte offset and the time range lost),
    never the chunks around it nor a traceback. The file is read front to back (the records
    themselves say what is there); where a record is unreadable (a damaged chunk header, a
    recording cut short), the summary's chunk index, when it is readable, gives the next chunk
    to resume at."""
    path = Path(path)
    report = report if report is not None else ScanReport()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}

    def take(records: list[McapRecord]) -> Iterator[_Scanned]:
        for rec in records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is not None:
                    report.messages += 1
                    yield schemas.get(ch.schema_id), ch, rec

    def damaged(d: Damage) -> None:
        report.damaged.append(d)
        log.warning("%s", d.line(path))

    def chunk_messages(chunk: Chunk, at: int) -> Iterator[_Scanned]:
        report.chunks += 1
        try:
            records = _chunk_records(chunk)
        except ValueError as exc:
            damaged(Damage(at, f"damaged chunk: {exc}", chunk.message_start_time,
                           chunk.message_end_time))  # fmt: skip
            return
        yield from take(records)

    with _open(path) as f:
        _check_magic(path, f)
        try:  # the summary (a file closed properly): fallback channels and the chunk index
            summary = make_reader(f).get_summary()
        except Exception:  # no summary (recorder killed) or a damaged one
            summary = None
        if summary is not None:  # a chunk's own records (CRC-checked) replace these
            schemas.update(summary.schemas)
            channels.update(summary.channels)
        size = f.seek(0, io.SEEK_END)
        f.seek(0)
        # no record is longer than the file: a damaged length never allocates gigabytes
        stream = StreamReader(f, emit_chunks=True, record_size_limit=size)
        start = 8  # each record's offset: where the one before it ended
        seen: set[int] = set()
        try:
            for rec in stream.records:
                if isinstance(rec, Chunk):
                    seen.add(start)
                    yield from chunk_messages(rec, start)
                elif not isinstance(rec, Footer):
                    yield from take([rec])
                start = f.tell()
            # a chunk whose opcode is damaged is skipped by the reader as an unknown record: the
            # index says it was there
            for ci in summary.chunk_indexes if summary is not None else []:
                if ci.chunk_start_offset not in seen:
                    report.chunks += 1
                    damaged(Damage(ci.chunk_start_offset, "damaged chunk: its record header is "
                                   "unreadable (skipped)", ci.message_start_time,
                                   ci.message_end_time))  # fmt: skip
            if start + 8 >= size:  # the footer, then the closing magic
                return
            broken, why = start, f"the footer is followed by {size - start} more bytes"
        except Exception as exc:  # a damaged record: any error of the mcap parser, none raised
            broken = start
            why = str(exc) or type(exc).__name__
        later = sorted((ci for ci in (summary.chunk_indexes if summary else [])
                        if ci.chunk_start_offset > broken),
                       key=lambda c: c.chunk_start_offset)  # fmt: skip
        if not later:
            damaged(Damage(broken, f"unreadable from here ({why}): a recording cut short, or "
                                   "damaged with no readable index after this point"))  # fmt: skip
            return
        report.indexed = True
        damaged(Damage(broken, f"unreadable record ({why}); resumed at the next indexed chunk, "
                               f"byte {later[0].chunk_start_offset}"))  # fmt: skip
        for ci in later:
            f.seek(ci.chunk_start_offset)
            recs = _all_records(f.read(ci.chunk_length), emit_chunks=True)
            chunk = next((r for r in recs if isinstance(r, Chunk)), None)
            if chunk is None:
                report.chunks += 1
                damaged(Damage(ci.chunk_start_offset, "damaged chunk: no chunk record where the "
                               "index points", ci.message_start_time, ci.message_end_time))
                continue
            yield from chunk_messages(chunk, ci.chunk_start_offset)


def iter_samples(path: str | Path, report: ScanReport | None = None) -> Iterator[RecordedSample]:
    """Every recorded message in file order (per key, the order the recorder received them),
    each chunk's CRC checked (:func:`scan_recording`: a damaged chunk costs that chunk only, one
    warning line and a :class:`Damage` in ``report``). A recording cut short (recorder killed)
    yields what was written."""
    for schema, channel, msg in scan_recording(path, report):
        if _DERIVED.match(channel.metadata.get("key", "")):
            continue  # /tf, /tf_static, /diagnostics: for ROS readers, not bus samples
        zenc = channel.metadata.get("zenoh_encoding", "")
        try:
            if channel.message_encoding == MESSAGE_ENCODING and schema is not None:
                yield _ros2_sample(schema.name, channel.metadata, channel.topic, msg, zenc)
            elif channel.message_encoding == RAW_ENCODING:
                att, payload = unpack_raw_record(msg.data)
                yield RecordedSample(
                    channel.topic, msg.log_time, att or None, payload, RAW_ENCODING, zenc
                )
            else:
                yield RecordedSample(
                    channel.topic, msg.log_time, None, msg.data, channel.message_encoding, zenc
                )
        except Exception as exc:  # a record CRC-valid but not ours to read: that one only
            if report is not None:
                report.damaged.append(Damage(0, f"{channel.topic}: message unreadable: {exc}",
                                             msg.log_time, msg.log_time))  # fmt: skip
            log.warning("%s: %s at %d ns: unreadable message skipped (%s)", path, channel.topic,
                        msg.log_time, exc)  # fmt: skip


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


def _ros2_sample(
    type_name: str, meta: Mapping[str, str], topic: str, msg: Message, zenc: str
) -> RecordedSample:
    """A recorded ROS 2 message as the bus sample it came from: raw frames with their
    attachment, Decoded messages with their JSON text, standard types as CDR bytes."""
    key = meta.get("key", topic)
    if type_name == ros2.RAW_FRAME_TYPE:
        m = ros2.read_raw_frame(msg.data)
        t_ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        att = pack_raw_attachment(t_ns, m.seq, m.stream_offset)
        return RecordedSample(key, msg.log_time, att, bytes(m.data), RAW_ENCODING, zenc)
    if type_name == ros2.DECODED_TYPE:
        d = ros2.read_decoded(msg.data)
        return RecordedSample(key, msg.log_time, None, d.json.encode(), "json", zenc)
    return RecordedSample(key, msg.log_time, None, msg.data, MESSAGE_ENCODING, zenc)


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
                msgs: tuple[object, ...] = (json.loads(s.payload),)
            except ValueError:
                msgs = ()
            yield Recorded(s.key, s.log_time_ns, s.payload, msgs)
