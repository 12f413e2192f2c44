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

import logging
import math
import threading
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike

from auvgw.ground.closing import Closing
from auvgw.ground.worker import Worker
from auvgw.viz import entities as ent
from auvgw.viz.entities import APPLICATION_ID, TIMELINE
from auvgw.viz.options import VizOptions
from auvgw.viz.scene import (
    ACOUSTIC_COLOUR,
    Scene,
    attitude_quaternion,
    depth_colours,
    ellipse_strips,
)
from auvgw.viz.views import VIEWS, View
from auvgw.viz.views.sensors import amplitude_colours

__all__ = [
    "ACOUSTIC_COLOUR",
    "TIMELINE",
    "LoggerStats",
    "RerunLogger",
    "VizOptions",
    "amplitude_colours",
    "attitude_quaternion",
    "depth_colours",
    "ellipse_strips",
]

log = logging.getLogger(__name__)

#: a queued logger call: (view kind, data time s, the view's arguments)
_Item = tuple[str, float, tuple[object, ...]]


def _same_length(what: str, **arrays: np.ndarray | None) -> None:
    """Raise ValueError naming the arrays of ``what`` whose lengths differ."""
    lengths = {k: len(v) for k, v in arrays.items() if v is not None}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{what}: arrays of different lengths {lengths}")


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
        super().__init__(max(1, opts.queue_size), period_s=opts.flush_period_s)
        self._lock = threading.Lock()
        self._dropped: Counter[str] = Counter()
        self._closed = False
        # the logging thread's: the views (their state) and what they share
        self._scene = Scene(self._rec, opts, blueprint)
        self._views: dict[str, View] = {v.kind: v(self._scene) for v in VIEWS}
        self._handlers: dict[str, Callable[..., None]] = {k: v.log for k, v in self._views.items()}
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

    def _put(self, kind: str, args: tuple[object, ...], t: float) -> bool:
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
        self,
        device: str,
        t: float,
        side: int,
        angle_deg: ArrayLike,
        range_m: ArrayLike,
        amplitude: ArrayLike,
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

    def _flush(self, final: bool) -> None:
        for view in self._views.values():
            view.flush(final, self._t_last)
        self._scene.send_streams(final, self._t_last)
        dropped = self.stats().dropped
        if dropped != self._dropped_logged and self._t_last:
            self._dropped_logged = dropped
            self._scene.set_time(self._t_last)
            self._rec.log(ent.VIZ_DROPPED, rr.Scalars([float(dropped)]))
        if not final:
            # cut the SDK's row batches here too, so chunks follow device time whatever the
            # replay speed (one batch spanning minutes of a fast replay confuses the viewer)
            self._rec.flush(timeout_sec=0.0)
