"""Step-by-step driver of the bathymetric filters for online use (pure: no bus, no Rerun).

Feeds one multibeam ping at a time with the odometry pose at the ping's time; the per-ping
storage of the filter grows as the mission goes on (:meth:`BathyFilter.reserve`)."""

from __future__ import annotations

import numpy as np

from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.filters import MTMPF, BathyFilter, DeadReckoning


def resample_swath(
    across: np.ndarray, along: np.ndarray, depth: np.ndarray, n_beams: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One swath's valid soundings (metres: starboard, forward, down) resampled by linear
    interpolation onto ``n_beams`` evenly spaced across-track positions, so every ping has the
    fixed beam count the filter stores. Raises ValueError on fewer than 2 finite soundings."""
    ok = np.isfinite(across) & np.isfinite(along) & np.isfinite(depth)
    if ok.sum() < 2:
        raise ValueError(f"swath has {int(ok.sum())} valid soundings, need at least 2")
    order = np.argsort(across[ok])
    a, f, d = across[ok][order], along[ok][order], depth[ok][order]
    grid = np.linspace(a[0], a[-1], n_beams)
    return grid, np.interp(grid, a, f), np.interp(grid, a, d)


def ned_offsets(heading: float, across: np.ndarray, along: np.ndarray) -> np.ndarray:
    """NED horizontal offsets (B, 2) m of soundings ``across`` m to starboard and ``along`` m
    forward of a vehicle at ``heading`` rad (0 = north, clockwise)."""
    c, s = np.cos(heading), np.sin(heading)
    fwd = np.array([c, s])
    stbd = np.array([-s, c])
    out: np.ndarray = across[:, None] * stbd[None, :] + along[:, None] * fwd[None, :]
    return out


class OnlineBathy:
    """mtm-pf and dead reckoning side by side, one ping at a time.

    ``add_ping(north, east, heading, across, along, depth)`` takes the odometry pose (NED m,
    rad) at the ping time and the swath; the odometry displacement since the previous ping is
    the filter's control ``u`` (eq. 2). ``n_beams`` fixes the stored beam count (the config's
    strides then decimate it)."""

    def __init__(
        self,
        cfg: BathyConfig,
        rng: np.random.Generator,
        n_beams: int = 141,
        capacity: int = 256,
    ) -> None:
        self.n_beams = n_beams
        self.filter: BathyFilter = MTMPF(cfg, capacity, rng)
        self.dr: BathyFilter = DeadReckoning(cfg, capacity, rng)
        self._last: np.ndarray | None = None

    @property
    def pings(self) -> int:
        """Pings fed so far."""
        return self.filter.t + 1

    def add_ping(
        self,
        north: float,
        east: float,
        heading: float,
        across: np.ndarray,
        along: np.ndarray,
        depth: np.ndarray,
    ) -> np.ndarray:
        """Feed one ping; return the corrected position (2,) NED m. ValueError on a swath
        with too few valid soundings (the filter state is then untouched)."""
        a, f, d = resample_swath(across, along, depth, self.n_beams)
        offsets = ned_offsets(heading, a, f)
        pos = np.array([north, east], dtype=float)
        if self._last is None:
            self.filter.start(pos, offsets, d)
            self.dr.start(pos, offsets, d)
        else:
            if self.pings >= self.filter.T:
                for flt in (self.filter, self.dr):
                    flt.reserve(2 * flt.T)
            u = pos - self._last
            self.filter.step(u, offsets, d)
            self.dr.step(u, offsets, d)
        self._last = pos
        return self.filter.trajectory()[-1].copy()

    def map_points(self, last_pings: int | None = None) -> np.ndarray:
        """Soundings placed by the corrected trajectory, (P, 3) north, east, depth m; only the
        last ``last_pings`` pings when given."""
        pts = self.filter.map_points()
        if last_pings is None:
            return pts
        keep = min(last_pings, self.pings) * self.n_beams
        return pts[-keep:]
