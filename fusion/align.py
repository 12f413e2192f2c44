"""Time alignment: INS interpolation at aiding times and the fixed-lag reorder buffer.

Rule: every aiding sample (DVL, depth) is applied at its own time ``t``. The filter is propagated
exactly to ``t`` with the INS state interpolated between the two INS samples that bracket ``t``
(angles along the shortest arc, so heading interpolates correctly across +-pi), the aiding update
is made there, and propagation continues to the next INS sample. Nothing is ever paired with the
"latest" INS sample.

Arrival order does not matter within a bound: :class:`ReorderBuffer` holds INS samples and aiding
samples and releases an INS interval only when the newest INS time has moved ``max_latency_s``
past its end, so any sample arriving at most ``max_latency_s`` (in sample time) behind the newest
INS sample is still processed in time order. Later samples are dropped and counted.
"""

from __future__ import annotations

import heapq
import itertools
import math
from bisect import bisect_left
from collections.abc import Iterator
from dataclasses import dataclass

from auvgw.fusion.frames import wrap_angle
from auvgw.fusion.samples import DepthSample, DvlSample, InsSample, PositionFix

__all__ = ["BufferStats", "ReorderBuffer", "interp_angle", "interpolate_ins"]

AidingSample = DvlSample | DepthSample | PositionFix

#: order of aiding kinds that share one time stamp (deterministic whatever the arrival order)
_KIND_RANK = {DvlSample: 0, DepthSample: 1, PositionFix: 2}


def interp_angle(a0: float, a1: float, alpha: float) -> float:
    """Angle a fraction ``alpha`` of the way from ``a0`` to ``a1`` along the shorter arc, wrapped
    into [-pi, pi) (rad)."""
    return wrap_angle(a0 + alpha * wrap_angle(a1 - a0))


def _lerp3(
    a: tuple[float, float, float], b: tuple[float, float, float], alpha: float
) -> tuple[float, float, float]:
    return (
        a[0] + alpha * (b[0] - a[0]),
        a[1] + alpha * (b[1] - a[1]),
        a[2] + alpha * (b[2] - a[2]),
    )


def interpolate_ins(a: InsSample, b: InsSample, t: float) -> InsSample:
    """The INS state at time ``t`` in ``[a.t, b.t]``: attitude along the shortest arc (wrapped),
    rates and specific force linear. Returns ``a`` or ``b`` themselves at the end points."""
    if not a.t <= t <= b.t:
        raise ValueError(f"t={t!r} s is outside the INS interval [{a.t!r}, {b.t!r}] s")
    if t == a.t:
        return a
    if t == b.t:
        return b
    alpha = (t - a.t) / (b.t - a.t)
    accel = None
    if a.accel is not None and b.accel is not None:
        accel = _lerp3(a.accel, b.accel, alpha)
    return InsSample(
        t=t,
        roll=interp_angle(a.roll, b.roll, alpha),
        pitch=a.pitch + alpha * (b.pitch - a.pitch),
        heading=interp_angle(a.heading, b.heading, alpha),
        rates=_lerp3(a.rates, b.rates, alpha),
        accel=accel,
    )


@dataclass
class BufferStats:
    """Counters of the reorder buffer (samples, not bytes)."""

    ins_late: int = 0  #: INS samples at or before the processed time (dropped)
    ins_duplicate: int = 0  #: INS samples with a time already pending (dropped)
    aiding_late: int = 0  #: aiding samples at or before the processed time (dropped)
    aiding_before_start: int = 0  #: aiding samples older than the first INS sample (dropped)
    aiding_overflow: int = 0  #: oldest aiding samples dropped because the buffer was full


class ReorderBuffer:
    """Fixed-lag time ordering of INS samples and aiding samples.

    ``max_latency_s``: how far (in sample time) behind the newest INS sample a sample may arrive
    and still be processed in order; INS intervals are released that much later.
    ``max_pending``: bound on buffered aiding samples; on overflow the oldest is dropped.
    """

    def __init__(self, max_latency_s: float, max_pending: int) -> None:
        self.max_latency_s = float(max_latency_s)
        self.max_pending = int(max_pending)
        self._ins: list[InsSample] = []
        self._aiding: list[tuple[float, int, int, AidingSample]] = []
        self._seq = itertools.count()
        self._newest = -math.inf
        self.done_t: float | None = None  #: time of the last released INS sample
        self.stats = BufferStats()

    def __len__(self) -> int:
        return len(self._ins) + len(self._aiding)

    def add_ins(self, s: InsSample) -> bool:
        """Buffer an INS sample; False (and counted) when late or a duplicate time."""
        t = s.t
        if self.done_t is not None and t <= self.done_t:
            self.stats.ins_late += 1
            return False
        ins = self._ins
        if not ins or t > ins[-1].t:  # the usual case: in order
            ins.append(s)
        else:
            i = bisect_left(ins, t, key=lambda x: x.t)
            if ins[i].t == t:
                self.stats.ins_duplicate += 1
                return False
            ins.insert(i, s)
        if t > self._newest:
            self._newest = t
        return True

    def add_aiding(self, s: AidingSample) -> bool:
        """Buffer a DVL or depth sample; False (and counted) when it arrives too late."""
        if self.done_t is not None and s.t <= self.done_t:
            self.stats.aiding_late += 1
            return False
        heapq.heappush(self._aiding, (s.t, _KIND_RANK[type(s)], next(self._seq), s))
        if len(self._aiding) > self.max_pending:
            heapq.heappop(self._aiding)
            self.stats.aiding_overflow += 1
        return True

    def release(self, flush: bool = False) -> Iterator[tuple[InsSample, list[AidingSample]]]:
        """Yield, in time order, each INS sample whose time is at least ``max_latency_s`` behind
        the newest INS time (all of them when ``flush``) with the aiding samples in
        ``(previous INS time, its time]``, sorted by time."""
        horizon = math.inf if flush else self._newest - self.max_latency_s
        while self._ins and self._ins[0].t <= horizon:
            s = self._ins.pop(0)
            events: list[AidingSample] = []
            while self._aiding and self._aiding[0][0] <= s.t:
                e = heapq.heappop(self._aiding)[3]
                if self.done_t is None and e.t < s.t:
                    self.stats.aiding_before_start += 1
                    continue
                events.append(e)
            self.done_t = s.t
            yield s, events
