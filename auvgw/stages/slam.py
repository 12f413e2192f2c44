"""The online SLAM stage: fusion odometry and MSIS scan lines in, pose and map out.

What it does, per input:

* **odometry** (:class:`~auvgw.fusion.Odometry`, the fusion stage's output): its pose
  ``(x, y, heading)`` joins a short history (to place each ping), its
  :class:`~auvgw.fusion.MotionIncrement` joins the increments not yet given to the filter;
* **MSIS HeadData** (SeaNet mtHeadData of the configured head, or of the first head seen): the
  ping waits until the odometry covers its time, then its bins go to the
  :class:`~auvgw.slam.features.SonarFeatureExtractor` with the odometry pose *at the ping's time*
  (interpolated), so the motion during a scan is compensated;
* when the extractor completes **point features**, the landmark filter is first predicted with
  the odometry increments up to the reference ping (their composition, as eq. (3) controls
  ``(v_forward, v_starboard, yaw_rate)`` over sub-steps of at most ``predict_period_s``), then
  updated with the points' range-bearing measurements (all the landmark filters take
  :class:`~auvgw.slam.models.RangeBearing` points);
* when it completes **line features** (quay walls: Hough ``(rho, theta)`` in the vehicle frame
  at the reference ping, with the fit's covariance), the filter is predicted the same way and,
  with ``use_lines`` (particle filters), updated with them as
  :class:`~auvgw.slam.models.LineFeature` observations of *line landmarks* on the same
  particles (``update(z, rng, model=LineFeature(), r=...)``): nearest-neighbour association
  with the Mahalanobis gate among the line landmarks only (a wall seen again), noise the fit's
  covariance plus ``line_sigma_*`` added in quadrature (the VB filters keep their noise
  posteriors for the points); lines shorter than ``line_min_length_m`` are not used (corner
  artefacts). Every line is also kept in the map's line layer, placed with the
  SLAM pose at its reference ping;
* without features the filter is still predicted every ``predict_period_s`` of odometry, and
  the estimate is published every ``publish_period_s`` of odometry time (a steady rate on the
  vehicle clock, the same online and over a recording).

Published (JSON, as ``docs/viz.md`` "JSON accepted" describes) on
``auv/<v>/slam/<pipeline>/pose``: ``t``, ``x``, ``y``, ``heading``, ``cov`` (3 x 3 over x, y,
heading), an evenly spaced subsample of the ``particles`` with their ``weights``, ``neff``; and
on ``auv/<v>/slam/<pipeline>/landmarks``: ``t``, ``mean``, ``cov``, ``ids`` and ``lines``
(``rho``, ``theta``, ``cov``, ``p0``, ``p1`` in the map frame). Counters on
``auv/<v>/status/slam-<pipeline>``.

Times are seconds on the odometry clock (the clock of the gateway's receive stamps online: the
host clock, or the vehicle-paced one of a gateway ``[clock]`` section; the fusion stage maps the
INS clock onto it; a ping's time is its receive stamp, SeaNet heads carry no clock). Nothing
here reads the host clock for data (prediction, publication period, ping matching all follow
those times), so the stage runs the same at any emulation speed; only the status period and the
counters' ``t_ns`` are host-clock health.

In-process (``auvgw slam-run``, tests) call :meth:`SlamStage.feed_odometry` and
:meth:`SlamStage.feed` (the work happens on the calling thread); ``auvgw demo`` uses
:meth:`~SlamStage.post_odometry` / :meth:`~SlamStage.post`, which only queue for the stage's
worker thread, so the gateway's reader threads are never held up by the filter (fed on them,
the stage cost the gateway INS frames at 4x real time). On the bus :meth:`SlamStage.start`
subscribes to ``nav/odometry`` and ``sensor/<msis>/mtheaddata`` through the same worker. The
filter and the random generator (seeded from the settings) are only touched under the stage's
lock, from one thread at a time.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field, field_validator

from auvgw.bus import Keys
from auvgw.drivers import registry
from auvgw.drivers import seanet as sn
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.slam.features import (
    BeamSettings,
    FeatureSettings,
    PointSettings,
    SonarFeatureExtractor,
    SonarMount,
)
from auvgw.slam.landmark.base import LandmarkFilter, LandmarkMap, ParticleFilterSLAM
from auvgw.slam.landmark.registry import ALGORITHMS, DISPLAY_NAMES, make_filter
from auvgw.slam.models import LineFeature, RangeBearing, VelocityModel, wrap_angle
from auvgw.stages.base import BusCounters, Stage

log = logging.getLogger(__name__)

__all__ = ["SlamStage", "SlamStageConfig", "SlamStats", "compose_increments"]

#: the gateway's key kind of imaging-sonar pings (the device registry's role ``sonar``: SeaNet
#: ``mtHeadData``); a second sonar kind would make the stage subscribe to each
(HEADDATA_KIND,) = registry.kinds_with_role("sonar")


class SlamStageConfig(BaseModel):
    """Settings of the SLAM stage.

    ``algorithm``: any name of :data:`auvgw.slam.landmark.registry.ALGORITHMS` (default
    VB-AUFastSLAM); ``pipeline``: the key segment (default the algorithm name);
    ``msis_device``: gateway device of the head (None: the first head seen); ``seed`` of the
    filter's random generator; ``association`` ``nn`` or ``jcbb`` (unknown identities).

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

    vehicle: str = "auv1"
    algorithm: str = "vb-aufastslam"
    pipeline: str | None = None
    msis_device: str | None = None
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
    #: absolute heading aiding: the odometry heading (the INS yaw, which eq. (3) of the VB
    #: paper drives its motion model with) as a measurement of this sigma every
    #: ``heading_period_s`` (None: off, the map keeps the INS's initial heading error)
    heading_sigma_deg: float | None = Field(1.0, gt=0)
    heading_period_s: float = Field(10.0, gt=0)
    publish_period_s: float = Field(0.5, gt=0)
    max_particles_published: int = Field(100, ge=0)
    max_lines: int = Field(200, ge=0)
    odometry_window_s: float = Field(30.0, gt=0)
    max_pending_pings: int = Field(2000, ge=1)
    status_period_s: float = Field(1.0, gt=0)
    queue_size: int = Field(100_000, ge=1)

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
    def pipeline_name(self) -> str:
        """The ``<pipeline>`` key segment."""
        return self.pipeline or self.algorithm

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
class SlamStats(BusCounters):
    """Counters of the stage (``received``: scan lines of the MSIS head)."""

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
    published: int = 0  #: pose + landmark publications


