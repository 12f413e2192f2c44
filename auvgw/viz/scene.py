"""What the Rerun logger's views share on its logging thread: the recording and its time, the
batched streams, the map (its frame, tracks, colours, metre grid and legend), the depth scale,
the vehicle frame and the layout.

One :class:`Scene` is made per :class:`~auvgw.viz.logger.RerunLogger` and handed to every view
(:mod:`auvgw.viz.views`); it is touched only by the logging thread. Frames and units as in
:mod:`auvgw.viz.logger`: map positions in metres (``ned``: x north, y east; ``xy``: x right,
y up), the 2-D map storing ``(east, -north)`` (``xy``: ``(x, -y)``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike

from auvgw.ground.geometry import TWO_PI, quaternion_zyx
from auvgw.viz import entities as ent
from auvgw.viz.blueprint import DEFAULT_TRACKS, default_blueprint
from auvgw.viz.entities import TIMELINE
from auvgw.viz.options import VizOptions

__all__ = [
    "ACOUSTIC_COLOUR",
    "Row",
    "Scene",
    "Vehicle",
    "attitude_quaternion",
    "depth_colours",
    "ellipse_strips",
]

#: a row of a batched stream: scalars, a transform or vector, (points, colours)
Row = Sequence[float] | np.ndarray | tuple[np.ndarray, np.ndarray]

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
TRUE_FEATURES = (90, 190, 110)
#: spacings (m) of the map's metre grid: the first that draws at most 6 lines across the tracks
_GRID_STEPS = (5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0)
_PALETTE: tuple[tuple[int, int, int], ...] = (
    (80, 160, 255), (230, 80, 220), (255, 90, 90), (120, 230, 230), (200, 200, 80),
    (160, 120, 255), (255, 255, 255),
)  # fmt: skip
#: the acoustic beacon's marker (magenta)
ACOUSTIC_COLOUR = (230, 0, 230)


# -- geometry helpers (pure, also used by tests) ------------------------------------------------
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


class _Stream:
    """Rows of one entity waiting for a batched ``send_columns``."""

    __slots__ = ("first_host", "kind", "rows", "times")

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.times: list[float] = []
        self.rows: list[Row] = []
        self.first_host = 0.0  # time.monotonic() of the first pending row


@dataclass
class Vehicle:
    """The vehicle frame (``world/vehicle``): placed by the navigation track (dead reckoning,
    else truth, else the first track seen: ``source``, at ``position`` m in the map frame) and
    turned by the INS attitude once one was seen (``attitude_seen``)."""

    position: tuple[float, ...] = (0.0, 0.0, 0.0)
    source: str = ""
    attitude_seen: bool = False


class Scene:
    """The recording ``rec`` as the views see it (logging thread only): time, static styles,
    batched streams, the map frame, the tracks' colours, the map's grid and legend, the shared
    depth scale, the vehicle frame and the layout (``blueprint``: send it, grown as tracks and
    the raw-ping view appear)."""

    def __init__(self, rec: rr.RecordingStream, options: VizOptions, blueprint: bool) -> None:
        self.rec = rec
        self.options = options
        self.vehicle = Vehicle()
        #: depth colour scale (m) of soundings, the grid and SLAM seabed maps (None: from the
        #: first data)
        self.depth_range: tuple[float, float] | None = options.depth_range
        #: the tracks in order of appearance and their colours
        self.tracks: dict[str, tuple[int, int, int]] = {}
        self._streams: dict[str, _Stream] = {}
        self._styled: set[str] = set()
        self._grid_bounds: tuple[np.ndarray, np.ndarray] | None = None  # the grid's area
        self._grid_extent: tuple[np.ndarray, np.ndarray] | None = None  # of what is drawn
        self._send_blueprint = blueprint
        self._bp_tracks: list[str] = list(DEFAULT_TRACKS)
        self._bp_raw_ping = False  # the layout has the GeoSwath raw-ping view
        if blueprint:
            rec.send_blueprint(default_blueprint(self._bp_tracks))

    # -- time, styles, streams -----------------------------------------------------------------
    def set_time(self, t: float) -> None:
        """Put the next :meth:`rr.RecordingStream.log` at device time ``t`` (s)."""
        if self.options.time_kind == "timestamp":
            self.rec.set_time(TIMELINE, timestamp=t)
        else:
            self.rec.set_time(TIMELINE, duration=t)

    def _time_column(self, times: Sequence[float]) -> rr.TimeColumn:
        arr = np.asarray(times, dtype=np.float64)
        if self.options.time_kind == "timestamp":
            return rr.TimeColumn(TIMELINE, timestamp=arr)
        return rr.TimeColumn(TIMELINE, duration=arr)

    def static(
        self, path: str, make: Callable[[], rr.AsComponents | tuple[rr.AsComponents, ...]]
    ) -> None:
        """Log ``make()`` (archetypes: styles, series names) once per entity, as static data."""
        if path not in self._styled:
            self._styled.add(path)
            made = make()
            self.rec.log(path, *(made if isinstance(made, tuple) else (made,)), static=True)

    def append(self, path: str, kind: str, t: float, row: Row) -> None:
        """One row at ``t`` of the batched stream ``path`` (``kind``: ``scalars``, ``transform``
        (x, y, z, qx, qy, qz, qw), ``arrows3`` or ``points3`` (points, colours))."""
        s = self._streams.get(path)
        if s is None:
            s = self._streams[path] = _Stream(kind)
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
            points = [r for r in rows if isinstance(r, tuple)]
            pos = np.concatenate([r[0] for r in points]).astype(np.float32)
            col = np.concatenate([r[1] for r in points])
            cols = rr.Points3D.columns(positions=pos, colors=col).partition(
                [len(r[0]) for r in points]
            )
        else:  # pragma: no cover - kinds are internal
            raise ValueError(f"unknown stream kind {s.kind}")
        self.rec.send_columns(path, indexes=index, columns=cols)

    def send_streams(self, final: bool, t_last: float) -> None:
        """Send the streams that are due (all with ``final``): enough rows, or the oldest row
        ``max_latency_s`` behind ``t_last`` (the newest data time, s) or the host clock."""
        o = self.options
        now = time.monotonic()
        for path, s in self._streams.items():
            if s.rows and (
                final
                or len(s.rows) >= o.min_batch_rows
                or t_last - s.times[0] >= o.max_latency_s
                or now - s.first_host >= o.max_latency_s
            ):
                self._send(path, s)

    # -- the map -------------------------------------------------------------------------------
    def to_map(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Map-frame (x, y) -> 2-D view coordinates (u right, v down), stacked on the last axis."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self.options.map_frame == "ned":
            return np.stack([y, -x], axis=-1)
        return np.stack([x, -y], axis=-1)

    def ellipses(self, centres: np.ndarray, covs: np.ndarray) -> list[np.ndarray]:
        """Confidence ellipses (``ellipse_sigma``) of 2-D Gaussians, in view coordinates."""
        o = self.options
        e = ellipse_strips(centres, covs, o.ellipse_sigma, o.ellipse_vertices)
        return list(self.to_map(e[..., 0], e[..., 1]))

    def colour(self, name: str, feature: bool = False) -> tuple[int, int, int]:
        """A track's colour (``feature``: of its landmarks and lines; the true ones apart)."""
        key = ent.track_segment(name)
        if feature and key == "truth":
            return TRUE_FEATURES
        if key in _TRACK_COLOURS:
            return _TRACK_COLOURS[key]
        others = [n for n in self.tracks if ent.track_segment(n) not in _TRACK_COLOURS]
        i = others.index(name) if name in others else len(others)
        return _PALETTE[i % len(_PALETTE)]

    def add_track(self, name: str) -> tuple[int, int, int]:
        """Register track ``name`` (its colour, the layout's view of it, the legend's line);
        returns its colour."""
        colour = self.tracks[name] = self.colour(name)
        seg = ent.track_segment(name)
        if self._send_blueprint and seg not in self._bp_tracks:
            self._bp_tracks.append(seg)
            self.rec.send_blueprint(default_blueprint(self._bp_tracks, raw_ping=self._bp_raw_ping))
        return colour

    def show_raw_ping(self) -> None:
        """Add the GeoSwath raw-ping view to the layout (once)."""
        if self._send_blueprint and not self._bp_raw_ping:
            self._bp_raw_ping = True
            self.rec.send_blueprint(default_blueprint(self._bp_tracks, raw_ping=True))

    def refresh_legend(self) -> None:
        """Redraw the grid and legend over what is drawn so far (a new track joins the legend)."""
        if self._grid_extent is not None:
            self.cover(np.array(self._grid_extent), force=True)

    def cover(self, uv: np.ndarray, force: bool = False) -> None:
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
        self.rec.log(
            ent.MAP_GRID,
            rr.LineStrips2D(strips, colors=[grey], radii=[-0.75], draw_order=-20.0),
            static=True,
        )
        # the coordinates: east along the bottom edge, north along the left (v = -north)
        ticks = np.array([[u, hi[1]] for u in us[1:-1]] + [[lo[0], v] for v in vs[1:-1]])
        labels = [f"{east} {u + 0.0:.0f} m" for u in us[1:-1]]
        labels += [f"{north} {0.0 - v:.0f} m" for v in vs[1:-1]]
        self.rec.log(
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
        self.rec.log(
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
        self._legend(lo, step)

    def _legend(self, lo: np.ndarray, step: float) -> None:
        """The map's legend in its top-left corner: a short line in each track's colour (and
        the true features'), labelled with its name."""
        first = {"truth": 0, "dead_reckoning": 1}  # then the others as they came
        names = sorted(self.tracks, key=lambda n: first.get(ent.track_segment(n), 2))
        entries = [(ent.track_segment(n).replace("slam/", "SLAM ").replace("_", " "),
                    self.tracks[n]) for n in names]  # fmt: skip
        entries.append(("true features", TRUE_FEATURES))
        x0, y0, dy = lo[0] + step / 6, lo[1] + step / 6, step / 4
        strips = [np.array([[x0, y0 + i * dy], [x0 + step / 3, y0 + i * dy]])
                  for i in range(len(entries))]  # fmt: skip
        self.rec.log(
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

    # -- depth ---------------------------------------------------------------------------------
    def depth_scale(self, depth: np.ndarray) -> tuple[float, float]:
        """The depth colour range (m), set from ``depth`` (padded) when not yet known."""
        if self.depth_range is None and len(depth):
            lo, hi = float(np.min(depth)), float(np.max(depth))
            pad = max(1.0, 0.5 * (hi - lo))
            self.depth_range = (lo - pad, hi + pad)
        return self.depth_range or (0.0, 1.0)
