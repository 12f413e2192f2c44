"""From transport chunks to (raw frame, decoded messages): the one decode path shared by the
gateway, ``auvgw replay`` and offline tools, so a replay decodes exactly as the live run did.

Byte-stream devices go through their format's framer; CAN devices deliver one frame per chunk,
carried raw as ``u32 arbitration id | u8 flags (bit0 extended) | data`` (:func:`pack_can_raw`).
The raw frame is what goes on the bus (``auv/<v>/raw/<device>``); :meth:`DeviceDecoder.decode_raw`
turns it into messages, live and in replay alike.
"""

from __future__ import annotations

import struct
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from auvgw.config.gateway import ConfigError, DeviceConfig, GatewayConfig
from auvgw.drivers import registry
from auvgw.drivers.formats import Format, format_from_table, get_format
from auvgw.drivers.framing import ErrorPolicy, Frame, Framer
from auvgw.envelope import Packed, layout_body

if TYPE_CHECKING:
    from auvgw.drivers.can_codec import CanDeviceCodec
    from auvgw.drivers.transports import Chunk

__all__ = [
    "DecodedItem",
    "DecoderCounts",
    "DeviceDecoder",
    "make_decoder",
    "make_decoders",
    "message_kind",
    "message_type",
    "pack_can_raw",
    "unpack_can_raw",
]

_CAN_HEAD = struct.Struct("<IB")


def pack_can_raw(can_id: int, is_extended_id: bool, data: bytes) -> bytes:
    """Raw bus form of one CAN frame."""
    return _CAN_HEAD.pack(can_id, 1 if is_extended_id else 0) + bytes(data)


def unpack_can_raw(raw: bytes) -> tuple[int, bool, bytes]:
    """(arbitration id, is_extended_id, data) of a raw CAN frame."""
    can_id, flags = _CAN_HEAD.unpack_from(raw)
    return can_id, bool(flags & 1), raw[_CAN_HEAD.size :]


def message_type(msg: object) -> str:
    """A decoded message's type name (its ``TYPE`` or class name), as in ``to_jsonable``."""
    return str(getattr(msg, "TYPE", type(msg).__name__))


def kind_of(type_name: str) -> str:
    """The ``<kind>`` key segment of a message type name (the device registry's public kinds,
    :func:`auvgw.drivers.registry.kind_of`: ``pd0.Ensemble`` -> ``ensemble``, ``Hn100Nav`` and
    ``HN100_Sample`` -> ``ins``)."""
    return registry.kind_of(type_name)


def message_kind(msg: object) -> str:
    """The ``<kind>`` key segment of a decoded message (:func:`kind_of` its type name)."""
    return kind_of(message_type(msg))


@dataclass(frozen=True, slots=True)
class DecodedItem:
    """One frame: its raw bytes, stream offset, decoded messages, or the decode error text."""

    raw: bytes
    offset: int
    messages: tuple[object, ...] = ()
    error: str | None = None


@dataclass
class DecoderCounts:
    """Framing counters of a device since its decoder was made (all connections)."""

    frames: int = 0
    bad_frames: int = 0
    skipped_bytes: int = 0
    reasons: Counter[str] = field(default_factory=Counter)


