"""GeoSwath Plus raw data: the RDF file (file header + pings) and the broadcast ping stream.

The layout is a declared, site-editable table, ``config/geoswath.toml``, reconstructed from the
vendor's rdf.h as MB-System's ``mbsys_geoswath.h`` reproduces it (line order scrambled) and GSF's
``gsfGeoSwathPlusSpecific``; every choice is written down in ``docs/protocols/geoswath.md``.

A file is one :class:`RdfFileHeader` followed by pings; the broadcast form is the pings alone.
A ping (:class:`GeoSwathPing`) is a fixed ping header, then per-ping arrays whose counts the
header gives (RAA samples, NAV, MRU, GYRO, ECHO, MINISVS, AUXDATA), then raw sensor strings.
Values are kept as on the wire (the table's units: degrees, wavelengths, ...): the codec is a
byte-exact round trip; conversion to SI belongs to the swath processing.

The format has no sync word and no checksum: :class:`GeoSwathFramer` accepts a ping only when
its header is self-consistent (counts and string sizes within the table's bounds, ``ping_size``
equal to the size the counts imply, a known side, a finite positive time, and in a file a
``previous_ping_position`` linking to the last ping seen) and resyncs one byte on.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from auvgw.drivers.framing import BadFrame, FramerStats
from auvgw.drivers.tablecodec import TableError, load_toml
from auvgw.ground.errors import DataError
from auvgw.ground.paths import config_file

__all__ = [
    "GeoSwathCodec",
    "GeoSwathFramer",
    "GeoSwathLayout",
    "GeoSwathPing",
    "RdfFileHeader",
    "default_codec",
    "read_rdf",
]

_TYPES = {
    "u8": "u1",
    "u16": "u2",
    "u32": "u4",
    "s16": "i2",
    "s32": "i4",
    "f32": "f4",
    "f64": "f8",
}
_SIDES = (0, 1)


def _dtype(source: str, where: str, rows: Any, order: str) -> np.dtype[Any]:
    """Packed numpy record type of a table's ``fields`` list."""
    if not isinstance(rows, list) or not rows:
        raise TableError(f"{source}: {where}.fields: expected a non-empty list of fields")
    names, formats = [], []
    for i, row in enumerate(rows):
        at = f"{source}: {where}.fields[{i}]"
        if not isinstance(row, dict) or not isinstance(row.get("name"), str):
            raise TableError(f"{at}: expected a table with a 'name'")
        kind = row.get("type")
        if kind == "bytes":
            size = row.get("size")
            if not isinstance(size, int) or size <= 0:
                raise TableError(f"{at} ({row['name']}): 'bytes' needs a positive integer size")
            formats.append(f"V{size}")
        elif kind in _TYPES:
            formats.append(order + _TYPES[kind])
        else:
            raise TableError(
                f"{at} ({row['name']}): type {kind!r} not one of bytes, {', '.join(_TYPES)}"
            )
        if not isinstance(row.get("source"), str):
            raise TableError(f"{at} ({row['name']}): every field says its 'source'")
        names.append(row["name"])
    if len(set(names)) != len(names):
        raise TableError(f"{source}: {where}: duplicate field names")
    return np.dtype({"names": names, "formats": formats})  # packed: no padding


def _section(doc: Mapping[str, Any], key: str, source: str) -> Mapping[str, Any]:
    sec = doc.get(key)
    if not isinstance(sec, dict):
        raise TableError(f"{source}: [{key}] missing")
    return sec


