"""Rerun logging of a run: one method per thing to show, plain arrays in, never blocking.

:class:`RerunLogger` is Rerun only (no Zenoh): every public method takes plain values or numpy
arrays and a device time ``t`` (s) for the ``sensor_time`` timeline, puts one item on a bounded
queue and returns at once (``True``), or drops the item and counts it when the queue is full
(``False``). One logging thread owns the Rerun recording: it sets its own time (Rerun time is per
thread), accumulates state (trajectory segments, the sonar fan, the bathymetric grid) and sends
high-rate data in batches with ``send_columns`` every ``flush_period_s``.

Frames and units of the inputs: positions in metres in the map frame of
:attr:`VizOptions.map_frame` (``ned``: x north, y east, z down; ``xy``: x right, y up, as in Tim
Bailey's simulator), headings in rad (``ned``: from north towards east; ``xy``: from x towards y),
attitude in rad (roll, pitch, heading; NED body axes x forward, y starboard, z down), velocities
in m/s, magnetic flux density in nT, sonar bearings in rad clockwise from the head's forward mark.

What is logged where (entity paths in :mod:`auvgw.viz.entities`, shown in ``docs/viz.md``): the
2-D map draws east to the right and north up (Rerun's 2-D y axis points down, so the map stores
``(east, -north)``; ``xy`` stores ``(x, -y)``); angles in time series are in degrees.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike

from auvgw.ground.closing import Closing
from auvgw.ground.geometry import TWO_PI, quaternion_zyx, wrap_angle
from auvgw.ground.worker import Worker
from auvgw.viz import entities as ent
from auvgw.viz.blueprint import DEFAULT_TRACKS, default_blueprint
from auvgw.viz.entities import APPLICATION_ID, TIMELINE
from auvgw.viz.options import VizOptions

__all__ = [
    "TIMELINE",
    "LoggerStats",
    "RerunLogger",
    "VizOptions",
    "amplitude_colours",
    "depth_colours",
    "ellipse_strips",
]

log = logging.getLogger(__name__)

#: a queued logger call: (kind, data time s, the view's arguments)
_Item = tuple[str, float, tuple[Any, ...]]
#: a row of a batched stream: scalars, a transform or vector, (points, colours)
_Row = Sequence[float] | np.ndarray | tuple[np.ndarray, np.ndarray]


#: turbo-like colour scale (low values dark blue, high values dark red), 11 control points
_TURBO = np.array(
    [
        (48, 18, 59), (68, 81, 191), (70, 134, 251), (41, 187, 236), (26, 228, 182),
        (100, 253, 106), (164, 252, 60), (225, 221, 55), (254, 165, 49), (239, 90, 17),
        (122, 4, 3),
    ],
    dtype=np.float64,
)  # fmt: skip
_LUT = np.stack(
    [
        np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, len(_TURBO)), _TURBO[:, c])
        for c in range(3)
    ],
    axis=1,
).astype(np.uint8)

#: fixed colours of the well-known trajectories; others take the palette in order of appearance
_TRACK_COLOURS: dict[str, tuple[int, int, int]] = {
    "truth": (240, 240, 240),
    "dead_reckoning": (255, 160, 40),
    "acoustic": (230, 0, 230),  # the acoustic beacon's fixes (map/acoustic/ranges)
}
#: the true features (walls, piles, beacons): apart from every track
_TRUE_FEATURES = (90, 190, 110)
#: line width (px) and draw order of the well-known tracks: the truth widest and underneath,
#: so three tracks on top of each other all show; others (SLAM) thinnest, on top
_TRACK_STYLE: dict[str, tuple[float, float]] = {"truth": (4.0, 28.0), "dead_reckoning": (2.5, 30.0)}
_TRACK_STYLE_OTHER = (1.5, 32.0)
#: the health views' colours, one per device in order of appearance
_HEALTH_PALETTE: tuple[tuple[int, int, int], ...] = (
    (80, 160, 255), (255, 160, 40), (90, 220, 110), (230, 80, 220), (255, 90, 90),
    (120, 230, 230), (220, 220, 80), (170, 130, 255), (200, 200, 200), (255, 200, 150),
)  # fmt: skip
#: spacings (m) of the map's metre grid: the first that draws at most 6 lines across the tracks
_GRID_STEPS = (5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0)
#: the sonar fan's range rings, fractions of the range scale
_RINGS = (0.25, 0.5, 0.75, 1.0)
#: which trajectory places the vehicle frame (lowest first; others rank 2)
_RANK: dict[str, int] = {"dead_reckoning": 0, "truth": 1}
_PALETTE: tuple[tuple[int, int, int], ...] = (
    (80, 160, 255), (230, 80, 220), (255, 90, 90), (120, 230, 230), (200, 200, 80),
    (160, 120, 255), (255, 255, 255),
)  # fmt: skip


@dataclass(frozen=True)
class LoggerStats:
    """Counters of a :class:`RerunLogger`: items processed by the logging thread, items dropped
    (queue full or logger closed) in total and per method, items whose logging failed."""

    processed: int
    dropped: int
    errors: int
    queued: int
    dropped_by_kind: dict[str, int] = field(default_factory=dict)
    last_error: str = ""


# -- geometry helpers (pure, also used by tests) ------------------------------------------------
#: the acoustic beacon's marker (magenta)
ACOUSTIC_COLOUR = (230, 0, 230)


def depth_colours(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """RGB (n, 3) uint8 of depths (m) on the turbo-like scale: ``lo`` dark blue, ``hi`` dark red."""
    span = hi - lo if hi > lo else 1.0
    idx = np.clip((np.asarray(depth, dtype=np.float64) - lo) / span * 255.0, 0, 255)
    return _LUT[np.nan_to_num(idx).astype(np.intp)]


def ellipse_strips(
    centres: np.ndarray, covs: np.ndarray, sigma: float = 2.0, vertices: int = 33
) -> np.ndarray:
    """Closed ellipse outlines (L, vertices, 2) of 2-D Gaussians ``centres (L, 2)``,
    ``covs (L, 2, 2)`` at ``sigma`` standard deviations (vectorised 2x2 Cholesky; negative
    variances clip to 0)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    a = np.maximum(p[:, 0, 0], 0.0)
    l11 = np.sqrt(a)
    l21 = np.divide(p[:, 1, 0], l11, out=np.zeros_like(l11), where=l11 > 0)
    l22 = np.sqrt(np.maximum(p[:, 1, 1] - l21 * l21, 0.0))
    ang = np.linspace(0.0, TWO_PI, vertices)
    ca, sa = np.cos(ang), np.sin(ang)
    x = c[:, 0:1] + sigma * l11[:, None] * ca[None, :]
    y = c[:, 1:2] + sigma * (l21[:, None] * ca[None, :] + l22[:, None] * sa[None, :])
    return np.stack([x, y], axis=-1)


def attitude_quaternion(roll: float, pitch: float, heading: float) -> tuple[float, ...]:
    """Quaternion (x, y, z, w) of body -> NED for roll, pitch, heading (rad, ZYX convention)."""
    return quaternion_zyx(roll, pitch, heading)


def _same_length(what: str, **arrays: np.ndarray | None) -> None:
    """Raise ValueError naming the arrays of ``what`` whose lengths differ."""
    lengths = {k: len(v) for k, v in arrays.items() if v is not None}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{what}: arrays of different lengths {lengths}")


def _disc_m(across: np.ndarray) -> float:
    """Radius (m) of a sounding's disc: 0.75 x the median spacing of one swath's beams (so
    neighbours overlap), at least 5 cm."""
    a = np.sort(np.asarray(across, dtype=np.float64)[np.isfinite(across)])
    gap = float(np.median(np.diff(a))) if len(a) > 2 else 0.1
    return max(0.05, 0.75 * gap)


#: the sonar fan's colour scale (inferno-like: black, purple, red, orange, pale yellow)
_FAN_SCALE = np.array(
    [(0, 0, 4), (40, 11, 84), (101, 21, 110), (159, 42, 99), (212, 72, 66), (245, 125, 21),
     (250, 193, 39), (252, 255, 164)],
    dtype=np.float64,
)  # fmt: skip


