"""The 2-D map and 3-D scene's views: trajectories, point and line features, particle clouds,
beacon ranges and the acoustic beacon (map frame metres, headings in rad; see
:mod:`auvgw.viz.scene`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from auvgw.viz import entities as ent
from auvgw.viz.scene import ACOUSTIC_COLOUR, Scene, attitude_quaternion
from auvgw.viz.views.base import View

__all__ = ["AcousticBeacon", "Landmarks", "Lines", "Particles", "Ranges", "Trajectory"]

#: line width (px) and draw order of the well-known tracks: the truth widest and underneath,
#: so three tracks on top of each other all show; others (SLAM) thinnest, on top
_TRACK_STYLE: dict[str, tuple[float, float]] = {"truth": (4.0, 28.0), "dead_reckoning": (2.5, 30.0)}
_TRACK_STYLE_OTHER = (1.5, 32.0)
#: which trajectory places the vehicle frame (lowest first; others rank 2)
_RANK: dict[str, int] = {"dead_reckoning": 0, "truth": 1}


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


class Trajectory(View):
    """Trajectory ``name``: a growing line strip on ``map/<name>/track`` and
    ``world/<name>/track`` (vertices ``track_min_step_m`` apart) and the current pose (point,
    heading arrow, 2-sigma ellipse) on ``map/<name>/pose``, sent every ``flush_period_s`` of
    device time; the navigation track places the vehicle frame until an attitude is seen."""

    kind = "trajectory"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._tracks: dict[str, _Track] = {}

    def _track(self, name: str) -> _Track:
        tr = self._tracks.get(name)
        if tr is None:
            sc = self.scene
            colour = sc.add_track(name)
            tr = self._tracks[name] = _Track(colour)
            seg = ent.track_segment(name)
            log_static = sc.rec.log
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
            sc.refresh_legend()  # the legend names the new track
            log_static(
                ent.map_path(name, "pose"),
                rr.Points2D.from_fields(colors=[colour], radii=[-5.0], draw_order=40.0),
                rr.Arrows2D.from_fields(colors=[colour], draw_order=40.0),
                rr.LineStrips2D.from_fields(colors=[colour], radii=[-1.0], draw_order=35.0),
                static=True,
            )
        return tr

    def log(
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
        vehicle = self.scene.vehicle
        if not vehicle.source or _RANK.get(seg, 2) <= _RANK.get(vehicle.source, 2):
            vehicle.source = seg
        if seg == vehicle.source:
            vehicle.position = p

    def flush(self, final: bool, t_last: float) -> None:
        for name, tr in self._tracks.items():
            self._flush_track(name, tr)

    def _flush_track(self, name: str, tr: _Track) -> None:
        sc = self.scene
        if tr.latest is not None:
            tr.flushed_t = tr.latest[0]
        if tr.pending:
            pts = ([tr.last_sent] if tr.last_sent is not None else []) + tr.pending
            if len(pts) >= 2:
                arr = np.asarray(pts)
                sc.set_time(tr.pending_t)
                uv = sc.to_map(arr[:, 0], arr[:, 1])
                sc.rec.log(ent.map_path(name, "track"), rr.LineStrips2D([uv]))
                sc.cover(uv)
                sc.rec.log(ent.world_path(name, "track"), rr.LineStrips3D([arr]))
                tr.last_sent = tr.pending[-1]
                tr.pending = []
        if tr.pose_dirty and tr.latest is not None:
            tr.pose_dirty = False
            t, x, y, z, heading, cov = tr.latest
            sc.set_time(t)
            uv = sc.to_map(x, y)
            arrows: list[np.ndarray] = []
            if not math.isnan(heading):
                arrows = [
                    sc.to_map(math.cos(heading), math.sin(heading)) * self.options.pose_arrow_m
                ]
            strips: list[np.ndarray] = []
            if cov is not None and np.all(np.isfinite(cov)):
                strips = sc.ellipses(np.array([[x, y]]), cov[None])
            # position, heading arrow and 2-sigma ellipse on one entity (one chunk per flush)
            sc.rec.log(
                ent.map_path(name, "pose"),
                rr.Points2D([uv]),
                rr.Arrows2D(origins=[uv] * len(arrows), vectors=arrows),
                rr.LineStrips2D(strips),
            )
            vehicle = sc.vehicle
            if not vehicle.attitude_seen and ent.track_segment(name) == vehicle.source:
                q = attitude_quaternion(0.0, 0.0, 0.0 if math.isnan(heading) else heading)
                tf = rr.Transform3D(translation=[x, y, z], quaternion=rr.Quaternion(xyzw=q))
                sc.rec.log(ent.VEHICLE, tf)


class Landmarks(View):
    """Point features of map ``name`` on ``map/<name>/landmarks``: points labelled with their
    ids (shown up to 40) and their confidence ellipses; the true ones widen the map's grid."""

    kind = "landmarks"

    def log(
        self, name: str, t: float, mean: np.ndarray, cov: np.ndarray | None, ids: np.ndarray | None
    ) -> None:
        sc = self.scene
        colour = sc.colour(name, feature=True)
        sc.set_time(t)
        labels = None if ids is None else [str(i) for i in ids]
        if len(mean) and ent.track_segment(name) == "truth":  # estimates may stray far
            sc.cover(sc.to_map(mean[:, 0], mean[:, 1]))
        # the points and their confidence ellipses on one entity (one chunk per flush)
        sc.rec.log(
            ent.map_path(name, "landmarks"),
            rr.Points2D(
                sc.to_map(mean[:, 0], mean[:, 1]),
                colors=[colour],
                radii=[-4.0],
                labels=labels,
                show_labels=labels is not None and len(labels) <= 40,
                draw_order=45.0,
            ),
            rr.LineStrips2D(
                [] if cov is None else sc.ellipses(mean, cov), colors=[colour], radii=[-1.0]
            ),
        )


