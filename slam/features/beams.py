"""MSIS beam processing: Cui et al. 2020 ("VRFastSLAM"), section 2.2.1, and motion compensation.

A mechanically scanning imaging sonar (MSIS) sends one ping at a time, each at one transducer
bearing, and returns a row of echo intensities (the bins) along that bearing. A full 360 deg
scan takes seconds, so the vehicle moves while it scans: every return is placed here with the
sonar pose *at the moment of its own ping*.

Input is plain arrays (:class:`ScanLines`: one row per ping with its time, bearing, intensities
and bin length), so the same code serves the online stage (pings as they arrive) and offline
runs (a recording, a simulation); :func:`scan_lines_from_head_data` adapts SeaNet ``HeadData``
messages.

Section 2.2.1 of the paper, per beam:

1. bins weaker than an intensity threshold are removed (background noise, false data);
2. the local maxima of the remaining bins are picked;
3. "minimum distance" criterion: two maxima closer in range than a minimum distance belong to
   one object; the weaker one is discarded (greedy, strongest first).

Frames and units: poses are ``(x, y, heading)`` in a horizontal NED frame (x north, y east, m;
heading rad from north towards east), the world frame of ``config/scenario.py`` or the fusion
odometry frame. The head's bearing is the transducer angle, clockwise from the head's forward
mark (SeaNet), rad. With a :class:`SonarMount` the beam points along
``heading + mount.yaw_rad + bearing`` (``- bearing`` for an inverted head) from the transducer
at ``mount.x_m`` forward and ``mount.y_m`` starboard of the vehicle reference point. Range of
bin ``k``: ``(k + bin_offset) * bin_length`` (``bin_offset`` 0.5: bin centres, as the emulated
head of ``auvgw.sim_devices.msis``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from auvgw.ground.geometry import wrap_angles as wrap_angle  # arrays in, arrays out

__all__ = [
    "BeamSettings",
    "HeadDataLike",
    "PlacedReturns",
    "PoseSource",
    "PoseTrack",
    "Returns",
    "ScanLines",
    "SonarMount",
    "detect_returns",
    "place_returns",
    "place_scan",
    "poses_at",
    "preprocess_beam",
    "scan_lines_from_head_data",
    "wrap_angle",
]

FArray = np.ndarray
#: poses of the vehicle at given times: ``f(t (n,)) -> (n, 3)`` of (x, y, heading)
PoseSource = Callable[[FArray], FArray]


# -- scan lines ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScanLines:
    """A run of MSIS pings as plain arrays, one row per ping.

    ``t`` (N,) ping times, s (any clock the poses share); ``bearing`` (N,) transducer angle,
    rad, clockwise from the head's forward mark; ``intensity`` (N, B) echo level per bin (any
    monotonic unit: raw bins, dB, 0..1; NaN pads pings with fewer bins); ``bin_length`` (N,)
    m per bin; ``bin_offset`` bins from the transducer to the first bin's range (0.5: centres).
    """

    t: FArray
    bearing: FArray
    intensity: FArray
    bin_length: FArray
    bin_offset: float = 0.5

    def __post_init__(self) -> None:
        t = np.atleast_1d(np.asarray(self.t, float))
        n = t.size
        inten = np.asarray(self.intensity, float)
        if inten.ndim == 1:
            inten = inten.reshape(1, -1) if n == 1 else inten.reshape(n, -1)
        bearing = np.broadcast_to(np.asarray(self.bearing, float), (n,)).copy()
        blen = np.broadcast_to(np.asarray(self.bin_length, float), (n,)).copy()
        if inten.shape[0] != n:
            raise ValueError(f"ScanLines: {n} times but {inten.shape[0]} intensity rows")
        if np.any(~(blen > 0)):
            raise ValueError("ScanLines.bin_length: must be > 0 m for every ping")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "bearing", bearing)
        object.__setattr__(self, "intensity", inten)
        object.__setattr__(self, "bin_length", blen)

    def __len__(self) -> int:
        return self.t.size

    @classmethod
    def from_pings(
        cls,
        t: Sequence[float] | FArray,
        bearing: Sequence[float] | FArray,
        bins: Sequence[Sequence[float] | FArray],
        bin_length: float | Sequence[float] | FArray,
        bin_offset: float = 0.5,
    ) -> ScanLines:
        """Pings whose bin rows may differ in length (padded with NaN)."""
        rows = [np.asarray(b, float).ravel() for b in bins]
        width = max((r.size for r in rows), default=0)
        inten = np.full((len(rows), width), np.nan)
        for i, r in enumerate(rows):
            inten[i, : r.size] = r
        blen = np.asarray(bin_length, float)
        return cls(np.asarray(t, float), np.asarray(bearing, float), inten, blen, bin_offset)

    def ranges(self) -> FArray:
        """(N, B) range of every bin, m."""
        k = np.arange(self.intensity.shape[1]) + self.bin_offset
        return self.bin_length[:, None] * k[None, :]

    def select(self, idx: FArray | slice) -> ScanLines:
        """The pings ``idx`` (an index array, a mask or a slice)."""
        return ScanLines(
            self.t[idx], self.bearing[idx], self.intensity[idx], self.bin_length[idx],
            self.bin_offset,
        )  # fmt: skip


class HeadDataLike(Protocol):
    """What :func:`scan_lines_from_head_data` reads of a SeaNet mtHeadData
    (``auvgw.drivers.seanet.HeadData``)."""

    bins: FArray
    bearing: float
    adc8on: bool
    ad_low: float
    ad_span: float

    def bin_length(self, sound_speed: float) -> float: ...


def scan_lines_from_head_data(
    msgs: Sequence[HeadDataLike],
    times: Sequence[float] | FArray,
    sound_speed: float = 1500.0,
    *,
    to_db: bool = True,
) -> ScanLines:
    """:class:`ScanLines` from decoded SeaNet mtHeadData messages and their ping ``times`` (s).

    ``to_db``: convert bins to the receiver level in dB so that 8- and 4-bit data share one
    threshold (8-bit: ``bins * 80 / 255``; 4-bit: ``ADLow + bins / 15 * ADSpan``); otherwise
    the raw bin values. Bin ranges are bin centres (``bin_offset`` 0.5) at ``sound_speed``.
    """
    if len(msgs) != len(times):
        raise ValueError(f"{len(msgs)} HeadData messages but {len(times)} times")
    rows = []
    for m in msgs:
        b = np.asarray(m.bins, float)
        if to_db:
            b = b * (80.0 / 255.0) if m.adc8on else m.ad_low + b / 15.0 * m.ad_span
        rows.append(b)
    blen = [m.bin_length(sound_speed) for m in msgs]
    return ScanLines.from_pings(times, [m.bearing for m in msgs], rows, blen, 0.5)


# -- section 2.2.1: threshold, local maxima, minimum distance ---------------------------------


@dataclass(frozen=True)
class BeamSettings:
    """Beam preprocessing (Cui 2020 sec. 2.2.1).

    ``threshold``: bins below it are removed (step 1), same unit as the intensities;
    ``min_distance_m``: maxima closer in range than this are one object, the weaker is
    discarded (step 3); ``min_range_m``: bins nearer than this are ignored (transducer
    ring-down, the vehicle's own hull); ``max_range_m``: bins beyond are ignored;
    ``max_returns``: keep at most this many returns per ping, strongest first (None: all).
    """

    threshold: float
    min_distance_m: float = 1.0
    min_range_m: float = 1.0
    max_range_m: float = math.inf
    max_returns: int | None = None

    def __post_init__(self) -> None:
        if self.min_distance_m < 0 or self.min_range_m < 0:
            raise ValueError("BeamSettings: distances must be >= 0")
        if self.max_returns is not None and self.max_returns < 1:
            raise ValueError("BeamSettings.max_returns: must be >= 1 or None")


@dataclass(frozen=True)
class Returns:
    """The returns kept by :func:`detect_returns`, one entry per return (R,), ordered by ping
    then range: ``ping`` index into the scan lines, ``t`` (s), head ``bearing`` (rad),
    ``range_m``, ``intensity`` (input unit), ``bin`` index and ``bin_length`` (m)."""

    ping: FArray
    t: FArray
    bearing: FArray
    range_m: FArray
    intensity: FArray
    bin: FArray
    bin_length: FArray

    def __len__(self) -> int:
        return self.ping.size

    def select(self, idx: FArray | slice) -> Returns:
        """The returns ``idx`` (an index array, a mask or a slice)."""
        return Returns(
            self.ping[idx], self.t[idx], self.bearing[idx], self.range_m[idx],
            self.intensity[idx], self.bin[idx], self.bin_length[idx],
        )  # fmt: skip


def _local_maxima(x: FArray) -> FArray:
    """Mask of local maxima along the last axis (step 2): greater than the bin before and not
    less than the bin after; a plateau keeps its first bin. NaN counts as -inf."""
    v = np.where(np.isnan(x), -np.inf, x)
    lo = np.full((*v.shape[:-1], 1), -np.inf)
    left = np.concatenate([lo, v[..., :-1]], axis=-1)
    right = np.concatenate([v[..., 1:], lo], axis=-1)
    return (v > left) & (v >= right) & np.isfinite(v)


def _min_distance(ping: FArray, rng: FArray, key: FArray, min_distance: float) -> FArray:
    """Step 3, the minimum-distance rule, for candidates sorted by (ping, range): mask of the
    survivors of greedy suppression (strongest ``key`` first; a weaker candidate closer than
    ``min_distance`` in range to a kept one in the same ping is discarded).

    Parallel form of the greedy rule (identical result): each round keeps every alive candidate
    that is the strongest alive one within the distance, then drops the alive candidates within
    the distance of a newly kept one.
    """
    n = ping.size
    kept = np.zeros(n, bool)
    if n == 0 or min_distance <= 0:
        return np.ones(n, bool)
    min_distance *= 1.0 - 1e-9  # a distance of exactly min_distance (in bins) is not closer
    # how far (in candidate positions) a neighbour within the distance can be
    close = (ping[1:] == ping[:-1]) & (np.diff(rng) < min_distance)
    # longest chain of consecutive close candidates: no pair further apart in the order can be
    # within the distance (ranges are sorted within a ping)
    edges = np.flatnonzero(np.diff(np.r_[0, close.astype(np.int8), 0]))
    span = int(np.max(edges[1::2] - edges[::2])) if edges.size else 0
    shifts = range(1, span + 1)

    def near(s: int) -> FArray:
        """(n - s,) candidate i and i + s are in one ping and within the distance."""
        return (ping[s:] == ping[:-s]) & (rng[s:] - rng[:-s] < min_distance)

    nears = [near(s) for s in shifts]
    alive = np.ones(n, bool)
    while alive.any():
        best = alive.copy()
        for s, nb in zip(shifts, nears, strict=True):
            # a stronger alive neighbour s positions after / before
            best[:-s] &= ~(nb & alive[s:] & (key[s:] > key[:-s]))
            best[s:] &= ~(nb & alive[:-s] & (key[:-s] > key[s:]))
        kept |= best
        alive &= ~best
        for s, nb in zip(shifts, nears, strict=True):
            alive[:-s] &= ~(nb & best[s:])
            alive[s:] &= ~(nb & best[:-s])
    return kept


def detect_returns(scan: ScanLines, settings: BeamSettings) -> Returns:
    """Section 2.2.1 over every ping of ``scan`` (vectorised): threshold, local maxima,
    minimum distance, then at most ``max_returns`` per ping (strongest)."""
    inten = scan.intensity
    ranges = scan.ranges()
    ok = (inten >= settings.threshold) & (ranges >= settings.min_range_m)
    ok &= ranges <= settings.max_range_m
    cand = ok & _local_maxima(inten)  # steps 1 and 2
    p, b = np.nonzero(cand)  # row-major: sorted by ping, then range
    val = inten[p, b]
    rng = ranges[p, b]
    # strength with a tie-break that prefers the nearer bin (a unique order)
    order = np.lexsort((-b, val))
    key = np.empty(p.size)
    key[order] = np.arange(p.size)
    keep = _min_distance(p, rng, key, settings.min_distance_m)  # step 3
    if settings.max_returns is not None and keep.any():
        idx = np.flatnonzero(keep)
        o = np.lexsort((-key[idx], p[idx]))  # per ping, strongest first
        ps = p[idx][o]
        first = np.r_[0, np.flatnonzero(np.diff(ps)) + 1]
        rank = np.arange(ps.size) - np.repeat(first, np.diff(np.r_[first, ps.size]))
        keep[idx[o[rank >= settings.max_returns]]] = False
    p, b = p[keep], b[keep]
    return Returns(
        ping=p,
        t=scan.t[p],
        bearing=scan.bearing[p],
        range_m=ranges[p, b],
        intensity=inten[p, b],
        bin=b,
        bin_length=scan.bin_length[p],
    )


def preprocess_beam(
    intensity: Sequence[float] | FArray,
    bin_length: float,
    settings: BeamSettings,
    bin_offset: float = 0.5,
) -> tuple[FArray, FArray, FArray]:
    """Section 2.2.1 on one beam: ``(bin indices, ranges m, intensities)`` of its returns."""
    scan = ScanLines(np.zeros(1), np.zeros(1), np.asarray(intensity, float)[None, :],
                     np.array([bin_length]), bin_offset)  # fmt: skip
    r = detect_returns(scan, settings)
    return r.bin, r.range_m, r.intensity


# -- poses and motion compensation ------------------------------------------------------------


@dataclass(frozen=True)
class SonarMount:
    """Where the head sits on the vehicle: transducer ``x_m`` forward and ``y_m`` starboard of
    the vehicle reference point (m), forward mark turned ``yaw_rad`` clockwise from the vehicle's
    bow, ``inverted`` for a head mounted upside down (bearings run anticlockwise)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    inverted: bool = False

    def beam_angle(self, bearing: FArray | float) -> FArray:
        """Beam direction in the vehicle frame (rad from the bow, clockwise) for head bearings."""
        sense = -1.0 if self.inverted else 1.0
        return self.yaw_rad + sense * np.asarray(bearing, float)

    def transducer(self, poses: FArray) -> tuple[FArray, FArray]:
        """Transducer position (x, y) in the pose frame for vehicle ``poses`` (..., 3)."""
        p = np.asarray(poses, float)
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        return (
            p[..., 0] + self.x_m * c - self.y_m * s,
            p[..., 1] + self.x_m * s + self.y_m * c,
        )


@dataclass(frozen=True)
class PoseTrack:
    """Vehicle poses at times, interpolated (linear; heading along the shortest way): a
    :data:`PoseSource` from the fusion odometry or the simulation truth.

    ``t`` (n,) s, increasing; ``poses`` (n, 3) ``(x, y, heading)``. Outside ``t`` the first /
    last pose is held.
    """

    t: FArray
    poses: FArray
    _heading: FArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, float).ravel()
        p = np.asarray(self.poses, float).reshape(-1, 3)
        if t.size != len(p) or t.size == 0:
            raise ValueError(f"PoseTrack: {t.size} times for {len(p)} poses")
        if np.any(np.diff(t) <= 0):
            raise ValueError("PoseTrack.t: times must increase strictly")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "poses", p)
        object.__setattr__(self, "_heading", np.unwrap(p[:, 2]))

    def __call__(self, t: FArray | float) -> FArray:
        """Poses (n, 3) at times ``t`` (s)."""
        tq = np.atleast_1d(np.asarray(t, float))
        out = np.empty((tq.size, 3))
        out[:, 0] = np.interp(tq, self.t, self.poses[:, 0])
        out[:, 1] = np.interp(tq, self.t, self.poses[:, 1])
        out[:, 2] = wrap_angle(np.interp(tq, self.t, self._heading))
        return out


