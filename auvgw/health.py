"""Per-device health: counters, message rates, last seen, connection state, backoff.

A device's reader thread updates its :class:`DeviceHealth`; the status publisher and the status
queryable read :meth:`DeviceHealth.snapshot` (the JSON fields are listed in docs/gateway.md).
Times are host wall-clock ns since the Unix epoch (``time.time_ns()``). A rate counts the
messages received in the last ``window_s`` seconds of the stamp clock (the host's, or the
vehicle's under a gateway ``[clock]``) over the span of their own device times, so it is per
second of the device's clock: an emulated vehicle at ``--speed 2`` shows its INS at 100 Hz, not
200, and a burst of frames that arrive late after a stall reads the rate they were sampled at,
not the rate they arrived at. A message type whose wire carries no time is timed by the lower
envelope of its receive stamps (the samples that arrived on time; see :func:`_arrival_rate`),
and counted over the window where it has too few samples for that (once it has been seen for a
whole window). A rate not known yet (a type first seen less than a window ago with one or two
samples, as the first frame of a connection before a stall) is left out of ``rates_hz`` and
makes ``rate_hz`` None: counted over the window, that one frame read 0.2 Hz for a 100 Hz INS
(issue 33).
"""

from __future__ import annotations

import datetime as dt
import itertools
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["RATE_SAMPLES", "Backoff", "DeviceHealth", "LagTracker", "device_time_s"]

#: (stamp, device time) pairs kept per message type for the rate (bounds memory under a flood; above
#: RATE_SAMPLES / window_s messages per second the rate is taken over the samples kept)
RATE_SAMPLES = 4096


@dataclass
class Backoff:
    """Exponential retry delay in seconds: ``initial_s`` doubling up to ``max_s``; reset on
    success."""

    initial_s: float = 0.2
    max_s: float = 5.0
    _next: float = 0.0

    def next_delay(self) -> float:
        self._next = self.initial_s if self._next == 0.0 else min(self._next * 2, self.max_s)
        return self._next

    def reset(self) -> None:
        self._next = 0.0


def device_time_s(msg: object) -> float | None:
    """A decoded message's own clock in seconds (``device_time_s``, ``device_time`` or ``time``:
    a float, or a datetime as its POSIX time), or None when its wire carries no time."""
    for name in ("device_time_s", "device_time", "time"):
        v = getattr(msg, name, None)
        if isinstance(v, dt.datetime):
            return v.timestamp()
        if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
            return float(v)
    return None


def _device_rate(times: deque[tuple[int, float | None]]) -> float | None:
    """Samples per second of their own device time, ``(n - 1) / (last - first)``, over the
    newest run of ``(stamp, device time)`` pairs whose device time increases (a device clock
    that stepped back restarted); None where fewer than two samples carry a time."""
    n = 0
    last = first = math.inf
    for _, t in reversed(times):
        if t is None or t >= first:  # no time, or the device clock stepped back here
            break
        if n == 0:
            last = t
        first = t
        n += 1
    if n < 2:
        return None
    return (n - 1) / (last - first)


def _arrival_rate(times: deque[tuple[int, float | None]]) -> float | None:
    """Samples per second of a type whose wire carries no time, from their receive stamps:
    a delay (a stall, then a burst) only adds to a stamp, so the samples that arrived on time
    lie on the lower convex hull of (sample index, stamp), and its edge over the middle sample
    has the sampling period for slope (a count over the window read 20 Hz as 24-28 Hz when
    bursts crossed its edges on a loaded host, issue 33). None with fewer than three samples
    or no positive slope there (one burst)."""
    n = len(times)
    if n < 3:
        return None
    hull: list[tuple[int, int]] = []
    for k, (stamp, _) in enumerate(times):
        while len(hull) >= 2:
            (k0, s0), (k1, s1) = hull[-2], hull[-1]
            if (k1 - k0) * (stamp - s0) - (s1 - s0) * (k - k0) > 0:  # a left turn: convex
                break
            hull.pop()
        hull.append((k, stamp))
    mid = (n - 1) / 2
    for (k0, s0), (k1, s1) in itertools.pairwise(hull):
        if k0 <= mid <= k1:
            return (k1 - k0) * 1e9 / (s1 - s0) if s1 > s0 else None
    return None


