"""The vehicle's actuators on CAN (``config/actuators.dbc``): commands in, feedback out.

One motor/fin controller drives the main thruster, the rudder and the stern plane. The host
sends :data:`COMMAND_TYPE` (``ActuatorCommand``: sequence number, shaft speed rpm, rudder and
stern-plane angles in rad once decoded); the controller answers at its own rate with one
``ActuatorState`` sample (two frames sharing ``Counter``: measured shaft speed, fin angles,
motor current, the fault word :data:`FAULT_BITS` and the ``cmd_seq`` it last applied).
Layout and conventions: docs/protocols/actuators.md.

:class:`CommandGate` is what stands between the bus and the CAN adapter: a command leaves only
if it is this DBC's command, inside the DBC ranges and newer than the last one forwarded
(serial-number order modulo 65536); everything else is refused and counted by reason. Pure: no
bus, no port.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from typing import Any

from auvgw.drivers.can_codec import CanCodecError, CanFrame, DbcCodec, shipped_can

__all__ = [
    "COMMAND_TYPE",
    "FAULT_BITS",
    "SEQ_MODULO",
    "STATE_TYPE",
    "CommandGate",
    "CommandRefused",
    "actuators_can",
    "fault_names",
    "fault_word",
    "seq_newer",
]

#: the command message of the DBC and the feedback sample (the registry's names)
COMMAND_TYPE = "ActuatorCommand"
STATE_TYPE = "ActuatorState"
#: sequence numbers wrap at this
SEQ_MODULO = 65536

#: fault word bit -> name (the DBC comment of ``Faults``)
FAULT_BITS: dict[str, int] = {
    "rudder_jammed": 1 << 0,
    "stern_jammed": 1 << 1,
    "thruster_no_answer": 1 << 2,
    "overcurrent": 1 << 3,
    "command_timeout": 1 << 4,
}


def actuators_can(path: str | None = None) -> DbcCodec:
    """The actuators' CAN codec (default: the shipped ``config/actuators.dbc``); feedback
    samples are ``ActuatorState``."""
    return shipped_can("actuators", path)


def fault_word(*names: str) -> int:
    """The fault word with the named bits set (:data:`FAULT_BITS`)."""
    word = 0
    for n in names:
        try:
            word |= FAULT_BITS[n]
        except KeyError:
            known = ", ".join(FAULT_BITS)
            raise KeyError(f"unknown actuator fault {n!r}; known: {known}") from None
    return word


def fault_names(word: int) -> tuple[str, ...]:
    """The names of the bits set in a fault word (unknown bits as ``bit<n>``)."""
    out = [n for n, b in FAULT_BITS.items() if word & b]
    known = sum(FAULT_BITS.values())
    out += [f"bit{i}" for i in range(16) if word & ~known & (1 << i)]
    return tuple(out)


def seq_newer(seq: int, last: int | None) -> bool:
    """Whether ``seq`` comes after ``last`` in serial-number order modulo 65536 (RFC 1982 style:
    up to half the range ahead); any sequence number is new when there was none."""
    if last is None:
        return True
    d = (seq - last) % SEQ_MODULO
    return 0 < d < SEQ_MODULO // 2


class CommandRefused(ValueError):
    """A command the gate does not forward; ``reason`` is its counter's name."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class CommandGate:
    """Checks actuator commands before they reach the CAN bus (see the module docstring).

    :meth:`check` returns the CAN frame of a good command or raises :class:`CommandRefused`
    (``wrong_type``, ``out_of_range``, ``stale_seq``); once the frame is on the bus,
    :meth:`sent` counts it as forwarded and makes its sequence number the last one (a frame
    that could not be sent leaves both as they were). :attr:`counts` has ``forwarded`` and one
    counter per refusal reason. A command of another class of the same DBC message (another
    codec instance, an envelope's class) is taken by its field names.
    """

    REASONS = ("malformed", "wrong_type", "out_of_range", "stale_seq", "send_failed")

    def __init__(self, codec: DbcCodec | None = None, new_stream_after_s: float = 2.0) -> None:
        self.codec = codec if codec is not None else actuators_can()
        self.command_type = self.codec.types[COMMAND_TYPE]
        self.last_seq: int | None = None
        #: s without a forwarded command after which any sequence number starts a new stream (a
        #: restarted controller counts from 0 again); within a stream a replayed or reordered
        #: command is stale. Longer than the controller's command timeout, which stops the
        #: thruster first.
        self.new_stream_after_s = new_stream_after_s
        self._last_sent_at: float | None = None
        self.counts: Counter[str] = Counter({r: 0 for r in ("forwarded", *self.REASONS)})
        self.last_refusal = ""

    def refuse(self, reason: str, detail: str) -> CommandRefused:
        """Count a refusal (also for reasons found outside the gate: ``malformed`` envelopes,
        ``send_failed``) and return the exception to raise."""
        self.counts[reason] += 1
        self.last_refusal = f"{reason}: {detail}"
        return CommandRefused(reason, detail)

    def check(self, msg: Any, now: float | None = None) -> CanFrame:
        """The frame of ``msg`` if it may go on the bus; :class:`CommandRefused` (counted)
        otherwise. ``now``: monotonic s (None: no new stream is ever started)."""
        name = getattr(msg, "TYPE", type(msg).__name__)
        if type(msg) is not self.command_type:
            if name != COMMAND_TYPE or not dataclasses.is_dataclass(msg):
                raise self.refuse("wrong_type", f"expected {COMMAND_TYPE}, got {name}")
            try:
                msg = self.command_type(
                    **{f.name: getattr(msg, f.name) for f in dataclasses.fields(self.command_type)}
                )
            except (AttributeError, TypeError) as exc:
                detail = f"{name} without this DBC's fields: {exc}"
                raise self.refuse("wrong_type", detail) from None
        try:
            frame = self.codec.encode(msg, strict=True)  # the DBC ranges, finite numbers
        except CanCodecError as exc:
            raise self.refuse("out_of_range", str(exc)) from None
        quiet = (now is not None and self._last_sent_at is not None
                 and now - self._last_sent_at > self.new_stream_after_s)  # fmt: skip
        if not quiet and not seq_newer(msg.seq, self.last_seq):
            raise self.refuse("stale_seq", f"seq {msg.seq} not after {self.last_seq}")
        return frame

    def sent(self, frame: CanFrame, now: float | None = None) -> None:
        """Count a checked command's frame as forwarded (at monotonic ``now`` s); its sequence
        number is the last."""
        self.last_seq = int(self.codec.decode_frame(frame).seq)
        self._last_sent_at = now
        self.counts["forwarded"] += 1

    def as_dict(self) -> dict[str, Any]:
        """The counters and the last refusal (JSON-ready)."""
        return {**dict(self.counts), "last_seq": self.last_seq, "last_refusal": self.last_refusal}
