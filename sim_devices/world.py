"""The simulated world: seabed, sonar targets, magnetic and acoustic beacons, water.

Frames and units follow :mod:`auvgw.config.scenario`: a local NED frame in metres (``x`` north,
``y`` east, ``z`` down), headings in radians from north towards east, magnetic fields in tesla
(NED components). Everything is pure numpy and vectorised; nothing here holds a clock or a port.

* :class:`FlatTerrain`, :class:`ProceduralTerrain`, :class:`GridTerrain`: seabed depth
  ``z(x, y)`` (positive down) and its gradient, for arrays of any shape.
* :func:`cast_rays`: horizontal rays against line segments (walls, piers) and point features
  (circles of a radius), the first hit per ray with its range and incidence angle: the MSIS beam.
* :func:`first_crossing`: straight rays against the terrain, the slant range to the first
  crossing of each (the DVL's beams, the multibeam's fan).
* :func:`cast_swath`: a fan of beams across track intersected with the terrain: depth, across,
  along per beam, GeoSwath-like (swath up to ``swath_factor`` x altitude, port and starboard).
* :func:`dipole_field`: the field of magnetic dipoles, ``B = mu0/(4 pi) (3 (m.r^) r^ - m) / r^3``.
* :class:`World`: all of the above built from a :class:`~auvgw.config.scenario.Scenario`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from auvgw.config.scenario import ObservationSettings, Scenario, ScenarioError, Terrain
from auvgw.ground.geometry import body_to_ned_matrix as body_to_ned  # (heading, pitch, roll) -> R
from auvgw.ground.geometry import wrap_angles as wrap_angle  # arrays in, arrays out

__all__ = [
    "MU0_OVER_4PI",
    "FlatTerrain",
    "GridTerrain",
    "MixedTerrain",
    "ProceduralTerrain",
    "RayHits",
    "SandWaveField",
    "SandWaveTerrain",
    "Swath",
    "SwathGeometry",
    "TerrainModel",
    "World",
    "body_to_ned",
    "cast_rays",
    "cast_swath",
    "dipole_field",
    "first_crossing",
    "terrain_from_settings",
    "wrap_angle",
]

#: mu0 / (4 pi) in T m / A
MU0_OVER_4PI = 1e-7

FArray = np.ndarray
#: a seabed depth function of (x, y), metres
DepthFn = Callable[[FArray, FArray], FArray]


# -- terrain ---------------------------------------------------------------------------------


class TerrainModel:
    """Seabed depth below the surface, metres (positive down), as a function of (x, y)."""

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        """Seabed depth at (x north, y east), metres, broadcast over array inputs."""
        raise NotImplementedError

    def gradient(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        """(dz/dx, dz/dy) of the seabed depth, dimensionless, broadcast over array inputs."""
        raise NotImplementedError

    #: the largest error of :meth:`depth_coarse`, metres
    coarse_tol_m: float = 0.0

    def depth_coarse(self, x: FArray | float, y: FArray | float) -> FArray:
        """:meth:`depth` to within :attr:`coarse_tol_m` metres, possibly cheaper: what
        :func:`first_crossing` samples a ray with before it refines the crossing exactly."""
        return self.depth(x, y)

    def gradient_coarse(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        """:meth:`gradient`, possibly cheaper and less precise (an emulated amplitude's
        incidence angle); relative error about ``coarse_tol_m`` / the relief."""
        return self.gradient(x, y)

    @property
    def bounds(self) -> tuple[float, float]:
        """(shallowest, deepest) seabed depth anywhere, metres."""
        raise NotImplementedError


@dataclass(frozen=True)
class FlatTerrain(TerrainModel):
    """A flat seabed at ``depth_m``."""

    depth_m: float

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, float(self.depth_m))

    def gradient(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        shape = np.broadcast(np.asarray(x), np.asarray(y)).shape
        return np.zeros(shape), np.zeros(shape)

    @property
    def bounds(self) -> tuple[float, float]:
        return (float(self.depth_m), float(self.depth_m))


class ProceduralTerrain(TerrainModel):
    """``depth_m`` plus a seeded sum of plane sinusoids (6 per octave).

    Octave ``o`` has wavelengths around ``wavelength_m / 2**o`` (jittered 0.7-1.4x), random
    directions and phases, and amplitude weight ``0.5**o``; all amplitudes are scaled so their
    absolute sum is ``relief_m``, hence the depth stays within ``depth_m +- relief_m``.
    """

    PER_OCTAVE = 6

    def __init__(
        self, depth_m: float, relief_m: float, wavelength_m: float, seed: int, octaves: int = 1
    ) -> None:
        rng = np.random.default_rng(seed)
        n = self.PER_OCTAVE * octaves
        octave = np.repeat(np.arange(octaves), self.PER_OCTAVE)
        lam = wavelength_m / 2.0**octave * rng.uniform(0.7, 1.4, n)
        theta = rng.uniform(0.0, math.pi, n)
        self.kx = 2 * math.pi / lam * np.cos(theta)
        self.ky = 2 * math.pi / lam * np.sin(theta)
        self.phase = rng.uniform(0.0, 2 * math.pi, n)
        self._kmat = np.stack([self.kx, self.ky, self.phase])  # (3, K)
        weights = 0.5**octave
        self.amp = relief_m * weights / weights.sum()
        self.depth_m = float(depth_m)
        self.relief_m = float(relief_m)

    def _arg(self, x: FArray, y: FArray) -> FArray:
        """Phases of every component at every point: (..., K), one matrix product."""
        xy1 = np.stack([x, y, np.ones_like(x)], axis=-1)
        return xy1 @ self._kmat

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        return self.depth_m + np.sin(self._arg(x, y)) @ self.amp

    def gradient(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        c = np.cos(self._arg(x, y))
        return c @ (self.amp * self.kx), c @ (self.amp * self.ky)

    #: single precision (phases of up to ~1e4 rad, x and y within ~10 km, carry ~1e-3 rad of
    #: rounding, times at most ``relief_m`` of amplitude; measured: 2e-5 m within 1 km)
    coarse_tol_m = 0.01

    def _arg32(self, x: FArray | float, y: FArray | float) -> FArray:
        """:meth:`_arg` in single precision."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        xy1 = np.empty((*x.shape, 3), np.float32)
        xy1[..., 0], xy1[..., 1], xy1[..., 2] = x, y, 1.0
        return xy1 @ self._kmat.astype(np.float32)

    def depth_coarse(self, x: FArray | float, y: FArray | float) -> FArray:
        """:meth:`depth` in single precision (numpy's float32 sine is vectorised: about 30x
        the float64 one here), within :attr:`coarse_tol_m`."""
        arg = self._arg32(x, y)
        return self.depth_m + (np.sin(arg, out=arg) @ self.amp.astype(np.float32)).astype(float)

    def gradient_coarse(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        """:meth:`gradient` in single precision (relative error ~1e-3 within 10 km)."""
        arg = self._arg32(x, y)
        c = np.cos(arg, out=arg)
        gx = c @ (self.amp * self.kx).astype(np.float32)
        return gx.astype(float), (c @ (self.amp * self.ky).astype(np.float32)).astype(float)

    @property
    def bounds(self) -> tuple[float, float]:
        return (self.depth_m - self.relief_m, self.depth_m + self.relief_m)


class GridTerrain(TerrainModel):
    """A depth grid, bilinear between nodes, clamped to the edge values outside.

    ``grid[i, j]`` is the depth at ``x = origin[0] + i cell_m``, ``y = origin[1] + j cell_m``.
    """

    def __init__(self, grid: FArray, cell_m: float, origin: tuple[float, float] = (0, 0)) -> None:
        g = np.asarray(grid, dtype=float)
        if g.ndim != 2 or min(g.shape) < 2:
            raise ValueError(f"depth grid must be 2-D with at least 2x2 nodes, got {g.shape}")
        if not np.all(np.isfinite(g)) or np.any(g <= 0):
            raise ValueError("depth grid must be finite and positive (metres below the surface)")
        self.grid = g
        self.cell_m = float(cell_m)
        self.origin = (float(origin[0]), float(origin[1]))
        self._gx, self._gy = np.gradient(g, self.cell_m)

    def _interp(self, table: FArray, x: FArray | float, y: FArray | float) -> FArray:
        n, m = table.shape
        fi = np.clip((np.asarray(x, float) - self.origin[0]) / self.cell_m, 0, n - 1)
        fj = np.clip((np.asarray(y, float) - self.origin[1]) / self.cell_m, 0, m - 1)
        i0 = np.minimum(np.floor(fi).astype(int), n - 2)
        j0 = np.minimum(np.floor(fj).astype(int), m - 2)
        ti, tj = fi - i0, fj - j0
        return (
            table[i0, j0] * (1 - ti) * (1 - tj)
            + table[i0 + 1, j0] * ti * (1 - tj)
            + table[i0, j0 + 1] * (1 - ti) * tj
            + table[i0 + 1, j0 + 1] * ti * tj
        )

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        return self._interp(self.grid, x, y)

    def gradient(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        return self._interp(self._gx, x, y), self._interp(self._gy, x, y)

    @property
    def bounds(self) -> tuple[float, float]:
        return (float(self.grid.min()), float(self.grid.max()))


class _NumericGradient(TerrainModel):
    """Central-difference gradient for terrains defined by a depth formula only."""

    GRAD_STEP_M = 0.05

    def gradient(self, x: FArray | float, y: FArray | float) -> tuple[FArray, FArray]:
        h = self.GRAD_STEP_M
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        gx = (self.depth(x + h, y) - self.depth(x - h, y)) / (2 * h)
        gy = (self.depth(x, y + h) - self.depth(x, y - h)) / (2 * h)
        return gx, gy


class MixedTerrain(_NumericGradient):
    """Varied relief for bathymetric SLAM: flat patches, rough ground, ridges and mounds.

    depth = ``depth_m`` + mask(x, y) * procedural(relief_m, wavelength_m, octaves)
    + ridges + mounds. ``mask`` is a smooth 0..1 field (three long waves of 4 x wavelength_m
    through a steep logistic) that is 0 on about ``flat_fraction`` of the area: flat patches with
    no information. Ridges (``n_ridges``, height ``relief_m``, 1/e half-width 25 m) run along
    random directions, mounds (``n_mounds``, height ``relief_m``, sigma 15-40 m) sit at random
    points of ``extent_m`` = (x_min, x_max, y_min, y_max); both are masked like the relief, so
    flat patches stay flat. ``sand_fields`` (:class:`SandWaveField`) replace all of that inside
    their extent with sand waves on a flat bed. Metres, positive down; everything seeded by
    ``seed``.
    """

    def __init__(
        self,
        depth_m: float,
        relief_m: float,
        wavelength_m: float,
        seed: int,
        octaves: int = 3,
        flat_fraction: float = 0.3,
        n_ridges: int = 3,
        n_mounds: int = 12,
        extent_m: tuple[float, float, float, float] = (-200.0, 1000.0, -200.0, 1000.0),
        sand_fields: tuple[SandWaveField, ...] = (),
    ) -> None:
        rng = np.random.default_rng([seed, 1])
        self.sand_fields = tuple(sand_fields)
        self.rough = ProceduralTerrain(0.0, relief_m, wavelength_m, seed, octaves)
        self.mask_field = ProceduralTerrain(0.0, 1.0, 4.0 * wavelength_m, seed + 7, 1)
        # threshold of the logistic so that ~flat_fraction of the mask field is below it
        probe = self.mask_field.depth(*rng.uniform(-5e3, 5e3, (2, 4000)))
        self.mask_at = float(np.quantile(probe, flat_fraction))
        x0, x1, y0, y1 = extent_m
        self.ridge_pt = np.column_stack(
            [rng.uniform(x0, x1, n_ridges), rng.uniform(y0, y1, n_ridges)]
        )
        a = rng.uniform(0, math.pi, n_ridges)
        self.ridge_n = np.column_stack([-np.sin(a), np.cos(a)])  # unit normals
        self.mound_pt = np.column_stack(
            [rng.uniform(x0, x1, n_mounds), rng.uniform(y0, y1, n_mounds)]
        )
        self.mound_sigma = rng.uniform(15.0, 40.0, n_mounds)
        self.mound_sign = rng.choice([-1.0, 1.0], n_mounds)
        self.depth_m = float(depth_m)
        self.relief_m = float(relief_m)

    def mask(self, x: FArray | float, y: FArray | float) -> FArray:
        """0 on flat patches, 1 on rough ground, smooth between."""
        m = self.mask_field.depth(x, y)
        return 1.0 / (1.0 + np.exp(-12.0 * (m - self.mask_at)))

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        xy = np.stack([x, y], axis=-1)
        dist = np.einsum("...kj,kj->...k", xy[..., None, :] - self.ridge_pt, self.ridge_n)
        ridges = np.exp(-((dist / 25.0) ** 2)).sum(-1)
        d2 = ((xy[..., None, :] - self.mound_pt) ** 2).sum(-1)
        mounds = (self.mound_sign * np.exp(-d2 / (2 * self.mound_sigma**2))).sum(-1)
        relief = self.rough.depth(x, y) - self.relief_m * (ridges + mounds)
        out = self.mask(x, y) * relief
        for f in self.sand_fields:  # each field replaces what lies under it
            w = f.window(x, y)
            out = out * (1.0 - w) + w * (f.waves.depth(x, y) - f.waves.depth_m)
        return self.depth_m + out

    @property
    def bounds(self) -> tuple[float, float]:
        r = max([3 * self.relief_m] + [f.waves.relief_m for f in self.sand_fields])
        return (self.depth_m - r, self.depth_m + r)


class SandWaveTerrain(_NumericGradient):
    """Self-similar sand waves: ``depth_m`` + ``relief_m`` x a sine of ``wavelength_m`` across
    ``direction_rad`` (from north towards east), crests slightly wavy (5 % of the wavelength over
    8 wavelengths along the crest), amplitude modulated +-20 % over 10 wavelengths. Any shift by
    a wavelength across the crests, or along them, matches almost as well as the truth: the
    terrain of false loop closures. Metres, positive down."""

    def __init__(
        self, depth_m: float, relief_m: float, wavelength_m: float, direction_rad: float, seed: int
    ) -> None:
        rng = np.random.default_rng([seed, 2])
        self.depth_m, self.relief_m, self.lam = float(depth_m), float(relief_m), float(wavelength_m)
        self.n = np.array([math.cos(direction_rad), math.sin(direction_rad)])
        self.phase = rng.uniform(0, 2 * math.pi, 3)

    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        s = x * self.n[0] + y * self.n[1]  # across crests
        c = -x * self.n[1] + y * self.n[0]  # along crests
        k = 2 * math.pi / self.lam
        wav = 0.05 * self.lam * np.sin(k * c / 8 + self.phase[0])
        amp = 1.0 + 0.2 * np.sin(k * (s + c) / 10 + self.phase[1])
        return self.depth_m + self.relief_m * amp / 1.2 * np.sin(k * (s + wav) + self.phase[2])

    @property
    def bounds(self) -> tuple[float, float]:
        return (self.depth_m - self.relief_m, self.depth_m + self.relief_m)


@dataclass(frozen=True)
class SandWaveField:
    """Sand waves on a flat sandy bed inside ``extent_m`` = (x_min, x_max, y_min, y_max) of a
    :class:`MixedTerrain`: its ``window`` is 1 inside, 0 outside, a smooth logistic fade of
    about ``edge_m`` at the borders; ``waves`` gives the seabed there. Metres, NED."""

    waves: SandWaveTerrain
    extent_m: tuple[float, float, float, float]
    edge_m: float = 20.0

    def window(self, x: FArray, y: FArray) -> FArray:
        """1 inside the field, 0 outside, smooth over ``edge_m`` (the 12-88 % rise)."""
        x0, x1, y0, y1 = self.extent_m
        k = 4.0 / self.edge_m
        inside = np.minimum(np.minimum(x - x0, x1 - x), np.minimum(y - y0, y1 - y))
        return 1.0 / (1.0 + np.exp(-k * inside))


#: the largest terrain grid file read (bytes): 64 MiB, 8 M cells of float64
MAX_GRID_BYTES = 1 << 26


def _load_grid(path: Path) -> FArray:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ScenarioError(f"terrain.file {path}: cannot read a depth grid: {exc}") from exc
    if size > MAX_GRID_BYTES:
        raise ScenarioError(
            f"terrain.file {path}: too large for a depth grid (over {MAX_GRID_BYTES} bytes)"
        )
    try:
        if path.suffix == ".npy":
            return np.load(path, allow_pickle=False)
        return np.asarray(json.loads(path.read_text()), dtype=float)
    except (OSError, ValueError, TypeError) as exc:
        raise ScenarioError(f"terrain.file {path}: cannot read a depth grid: {exc}") from exc


#: terrain kind -> its model and the ``Terrain`` settings passed to it by keyword (sandwaves takes
#: its direction in radians, a grid its file: both below)
_TERRAINS: dict[str, tuple[Callable[..., TerrainModel], tuple[str, ...]]] = {
    "flat": (FlatTerrain, ("depth_m",)),
    "procedural": (ProceduralTerrain, ("depth_m", "relief_m", "wavelength_m", "seed", "octaves")),
    "mixed": (MixedTerrain, ("depth_m", "relief_m", "wavelength_m", "seed", "octaves",
                             "flat_fraction", "n_ridges", "n_mounds", "extent_m")),
}  # fmt: skip


def terrain_from_settings(settings: Terrain, resolve: Callable[[str], Path] = Path) -> TerrainModel:
    """The terrain model a scenario's ``terrain`` section describes (``resolve`` finds files)."""
    if settings.kind in _TERRAINS:
        model, names = _TERRAINS[settings.kind]
        kwargs = {name: getattr(settings, name) for name in names}
        if settings.sand_fields:
            kwargs["sand_fields"] = tuple(
                SandWaveField(
                    SandWaveTerrain(
                        0.0, f.relief_m, f.wavelength_m, math.radians(f.direction_deg), f.seed
                    ),
                    f.extent_m,
                    f.edge_m,
                )
                for f in settings.sand_fields
            )
        return model(**kwargs)
    if settings.kind == "sandwaves":
        return SandWaveTerrain(
            settings.depth_m,
            settings.relief_m,
            settings.wavelength_m,
            math.radians(settings.direction_deg),
            settings.seed,
        )
    assert settings.file is not None  # the scenario model enforces it
    path = resolve(settings.file)
    grid = _load_grid(path)
    try:
        return GridTerrain(grid, settings.cell_m, settings.origin)
    except ValueError as exc:
        raise ScenarioError(f"terrain.file {path}: {exc}") from exc


# -- horizontal ray casting (MSIS) -----------------------------------------------------------


@dataclass(frozen=True)
class RayHits:
    """First hit of each ray: range (m, ``inf`` if none), incidence angle between the ray and
    the surface normal (rad, ``nan`` if none), what was hit (``kind`` 0 nothing, 1 line,
    2 point) and its index in the world's line or point list (-1 if none)."""

    range_m: FArray
    incidence: FArray
    kind: FArray
    index: FArray

    @property
    def hit(self) -> FArray:
        return self.kind > 0


def _cross(ax: FArray, ay: FArray, bx: FArray, by: FArray) -> FArray:
    return ax * by - ay * bx


def cast_rays(
    origin: tuple[float, float] | FArray,
    angles: FArray | float,
    lines: FArray,
    points: FArray,
    radius: float,
    max_range: float = math.inf,
) -> RayHits:
    """Cast horizontal rays from ``origin`` (x, y) in directions ``angles`` (rad from north
    towards east) against line segments ``lines`` (M, 4: x1, y1, x2, y2) and circles of
    ``radius`` around ``points`` (P, 2); return the first hit within ``max_range`` per ray.

    A ray starting inside a circle does not see that circle.
    """
    ang = np.atleast_1d(np.asarray(angles, float))
    ox, oy = float(origin[0]), float(origin[1])
    dx, dy = np.cos(ang)[:, None], np.sin(ang)[:, None]
    n = ang.size
    best = np.full(n, math.inf)
    inc = np.full(n, math.nan)
    kind = np.zeros(n, np.int8)
    index = np.full(n, -1, np.int64)

    lines = np.asarray(lines, float).reshape(-1, 4)
    if len(lines):
        px, py = lines[:, 0], lines[:, 1]
        ex, ey = lines[:, 2] - px, lines[:, 3] - py
        wx, wy = px - ox, py - oy
        denom = _cross(dx, dy, ex, ey)  # (n, M)
        ok = np.abs(denom) > 1e-12
        safe = np.where(ok, denom, 1.0)
        t = _cross(wx, wy, ex, ey) / safe
        s = _cross(wx, wy, dx, dy) / safe
        t = np.where(ok & (t > 1e-9) & (s >= 0.0) & (s <= 1.0), t, math.inf)
        j = np.argmin(t, axis=1)
        tj = t[np.arange(n), j]
        hit = tj < best
        best = np.where(hit, tj, best)
        elen = np.hypot(ex, ey)[j]
        cos_inc = np.abs(denom[np.arange(n), j]) / np.where(elen > 0, elen, 1.0)
        inc = np.where(hit, np.arccos(np.clip(cos_inc, 0.0, 1.0)), inc)
        kind = np.where(hit, 1, kind).astype(np.int8)
        index = np.where(hit, j, index)

    points = np.asarray(points, float).reshape(-1, 2)
    if len(points):
        fx, fy = ox - points[:, 0], oy - points[:, 1]  # (P,)
        b = dx * fx + dy * fy  # (n, P)
        c = fx * fx + fy * fy - radius * radius
        disc = b * b - c
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        t = np.where((disc >= 0) & (c > 0) & (t > 1e-9), t, math.inf)
        j = np.argmin(t, axis=1)
        tj = t[np.arange(n), j]
        hit = tj < best
        best = np.where(hit, tj, best)
        tf = np.where(hit, tj, 0.0)
        hx = ox + dx[:, 0] * tf - points[j, 0]
        hy = oy + dy[:, 0] * tf - points[j, 1]
        cos_inc = np.abs(dx[:, 0] * hx + dy[:, 0] * hy) / radius
        inc = np.where(hit, np.arccos(np.clip(cos_inc, 0.0, 1.0)), inc)
        kind = np.where(hit, 2, kind).astype(np.int8)
        index = np.where(hit, j, index)

    far = best > max_range
    return RayHits(
        range_m=np.where(far, math.inf, best),
        incidence=np.where(far, math.nan, inc),
        kind=np.where(far, 0, kind).astype(np.int8),
        index=np.where(far, -1, index),
    )


# -- multibeam swath -------------------------------------------------------------------------


@dataclass(frozen=True)
class SwathGeometry:
    """Beam layout of an interferometric (GeoSwath-like) swath across track.

    ``n_beams`` across the whole swath, from port to starboard; on a flat seabed the outermost
    beams reach ``swath_factor / 2`` times the altitude on each side (GeoSwath: up to 12x water
    depth). ``equidistant`` spaces beams evenly in across-track distance on a flat seabed (the
    interferometric bins); ``equiangular`` evenly in angle. ``nadir_gap_deg`` leaves out beams
    closer to vertical than that (interferometers resolve nadir poorly). Hits beyond
    ``max_range_m`` slant range or beyond the swath width are invalid. ``samples`` is how many
    points per beam search the seabed's depth band for the first crossing (cost grows with it;
    a crest thinner than one step at grazing incidence can be missed).
    """

    n_beams: int = 256
    swath_factor: float = 12.0
    max_range_m: float = 300.0
    spacing: Literal["equidistant", "equiangular"] = "equidistant"
    nadir_gap_deg: float = 0.0
    samples: int = 16

    def beam_angles(self) -> FArray:
        """Beam angles from the body vertical, radians, positive to starboard."""
        half = self.swath_factor / 2.0
        if self.spacing == "equidistant":
            a = np.arctan(np.linspace(-half, half, self.n_beams))
        else:
            a = np.linspace(-math.atan(half), math.atan(half), self.n_beams)
        return a[np.abs(a) >= math.radians(self.nadir_gap_deg)]


@dataclass(frozen=True)
class Swath:
    """One ping: per beam (port to starboard) the beam angle (rad, + starboard, body frame),
    ``depth`` of the hit below the transducer (m, + down), ``across`` (m, + starboard) and
    ``along`` (m, + forward) in the heading-aligned horizontal frame, slant ``range_m``,
    two-way travel time ``twtt_s`` at the world's sound speed, ``incidence`` angle on the
    seabed (rad), the hit point ``x, y, z`` (NED), ``side`` (-1 port, +1 starboard) and
    ``valid`` (NaN in the float fields where not valid)."""

    angle: FArray
    depth: FArray
    across: FArray
    along: FArray
    range_m: FArray
    twtt_s: FArray
    incidence: FArray
    x: FArray
    y: FArray
    z: FArray
    side: FArray
    valid: FArray
    altitude: float


def first_crossing(
    terrain: TerrainModel,
    position: FArray | tuple[float, float, float],
    directions: FArray,
    max_range: float,
    *,
    samples: int | None = None,
    step: float = 0.25,
    iterations: int = 12,
    tol: float = 1e-6,
    exact: bool = True,
) -> FArray:
    """Slant range (m) from ``position`` (NED, m) along each unit vector of ``directions``
    ((N, 3), NED) to its first crossing of the seabed; NaN where there is none within
    ``max_range`` m (a ray that does not point down never crosses).

    Each ray is sampled between the depths of the terrain's shallowest and deepest points, at
    ``samples`` points (or every ``step`` m, at most 4097 points), and the first bracketed
    crossing is refined by regula falsi (Illinois) until it is within ``tol`` m of the seabed
    or after ``iterations`` steps. Straight rays, no refraction; a crest thinner than one
    sampling step along the ray can be missed. The samples use the terrain's
    :meth:`~TerrainModel.depth_coarse` (the bracket found is then checked, and refined, with the
    exact depth), so a ray that touches the seabed at a sample within ``coarse_tol_m`` may be
    taken to cross there or not. ``exact=False``: the coarse depth throughout, and ``tol`` at
    least a tenth of ``coarse_tol_m``: ranges within about ``coarse_tol_m`` of the seabed (an
    emulator's rays, several times cheaper).
    """
    p = np.asarray(position, float)
    d = np.asarray(directions, float).reshape(-1, 3)
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    zmin, zmax = terrain.bounds
    down = dz > 1e-9
    dzs = np.where(down, dz, 1.0)
    s_lo = np.clip((zmin - p[2]) / dzs, 0.0, None)
    s_hi = np.clip((zmax - p[2]) / dzs, 0.0, None) * (1 + 1e-9) + 1e-6  # rounding margin
    s_hi = np.minimum(s_hi, max_range)
    s_lo = np.minimum(s_lo, s_hi)
    if samples is None:
        k = int(min(max(math.ceil(float(np.max(s_hi - s_lo, initial=0.0)) / step), 1), 4096)) + 1
    else:
        k = max(2, samples)
    s = s_lo[:, None] + (s_hi - s_lo)[:, None] * np.linspace(0.0, 1.0, k)

    def below(
        sv: FArray,
        ddx: FArray,
        ddy: FArray,
        ddz: FArray,
        depth: DepthFn = terrain.depth if exact else terrain.depth_coarse,
    ) -> FArray:
        """How far the ray point is below the seabed, m (>= 0 once the ray has hit)."""
        return p[2] + sv * ddz - depth(p[0] + sv * ddx, p[1] + sv * ddy)

    # the samples with the terrain's coarse depth (a ray's samples are most of the cost), the
    # bracket's two ends again exactly; a ray whose exact ends do not bracket a crossing (the
    # seabed within the coarse tolerance of a sample) is sampled again exactly
    g = below(s, dx[:, None], dy[:, None], dz[:, None], terrain.depth_coarse)
    crossed = g >= 0.0
    out = np.full(len(d), math.nan)
    rows = np.flatnonzero(crossed.any(axis=1) & down)
    hi = np.argmax(crossed[rows], axis=1)
    lo = np.maximum(hi - 1, 0)
    if exact and terrain.coarse_tol_m > 0 and len(rows):
        ends = np.stack([lo, hi], axis=1)
        rc = rows[:, None]
        g[rc, ends] = g_ends = below(s[rc, ends], dx[rc], dy[rc], dz[rc])
        wrong = rows[(g_ends[:, 1] < 0.0) | ((hi > 0) & (g_ends[:, 0] >= 0.0))]
        if len(wrong):
            g[wrong] = below(s[wrong], dx[wrong, None], dy[wrong, None], dz[wrong, None])
            crossed[wrong] = g[wrong] >= 0.0
            rows = np.flatnonzero(crossed.any(axis=1) & down)
            hi = np.argmax(crossed[rows], axis=1)
            lo = np.maximum(hi - 1, 0)
    if not len(rows):
        return out
    a, b = s[rows, lo], s[rows, hi]
    ga, gb = g[rows, lo], g[rows, hi]
    rx, ry, rz = dx[rows], dy[rows], dz[rows]
    side = np.zeros(len(rows), np.int8)
    if not exact:  # the coarse depth's own error is the floor
        tol = max(tol, terrain.coarse_tol_m / 10.0)
    for _ in range(iterations):
        span = gb - ga
        ok = span > 1e-12
        m = np.where(ok, a - ga * (b - a) / np.where(ok, span, 1.0), b)
        gm = below(m, rx, ry, rz)
        right = gm >= 0.0
        # Illinois: an end point kept twice in a row has its value halved
        ga = np.where(right & (side == 1), ga * 0.5, ga)
        gb = np.where(~right & (side == -1), gb * 0.5, gb)
        b, gb = np.where(right, m, b), np.where(right, gm, gb)
        a, ga = np.where(right, a, m), np.where(right, ga, gm)
        side = np.where(right, 1, -1).astype(np.int8)
        if float(np.max(np.abs(gm))) < tol:
            break
    span = gb - ga
    ok = span > 1e-12
    out[rows] = np.where(ok, a - ga * (b - a) / np.where(ok, span, 1.0), b)
    return out


def cast_swath(
    terrain: TerrainModel,
    position: FArray | tuple[float, float, float],
    heading: float,
    geometry: SwathGeometry,
    pitch: float = 0.0,
    roll: float = 0.0,
    sound_speed: float = 1500.0,
) -> Swath:
    """Intersect the swath fan of a transducer at ``position`` (NED, m) with the terrain.

    Each beam leaves in the body y-z plane at its angle from the body vertical; its first
    crossing with the seabed comes from :func:`first_crossing` with ``geometry.samples``
    points per beam. Straight rays (no refraction).
    """
    p = np.asarray(position, float)
    ang = geometry.beam_angles()
    r = body_to_ned(heading, pitch, roll)
    d = r @ np.stack([np.zeros_like(ang), np.sin(ang), np.cos(ang)])  # (3, n) unit NED
    dx, dy, dz = d
    slant = first_crossing(
        terrain, p, d.T, geometry.max_range_m, samples=geometry.samples, iterations=12
    )
    found = np.isfinite(slant)
    sh = np.where(found, slant, 0.0)  # the geometry below stays finite; invalid beams are NaN

    hx, hy, hz = p[0] + sh * dx, p[1] + sh * dy, p[2] + sh * dz
    ch, sn = math.cos(heading), math.sin(heading)
    along = (hx - p[0]) * ch + (hy - p[1]) * sn
    across = -(hx - p[0]) * sn + (hy - p[1]) * ch
    altitude = float(terrain.depth(p[0], p[1])) - p[2]
    valid = (
        found
        & (sh <= geometry.max_range_m)
        & (np.abs(across) <= geometry.swath_factor / 2.0 * max(altitude, 0.0) * (1 + 1e-9) + 1e-9)
    )
    gx, gy = terrain.gradient(hx, hy)
    nrm = np.sqrt(gx * gx + gy * gy + 1.0)
    cos_inc = np.abs(-gx * dx - gy * dy + dz) / nrm
    nan = np.where(valid, 1.0, math.nan)
    return Swath(
        angle=ang,
        depth=(hz - p[2]) * nan,
        across=across * nan,
        along=along * nan,
        range_m=sh * nan,
        twtt_s=2.0 * sh / sound_speed * nan,
        incidence=np.arccos(np.clip(cos_inc, 0.0, 1.0)) * nan,
        x=hx * nan,
        y=hy * nan,
        z=hz * nan,
        side=np.where(ang < 0, -1, 1).astype(np.int8),
        valid=valid,
        altitude=altitude,
    )


# -- magnetic dipoles ------------------------------------------------------------------------


def dipole_field(points: FArray, positions: FArray, moments: FArray) -> FArray:
    """Field of each dipole at each point, tesla, NED: shape (B, N, 3) for ``points`` (N, 3),
    dipole ``positions`` (B, 3) in metres and ``moments`` (B, 3) in A m^2.

    ``B = mu0/(4 pi) (3 (m.r^) r^ - m) / r^3``; ranges below 1 mm are clamped to 1 mm.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    pos = np.asarray(positions, float).reshape(-1, 3)
    mom = np.asarray(moments, float).reshape(-1, 3)
    rvec = pts[None, :, :] - pos[:, None, :]
    rn = np.maximum(np.linalg.norm(rvec, axis=-1, keepdims=True), 1e-3)
    rhat = rvec / rn
    mdotr = np.sum(mom[:, None, :] * rhat, axis=-1, keepdims=True)
    return MU0_OVER_4PI * (3.0 * mdotr * rhat - mom[:, None, :]) / rn**3


# -- the world -------------------------------------------------------------------------------


def _empty(n: int) -> FArray:
    return np.zeros((0, n))


@dataclass
class World:
    """The static world of a scenario (see the module docstring for frames and units).

    ``beacon_moments`` are dipole moment vectors (A m^2, NED), ``earth_field`` is in tesla.
    """

    terrain: TerrainModel = field(default_factory=lambda: FlatTerrain(50.0))
    lines: FArray = field(default_factory=lambda: _empty(4))
    points: FArray = field(default_factory=lambda: _empty(2))
    point_radius: float = 0.5
    beacon_positions: FArray = field(default_factory=lambda: _empty(3))
    beacon_moments: FArray = field(default_factory=lambda: _empty(3))
    beacon_frequencies: FArray = field(default_factory=lambda: np.zeros(0))
    earth_field: FArray = field(default_factory=lambda: np.array([20e-6, 0.0, 45e-6]))
    acoustic_beacon: FArray | None = None
    acoustic_sigma: float = 0.5
    sound_speed: float = 1500.0

    def __post_init__(self) -> None:
        self.lines = np.asarray(self.lines, float).reshape(-1, 4)
        self.points = np.asarray(self.points, float).reshape(-1, 2)
        self.beacon_positions = np.asarray(self.beacon_positions, float).reshape(-1, 3)
        self.beacon_moments = np.asarray(self.beacon_moments, float).reshape(-1, 3)
        self.beacon_frequencies = np.asarray(self.beacon_frequencies, float).reshape(-1)
        self.earth_field = np.asarray(self.earth_field, float).reshape(3)
        if self.acoustic_beacon is not None:
            self.acoustic_beacon = np.asarray(self.acoustic_beacon, float).reshape(3)
        nb = len(self.beacon_positions)
        if len(self.beacon_moments) != nb or len(self.beacon_frequencies) not in (0, nb):
            raise ValueError("beacon positions, moments and frequencies differ in number")
        if len(self.beacon_frequencies) == 0:
            self.beacon_frequencies = np.zeros(nb)

    @classmethod
    def from_scenario(cls, scn: Scenario) -> World:
        """Build the world a scenario describes (reads its points file and terrain grid)."""
        beacons = scn.magnetic_beacons
        moments = []
        for b in beacons:
            axis = np.asarray(b.axis, float)
            norm = np.linalg.norm(axis)
            if norm == 0:
                raise ScenarioError(f"{scn.source or scn.name}: a magnetic beacon axis is zero")
            moments.append(b.moment_am2 * axis / norm)
        ab = scn.acoustic_beacon
        return cls(
            terrain=terrain_from_settings(scn.terrain, scn.resolve_path),
            lines=np.asarray(scn.features.lines, float).reshape(-1, 4),
            points=np.asarray(scn.point_features(), float).reshape(-1, 2),
            point_radius=scn.features.point_radius_m,
            beacon_positions=np.array([(b.x, b.y, b.z) for b in beacons]).reshape(-1, 3),
            beacon_moments=np.asarray(moments, float).reshape(-1, 3),
            beacon_frequencies=np.array([b.frequency_hz for b in beacons], float),
            earth_field=np.asarray(scn.earth_field_nt, float) * 1e-9,
            acoustic_beacon=None if ab is None else np.array([ab.x, ab.y, ab.z]),
            acoustic_sigma=0.5 if ab is None else ab.sigma_range_m,
            sound_speed=scn.sound_speed_mps,
        )

    # seabed
    def depth(self, x: FArray | float, y: FArray | float) -> FArray:
        """Seabed depth at (x, y), metres below the surface."""
        return self.terrain.depth(x, y)

    def altitude(self, x: FArray | float, y: FArray | float, z: FArray | float) -> FArray:
        """Height above the seabed of points at depth ``z``, metres."""
        return self.terrain.depth(x, y) - np.asarray(z, float)

    def swath(
        self,
        position: FArray | tuple[float, float, float],
        heading: float,
        geometry: SwathGeometry,
        pitch: float = 0.0,
        roll: float = 0.0,
    ) -> Swath:
        """One multibeam ping from ``position`` (see :func:`cast_swath`)."""
        return cast_swath(self.terrain, position, heading, geometry, pitch, roll, self.sound_speed)

    # sonar targets
    def cast(
        self, origin: tuple[float, float] | FArray, angles: FArray | float, max_range: float
    ) -> RayHits:
        """Horizontal rays against the world's walls and point features (see
        :func:`cast_rays`)."""
        return cast_rays(origin, angles, self.lines, self.points, self.point_radius, max_range)

    def beam(
        self,
        origin: tuple[float, float] | FArray,
        bearing: float,
        width: float,
        max_range: float,
        n_rays: int = 7,
    ) -> tuple[FArray, RayHits]:
        """A horizontal beam of angular ``width`` (rad) centred on ``bearing`` (rad from north),
        sampled by ``n_rays`` rays: (ray angles, hits)."""
        angles = bearing + np.linspace(-width / 2, width / 2, n_rays)
        return angles, self.cast(origin, angles, max_range)

    def observe_points(
        self,
        pose: tuple[float, float, float] | FArray,
        max_range: float,
        field_of_view: float = 2 * math.pi,
    ) -> tuple[FArray, FArray, FArray]:
        """Point features closer than ``max_range`` and within +-``field_of_view``/2 (rad) of
        the heading of ``pose`` (x, y, heading): (indices, ranges in m, bearings in rad
        relative to the heading, clockwise positive), noise-free. Bailey's sensor sees a
        half-plane: ``field_of_view = pi``."""
        x, y, h = (float(v) for v in pose)
        dx, dy = self.points[:, 0] - x, self.points[:, 1] - y
        r = np.hypot(dx, dy)
        b = wrap_angle(np.arctan2(dy, dx) - h)
        seen = r < max_range
        if field_of_view < 2 * math.pi:
            seen &= np.abs(b) < field_of_view / 2
        idx = np.flatnonzero(seen)
        return idx, r[idx], b[idx]

    def observe_points_noisy(
        self,
        pose: tuple[float, float, float] | FArray,
        settings: ObservationSettings,
        rng: np.random.Generator,
    ) -> tuple[FArray, FArray, FArray, FArray]:
        """Range-bearing observations with the scenario's noise: (indices, ranges, bearings,
        burst mask). Each observation is, with probability ``burst_p``, a burst whose
        covariance is ``burst_n`` times larger (the VB paper's dynamic noise, its table 3)."""
        fov = math.radians(settings.field_of_view_deg)
        idx, r, b = self.observe_points(pose, settings.max_range_m, fov)
        burst = rng.random(idx.size) < settings.burst_p
        k = np.where(burst, math.sqrt(settings.burst_n), 1.0)
        r = r + rng.normal(0.0, 1.0, r.size) * settings.sigma_range_m * k
        sb = math.radians(settings.sigma_bearing_deg)
        b = wrap_angle(b + rng.normal(0.0, 1.0, b.size) * sb * k)
        return idx, r, b, burst

    # magnetics
    def beacon_fields(self, points: FArray, t: float | None = None) -> FArray:
        """Field of each magnetic beacon at ``points`` (N, 3), tesla NED, shape (B, N, 3).

        Beacons with a frequency are coils driven at it: at time ``t`` (s) their moment is
        scaled by ``cos(2 pi f t)``; ``t=None`` gives the amplitude (moment at full scale).
        """
        f = dipole_field(points, self.beacon_positions, self.beacon_moments)
        if t is not None:
            f = f * np.cos(2 * math.pi * self.beacon_frequencies * t)[:, None, None]
        return f

    def magnetic_field(self, points: FArray, t: float | None = None) -> FArray:
        """Total field at ``points`` ((3,) or (N, 3)), tesla NED: Earth field plus all
        beacons (see :meth:`beacon_fields`)."""
        pts = np.asarray(points, float)
        total = self.earth_field + self.beacon_fields(pts, t).sum(axis=0)
        return total.reshape(pts.shape)

    # acoustics
    def acoustic_range(self, points: FArray) -> FArray:
        """Slant range from ``points`` ((3,) or (N, 3), NED) to the acoustic beacon, metres."""
        if self.acoustic_beacon is None:
            raise ValueError("the scenario has no acoustic beacon")
        pts = np.asarray(points, float)
        return np.linalg.norm(pts - self.acoustic_beacon, axis=-1)

    def acoustic_travel_time(self, points: FArray) -> FArray:
        """One-way acoustic travel time to the beacon at the world's sound speed, seconds."""
        return self.acoustic_range(points) / self.sound_speed
