"""What every online pipeline does with the odometry: a pose history, samples held until the
odometry covers them, and odometry increments composed into one motion.

* :class:`StateHistory`: a short, time-ordered history of vehicle states, interpolated at any
  time inside it. The online pipelines place a sensor sample with the odometry *at the sample's
  own time*: the landmark pipeline an MSIS ping with the pose ``(x, y, heading)``
  (:class:`~auvgw.slam.landmark.online.LandmarkOnline`), the bathymetric stage a swath with the
  same pose, the magnetic stage a magnetometer sample with the attitude ``(heading, pitch,
  roll)``. Angles are stored unwrapped (each new value is moved by whole turns next to the
  previous one), so a linear interpolation takes the shortest way round; they are returned
  wrapped to [-pi, pi).
* :class:`HeldSamples`: sensor samples received before the odometry reaches their time wait in
  it, bounded (the oldest is dropped and counted), and are released in time order once covered.
* :func:`compose_increments`: consecutive odometry motion increments as one (eq. 3 of Mu et al.
  2022 applied in turn).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterator, Sequence
from typing import Generic, Protocol, TypeVar

import numpy as np

from auvgw.ground.geometry import wrap_angle

__all__ = ["HeldSamples", "Increment", "StateHistory", "compose_increments"]

S = TypeVar("S")


class Increment(Protocol):
    """One odometry motion increment (:class:`auvgw.fusion.MotionIncrement`)."""

    @property
    def t1(self) -> float: ...  # end time, s

    @property
    def dt(self) -> float: ...  # duration, s

    def apply(self, x: float, y: float, heading: float) -> tuple[float, float, float]: ...


def compose_increments(incs: Sequence[Increment]) -> tuple[float, float, float, float]:
    """The motion of consecutive increments as one: ``(dx forward, dy starboard, dheading,
    dt)`` in the body frame at the first increment's start (m, m, rad, s); eq. (3) of Mu et al.
    2022 applied increment by increment."""
    x = y = h = 0.0
    dt = 0.0
    for inc in incs:
        x, y, h = inc.apply(x, y, h)
        dt += inc.dt
    return x, y, h, dt


class HeldSamples(Generic[S]):
    """Samples ``(t, sample)`` waiting for the odometry to cover their time ``t`` (s, the
    odometry clock), in arrival order, at most ``limit`` of them: :meth:`hold` one, then
    :meth:`release` those the odometry covers. ``dropped``: samples dropped because the hold was
    full (the oldest goes); ``held``: samples ever held."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f"HeldSamples: limit {limit}, need at least 1")
        self.limit = limit
        self.dropped = 0
        self.held = 0
        self._q: deque[tuple[float, S]] = deque()

    def __len__(self) -> int:
        return len(self._q)

    def hold(self, t: float, sample: S) -> int:
        """Hold ``sample`` received at ``t``; returns the number dropped to make room (0 or 1)."""
        dropped = 0
        if len(self._q) >= self.limit:
            self._q.popleft()
            dropped = 1
        self._q.append((float(t), sample))
        self.held += 1
        self.dropped += dropped
        return dropped

    def release(self, t_covered: float | None) -> Iterator[tuple[float, S]]:
        """The held samples at or before ``t_covered`` (the newest odometry time; None: none),
        oldest first, each removed as it is given."""
        if t_covered is None:
            return
        while self._q and self._q[0][0] <= t_covered:
            yield self._q.popleft()

    def clear(self) -> int:
        """Forget every held sample (end of data); returns how many there were."""
        n = len(self._q)
        self._q.clear()
        return n


class StateHistory:
    """States (vectors of ``width`` floats) at strictly increasing times (s).

    ``angles``: indices of the components that are angles (rad). Times and units are the
    caller's (the odometry clock, s; metres and radians in NED).
    """

    def __init__(self, width: int, angles: Sequence[int] = ()) -> None:
        self.width = width
        self.angles = tuple(angles)
        self._t: deque[float] = deque()
        self._x: deque[tuple[float, ...]] = deque()

    def __len__(self) -> int:
        return len(self._t)

    @property
    def first_t(self) -> float | None:
        """The oldest time held (None: empty)."""
        return self._t[0] if self._t else None

    @property
    def last_t(self) -> float | None:
        """The newest time held (None: empty)."""
        return self._t[-1] if self._t else None

    def append(self, t: float, state: Sequence[float]) -> bool:
        """Add ``state`` at ``t``; a time not after the newest is refused (returns False)."""
        if self._t and t <= self._t[-1]:
            return False
        x = [float(v) for v in state]
        if len(x) != self.width:
            raise ValueError(f"StateHistory: a state of {len(x)} values, expected {self.width}")
        if self._x:
            prev = self._x[-1]
            for i in self.angles:
                x[i] = prev[i] + math.remainder(x[i] - prev[i], math.tau)
        self._t.append(float(t))
        self._x.append(tuple(x))
        return True

    def at(self, t: float, hold_first: bool = False) -> np.ndarray | None:
        """The state at ``t``, linearly interpolated (angles the shortest way, wrapped); after
        the newest time the newest state; before the oldest None (``hold_first``: the oldest)."""
        th = self._t
        if not th:
            return None
        if t < th[0] and not hold_first:
            return None
        i = bisect.bisect_left(th, t)
        if i >= len(th):
            x = np.array(self._x[-1])
        elif i == 0 or th[i] == t:
            x = np.array(self._x[i])
        else:
            t0, t1 = th[i - 1], th[i]
            a = (t - t0) / (t1 - t0)
            x0, x1 = np.array(self._x[i - 1]), np.array(self._x[i])
            x = x0 + a * (x1 - x0)
        for i in self.angles:
            x[i] = float(wrap_angle(x[i]))
        return x

    def trim(self, keep_from: float, keep: int = 2) -> None:
        """Forget the states before ``keep_from`` (s), keeping the one just before it (so
        ``keep_from`` itself still interpolates) and at least ``keep`` states."""
        while len(self._t) > keep and self._t[1] < keep_from:
            self._t.popleft()
            self._x.popleft()
