"""Offline use of the filter: recordings or arrays in, odometry out (no bus needed).

:func:`run_filter` returns the same :class:`~auvgw.fusion.odometry.Odometry` objects the online
stage publishes; :func:`run_filter_arrays` returns them as columns (:class:`OdometryArrays`) for
long runs and evaluation. :func:`ins_from_arrays`, :func:`dvl_from_arrays` and
:func:`depth_from_arrays` build the input samples from arrays in SI units.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from auvgw.fusion.config import FusionConfig
from auvgw.fusion.navfilter import FusionStats, NavFilter
from auvgw.fusion.odometry import Odometry
from auvgw.fusion.samples import DepthSample, DvlFrame, DvlSample, InsSample, PositionFix

__all__ = [
    "OdometryArrays",
    "depth_from_arrays",
    "dvl_from_arrays",
    "ins_from_arrays",
    "iter_filter",
    "run_filter",
    "run_filter_arrays",
]

Sample = InsSample | DvlSample | DepthSample | PositionFix


def ins_from_arrays(
    t: np.ndarray,
    roll: np.ndarray,
    pitch: np.ndarray,
    heading: np.ndarray,
    rates: np.ndarray | None = None,
    accel: np.ndarray | None = None,
) -> list[InsSample]:
    """INS samples from arrays: times (s), attitude (rad), body rates (n, 3) rad/s, specific
    force (n, 3) m/s^2."""
    n = len(t)
    r = np.zeros((n, 3)) if rates is None else np.asarray(rates, dtype=float).reshape(n, 3)
    acc = (
        [None] * n
        if accel is None
        else zip(*np.asarray(accel, float).reshape(n, 3).T.tolist(), strict=True)
    )
    return list(
        map(
            InsSample,
            np.asarray(t, float).tolist(),
            np.asarray(roll, float).tolist(),
            np.asarray(pitch, float).tolist(),
            np.asarray(heading, float).tolist(),
            zip(*r.T.tolist(), strict=True),
            acc,
        )
    )


def dvl_from_arrays(
    t: np.ndarray,
    velocity: np.ndarray,
    bottom_lock: np.ndarray | None = None,
    frame: DvlFrame = "instrument",
    altitude: np.ndarray | None = None,
    depth: np.ndarray | None = None,
) -> list[DvlSample]:
    """DVL fixes from arrays: times (s), velocity (n, 3) m/s in ``frame`` axes (NaN = missing),
    bottom lock flags, altitude and pressure depth (m, NaN = absent)."""
    n = len(t)
    lock = np.ones(n, bool) if bottom_lock is None else np.asarray(bottom_lock, bool)
    alt = np.full(n, np.nan) if altitude is None else np.asarray(altitude, float)
    dep = np.full(n, np.nan) if depth is None else np.asarray(depth, float)
    vel = [tuple(row) for row in np.asarray(velocity, dtype=float).tolist()]
    return [
        DvlSample(t=a, velocity=v, bottom_lock=bool(k), frame=frame, altitude=al, depth=d)
        for a, v, k, al, d in zip(
            np.asarray(t, float).tolist(), vel, lock.tolist(), alt.tolist(), dep.tolist(),
            strict=True,
        )
    ]


def depth_from_arrays(t: np.ndarray, depth: np.ndarray) -> list[DepthSample]:
    """Pressure depths (m, positive down) at times ``t`` (s)."""
    return [
        DepthSample(t=a, depth=d)
        for a, d in zip(np.asarray(t, float).tolist(), np.asarray(depth, float).tolist(),
                        strict=True)
    ]


def _time_ordered(*streams: Iterable[Sample]) -> Iterator[Sample]:
    return heapq.merge(*(sorted(s, key=lambda x: x.t) for s in streams), key=lambda x: x.t)


def iter_filter(
    ins: Iterable[InsSample],
    dvl: Iterable[DvlSample] = (),
    config: FusionConfig | None = None,
    depth: Iterable[DepthSample | PositionFix] = (),
    nav: NavFilter | None = None,
) -> Iterator[Odometry]:
    """Run a :class:`NavFilter` over recorded samples (merged in time order), yielding each
    :class:`Odometry` as it is produced (one per usable INS sample)."""
    f = nav if nav is not None else NavFilter(config)
    for s in _time_ordered(ins, dvl, depth):
        yield from f.push(s)
    yield from f.flush()


def run_filter(
    ins: Iterable[InsSample],
    dvl: Iterable[DvlSample] = (),
    config: FusionConfig | None = None,
    depth: Iterable[DepthSample] = (),
) -> list[Odometry]:
    """Dead reckoning over recorded samples: one :class:`Odometry` per usable INS sample."""
    return list(iter_filter(ins, dvl, config, depth))


@dataclass(frozen=True)
class OdometryArrays:
    """Columns of an odometry run (``n`` INS epochs). Units and frames as :class:`Odometry`;
    the increment columns are NaN at the first epoch."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    heading: np.ndarray
    velocity_ned: np.ndarray  #: (n, 3)
    velocity_body: np.ndarray  #: (n, 3)
    cov_xy: np.ndarray  #: (n, 2, 2)
    variances: np.ndarray  #: (n, 8) diagonal of the covariance
    bottom_lock: np.ndarray
    coasting: np.ndarray
    increment: np.ndarray  #: (n, 4): dx, dy, dheading, dt
    increment_cov: np.ndarray  #: (n, 3, 3)
    covariance: np.ndarray | None  #: (n, 8, 8) when asked for
    stats: FusionStats

    def __len__(self) -> int:
        return len(self.t)