@dataclass(frozen=True)
class GeoSwathLayout:
    """The table: record types (packed numpy dtypes) and the framer's bounds."""

    source: str
    file_header: np.dtype[Any]
    ping_header: np.dtype[Any]
    #: (array name, ping header count field, record dtype), in wire order
    arrays: tuple[tuple[str, str, np.dtype[Any]], ...]
    #: ping header fields sizing the raw string blocks, in wire order
    strings: tuple[str, ...]
    max_samples: int
    max_ping_size: int
    max_string_size: int

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> GeoSwathLayout:
        """The layout of the table at ``path`` (default: the shipped ``config/geoswath.toml``);
        :class:`TableError` naming the file and the entry when it is not valid."""
        path = Path(path) if path is not None else config_file("geoswath.toml")
        doc, src = load_toml(path), str(path)
        order = {"little": "<", "big": ">"}.get(doc.get("byte_order", ""))
        if order is None:
            raise TableError(f"{src}: byte_order must be 'little' or 'big'")
        fh = _dtype(src, "file_header", _section(doc, "file_header", src).get("fields"), order)
        ph = _dtype(src, "ping_header", _section(doc, "ping_header", src).get("fields"), order)
        for need in ("raw_header_size", "raw_ping_header_size"):
            if need not in (fh.names or ()):
                raise TableError(f"{src}: file_header: field {need!r} is required")
        for need in ("ping_size", "previous_ping_position", "side", "ping_time"):
            if need not in (ph.names or ()):
                raise TableError(f"{src}: ping_header: field {need!r} is required")
        arrays = []
        for i, arr in enumerate(doc.get("arrays", [])):
            name, count = arr.get("name"), arr.get("count")
            if (
                not isinstance(name, str)
                or count not in (ph.names or ())
                or ph[count].kind not in "iu"
            ):
                raise TableError(
                    f"{src}: arrays[{i}]: needs a 'name' and a 'count' naming an integer "
                    f"ping_header field (got {count!r})"
                )
            arrays.append(
                (name, count, _dtype(src, f"arrays[{i}] ({name})", arr.get("fields"), order))
            )
        strings = tuple(_section(doc, "strings", src).get("sizes", []))
        for s in strings:
            if s not in (ph.names or ()) or ph[s].kind not in "iu":
                raise TableError(f"{src}: strings.sizes: {s!r} is not an integer ping_header field")
        b = _section(doc, "bounds", src)
        bounds: list[int] = []
        for key in ("max_samples", "max_ping_size", "max_string_size"):
            v = b.get(key)
            if not isinstance(v, int) or v <= 0:
                raise TableError(f"{src}: [bounds] {key}: expected a positive integer, got {v!r}")
            bounds.append(v)
        return cls(src, fh, ph, tuple(arrays), strings, *bounds)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class RdfFileHeader:
    """The RDF file header: each table field's wire value (``bytes`` fields as bytes)."""

    fields: Mapping[str, Any]


@dataclass(frozen=True, eq=False)
class GeoSwathPing:
    """One ping of one side: ``header`` (ping header fields, wire values), ``arrays`` (name ->
    read-only numpy record array, e.g. ``arrays["raa"]["sine"]``) and the raw sensor string
    blocks, in table order."""

    header: Mapping[str, Any]
    arrays: Mapping[str, np.ndarray]
    strings: tuple[bytes, ...]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GeoSwathPing):
            return NotImplemented
        return (
            dict(self.header) == dict(other.header)
            and self.strings == other.strings
            and self.arrays.keys() == other.arrays.keys()
            and all(self.arrays[k].tobytes() == other.arrays[k].tobytes() for k in self.arrays)
        )

    __hash__ = None  # type: ignore[assignment]


def _record_values(rec: np.void) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in rec.dtype.names or ():
        v = rec[name]
        out[name] = bytes(v) if rec.dtype[name].kind == "V" else v.item()
    return out