def _length(ln: Any) -> float:
    """Length of a line observation's supported segment, m."""
    e = np.asarray(ln.endpoints, float)
    return float(np.hypot(*(e[1] - e[0])))


def compose_increments(incs: list[MotionIncrement]) -> tuple[float, float, float, float]:
    """The motion of consecutive increments as one: ``(dx forward, dy starboard, dheading,
    dt)`` in the body frame at the first increment's start (m, m, rad, s)."""
    x = y = h = 0.0
    dt = 0.0
    for inc in incs:
        x, y, h = inc.apply(x, y, h)
        dt += inc.dt
    return x, y, h, dt


class SlamStage(Stage):
    """Odometry + MSIS scan lines -> SLAM pose and map (see the module docstring).

    ``session``: publish on it (None: in-process only). ``on_publish``: called with ``(key,
    JSON payload bytes, t_ns)`` at every publication (the demo logs them into Rerun).
    """

    name = "slam"
    status_schema = "SlamStatus"
    outputs = ("pose", "landmarks")
    stats: SlamStats

    def __init__(
        self,
        config: SlamStageConfig | None = None,
        session: zenoh.Session | None = None,
        on_publish: Callable[[str, bytes, int], object] | None = None,
    ) -> None:
        self.config = cfg = config or SlamStageConfig()
        super().__init__(Keys(cfg.vehicle), SlamStats(), session,
                         status_period_s=cfg.status_period_s, queue_size=cfg.queue_size,
                         on_publish=on_publish)  # fmt: skip
        self.extractor = SonarFeatureExtractor(cfg.feature_settings())
        self.rng = np.random.default_rng(cfg.seed)
        self.filter: LandmarkFilter | None = None
        self._line_model = LineFeature()
        self.msis_device = cfg.msis_device
        #: SLAM poses at every publication: (t s, x, y, heading)
        self.track: list[tuple[float, float, float, float]] = []
        self.lines: deque[dict[str, Any]] = deque(maxlen=cfg.max_lines)
        self._t_hist: deque[float] = deque()
        self._p_hist: deque[tuple[float, float, float]] = deque()
        self._incs: deque[MotionIncrement] = deque()
        self._pings: deque[tuple[float, sn.HeadData]] = deque()
        self._t_filter: float | None = None
        self._t_pub: float | None = None
        self._t_heading: float | None = None

    @property
    def component(self) -> str:
        """Status / liveliness component name."""
        return f"slam-{self.config.pipeline_name}"

    def key(self, what: str) -> str:
        """``auv/<v>/slam/<pipeline>/<what>``."""
        return self.keys.slam(self.config.pipeline_name, what)

    def input_keys(self) -> list[str]:
        """The key expressions the stage subscribes to: odometry and the MSIS scan lines."""
        return [self.keys.odometry(), self.keys.sensor(self.config.msis_device or "*",
                                                       HEADDATA_KIND)]  # fmt: skip

    # -- in-process use -----------------------------------------------------------------------
    def feed_odometry(self, o: Odometry) -> None:
        """One odometry sample (in time order)."""
        with self._lock:
            self.stats.odometry += 1
            if self._t_hist and o.t <= self._t_hist[-1]:
                return
            if self.filter is None:
                self._make_filter(o)
            elif o.increment is not None:
                self._incs.append(o.increment)
            self._t_hist.append(o.t)
            self._p_hist.append((o.x, o.y, o.heading))
            while self._pings and self._pings[0][0] <= o.t:
                self._process_ping(*self._pings.popleft())
            assert self._t_filter is not None
            if o.t - self._t_filter >= self.config.predict_period_s:
                self._predict_to(o.t)
            self._aid_heading(o)
            if self._t_pub is None or o.t - self._t_pub >= self.config.publish_period_s:
                self._predict_to(o.t)
                self._publish(o.t)
            self._trim(o.t)

    def feed(self, device: str, t_recv_ns: int, message: Any) -> None:
        """One decoded gateway message (the gateway's ``on_message`` signature); scan lines of
        the MSIS head are used, everything else is ignored. ``t_recv_ns``: the odometry clock."""
        if not isinstance(message, sn.HeadData):
            return
        with self._lock:
            if self.msis_device is None:
                self.msis_device = device
            if device != self.msis_device:
                return
            self.stats.received += 1
            t = t_recv_ns / 1e9
            if self._t_hist and t <= self._t_hist[-1]:
                self._process_ping(t, message)
                return
            self._pings.append((t, message))
            if len(self._pings) > self.config.max_pending_pings:
                self._pings.popleft()
                self.stats.pings_dropped += 1

    def post(self, device: str, t_recv_ns: int, message: Any) -> None:
        """:meth:`feed` on the stage's worker thread (after :meth:`start`); only scan lines are
        queued."""
        if isinstance(message, sn.HeadData):
            super().post(device, t_recv_ns, message)

    def flush(self) -> None:
        """End of data: publish the latest estimate (pings newer than the odometry stay out)."""
        with self._lock:
            if self._t_hist:
                self._predict_to(self._t_hist[-1])
                self._publish(self._t_hist[-1])

    # -- the pipeline ---------------------------------------------------------------------------
    def _make_filter(self, o: Odometry) -> None:
        c = self.config
        q = np.diag([c.sigma_v_mps**2, c.sigma_v_mps**2, math.radians(c.sigma_yaw_rate_dps) ** 2])
        r = np.diag([c.sigma_range_m**2, math.radians(c.sigma_bearing_deg) ** 2])
        self.filter = make_filter(
            c.algorithm, VelocityModel(), RangeBearing(), q, r, n_particles=c.n_particles,
            x0=(o.x, o.y, o.heading), association=c.association,
        )  # fmt: skip
        self._t_filter = o.t

    def _pose_at(self, t: float) -> np.ndarray | None:
        th = self._t_hist
        if not th or t < th[0]:
            return None
        i = bisect.bisect_left(th, t)
        if i >= len(th):
            return np.array(self._p_hist[-1])
        if i == 0 or th[i] == t:
            return np.array(self._p_hist[i])
        t0, t1 = th[i - 1], th[i]
        a = (t - t0) / (t1 - t0)
        p0, p1 = self._p_hist[i - 1], self._p_hist[i]
        dh = float(wrap_angle(p1[2] - p0[2]))
        return np.array([p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]),
                         float(wrap_angle(p0[2] + a * dh))])  # fmt: skip

    def _process_ping(self, t: float, msg: sn.HeadData) -> None:
        pose = self._pose_at(t)
        if pose is None:
            self.stats.pings_before_odometry += 1
            return
        self.stats.pings += 1
        b = np.asarray(msg.bins, float)
        b = b * (80.0 / 255.0) if msg.adc8on else msg.ad_low + b / 15.0 * msg.ad_span
        feats = self.extractor.push_ping(
            t, float(msg.bearing), b, msg.bin_length(self.config.sound_speed_mps), pose
        )
        if not feats:
            return
        self._predict_to(t)
        if feats.points:
            self.stats.point_features += len(feats.points)
            self.stats.updates += 1
            z = np.array([p.z for p in feats.points])
            assert self.filter is not None
            self.filter.update(z, self.rng)
        c = self.config
        use = [ln for ln in feats.lines if _length(ln) >= c.line_min_length_m]
        if use and self._lines_to_filter():
            self.stats.line_updates += 1
            z = np.array([ln.z for ln in use])
            floor = np.diag([c.line_sigma_rho_m**2, math.radians(c.line_sigma_theta_deg) ** 2])
            r = np.array([np.asarray(ln.covariance, float) for ln in use]) + floor
            assert self.filter is not None
            self.filter.update(z, self.rng, model=self._line_model, r=r)
        for ln in feats.lines:
            self.stats.line_features += 1
            self.lines.append(self._map_line(ln))

    def _lines_to_filter(self) -> bool:
        """Whether line features update the filter (``use_lines``, a particle filter)."""
        return self.config.use_lines and isinstance(self.filter, ParticleFilterSLAM)

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

    def _aid_heading(self, o: Odometry) -> None:
        """Every ``heading_period_s`` of odometry time, the odometry's heading as an absolute
        heading measurement (``heading_sigma_deg``), after predicting to its time."""
        c = self.config
        f = self.filter
        if c.heading_sigma_deg is None or not hasattr(f, "observe_heading"):
            return
        if self._t_heading is not None and o.t - self._t_heading < c.heading_period_s:
            return
        self._t_heading = o.t
        self._predict_to(o.t)
        f.observe_heading(o.heading, math.radians(c.heading_sigma_deg) ** 2, self.rng)
        self.stats.heading_updates += 1

    def _predict_to(self, t: float) -> None:
        """Predict the filter with the increments ending by ``t``, in sub-steps of at most
        ``predict_period_s``."""
        f = self.filter
        assert f is not None and self._t_filter is not None
        take: list[MotionIncrement] = []
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

    def _trim(self, t: float) -> None:
        keep = t - self.config.odometry_window_s
        while len(self._t_hist) > 2 and self._t_hist[1] < keep:
            self._t_hist.popleft()
            self._p_hist.popleft()

    # -- output -------------------------------------------------------------------------------
    def pose_message(self, t: float) -> dict[str, Any]:
        """The pose JSON: estimate, 3 x 3 covariance, subsampled particles and weights."""
        f = self.filter
        assert f is not None
        est = f.estimate()
        body: dict[str, Any] = {
            "t": t,
            "x": float(est[0]),
            "y": float(est[1]),
            "heading": float(est[2]),
            "algorithm": self.config.algorithm,
        }
        parts = getattr(f, "x", None)
        if isinstance(parts, np.ndarray) and parts.ndim == 2 and hasattr(f, "weights"):
            w = f.weights()
            d = parts - est
            d[:, 2] = wrap_angle(d[:, 2])
            cov = np.einsum("p,pi,pj->ij", w, d, d)
            k = min(self.config.max_particles_published, len(parts))
            if k:
                idx = np.linspace(0, len(parts) - 1, k).astype(int)
                body["particles"] = np.round(parts[idx], 4).tolist()
                body["weights"] = w[idx].tolist()
        elif isinstance(getattr(f, "p", None), np.ndarray):
            cov = f.p[:3, :3]  # EKF family: the pose block of the joint covariance
        else:
            cov = None
        if cov is not None:
            body["cov"] = np.asarray(cov, float).tolist()
        neff = f.neff
        body["neff"] = None if not math.isfinite(neff) else float(neff)
        return body

    def _maps(self) -> tuple[LandmarkMap, LandmarkMap]:
        """The filter's point landmarks and line landmarks (``(rho, theta)``, map frame)."""
        assert self.filter is not None
        lm = self.filter.landmarks()
        models = getattr(self.filter, "models", [])
        kind = next((i for i, m in enumerate(models) if isinstance(m, LineFeature)), -1)
        return lm.of_kind(0), lm.of_kind(kind if kind > 0 else -1)

    def landmarks_message(self, t: float) -> dict[str, Any]:
        """The map JSON: point landmarks with covariances, the line layer (observations placed
        with the SLAM pose) and the filter's wall landmarks (``line_landmarks``: ``rho``,
        ``theta`` and their 2 x 2 covariance in the map frame)."""
        pts, walls = self._maps()
        return {
            "t": t,
            "mean": np.asarray(pts.mean, float).tolist(),
            "cov": np.asarray(pts.cov, float).tolist(),
            "ids": np.asarray(pts.ids).astype(int).tolist(),
            "lines": list(self.lines),
            "line_landmarks": [
                {"rho": float(m[0]), "theta": float(m[1]), "cov": np.asarray(c).tolist()}
                for m, c in zip(walls.mean, walls.cov, strict=True)
            ],
        }

    def _publish(self, t: float) -> None:
        self._t_pub = t
        pose = self.pose_message(t)
        self.track.append((t, pose["x"], pose["y"], pose["heading"]))
        self.stats.published += 1
        for what, body in (("pose", pose), ("landmarks", self.landmarks_message(t))):
            self.publish_json(what, body, t, f"Slam{what.title()}")

    def status_fields(self) -> dict[str, Any]:
        """Algorithm, MSIS device, extractor, map sizes, Neff and resamples."""
        f = self.filter
        pts, walls = (None, None) if f is None else self._maps()
        return {
            "algorithm": self.config.algorithm,
            "msis_device": self.msis_device,
            "extractor": {"pings": self.extractor.pings, "votes": self.extractor.votes},
            "landmarks": 0 if pts is None else len(pts.mean),
            "line_landmarks": 0 if walls is None else len(walls.mean),
            "lines": len(self.lines),
            "neff": None if f is None or not math.isfinite(f.neff) else float(f.neff),
            "resamples": getattr(f, "resample_count", None),
        }
