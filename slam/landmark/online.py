"""The online landmark-SLAM pipeline without any transport: fusion odometry and MSIS scan lines
in, the landmark filter's pose and map out (the core of :class:`auvgw.stages.slam.SlamStage`,
as :class:`~auvgw.fusion.navfilter.NavFilter` is of the fusion stage).

What it does, per input (each kind in time order, any interleaving between kinds):

* **odometry** (:meth:`LandmarkOnline.add_odometry`, the fusion stage's
  :class:`~auvgw.fusion.Odometry`): its pose ``(x, y, heading)`` joins a short
  :class:`~auvgw.slam.history.StateHistory` (to place each ping), its motion increment joins the
  increments not yet given to the filter;
* **MSIS scan lines** (:meth:`LandmarkOnline.add_ping`, SeaNet ``mtHeadData``): a ping waits
  until the odometry covers its time, then its bins go to the
  :class:`~auvgw.slam.features.SonarFeatureExtractor` with the odometry pose *at the ping's
  time* (interpolated), so the motion during a scan is compensated;
* when the extractor completes **point features**, the filter is first predicted with the
  odometry increments up to the reference ping (their composition, as eq. (3) controls
  ``(v_forward, v_starboard, yaw_rate)`` over sub-steps of at most ``predict_period_s``), then
  updated with the points' range-bearing measurements
  (:class:`~auvgw.slam.models.RangeBearing`);
* when it completes **line features** (quay walls: Hough ``(rho, theta)`` in the vehicle frame
  at the reference ping, with the fit's covariance), the filter is predicted the same way and,
  with ``use_lines`` (particle filters), updated with them as
  :class:`~auvgw.slam.models.LineFeature` observations of *line landmarks* on the same
  particles: nearest-neighbour association with the Mahalanobis gate among the line landmarks
  only, noise the fit's covariance plus ``line_sigma_*`` in quadrature; lines shorter than
  ``line_min_length_m`` are not used (corner artefacts). Every line is also kept in the map's
  line layer, placed with the SLAM pose at its reference ping;
* **heading aiding**: every ``heading_period_s`` of odometry time the odometry heading (the INS
  yaw, which eq. (3) of the VB paper drives its motion model with) is an absolute heading
  measurement of ``heading_sigma_deg`` (filters that offer ``observe_heading``);
* without features the filter is still predicted every ``predict_period_s`` of odometry, and an
  estimate is *due* every ``publish_period_s`` of odometry time (:meth:`add_odometry` returns
  True; :meth:`pose_message` and :meth:`landmarks_message` give it).

Times are seconds on the odometry clock; nothing here reads the host clock, so a recording, a
test and a live stage give the same estimates. Not thread-safe: one caller at a time (the stage
holds its lock). The random generator comes from the caller.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from auvgw.slam.features import (
    BeamSettings,
    FeatureSettings,
    PointSettings,
    SonarFeatureExtractor,
    SonarMount,
)
from auvgw.slam.history import HeldSamples, Increment, StateHistory, compose_increments
from auvgw.slam.landmark.base import LandmarkFilter, LandmarkMap, ParticleFilterSLAM
from auvgw.slam.landmark.registry import ALGORITHMS, DISPLAY_NAMES, make_filter
from auvgw.slam.models import LineFeature, RangeBearing, VelocityModel, wrap_angle
from auvgw.slam.outputs import LineSet, PointMap, PoseEstimate

__all__ = [
    "Increment",
    "LandmarkOnline",
    "LandmarkOnlineConfig",
    "OdometrySample",
    "OnlineStats",
    "Ping",
    "compose_increments",
]


class OdometrySample(Protocol):
    """One odometry sample (:class:`auvgw.fusion.Odometry`): time s, NED pose m / rad and the
    motion since the previous sample."""

    @property
    def t(self) -> float: ...

    @property
    def x(self) -> float: ...

    @property
    def y(self) -> float: ...

    @property
    def heading(self) -> float: ...

    @property
    def increment(self) -> Increment | None: ...


class Ping(Protocol):
    """One MSIS scan line (SeaNet ``mtHeadData``: :class:`auvgw.drivers.seanet.HeadData`)."""

    @property
    def bins(self) -> Sequence[int] | np.ndarray: ...

    @property
    def bearing(self) -> float: ...  # head bearing, rad

    @property
    def adc8on(self) -> bool: ...

    @property
    def ad_low(self) -> float: ...  # dB

    @property
    def ad_span(self) -> float: ...  # dB

    def bin_length(self, sound_speed: float) -> float: ...  # m


class LandmarkOnlineConfig(BaseModel):
    """Settings of the online landmark pipeline.

    ``algorithm``: any name of :data:`auvgw.slam.landmark.registry.ALGORITHMS` (default
    VB-AUFastSLAM); ``seed`` of the filter's random generator (the stage's; the pipeline takes
    a generator); ``association`` ``nn`` or ``jcbb`` (unknown identities).

    Noise: the filter's control noise ``Q = diag(sigma_v^2, sigma_v^2, sigma_yaw_rate^2)``
    (m/s, m/s, deg/s) and nominal observation noise ``R0 = diag(sigma_range^2,
    sigma_bearing^2)`` (m, deg; the VB filters adapt it). ``Q`` is what the odometry's errors
    add per prediction step (``predict_period_s``): the defaults (0.01 m/s, 0.05 deg/s) suit the
    INS + DVL fusion odometry (DVL 0.2 cm/s and a few tenths of a percent of scale; a heading
    error of a few tenths of a degree changing over minutes: 0.4 deg RMS with a 400 s
    correlation time changes by ~0.02 deg per 0.5 s step). A much larger ``Q`` (the former 0.3
    deg/s: a 5 deg heading random walk over 10 minutes) lets the particles wander off a good
    odometry between the few point features, so SLAM ends worse than the dead reckoning it is
    given; raise it for a poorer odometry (a gyro with a large uncompensated bias).
    Features: ``threshold_db`` of the beam preprocessing (receiver dB), ``target_radius_m``
    of point targets, ``sound_speed_mps`` for the bin length, ``mount`` of the head (x, y m;
    yaw deg; inverted). ``use_lines``: line features (walls) update the filter too (particle
    filters; the EKF family takes points only), with the line fit's covariance plus
    ``line_sigma_rho_m`` and ``line_sigma_theta_deg`` in quadrature (what the fit does not
    see: the odometry's error over the scan that placed the returns, a wall's roughness); only
    lines whose supported segment is at least ``line_min_length_m`` long (shorter fits are
    where wall corners and pier ends give lines 5-25 deg off any wall; they stay in the map's
    line layer).
    """

    model_config = ConfigDict(extra="forbid")

    algorithm: str = "vb-aufastslam"
    n_particles: int = Field(50, ge=1)
    seed: int = 0
    association: str = "nn"
    sigma_v_mps: float = Field(0.01, gt=0)
    sigma_yaw_rate_dps: float = Field(0.05, gt=0)
    sigma_range_m: float = Field(0.3, gt=0)
    sigma_bearing_deg: float = Field(1.5, gt=0)
    threshold_db: float = 20.0
    target_radius_m: float = Field(0.6, ge=0)
    sound_speed_mps: float = Field(1500.0, gt=0)
    mount_x_m: float = 0.0
    mount_y_m: float = 0.0
    mount_yaw_deg: float = 0.0
    mount_inverted: bool = False
    use_lines: bool = True
    line_sigma_rho_m: float = Field(0.05, ge=0)
    line_sigma_theta_deg: float = Field(0.2, ge=0)
    line_min_length_m: float = Field(10.0, ge=0)
    predict_period_s: float = Field(0.5, gt=0)
    #: absolute heading aiding: the odometry heading as a measurement of this sigma every
    #: ``heading_period_s`` (None: off, the map keeps the INS's initial heading error)
    heading_sigma_deg: float | None = Field(1.0, gt=0)
    heading_period_s: float = Field(10.0, gt=0)
    publish_period_s: float = Field(0.5, gt=0)
    max_particles_published: int = Field(100, ge=0)
    max_lines: int = Field(200, ge=0)
    odometry_window_s: float = Field(30.0, gt=0)
    max_pending_pings: int = Field(2000, ge=1)

    @field_validator("algorithm")
    @classmethod
    def _known(cls, v: str) -> str:
        if v not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {v!r}; choose from {sorted(ALGORITHMS)}")
        return v

    @field_validator("association")
    @classmethod
    def _assoc(cls, v: str) -> str:
        if v not in ("nn", "jcbb"):
            raise ValueError("association: 'nn' or 'jcbb' (identities are unknown online)")
        return v

    @property
    def display_name(self) -> str:
        """The algorithm's name as the papers print it."""
        return DISPLAY_NAMES.get(self.algorithm, self.algorithm)

    def feature_settings(self) -> FeatureSettings:
        """The feature extractor's settings."""
        return FeatureSettings(
            beam=BeamSettings(threshold=self.threshold_db),
            points=PointSettings(target_radius_m=self.target_radius_m),
            mount=SonarMount(
                self.mount_x_m, self.mount_y_m, math.radians(self.mount_yaw_deg),
                self.mount_inverted,
            ),
        )  # fmt: skip