@dataclass
class LagTracker:
    """Transport lag from a device's own clock: ``(t_recv - t_device) - min(t_recv - t_device)``.

    The offset between the receive stamp and the device's time is the clocks' difference plus
    the transport delay; its minimum over the connection is the clocks' difference plus the
    best delay seen, so what a sample has on top of it is how far the reader has fallen behind
    the device (seconds, on the stamp clock: vehicle-paced under ``[clock]``). The baseline
    restarts when the device clock steps back (a wrap, a device reset): see :meth:`reset`.
    A device clock drifting against the host shows up as a slowly growing lag (50 ppm: 0.18 s
    an hour).
    """

    _min_offset: float | None = None
    _last_device: float | None = None

    def observe(self, t_stamp_s: float, t_device_s: float) -> float:
        """The lag (s) of one sample stamped ``t_stamp_s`` whose device time is ``t_device_s``."""
        if self._last_device is not None and t_device_s < self._last_device:
            self._min_offset = None  # the device clock wrapped or restarted
        self._last_device = t_device_s
        offset = t_stamp_s - t_device_s
        if self._min_offset is None or offset < self._min_offset:
            self._min_offset = offset
        return offset - self._min_offset

    def reset(self) -> None:
        """Forget the baseline (a new connection may be a new device clock)."""
        self._min_offset = self._last_device = None


