"""CAN forms of the HN-100 INS and the MS3A magnetometer: DBC files decoded with cantools.

:class:`DbcCodec` wraps ``cantools.database.load_file``. Each DBC message becomes a frozen
message class whose fields are its signals in snake case (``RateX`` -> ``rate_x``) in SI units:
signal units the project knows are converted (``deg`` -> rad, ``mm`` -> m, ...; see
:data:`auvgw.drivers.tablecodec.UNITS`), others are kept as the DBC states them; signals with
named values (``VAL_``) decode to the name (``"FINE"``) and a raw value without a name to its
number. Decoding checks the data length and the DBC ranges; encoding goes through cantools'
strict range checks, so errors name the message and the signal.

A DBC that carries an epoch counter (the signal named by the network attribute
``AuvgwSequenceSignal``, or ``sequence_signal=``) groups the per-frame messages of one epoch into
one sample (:meth:`DbcCodec.assembler`, :meth:`DbcCodec.encode_sample`).

The codec is pure: frames in and out are :class:`CanFrame` values (or anything with
``arbitration_id``, ``data``, ``is_extended_id``, such as ``can.Message``); no bus is opened here.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools

from auvgw.drivers import registry
from auvgw.drivers.spec import message
from auvgw.drivers.tablecodec import UNITS
from auvgw.ground.errors import DataError
from auvgw.ground.paths import config_file

__all__ = [
    "CanCodecError",
    "CanFrame",
    "DbcCodec",
    "EpochAssembler",
    "hn100_can",
    "ms3a_can",
    "shipped_can",
    "shipped_can_types",
]


_LINE_COL = re.compile(r"line (\d+), column (\d+)")


def _where(exc: BaseException) -> str:
    """A parse error's position without the file's text (cantools quotes the offending line; a
    DBC path from an untrusted recording may point at any file, e.g. /etc/shadow)."""
    m = _LINE_COL.search(str(exc))
    if isinstance(exc, UnicodeDecodeError):
        return f"not text (byte {exc.start} is not valid {exc.encoding})"
    return "invalid DBC syntax" + (f" at line {m[1]}, column {m[2]}" if m else "")


class CanCodecError(DataError):
    """A CAN frame or message that the DBC cannot decode or encode (names message and signal)."""


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One classic CAN frame: identifier (11 or 29 bit), payload and the extended-ID flag."""

    arbitration_id: int
    data: bytes
    is_extended_id: bool

    def __str__(self) -> str:
        width = 8 if self.is_extended_id else 3
        return f"{self.arbitration_id:0{width}X}#{self.data.hex().upper()}"


def _snake(name: str) -> str:
    s = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    s = re.sub(r"(?<=[A-Z])(?=[A-Z][a-z])", "_", s)
    return s.lower()


@dataclass(frozen=True)
class _Signal:
    name: str  # DBC signal name
    field: str  # message field name
    units: str  # decoded units
    factor: float  # decoded = DBC value * factor
    choices: tuple[str, ...]  # VAL_ names
    scaled: bool
    minimum: float | None
    maximum: float | None
    tolerance: float
    comment: str
    #: (DBC scale, DBC offset): decoded = (raw * scale + offset) * factor; None when the
    #: signal is an IEEE float or not scaled
    linear: tuple[float, float] | None = None


@dataclass(frozen=True)
class _Message:
    db: Any  # cantools Message
    cls: type
    signals: tuple[_Signal, ...]

    @property
    def label(self) -> str:
        kind = "extended" if self.db.is_extended_frame else "standard"
        return f"{self.db.name} (0x{self.db.frame_id:X} {kind})"


def _signal_info(sig: Any) -> _Signal:
    dbc_units = sig.unit or ""
    units, factor = UNITS.get(dbc_units, (dbc_units, 1.0))
    conv = sig.conversion
    scaled = bool(conv.scale != 1 or conv.offset != 0 or factor != 1.0 or conv.is_float)
    return _Signal(
        name=sig.name,
        field=_snake(sig.name),
        units=units,
        factor=factor,
        choices=tuple(str(c) for c in (sig.choices or {}).values()),
        scaled=scaled,
        minimum=sig.minimum,
        maximum=sig.maximum,
        tolerance=abs(conv.scale) * 1e-6,
        comment=(sig.comment or "").strip(),
        linear=(conv.scale, conv.offset) if scaled and not conv.is_float else None,
    )