class Lines(View):
    """Line features of map ``name`` (normal form rho, theta) on ``map/<name>/lines`` (their
    end points, else ``line_half_length_m`` either side of the foot point) and the foot points'
    ellipses on ``map/<name>/line_cov``."""

    kind = "lines"

    def log(
        self,
        name: str,
        t: float,
        rho: np.ndarray,
        theta: np.ndarray,
        cov: np.ndarray | None,
        endpoints: np.ndarray | None,
    ) -> None:
        sc = self.scene
        colour = sc.colour(name, feature=True)
        n = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        foot = rho[:, None] * n
        if endpoints is not None and len(endpoints) == len(rho):
            seg = endpoints
        else:
            d = np.stack([-n[:, 1], n[:, 0]], axis=-1) * self.options.line_half_length_m
            seg = np.stack([foot - d, foot + d], axis=1)
        sc.set_time(t)
        if len(seg) and ent.track_segment(name) == "truth":
            sc.cover(sc.to_map(seg[..., 0], seg[..., 1]).reshape(-1, 2))
        sc.rec.log(
            ent.map_path(name, "lines"),
            rr.LineStrips2D(
                list(sc.to_map(seg[..., 0], seg[..., 1])), colors=[colour], radii=[-2.0]
            ),
        )
        if cov is not None and len(cov) == len(rho):
            c, s = n[:, 0], n[:, 1]
            jac = np.empty((len(rho), 2, 2))
            jac[:, 0, 0], jac[:, 0, 1] = c, -rho * s
            jac[:, 1, 0], jac[:, 1, 1] = s, rho * c
            cxy = jac @ cov @ np.transpose(jac, (0, 2, 1))
            sc.rec.log(
                ent.map_path(name, "line_cov"),
                rr.LineStrips2D(sc.ellipses(foot, cxy), colors=[colour], radii=[-1.0]),
            )


class Particles(View):
    """A filter's particle cloud on ``map/<name>/particles`` (in its track's colour)."""

    kind = "particles"

    def log(self, name: str, t: float, p: np.ndarray) -> None:
        sc = self.scene
        sc.set_time(t)
        sc.rec.log(
            ent.map_path(name, "particles"),
            rr.Points2D(
                sc.to_map(p[:, 0], p[:, 1]),
                colors=[sc.colour(name)],
                radii=[-1.5],
                draw_order=20.0,
            ),
        )


class Ranges(View):
    """Beacon observations of ``name`` on ``map/<name>/ranges``: one line from the vehicle to
    each observed beacon (replacing the previous set)."""

    kind = "ranges"

    def log(self, name: str, t: float, origin: np.ndarray, targets: np.ndarray) -> None:
        sc = self.scene
        sc.set_time(t)
        seg = np.stack([np.broadcast_to(origin, targets.shape), targets], axis=1)
        sc.rec.log(
            ent.map_path(name, "ranges"),
            rr.LineStrips2D(list(sc.to_map(seg[..., 0], seg[..., 1])),
                            colors=[sc.colour(name)], radii=[-1.0], draw_order=25.0),
        )  # fmt: skip


class AcousticBeacon(View):
    """The acoustic beacon of map ``name`` (a known position) on
    ``map/<name>/acoustic_beacon``."""

    kind = "acoustic_beacon"

    def log(self, name: str, t: float, x: float, y: float) -> None:
        sc = self.scene
        sc.set_time(t)
        sc.rec.log(
            ent.map_path(name, "acoustic_beacon"),
            rr.Points2D(sc.to_map([x], [y]), colors=[ACOUSTIC_COLOUR], radii=[-7.0],
                        labels=["acoustic beacon"], draw_order=50.0),
        )  # fmt: skip
