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
from typing import Any, ClassVar

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import (
    BadFrame,
    DecodeError,
    ErrorPolicy,
    Frame,
    FrameError,
    Framer,
    FramerStats,
    read_file_frames,
)
from auvgw.drivers.spec import MESSAGE_TYPES
from auvgw.drivers.tablecodec import TableError, load_toml
from auvgw.ground.errors import DataError
from auvgw.ground.paths import config_file

__all__ = [
    "FORMAT",
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


#: the file header's ``raw_header_size`` and ``raw_ping_header_size`` (bytes 4-7) of the shipped
#: table: how a stream says it is a file (a ping has the low bytes of its f64 time there)
def _file_magic(layout: GeoSwathLayout) -> bytes | None:
    fh = layout.file_header
    names = ("raw_header_size", "raw_ping_header_size")
    off = [fh.fields[n][1] for n in names] if fh.fields else []
    if len(off) != 2 or off[1] != off[0] + fh["raw_header_size"].itemsize:
        return None  # a site table that moved them: files are then read with file_mode=True
    return _pack(
        np.dtype([(n, fh[n]) for n in ("raw_header_size", "raw_ping_header_size")]),
        {"raw_header_size": fh.itemsize, "raw_ping_header_size": layout.ping_header.itemsize},
    )


@dataclass(frozen=True)
class RdfFileHeader:
    """The RDF file header: each table field's wire value (``bytes`` fields as bytes)."""

    TYPE: ClassVar[str] = "RdfFileHeader"
    fields: Mapping[str, Any]

    def __post_init__(self) -> None:
        object.__setattr__(self, "fields", MappingProxyType(dict(self.fields)))


@dataclass(frozen=True, eq=False)
class GeoSwathPing:
    """One ping of one side: ``header`` (ping header fields, wire values), ``arrays`` (array
    name -> field name -> read-only 1-D column, e.g. ``arrays["raa"]["sine"]``; a ``bytes``
    field is an (n, size) uint8 column) and the raw sensor string blocks, in table order."""

    TYPE: ClassVar[str] = "GeoSwathPing"
    header: Mapping[str, Any]
    arrays: Mapping[str, Mapping[str, np.ndarray]]
    strings: tuple[bytes, ...]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GeoSwathPing):
            return NotImplemented
        return (
            dict(self.header) == dict(other.header)
            and self.strings == other.strings
            and self.arrays.keys() == other.arrays.keys()
            and all(
                self.arrays[k].keys() == other.arrays[k].keys()
                and all(
                    np.array_equal(self.arrays[k][f], other.arrays[k][f]) for f in self.arrays[k]
                )
                for k in self.arrays
            )
        )

    __hash__ = None  # type: ignore[assignment]

    def __post_init__(self) -> None:  # read-only whatever it is built from (a bus reader)
        arrays = {
            k: MappingProxyType({f: c if not c.flags.writeable else _frozen(c.copy())
                                 for f, c in cols.items()})
            for k, cols in self.arrays.items()
        }  # fmt: skip
        object.__setattr__(self, "header", MappingProxyType(dict(self.header)))
        object.__setattr__(self, "arrays", MappingProxyType(arrays))
        object.__setattr__(self, "strings", tuple(bytes(b) for b in self.strings))

    def count(self, name: str) -> int:
        """Records in array ``name``."""
        cols = self.arrays[name]
        return len(next(iter(cols.values()))) if cols else 0


MESSAGE_TYPES[RdfFileHeader.TYPE] = RdfFileHeader
MESSAGE_TYPES[GeoSwathPing.TYPE] = GeoSwathPing


def _record_values(rec: np.void) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in rec.dtype.names or ():
        v = rec[name]
        out[name] = bytes(v) if rec.dtype[name].kind == "V" else v.item()
    return out


def _columns(rec: np.ndarray) -> MappingProxyType[str, np.ndarray]:
    """Read-only columns of a record array (``bytes`` fields as (n, size) uint8)."""
    out = {}
    for name in rec.dtype.names or ():
        col = rec[name]
        if col.dtype.kind == "V":
            col = np.ascontiguousarray(col).view(np.uint8).reshape(len(rec), col.dtype.itemsize)
        out[name] = _frozen(col) if col.flags.writeable else col
    return MappingProxyType(out)