def poses_at(poses: PoseSource | FArray, t: FArray, ping: FArray | None = None) -> FArray:
    """(n, 3) poses for times ``t``: from a :data:`PoseSource` called with ``t``; from an
    (N_pings, 3) array of per-ping poses indexed by ``ping``; or one (3,) pose for all (no
    motion compensation)."""
    t = np.atleast_1d(np.asarray(t, float))
    if callable(poses):
        out = np.asarray(poses(t), float).reshape(-1, 3)
        if len(out) != t.size:
            raise ValueError(f"pose source returned {len(out)} poses for {t.size} times")
        return out
    p = np.asarray(poses, float)
    if p.shape == (3,):
        return np.broadcast_to(p, (t.size, 3)).copy()
    p = p.reshape(-1, 3)
    if ping is None:
        if len(p) != t.size:
            raise ValueError(f"{len(p)} poses for {t.size} times and no ping index")
        return p
    return p[np.asarray(ping, int)]


@dataclass(frozen=True)
class PlacedReturns:
    """Returns placed in the pose frame with the sonar pose at their own ping (R,) each:
    ``returns`` (what was detected), vehicle ``pose`` (R, 3) at the ping, transducer position
    ``sonar_x, sonar_y`` (m), beam direction ``angle`` (rad from north, clockwise) and the
    return's position ``x, y`` (m) on the beam axis."""

    returns: Returns
    pose: FArray
    sonar_x: FArray
    sonar_y: FArray
    angle: FArray
    x: FArray
    y: FArray

    def __len__(self) -> int:
        return self.x.size

    @property
    def xy(self) -> FArray:
        """(R, 2) return positions, m."""
        return np.stack([self.x, self.y], axis=1)


