"""The sensors' views: INS attitude, DVL, magnetometer, the MSIS sonar fan and the GeoSwath
raw ping (angles in time series in degrees; sonar bearings in rad clockwise from forward)."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from auvgw.ground.geometry import TWO_PI, wrap_angle
from auvgw.viz import entities as ent
from auvgw.viz.scene import Scene, attitude_quaternion
from auvgw.viz.views.base import View

__all__ = ["Attitude", "Dvl", "Magnetometer", "RawPing", "Sonar", "amplitude_colours"]

#: the sonar fan's range rings, fractions of the range scale
_RINGS = (0.25, 0.5, 0.75, 1.0)
#: the sonar fan's colour scale (inferno-like: black, purple, red, orange, pale yellow)
_FAN_SCALE = np.array(
    [(0, 0, 4), (40, 11, 84), (101, 21, 110), (159, 42, 99), (212, 72, 66), (245, 125, 21),
     (250, 193, 39), (252, 255, 164)],
    dtype=np.float64,
)  # fmt: skip
#: x red, y green, z blue
_XYZ = [(235, 80, 80), (90, 210, 90), (80, 150, 255)]


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


class Attitude(View):
    """INS attitude: roll and pitch (deg) on ``ins/attitude``, heading (0-360 deg) on
    ``ins/heading`` and the vehicle frame's transform (``vehicle_pose_hz``; at the navigation
    track's position unless given)."""

    kind = "attitude"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._pose_t = -math.inf

    def log(
        self, t: float, roll: float, pitch: float, heading: float, pos: tuple[float, ...] | None
    ) -> None:
        sc = self.scene
        sc.vehicle.attitude_seen = True
        sc.static(ent.INS_ATTITUDE, lambda: rr.SeriesLines(names=["roll deg", "pitch deg"]))
        sc.static(ent.INS_HEADING, lambda: rr.SeriesLines(names=["heading deg"]))
        sc.append(ent.INS_ATTITUDE, "scalars", t, (math.degrees(roll), math.degrees(pitch)))
        sc.append(ent.INS_HEADING, "scalars", t, (math.degrees(heading) % 360.0,))
        # 100 us slack: device times near 1.7e9 s carry about 0.2 us of float rounding
        if t - self._pose_t >= 1.0 / self.options.vehicle_pose_hz - 1e-4 or t < self._pose_t:
            self._pose_t = t
            p = pos if pos is not None else sc.vehicle.position
            q = attitude_quaternion(roll, pitch, heading)
            sc.append(ent.VEHICLE, "transform", t, (*p, *q))


class Dvl(View):
    """DVL velocity (m/s, per named axis), altitude (m) and bottom lock (0/1), each on its own
    ``dvl/...`` series."""

    kind = "dvl"

    def log(
        self,
        t: float,
        v: np.ndarray,
        altitude: float,
        names: tuple[str, ...],
        bottom_lock: bool | None,
    ) -> None:
        sc = self.scene
        if len(v):
            sc.static(
                ent.DVL_VELOCITY,
                lambda: rr.SeriesLines(
                    names=[f"{n} m/s" for n in names[: len(v)]], colors=_XYZ[: len(v)]
                ),
            )
            sc.append(ent.DVL_VELOCITY, "scalars", t, tuple(v))
        if not math.isnan(altitude):
            sc.static(ent.DVL_ALTITUDE, lambda: rr.SeriesLines(names=["altitude m"]))
            sc.append(ent.DVL_ALTITUDE, "scalars", t, (altitude,))
        if bottom_lock is not None:
            sc.static(ent.DVL_BOTTOM_LOCK, lambda: rr.SeriesLines(names=["bottom lock"]))
            sc.append(ent.DVL_BOTTOM_LOCK, "scalars", t, (1.0 if bottom_lock else 0.0,))


class Magnetometer(View):
    """Magnetic flux density (nT, body axes): the field, its departure from a running mean
    (``mag_baseline_s`` of device time), its magnitude, and an arrow on the vehicle."""

    kind = "mag"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._mean: np.ndarray | None = None  # running mean of the field (nT)
        self._t = -math.inf

    def log(self, t: float, b: np.ndarray) -> None:
        sc = self.scene
        sc.static(ent.MAG_FIELD, lambda: rr.SeriesLines(names=["x nT", "y nT", "z nT"],
                                                        colors=_XYZ))  # fmt: skip
        sc.static(ent.MAG_CHANGE, lambda: rr.SeriesLines(names=["x", "y", "z"], colors=_XYZ))
        white = [(230, 230, 230)]
        sc.static(ent.MAG_MAGNITUDE, lambda: rr.SeriesLines(names=["|B| nT"], colors=white))
        # the field itself spans tens of thousands of nT, and a turn moves it by as much in the
        # body frame: its departure from a running mean (time constant mag_baseline_s of device
        # time) is what shows a beacon's signal or an anomaly of a few nT
        bb = np.asarray(b, dtype=np.float64)
        if self._mean is None or t < self._t:
            self._mean = bb.copy()
        else:
            alpha = 1.0 - math.exp(-(t - self._t) / self.options.mag_baseline_s)
            self._mean += alpha * (bb - self._mean)
        self._t = t
        sc.append(ent.MAG_CHANGE, "scalars", t, tuple(bb - self._mean))
        sc.static(ent.VEHICLE_MAG, lambda: rr.Arrows3D.from_fields(colors=[(0, 200, 255)]))
        sc.append(ent.MAG_FIELD, "scalars", t, tuple(b))
        sc.append(ent.MAG_MAGNITUDE, "scalars", t, (float(np.linalg.norm(b)),))
        sc.append(ent.VEHICLE_MAG, "arrows3", t, tuple(b * self.options.mag_arrow_m_per_nt))


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