@dataclass
class OnlineStats:
    """Counters of the pipeline."""

    odometry: int = 0  #: odometry samples used
    pings: int = 0  #: scan lines given to the feature extractor
    pings_before_odometry: int = 0  #: scan lines older than the odometry history (dropped)
    pings_dropped: int = 0  #: scan lines dropped because too many waited for odometry
    predictions: int = 0  #: filter prediction steps
    updates: int = 0  #: filter updates (scans with point features)
    line_updates: int = 0  #: filter updates with line features
    heading_updates: int = 0  #: absolute heading measurements (``heading_sigma_deg``)
    point_features: int = 0
    line_features: int = 0


def _length(ln: Any) -> float:
    """Length of a line observation's supported segment, m."""
    e = np.asarray(ln.endpoints, float)
    return float(np.hypot(*(e[1] - e[0])))


def ping_intensity(msg: Ping) -> np.ndarray:
    """A scan line's bins as receiver dB (8-bit: 0-255 over 80 dB; 4-bit: ``ad_low`` plus the
    nibble's share of ``ad_span``)."""
    b = np.asarray(msg.bins, float)
    return b * (80.0 / 255.0) if msg.adc8on else msg.ad_low + b / 15.0 * msg.ad_span


class LandmarkOnline:
    """Odometry + MSIS scan lines -> landmark-SLAM estimates (see the module docstring).

    ``rng``: the filter's random generator (default: seeded with ``config.seed``); ``stats``:
    the counters to keep (a subclass of :class:`OnlineStats`, e.g. the stage's).
    """

    def __init__(
        self,
        config: LandmarkOnlineConfig | None = None,
        rng: np.random.Generator | None = None,
        stats: OnlineStats | None = None,
    ) -> None:
        self.config = cfg = config or LandmarkOnlineConfig()
        self.rng = rng if rng is not None else np.random.default_rng(cfg.seed)
        self.stats = stats if stats is not None else OnlineStats()
        self.extractor = SonarFeatureExtractor(cfg.feature_settings())
        self.filter: LandmarkFilter | None = None
        self._line_model = LineFeature()
        #: SLAM poses at every estimate due: (t s, x, y, heading)
        self.track: list[tuple[float, float, float, float]] = []
        self.lines: deque[dict[str, Any]] = deque(maxlen=cfg.max_lines)
        self.poses = StateHistory(3, angles=(2,))
        self._incs: deque[Increment] = deque()
        self._pings: HeldSamples[Ping] = HeldSamples(cfg.max_pending_pings)
        self._t_filter: float | None = None
        self._t_pub: float | None = None
        self._t_heading: float | None = None

    # -- inputs ---------------------------------------------------------------------------------
    def add_odometry(self, o: OdometrySample) -> bool:
        """One odometry sample (in time order; an older or repeated one is counted and
        ignored). True when an estimate is due at ``o.t`` (it is then on :attr:`track`)."""
        self.stats.odometry += 1
        last = self.poses.last_t
        if last is not None and o.t <= last:
            return False
        if self.filter is None:
            self._make_filter(o)
        elif o.increment is not None:
            self._incs.append(o.increment)
        self.poses.append(o.t, (o.x, o.y, o.heading))
        for t, ping in self._pings.release(o.t):
            self._process_ping(t, ping)
        assert self._t_filter is not None
        if o.t - self._t_filter >= self.config.predict_period_s:
            self._predict_to(o.t)
        self._aid_heading(o)
        due = self._t_pub is None or o.t - self._t_pub >= self.config.publish_period_s
        if due:
            self._estimate_at(o.t)
        self.poses.trim(o.t - self.config.odometry_window_s)
        return due

    def add_ping(self, t: float, msg: Ping) -> None:
        """One scan line received at ``t`` (odometry clock, s): used at once when the odometry
        covers it, else held until it does (at most ``max_pending_pings``)."""
        last = self.poses.last_t
        if last is not None and t <= last:
            self._process_ping(t, msg)
            return
        self.stats.pings_dropped += self._pings.hold(t, msg)

    def finish(self) -> float | None:
        """End of data: predict to the newest odometry and make an estimate due there (its
        time; None without odometry). Pings newer than the odometry stay out."""
        t = self.poses.last_t
        if t is None:
            return None
        self._estimate_at(t)
        return t

    # -- the pipeline ---------------------------------------------------------------------------
    def _estimate_at(self, t: float) -> None:
        self._predict_to(t)
        self._t_pub = t
        assert self.filter is not None
        est = self.filter.estimate()
        self.track.append((t, float(est[0]), float(est[1]), float(est[2])))

    def _make_filter(self, o: OdometrySample) -> None:
        c = self.config
        q = np.diag([c.sigma_v_mps**2, c.sigma_v_mps**2, math.radians(c.sigma_yaw_rate_dps) ** 2])
        r = np.diag([c.sigma_range_m**2, math.radians(c.sigma_bearing_deg) ** 2])
        self.filter = make_filter(
            c.algorithm, VelocityModel(), RangeBearing(), q, r, n_particles=c.n_particles,
            x0=(o.x, o.y, o.heading), association=c.association,
        )  # fmt: skip
        self._t_filter = o.t

    def _process_ping(self, t: float, msg: Ping) -> None:
        pose = self.poses.at(t)
        if pose is None:
            self.stats.pings_before_odometry += 1
            return
        self.stats.pings += 1
        feats = self.extractor.push_ping(
            t, float(msg.bearing), ping_intensity(msg),
            msg.bin_length(self.config.sound_speed_mps), pose,
        )  # fmt: skip
        if not feats:
            return
        self._predict_to(t)
        assert self.filter is not None
        if feats.points:
            self.stats.point_features += len(feats.points)
            self.stats.updates += 1
            z = np.array([p.z for p in feats.points])
            self.filter.update(z, self.rng)
        c = self.config
        use = [ln for ln in feats.lines if _length(ln) >= c.line_min_length_m]
        pf = self.filter
        # line features update particle filters only (``use_lines``; the EKF family takes points)
        if use and c.use_lines and isinstance(pf, ParticleFilterSLAM):
            self.stats.line_updates += 1
            z = np.array([ln.z for ln in use])
            floor = np.diag([c.line_sigma_rho_m**2, math.radians(c.line_sigma_theta_deg) ** 2])
            r = np.array([np.asarray(ln.covariance, float) for ln in use]) + floor
            pf.update(z, self.rng, model=self._line_model, r=r)
        for ln in feats.lines:
            self.stats.line_features += 1
            self.lines.append(self._map_line(ln))

    def _map_line(self, ln: Any) -> dict[str, Any]:
        """A line observation placed with the SLAM pose: (rho, theta) and its end points (the
        extractor gives them in the odometry frame; moved by the SLAM-minus-odometry pose)."""
        assert self.filter is not None
        est = self.filter.estimate()
        m = LineFeature().inverse(est, np.array([ln.rho, ln.theta]))
        dr = np.asarray(ln.pose, float)
        dh = float(wrap_angle(est[2] - dr[2]))
        c, s = math.cos(dh), math.sin(dh)
        rel = np.asarray(ln.endpoints, float) - dr[:2]
        ends = np.stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]], 1) + est[:2]
        return {"rho": float(m[0]), "theta": float(m[1]),
                "cov": np.asarray(ln.covariance, float).tolist(),
                "p0": ends[0].tolist(), "p1": ends[1].tolist()}  # fmt: skip

    def _aid_heading(self, o: OdometrySample) -> None:
        """Every ``heading_period_s`` of odometry time, the odometry's heading as an absolute
        heading measurement (``heading_sigma_deg``), after predicting to its time."""
        c = self.config
        f = self.filter
        observe = getattr(f, "observe_heading", None)
        if c.heading_sigma_deg is None or observe is None:
            return
        if self._t_heading is not None and o.t - self._t_heading < c.heading_period_s:
            return
        self._t_heading = o.t
        self._predict_to(o.t)
        observe(o.heading, math.radians(c.heading_sigma_deg) ** 2, self.rng)
        self.stats.heading_updates += 1

    def _predict_to(self, t: float) -> None:
        """Predict the filter with the increments ending by ``t``, in sub-steps of at most
        ``predict_period_s``."""
        f = self.filter
        assert f is not None and self._t_filter is not None
        take: list[Increment] = []
        while self._incs and self._incs[0].t1 <= t + 1e-9:
            take.append(self._incs.popleft())
        if not take:
            return
        dx, dy, dh, dt = compose_increments(take)
        self._t_filter = take[-1].t1
        if dt <= 0:
            return
        n = max(1, math.ceil(dt / self.config.predict_period_s - 1e-9))
        # n equal sub-steps with the composite's constant velocities (eq. 3 is exact for one
        # step; sub-steps of a constant turn differ from it by O(dh^2 / n), negligible here)
        u = np.array([dx / dt, dy / dt, dh / dt])
        for _ in range(n):
            f.predict(u, dt / n, self.rng)
            self.stats.predictions += 1

    # -- estimates ------------------------------------------------------------------------------
    def pose_message(self, t: float) -> PoseEstimate:
        """The pose estimate at ``t``: ``x``, ``y`` (m, NED), ``heading`` (rad), 3 x 3 ``cov``,
        an evenly spaced subsample of the ``particles`` with their ``weights``, ``neff``."""
        f = self.filter
        assert f is not None
        est = f.estimate()
        parts = getattr(f, "x", None)
        weights = getattr(f, "weights", None)
        cov: Any = None
        sample = w_sample = None
        if isinstance(parts, np.ndarray) and parts.ndim == 2 and weights is not None:
            w = weights()
            d = parts - est
            d[:, 2] = wrap_angle(d[:, 2])
            cov = np.einsum("p,pi,pj->ij", w, d, d)
            k = min(self.config.max_particles_published, len(parts))
            if k:
                idx = np.linspace(0, len(parts) - 1, k).astype(int)
                sample, w_sample = np.round(parts[idx], 4), np.asarray(w[idx], float)
        elif isinstance(joint := getattr(f, "p", None), np.ndarray):
            cov = joint[:3, :3]  # EKF family: the pose block of the joint covariance
        neff = f.neff
        return PoseEstimate(
            t, float(est[0]), float(est[1]), float(est[2]),
            cov=None if cov is None else np.asarray(cov, float), particles=sample,
            weights=w_sample, neff=float(neff) if math.isfinite(neff) else None,
            algorithm=self.config.algorithm,
        )  # fmt: skip

    def maps(self) -> tuple[LandmarkMap, LandmarkMap]:
        """The filter's point landmarks and line landmarks (``(rho, theta)``, map frame)."""
        assert self.filter is not None
        lm = self.filter.landmarks()
        models = getattr(self.filter, "models", [])
        kind = next((i for i, m in enumerate(models) if isinstance(m, LineFeature)), -1)
        return lm.of_kind(0), lm.of_kind(kind if kind > 0 else -1)

    def landmarks_message(self, t: float) -> PointMap:
        """The map at ``t``: point landmarks with covariances, the line layer (observations
        placed with the SLAM pose, ``lines``) and the filter's wall landmarks
        (``line_landmarks``: ``rho``, ``theta`` and their 2 x 2 covariance in the map frame)."""
        pts, walls = self.maps()
        obs = list(self.lines)
        col = {k: np.array([ln[k] for ln in obs], float)
               for k in ("rho", "theta", "cov", "p0", "p1")}  # fmt: skip
        lines = LineSet(col["rho"], col["theta"], col["cov"].reshape(-1, 2, 2),
                        col["p0"].reshape(-1, 2), col["p1"].reshape(-1, 2))  # fmt: skip
        wm = np.asarray(walls.mean, float).reshape(-1, 2)
        return PointMap(
            t, np.asarray(pts.mean, float).reshape(-1, 2),
            np.asarray(pts.cov, float).reshape(-1, 2, 2), np.asarray(pts.ids).astype(int),
            lines=lines,
            line_landmarks=LineSet(wm[:, 0], wm[:, 1],
                                   np.asarray(walls.cov, float).reshape(-1, 2, 2)),
        )  # fmt: skip

    def summary(self) -> dict[str, Any]:
        """Algorithm, extractor counts, map sizes, Neff and resamples (JSON-ready)."""
        f = self.filter
        pts, walls = (None, None) if f is None else self.maps()
        return {
            "algorithm": self.config.algorithm,
            "extractor": {"pings": self.extractor.pings, "votes": self.extractor.votes},
            "landmarks": 0 if pts is None else len(pts.mean),
            "line_landmarks": 0 if walls is None else len(walls.mean),
            "lines": len(self.lines),
            "neff": None if f is None or not math.isfinite(f.neff) else float(f.neff),
            "resamples": getattr(f, "resample_count", None),
        }
