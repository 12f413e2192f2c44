"""GeoSwath Plus swath processing: raw interferometric samples to georeferenced soundings, then
to a swath of ``n_bins`` points, the XYZ 88 message the bathymetric stage already consumes.

Per ping of one side (:class:`~auvgw.drivers.geoswath.GeoSwathPing`, wire values):

1. **range and angle**: two-way time ``t = time / frequency`` (s; the RAA ``time`` counts
   wavelengths of the sonar frequency, which the broadcast ping does not carry: configured),
   slant range ``r = c t / 2`` with ``c`` the ping's MINISVS sound speed (or the configured one),
   return angle ``a = asin(sine / 32767)`` from the body vertical, positive outward on that side
   (``side`` 0 port, 1 starboard);
2. **filters** (per sample): amplitude at least ``min_amplitude``, angle between
   ``nadir_gap_deg`` and ``max_angle_deg``, range between ``min_range_m`` and ``max_range_m``;
3. **geometry**: the sounding relative to the vehicle's reference point, in the heading-aligned
   level frame (x forward = along, y starboard = across, z down = depth): ``p = R (lever + r
   b)`` with ``b = (0, +-sin a, cos a)`` (body FRD) and ``R = Rz(0) Ry(pitch) Rx(roll)`` from the
   ping's MRU record (deg); the lever arm is the transducer's position in the body frame (m);
4. **across-track median**: the ping's soundings sorted by across distance; a sounding whose
   depth is more than ``max(median_tol_m, median_tol_frac * depth)`` from the running median
   of ``across_window`` neighbours is dropped (water-column, surface and nadir-gap returns).

Pings are grouped into swaths of ``1 / swath_rate_hz`` s (both sides; the paper used 1 Hz):
each ping's soundings are moved to the swath's reference ping by their NAV positions (x east,
y north, m), and binned across track into ``n_bins`` equal bins spanning ``+-swath_factor / 2``
times the altitude (the ECHO ``depth1``, else the median depth of the soundings); a bin takes
the median across, along and depth of its soundings (at least ``min_per_bin``). **Along-track
median**: each bin's depth is the median of the same bin over ``along_window`` consecutive
swaths (the middle one is emitted, so a swath comes out ``along_window // 2`` swaths late).

The output is an XYZ 88 message (:func:`auvgw.drivers.kongsberg.make_xyz88`): per bin ``depth``
below the vehicle's reference point (m, + down; NaN: empty bin), ``across`` (+ starboard),
``along`` (+ forward), ``transducer_depth`` the reference point's depth (NAV ``z`` is -depth),
``heading`` (GYRO, rad), the sound speed, the swath's ping time: depth re the water level is
``depth + transducer_depth``, as for the Kongsberg multibeam.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter

from auvgw.drivers import kongsberg
from auvgw.drivers.geoswath import GeoSwathPing
from auvgw.ground.geometry import body_to_ned_matrix

__all__ = [
    "SINE_SCALE",
    "PingSoundings",
    "SwathProcessing",
    "SwathProcessor",
    "bin_swath",
    "ping_samples",
    "ping_soundings",
]

#: the RAA ``sine`` field's scale (sine x 32767)
SINE_SCALE = 32767.0


@dataclass(frozen=True)
class SwathProcessing:
    """Settings of the swath processing (see the module docstring; SI units, degrees where
    named ``_deg``). ``sound_speed``: None uses each ping's MINISVS record (1500 m/s when it has
    none). ``lever_arm_m``: the transducer in the body frame (x forward, y starboard, z down)."""

    frequency_hz: float = 250_000.0
    sound_speed: float | None = None
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    min_amplitude: float = 400.0
    nadir_gap_deg: float = 5.0
    max_angle_deg: float = 85.0
    min_range_m: float = 0.5
    max_range_m: float = 400.0
    across_window: int = 15
    median_tol_m: float = 0.3
    median_tol_frac: float = 0.02
    swath_rate_hz: float = 1.0
    n_bins: int = 141
    swath_factor: float = 10.0
    min_per_bin: int = 2
    along_window: int = 3

    def __post_init__(self) -> None:
        if self.n_bins < 1 or self.along_window < 1 or self.across_window < 1:
            raise ValueError("n_bins, along_window and across_window must be at least 1")
        if self.frequency_hz <= 0 or self.swath_rate_hz <= 0 or self.swath_factor <= 0:
            raise ValueError("frequency_hz, swath_rate_hz and swath_factor must be positive")


@dataclass(frozen=True)
class PingSoundings:
    """The soundings of one ping kept by the filters: ``across``, ``along``, ``depth`` (m, re
    the vehicle's reference point, heading-aligned level frame), ``amplitude``, and the ping's
    ``time`` (s, device clock), ``side``, ``heading`` (rad), NAV ``east``/``north`` (m),
    reference-point ``depth_ref`` (m), ``altitude`` (ECHO depth1, m; NaN without), ``sound_speed``
    and the count of samples each filter dropped (``dropped``)."""

    across: np.ndarray
    along: np.ndarray
    depth: np.ndarray
    amplitude: np.ndarray
    time: float
    side: int
    heading: float
    east: float
    north: float
    depth_ref: float
    altitude: float
    sound_speed: float
    dropped: Mapping[str, int] = field(default_factory=dict)


def _first(ping: GeoSwathPing, array: str, name: str, default: float) -> float:
    cols = ping.arrays.get(array)
    if not cols or name not in cols or len(cols[name]) == 0:
        return default
    return float(cols[name][0])


def ping_samples(
    ping: GeoSwathPing, cfg: SwathProcessing
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Step 1 of the module docstring: each RAA sample's return angle ``a`` (rad from the body
    vertical, positive outward on the ping's side), slant range ``r`` (m) and amplitude (wire
    counts), and the sound speed used (m/s)."""
    raa = ping.arrays["raa"]
    c = cfg.sound_speed or _first(ping, "minisvs", "velocity", 1500.0)
    r = c * (np.asarray(raa["time"], float) / cfg.frequency_hz) / 2.0
    sine = np.asarray(raa["sine"], float) / SINE_SCALE
    a = np.arcsin(np.clip(sine, -1.0, 1.0))
    return a, r, np.asarray(raa["amplitude"], float), c


def ping_soundings(ping: GeoSwathPing, cfg: SwathProcessing) -> PingSoundings:
    """Steps 1-4 of the module docstring for one ping (vectorised over its samples)."""
    a, r, amp, c = ping_samples(ping, cfg)
    ok_amp = amp >= cfg.min_amplitude
    ok_ang = (a >= math.radians(cfg.nadir_gap_deg)) & (a <= math.radians(cfg.max_angle_deg))
    ok_rng = (r >= cfg.min_range_m) & (r <= cfg.max_range_m)
    keep = ok_amp & ok_ang & ok_rng
    dropped = {
        "amplitude": int((~ok_amp).sum()),
        "angle": int((ok_amp & ~ok_ang).sum()),
        "range": int((ok_amp & ok_ang & ~ok_rng).sum()),
    }
    side = int(ping.header["side"])
    sgn = 1.0 if side == 1 else -1.0
    roll = math.radians(_first(ping, "mru", "roll", 0.0))
    pitch = math.radians(_first(ping, "mru", "pitch", 0.0))
    rot = body_to_ned_matrix(0.0, pitch, roll)
    ak, rk = a[keep], r[keep]
    body = np.stack([np.zeros_like(ak), sgn * np.sin(ak), np.cos(ak)]) * rk
    p = rot @ (body + np.asarray(cfg.lever_arm_m, float)[:, None])
    along, across, depth = p[0], p[1], p[2]
    order = np.argsort(across, kind="stable")
    along, across, depth, ampk = along[order], across[order], depth[order], amp[keep][order]
    if len(depth) >= 3 and cfg.across_window > 1:  # step 4: the across-track running median
        # (mirror: an end sounding counts once in its own window, never outvotes the rest)
        med = median_filter(depth, size=cfg.across_window, mode="mirror")
        near = np.abs(depth - med) <= np.maximum(cfg.median_tol_m, cfg.median_tol_frac * med)
        dropped["median"] = int((~near).sum())
        along, across, depth, ampk = along[near], across[near], depth[near], ampk[near]
    return PingSoundings(
        across=across,
        along=along,
        depth=depth,
        amplitude=ampk,
        time=float(ping.header["ping_time"]),
        side=side,
        heading=math.radians(_first(ping, "gyro", "heading", 0.0)),
        east=_first(ping, "nav", "x", math.nan),
        north=_first(ping, "nav", "y", math.nan),
        depth_ref=-_first(ping, "nav", "z", 0.0),
        altitude=_first(ping, "echo", "depth1", math.nan),
        sound_speed=c,
        dropped=dropped,
    )


def bin_swath(
    pings: Sequence[PingSoundings], cfg: SwathProcessing
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pings of one swath moved to the first ping's position and heading (by their NAV
    positions) and binned across track: per bin ``(across, along, depth, count)`` (m; NaN where
    fewer than ``min_per_bin`` soundings)."""
    ref = pings[0]
    ch, sh = math.cos(ref.heading), math.sin(ref.heading)
    xs, ys, zs = [], [], []
    for p in pings:
        dn, de = p.north - ref.north, p.east - ref.east
        if not (math.isfinite(dn) and math.isfinite(de)):
            dn = de = 0.0
        # the ping's frame turned into the reference heading, then shifted by its position
        dh = p.heading - ref.heading
        cd, sd = math.cos(dh), math.sin(dh)
        xs.append(dn * ch + de * sh + p.along * cd - p.across * sd)
        ys.append(-dn * sh + de * ch + p.along * sd + p.across * cd)
        zs.append(p.depth + (p.depth_ref - ref.depth_ref))
    along, across, depth = np.concatenate(xs), np.concatenate(ys), np.concatenate(zs)
    n = cfg.n_bins
    nan = np.full(n, math.nan)
    if not len(depth):
        return nan, nan.copy(), nan.copy(), np.zeros(n, np.int64)
    alts = np.array([p.altitude for p in pings])
    alts = alts[np.isfinite(alts)]
    alt = float(np.median(alts)) if len(alts) else math.nan
    if not math.isfinite(alt) or alt <= 0:
        alt = float(np.median(depth))
    half = cfg.swath_factor / 2.0 * alt
    k = np.floor((across + half) / (2.0 * half) * n).astype(np.int64)
    inside = (k >= 0) & (k < n)
    k, along, across, depth = k[inside], along[inside], across[inside], depth[inside]
    order = np.lexsort((depth, k))
    k, along, across, depth = k[order], along[order], across[order], depth[order]
    count = np.bincount(k, minlength=n)
    out_d, out_x, out_y = nan.copy(), nan.copy(), nan.copy()
    starts = np.concatenate([[0], np.cumsum(count)[:-1]])
    full = np.flatnonzero(count >= max(cfg.min_per_bin, 1))
    lo, c = starts[full], count[full]
    mid_lo, mid_hi = lo + (c - 1) // 2, lo + c // 2
    out_d[full] = 0.5 * (depth[mid_lo] + depth[mid_hi])  # sorted by depth within each bin
    for arr, out in ((across, out_y), (along, out_x)):
        out[full] = [float(np.median(arr[a : a + m])) for a, m in zip(lo, c, strict=True)]
    return out_y, out_x, out_d, count


_Binned = tuple[PingSoundings, np.ndarray, np.ndarray, np.ndarray]


class SwathProcessor:
    """Pings in (in time order), XYZ 88 swaths out (see the module docstring): :meth:`add`
    returns the swaths a ping completes, :meth:`flush` the rest at the end of a stream."""

    def __init__(self, cfg: SwathProcessing | None = None) -> None:
        self.cfg = cfg or SwathProcessing()
        self._pings: list[PingSoundings] = []
        self._binned: list[_Binned] = []  # binned swaths from number _base on
        self._base = 0
        self._next = 0  # number of the next swath to emit
        self.swaths = 0
        self.pings = 0
        self.dropped: dict[str, int] = {}

    def add(self, ping: GeoSwathPing) -> list[kongsberg.XYZ88]:
        """One ping; the swaths it completes (usually none or one)."""
        ps = ping_soundings(ping, self.cfg)
        self.pings += 1
        for k, v in ps.dropped.items():
            self.dropped[k] = self.dropped.get(k, 0) + v
        out: list[kongsberg.XYZ88] = []
        if self._pings and ps.time - self._pings[0].time >= 1.0 / self.cfg.swath_rate_hz - 1e-6:
            out += self._close()
        self._pings.append(ps)
        return out

    def flush(self) -> list[kongsberg.XYZ88]:
        """The swaths still held (end of a stream): the last group, then those waiting for
        the along-track window (their median over the swaths there are)."""
        out = self._close() if self._pings else []
        while self._next < self._base + len(self._binned):
            out.append(self._emit(self._next))
            self._next += 1
        return out

    def _close(self) -> list[kongsberg.XYZ88]:
        across, along, depth, _ = bin_swath(self._pings, self.cfg)
        self._binned.append((self._pings[0], across, along, depth))
        self._pings = []
        h, out = self.cfg.along_window // 2, []
        while self._next + h < self._base + len(self._binned):
            out.append(self._emit(self._next))
            self._next += 1
        drop = max(self._next - h - self._base, 0)
        del self._binned[:drop]
        self._base += drop
        return out

    def _emit(self, i: int) -> kongsberg.XYZ88:
        """Swath ``i`` with each bin's depth the median of that bin over the along-track
        window around it (the swaths held: fewer at the ends of a stream)."""
        h = self.cfg.along_window // 2
        ref, across, along, own = self._binned[i - self._base]
        window = self._binned[max(i - h - self._base, 0) : i + h + 1 - self._base]
        stack = np.stack([d + (r.depth_ref - ref.depth_ref) for r, _, _, d in window])
        filled = ~np.isnan(stack)
        safe = np.where(filled, stack, np.inf)  # NaN last when sorted
        srt = np.sort(safe, axis=0)
        m = filled.sum(axis=0)
        cols = np.arange(stack.shape[1])
        lo = srt[np.maximum((m - 1) // 2, 0), cols]
        hi = srt[np.maximum(m // 2, 0), cols]
        depth = np.where((m > 0) & ~np.isnan(own), 0.5 * (lo + hi), math.nan)
        self.swaths += 1
        return kongsberg.make_xyz88(
            time=ref.time,
            depth=depth,
            across=np.where(np.isnan(depth), 0.0, across),
            along=np.where(np.isnan(depth), 0.0, along),
            heading=ref.heading % (2 * math.pi),
            sound_speed=ref.sound_speed,
            transducer_depth=ref.depth_ref,
            ping_counter=(self.swaths - 1) & 0xFFFF,
        )