def _build_class(name: str, signals: Sequence[_Signal], doc: str, module: str) -> type:
    annotations: dict[str, Any] = {}
    ns: dict[str, Any] = {"__module__": module, "__qualname__": name}
    lines = [doc, "", "Fields [decoded units]:"]
    for s in signals:
        annotations[s.field] = (str | int) if s.choices else (float if s.scaled else int)
        meta: dict[str, Any] = {"signal": s.name, "units": s.units}
        if s.linear is not None and not s.choices:  # how the envelope carries the raw value
            meta["linear"] = (*s.linear, s.factor)
        ns[s.field] = dataclasses.field(metadata=meta)
        lines.append(f"    {s.field} [{s.units or '1'}]: DBC signal {s.name}. {s.comment}".rstrip())
    ns["__annotations__"] = annotations
    ns["__doc__"] = "\n".join(lines)
    return message(type(name, (), ns))


class DbcCodec:
    """Decode and encode the CAN frames of one DBC file into typed, immutable SI messages.

    ``sequence_signal`` names the epoch counter that groups frames into one sample (default:
    the DBC's ``AuvgwSequenceSignal`` attribute, if any); ``sample_name`` names the sample class.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        sequence_signal: str | None = None,
        sample_name: str | None = None,
        module: str = __name__,
    ) -> None:
        self.path = Path(path)
        try:
            db = cantools.database.load_file(str(self.path), database_format="dbc")
        except OSError as exc:
            raise CanCodecError(f"{self.path}: cannot load DBC: {exc.strerror or exc}") from None
        except (UnicodeDecodeError, cantools.database.Error) as exc:
            raise CanCodecError(f"{self.path}: cannot load DBC: {_where(exc)}") from None
        assert isinstance(db, cantools.database.can.Database)  # database_format="dbc"
        self.db = db
        if not self.db.messages:
            raise CanCodecError(f"{self.path}: the DBC defines no message (BO_)")
        self._by_id: dict[tuple[int, bool], _Message] = {}
        self._by_type: dict[type, _Message] = {}
        self.types: dict[str, type] = {}
        for m in self.db.messages:
            signals = tuple(_signal_info(s) for s in m.signals)
            fields = [s.field for s in signals]
            if len(set(fields)) != len(fields):
                raise CanCodecError(f"{self.path}: {m.name}: two signals map to one field name")
            comment = (m.comment or "").strip()
            doc = f"{m.name}: CAN message from {self.path.name}. {comment}".strip()
            cls = _build_class(m.name, signals, doc, module)
            info = _Message(m, cls, signals)
            self._by_id[(m.frame_id, bool(m.is_extended_frame))] = info
            self._by_type[cls] = info
            self.types[m.name] = cls
        self.sequence_signal = sequence_signal or self._attribute("AuvgwSequenceSignal")
        self.sample_type: type | None = None
        self._epoch: tuple[_Message, ...] = ()
        if self.sequence_signal:
            self._build_sample(sample_name or f"{self.path.stem.upper()}_Sample", module)

    def _attribute(self, name: str) -> str | None:
        attrs = getattr(self.db.dbc, "attributes", None) or {}
        attr = attrs.get(name)
        return str(attr.value) if attr is not None and attr.value else None

    def _build_sample(self, name: str, module: str) -> None:
        seq = str(self.sequence_signal)
        members = tuple(
            info for info in self._by_type.values() if any(s.name == seq for s in info.signals)
        )
        if not members:
            raise CanCodecError(f"{self.path}: no message carries the sequence signal {seq!r}")
        signals: OrderedDict[str, _Signal] = OrderedDict()
        owner: dict[str, str] = {}
        for info in members:
            for s in info.signals:
                if s.name == seq:
                    signals.setdefault(s.field, s)
                    continue
                if s.field in signals:
                    raise CanCodecError(
                        f"{self.path}: signal {s.name} of {info.db.name} and of "
                        f"{owner[s.field]} would share the sample field {s.field!r}"
                    )
                signals[s.field] = s
                owner[s.field] = info.db.name
        seq_field = _snake(seq)
        ordered = [signals.pop(seq_field), *signals.values()]
        names = ", ".join(i.db.name for i in members)
        doc = f"{name}: one epoch of {self.path.name} ({names}), grouped by {seq}."
        self.sample_type = _build_class(name, ordered, doc, module)
        self._epoch = members

    # -- frames <-> messages ----------------------------------------------------------------
    def message_info(self, arbitration_id: int, is_extended_id: bool) -> _Message:
        try:
            return self._by_id[(arbitration_id, bool(is_extended_id))]
        except KeyError:
            kind = "extended" if is_extended_id else "standard"
            raise CanCodecError(
                f"{self.path.name}: no message with {kind} ID 0x{arbitration_id:X}"
            ) from None

    def decode(self, arbitration_id: int, data: bytes | bytearray, is_extended_id: bool) -> Any:
        """The typed message of one CAN frame; :class:`CanCodecError` if the DBC rejects it."""
        info = self.message_info(arbitration_id, is_extended_id)
        data = bytes(data)
        if len(data) != info.db.length:
            raise CanCodecError(
                f"{self.path.name}: {info.label}: {len(data)} data bytes, DBC says {info.db.length}"
            )
        try:
            values = info.db.decode(data, decode_choices=True, scaling=True)
        except (cantools.database.DecodeError, ValueError) as exc:
            raise CanCodecError(f"{self.path.name}: {info.label}: {exc}") from None
        out: dict[str, Any] = {}
        for s in info.signals:
            v = values[s.name]
            if isinstance(v, cantools.database.namedsignalvalue.NamedSignalValue):
                out[s.field] = v.name
                continue
            if (s.minimum is not None and v < s.minimum - s.tolerance) or (
                s.maximum is not None and v > s.maximum + s.tolerance
            ):
                raise CanCodecError(
                    f"{self.path.name}: {info.label}: signal {s.name} = {v} outside the DBC "
                    f"range [{s.minimum}, {s.maximum}]"
                )
            out[s.field] = float(v) * s.factor if s.scaled else int(v)
        return info.cls(**out)

    def decode_frame(self, frame: Any) -> Any:
        """Decode anything with ``arbitration_id``, ``data``, ``is_extended_id`` (can.Message)."""
        return self.decode(frame.arbitration_id, bytes(frame.data), frame.is_extended_id)

    def encode(self, msg: Any, *, strict: bool = True) -> CanFrame:
        """The CAN frame of a typed message.

        ``strict`` (default): cantools' strict mode checks every signal against the DBC.
        ``strict=False``: this codec checks the same DBC ranges and named values itself (about
        half the cost, for emulators encoding at high rates) and cantools encodes unchecked.
        """
        info = self._by_type.get(type(msg))
        if info is None:
            raise CanCodecError(
                f"{self.path.name}: cannot encode {type(msg).__name__}: not a message of this DBC"
            )
        values: dict[str, Any] = {}
        for s in info.signals:
            v = getattr(msg, s.field)
            if isinstance(v, str):
                if v not in s.choices:
                    raise CanCodecError(
                        f"{self.path.name}: {info.db.name}.{s.field} (signal {s.name}) = {v!r}: "
                        f"expected a number or one of {', '.join(s.choices) or 'no names'}"
                    )
                values[s.name] = v
                continue
            if not math.isfinite(v):
                raise CanCodecError(
                    f"{self.path.name}: {info.db.name}.{s.field} (signal {s.name}) = {v}: "
                    f"not a finite number"
                )
            dv = v / s.factor if s.scaled else v  # in the DBC's units
            if not strict and (
                (s.minimum is not None and dv < s.minimum - s.tolerance)
                or (s.maximum is not None and dv > s.maximum + s.tolerance)
            ):
                raise CanCodecError(
                    f"{self.path.name}: cannot encode {info.db.name}: signal {s.name} = {dv} "
                    f"outside the DBC range [{s.minimum}, {s.maximum}]"
                )
            values[s.name] = dv
        try:
            data = info.db.encode(values, scaling=True, strict=strict)
        except (cantools.database.EncodeError, KeyError, ValueError, TypeError) as exc:
            raise CanCodecError(f"{self.path.name}: cannot encode {info.db.name}: {exc}") from None
        return CanFrame(info.db.frame_id, bytes(data), bool(info.db.is_extended_frame))

    def raw_values(self, msg: Any) -> dict[str, int]:
        """Signal name -> raw integer on the wire, for a typed message."""
        frame = self.encode(msg)
        info = self._by_type[type(msg)]
        raw = info.db.decode(frame.data, decode_choices=False, scaling=False)
        return {name: int(v) for name, v in raw.items()}

    def signal_units(self, msg_type: type) -> dict[str, str]:
        """Field name -> decoded units of a message class of this DBC."""
        return {s.field: s.units for s in self._by_type[msg_type].signals}

    # -- epochs ----------------------------------------------------------------------------
    @property
    def epoch_types(self) -> tuple[type, ...]:
        """Message classes whose frames make up one epoch (those carrying the sequence signal)."""
        return tuple(i.cls for i in self._epoch)

    def split_sample(self, sample: Any) -> list[Any]:
        """The per-frame messages of one sample, in DBC order."""
        if self.sample_type is None or type(sample) is not self.sample_type:
            raise CanCodecError(
                f"{self.path.name}: {type(sample).__name__} is not this DBC's sample"
            )
        return [
            info.cls(**{s.field: getattr(sample, s.field) for s in info.signals})
            for info in self._epoch
        ]

    def encode_sample(self, sample: Any, *, strict: bool = True) -> list[CanFrame]:
        """The CAN frames of one sample (one per epoch message), in DBC order (``strict``: see
        :meth:`encode`)."""
        return [self.encode(m, strict=strict) for m in self.split_sample(sample)]

    def assembler(self, max_pending: int = 4) -> EpochAssembler:
        """A fresh :class:`EpochAssembler` for this DBC's epochs."""
        return EpochAssembler(self, max_pending=max_pending)