class GeoSwathCodec:
    """Decode and encode RDF file headers and pings under one :class:`GeoSwathLayout`."""

    def __init__(self, layout: GeoSwathLayout) -> None:
        self.layout = layout

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> GeoSwathCodec:
        """The codec of the table at ``path`` (default: the shipped table)."""
        return cls(GeoSwathLayout.from_toml(path))

    # -- sizes and checks -------------------------------------------------------------------
    def data_size(self, header: Mapping[str, Any]) -> int:
        """Bytes of ping data the header's counts and string sizes imply."""
        lay = self.layout
        size = sum(int(header[c]) * dt.itemsize for _, c, dt in lay.arrays)
        return size + sum(int(header[s]) for s in lay.strings)

    def check_header(self, header: Mapping[str, Any]) -> str | None:
        """Why the ping header cannot start a valid ping (a short reason), or None."""
        lay = self.layout
        for name, count, _ in lay.arrays:
            n = int(header[count])
            limit = lay.max_samples if name == "raa" else 255
            if not 0 <= n <= limit:
                return f"count {count} = {n} outside 0..{limit}"
        for s in lay.strings:
            if not 0 <= int(header[s]) <= lay.max_string_size:
                return f"size {s} = {header[s]} outside 0..{lay.max_string_size}"
        size = int(header["ping_size"])
        if not 0 <= size <= lay.max_ping_size:
            return f"ping_size {size} outside 0..{lay.max_ping_size}"
        want = self.data_size(header)
        if size != want:
            return f"ping_size {size} but the counts give {want}"
        if header["side"] not in _SIDES:
            return f"side {header['side']} not 0 (port) or 1 (starboard)"
        t = float(header["ping_time"])
        if not (math.isfinite(t) and t > 0):
            return f"ping_time {t} not a finite positive time"
        return None

    # -- file header --------------------------------------------------------------------------
    def decode_file_header(self, data: bytes | bytearray | memoryview) -> RdfFileHeader:
        """The file header in ``data`` (exactly its size); :class:`DataError` if not valid."""
        dt = self.layout.file_header
        if len(data) != dt.itemsize:
            raise DataError(
                f"{len(data)} bytes, the file header has {dt.itemsize}", field="RdfFileHeader"
            )
        fields = _record_values(np.frombuffer(data, dtype=dt)[0])
        for name, want in (
            ("raw_header_size", dt.itemsize),
            ("raw_ping_header_size", self.layout.ping_header.itemsize),
        ):
            if fields[name] != want:
                raise DataError(
                    f"{name} = {fields[name]}, the table ({self.layout.source}) says {want}",
                    field=f"RdfFileHeader.{name}",
                    offset=dt.fields[name][1] if dt.fields else None,
                )
        return RdfFileHeader(MappingProxyType(fields))

    def encode_file_header(self, msg: RdfFileHeader) -> bytes:
        """The wire bytes of a file header."""
        return _pack(self.layout.file_header, msg.fields)

    # -- pings ----------------------------------------------------------------------------------
    def decode_header(
        self, data: bytes | bytearray | memoryview, offset: int = 0
    ) -> dict[str, Any]:
        """The ping header fields at ``data[offset:]`` (wire values, unchecked)."""
        return _record_values(
            np.frombuffer(data, dtype=self.layout.ping_header, count=1, offset=offset)[0]
        )

    def decode(self, frame: bytes | bytearray | memoryview) -> GeoSwathPing:
        """One ping (header + data, exactly); :class:`DataError` naming the field if not valid."""
        hsize = self.layout.ping_header.itemsize
        if len(frame) < hsize:
            raise DataError(
                f"{len(frame)} bytes, shorter than the {hsize}-byte ping header",
                field="GeoSwathPing",
            )
        header = self.decode_header(frame)
        reason = self.check_header(header)
        if reason is not None:
            raise DataError(reason, field="GeoSwathPing.header")
        if len(frame) != hsize + int(header["ping_size"]):
            raise DataError(
                f"{len(frame)} bytes, the header says {hsize} + {header['ping_size']}",
                field="GeoSwathPing.ping_size",
            )
        arrays, pos = {}, hsize
        for name, count, dt in self.layout.arrays:
            n = int(header[count])
            arrays[name] = _frozen(np.frombuffer(frame, dtype=dt, count=n, offset=pos).copy())
            pos += n * dt.itemsize
        strings = []
        for s in self.layout.strings:
            n = int(header[s])
            strings.append(bytes(frame[pos : pos + n]))
            pos += n
        return GeoSwathPing(MappingProxyType(header), MappingProxyType(arrays), tuple(strings))

    def encode(self, msg: GeoSwathPing) -> bytes:
        """The wire bytes of a ping; :class:`ValueError` if its counts disagree with its data."""
        header = dict(msg.header)
        parts = []
        for name, count, dt in self.layout.arrays:
            arr = np.asarray(msg.arrays.get(name, np.zeros(0, dt)))
            if len(arr) != int(header[count]):
                raise ValueError(
                    f"GeoSwathPing.{name}: {len(arr)} records, header {count} = {header[count]}"
                )
            parts.append(arr.astype(dt, copy=False).tobytes())
        if len(msg.strings) != len(self.layout.strings):
            raise ValueError(
                f"GeoSwathPing.strings: {len(msg.strings)} blocks, "
                f"the table has {len(self.layout.strings)}"
            )
        for s, block in zip(self.layout.strings, msg.strings, strict=True):
            if len(block) != int(header[s]):
                raise ValueError(
                    f"GeoSwathPing.strings: {len(block)} bytes, header {s} = {header[s]}"
                )
            parts.append(bytes(block))
        body = b"".join(parts)
        if int(header["ping_size"]) != len(body):
            raise ValueError(
                f"GeoSwathPing.ping_size = {header['ping_size']}, data has {len(body)} bytes"
            )
        return _pack(self.layout.ping_header, header) + body

    def make_ping(
        self,
        header: Mapping[str, Any],
        arrays: Mapping[str, np.ndarray] | None = None,
        strings: Iterable[bytes] | None = None,
    ) -> GeoSwathPing:
        """A ping from header values (missing ones 0) and data; counts, string sizes and
        ``ping_size`` are filled in from the data."""
        lay = self.layout
        h: dict[str, Any] = {n: 0 for n in lay.ping_header.names or ()}
        for n in lay.ping_header.names or ():
            if lay.ping_header[n].kind == "V":
                h[n] = bytes(lay.ping_header[n].itemsize)
        h.update(header)
        arrays = dict(arrays or {})
        out = {}
        for name, count, dt in lay.arrays:
            arr = np.asarray(arrays.pop(name, np.zeros(0, dt))).astype(dt)
            h[count] = len(arr)
            out[name] = _frozen(arr)
        if arrays:
            raise ValueError(
                f"unknown arrays {sorted(arrays)} (table has {[a[0] for a in lay.arrays]})"
            )
        blocks = tuple(bytes(b) for b in (strings or [b""] * len(lay.strings)))
        for s, block in zip(lay.strings, blocks, strict=True):
            h[s] = len(block)
        h["ping_size"] = self.data_size(h)
        return GeoSwathPing(MappingProxyType(h), MappingProxyType(out), blocks)


