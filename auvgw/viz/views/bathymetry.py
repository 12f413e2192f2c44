"""The seabed's views: multibeam soundings and their grid, a SLAM pipeline's seabed points and
DEM tiles (depths in m, down; positions in the map frame, m), on one depth colour scale."""

from __future__ import annotations

import itertools
import math

import numpy as np
import rerun as rr

from auvgw.viz import entities as ent
from auvgw.viz.scene import Scene, depth_colours
from auvgw.viz.views.base import View

__all__ = ["Dem", "Seabed", "Swath"]


def _disc_m(across: np.ndarray) -> float:
    """Radius (m) of a sounding's disc: 0.75 x the median spacing of one swath's beams (so
    neighbours overlap), at least 5 cm."""
    a = np.sort(np.asarray(across, dtype=np.float64)[np.isfinite(across)])
    gap = float(np.median(np.diff(a))) if len(a) > 2 else 0.1
    return max(0.05, 0.75 * gap)


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


class Swath(View):
    """Multibeam pings: depth-coloured soundings on ``world/multibeam/soundings`` (discs sized
    to the beams' spacing), the depth colour scale beside the first swath, the gridded mean
    depth on ``map/bathymetry`` (cells updated every ``bathy_period_s``) and, at the end, the
    mean depth image ``bathymetry/mean_depth``."""

    kind = "swath"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._grid = _Grid(self.options.bathy_cell_m, self.options.bathy_max_cells)
        self._logged_t = -math.inf
        self._t = 0.0
        self._scale_logged = False

    def log(
        self,
        t: float,
        along: np.ndarray,
        across: np.ndarray,
        depth: np.ndarray,
        pose: tuple[float, float, float, float],
    ) -> None:
        if not len(depth):
            return
        sc = self.scene
        x0, y0, z0, h = pose
        ch, sh = math.cos(h), math.sin(h)
        if self.options.map_frame == "ned":  # along = forward, across = starboard
            xs = x0 + along * ch - across * sh
            ys = y0 + along * sh + across * ch
        else:  # x right, y up, heading counter-clockwise: starboard is to the right
            xs = x0 + along * ch + across * sh
            ys = y0 + along * sh - across * ch
        zs = z0 + depth
        lo, hi = sc.depth_scale(zs)
        if not self._scale_logged:
            width = float(np.nanmax(across) - np.nanmin(across)) if len(across) > 1 else 40.0
            self._depth_scale(x0, y0, lo, hi, max(20.0, 0.5 * width))
        colours = depth_colours(zs, lo, hi)
        # discs in metres, sized to the beams' spacing: screen-sized ones left gaps where the
        # spacing was wider (a white band along the swath, issue 33)
        sc.static(ent.SOUNDINGS, lambda: rr.Points3D.from_fields(radii=[_disc_m(across)]))
        sc.append(ent.SOUNDINGS, "points3", t, (np.column_stack([xs, ys, zs]), colours))
        uv = sc.to_map(xs, ys)
        self._grid.add(uv[:, 0], uv[:, 1], zs)
        self._t = t
        if t - self._logged_t >= self.options.bathy_period_s:
            self._log_grid(t)

    def flush(self, final: bool, t_last: float) -> None:
        if final and self._grid.counts.size:
            self._log_grid(self._t, final=True)

    def _depth_scale(self, x: float, y: float, lo: float, hi: float, length: float) -> None:
        """The depth colour scale in the 3-D view (static): a bar ``length`` m long in depth
        colours from ``lo`` to ``hi`` m, lying at ``hi`` m from 10 m behind the first swath's
        place (``x``, ``y`` in the map frame) backwards, the depths labelled along it."""
        self._scale_logged = True
        rec = self.scene.rec
        frac = np.linspace(0.0, 1.0, 21)
        px = x - 10.0 - frac * length
        segs = [np.array([[a, y, hi], [b, y, hi]]) for a, b in itertools.pairwise(px)]
        mids = lo + (hi - lo) * 0.5 * (frac[:-1] + frac[1:])
        rec.log(
            ent.DEPTH_SCALE,
            rr.LineStrips3D(segs, colors=depth_colours(mids, lo, hi), radii=[-6.0]),
            static=True,
        )
        tf = np.linspace(0.0, 1.0, 5)
        ticks = lo + (hi - lo) * tf
        rec.log(
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
        sc = self.scene
        u, v, mean = self._grid.take_touched()
        lo, hi = sc.depth_range or (0.0, 1.0)
        sc.set_time(t)
        if len(u):
            sc.rec.log(
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
            sc.rec.log(
                ent.MEAN_DEPTH,
                rr.DepthImage(img, meter=1.0, colormap="turbo", depth_range=(lo, hi)),
                rr.Transform3D(translation=[u0, v0, 0.0], scale=self._grid.cell),
            )
        self._logged_t = t


class Seabed(View):
    """Soundings placed by a SLAM trajectory on ``world/<name>/seabed`` (depth-coloured 3-D
    points, accumulated)."""

    kind = "seabed"

    def log(self, name: str, t: float, pts: np.ndarray) -> None:
        if not len(pts):
            return
        sc = self.scene
        path = ent.world_path(name, "seabed")
        sc.static(path, lambda: rr.Points3D.from_fields(radii=[-2.0]))
        lo, hi = sc.depth_scale(pts[:, 2])
        sc.append(path, "points3", t, (pts, depth_colours(pts[:, 2], lo, hi)))


class Dem(View):
    """A SLAM map's DEM tile on ``map/<name>/dem`` (depth-coloured discs, each tile replacing
    the last)."""

    kind = "dem"

    def log(self, name: str, t: float, x0: float, y0: float, cell: float, grid: np.ndarray) -> None:
        i, j = np.nonzero(np.isfinite(grid))
        if not len(i):
            return
        sc = self.scene
        uv = sc.to_map(x0 + (i + 0.5) * cell, y0 + (j + 0.5) * cell)
        depth = grid[i, j]
        lo, hi = sc.depth_scale(depth)
        sc.set_time(t)
        sc.rec.log(
            ent.map_path(name, "dem"),
            rr.Points2D(uv, colors=depth_colours(depth, lo, hi), radii=[0.6 * cell],
                        draw_order=-5.0),
        )  # fmt: skip