class EpochAssembler:
    """Groups per-frame messages sharing a sequence value into one sample.

    A sample is emitted when every epoch message of one sequence value has arrived (any order).
    A repeated message for a pending sequence value, or more than ``max_pending`` open epochs,
    drops the oldest incomplete epoch (counted in :attr:`dropped`). Messages not part of an epoch
    are ignored (counted in :attr:`ignored`).
    """

    def __init__(self, codec: DbcCodec, max_pending: int = 4) -> None:
        if codec.sample_type is None:
            raise CanCodecError(f"{codec.path.name}: the DBC names no sequence signal")
        self.codec = codec
        self.max_pending = max_pending
        self._types = set(codec.epoch_types)
        self._seq_field = _snake(str(codec.sequence_signal))
        self._pending: OrderedDict[int, dict[type, Any]] = OrderedDict()
        self.complete = 0
        self.dropped = 0
        self.ignored = 0

    def add(self, msg: Any) -> Any | None:
        """Add one decoded message; the completed sample, or None."""
        if type(msg) not in self._types:
            self.ignored += 1
            return None
        seq = getattr(msg, self._seq_field)
        parts = self._pending.get(seq)
        if parts is not None and type(msg) in parts:
            del self._pending[seq]
            self.dropped += 1
            parts = None
        if parts is None:
            parts = self._pending[seq] = {}
            while len(self._pending) > self.max_pending:
                self._pending.popitem(last=False)
                self.dropped += 1
        parts[type(msg)] = msg
        if len(parts) < len(self._types):
            return None
        del self._pending[seq]
        self.complete += 1
        values: dict[str, Any] = {}
        for part in parts.values():
            values.update((f.name, getattr(part, f.name)) for f in dataclasses.fields(part))
        assert self.codec.sample_type is not None
        return self.codec.sample_type(**values)

    @property
    def pending(self) -> int:
        """Epochs waiting for more frames."""
        return len(self._pending)