def amplitude_colours(amp: np.ndarray) -> np.ndarray:
    """RGB (n, 3) uint8 of sonar amplitudes on the fan's inferno-like scale, logarithmic from
    the 1st (black) to the 99.5th percentile (pale yellow) of ``amp``."""
    la = np.log10(np.maximum(np.asarray(amp, dtype=np.float64), 1.0))
    if not la.size:
        return np.zeros((0, 3), dtype=np.uint8)
    lo, hi = np.percentile(la, [1.0, 99.5])
    f = np.clip((la - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    x = np.linspace(0.0, 1.0, len(_FAN_SCALE))
    return np.stack([np.interp(f, x, _FAN_SCALE[:, c]) for c in range(3)], axis=1).astype(np.uint8)


def _fan_colours(lo: float, hi: float) -> rr.AnnotationContext:
    """Colours of the fan's 256 echo levels: the scale stretched from ``lo`` (and below: black)
    to ``hi`` (and above: the top colour); level 0 (no return) black."""
    f = np.clip((np.arange(256) - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    x = np.linspace(0.0, 1.0, len(_FAN_SCALE))
    rgb = np.stack([np.interp(f, x, _FAN_SCALE[:, c]) for c in range(3)], axis=1).astype(int)
    rgb[0] = 0
    return rr.AnnotationContext(
        [rr.AnnotationInfo(id=i, color=tuple(int(v) for v in c)) for i, c in enumerate(rgb)]
    )


def _fan_levels(img: np.ndarray) -> tuple[float, float]:
    """The fan's display range: from the sweep's median echo level (the speckle's: half of it
    is drawn black, the rest dark) to its strongest echo, so targets stand out bright whatever
    the head's gain."""
    echoes = img[img > 0]
    if not echoes.size:
        return 1.0, 255.0
    lo = float(np.median(echoes)) - 1.0  # the median level itself is just not black
    return lo, max(float(echoes.max()), lo + 1.0)


# -- accumulated state (owned by the logging thread) --------------------------------------------
class _Fan:
    """MSIS scan lines accumulated into a Cartesian fan image (forward up, starboard right).

    Pixels inside the disc are sorted by bearing once, so painting one scan line is a binary
    search plus a vectorised assignment of the pixels between two bearings.
    """

    def __init__(self, pixels: int) -> None:
        n = int(pixels)
        c = (n - 1) / 2.0
        rows, cols = np.mgrid[0:n, 0:n]
        dx, dy = cols - c, c - rows
        r = np.hypot(dx, dy) / (n / 2.0)
        ang = np.mod(np.arctan2(dx, dy), TWO_PI)
        flat = np.flatnonzero(r.ravel() <= 1.0)
        order = np.argsort(ang.ravel()[flat], kind="stable")
        self.size = n
        self._idx = flat[order]
        self._ang = ang.ravel()[self._idx]
        self._r = r.ravel()[self._idx]
        self.image = np.zeros((n, n), dtype=np.uint8)
        self.prev: float | None = None
        self.direction = 0
        self.swept = 0.0
        self.range_m = math.nan
        self.n_bins = 0
        self.sweeps = 0

    def new_sweep(self, bearing: float, range_m: float, n_bins: int) -> bool:
        """Whether this scan line starts a new sweep: the head reversed (sector scan), went
        round once (continuous scan) or the range / bin count changed. Updates the sweep state."""
        changed = self.prev is not None and (
            n_bins != self.n_bins or abs(range_m - self.range_m) > 1e-3 * max(1.0, range_m)
        )
        self.range_m, self.n_bins = range_m, n_bins
        if self.prev is None:
            self.prev = bearing
            return False
        d = wrap_angle(bearing - self.prev)
        direction = (1 if d > 0 else -1) if abs(d) > 1e-9 else self.direction
        reversed_ = self.direction != 0 and direction != self.direction
        full = self.swept + abs(d) >= TWO_PI - 1e-6
        self.prev = bearing
        if changed or reversed_ or full:
            self.direction, self.swept = direction, 0.0
            self.sweeps += 1
            return True
        self.direction = direction
        self.swept += abs(d)
        return False

    def clear(self) -> None:
        self.image[:] = 0

    def paint(self, bearing: float, bins: np.ndarray, half_width: float) -> None:
        """Paint one scan line (``bins`` uint8, near to far) over ``bearing +- half_width``."""
        if len(bins) == 0:
            return
        lo = (bearing - half_width) % TWO_PI
        hi = lo + 2.0 * half_width
        s = int(np.searchsorted(self._ang, lo))
        if hi <= TWO_PI:
            sel = slice(s, int(np.searchsorted(self._ang, hi)))
            idx, r = self._idx[sel], self._r[sel]
        else:
            e = int(np.searchsorted(self._ang, hi - TWO_PI))
            idx = np.concatenate([self._idx[s:], self._idx[:e]])
            r = np.concatenate([self._r[s:], self._r[:e]])
        k = np.minimum((r * len(bins)).astype(np.intp), len(bins) - 1)
        self.image.ravel()[idx] = bins[k]

    def beam(self, bearing: float) -> np.ndarray:
        """End points (2, 2) of the current bearing line, in pixels."""
        c = (self.size - 1) / 2.0
        rad = self.size / 2.0
        return np.array([[c, c], [c + rad * math.sin(bearing), c - rad * math.cos(bearing)]])


class _Grid:
    """Gridded mean depth over map coordinates (u, v), growing as soundings arrive."""

    def __init__(self, cell: float, max_cells: int) -> None:
        self.cell = float(cell)
        self.max_cells = int(max_cells)
        self.i0 = 0  # column index of the first column (u)
        self.j0 = 0  # row index of the first row (v)
        self.sums = np.zeros((0, 0))
        self.counts = np.zeros((0, 0), dtype=np.int32)
        self.touched = np.zeros((0, 0), dtype=bool)  # cells updated since take_touched()
        self.rejected = 0

    def _grow(self, imin: int, imax: int, jmin: int, jmax: int) -> None:
        rows, cols = self.sums.shape
        if rows:
            imin, jmin = min(imin, self.i0), min(jmin, self.j0)
            imax, jmax = max(imax, self.i0 + cols - 1), max(jmax, self.j0 + rows - 1)
        margin = 16
        imin, jmin, imax, jmax = imin - margin, jmin - margin, imax + margin, jmax + margin
        ncols, nrows = imax - imin + 1, jmax - jmin + 1
        if ncols * nrows > self.max_cells:
            return
        sums = np.zeros((nrows, ncols))
        counts = np.zeros((nrows, ncols), dtype=np.int32)
        touched = np.zeros((nrows, ncols), dtype=bool)
        if rows:
            r0, c0 = self.j0 - jmin, self.i0 - imin
            sums[r0 : r0 + rows, c0 : c0 + cols] = self.sums
            counts[r0 : r0 + rows, c0 : c0 + cols] = self.counts
            touched[r0 : r0 + rows, c0 : c0 + cols] = self.touched
        self.sums, self.counts, self.touched = sums, counts, touched
        self.i0, self.j0 = imin, jmin

    def add(self, u: np.ndarray, v: np.ndarray, depth: np.ndarray) -> None:
        ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(depth)
        if not ok.any():
            return
        iu = np.floor(u[ok] / self.cell).astype(np.int64)
        iv = np.floor(v[ok] / self.cell).astype(np.int64)
        z = depth[ok]
        rows, cols = self.sums.shape
        if (
            not rows
            or iu.min() < self.i0
            or iv.min() < self.j0
            or iu.max() >= self.i0 + cols
            or iv.max() >= self.j0 + rows
        ):
            self._grow(int(iu.min()), int(iu.max()), int(iv.min()), int(iv.max()))
            rows, cols = self.sums.shape
        c, r = iu - self.i0, iv - self.j0
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        self.rejected += int(np.count_nonzero(~inside))
        np.add.at(self.sums, (r[inside], c[inside]), z[inside])
        np.add.at(self.counts, (r[inside], c[inside]), 1)
        self.touched[r[inside], c[inside]] = True

    def take_touched(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres (u, v) and mean depths of the cells updated since the previous call."""
        rows, cols = np.nonzero(self.touched)
        self.touched[rows, cols] = False
        mean = self.sums[rows, cols] / self.counts[rows, cols]
        u = (self.i0 + cols + 0.5) * self.cell
        v = (self.j0 + rows + 0.5) * self.cell
        return u, v, mean

    def mean(self) -> tuple[np.ndarray, float, float]:
        """Mean depth image (rows = v, columns = u; 0 where empty) and the map coordinates of
        its first pixel's corner."""
        img = np.divide(
            self.sums, self.counts, out=np.zeros_like(self.sums), where=self.counts > 0
        ).astype(np.float32)
        return img, self.i0 * self.cell, self.j0 * self.cell


@dataclass
class _Track:
    colour: tuple[int, int, int]
    pending: list[tuple[float, float, float]] = field(default_factory=list)
    pending_t: float = 0.0
    last_sent: tuple[float, float, float] | None = None
    kept: tuple[float, float, float] | None = None
    latest: tuple[float, float, float, float, float, np.ndarray | None] | None = None
    pose_dirty: bool = False
    flushed_t: float = -math.inf


class _Stream:
    """Rows of one entity waiting for a batched ``send_columns``."""

    __slots__ = ("first_host", "kind", "rows", "times")

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.times: list[float] = []
        self.rows: list[_Row] = []
        self.first_host = 0.0  # time.monotonic() of the first pending row


# -- the logger --------------------------------------------------------------------------------
class RerunLogger(Closing, Worker[_Item]):
    """Logs a run to an ``.rrd`` file (``rrd``) and/or a running viewer (``connect``, a
    ``rerun+http://host:9876/proxy`` URL) without ever blocking the caller.

    Methods return ``True`` when the item was queued and ``False`` when it was dropped (queue
    full, or logger closed); :meth:`stats` counts both. :meth:`close` drains the queue, sends the
    buffered batches, flushes and disconnects (which writes the ``.rrd`` footer). With
    ``autostart=False`` the logging thread starts on :meth:`start` (or at :meth:`close`).
    """

    def __init__(
        self,
        *,
        rrd: str | Path | None = None,
        connect: str | None = None,
        options: VizOptions | None = None,
        application_id: str = APPLICATION_ID,
        recording_id: str | None = None,
        blueprint: bool = True,
        autostart: bool = True,
    ) -> None:
        if rrd is None and connect is None:
            raise ValueError("RerunLogger needs an output: rrd=FILE and/or connect=URL")
        self.options = opts = options or VizOptions()
        if opts.map_frame not in ("ned", "xy"):
            raise ValueError(f"map_frame must be 'ned' or 'xy', not {opts.map_frame!r}")
        if opts.time_kind not in ("timestamp", "duration"):
            raise ValueError(f"time_kind must be 'timestamp' or 'duration', not {opts.time_kind!r}")
        self.rrd = Path(rrd) if rrd is not None else None
        self.connect = connect
        # the logging thread cuts the SDK's row batches at its own (device-time) flushes; the
        # SDK's tick is only a backstop
        batching = rr.ChunkBatcherConfig(flush_tick=10.0, flush_num_bytes=1 << 20)
        self._rec = rr.RecordingStream(
            application_id, recording_id=recording_id, batcher_config=batching
        )
        if rrd is not None and connect is not None:
            self._rec.set_sinks(rr.FileSink(str(rrd)), rr.GrpcSink(connect))
        elif rrd is not None:
            self._rec.save(str(rrd))
        else:
            self._rec.connect_grpc(connect)
        self._send_blueprint = blueprint
        self._bp_tracks: list[str] = list(DEFAULT_TRACKS)
        self._bp_raw_ping = False  # the layout has the GeoSwath raw-ping view
        if blueprint:
            self._rec.send_blueprint(default_blueprint(self._bp_tracks))
        super().__init__(max(1, opts.queue_size), period_s=opts.flush_period_s)
        self._lock = threading.Lock()
        self._dropped: Counter[str] = Counter()
        self._closed = False
        self._handlers: dict[str, Callable[..., None]] = {
            name[4:]: getattr(self, name) for name in dir(self) if name.startswith("_do_")
        }
        # state of the logging thread
        self._streams: dict[str, _Stream] = {}
        self._health_names: dict[str, tuple[str, ...]] = {}
        self._device_colours: dict[str, tuple[int, int, int]] = {}
        self._grid_bounds: tuple[np.ndarray, np.ndarray] | None = None  # the grid's area
        self._grid_extent: tuple[np.ndarray, np.ndarray] | None = None  # of what is drawn
        self._mag_mean: np.ndarray | None = None  # running mean of the field (nT)
        self._mag_t = -math.inf
        self._fan_overlay: float | None = None
        self._fan_scale: tuple[float, float] | None = None
        self._depth_scale_logged = False
        self._counters: dict[str, dict[str, float]] = {}
        self._counters_dirty = False
        self._counters_t = -math.inf
        self._styled: set[str] = set()
        self._tracks: dict[str, _Track] = {}
        self._fan = _Fan(opts.fan_pixels)
        self._fan_logged_t = -math.inf
        self._fan_t = 0.0
        self._grid = _Grid(opts.bathy_cell_m, opts.bathy_max_cells)
        self._grid_logged_t = -math.inf
        self._grid_t = 0.0
        self._depth_range = opts.depth_range
        self._vehicle_pos = (0.0, 0.0, 0.0)
        self._vehicle_src = ""
        self._attitude_seen = False
        self._pose_t = -math.inf
        self._t_last = 0.0
        self._t_flushed = -math.inf
        self._dropped_logged = 0
        if autostart:
            self.start()

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Start the logging thread (idempotent)."""
        self.start_worker()

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop accepting items, log what is queued, send the batches, flush and disconnect."""
        if self._closed:
            return
        self._closed = True
        self.start_worker()
        self.stop_worker(timeout_s)
        try:
            self._rec.flush(timeout_sec=timeout_s)
        finally:
            self._rec.disconnect()

    def stats(self) -> LoggerStats:
        """Current counters (see :class:`LoggerStats`)."""
        with self._lock:
            dropped = dict(self._dropped)
        w = self.worker_stats()
        return LoggerStats(
            processed=w.handled,
            dropped=sum(dropped.values()),
            errors=w.errors,
            queued=w.queued,
            dropped_by_kind=dropped,
            last_error=w.last_error,
        )

    def _put(self, kind: str, args: tuple[Any, ...], t: float) -> bool:
        if self.submit((kind, t, args)):
            return True
        with self._lock:
            self._dropped[kind] += 1
        return False

    # -- public API: one method per thing to show -------------------------------------------
    def trajectory(
        self,
        name: str,
        t: float,
        x: float,
        y: float,
        z: float = math.nan,
        heading: float = math.nan,
        cov_xy: ArrayLike | None = None,
    ) -> bool:
        """One pose of trajectory ``name`` (``truth``, ``dead_reckoning``, ``slam/<pipeline>``):
        position (m), heading (rad), optional 2x2 horizontal covariance (m^2). The line strip
        grows (vertices at least ``track_min_step_m`` apart); the current pose is an arrow with
        its ellipse."""
        cov = None if cov_xy is None else np.array(cov_xy, dtype=np.float64).reshape(2, 2)
        args = (name, float(t), float(x), float(y), float(z), float(heading), cov)
        return self._put("trajectory", args, float(t))

    def landmarks(
        self,
        name: str,
        t: float,
        mean: ArrayLike,
        cov: ArrayLike | None = None,
        ids: ArrayLike | None = None,
    ) -> bool:
        """Point features of map ``name``: ``mean (L, 2)`` m, ``cov (L, 2, 2)`` m^2 (drawn as
        confidence ellipses), ``ids (L,)``. Replaces the previous set."""
        m = np.array(mean, dtype=np.float64).reshape(-1, 2)
        c = None if cov is None else np.array(cov, dtype=np.float64).reshape(-1, 2, 2)
        i = None if ids is None else np.array(ids).reshape(-1)
        _same_length("landmarks", mean=m, cov=c, ids=i)
        return self._put("landmarks", (name, float(t), m, c, i), float(t))

    def lines(
        self,
        name: str,
        t: float,
        rho: ArrayLike,
        theta: ArrayLike,
        cov: ArrayLike | None = None,
        endpoints: ArrayLike | None = None,
    ) -> bool:
        """Line features of map ``name`` in normal form ``x cos(theta) + y sin(theta) = rho``
        (m, rad, map frame axes), ``cov (K, 2, 2)`` over (rho, theta) drawn as the ellipse of the
        line's foot point, optional ``endpoints (K, 2, 2)`` (m) for finite segments."""
        r = np.array(rho, dtype=np.float64).reshape(-1)
        th = np.array(theta, dtype=np.float64).reshape(-1)
        c = None if cov is None else np.array(cov, dtype=np.float64).reshape(-1, 2, 2)
        e = None if endpoints is None else np.array(endpoints, dtype=np.float64).reshape(-1, 2, 2)
        _same_length("lines", rho=r, theta=th, cov=c, endpoints=e)
        return self._put("lines", (name, float(t), r, th, c, e), float(t))

    def particles(
        self, name: str, t: float, poses: ArrayLike, weights: ArrayLike | None = None
    ) -> bool:
        """Particle cloud of filter ``name``: ``poses (N, 2+)`` (x, y first, m); an evenly
        spaced subsample of ``max_particles`` is drawn (the heaviest first when ``weights``)."""
        p = np.asarray(poses, dtype=np.float64)
        p = p.reshape(len(p), -1)[:, :2] if p.size else np.zeros((0, 2))
        w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        keep = self.options.max_particles
        if len(p) > keep:
            if w is not None and len(w) == len(p):
                order = np.argsort(-w, kind="stable")
                p = p[order[np.linspace(0, len(p) - 1, keep).astype(np.intp)]]
            else:
                p = p[np.linspace(0, len(p) - 1, keep).astype(np.intp)]
        else:
            p = p.copy()
        return self._put("particles", (name, float(t), p), float(t))

    def attitude(
        self, t: float, roll: float, pitch: float, heading: float, position: ArrayLike | None = None
    ) -> bool:
        """INS attitude (rad): the vehicle's Transform3D (at ``position`` NED m if given, else at
        the latest position of the navigation trajectory) and roll/pitch/heading series (deg)."""
        pos = None if position is None else tuple(float(v) for v in np.ravel(position))
        return self._put(
            "attitude", (float(t), float(roll), float(pitch), float(heading), pos), float(t)
        )

    def dvl(
        self,
        t: float,
        velocity: ArrayLike,
        altitude: float = math.nan,
        names: Sequence[str] = ("x", "y", "z"),
        bottom_lock: bool | None = None,
    ) -> bool:
        """DVL velocity over the bottom (m/s, 3 components named ``names``, e.g. the instrument
        axes), altitude (m) and bottom lock."""
        v = np.array(velocity, dtype=np.float64).reshape(-1)[:3]
        return self._put("dvl", (float(t), v, float(altitude), tuple(names), bottom_lock), float(t))

    def msis_ping(
        self,
        t: float,
        bearing: float,
        bins: ArrayLike,
        range_m: float,
        step: float = 0.0,
        max_value: int = 255,
    ) -> bool:
        """One MSIS scan line: ``bearing`` (rad, clockwise from forward), amplitudes ``bins``
        (near to far, 0..``max_value``) over ``range_m``; ``step`` the head step (rad). Lines
        accumulate into the fan image of the current sweep."""
        b = np.asarray(bins)
        if max_value != 255:
            b = np.clip(b.astype(np.float64) * (255.0 / max(1, max_value)), 0, 255)
        b = b.astype(np.uint8, copy=True).reshape(-1)
        return self._put(
            "msis", (float(t), float(bearing), b, float(range_m), float(step)), float(t)
        )

    def swath(
        self,
        t: float,
        along: ArrayLike,
        across: ArrayLike,
        depth: ArrayLike,
        *,
        x: float = 0.0,
        y: float = 0.0,
        z: float = 0.0,
        heading: float = 0.0,
        valid: ArrayLike | None = None,
    ) -> bool:
        """One multibeam ping: soundings ``along`` (forward), ``across`` (starboard), ``depth``
        (down) in m from the transducer, placed at the transducer position ``x, y, z`` (map frame,
        m) with ``heading`` (rad). Valid soundings become coloured points and feed the grid."""
        a = np.array(along, dtype=np.float64).reshape(-1)
        c = np.array(across, dtype=np.float64).reshape(-1)
        d = np.array(depth, dtype=np.float64).reshape(-1)
        v = None if valid is None else np.asarray(valid, dtype=bool).reshape(-1)
        _same_length("swath", along=a, across=c, depth=d, valid=v)
        ok = np.isfinite(a) & np.isfinite(c) & np.isfinite(d)
        if v is not None:
            ok &= v
        pose = (float(x), float(y), float(z), float(heading))
        return self._put("swath", (float(t), a[ok], c[ok], d[ok], pose), float(t))

    def raw_ping(
        self, device: str, t: float, side: int, angle_deg: Any, range_m: Any, amplitude: Any
    ) -> bool:
        """The raw samples of one GeoSwath ping of ``side`` (0 port, 1 starboard): return angle
        (deg from the vertical, positive outward on that side), slant range (m) and amplitude
        (wire counts) per sample, drawn on ``raw_ping/<device>/<side>`` (replacing that side's
        previous ping) at x = the angle (port negative), y = the range, coloured by amplitude
        (log scale, the ping's 1st to 99.5th percentile); at most ``raw_ping_max_samples``
        (every k-th sample beyond)."""
        a = np.array(angle_deg, dtype=np.float64).reshape(-1)
        r = np.array(range_m, dtype=np.float64).reshape(-1)
        amp = np.array(amplitude, dtype=np.float64).reshape(-1)
        _same_length("raw_ping", angle=a, range=r, amplitude=amp)
        return self._put("raw_ping", (str(device), float(t), int(side), a, r, amp), float(t))

    # bathymetric SLAM map (slam/<p>/cloud and slam/<p>/map DEM tiles) ------------------------
    def seabed(self, name: str, t: float, points: ArrayLike) -> bool:
        """Soundings placed by a SLAM trajectory, ``points`` (P, 3) x, y (map frame, m), depth
        (m, down): depth-coloured 3-D points on ``world/<name>/seabed`` (accumulated like the
        multibeam soundings)."""
        pts = np.array(points, dtype=np.float64).reshape(-1, 3)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        return self._put("seabed", (str(name), float(t), pts), float(t))

    def dem(
        self, name: str, t: float, x0: float, y0: float, cell_m: float, depth: ArrayLike
    ) -> bool:
        """A DEM tile of a SLAM map: ``depth[i][j]`` (m, NaN = empty) the mean depth of the
        ``cell_m`` cell centred at ``x0 + (i + 0.5) cell_m, y0 + (j + 0.5) cell_m`` (map
        frame): depth-coloured discs on ``map/<name>/dem`` (each tile replaces the last)."""
        grid = np.array(depth, dtype=np.float64)
        if grid.ndim != 2:
            raise ValueError(f"dem: depth must be a 2-D grid, got shape {grid.shape}")
        args = (str(name), float(t), float(x0), float(y0), float(cell_m), grid)
        return self._put("dem", args, float(t))

    def magnetometer(self, t: float, b_nt: ArrayLike) -> bool:
        """Magnetic flux density (nT, sensor axes = body axes): field series, magnitude and an
        arrow on the vehicle."""
        b = np.array(b_nt, dtype=np.float64).reshape(-1)[:3]
        return self._put("mag", (float(t), b), float(t))

    def health(self, device: str, t: float, metrics: Mapping[str, float]) -> bool:
        """Per-device health numbers: one series each on ``health/<device>/status``; the
        metric names of a device's first call name its series, later calls are matched by
        name (a missing metric is NaN, a new one is not shown)."""
        values = tuple((str(k), float(v)) for k, v in metrics.items())
        return self._put("health", (str(device), float(t), values), float(t))

    def series(self, path: str, t: float, metrics: Mapping[str, float]) -> bool:
        """Named series of one unit on entity ``path`` (e.g. ``pilot/fins``): the names of the
        first call name the series, later calls are matched by name (missing: NaN)."""
        values = tuple((str(k), float(v)) for k, v in metrics.items())
        return self._put("series", (str(path), float(t), values), float(t))

    def event(self, device: str, t: float, text: str, level: str = "INFO") -> bool:
        """A text event of one device (``health/<device>/events``)."""
        return self._put("event", (str(device), float(t), str(text), str(level)), float(t))

    # -- magnetic beacons (AMB-SLAM) --------------------------------------------------------
    def ranges(self, name: str, t: float, origin: ArrayLike, targets: ArrayLike) -> bool:
        """Beacon observations of ``name`` (``slam/magnetic``): one line per observed beacon
        from the vehicle at ``origin (x, y)`` to ``targets (K, 2)`` (m, map frame), on
        ``map/<name>/ranges``; replaces the previous set."""
        o = np.array(origin, dtype=np.float64).reshape(2)
        tg = np.array(targets, dtype=np.float64).reshape(-1, 2)
        return self._put("ranges", (name, float(t), o, tg), float(t))

    def acoustic_beacon(self, name: str, t: float, x: float, y: float) -> bool:
        """The acoustic beacon (a fixed, known position, m) of map ``name``, on
        ``map/<name>/acoustic_beacon``."""
        return self._put("acoustic_beacon", (name, float(t), float(x), float(y)), float(t))

    # -- the logging thread ----------------------------------------------------------------
    def _work_started(self) -> None:
        self._rec.set_log_tick_enabled(False)
        self._rec.set_log_time_enabled(False)
        self._static_setup()

    def _work_item(self, item: _Item) -> None:
        kind, t, args = item
        if t > self._t_last:
            self._t_last = t
        try:
            self._handlers[kind](*args)
        finally:  # batches cut at device-time flushes, failed item or not
            if self._t_last - self._t_flushed >= self.options.flush_period_s:
                self._work_tick()

    def _work_describe(self, item: _Item) -> str:
        return item[0]

    def _work_tick(self) -> None:
        self._t_flushed = self._t_last
        self._flush(final=False)

    def _work_finished(self) -> None:
        self._flush(final=True)

    def _set_time(self, t: float) -> None:
        if self.options.time_kind == "timestamp":
            self._rec.set_time(TIMELINE, timestamp=t)
        else:
            self._rec.set_time(TIMELINE, duration=t)

    def _time_column(self, times: Sequence[float]) -> rr.TimeColumn:
        arr = np.asarray(times, dtype=np.float64)
        if self.options.time_kind == "timestamp":
            return rr.TimeColumn(TIMELINE, timestamp=arr)
        return rr.TimeColumn(TIMELINE, duration=arr)

    def _static(
        self, path: str, make: Callable[[], rr.AsComponents | tuple[rr.AsComponents, ...]]
    ) -> None:
        """Log ``make()`` (archetypes: styles, series names) once per entity, as static data."""
        if path not in self._styled:
            self._styled.add(path)
            made = make()
            self._rec.log(path, *(made if isinstance(made, tuple) else (made,)), static=True)

    def _static_setup(self) -> None:
        rec = self._rec
        frd = self.options.map_frame == "ned"
        rec.log(
            ent.WORLD,
            rr.ViewCoordinates.FRD if frd else rr.ViewCoordinates.RIGHT_HAND_Z_UP,
            static=True,
        )
        rec.log(
            ent.VEHICLE,
            rr.Boxes3D(half_sizes=[[1.0, 0.25, 0.25]], colors=[(255, 220, 0)]),
            rr.TransformAxes3D(1.5),
            static=True,
        )

    def _stream(self, path: str, kind: str) -> _Stream:
        s = self._streams.get(path)
        if s is None:
            s = self._streams[path] = _Stream(kind)
        return s

    def _append(self, path: str, kind: str, t: float, row: _Row) -> None:
        s = self._stream(path, kind)
        if not s.rows:
            s.first_host = time.monotonic()
        s.times.append(t)
        s.rows.append(row)
        if len(s.rows) >= self.options.max_batch_rows:
            self._send(path, s)

    def _send(self, path: str, s: _Stream) -> None:
        if not s.rows:
            return
        times, rows = s.times, s.rows
        s.times, s.rows = [], []
        index = [self._time_column(times)]
        if s.kind == "scalars":
            scalars = np.asarray(rows, dtype=np.float64)
            cols: rr.ComponentColumnList = rr.Scalars.columns(scalars=scalars)
        elif s.kind == "transform":
            arr = np.asarray(rows, dtype=np.float64)
            cols = rr.Transform3D.columns(translation=arr[:, :3], quaternion=arr[:, 3:])
        elif s.kind == "arrows3":
            cols = rr.Arrows3D.columns(vectors=np.asarray(rows, dtype=np.float32))
        elif s.kind == "points3":
            pos = np.concatenate([r[0] for r in rows]).astype(np.float32)
            col = np.concatenate([r[1] for r in rows])
            cols = rr.Points3D.columns(positions=pos, colors=col).partition(
                [len(r[0]) for r in rows if isinstance(r, tuple)]
            )
        else:  # pragma: no cover - kinds are internal
            raise ValueError(f"unknown stream kind {s.kind}")
        self._rec.send_columns(path, indexes=index, columns=cols)

    def _flush(self, final: bool) -> None:
        for name, tr in self._tracks.items():
            self._flush_track(name, tr)
        o = self.options
        now = time.monotonic()
        for path, s in self._streams.items():
            if s.rows and (
                final
                or len(s.rows) >= o.min_batch_rows
                or self._t_last - s.times[0] >= o.max_latency_s
                or now - s.first_host >= o.max_latency_s
            ):
                self._send(path, s)
        if final and self._grid.counts.size:
            self._log_grid(self._grid_t, final=True)
        if final and self._counters_dirty and self._t_last:
            self._log_counters(max(self._t_last, self._counters_t))
        if final and self._fan_t and self._fan_logged_t < self._fan_t:
            self._log_fan(self._fan_t, None)
        dropped = self.stats().dropped
        if dropped != self._dropped_logged and self._t_last:
            self._dropped_logged = dropped
            self._set_time(self._t_last)
            self._rec.log(ent.VIZ_DROPPED, rr.Scalars([float(dropped)]))
        if not final:
            # cut the SDK's row batches here too, so chunks follow device time whatever the
            # replay speed (one batch spanning minutes of a fast replay confuses the viewer)
            self._rec.flush(timeout_sec=0.0)

    # -- map helpers -----------------------------------------------------------------------
    def _to_map(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Map-frame (x, y) -> 2-D view coordinates (u right, v down), stacked on the last axis."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self.options.map_frame == "ned":
            return np.stack([y, -x], axis=-1)
        return np.stack([x, -y], axis=-1)

    def _map_grid(self, uv: np.ndarray, force: bool = False) -> None:
        """The map's metre grid (lines every ``step`` m, their coordinates along the bottom and
        left edges), a scale bar and the legend, re-logged (static) when what is drawn (``uv``:
        tracks, features) leaves the area they cover, or with ``force`` (a new track)."""
        lo, hi = np.nanmin(uv, axis=0), np.nanmax(uv, axis=0)
        b = self._grid_bounds
        if b is not None and np.all(lo >= b[0]) and np.all(hi <= b[1]) and not force:
            return
        if self._grid_extent is not None:  # what was drawn so far (the grid has margins)
            lo = np.minimum(lo, self._grid_extent[0])
            hi = np.maximum(hi, self._grid_extent[1])
        self._grid_extent = (lo, hi)
        span = float(np.max(hi - lo))
        step = next((s for s in _GRID_STEPS if span / s <= 5.0), _GRID_STEPS[-1])
        lo = np.floor(lo / step - 0.5) * step
        hi = np.ceil(hi / step + 0.5) * step
        self._grid_bounds = (lo, hi)
        east, north = ("E", "N") if self.options.map_frame == "ned" else ("x", "y")
        us = np.arange(lo[0], hi[0] + step / 2, step)
        vs = np.arange(lo[1], hi[1] + step / 2, step)
        strips = [np.array([[u, lo[1]], [u, hi[1]]]) for u in us]
        strips += [np.array([[lo[0], v], [hi[0], v]]) for v in vs]
        grey = (60, 70, 85)
        self._rec.log(
            ent.MAP_GRID,
            rr.LineStrips2D(strips, colors=[grey], radii=[-0.75], draw_order=-20.0),
            static=True,
        )
        # the coordinates: east along the bottom edge, north along the left (v = -north)
        ticks = np.array([[u, hi[1]] for u in us[1:-1]] + [[lo[0], v] for v in vs[1:-1]])
        labels = [f"{east} {u + 0.0:.0f} m" for u in us[1:-1]]
        labels += [f"{north} {0.0 - v:.0f} m" for v in vs[1:-1]]
        self._rec.log(
            f"{ent.MAP_GRID}/ticks",
            rr.Points2D(
                ticks,
                colors=[(150, 160, 175)],
                radii=[-2.0],
                labels=labels,
                show_labels=True,
                draw_order=55.0,
            ),
            static=True,
        )
        x0, y1 = lo[0] + step / 2, hi[1] - step / 3
        self._rec.log(
            f"{ent.MAP_GRID}/scale",
            rr.LineStrips2D(
                [np.array([[x0, y1], [x0 + step, y1]])],
                colors=[(255, 255, 255)],
                radii=[-2.5],
                labels=[f"{step:g} m"],
                draw_order=60.0,
            ),
            static=True,
        )
        self._map_legend(lo, step)

    def _map_legend(self, lo: np.ndarray, step: float) -> None:
        """The map's legend in its top-left corner: a short line in each track's colour (and
        the true features'), labelled with its name."""
        first = {"truth": 0, "dead_reckoning": 1}  # then the others as they came
        names = sorted(self._tracks, key=lambda n: first.get(ent.track_segment(n), 2))
        entries = [(ent.track_segment(n).replace("slam/", "SLAM ").replace("_", " "),
                    self._tracks[n].colour) for n in names]  # fmt: skip
        entries.append(("true features", _TRUE_FEATURES))
        x0, y0, dy = lo[0] + step / 6, lo[1] + step / 6, step / 4
        strips = [np.array([[x0, y0 + i * dy], [x0 + step / 3, y0 + i * dy]])
                  for i in range(len(entries))]  # fmt: skip
        self._rec.log(
            f"{ent.MAP_GRID}/legend",
            rr.LineStrips2D(
                strips,
                colors=[c for _, c in entries],
                radii=[-3.0],
                labels=[n for n, _ in entries],
                show_labels=True,
                draw_order=60.0,
            ),
            static=True,
        )

    def _ellipses(self, centres: np.ndarray, covs: np.ndarray) -> list[np.ndarray]:
        o = self.options
        e = ellipse_strips(centres, covs, o.ellipse_sigma, o.ellipse_vertices)
        return list(self._to_map(e[..., 0], e[..., 1]))

    def _colour(self, name: str, feature: bool = False) -> tuple[int, int, int]:
        """A track's colour (``feature``: of its landmarks and lines; the true ones apart)."""
        key = ent.track_segment(name)
        if feature and key == "truth":
            return _TRUE_FEATURES
        if key in _TRACK_COLOURS:
            return _TRACK_COLOURS[key]
        others = [n for n in self._tracks if ent.track_segment(n) not in _TRACK_COLOURS]
        i = others.index(name) if name in others else len(others)
        return _PALETTE[i % len(_PALETTE)]

    def _track(self, name: str) -> _Track:
        tr = self._tracks.get(name)
        if tr is None:
            colour = self._colour(name)
            tr = self._tracks[name] = _Track(colour)
            seg = ent.track_segment(name)
            if self._send_blueprint and seg not in self._bp_tracks:
                self._bp_tracks.append(seg)
                self._rec.send_blueprint(
                    default_blueprint(self._bp_tracks, raw_ping=self._bp_raw_ping)
                )
            log_static = self._rec.log
            width, order = _TRACK_STYLE.get(seg, _TRACK_STYLE_OTHER)
            log_static(
                ent.map_path(name, "track"),
                rr.LineStrips2D.from_fields(colors=[colour], radii=[-width], draw_order=order),
                static=True,
            )
            log_static(
                ent.world_path(name, "track"),
                rr.LineStrips3D.from_fields(colors=[colour], radii=[-width]),
                static=True,
            )
            if self._grid_extent is not None:  # the legend names the new track
                self._map_grid(np.array(self._grid_extent), force=True)
            log_static(
                ent.map_path(name, "pose"),
                rr.Points2D.from_fields(colors=[colour], radii=[-5.0], draw_order=40.0),
                rr.Arrows2D.from_fields(colors=[colour], draw_order=40.0),
                rr.LineStrips2D.from_fields(colors=[colour], radii=[-1.0], draw_order=35.0),
                static=True,
            )
        return tr

    # -- handlers (logging thread) ---------------------------------------------------------
    def _do_trajectory(
        self,
        name: str,
        t: float,
        x: float,
        y: float,
        z: float,
        heading: float,
        cov: np.ndarray | None,
    ) -> None:
        tr = self._track(name)
        zz = 0.0 if math.isnan(z) else z
        p = (x, y, zz)
        tr.latest = (t, x, y, zz, heading, cov)
        tr.pose_dirty = True
        if (
            tr.kept is None
            or math.hypot(x - tr.kept[0], y - tr.kept[1]) >= (self.options.track_min_step_m)
            or abs(zz - tr.kept[2]) >= self.options.track_min_step_m
        ):
            tr.kept = p
            tr.pending.append(p)
            tr.pending_t = t
        if t - tr.flushed_t >= self.options.flush_period_s:
            self._flush_track(name, tr)
        # the vehicle frame follows dead reckoning, else truth, else the first track seen
        seg = ent.track_segment(name)
        if not self._vehicle_src or _RANK.get(seg, 2) <= _RANK.get(self._vehicle_src, 2):
            self._vehicle_src = seg
        if seg == self._vehicle_src:
            self._vehicle_pos = p

    def _flush_track(self, name: str, tr: _Track) -> None:
        if tr.latest is not None:
            tr.flushed_t = tr.latest[0]
        if tr.pending:
            pts = ([tr.last_sent] if tr.last_sent is not None else []) + tr.pending
            if len(pts) >= 2:
                arr = np.asarray(pts)
                self._set_time(tr.pending_t)
                uv = self._to_map(arr[:, 0], arr[:, 1])
                self._rec.log(ent.map_path(name, "track"), rr.LineStrips2D([uv]))
                self._map_grid(uv)
                self._rec.log(ent.world_path(name, "track"), rr.LineStrips3D([arr]))
                tr.last_sent = tr.pending[-1]
                tr.pending = []
        if tr.pose_dirty and tr.latest is not None:
            tr.pose_dirty = False
            t, x, y, z, heading, cov = tr.latest
            self._set_time(t)
            uv = self._to_map(x, y)
            arrows: list[np.ndarray] = []
            if not math.isnan(heading):
                arrows = [
                    self._to_map(math.cos(heading), math.sin(heading)) * self.options.pose_arrow_m
                ]
            strips: list[np.ndarray] = []
            if cov is not None and np.all(np.isfinite(cov)):
                strips = self._ellipses(np.array([[x, y]]), cov[None])
            # position, heading arrow and 2-sigma ellipse on one entity (one chunk per flush)
            self._rec.log(
                ent.map_path(name, "pose"),
                rr.Points2D([uv]),
                rr.Arrows2D(origins=[uv] * len(arrows), vectors=arrows),
                rr.LineStrips2D(strips),
            )
            if not self._attitude_seen and ent.track_segment(name) == self._vehicle_src:
                q = attitude_quaternion(0.0, 0.0, 0.0 if math.isnan(heading) else heading)
                self._rec.log(ent.VEHICLE, rr.Transform3D(translation=[x, y, z],
                                                          quaternion=rr.Quaternion(xyzw=q)))

    def _do_landmarks(
        self, name: str, t: float, mean: np.ndarray, cov: np.ndarray | None, ids: np.ndarray | None
    ) -> None:
        colour = self._colour(name, feature=True)
        self._set_time(t)
        labels = None if ids is None else [str(i) for i in ids]
        if len(mean) and ent.track_segment(name) == "truth":  # estimates may stray far
            self._map_grid(self._to_map(mean[:, 0], mean[:, 1]))
        # the points and their confidence ellipses on one entity (one chunk per flush)
        self._rec.log(
            ent.map_path(name, "landmarks"),
            rr.Points2D(
                self._to_map(mean[:, 0], mean[:, 1]),
                colors=[colour],
                radii=[-4.0],
                labels=labels,
                show_labels=labels is not None and len(labels) <= 40,
                draw_order=45.0,
            ),
            rr.LineStrips2D(
                [] if cov is None else self._ellipses(mean, cov), colors=[colour], radii=[-1.0]
            ),
        )

    def _do_lines(
        self,
        name: str,
        t: float,
        rho: np.ndarray,
        theta: np.ndarray,
        cov: np.ndarray | None,
        endpoints: np.ndarray | None,
    ) -> None:
        colour = self._colour(name, feature=True)
        n = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        foot = rho[:, None] * n
        if endpoints is not None and len(endpoints) == len(rho):
            seg = endpoints
        else:
            d = np.stack([-n[:, 1], n[:, 0]], axis=-1) * self.options.line_half_length_m
            seg = np.stack([foot - d, foot + d], axis=1)
        self._set_time(t)
        if len(seg) and ent.track_segment(name) == "truth":
            self._map_grid(self._to_map(seg[..., 0], seg[..., 1]).reshape(-1, 2))
        self._rec.log(
            ent.map_path(name, "lines"),
            rr.LineStrips2D(
                list(self._to_map(seg[..., 0], seg[..., 1])), colors=[colour], radii=[-2.0]
            ),
        )
        if cov is not None and len(cov) == len(rho):
            c, s = n[:, 0], n[:, 1]
            jac = np.empty((len(rho), 2, 2))
            jac[:, 0, 0], jac[:, 0, 1] = c, -rho * s
            jac[:, 1, 0], jac[:, 1, 1] = s, rho * c
            cxy = jac @ cov @ np.transpose(jac, (0, 2, 1))
            self._rec.log(
                ent.map_path(name, "line_cov"),
                rr.LineStrips2D(self._ellipses(foot, cxy), colors=[colour], radii=[-1.0]),
            )

    def _do_particles(self, name: str, t: float, p: np.ndarray) -> None:
        self._set_time(t)
        self._rec.log(
            ent.map_path(name, "particles"),
            rr.Points2D(
                self._to_map(p[:, 0], p[:, 1]),
                colors=[self._colour(name)],
                radii=[-1.5],
                draw_order=20.0,
            ),
        )

    def _do_attitude(
        self,
        t: float,
        roll: float,
        pitch: float,
        heading: float,
        pos: tuple[float, ...] | None,
    ) -> None:
        self._attitude_seen = True
        self._static(ent.INS_ATTITUDE, lambda: rr.SeriesLines(names=["roll deg", "pitch deg"]))
        self._static(ent.INS_HEADING, lambda: rr.SeriesLines(names=["heading deg"]))
        self._append(ent.INS_ATTITUDE, "scalars", t, (math.degrees(roll), math.degrees(pitch)))
        self._append(ent.INS_HEADING, "scalars", t, (math.degrees(heading) % 360.0,))
        # 100 us slack: device times near 1.7e9 s carry about 0.2 us of float rounding
        if t - self._pose_t >= 1.0 / self.options.vehicle_pose_hz - 1e-4 or t < self._pose_t:
            self._pose_t = t
            p = pos if pos is not None else self._vehicle_pos
            q = attitude_quaternion(roll, pitch, heading)
            self._append(ent.VEHICLE, "transform", t, (*p, *q))

    def _do_dvl(
        self,
        t: float,
        v: np.ndarray,
        altitude: float,
        names: tuple[str, ...],
        bottom_lock: bool | None,
    ) -> None:
        if len(v):
            self._static(
                ent.DVL_VELOCITY,
                lambda: rr.SeriesLines(
                    names=[f"{n} m/s" for n in names[: len(v)]],
                    colors=[(235, 80, 80), (90, 210, 90), (80, 150, 255)][: len(v)],
                ),
            )
            self._append(ent.DVL_VELOCITY, "scalars", t, tuple(v))
        if not math.isnan(altitude):
            self._static(ent.DVL_ALTITUDE, lambda: rr.SeriesLines(names=["altitude m"]))
            self._append(ent.DVL_ALTITUDE, "scalars", t, (altitude,))
        if bottom_lock is not None:
            self._static(ent.DVL_BOTTOM_LOCK, lambda: rr.SeriesLines(names=["bottom lock"]))
            self._append(ent.DVL_BOTTOM_LOCK, "scalars", t, (1.0 if bottom_lock else 0.0,))

    def _log_fan(self, t: float, bearing: float | None) -> None:
        self._set_time(t)
        img = self._fan.image.copy()
        quality = self.options.fan_jpeg_quality
        if quality is None:
            # the echo levels as they came (0 = no return), in a colour map whose range is the
            # sweep's own echoes (display gain: the top 0.5 % saturate) so targets stand out
            # the echo levels as the head sent them, each level drawn in the colour of the
            # sweep's own scale (an annotation context: a display gain from the speckle's level
            # to the strongest echo), no return black
            lo, hi = _fan_levels(img)
            if (lo, hi) != self._fan_scale:
                self._fan_scale = (lo, hi)
                self._rec.log(ent.SONAR, _fan_colours(lo, hi))
            self._rec.log(ent.SONAR_FAN, rr.SegmentationImage(img, opacity=1.0))
        else:
            self._rec.log(ent.SONAR_FAN, rr.Image(img).compress(quality))
        if self._fan_overlay != self._fan.range_m:
            self._fan_overlay = self._fan.range_m
            self._sonar_overlay(self._fan.range_m)
        if bearing is not None:
            self._rec.log(
                ent.SONAR_BEAM,
                rr.LineStrips2D([self._fan.beam(bearing)], colors=[(255, 80, 80)], radii=[-1.0]),
            )
        self._fan_logged_t = t

    def _sonar_overlay(self, range_m: float) -> None:
        """Range rings every quarter of the range scale (labelled in metres) and the vehicle,
        bow up, at the centre of the fan (pixels; static, re-logged when the range changes)."""
        n = self._fan.size
        c, rad = (n - 1) / 2.0, n / 2.0
        a = np.linspace(0.0, TWO_PI, 97)
        rings = [np.column_stack([c + f * rad * np.sin(a), c - f * rad * np.cos(a)])
                 for f in _RINGS]  # fmt: skip
        labels = [f"{f * range_m:.3g} m" if math.isfinite(range_m) else "" for f in _RINGS]
        self._rec.log(
            ent.SONAR_RINGS,
            rr.LineStrips2D(rings, colors=[(90, 200, 255)], radii=[-0.75], draw_order=20.0),
            static=True,
        )
        # each ring's range where it crosses the 45 deg bearing (the labels of line strips sit
        # on top of each other at the centre)
        d = rad * math.sqrt(0.5)
        at = np.array([[c + f * d, c - f * d] for f in _RINGS])
        self._rec.log(f"{ent.SONAR_RINGS}/labels", rr.Points2D(
            at, colors=[(90, 200, 255)], radii=[-1.5], labels=labels, show_labels=True,
            draw_order=25.0), static=True)  # fmt: skip
        s = max(3.0, n / 40.0)
        hull = np.array([[c, c - 1.6 * s], [c + s, c + s], [c - s, c + s], [c, c - 1.6 * s]])
        self._rec.log(ent.SONAR_VEHICLE, rr.LineStrips2D(
            [hull], colors=[(255, 220, 0)], radii=[-1.5], draw_order=30.0),
            static=True)  # fmt: skip

    def _do_msis(
        self, t: float, bearing: float, bins: np.ndarray, range_m: float, step: float
    ) -> None:
        fan = self._fan
        prev = fan.prev
        if fan.new_sweep(bearing, range_m, len(bins)):
            self._log_fan(self._fan_t, prev)
            fan.clear()
        d = abs(wrap_angle(bearing - prev)) if prev is not None else 0.0
        half = max(step, d, math.radians(0.45)) / 2.0
        fan.paint(bearing, bins, half)
        self._fan_t = t
        if t - self._fan_logged_t >= self.options.fan_period_s:
            self._log_fan(t, bearing)

    def _do_raw_ping(
        self, device: str, t: float, side: int, a: np.ndarray, r: np.ndarray, amp: np.ndarray
    ) -> None:
        if self._send_blueprint and not self._bp_raw_ping:
            self._bp_raw_ping = True
            self._rec.send_blueprint(default_blueprint(self._bp_tracks, raw_ping=True))
        ok = np.isfinite(a) & np.isfinite(r) & np.isfinite(amp)
        a, r, amp = a[ok], r[ok], amp[ok]
        step = -(-len(a) // max(1, self.options.raw_ping_max_samples))  # ceil
        a, r, amp = a[::step], r[::step], amp[::step]
        x = -a if side == 0 else a
        self._set_time(t)
        self._rec.log(
            ent.raw_ping_path(device, side),
            rr.Points2D(np.column_stack([x, r]), colors=amplitude_colours(amp),
                        radii=rr.Radius.ui_points(1.5)),
        )  # fmt: skip

    def _do_swath(
        self,
        t: float,
        along: np.ndarray,
        across: np.ndarray,
        depth: np.ndarray,
        pose: tuple[float, float, float, float],
    ) -> None:
        if not len(depth):
            return
        x0, y0, z0, h = pose
        frd = self.options.map_frame == "ned"
        ch, sh = math.cos(h), math.sin(h)
        if frd:  # along = forward, across = starboard
            xs = x0 + along * ch - across * sh
            ys = y0 + along * sh + across * ch
        else:  # x right, y up, heading counter-clockwise: starboard is to the right
            xs = x0 + along * ch + across * sh
            ys = y0 + along * sh - across * ch
        zs = z0 + depth
        if self._depth_range is None:
            lo, hi = float(np.min(zs)), float(np.max(zs))
            pad = max(1.0, 0.5 * (hi - lo))
            self._depth_range = (lo - pad, hi + pad)
        lo, hi = self._depth_range
        if not self._depth_scale_logged:
            width = float(np.nanmax(across) - np.nanmin(across)) if len(across) > 1 else 40.0
            self._depth_scale(x0, y0, lo, hi, max(20.0, 0.5 * width))
        colours = depth_colours(zs, lo, hi)
        # discs in metres, sized to the beams' spacing: screen-sized ones left gaps where the
        # spacing was wider (a white band along the swath, issue 33)
        self._static(ent.SOUNDINGS, lambda: rr.Points3D.from_fields(radii=[_disc_m(across)]))
        self._append(ent.SOUNDINGS, "points3", t, (np.column_stack([xs, ys, zs]), colours))
        uv = self._to_map(xs, ys)
        self._grid.add(uv[:, 0], uv[:, 1], zs)
        self._grid_t = t
        if t - self._grid_logged_t >= self.options.bathy_period_s:
            self._log_grid(t)

    def _depth_scale(self, x: float, y: float, lo: float, hi: float, length: float) -> None:
        """The depth colour scale in the 3-D view (static): a bar ``length`` m long in depth
        colours from ``lo`` to ``hi`` m, lying at ``hi`` m from 10 m behind the first swath's
        place (``x``, ``y`` in the map frame) backwards, the depths labelled along it."""
        self._depth_scale_logged = True
        frac = np.linspace(0.0, 1.0, 21)
        px = x - 10.0 - frac * length
        segs = [np.array([[a, y, hi], [b, y, hi]]) for a, b in itertools.pairwise(px)]
        mids = lo + (hi - lo) * 0.5 * (frac[:-1] + frac[1:])
        self._rec.log(
            ent.DEPTH_SCALE,
            rr.LineStrips3D(segs, colors=depth_colours(mids, lo, hi), radii=[-6.0]),
            static=True,
        )
        tf = np.linspace(0.0, 1.0, 5)
        ticks = lo + (hi - lo) * tf
        self._rec.log(
            f"{ent.DEPTH_SCALE}/ticks",
            rr.Points3D(
                np.column_stack([x - 10.0 - tf * length, np.full(5, y), np.full(5, hi)]),
                colors=depth_colours(ticks, lo, hi),
                radii=[-4.0],
                labels=[f"{d:.1f} m" for d in ticks],
                show_labels=True,
            ),
            static=True,
        )

    def _log_grid(self, t: float, final: bool = False) -> None:
        """The grid cells updated since the last log as depth-coloured discs on the map (the
        layout accumulates them) and, at the end, the mean depths themselves as a DepthImage
        (``bathymetry/mean_depth``, m, 0 = no sounding)."""
        u, v, mean = self._grid.take_touched()
        lo, hi = self._depth_range or (0.0, 1.0)
        self._set_time(t)
        if len(u):
            self._rec.log(
                ent.MAP_BATHYMETRY,
                rr.Points2D(
                    np.column_stack([u, v]),
                    colors=depth_colours(mean, lo, hi),
                    radii=[0.75 * self._grid.cell],
                    draw_order=-10.0,
                ),
            )
        if final:
            img, u0, v0 = self._grid.mean()
            self._rec.log(
                ent.MEAN_DEPTH,
                rr.DepthImage(img, meter=1.0, colormap="turbo", depth_range=(lo, hi)),
                rr.Transform3D(translation=[u0, v0, 0.0], scale=self._grid.cell),
            )
        self._grid_logged_t = t

    # bathymetric SLAM map ------------------------------------------------------------------
    def _seabed_colours(self, depth: np.ndarray) -> np.ndarray:
        if self._depth_range is None and len(depth):
            lo, hi = float(np.min(depth)), float(np.max(depth))
            pad = max(1.0, 0.5 * (hi - lo))
            self._depth_range = (lo - pad, hi + pad)
        lo, hi = self._depth_range or (0.0, 1.0)
        return depth_colours(depth, lo, hi)

    def _do_seabed(self, name: str, t: float, pts: np.ndarray) -> None:
        if not len(pts):
            return
        path = ent.world_path(name, "seabed")
        self._static(path, lambda: rr.Points3D.from_fields(radii=[-2.0]))
        self._append(path, "points3", t, (pts, self._seabed_colours(pts[:, 2])))

    def _do_dem(
        self, name: str, t: float, x0: float, y0: float, cell: float, grid: np.ndarray
    ) -> None:
        i, j = np.nonzero(np.isfinite(grid))
        if not len(i):
            return
        uv = self._to_map(x0 + (i + 0.5) * cell, y0 + (j + 0.5) * cell)
        self._set_time(t)
        self._rec.log(
            ent.map_path(name, "dem"),
            rr.Points2D(
                uv, colors=self._seabed_colours(grid[i, j]), radii=[0.6 * cell], draw_order=-5.0
            ),
        )

    def _do_mag(self, t: float, b: np.ndarray) -> None:
        xyz = [(235, 80, 80), (90, 210, 90), (80, 150, 255)]  # x red, y green, z blue
        self._static(ent.MAG_FIELD, lambda: rr.SeriesLines(names=["x nT", "y nT", "z nT"],
                                                           colors=xyz))  # fmt: skip
        self._static(ent.MAG_CHANGE, lambda: rr.SeriesLines(names=["x", "y", "z"], colors=xyz))
        white = [(230, 230, 230)]
        self._static(ent.MAG_MAGNITUDE, lambda: rr.SeriesLines(names=["|B| nT"], colors=white))
        # the field itself spans tens of thousands of nT, and a turn moves it by as much in the
        # body frame: its departure from a running mean (time constant mag_baseline_s of device
        # time) is what shows a beacon's signal or an anomaly of a few nT
        bb = np.asarray(b, dtype=np.float64)
        if self._mag_mean is None or t < self._mag_t:
            self._mag_mean = bb.copy()
        else:
            alpha = 1.0 - math.exp(-(t - self._mag_t) / self.options.mag_baseline_s)
            self._mag_mean += alpha * (bb - self._mag_mean)
        self._mag_t = t
        self._append(ent.MAG_CHANGE, "scalars", t, tuple(bb - self._mag_mean))
        self._static(ent.VEHICLE_MAG, lambda: rr.Arrows3D.from_fields(colors=[(0, 200, 255)]))
        self._append(ent.MAG_FIELD, "scalars", t, tuple(b))
        self._append(ent.MAG_MAGNITUDE, "scalars", t, (float(np.linalg.norm(b)),))
        self._append(ent.VEHICLE_MAG, "arrows3", t, tuple(b * self.options.mag_arrow_m_per_nt))

    def _do_health(self, device: str, t: float, values: tuple[tuple[str, float], ...]) -> None:
        """One status of ``device``: each metric into its group's series (one unit per view,
        :func:`~auvgw.viz.entities.health_group`), cumulative counters into the table."""
        groups: dict[str, list[tuple[str, float]]] = {}
        for name, v in values:
            group = ent.health_group(name)
            if group is None:  # the table, and a series no view shows (for tools, tests)
                self._counters.setdefault(device, {})[name] = v
                self._counters_dirty = True
                group = "count"
            groups.setdefault(group, []).append((name, v))
        for group, metrics in groups.items():
            self._named_series(ent.health_path(device, group), t, metrics, device)
        if self._counters_dirty and t - self._counters_t >= self.options.counters_period_s:
            self._log_counters(t)

    def _do_series(self, path: str, t: float, values: tuple[tuple[str, float], ...]) -> None:
        self._named_series(path, t, values)

    def _named_series(self, path: str, t: float, metrics: Iterable[tuple[str, float]],
                      device: str | None = None) -> None:  # fmt: skip
        """Scalars of named series on ``path``, named (and coloured: one colour per ``device``,
        else one per series) at the path's first call."""
        metrics = tuple(metrics)
        names = self._health_names.get(path)
        if names is None:
            names = self._health_names[path] = tuple(k for k, _ in metrics)
            prefix = f"{device} " if device is not None else ""
            colours = ([self._device_colour(device)] * len(names) if device is not None
                       else [_HEALTH_PALETTE[i % len(_HEALTH_PALETTE)] for i in range(len(names))])
            series = rr.SeriesLines(names=[f"{prefix}{k}" for k in names], colors=colours,
                                    widths=[1.5] * len(names))  # fmt: skip
            self._static(path, lambda: series)
        got = dict(metrics)
        self._append(path, "scalars", t, tuple(got.get(n, math.nan) for n in names))

    def _device_colour(self, device: str) -> tuple[int, int, int]:
        """One colour per device (or stage) across the health views, in order of appearance."""
        if device not in self._device_colours:
            palette = _HEALTH_PALETTE
            self._device_colours[device] = palette[len(self._device_colours) % len(palette)]
        return self._device_colours[device]

    def _log_counters(self, t: float) -> None:
        """Every component's latest cumulative counters as one markdown table at ``t``."""
        self._counters_t, self._counters_dirty = t, False
        lines = ["| component | counters |", "|---|---|"]
        for device, counts in sorted(self._counters.items()):
            cells = ", ".join(
                f"{k} {v:.0f}" if float(v).is_integer() else f"{k} {v:.3g}"
                for k, v in counts.items()
                if math.isfinite(v)
            )
            lines.append(f"| {device} | {cells} |")
        self._set_time(t)
        self._rec.log(
            ent.HEALTH_COUNTERS, rr.TextDocument("\n".join(lines), media_type="text/markdown")
        )

    def _do_event(self, device: str, t: float, text: str, level: str) -> None:
        self._set_time(t)
        self._rec.log(ent.events_path(device), rr.TextLog(text, level=level))

    # -- magnetic beacons (AMB-SLAM) --------------------------------------------------------
    def _do_ranges(self, name: str, t: float, origin: np.ndarray, targets: np.ndarray) -> None:
        self._set_time(t)
        seg = np.stack([np.broadcast_to(origin, targets.shape), targets], axis=1)
        self._rec.log(
            ent.map_path(name, "ranges"),
            rr.LineStrips2D(list(self._to_map(seg[..., 0], seg[..., 1])),
                            colors=[self._colour(name)], radii=[-1.0], draw_order=25.0),
        )  # fmt: skip

    def _do_acoustic_beacon(self, name: str, t: float, x: float, y: float) -> None:
        self._set_time(t)
        self._rec.log(
            ent.map_path(name, "acoustic_beacon"),
            rr.Points2D(self._to_map([x], [y]), colors=[ACOUSTIC_COLOUR], radii=[-7.0],
                        labels=["acoustic beacon"], draw_order=50.0),
        )  # fmt: skip