def _pack(dt: np.dtype[Any], values: Mapping[str, Any]) -> bytes:
    rec = np.zeros(1, dtype=dt)
    for name in dt.names or ():
        v = values[name]
        if dt[name].kind == "V":
            if len(v) != dt[name].itemsize:
                raise ValueError(f"{name}: {len(v)} bytes, the table has {dt[name].itemsize}")
            rec[name] = np.void(bytes(v))
        else:
            rec[name] = v
    return rec.tobytes()


@functools.cache
def default_codec() -> GeoSwathCodec:
    """The codec of the shipped table (read on first use)."""
    return GeoSwathCodec.from_toml()


class GeoSwathFramer:
    """Cuts an RDF file (``file_mode=True``: file header, then pings) or a broadcast stream
    (pings only) into records; :meth:`feed` returns ``(offset, bytes)`` per whole record.

    A record whose header is not self-consistent, or whose claimed size exceeds the table's
    bound, is refused at once and the search resumes one byte on; a file's
    ``previous_ping_position`` must point at the last ping seen (or, after a refused stretch,
    between it and this one). ``stats`` counts frames, bad frames (by reason) and skipped bytes.
    """

    def __init__(self, codec: GeoSwathCodec | None = None, file_mode: bool = False) -> None:
        self.codec = codec or default_codec()
        self.file_mode = file_mode
        self.stats = FramerStats()
        self.file_header: RdfFileHeader | None = None
        self._need_file_header = file_mode
        self._buf = bytearray()
        self._base = 0
        self._last_ping: int | None = None  # stream offset of the last ping accepted
        self._bad_since = False  # a stretch was refused since that ping
        self._refusing = False  # inside a refused stretch (counted once, across chunks)

    def _check(self, start: int) -> int:
        """Size of the valid record at ``_buf[start]``, 0 if more bytes are needed."""
        lay, buf = self.codec.layout, self._buf
        if self._need_file_header:
            n = lay.file_header.itemsize
            if len(buf) - start < n:
                return 0
            try:
                self.file_header = self.codec.decode_file_header(memoryview(buf)[start : start + n])
            except DataError as exc:
                raise BadFrame(f"file_header: {exc.reason}") from None
            return n
        hsize = lay.ping_header.itemsize
        if len(buf) - start < hsize:
            return 0
        header = self.codec.decode_header(buf, start)
        reason = self.codec.check_header(header)
        if reason is None and self.file_mode:
            prev, here = int(header["previous_ping_position"]), self._base + start
            last = self._last_ping
            if last is None:
                ok = prev == -1 or (self._bad_since and 0 <= prev < here)
            else:
                ok = prev == last or (self._bad_since and last < prev < here)
            if not ok:
                reason = f"previous_ping_position {prev} does not link to the last ping ({last})"
        if reason is not None:
            raise BadFrame(reason)
        total = hsize + int(header["ping_size"])
        return total if len(buf) - start >= total else 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        """Add bytes; return every record they complete, in order, with its stream offset."""
        self._buf += chunk
        self.stats.bytes_in += len(chunk)
        return self._scan()

    def finish(self) -> list[tuple[int, bytes]]:
        """End of stream: a record left incomplete is counted as truncated."""
        return self._scan_to_end()

    def feed_datagram(self, datagram: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        """One broadcast datagram framed on its own: what it leaves incomplete is counted as
        truncated, never prepended to the next datagram."""
        self._buf += datagram
        self.stats.bytes_in += len(datagram)
        return self._scan_to_end()

    def _scan_to_end(self) -> list[tuple[int, bytes]]:
        return self._scan(eof=True)

    def _scan(self, eof: bool = False) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        i, buf = 0, self._buf
        while i < len(buf):
            try:
                n = self._check(i)
                if n == 0 and eof:
                    raise BadFrame(f"truncated: the stream ends {len(buf) - i} bytes into it")
            except BadFrame as exc:
                if not self._refusing:  # one bad frame per refused stretch, not per byte
                    self.stats.bad_frames += 1
                    self.stats.reasons[exc.reason.split(" ")[0].rstrip(":")] += 1
                    self._refusing = True
                self.stats.skipped_bytes += 1
                self._bad_since = True
                i += 1
                continue
            if n == 0:
                break
            self._refusing = False
            out.append((self._base + i, bytes(buf[i : i + n])))
            self.stats.frames += 1
            if self._need_file_header:
                self._need_file_header = False
            else:
                self._last_ping, self._bad_since = self._base + i, False
            i += n
        del buf[:i]
        self._base += i
        return out


def read_rdf(
    path: str | Path, codec: GeoSwathCodec | None = None
) -> Iterator[RdfFileHeader | GeoSwathPing]:
    """The file header, then the pings of an RDF file, in order; bad stretches are skipped and
    counted by the framer (bytes before the first valid file header included)."""
    framer = GeoSwathFramer(codec, file_mode=True)
    header_done = False
    with open(path, "rb") as fh:
        chunks = iter(lambda: fh.read(1 << 16), b"")
        for recs in [*(framer.feed(c) for c in chunks), framer.finish()]:
            for _, data in recs:
                if not header_done:
                    header_done = True
                    assert framer.file_header is not None
                    yield framer.file_header
                else:
                    yield framer.codec.decode(data)