class Sonar(View):
    """The MSIS fan: scan lines painted into the current sweep's image on ``sonar/fan`` (every
    ``fan_period_s`` of device time and at each new sweep), the beam line, range rings labelled
    in metres and the vehicle at the centre."""

    kind = "msis"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._fan = _Fan(self.options.fan_pixels)
        self._logged_t = -math.inf
        self._t = 0.0
        self._overlay: float | None = None
        self._scale: tuple[float, float] | None = None

    def log(self, t: float, bearing: float, bins: np.ndarray, range_m: float, step: float) -> None:
        fan = self._fan
        prev = fan.prev
        if fan.new_sweep(bearing, range_m, len(bins)):
            self._log_fan(self._t, prev)
            fan.clear()
        d = abs(wrap_angle(bearing - prev)) if prev is not None else 0.0
        half = max(step, d, math.radians(0.45)) / 2.0
        fan.paint(bearing, bins, half)
        self._t = t
        if t - self._logged_t >= self.options.fan_period_s:
            self._log_fan(t, bearing)

    def flush(self, final: bool, t_last: float) -> None:
        if final and self._t and self._logged_t < self._t:
            self._log_fan(self._t, None)

    def _log_fan(self, t: float, bearing: float | None) -> None:
        sc = self.scene
        sc.set_time(t)
        img = self._fan.image.copy()
        quality = self.options.fan_jpeg_quality
        if quality is None:
            # the echo levels as the head sent them (0 = no return), each level drawn in the
            # colour of the sweep's own scale (an annotation context: a display gain from the
            # speckle's level to the strongest echo, the top 0.5 % saturating), so targets
            # stand out
            lo, hi = _fan_levels(img)
            if (lo, hi) != self._scale:
                self._scale = (lo, hi)
                sc.rec.log(ent.SONAR, _fan_colours(lo, hi))
            sc.rec.log(ent.SONAR_FAN, rr.SegmentationImage(img, opacity=1.0))
        else:
            sc.rec.log(ent.SONAR_FAN, rr.Image(img).compress(quality))
        if self._overlay != self._fan.range_m:
            self._overlay = self._fan.range_m
            self._rings(self._fan.range_m)
        if bearing is not None:
            sc.rec.log(
                ent.SONAR_BEAM,
                rr.LineStrips2D([self._fan.beam(bearing)], colors=[(255, 80, 80)], radii=[-1.0]),
            )
        self._logged_t = t

    def _rings(self, range_m: float) -> None:
        """Range rings every quarter of the range scale (labelled in metres) and the vehicle,
        bow up, at the centre of the fan (pixels; static, re-logged when the range changes)."""
        rec = self.scene.rec
        n = self._fan.size
        c, rad = (n - 1) / 2.0, n / 2.0
        a = np.linspace(0.0, TWO_PI, 97)
        rings = [np.column_stack([c + f * rad * np.sin(a), c - f * rad * np.cos(a)])
                 for f in _RINGS]  # fmt: skip
        labels = [f"{f * range_m:.3g} m" if math.isfinite(range_m) else "" for f in _RINGS]
        rec.log(
            ent.SONAR_RINGS,
            rr.LineStrips2D(rings, colors=[(90, 200, 255)], radii=[-0.75], draw_order=20.0),
            static=True,
        )
        # each ring's range where it crosses the 45 deg bearing (the labels of line strips sit
        # on top of each other at the centre)
        d = rad * math.sqrt(0.5)
        at = np.array([[c + f * d, c - f * d] for f in _RINGS])
        rec.log(f"{ent.SONAR_RINGS}/labels", rr.Points2D(
            at, colors=[(90, 200, 255)], radii=[-1.5], labels=labels, show_labels=True,
            draw_order=25.0), static=True)  # fmt: skip
        s = max(3.0, n / 40.0)
        hull = np.array([[c, c - 1.6 * s], [c + s, c + s], [c - s, c + s], [c, c - 1.6 * s]])
        rec.log(ent.SONAR_VEHICLE, rr.LineStrips2D(
            [hull], colors=[(255, 220, 0)], radii=[-1.5], draw_order=30.0),
            static=True)  # fmt: skip


class RawPing(View):
    """The latest raw GeoSwath ping of each side on ``raw_ping/<device>/<side>``: x the return
    angle (deg, port negative), y the slant range (m), coloured by amplitude; the layout gets
    its view at the first one."""

    kind = "raw_ping"

    def log(
        self, device: str, t: float, side: int, a: np.ndarray, r: np.ndarray, amp: np.ndarray
    ) -> None:
        sc = self.scene
        sc.show_raw_ping()
        ok = np.isfinite(a) & np.isfinite(r) & np.isfinite(amp)
        a, r, amp = a[ok], r[ok], amp[ok]
        step = -(-len(a) // max(1, self.options.raw_ping_max_samples))  # ceil
        a, r, amp = a[::step], r[::step], amp[::step]
        x = -a if side == 0 else a
        sc.set_time(t)
        sc.rec.log(
            ent.raw_ping_path(device, side),
            rr.Points2D(np.column_stack([x, r]), colors=amplitude_colours(amp),
                        radii=rr.Radius.ui_points(1.5)),
        )  # fmt: skip