def _records(dt: np.dtype[Any], cols: Any) -> np.ndarray:
    """The record array of ``cols`` (a record array, or field name -> column)."""
    if isinstance(cols, np.ndarray) and cols.dtype.names:
        return cols.astype(dt, copy=False)
    names = dt.names or ()
    missing = [n for n in names if n not in cols]
    if missing and len(missing) == len(names):
        raise ValueError(f"no field of {list(names)} given")
    n = len(next(iter(cols[f] for f in names if f in cols)))
    rec = np.zeros(n, dt)
    for name in names:
        if name not in cols:
            continue
        col = np.asarray(cols[name])
        if dt[name].kind == "V":
            size = dt[name].itemsize
            col = np.ascontiguousarray(col, dtype=np.uint8).reshape(n, size).view(dt[name])[:, 0]
        rec[name] = col
    return rec


class GeoSwathCodec:
    """Decode and encode RDF file headers and pings under one :class:`GeoSwathLayout`."""

    def __init__(self, layout: GeoSwathLayout) -> None:
        self.layout = layout
        self.file_magic = _file_magic(layout)

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> GeoSwathCodec:
        """The codec of the table at ``path`` (default: the shipped table)."""
        return cls(GeoSwathLayout.from_toml(path))

    def framer(
        self, policy: ErrorPolicy | str = ErrorPolicy.LOG, source: str = ""
    ) -> GeoSwathFramer:
        """A framer of this table (a file or a broadcast stream, told apart by its start)."""
        return GeoSwathFramer(self, policy=policy, source=source)

    # -- sizes and checks -------------------------------------------------------------------
    def data_size(self, header: Mapping[str, Any]) -> int:
        """Bytes of ping data the header's counts and string sizes imply."""
        lay = self.layout
        size = sum(int(header[c]) * dt.itemsize for _, c, dt in lay.arrays)
        return size + sum(int(header[s]) for s in lay.strings)

    def check_header(self, header: Mapping[str, Any]) -> str | None:
        """Why the ping header cannot start a valid ping (a short reason), or None. A ping
        has at least one RAA sample (a header of zeros with a time read from the bytes before
        it would otherwise pass in any run of zero bytes)."""
        lay = self.layout
        for name, count, _ in lay.arrays:
            n = int(header[count])
            lo, hi = (1, lay.max_samples) if name == "raa" else (0, 255)
            if not lo <= n <= hi:
                return f"count {count} = {n} outside {lo}..{hi}"
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

    def plausible(self, data: bytes, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The offsets ``q`` in ``lo..hi-1`` where ``data[q:]`` holds a ping header that
        :meth:`check_header` accepts (vectorised over every byte offset; ``hi`` at most
        ``len(data) - 64 + 1``), with each one's ``ping_size`` and ``ping_time``."""
        lay, ph = self.layout, self.layout.ping_header
        n = hi - lo
        empty = np.zeros(0, np.int64)
        if n <= 0:
            return empty, empty, np.zeros(0)
        view = np.ndarray((n,), dtype=ph, buffer=data, offset=lo, strides=(1,))
        q = np.flatnonzero(view["side"] <= 1)  # the cheapest, most selective test first
        for name, count, _ in lay.arrays:
            c = view[count][q].astype(np.int64)
            lo, hi = (1, lay.max_samples) if name == "raa" else (0, 255)
            q = q[(c >= lo) & (c <= hi)]
        for s in lay.strings:
            c = view[s][q].astype(np.int64)
            q = q[(c >= 0) & (c <= lay.max_string_size)]
        size = view["ping_size"][q].astype(np.int64)
        want = np.zeros(len(q), np.int64)
        for _, count, dt in lay.arrays:
            want += view[count][q].astype(np.int64) * dt.itemsize
        for s in lay.strings:
            want += view[s][q].astype(np.int64)
        ok = (size == want) & (size <= lay.max_ping_size)
        q, size = q[ok], size[ok]
        t = view["ping_time"][q].astype(np.float64)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(t) & (t > 0)
        return q[ok] + lo, size[ok], t[ok]

    # -- file header --------------------------------------------------------------------------
    def decode_file_header(self, data: bytes | bytearray | memoryview) -> RdfFileHeader:
        """The file header in ``data`` (exactly its size); :class:`DataError` if not valid."""
        dt = self.layout.file_header
        if len(data) != dt.itemsize:
            raise DecodeError(
                f"{len(data)} bytes, the file header has {dt.itemsize}", field="RdfFileHeader"
            )
        fields = _record_values(np.frombuffer(data, dtype=dt)[0])
        for name, want in (
            ("raw_header_size", dt.itemsize),
            ("raw_ping_header_size", self.layout.ping_header.itemsize),
        ):
            if fields[name] != want:
                raise DecodeError(
                    f"{name} = {fields[name]}, the table ({self.layout.source}) says {want}",
                    field=f"RdfFileHeader.{name}",
                    offset=dt.fields[name][1] if dt.fields else None,
                )
        return RdfFileHeader(MappingProxyType(fields))

    def encode_file_header(self, msg: RdfFileHeader) -> bytes:
        """The wire bytes of a file header."""
        return _pack(self.layout.file_header, msg.fields)

    def is_file_header(self, data: bytes | bytearray | memoryview) -> bool:
        """``data`` is a file header's size and carries its two size fields (bytes 4-7)."""
        magic = self.file_magic
        if len(data) != self.layout.file_header.itemsize or magic is None:
            return False
        return bytes(data[4 : 4 + len(magic)]) == magic

    # -- pings ----------------------------------------------------------------------------------
    def decode_header(
        self, data: bytes | bytearray | memoryview, offset: int = 0
    ) -> dict[str, Any]:
        """The ping header fields at ``data[offset:]`` (wire values, unchecked)."""
        return _record_values(
            np.frombuffer(data, dtype=self.layout.ping_header, count=1, offset=offset)[0]
        )

    def decode(self, frame: bytes | bytearray | memoryview) -> GeoSwathPing | RdfFileHeader:
        """One record a framer delivered: the file header (:meth:`is_file_header`) or a ping
        (:meth:`decode_ping`)."""
        if self.is_file_header(frame):
            return self.decode_file_header(frame)
        return self.decode_ping(frame)

    def decode_ping(self, frame: bytes | bytearray | memoryview) -> GeoSwathPing:
        """One ping (header + data, exactly); :class:`DecodeError` naming the field if not
        valid."""
        hsize = self.layout.ping_header.itemsize
        if len(frame) < hsize:
            raise DecodeError(
                f"{len(frame)} bytes, shorter than the {hsize}-byte ping header",
                field="GeoSwathPing",
            )
        frame = bytes(frame)  # read-only: the columns are views of it
        header = self.decode_header(frame)
        reason = self.check_header(header)
        if reason is not None:
            raise DecodeError(reason, field="GeoSwathPing.header")
        if len(frame) != hsize + int(header["ping_size"]):
            raise DecodeError(
                f"{len(frame)} bytes, the header says {hsize} + {header['ping_size']}",
                field="GeoSwathPing.ping_size",
            )
        arrays, pos = {}, hsize
        for name, count, dt in self.layout.arrays:
            n = int(header[count])
            arrays[name] = _columns(np.frombuffer(frame, dtype=dt, count=n, offset=pos))
            pos += n * dt.itemsize
        strings = []
        for s in self.layout.strings:
            n = int(header[s])
            strings.append(frame[pos : pos + n])
            pos += n
        return GeoSwathPing(MappingProxyType(header), MappingProxyType(arrays), tuple(strings))

    def encode(self, msg: GeoSwathPing | RdfFileHeader) -> bytes:
        """The wire bytes of a ping or a file header; :class:`ValueError` if a ping's counts
        disagree with its data."""
        if isinstance(msg, RdfFileHeader):
            return self.encode_file_header(msg)
        header = dict(msg.header)
        parts = []
        for name, count, dt in self.layout.arrays:
            cols = msg.arrays.get(name)
            rec = np.zeros(0, dt) if not cols else _records(dt, cols)
            if len(rec) != int(header[count]):
                raise ValueError(
                    f"GeoSwathPing.{name}: {len(rec)} records, header {count} = {header[count]}"
                )
            parts.append(rec.tobytes())
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
        arrays: Mapping[str, Any] | None = None,
        strings: Iterable[bytes] | None = None,
    ) -> GeoSwathPing:
        """A ping from header values (missing ones 0) and data (per array: a record array or
        field name -> column, missing fields 0); counts, string sizes and ``ping_size`` are
        filled in from the data."""
        lay = self.layout
        h: dict[str, Any] = {n: 0 for n in lay.ping_header.names or ()}
        for n in lay.ping_header.names or ():
            if lay.ping_header[n].kind == "V":
                h[n] = bytes(lay.ping_header[n].itemsize)
        h.update(header)
        arrays = dict(arrays or {})
        out = {}
        for name, count, dt in lay.arrays:
            given = arrays.pop(name, None)
            rec = np.zeros(0, dt) if given is None else _records(dt, given)
            h[count] = len(rec)
            out[name] = _columns(rec.copy())
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