class DeviceDecoder:
    """Stateful framing + stateless decoding of one device's stream.

    Bad frames are counted (with their reasons), never logged one by one: a garbage stream
    would flood the log; the gateway reports the counts in the device status instead.
    """

    def __init__(
        self,
        name: str,
        fmt: Format | None,
        can_codec: CanDeviceCodec | None = None,
        datagrams: bool = False,
        max_partial_age_s: float | None = None,
    ) -> None:
        if (fmt is None) == (can_codec is None):
            raise ValueError("a device decoder needs a format or a CAN codec, not both")
        self.name = name
        #: each chunk is a datagram, framed on its own (UDP): a bad one costs itself only
        self.datagrams = datagrams
        #: host seconds a partial frame may wait for its bytes before :meth:`expire` drops it
        self.max_partial_age_s = max_partial_age_s
        self.format = fmt
        self.can = can_codec
        self._framer: Framer | None = None
        self._closed = DecoderCounts()
        self._reasons: Counter[str] = Counter()
        self._reasons_at = 0  # the bad-frame total ``_reasons`` was summed at
        self.reset()

    def reset(self) -> None:
        """Start a new stream (after a reconnect): forget a partial frame; counters carry on."""
        if self._framer is not None:
            s = self._framer.stats
            self._closed.frames += s.frames
            self._closed.bad_frames += s.bad_frames
            self._closed.skipped_bytes += s.skipped_bytes
            self._closed.reasons.update(s.reasons)
        self._framer = (
            self.format.framer(policy=ErrorPolicy.IGNORE, source=self.name)
            if self.format is not None
            else None
        )

    def counts(self) -> DecoderCounts:
        """Totals since creation: (frames, bad frames, skipped bytes, bad-frame reasons). The
        gateway asks after every chunk: the reasons (a new Counter, never changed afterwards)
        are summed again only when the bad-frame total has moved."""
        c = self._closed
        s = self._framer.stats if self._framer is not None else None
        bad = c.bad_frames + (s.bad_frames if s is not None else 0)
        if bad != self._reasons_at:
            self._reasons = c.reasons + s.reasons if s is not None else Counter(c.reasons)
            self._reasons_at = bad
        if s is None:
            return DecoderCounts(c.frames, bad, c.skipped_bytes, self._reasons)
        return DecoderCounts(
            c.frames + s.frames, bad, c.skipped_bytes + s.skipped_bytes, self._reasons
        )

    def decode_raw(self, raw: bytes, verified: bool = False) -> tuple[object, ...]:
        """Messages of one raw frame as published on the bus (raises on undecodable content);
        ``verified``: the frame came out of this decoder's framer, its checksum is not checked
        again (replay and offline tools leave it False: their bytes are checked)."""
        if self.can is not None:
            can_id, ext, data = unpack_can_raw(raw)
            msg = self.can.decode(can_id, data, is_extended_id=ext)
            return () if msg is None else (msg,)
        assert self.format is not None
        return tuple(self.format.decode_frame(raw, verified))

    def item(self, raw: bytes, offset: int = 0, verified: bool = False) -> DecodedItem:
        """Decode one raw frame; an error (any exception of the codec) becomes the item's text."""
        try:
            return DecodedItem(raw, offset, self.decode_raw(raw, verified))
        except Exception as exc:  # a codec failing on odd content must not stop the device
            where = f"frame at byte offset {offset}" if self.can is None else "CAN frame"
            return DecodedItem(
                raw, offset, (), f"{self.name}: {where}: {type(exc).__name__}: {exc}"
            )

    def envelope_body(self, raw: bytes) -> tuple[str, int, list[Packed]] | None:
        """(type, schema, body) of the envelope of a frame this decoder's framer delivered,
        read straight from its bytes (:func:`auvgw.envelope.layout_body`): the envelope of the
        message :meth:`item` decodes, byte for byte. None where the format has no such path or
        the frame would not decode (:meth:`item` then gives its error)."""
        layout = self.format.layout if self.format is not None else None
        if layout is None:
            return None
        try:
            return layout_body(layout(raw), raw)
        except Exception:  # the decode's error, which item() reports
            return None

    def frames(self, chunk: Chunk) -> list[Frame]:
        """Raw frames completed by one transport chunk (a
        :class:`~auvgw.drivers.transports.Chunk`), not decoded yet (:meth:`item` with
        :attr:`verified`)."""
        if self.can is not None:
            if chunk.can_id is None:
                raise ValueError(f"{self.name}: a CAN decoder was given a chunk with no CAN id")
            self._closed.frames += 1
            return [Frame(pack_can_raw(chunk.can_id, chunk.is_extended_id, chunk.data), 0)]
        assert self._framer is not None
        if self.datagrams:
            return self._framer.feed_datagram(chunk.data)
        return self._framer.feed(chunk.data, time.monotonic())

    @property
    def verified(self) -> bool:
        """Frames of :meth:`frames` passed this decoder's framer (CAN frames have none)."""
        return self.can is None

    def feed(self, chunk: Chunk) -> list[DecodedItem]:
        """Items completed by one transport chunk (:meth:`frames`, decoded)."""
        return [self.item(f.data, f.offset, self.verified) for f in self.frames(chunk)]

    def has_stale(self, now: float) -> bool:
        """A partial frame has waited more than ``max_age`` (host monotonic seconds ``now``)."""
        if self._framer is None or self.max_partial_age_s is None:
            return False
        since = self._framer.waiting_s
        return since is not None and now - since > self.max_partial_age_s

    def expire(self, now: float) -> list[Frame]:
        """Drop a partial frame older than ``max_partial_age_s`` (host monotonic seconds ``now``;
        counted, reason ``stale``) and return the frames that were queued behind it."""
        if self._framer is None or self.max_partial_age_s is None:
            return []
        return self._framer.expire(now, self.max_partial_age_s)

    def finish(self) -> list[Frame]:
        """End of a finite stream: judge the bytes left (an incomplete frame is a bad frame)."""
        if self._framer is None:
            return []
        return self._framer.finish()


def make_decoder(cfg: DeviceConfig, name: str = "") -> DeviceDecoder:
    """The decoder a device's configuration asks for (site tables and DBCs resolved here)."""
    if cfg.format == registry.CAN_FORMAT:
        from auvgw.drivers.can_codec import load_can_codec

        assert cfg.dbc is not None  # the model refuses a CAN device without one
        return DeviceDecoder(name, None, load_can_codec(cfg.dbc))
    fmt = format_from_table(cfg.format, cfg.table) if cfg.table else get_format(cfg.format)
    return DeviceDecoder(
        name, fmt, datagrams=cfg.transport.kind == "udp",
        max_partial_age_s=cfg.partial_frame_max_age_s,
    )  # fmt: skip


def make_decoders(cfg: GatewayConfig) -> dict[str, DeviceDecoder]:
    """A decoder per enabled device; a format, table or DBC that cannot be loaded is a
    :class:`ConfigError` naming the file and the device's field."""
    out: dict[str, DeviceDecoder] = {}
    src = cfg.source or "<config>"
    for name, dcfg in cfg.devices.items():
        if not dcfg.enabled:
            continue
        what = "dbc" if dcfg.format == registry.CAN_FORMAT else "table" if dcfg.table else "format"
        try:
            out[name] = make_decoder(dcfg, name)
        except ImportError as exc:
            raise ConfigError(
                f"{src}: devices.{name}.{what}: format {dcfg.format!r} is not available in this "
                f"build ({exc})"
            ) from exc
        except (OSError, ValueError, KeyError) as exc:
            value = getattr(dcfg, what)
            raise ConfigError(
                f"{src}: devices.{name}.{what}: cannot load {value!r}: {type(exc).__name__}: {exc}"
            ) from exc
    return out