def place_returns(
    returns: Returns, poses: PoseSource | FArray, mount: SonarMount | None = None
) -> PlacedReturns:
    """Place each return with the vehicle pose at its own ping time (motion compensation):
    ``poses`` is a :data:`PoseSource` (called with the ping times), per-ping poses (N_pings, 3)
    indexed by ``returns.ping``, or a single pose (3,) for every return (no compensation)."""
    mount = mount if mount is not None else SonarMount()
    pose = poses_at(poses, returns.t, returns.ping)
    sx, sy = mount.transducer(pose)
    angle = wrap_angle(pose[:, 2] + mount.beam_angle(returns.bearing))
    r = returns.range_m
    return PlacedReturns(
        returns=returns,
        pose=pose,
        sonar_x=sx,
        sonar_y=sy,
        angle=angle,
        x=sx + r * np.cos(angle),
        y=sy + r * np.sin(angle),
    )


def place_scan(
    scan: ScanLines,
    settings: BeamSettings,
    poses: PoseSource | FArray,
    mount: SonarMount | None = None,
) -> PlacedReturns:
    """Sec. 2.2.1 on every ping of ``scan``, then each return placed with the pose at its own
    ping (:func:`detect_returns` then :func:`place_returns`)."""
    return place_returns(detect_returns(scan, settings), poses, mount)