class GeoSwathFramer(Framer):
    """Cuts an RDF file (file header, then pings) or a broadcast stream (pings only) into
    records (:class:`~auvgw.drivers.framing.Frame`, ``feed`` / ``feed_datagram`` / ``finish``
    / ``expire`` as every framer).

    ``file_mode``: True a file (its header first), False a broadcast stream, None (default)
    told by the first bytes (a file header's two size fields at bytes 4-7).

    The format has no sync and no checksum, so every byte offset is a candidate: a record
    whose header is not self-consistent (:meth:`GeoSwathCodec.check_header`), or whose claimed
    size exceeds the table's bound, is refused at once; in a file ``previous_ping_position``
    must point at the last ping seen (or, after a refused stretch, between it and this one).
    A candidate inside whose data a complete plausible ping starts (its whole header inside
    the candidate's claimed size, its ``ping_time`` within :attr:`inner_window_s` of the
    candidate's) is refused too (reason ``inner_frame``): a ping cut short whose claim swallows
    the next ping costs itself only. A complete candidate is accepted when the bytes at its
    claimed end start a plausible ping (or the stream ends there); else a plausible header near
    its time inside its claim (its own header's tail, its data, across its end) proves it cut
    (reason ``cut``: cut in its last bytes or inside its header, in a byte stream), and with
    none it is accepted (garbage follows). So a complete ping in a byte stream waits for a
    header's worth of the next bytes; :meth:`expire` delivers one that waited too long (an
    idle stream's last ping). The search resumes at the next plausible header
    (:meth:`GeoSwathCodec.plausible`, vectorised). ``stats`` counts frames, bad frames (one per
    refused stretch, by reason) and skipped bytes, the same for any chunking.
    """

    name = "geoswath"
    #: how far (s) the time of a ping starting inside a candidate may be from the candidate's
    #: for it to prove the candidate cut (a header read from sample bytes is never that close)
    inner_window_s = 60.0

    def __init__(
        self,
        codec: GeoSwathCodec | None = None,
        file_mode: bool | None = None,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
    ) -> None:
        # (the base class's sync search is not used: no Framer.__init__)
        self.codec = codec or default_codec()
        self.policy = ErrorPolicy(policy)
        self.source = source or self.name
        lay = self.codec.layout
        self.max_frame_size = lay.ping_header.itemsize + lay.max_ping_size
        self.stats = FramerStats()
        self._buf = bytearray()
        self._base = 0
        self._pending: list[Frame] = []
        self._waiting: int | None = None
        self._waiting_since: float | None = None
        self.file_mode = file_mode
        self.file_header: RdfFileHeader | None = None
        self._need_file_header = bool(file_mode)
        self._last_ping: int | None = None  # stream offset of the last ping accepted
        self._bad_since = False  # a stretch was refused since that ping
        self._refusing = False  # inside a refused stretch (counted once, across chunks)
        #: refuse a candidate inside which a complete plausible ping starts (as the base)
        self.abandon_on_inner = True
        #: judge the bytes at a complete ping's claimed end (:meth:`_end_check`); False accepts
        #: it at once, as before issue 31 (the benchmark's reference: the two cut cases open)
        self.check_end = True
        #: stream offset of a complete ping held for the header after it (:meth:`_end_check`)
        self._held: int | None = None
        #: stream offset of a held ping :meth:`expire` released (delivered without that header)
        self._release: int | None = None

    # -- judging one candidate ----------------------------------------------------------------
    def _check_at(self, start: int, eof: bool) -> int:
        """Size of the valid record at ``_buf[start]``, 0 if more bytes are needed."""
        codec, lay, buf = self.codec, self.codec.layout, self._buf
        if self.file_mode is None:  # the stream's first bytes tell a file from a broadcast
            magic = codec.file_magic
            if magic is not None and len(buf) < 4 + len(magic) and not eof:
                return 0
            self.file_mode = magic is not None and bytes(buf[4 : 4 + len(magic)]) == magic
            self._need_file_header = self.file_mode
        if self._need_file_header:
            n = lay.file_header.itemsize
            if len(buf) - start < n:
                return 0
            try:
                self.file_header = codec.decode_file_header(bytes(buf[start : start + n]))
            except DataError as exc:
                raise BadFrame(f"file_header: {exc.reason}") from None
            return n
        hsize = lay.ping_header.itemsize
        if len(buf) - start < hsize:
            return 0
        header = codec.decode_header(buf, start)
        reason = codec.check_header(header)
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
        total, t = hsize + int(header["ping_size"]), float(header["ping_time"])
        inner = None
        if self.abandon_on_inner:
            inner = self._inner(start, total, t)
        if inner == "complete":
            raise BadFrame("inner_frame: a complete ping starts inside this one")
        if len(buf) - start < total or (inner == "open" and not eof):
            return 0
        end = self._end_check(start, total, t, eof) if self.check_end else "ok"
        if end == "cut":
            raise BadFrame("cut: the bytes at its claimed end start no ping, and a ping "
                           "header starts inside its claim")  # fmt: skip
        if end == "wait":
            self._held = self._base + start
            return 0
        return total

    def _end_check(self, start: int, total: int, t: float, eof: bool) -> str:
        """Whether the complete candidate ``_buf[start:start+total]`` ends where a ping ends
        (``"ok"``), was cut short and claims the next ping's first bytes (``"cut"``), or must
        wait for a header's worth of the bytes after it (``"wait"``).

        ``"ok"``: the bytes at its claimed end hold a plausible ping header (in a file, one
        linking back to this ping), or the stream (the datagram) ends right there, or the
        candidate was released by :meth:`expire`; else ``"cut"`` when a plausible header with
        a time within :attr:`inner_window_s` of the candidate's starts anywhere inside its claim
        after its first byte (inside its own header, in its data, or across its end: the cut
        ping's claim ends inside the next ping), else ``"ok"`` (garbage follows it)."""
        buf, codec = self._buf, self.codec
        hsize = codec.layout.ping_header.itemsize
        end = start + total
        if self._release == self._base + start:
            return "ok"
        if len(buf) >= end + hsize:
            after = codec.decode_header(buf, end)
            if codec.check_header(after) is None and (
                not self.file_mode or int(after["previous_ping_position"]) == self._base + start
            ):
                return "ok"
        elif not eof:
            return "wait"
        elif len(buf) == end:
            return "ok"
        lo, hi = start + 1, min(end, len(buf) - hsize + 1)
        _, _, tq = codec.plausible(bytes(buf[lo : hi + hsize - 1]), 0, hi - lo)
        return "cut" if bool((np.abs(tq - t) <= self.inner_window_s).any()) else "ok"

    def _inner(self, start: int, total: int, t: float) -> str | None:
        """Whether a plausible ping starts inside the data of the candidate
        ``_buf[start:start+total]`` (after its header, whole header inside it, time within
        the window): ``"complete"`` (all its bytes are here), ``"open"`` (waiting for its
        bytes) or None."""
        hsize = self.codec.layout.ping_header.itemsize
        buf = self._buf
        lo = start + hsize
        hi = min(start + total - hsize, len(buf) - hsize) + 1
        if hi <= lo:
            return None
        q, size, tq = self.codec.plausible(bytes(buf[lo : hi + hsize - 1]), 0, hi - lo)
        near = np.abs(tq - t) <= self.inner_window_s
        if not near.any():
            return None
        ends = q[near] + lo + hsize + size[near]
        return "complete" if bool((ends <= len(buf)).any()) else "open"

    def _next_plausible(self, lo: int, eof: bool) -> int:
        """Where the search resumes after a refusal at ``lo - 1``: the next offset holding a
        plausible ping header (or, in a file before its header, the next byte), else the
        first offset whose header is not all here yet (the end at ``eof``)."""
        buf = self._buf
        if self._need_file_header or self.file_mode is None:
            return lo
        hsize = self.codec.layout.ping_header.itemsize
        hi = len(buf) - hsize + 1
        if hi > lo:
            data = bytes(buf[lo:])
            q, _, _ = self.codec.plausible(data, 0, hi - lo)
            if len(q):
                return lo + int(q[0])
        return len(buf) if eof else max(lo, hi)

    @property
    def held(self) -> int | None:
        """Stream offset of the complete ping waiting only for a header's worth of the bytes
        after it (:meth:`finish` or :meth:`expire` delivers it), else None."""
        return self._held

    # -- driving ------------------------------------------------------------------------------
    def feed(self, chunk: bytes | bytearray | memoryview, now: float | None = None) -> list[Frame]:
        """Add bytes; return every record they complete, in order, with its stream offset;
        ``now`` (host seconds) dates a record left waiting for :meth:`expire`."""
        self._buf += chunk
        self.stats.bytes_in += len(chunk)
        before = self._waiting
        try:
            return self._scan(eof=False)
        finally:
            if self._waiting is None or self._waiting != before:
                self._waiting_since = now if self._waiting is not None else None

    def feed_datagram(self, datagram: bytes | bytearray | memoryview) -> list[Frame]:
        """One broadcast datagram framed on its own: what it leaves incomplete is counted as
        truncated, never prepended to the next datagram."""
        self._buf += datagram
        self.stats.bytes_in += len(datagram)
        self._refusing = False
        return self._scan(eof=True)

    def finish(self) -> list[Frame]:
        """End of stream: a record left incomplete is counted as truncated (a complete ping
        held for the bytes after it comes out)."""
        out = self._scan(eof=True)
        if self._waiting is None:
            self._waiting_since = None
        return out

    def expire(self, now: float, max_age_s: float) -> list[Frame]:
        """As every framer's (:meth:`Framer.expire`): the record waiting longer than
        ``max_age_s`` is dropped (``stale``), and the rest of it is the same refused stretch
        (one bad frame, not two)."""
        since = self._waiting_since
        if self._waiting is None or since is None or now - since <= max_age_s:
            return []
        if self._held is not None and self._held == self._waiting:
            # a complete ping waiting only for the next ping's header (an idle stream's last
            # ping): delivered as at the stream's end, not dropped
            self._release = self._held
            try:
                return self.feed(b"", now)
            finally:
                self._release = None
        self._refusing = self._bad_since = True
        return super().expire(now, max_age_s)

    def _scan(self, eof: bool) -> list[Frame]:
        out, self._pending = self._pending, []
        i, buf = 0, self._buf
        error: FrameError | None = None
        self._waiting = self._held = None
        while i < len(buf):
            try:
                n = self._check_at(i, eof)
                if n == 0 and eof:
                    raise BadFrame(f"truncated: the stream ends {len(buf) - i} bytes into it")
            except BadFrame as exc:
                if not self._refusing:  # one bad frame per refused stretch, not per byte
                    self._refusing = True
                    error = self._bad(i, exc.reason)
                self._bad_since = True
                nxt = self._next_plausible(i + 1, eof)
                self.stats.skipped_bytes += nxt - i
                i = nxt
                if error is not None:
                    break
                continue
            if n == 0:
                self._waiting = self._base + i
                break
            self._refusing = False
            out.append(Frame(bytes(buf[i : i + n]), self._base + i))
            self.stats.frames += 1
            if self._need_file_header:
                self._need_file_header = False
            else:
                self._last_ping, self._bad_since = self._base + i, False
            i += n
        return self._consumed(i, out, error)


