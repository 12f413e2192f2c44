"""Tritech Seanet ``.V4LOG`` files: what Seanet Pro records from a SeaNet line.

Layout (little endian; verified against two open readers, see ``docs/protocols/v4log.md``)::

    header, 80 bytes
      0   char[32]  "SeaNetV4 Log File V1", NUL padded
      32  u32       version
      36  u32       registration section offset (0 = none)
      40  u32       data offset: first record
      44  u32       number of records ("nScanLines")
      48  u32       config section offset = end of the records
      52  u32       extra section offset
      56  u32       index section offset
      60  u32       check section offset
      64  f64       log opened, TDateTime (days since 1899-12-30)
      72  f64       log closed, TDateTime
    records, from the data offset up to the config offset
      0   u16       record length, this field included
      2   f64       PC time of the packet, TDateTime
      10  u8        Tx node
      11  u8        Rx node
      12  ...       the SeaNet packet from its type byte (offset 10) up to, not including, the LF

A record drops the packet's '@', both lengths and its byte count, so records are rebuilt into
whole SeaNet packets (byte count: 0 in mtHeadData, else L - 5, as a head sends them) and decoded
by :mod:`auvgw.drivers.seanet`. Each record decodes to a :class:`V4LogRecord`: the PC time as
POSIX seconds (``time``; TDateTime carries no time zone, it is read as UTC), the exact TDateTime
(``tdatetime``) and the SeaNet message.

Records have no sync bytes, so :class:`V4LogFramer` walks them by their lengths within the
record section; a record with an implausible length or time (outside the log's open/close
times, one day of slack) is a bad frame, and the framer then slides byte by byte until a
plausible record starts again. A record inside which a complete record starts (its TDateTime
inside the outer one) is refused; a record starting in the last 9 bytes of the one delivered
before it is found by looking back (the two frames overlap). Whatever the chunking, the same
records come out. ``skipped_bytes`` counts the 80-byte header and any non-record
section too (every byte not delivered in a record).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO, ClassVar

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import (
    BadFrame,
    DecodeError,
    ErrorPolicy,
    Frame,
    FrameError,
    Framer,
    read_file_frames,
)
from auvgw.drivers.seanet import codec as seanet
from auvgw.drivers.spec import (
    WireError,
    decode_block,
    encode_block,
    from_jsonable,
    message,
    wire,
)
from auvgw.ground.closing import Closing

__all__ = [
    "FORMAT",
    "HEADER_SIZE",
    "HEADER_TEXT",
    "MAGIC",
    "V4LogError",
    "V4LogFramer",
    "V4LogHeader",
    "V4LogRecord",
    "V4LogWriter",
    "decode",
    "encode",
    "packet_to_record",
    "read_file",
    "read_header",
    "read_v4log",
    "record_to_packet",
    "tdatetime_from_unix",
    "unix_from_tdatetime",
    "write_v4log",
]

log = logging.getLogger(__name__)

#: what every .V4LOG starts with
MAGIC = b"SeaNetV4 Log File"
#: the header text this writer puts in
HEADER_TEXT = "SeaNetV4 Log File V1"
HEADER_SIZE = 80
RECORD_HEADER_SIZE = 12  # length, time, Tx, Rx
#: shortest record: header + type, sequence, node
MIN_RECORD_SIZE = RECORD_HEADER_SIZE + 3
#: days from the TDateTime epoch (1899-12-30) to the POSIX epoch (1970-01-01)
TDATETIME_POSIX_EPOCH = 25569.0
SECONDS_PER_DAY = 86400.0
_MAX_TDATETIME = 2958466.0  # year 9999


def unix_from_tdatetime(days: float) -> float:
    """Delphi TDateTime (days since 1899-12-30) -> POSIX seconds (the day count taken as UTC)."""
    return (days - TDATETIME_POSIX_EPOCH) * SECONDS_PER_DAY


def tdatetime_from_unix(seconds: float) -> float:
    """POSIX seconds -> Delphi TDateTime (days since 1899-12-30)."""
    return seconds / SECONDS_PER_DAY + TDATETIME_POSIX_EPOCH


class V4LogError(ValueError):
    """The file is not a readable .V4LOG (its header is missing or inconsistent)."""


@message
class V4LogHeader:
    """The 80-byte file header."""

    TYPE: ClassVar[str] = "V4LogHeader"

    text: str = wire("str", 0, size=32, vendor="Header", doc="'SeaNetV4 Log File V1'")
    version: int = wire("u32", 32, vendor="Version")
    reg_offset: int = wire("u32", 36, units="byte", vendor="RegOffset")
    data_offset: int = wire("u32", 40, units="byte", vendor="DataOffset", doc="first record")
    n_records: int = wire("u32", 44, vendor="nScanLines", doc="records of every type")
    config_offset: int = wire("u32", 48, units="byte", vendor="ConfigOffset", doc="records end")
    extra_offset: int = wire("u32", 52, units="byte", vendor="ExtraOffset")
    index_offset: int = wire("u32", 56, units="byte", vendor="IndexOffset")
    check_offset: int = wire("u32", 60, units="byte", vendor="CheckOffset")
    open_tdatetime: float = wire("f64", 64, units="day", vendor="LogOpen (TDateTime)")
    close_tdatetime: float = wire("f64", 72, units="day", vendor="LogClose (TDateTime)")

    @property
    def open_time(self) -> float:
        """Log opened, POSIX seconds."""
        return unix_from_tdatetime(self.open_tdatetime)

    @property
    def close_time(self) -> float:
        """Log closed, POSIX seconds."""
        return unix_from_tdatetime(self.close_tdatetime)


@message
class V4LogRecord:
    """One logged SeaNet packet: PC time and the decoded message.

    ``tdatetime`` is the record's exact time (days since 1899-12-30); ``time`` the same as POSIX
    seconds (build records with :meth:`at` so the two agree). ``message`` is a
    :mod:`~auvgw.drivers.seanet` message.
    """

    TYPE: ClassVar[str] = "V4LogRecord"

    tdatetime: float = wire("f64", 2, units="day", vendor="Time (TDateTime)")
    time: float
    message: Any

    def __post_init__(self) -> None:
        if isinstance(self.message, Mapping):  # rebuilt from JSON: the nested type names it
            object.__setattr__(self, "message", from_jsonable(self.message))

    @classmethod
    def at(cls, time: float, msg: Any) -> V4LogRecord:
        """A record of ``msg`` at POSIX ``time`` (s)."""
        days = tdatetime_from_unix(time)
        return cls(tdatetime=days, time=unix_from_tdatetime(days), message=msg)


# -- records <-> packets ----------------------------------------------------------------------
def record_to_packet(record: bytes | bytearray) -> bytes:
    """A V4LOG record -> the whole SeaNet packet it logged."""
    if len(record) < MIN_RECORD_SIZE:
        raise DecodeError(f"V4LOG record of {len(record)} bytes, at least {MIN_RECORD_SIZE}")
    (length,) = struct.unpack_from("<H", record, 0)
    if length != len(record):
        raise DecodeError(f"V4LOG record length field says {length}, record has {len(record)}")
    body = bytes(record[RECORD_HEADER_SIZE:])  # from the type byte on
    length = len(body) + 5
    count = seanet.default_byte_count(body[0], length)
    head = b"@%04X" % length + struct.pack("<H", length) + bytes([record[10], record[11], count])
    return head + body + b"\n"


def packet_to_record(packet: bytes | bytearray, tdatetime: float) -> bytes:
    """A whole SeaNet packet and its TDateTime -> the V4LOG record (drops '@', the lengths,
    the byte count and the LF)."""
    total = seanet.packet_length(packet)
    record = bytearray(total + 1)
    struct.pack_into("<Hd", record, 0, total + 1, tdatetime)
    record[10:12] = packet[7:9]
    record[12:] = packet[10 : total - 1]
    return bytes(record)


# -- codec ------------------------------------------------------------------------------------
def decode(record: bytes | bytearray | memoryview) -> list[V4LogRecord]:
    """One record (as :class:`V4LogFramer` delivers it) -> [V4LogRecord]."""
    rec = bytes(record)
    msgs = seanet.decode(record_to_packet(rec))
    (days,) = struct.unpack_from("<d", rec, 2)
    try:
        return [
            decode_block(V4LogRecord, rec, time=unix_from_tdatetime(days), message=m) for m in msgs
        ]
    except WireError as exc:
        raise DecodeError(str(exc)) from None


def encode(rec: V4LogRecord) -> bytes:
    """A V4LogRecord -> its record bytes (length, TDateTime, Tx, Rx, packet from the type on)."""
    out = bytearray(packet_to_record(seanet.encode(rec.message), 0.0))
    encode_block(rec, out)
    return bytes(out)


# -- framing ----------------------------------------------------------------------------------
class V4LogFramer(Framer):
    """Delivers the records of a .V4LOG fed in chunks (``sync`` is the file magic).

    Raises :class:`V4LogError` (whatever the policy) when the stream does not start with a
    V4LOG header: that is the wrong kind of file, not a bad record.
    """

    name = "v4log"
    sync = MAGIC
    max_frame_size = seanet.MAX_PACKET_SIZE + 1

    # the state of one stream, until its header and records set their own (immutable values)
    header: V4LogHeader | None = None
    _start: int = HEADER_SIZE
    _end: int | None = None
    _times: tuple[float, float] = (0.0, _MAX_TDATETIME)
    _resync: bool = False
    _last_end: int = -1  # absolute end of the last record delivered
    _tail: bytes = b""  # its last bytes, for _look_back

    def _read_header(self, buf: bytearray) -> None:
        if bytes(buf[: len(MAGIC)]) != MAGIC:
            raise V4LogError(
                f"not a SeaNet .V4LOG file: it starts {bytes(buf[:20])!r}, "
                f"a .V4LOG starts {HEADER_TEXT!r}"
            )
        if len(buf) < HEADER_SIZE:
            raise V4LogError(f"truncated .V4LOG header: {len(buf)} of {HEADER_SIZE} bytes")
        hdr = decode_block(V4LogHeader, buf)
        if hdr.data_offset < HEADER_SIZE:
            raise V4LogError(f".V4LOG header: data offset {hdr.data_offset} is inside the header")
        self.header = hdr
        self._start = hdr.data_offset
        self._end = hdr.config_offset if hdr.config_offset > hdr.data_offset else None
        t0, t1 = hdr.open_tdatetime, hdr.close_tdatetime
        if 0.0 < t0 <= t1 < _MAX_TDATETIME:
            self._times = (t0 - 1.0, t1 + 1.0)

    def check(self, buf: bytearray, start: int) -> int:
        """Length of the plausible record at ``start``, 0 if more bytes are needed."""
        avail = len(buf) - start
        if avail < 2:
            return 0
        (length,) = struct.unpack_from("<H", buf, start)
        if not MIN_RECORD_SIZE <= length <= self.max_frame_size:
            raise BadFrame(f"record_length: {length} (allowed {MIN_RECORD_SIZE}..)")
        if self._end is not None and self._base + start + length > self._end:
            raise BadFrame(f"record_length: {length} runs past the record section")
        if avail < RECORD_HEADER_SIZE:
            return 0
        (days,) = struct.unpack_from("<d", buf, start + 2)
        lo, hi = self._times
        if not (math.isfinite(days) and lo <= days <= hi):
            raise BadFrame(f"record_time: TDateTime {days!r} outside the log's time span")
        if avail < length:
            return 0
        # no checksum: the SeaNet packet inside must be consistent with the record's length
        # (mtHeadData counts, fixed sizes), or a corrupted length swallows the next records
        try:
            packet = record_to_packet(bytes(buf[start : start + length]))
            seanet.decode(packet)
        except DecodeError as exc:
            raise BadFrame(f"record_content: {exc}") from None
        seanet.check_plausible(packet)  # node ids, counts, angles: as the SeaNet framer judges
        return length

    def _time_pattern(self) -> bytes | None:
        """The two top bytes every TDateTime in the log's time span shares (sign, exponent and
        high mantissa of a little-endian f64), or None when the span is too wide to have them."""
        lo, hi = self._times
        a, b = struct.pack("<d", max(lo, 1.0)), struct.pack("<d", hi)
        return a[6:] if a[6:] == b[6:] else None

    def _candidates(self, buf: bytearray, lo: int, last: int) -> Iterator[int]:
        """Positions in ``lo..last`` that may start a record: those whose TDateTime (all in
        ``buf``) has the log's top bytes (found in C). None when the log's time span has no
        such bytes (a header without times: any date up to year 9999 is plausible, and records
        found inside good ones would cost them)."""
        pat = self._time_pattern()
        if pat is None:
            return
        q = buf.find(pat, lo + 8, last + 10) - 8
        while lo <= q <= last:
            yield q
            q = buf.find(pat, q + 9, last + 10) - 8

    def _inner_record(self, buf: bytearray, start: int, end: int | None = None) -> bool | None:
        """A complete plausible record starts inside the one at ``start`` (``end``: its end when
        complete; None: it waits for bytes): its length field is the corrupted one. None when it
        is complete but a record starting inside it still waits for bytes (it waits too).

        Only starts whose TDateTime lies inside the record at ``start`` count, so the verdict
        never depends on bytes that may not have arrived yet (a start nearer the end is found
        by :meth:`_look_back` once the record after it fails). A waiting record is probed once
        per position while it waits (those that wait for bytes themselves are judged again)."""
        waiting = end is None
        if waiting:
            if len(buf) - start < 2:
                return False
            (claimed,) = struct.unpack_from("<H", buf, start)
            if self._waiting != self._base + start:
                self._probed = self._base + start + 1
            lo = max(start + 1, self._probed - self._base)
            last = min(len(buf) - MIN_RECORD_SIZE, start + claimed - 10)
        else:
            assert end is not None
            lo, last = start + 1, end - 10
        first_open: int | None = None
        for q in self._candidates(buf, lo, last):
            try:
                n = self.check(buf, q)
            except BadFrame:
                n = -1
            if n > 0:
                return True
            if n == 0 and first_open is None:
                first_open = q
        if not waiting and first_open is not None:
            return None  # complete, but a record starting inside it still waits: wait too
        if waiting:
            self._probed = self._base + (
                first_open if first_open is not None else max(last, start) + 1
            )
        return False

    def _look_back(self, buf: bytearray, i: int, eof: bool) -> Frame | None:
        """The record starting in the last bytes of the record delivered just before ``i``
        (where no record starts): that record's length claimed a few bytes too many (its
        TDateTime lies past the corrupted record's end, where :meth:`_inner_record` does not
        look). Raises :class:`_Wait` when one of them still waits for bytes."""
        if self._last_end != self._base + i or not self._tail:
            return None
        tail = self._tail
        probe = bytearray(tail) + buf[i:]
        shift = i - len(tail)
        self._base += shift  # check() places records by absolute offset: probe[0] is there
        try:
            for q in range(len(tail)):
                try:
                    n = self.check(probe, q)
                except BadFrame:
                    continue
                if n > 0:
                    return Frame(bytes(probe[q : q + n]), self._base + q)
                if not eof:
                    raise _Wait
        finally:
            self._base -= shift
        return None

    def _deliver(self, out: list[Frame], frame: Frame) -> None:
        out.append(frame)
        self.stats.frames += 1
        self._resync = False
        self._last_end = frame.offset + len(frame.data)
        self._tail = frame.data[-(RECORD_HEADER_SIZE - 3) :]  # starts whose TDateTime is past it

    def _scan(self, eof: bool) -> list[Frame]:
        buf = self._buf
        out, self._pending = self._pending, []
        if self.header is None:
            if len(buf) < HEADER_SIZE and not eof:
                return out
            self._read_header(buf)
        i = 0
        error: FrameError | None = None
        while i < len(buf) or eof:
            pos = self._base + i
            if pos < self._start:  # the header and anything before the first record
                n = min(self._start - pos, len(buf) - i)
                self.stats.skipped_bytes += n
                i += n
                if self._base + i < self._start:
                    break
                continue
            if self._end is not None and pos >= self._end:  # sections after the records
                self.stats.skipped_bytes += len(buf) - i
                i = len(buf)
                break
            reason = ""
            try:
                length = self.check(buf, i)
                if length == 0 and eof and i < len(buf):
                    raise BadFrame(f"truncated: stream ends {len(buf) - i} bytes into a record")
            except BadFrame as exc:
                reason = exc.reason
            if not reason:
                inner: bool | None = False
                if length > 0 or not eof:
                    inner = self._inner_record(buf, i, i + length if length else None)
                    if inner is None and eof:
                        inner = False
                if inner is None:
                    length = 0
                elif inner:
                    reason = "inner_frame: a complete record starts inside this one"
                    self._waiting = None
            if reason:
                try:
                    found = self._look_back(buf, i, eof)
                except _Wait:
                    self._waiting = self._base + i
                    break
                if found is not None:  # the record before claimed too much: it passed
                    self._deliver(out, found)
                    i = found.offset + len(found.data) - self._base
                    continue
                self.stats.skipped_bytes += 1
                if not self._resync:  # one bad frame per lost stretch, then slide quietly
                    self._resync = True
                    error = self._bad(i, reason)
                i += 1
                if error is not None:
                    break
                continue
            if length == 0:
                self._waiting = self._base + i
                break
            self._deliver(out, Frame(bytes(buf[i : i + length]), pos))
            i += length
        return self._consumed(i, out, error)


class _Wait(Exception):
    """A record found by :meth:`V4LogFramer._look_back` still waits for bytes."""


def read_file(
    path: str | Path, policy: ErrorPolicy | str = ErrorPolicy.IGNORE
) -> tuple[Iterator[Frame], V4LogFramer]:
    """The records of a .V4LOG file as frames, and the framer counting them (for the format
    registry); iterating raises :class:`V4LogError` when the file is not a .V4LOG."""
    framer = V4LogFramer(policy=policy, source=str(path))
    return read_file_frames(framer, path), framer


def read_header(path: str | Path) -> V4LogHeader:
    """The header of a .V4LOG file (:class:`V4LogError` naming the file if there is none)."""
    with open(path, "rb") as fh:
        data = fh.read(HEADER_SIZE)
    framer = V4LogFramer(source=str(path))
    try:
        framer._read_header(bytearray(data))
    except V4LogError as exc:
        raise V4LogError(f"{path}: {exc}") from None
    assert framer.header is not None
    return framer.header


def read_v4log(
    path: str | Path, policy: ErrorPolicy | str = ErrorPolicy.LOG
) -> Iterator[tuple[float, seanet.SeaNetMessage]]:
    """(POSIX time s, SeaNet message) for every record of a .V4LOG file, in file order.

    Bad records are counted and skipped (or raised, or logged, as ``policy`` says); a record
    whose packet does not decode is handled the same way.
    """
    frames, _ = read_file(path, policy)
    policy = ErrorPolicy(policy)
    try:
        for frame in frames:
            try:
                records = decode(frame.data)
            except DecodeError as exc:
                if policy is ErrorPolicy.RAISE:
                    where = f"{path}: record at byte offset {frame.offset}"
                    raise DecodeError(f"{where}: {exc}") from None
                if policy is ErrorPolicy.LOG:
                    log.warning("%s: record at byte offset %d: %s", path, frame.offset, exc)
                continue
            for rec in records:
                yield rec.time, rec.message
    except V4LogError as exc:
        raise V4LogError(f"{path}: {exc}") from None


# -- writing ----------------------------------------------------------------------------------
class V4LogWriter(Closing):
    """Writes a .V4LOG: the header (patched on :meth:`close`), then one record per packet.

    No clock inside: every record gets the time it is given; the header's open/close times
    default to the first/last record's.
    """

    def __init__(self, file: str | Path | BinaryIO, *, version: int = 1) -> None:
        self._own = isinstance(file, str | Path)
        self._fh: BinaryIO = open(file, "wb") if isinstance(file, str | Path) else file  # noqa: SIM115
        self._origin = self._fh.tell()
        self._fh.write(bytes(HEADER_SIZE))
        self.version = version
        self.n_records = 0
        self._first: float | None = None
        self._last: float | None = None

    def write(self, time: float, item: seanet.SeaNetMessage | bytes) -> None:
        """Log a SeaNet message (or a whole packet's bytes) at POSIX ``time`` (s)."""
        packet = bytes(item) if isinstance(item, bytes | bytearray) else seanet.encode(item)
        self._write(packet_to_record(packet, tdatetime_from_unix(time)), tdatetime_from_unix(time))

    def write_record(self, rec: V4LogRecord) -> None:
        """Log a :class:`V4LogRecord` exactly (its TDateTime as it is)."""
        self._write(encode(rec), rec.tdatetime)

    def _write(self, record: bytes, days: float) -> None:
        self._fh.write(record)
        self.n_records += 1
        self._first = days if self._first is None else self._first
        self._last = days

    def close(
        self, *, open_time: float | None = None, close_time: float | None = None
    ) -> V4LogHeader:
        """Write the header (open/close POSIX times default to the first/last record's)."""
        end = self._fh.tell() - self._origin
        t_open = tdatetime_from_unix(open_time) if open_time is not None else self._first
        t_close = tdatetime_from_unix(close_time) if close_time is not None else self._last
        header = V4LogHeader(
            text=HEADER_TEXT,
            version=self.version,
            reg_offset=0,
            data_offset=HEADER_SIZE,
            n_records=self.n_records,
            config_offset=end,
            extra_offset=end,
            index_offset=end,
            check_offset=end,
            open_tdatetime=t_open or 0.0,
            close_tdatetime=t_close or 0.0,
        )
        buf = bytearray(HEADER_SIZE)
        encode_block(header, buf)
        self._fh.seek(self._origin)
        self._fh.write(buf)
        self._fh.seek(self._origin + end)
        if self._own:
            self._fh.close()
        return header

    def __exit__(self, *exc: object) -> None:
        if not self._fh.closed:
            self.close()


def write_v4log(
    path: str | Path,
    items: Iterable[tuple[float, seanet.SeaNetMessage | bytes]],
    *,
    open_time: float | None = None,
    close_time: float | None = None,
) -> V4LogHeader:
    """Write (POSIX time s, message or packet bytes) pairs as a .V4LOG file; its header."""
    writer = V4LogWriter(path)
    for time, item in items:
        writer.write(time, item)
    return writer.close(open_time=open_time, close_time=close_time)


FORMAT = Format(
    name="v4log",
    summary="a Tritech Seanet .V4LOG file (80-byte header, timed SeaNet records)",
    framer=V4LogFramer,
    decode=decode,
    encode=encode,
    read_file=read_file,
)