def shipped_can(fmt: str, path: str | Path | None = None) -> DbcCodec:
    """The CAN codec of a registered device (``hn100``, ``ms3a``): its DBC (default the shipped
    one the registry names) with its samples named as the registry's CAN message type."""
    dev = registry.device(fmt)
    sample = next((m.type for m in dev.messages if m.wire == "can"), None)
    if dev.dbc is None:
        raise KeyError(f"format {fmt!r} has no CAN database in the registry")
    return DbcCodec(path or config_file(dev.dbc), sample_name=sample)


def shipped_can_types() -> None:
    """Load every shipped DBC once, so its sample types are in ``MESSAGE_TYPES``."""
    for dev in registry.DEVICES:
        if dev.dbc is not None:
            shipped_can(dev.format)


def hn100_can(path: str | Path | None = None) -> DbcCodec:
    """The HN-100 CAN codec (default: the shipped ``config/hn100.dbc``); samples HN100_Sample."""
    return shipped_can("hn100", path)


def ms3a_can(path: str | Path | None = None) -> DbcCodec:
    """The MS3A CAN codec (default: the shipped ``config/ms3a.dbc``); samples MS3A_Sample."""
    return shipped_can("ms3a", path)


class CanDeviceCodec:
    """A DBC codec as one CAN device's decoder: frames that belong to an epoch are grouped and
    decode to the whole sample once complete (``None`` until then); other frames decode alone."""

    def __init__(self, codec: DbcCodec) -> None:
        self.codec = codec
        self.assembler = codec.assembler() if codec.sample_type is not None else None
        self._epoch = set(codec.epoch_types) if self.assembler is not None else set()

    def decode(self, arbitration_id: int, data: bytes | bytearray, is_extended_id: bool) -> Any:
        msg = self.codec.decode(arbitration_id, data, is_extended_id)
        if self.assembler is None or type(msg) not in self._epoch:
            return msg
        return self.assembler.add(msg)


def load_can_codec(dbc: str | Path) -> CanDeviceCodec:
    """The device codec of a DBC named in a configuration: a file shipped in ``config/``
    (``"hn100.dbc"``) or a path. The shipped DBCs get their registry sample names."""
    path = Path(dbc)
    if not path.is_file():
        shipped = config_file(str(dbc))
        if not shipped.is_file():
            raise FileNotFoundError(f"{dbc}: no such DBC file (neither a path nor in config/)")
        path = shipped
    names: dict[str, str] = {}
    for d, m in registry.message_types():  # a device's first CAN type names its sample
        if m.wire == "can" and d.dbc:
            names.setdefault(d.dbc, m.type)
    return CanDeviceCodec(DbcCodec(path, sample_name=names.get(path.name)))