def run_filter_arrays(
    ins: Sequence[InsSample],
    dvl: Sequence[DvlSample] = (),
    config: FusionConfig | None = None,
    depth: Sequence[DepthSample] = (),
    full_covariance: bool = False,
    nav: NavFilter | None = None,
    fixes: Sequence[PositionFix] = (),
) -> OdometryArrays:
    """:func:`run_filter` returning columns; keeps the full 8 x 8 covariance only if asked.
    ``nav``: run this filter (e.g. to read its diagnostics afterwards) instead of a new one
    built from ``config``; ``fixes``: position fixes (GNSS, USBL) merged with the depths."""
    nav = nav if nav is not None else NavFilter(config)
    rows: list[tuple[float, ...]] = []
    inc: list[tuple[float, float, float, float]] = []
    inc_cov: list[np.ndarray] = []
    pending: list[np.ndarray] = []  # covariances not yet reduced (reduced in blocks)
    cov_xy: list[np.ndarray] = []
    variances: list[np.ndarray] = []
    covs: list[np.ndarray] = []
    nan3 = np.full((3, 3), np.nan)
    nan4 = (np.nan, np.nan, np.nan, np.nan)

    def reduce() -> None:
        if pending:
            block = np.stack(pending)
            cov_xy.append(block[:, 0:2, 0:2].copy())
            variances.append(np.diagonal(block, axis1=1, axis2=2).copy())
            if full_covariance:
                covs.append(block)
            pending.clear()

    aiding: Iterator[DepthSample | PositionFix] = heapq.merge(
        sorted(depth, key=lambda x: x.t), sorted(fixes, key=lambda x: x.t), key=lambda x: x.t)
    for o in iter_filter(ins, dvl, config, aiding, nav=nav):
        vn, vb = o.velocity_ned, o.velocity_body
        rows.append(
            (o.t, o.x, o.y, o.z, o.roll, o.pitch, o.heading, vn[0], vn[1], vn[2], vb[0], vb[1],
             vb[2], o.bottom_lock, o.coasting)
        )  # fmt: skip
        pending.append(o.covariance)
        if len(pending) >= 4096:
            reduce()
        m = o.increment
        if m is None:
            inc.append(nan4)
            inc_cov.append(nan3)
        else:
            inc.append((m.dx, m.dy, m.dheading, m.dt))
            inc_cov.append(m.covariance)
    reduce()
    a = np.array(rows, dtype=float).reshape(-1, 15)
    return OdometryArrays(
        t=a[:, 0],
        x=a[:, 1],
        y=a[:, 2],
        z=a[:, 3],
        roll=a[:, 4],
        pitch=a[:, 5],
        heading=a[:, 6],
        velocity_ned=a[:, 7:10],
        velocity_body=a[:, 10:13],
        cov_xy=np.concatenate(cov_xy) if cov_xy else np.zeros((0, 2, 2)),
        variances=np.concatenate(variances) if variances else np.zeros((0, 8)),
        bottom_lock=a[:, 13].astype(bool),
        coasting=a[:, 14].astype(bool),
        increment=np.array(inc, dtype=float).reshape(-1, 4),
        increment_cov=np.array(inc_cov).reshape(-1, 3, 3),
        covariance=(np.concatenate(covs) if covs else np.zeros((0, 8, 8)))
        if full_covariance
        else None,
        stats=nav.stats,
    )