@dataclass
class DeviceHealth:
    """What the gateway knows about one device; updated by its reader, read by the status task.

    Rates: the messages stamped in the last ``window_s`` seconds, per second of the time their
    device times span (see the module docstring; per ``window_s`` where there is none, once the
    type has been seen for a whole window; None until a rate is known).
    """

    name: str
    format: str
    port: str = ""
    window_s: float = 5.0
    connected: bool = False
    ended: bool = False
    frames: int = 0
    bad_frames: int = 0
    skipped_bytes: int = 0
    bad_frame_reasons: Counter[str] = field(default_factory=Counter)
    decode_errors: int = 0
    messages: Counter[str] = field(default_factory=Counter)
    connects: int = 0
    outages: int = 0
    reopens: int = 0
    last_seen_ns: int | None = None
    connected_since_ns: int | None = None
    next_retry_s: float | None = None
    last_error: str = ""
    rejected_datagrams: int = 0
    last_rejected_sender: str | None = None
    #: newest sample: its stamp (ns, the published clock) and transport lag (s, None: no time)
    last_stamp_ns: int | None = None
    lag_s: float | None = None
    lag_max_s: float | None = None
    #: data lost below the framer, per counter (:meth:`Transport.losses
    #: <auvgw.drivers.transports.Transport.losses>`), since the gateway started
    transport_losses: Counter[str] = field(default_factory=Counter)
    lag: LagTracker = field(default_factory=LagTracker)
    _times: dict[str, deque[tuple[int, float | None]]] = field(default_factory=dict)
    #: the stamp (ns) each message type was first seen at (for an untimed type's full window)
    _first_ns: dict[str, int] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def seen(
        self,
        t_ns: int,
        type_name: str,
        t_stamp_ns: int | None = None,
        t_device_s: float | None = None,
    ) -> None:
        """A message of ``type_name`` decoded from a chunk received at ``t_ns`` (host clock),
        published with the stamp ``t_stamp_ns`` (default ``t_ns``), carrying the device's own
        time ``t_device_s`` (s) if its wire has one (for the lag)."""
        stamp = t_ns if t_stamp_ns is None else t_stamp_ns
        with self._lock:
            self.messages[type_name] += 1
            self.last_seen_ns = t_ns
            self.last_stamp_ns = stamp
            times = self._times.get(type_name)
            if times is None:  # (not setdefault: that builds a deque per message)
                times = self._times[type_name] = deque(maxlen=RATE_SAMPLES)
                self._first_ns[type_name] = stamp
            times.append((stamp, t_device_s))  # the window on the stamp clock
            if t_device_s is not None:
                self.lag_s = self.lag.observe(stamp / 1e9, t_device_s)
                self.lag_max_s = max(self.lag_s, self.lag_max_s or 0.0)

    def set_transport_losses(self, losses: Mapping[str, int]) -> None:
        """Totals of the transport's loss counters since the gateway started."""
        with self._lock:
            self.transport_losses = Counter(losses)

    def set_rejected(self, datagrams: int, sender: str | None) -> None:
        """Datagrams dropped (since the gateway started) because their sender is not allowed."""
        with self._lock:
            self.rejected_datagrams = datagrams
            if sender is not None:
                self.last_rejected_sender = sender

    def decode_error(self, text: str) -> None:
        """A frame passed its checksum but could not be decoded."""
        with self._lock:
            self.decode_errors += 1
            self.last_error = text

    def set_connected(
        self, connected: bool, error: str = "", retry_in_s: float | None = None
    ) -> None:
        """Record a connect (``connected=True``) or a failed open / disconnect with its reason."""
        with self._lock:
            if self.connected and not connected:
                self.outages += 1
            if connected and not self.connected:
                self.connects += 1
                self.connected_since_ns = time.time_ns()
                self.lag.reset()
            if not connected:
                self.connected_since_ns = None
            self.connected = connected
            self.next_retry_s = None if connected else retry_in_s
            if error:
                self.last_error = error

    def set_reopening(self, reason: str) -> None:
        """The gateway closes an open but silent connection to reopen it at once: counted in
        ``reopens``; still ``connected`` (not an outage, not a new connect) unless the reopen
        fails."""
        with self._lock:
            self.reopens += 1
            self.last_error = reason

    def set_retry(self, delay_s: float) -> None:
        """The next reopen attempt is ``delay_s`` seconds away."""
        with self._lock:
            self.next_retry_s = delay_s

    def set_ended(self, reason: str) -> None:
        """A finite source (a file replayed without loop) is over; no reconnect follows."""
        with self._lock:
            self.connected = False
            self.connected_since_ns = None
            self.ended = True
            self.next_retry_s = None
            self.last_error = reason

    def set_framing(
        self, frames: int, bad_frames: int, skipped_bytes: int, reasons: Counter[str]
    ) -> None:
        """Framing totals since the gateway started (all connections)."""
        with self._lock:
            self.frames = frames
            self.bad_frames = bad_frames
            self.skipped_bytes = skipped_bytes
            self.bad_frame_reasons = reasons

    def _rates(self, now_ns: int) -> tuple[dict[str, float], bool]:
        """The rate per message type that has one, and whether every type has one."""
        cutoff = now_ns - int(self.window_s * 1e9)
        out = {}
        complete = True
        for name, times in self._times.items():
            while times and times[0][0] < cutoff:
                times.popleft()
            rate = _device_rate(times)
            if rate is None and times and times[-1][1] is None:
                rate = _arrival_rate(times)
            if rate is not None:
                out[name] = round(rate, 3)
            elif len(times) == times.maxlen and now_ns > times[0][0]:  # faster than kept
                out[name] = round(len(times) / ((now_ns - times[0][0]) / 1e9), 3)
            elif self._first_ns[name] <= cutoff:  # seen for a whole window: count over it
                out[name] = round(len(times) / self.window_s, 3)
            else:  # a sample or two, first seen less than a window ago
                complete = False
        return out, complete

    def rate_hz(self, now_ns: int | None = None) -> float | None:
        """Messages per second (all types) over the last ``window_s`` seconds of the stamp clock
        (``now_ns``: now on it; the host clock where no ``[clock]`` paces the stamps); None
        while a type's rate is not known yet (see the module docstring)."""
        now_ns = time.time_ns() if now_ns is None else now_ns
        with self._lock:
            rates, complete = self._rates(now_ns)
            return round(sum(rates.values()), 3) if complete else None

    def snapshot(
        self,
        now_ns: int | None = None,
        stale_after_s: float | None = None,
        now_stamp_ns: int | None = None,
    ) -> dict[str, Any]:
        """The JSON-ready status of the device (fields documented in docs/gateway.md);
        ``now_stamp_ns`` is now on the stamp clock (default ``now_ns``), for ``age_s``."""
        now_ns = time.time_ns() if now_ns is None else now_ns
        now_stamp_ns = now_ns if now_stamp_ns is None else now_stamp_ns
        with self._lock:
            age = None
            if self.last_stamp_ns is not None:
                age = round((now_stamp_ns - self.last_stamp_ns) / 1e9 + (self.lag_s or 0.0), 3)
            rates, complete = self._rates(now_stamp_ns)
            silent = (
                None if self.last_seen_ns is None else round((now_ns - self.last_seen_ns) / 1e9, 3)
            )
            stale = (
                not self.connected
                or silent is None
                or (stale_after_s is not None and silent > stale_after_s)
            )
            return {
                "device": self.name,
                "format": self.format,
                "port": self.port,
                "connected": self.connected,
                "ended": self.ended,
                "stale": stale,
                "rate_hz": round(sum(rates.values()), 3) if complete else None,
                "rates_hz": rates,
                "frames": self.frames,
                "bad_frames": self.bad_frames,
                "bad_frame_reasons": dict(self.bad_frame_reasons),
                "skipped_bytes": self.skipped_bytes,
                "decode_errors": self.decode_errors,
                "messages": dict(self.messages),
                "connects": self.connects,
                "outages": self.outages,
                "reopens": self.reopens,
                "connected_since_ns": self.connected_since_ns,
                "last_seen_ns": self.last_seen_ns,
                "silent_s": silent,
                "age_s": age,
                "lag_s": None if self.lag_s is None else round(self.lag_s, 3),
                "lag_max_s": None if self.lag_max_s is None else round(self.lag_max_s, 3),
                "transport_losses": dict(self.transport_losses),
                "transport_lost": sum(self.transport_losses.values()),
                "next_retry_s": self.next_retry_s,
                "last_error": self.last_error,
                "rejected_datagrams": self.rejected_datagrams,
                "last_rejected_sender": self.last_rejected_sender,
            }
