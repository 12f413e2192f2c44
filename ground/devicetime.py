"""Device time onto the common clock: the one home of device-time mapping.

Every device that stamps its own time (an INS's time since power-up, a DVL's RTC, a simulation
clock, an emulator's epoch) is mapped onto the common clock (the host receive time, or the
vehicle-paced stamp of a gateway ``[clock]``; seconds) by one :class:`DeviceClock` per device:
the fusion's :class:`~auvgw.fusion.adapters.MessageAdapter` to align samples, the Rerun stage
to put device times on the ``sensor_time`` timeline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ABSOLUTE_CLOCK_S", "ClockStats", "DeviceClock"]

#: a device time beyond this (s) reads an absolute (POSIX/UTC) clock (2001-09-09)
ABSOLUTE_CLOCK_S = 1e9


@dataclass
class ClockStats:
    """Counters of one :class:`DeviceClock`."""

    samples: int = 0
    wraps: int = 0  #: device-clock wraps unwrapped
    resets: int = 0  #: offset re-estimated after a backward device-clock jump


class DeviceClock:
    """Maps one device's own clock onto the common clock (host receive time, s).

    The offset ``t_recv - t_device`` of a sample is its transport latency plus the clocks'
    offset; the smallest seen is the best estimate of the clocks' offset (latency only adds).
    So the estimate follows ``offset_k = min(offset_{k-1} + skew * dt_recv, d_k)``: it drops at
    once to a smaller difference (a faster device clock, a forward jump) and may creep up by at
    most ``skew`` s/s (a slower device clock). A device clock that jumps backward makes every
    difference exceed the estimate; once they have exceeded it by more than ``jump_s`` for
    ``confirm`` samples AND ``confirm_s`` seconds of receive time (so a backlog after a stall is
    not taken for a jump), the estimate restarts from the current difference. Lag alone (frames
    late while the device's own time runs on without going back: a loaded host, a stalled
    reader) also makes the differences exceed the estimate, and mapping late frames onto their
    true times is then right: so when the device time did not go back where the excess began,
    the restart needs the excess to last ``lag_confirm_s`` s of device time as well (a common
    clock that itself jumped, as a gateway restarted on another epoch; 0: no such wait). Before
    this, frames a few seconds late at 10x reset the INS clock forward, the fusion coasted over
    the gap and dead reckoning ended 175-325 m off. ``wrap_s``: the
    device time wraps after this many seconds (unwrapped here). ``latency_s``: a known fixed
    delay between the device's time stamp and reception (e.g. frame bytes x 10 / baud),
    subtracted from every mapped time. ``sync_s``: a device clock that reads UTC (beyond
    :data:`ABSOLUTE_CLOCK_S`) and agrees with the common clock within this many seconds passes
    through unchanged (a GPS-disciplined sonar, a DVL set at dive start; None: never).

    :meth:`to_common` maps a sample; calling the clock (``clock(t_device, t_recv)``) does the
    same and passes a sample without a device time (None, NaN) through at ``t_recv``.
    """

    def __init__(
        self,
        latency_s: float = 0.0,
        skew: float = 1e-4,
        jump_s: float = 1.0,
        confirm: int = 3,
        confirm_s: float = 0.5,
        lag_confirm_s: float = 30.0,
        wrap_s: float | None = None,
        sync_s: float | None = None,
    ) -> None:
        self.latency_s = float(latency_s)
        self.skew = float(skew)
        self.jump_s = float(jump_s)
        self.confirm = int(confirm)
        self.confirm_s = float(confirm_s)
        self.lag_confirm_s = float(lag_confirm_s)
        self.wrap_s = wrap_s
        self.sync_s = sync_s
        self.offset: float | None = None
        self.stats = ClockStats()
        self._last_recv = math.nan
        self._last_dev = math.nan
        self._wrap_base = 0.0
        self._excess_n = 0
        self._excess_since = math.nan
        self._excess_dev_since = math.nan
        self._excess_backward = False

    def _unwrap(self, t_device: float) -> float:
        w = self.wrap_s
        if w is not None and math.isfinite(self._last_dev):
            t = t_device + self._wrap_base
            if t < self._last_dev - 0.5 * w:
                self._wrap_base += w
                self.stats.wraps += 1
                t += w
            return t
        return t_device

    def to_common(self, t_device: float, t_recv: float) -> float:
        """The common-clock time (s) of a sample stamped ``t_device`` (device s) and received at
        ``t_recv`` (common clock s)."""
        t_dev = self._unwrap(t_device)
        d = t_recv - t_dev
        if self.sync_s is not None and t_dev > ABSOLUTE_CLOCK_S and abs(d) <= self.sync_s:
            self.stats.samples += 1
            return t_dev
        off = self.offset
        if off is None:
            off = d
        else:
            off += self.skew * max(t_recv - self._last_recv, 0.0)
            if d <= off:
                off = d
                self._excess_n = 0
            elif d - off > self.jump_s:
                if self._excess_n == 0:
                    self._excess_since = t_recv
                    self._excess_dev_since = t_dev
                    self._excess_backward = t_dev < self._last_dev
                self._excess_n += 1
                if (
                    self._excess_n >= self.confirm
                    and t_recv - self._excess_since >= self.confirm_s
                    and (
                        self._excess_backward
                        or t_dev - self._excess_dev_since >= self.lag_confirm_s
                    )
                ):
                    off = d
                    self._excess_n = 0
                    self.stats.resets += 1
            else:
                self._excess_n = 0
        self.offset = off
        self._last_recv = t_recv
        self._last_dev = t_dev
        self.stats.samples += 1
        return t_dev + off - self.latency_s

    def __call__(self, t_device: float | None, t_recv: float) -> float:
        """:meth:`to_common`, or ``t_recv`` for a sample without a device time (None, NaN)."""
        if t_device is None or not math.isfinite(t_device):
            return t_recv
        return self.to_common(t_device, t_recv)