def read_rdf(
    path: str | Path, codec: GeoSwathCodec | None = None
) -> Iterator[RdfFileHeader | GeoSwathPing]:
    """The file header, then the pings of an RDF file, in order; bad stretches are skipped and
    counted by the framer (bytes before the first valid file header included)."""
    framer = GeoSwathFramer(codec, file_mode=True, policy=ErrorPolicy.IGNORE, source=str(path))
    for fr in read_file_frames(framer, path):
        if framer.codec.is_file_header(fr.data) and framer.file_header is not None:
            yield framer.file_header
        else:
            yield framer.codec.decode_ping(fr.data)


def _read_file(
    path: str | Path, policy: ErrorPolicy | str = ErrorPolicy.IGNORE
) -> tuple[Iterator[Frame], Framer]:
    """The records of a capture (an RDF file, or a broadcast stream saved to a file)."""
    framer = GeoSwathFramer(policy=policy, source=str(path))
    return read_file_frames(framer, path), framer


def _decode(frame: bytes) -> list[Any]:
    return [default_codec().decode(frame)]


def _encode(msg: Any) -> bytes:
    return default_codec().encode(msg)


FORMAT = Format(
    "geoswath",
    "GeoSwath Plus raw pings (RDF file or broadcast stream; table config/geoswath.toml)",
    framer=lambda *a, **k: default_codec().framer(*a, **k),
    decode=_decode,
    encode=_encode,
    read_file=_read_file,
)
