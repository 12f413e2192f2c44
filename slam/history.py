"""A short, time-ordered history of vehicle states, interpolated at any time inside it.

The online pipelines place a sensor sample with the odometry *at the sample's own time*: the
landmark pipeline an MSIS ping with the pose ``(x, y, heading)``
(:class:`~auvgw.slam.landmark.online.LandmarkOnline`), the magnetic stage a magnetometer sample
with the attitude ``(heading, pitch, roll)``. Angles are stored unwrapped (each new value is
moved by whole turns next to the previous one), so a linear interpolation takes the shortest
way round; they are returned wrapped to [-pi, pi).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from auvgw.ground.geometry import wrap_angle

__all__ = ["StateHistory"]


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
