"""Fault injection for one emulated device: encode, then corrupt, and count exactly.

A :class:`FaultInjector` is driven by a device's
:class:`~auvgw.config.scenario.FaultSettings` (switchable at run time with
:meth:`FaultInjector.update`) and a seeded :class:`numpy.random.Generator`. It offers:

* byte-level faults on already-encoded frames (:meth:`FaultInjector.process`): dropouts,
  garbage bytes before a frame, corrupted frames (one byte flipped), truncated frames;
* time windows (vehicle seconds, ``[start, end)``): unplug/replug (:meth:`sync_port` drives a
  port), stalls (the device goes silent), bottom-lock loss (for the DVL), clock jumps
  (:meth:`device_time`), jammed fins and a silent thruster (the actuators,
  :meth:`actuator_faults`);
* the VB paper's noise bursts: :meth:`sigma_multiplier` is ``sqrt(n)`` with probability ``p``
  (the covariance times ``n``), else 1.

Exact counts against a framer. Given the device's :class:`~auvgw.drivers.framing.Framer`
class, every bad frame is *verified*: a corrupted or truncated frame is held back until the
next good frame, and the whole stretch (bad frames, garbage, the good frame) is run through a
fresh framer; it must yield exactly that good frame and nothing else valid, preferably with
exactly one bad frame per injected fault, or the flip position / cut length is drawn again.
When sync bytes inside a bad frame make the framer try more candidates in every draw, those
are counted in ``extra_bad``; a faulty frame no draw makes safely rejected is dropped instead,
counted in ``downgraded``. Garbage never contains a byte of the sync pattern. A framer that
starts at a frame boundary and is fed the injector's output therefore reports
``bad_frames == counts.bad_frames`` and loses no good frame, whatever the checksum strength (a
held-back bad frame is invisible to a consumer anyway). This holds while no more than
``max_pending`` bad frames come in a row (beyond, they go out unverified, counted).
Without a framer the faults are applied blind (the counts say what was done, not what a
framer will see).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from auvgw.config.scenario import FaultSettings
from auvgw.drivers.framing import ErrorPolicy, Framer

__all__ = ["FaultCounts", "FaultInjector", "Pluggable", "in_windows"]


class Pluggable(Protocol):
    """A port that can be unplugged and replugged (PtyPort, UdpSender, SlcanAdapter)."""

    @property
    def plugged(self) -> bool: ...

    def unplug(self) -> None: ...

    def replug(self) -> None: ...


@dataclass
class FaultCounts:
    """What the injector did. ``bad_frames`` is what a framer fed its output will count."""

    frames_in: int = 0  # frames the emulator offered
    frames_sent: int = 0  # frames put on the wire intact
    dropped: int = 0  # dropouts (never sent)
    stalled: int = 0  # not sent: inside a stall window
    unplugged: int = 0  # not sent: inside an unplug window
    garbage_events: int = 0
    garbage_bytes: int = 0
    corrupted: int = 0  # frames sent with one byte flipped
    truncated: int = 0  # frames sent cut short
    bad_bytes: int = 0  # bytes of the corrupted and truncated frames sent
    extra_bad: int = 0  # further bad candidates a framer sees (sync bytes inside bad frames)
    pending: int = 0  # bad frames held back until the next good frame
    downgraded: int = 0  # planned bad frames no draw could make reliably rejected: dropped
    unverified: int = 0  # bad frames sent without the check (no framer, or too many pending)
    noise_samples: int = 0
    noise_bursts: int = 0
    undetected: int = 0  # frames sent corrupted so that the framer accepts them (counted sent)
    undetected_failed: int = 0  # planned undetected corruptions no draw achieved: sent intact

    @property
    def bad_frames(self) -> int:
        """Bad frames a framer counts: one per corrupted or truncated frame, plus the
        ``extra_bad`` sync candidates inside them."""
        return self.corrupted + self.truncated + self.extra_bad

    @property
    def skipped_bytes(self) -> int:
        """Bytes on the wire outside good frames (garbage and bad frames)."""
        return self.garbage_bytes + self.bad_bytes

    def as_dict(self) -> dict[str, int]:
        return {**asdict(self), "bad_frames": self.bad_frames}


def in_windows(windows: list[tuple[float, float]], t: float) -> bool:
    """Whether vehicle time ``t`` falls in any ``[start, end)`` window."""
    return any(a <= t < b for a, b in windows)


@dataclass
class _Bad:
    kind: str  # "corrupt" | "truncate"
    frame: bytes
    garbage: bytes
    wire: bytes = b""


class FaultInjector:
    """Faults of one device (see the module docstring).

    ``framer`` is the device's framer class (instantiated with the IGNORE policy) or a
    factory returning a fresh framer; it makes the bad-frame counts exact. ``max_pending``
    bounds how many bad frames wait for a good one (beyond it they are sent unverified).
    """

    def __init__(
        self,
        settings: FaultSettings | None,
        rng: np.random.Generator,
        framer: type[Framer] | Callable[[], Framer] | None = None,
        name: str = "",
        max_pending: int = 8,
        max_tries: int = 32,
    ) -> None:
        self._settings = settings if settings is not None else FaultSettings()
        self.rng = rng
        self.name = name
        self.max_pending = max_pending
        self.max_tries = max_tries
        self.counts = FaultCounts()
        self._lock = threading.RLock()
        self._pending: list[_Bad] = []
        self._framer_factory: Callable[[], Framer] | None = None
        self._hdr = 0
        alphabet = np.arange(256, dtype=np.uint8)
        if framer is not None:
            if isinstance(framer, type):
                cls = framer

                def factory() -> Framer:
                    return cls(policy=ErrorPolicy.IGNORE)
            else:
                make = framer

                def factory() -> Framer:
                    f = make()
                    f.policy = ErrorPolicy.IGNORE
                    return f

            self._framer_factory = factory
            probe = factory()
            self._hdr = probe.sync_offset + len(probe.sync)
            alphabet = np.setdiff1d(alphabet, np.frombuffer(probe.sync, np.uint8))
        self._alphabet = alphabet

    # -- settings -----------------------------------------------------------------------------
    @property
    def settings(self) -> FaultSettings:
        return self._settings

    @settings.setter
    def settings(self, value: FaultSettings) -> None:
        with self._lock:
            self._settings = value

    def update(self, **changes: Any) -> FaultSettings:
        """Switch fault knobs at run time (validated like the scenario file)."""
        with self._lock:
            self._settings = FaultSettings.model_validate(
                {**self._settings.model_dump(), **changes}
            )
            return self._settings

    # -- time windows -------------------------------------------------------------------------
    def unplugged(self, t: float) -> bool:
        """Whether the device is unplugged at vehicle time ``t``."""
        return in_windows(self._settings.unplug, t)

    def stalled(self, t: float) -> bool:
        """Whether the device is stalled (silent) at vehicle time ``t``."""
        return in_windows(self._settings.stall, t)

    def bottom_lock_lost(self, t: float) -> bool:
        """Whether a bottom-lock-loss window covers vehicle time ``t`` (DVL)."""
        return in_windows(self._settings.bottom_lock_loss, t)

    def actuator_faults(self, t: float) -> frozenset[str]:
        """The actuator fault windows covering vehicle time ``t``: ``rudder_jam``,
        ``stern_jam``, ``thruster_silent`` (the actuators device)."""
        s = self._settings
        return frozenset(
            k
            for k, w in (("rudder_jam", s.rudder_jam), ("stern_jam", s.stern_jam),
                         ("thruster_silent", s.thruster_silent))
            if in_windows(w, t)
        )  # fmt: skip

    def clock_offset(self, t: float) -> float:
        """Sum of the device clock jumps that happened by vehicle time ``t``, s."""
        return sum(j for tj, j in self._settings.clock_jumps if t >= tj)

    def device_time(self, t: float) -> float:
        """The device's own clock at vehicle time ``t`` (vehicle time plus its jumps), s."""
        return t + self.clock_offset(t)

    def sync_port(self, port: Pluggable, t: float) -> bool:
        """Unplug or replug ``port`` to match the unplug windows at ``t``; True if plugged."""
        want = not self.unplugged(t)
        if want and not port.plugged:
            port.replug()
        elif not want and port.plugged:
            port.unplug()
        return want

    # -- noise --------------------------------------------------------------------------------
    def sigma_multiplier(self) -> float:
        """Per-sample noise sigma multiplier: ``sqrt(noise_burst_n)`` with probability
        ``noise_burst_p`` (a burst: covariance x n), else 1."""
        with self._lock:
            s = self._settings
            self.counts.noise_samples += 1
            if s.noise_burst_p > 0 and self.rng.random() < s.noise_burst_p:
                self.counts.noise_bursts += 1
                return math.sqrt(s.noise_burst_n)
            return 1.0

    # -- byte faults --------------------------------------------------------------------------
    def _garbage(self) -> bytes:
        n = int(self.rng.integers(1, self._settings.garbage_max_bytes + 1))
        return self._alphabet[self.rng.integers(0, len(self._alphabet), n)].tobytes()

    def _realize(self, bad: _Bad, attempt: int = 0) -> None:
        """Draw the flip position/mask or the cut length of one bad frame. Odd attempts flip
        a structural byte (the last two, where checksums and terminators live, or the eight
        after the sync, where lengths live), so formats that check little still reject it."""
        frame = bad.frame
        lo = self._hdr if self._hdr < len(frame) else 0
        if bad.kind == "corrupt":
            if attempt % 2:
                n = len(frame)
                spots = sorted(p for p in {*range(lo, lo + 8), n - 2, n - 1} if lo <= p < n)
                pos = spots[int(self.rng.integers(0, len(spots)))]
            else:
                pos = int(self.rng.integers(lo, len(frame)))
            mask = int(self.rng.integers(1, 256))
            wire = bytearray(frame)
            wire[pos] ^= mask
            bad.wire = bytes(wire)
        else:
            lo = max(lo, 1)
            bad.wire = frame[: int(self.rng.integers(lo, len(frame)))]

    def _stretch(self, bads: list[_Bad]) -> bytes:
        return b"".join(b.garbage + b.wire for b in bads)

    def _verify(self, data: bytes, good: bytes | None) -> int | None:
        """Bad frames a fresh framer counts on ``data`` if it then delivers exactly ``good`` at
        the very end (for ``good`` None: nothing valid even at end of stream); None if a good
        frame would be lost or a bogus one accepted."""
        assert self._framer_factory is not None
        f = self._framer_factory()
        # judged as a framer that waits for every claimed length: what it rejects, a framer
        # that also abandons waiting candidates rejects too, for any chunking of the stream
        f.abandon_on_inner = False
        frames = f.feed(data)
        if good is not None and getattr(f, "held", None) == len(data) - len(good):
            frames += f.finish()  # a GeoSwath ping waits for the next bytes: they would come
        if good is None:
            frames += f.finish()
            return None if frames else f.stats.bad_frames
        ok = (
            len(frames) == 1
            and frames[0].data == good
            and frames[0].offset == len(data) - len(good)
            and f.buffered == 0
        )
        return f.stats.bad_frames if ok else None

    def _emit_bads(self, bads: list[_Bad], verified: bool) -> bytes:
        for b in bads:
            self.counts.garbage_events += bool(b.garbage)
            self.counts.garbage_bytes += len(b.garbage)
            if b.kind == "corrupt":
                self.counts.corrupted += 1
            else:
                self.counts.truncated += 1
            self.counts.bad_bytes += len(b.wire)
            if not verified:
                self.counts.unverified += 1
        return self._stretch(bads)

    def _resolve(self, garbage: bytes, good: bytes | None) -> bytes:
        """Bytes for the pending bad frames followed by ``garbage`` + ``good`` (None: end of
        stream), verified against the framer when there is one."""
        bads, self._pending = self._pending, []
        self.counts.pending = 0
        tail = garbage + (good or b"")
        if self._framer_factory is None:
            for b in bads:
                self._realize(b)
            return self._emit_bads(bads, verified=False) + tail
        fallback: tuple[int, list[bytes]] | None = None
        for _ in range(4):
            # draw each bad frame until it alone, followed by the tail, is one clean reject
            for b in bads:
                for attempt in range(self.max_tries):
                    self._realize(b, attempt)
                    if self._verify(b.garbage + b.wire + tail, good) == 1:
                        break
            # then check them together (a candidate may reach into the next bad frame)
            data = self._stretch(bads) + tail
            n_bad = self._verify(data, good)
            if n_bad == len(bads):
                return self._emit_bads(bads, verified=True) + tail
            if n_bad is not None and n_bad > len(bads) and fallback is None:
                fallback = (n_bad, [b.wire for b in bads])
        if fallback is not None:
            # sync patterns inside the bad frames make the framer try them too: count those
            self.counts.extra_bad += fallback[0] - len(bads)
            for b, wire in zip(bads, fallback[1], strict=True):
                b.wire = wire
            return self._emit_bads(bads, verified=True) + tail
        # no draw keeps the good frame safe: send the garbage but not the bad frames
        self.counts.downgraded += len(bads)
        junk = b"".join(b.garbage for b in bads)
        self.counts.garbage_events += sum(bool(b.garbage) for b in bads)
        self.counts.garbage_bytes += len(junk)
        return junk + tail

    def _undetected(self, frame: bytes) -> bytes:
        """``frame`` changed so that its framer still delivers it as one valid frame: one bit
        flipped, or two bytes moved by +1 and -1 (a byte sum keeps its value), or the same bit
        flipped in two bytes (an XOR keeps its value); drawn until the framer accepts it. Without
        a framer, or when no draw passes (a CRC), the frame goes out intact (counted)."""
        rng = self.rng
        lo = self._hdr if self._hdr < len(frame) else 0
        for attempt in range(self.max_tries * 4):
            out = bytearray(frame)
            i, j = (int(v) for v in rng.integers(lo, len(frame), 2))
            if attempt % 3 == 0:
                out[i] ^= 1 << int(rng.integers(0, 8))
            elif attempt % 3 == 1 and i != j:
                out[i], out[j] = (out[i] + 1) & 0xFF, (out[j] - 1) & 0xFF
            elif i != j:
                bit = 1 << int(rng.integers(0, 8))
                out[i] ^= bit
                out[j] ^= bit
            if bytes(out) == frame or self._framer_factory is None:
                continue
            f = self._framer_factory()
            f.abandon_on_inner = False
            got = f.feed(bytes(out)) + f.finish()
            if len(got) == 1 and got[0].data == out and f.stats.bad_frames == 0:
                self.counts.undetected += 1
                return bytes(out)
        self.counts.undetected_failed += 1
        return frame

    def process(self, frame: bytes, t: float) -> bytes:
        """The bytes to send for one encoded ``frame`` at vehicle time ``t`` (possibly empty,
        possibly with held-back bad frames and garbage before it)."""
        with self._lock:
            s = self._settings
            c = self.counts
            c.frames_in += 1
            if self.unplugged(t):
                c.unplugged += 1
                return b""
            if self.stalled(t):
                c.stalled += 1
                return b""
            rng = self.rng
            if s.dropout_p > 0 and rng.random() < s.dropout_p:
                c.dropped += 1
                return b""
            garbage = self._garbage() if s.garbage_p > 0 and rng.random() < s.garbage_p else b""
            u = rng.random() if (s.corrupt_p > 0 or s.truncate_p > 0) else 1.0
            kind = None
            if u < s.corrupt_p:
                kind = "corrupt"
            elif u < s.corrupt_p + s.truncate_p and len(frame) > max(self._hdr, 1):
                kind = "truncate"
            if kind is not None:
                self._pending.append(_Bad(kind, bytes(frame), garbage))
                c.pending = len(self._pending)
                if len(self._pending) >= self.max_pending:
                    bads, self._pending = self._pending, []
                    c.pending = 0
                    for b in bads:
                        self._realize(b)
                    return self._emit_bads(bads, verified=False)
                return b""
            if s.undetected_p > 0 and rng.random() < s.undetected_p:  # goes out, wrong
                frame = self._undetected(bytes(frame))
            c.frames_sent += 1
            if not self._pending and not garbage:
                return bytes(frame)
            if not self._pending:
                c.garbage_events += 1
                c.garbage_bytes += len(garbage)
                return garbage + bytes(frame)
            out = self._resolve(garbage, bytes(frame))
            if garbage:
                c.garbage_events += 1
                c.garbage_bytes += len(garbage)
            return out

    def flush(self) -> bytes:
        """End of stream: the held-back bad frames, verified to be rejected even at the end
        (a framer's ``finish()`` counts each exactly once)."""
        with self._lock:
            if not self._pending:
                return b""
            return self._resolve(b"", None)
