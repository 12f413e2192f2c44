"""The online bathymetric PF-SLAM stage (mtm-pf, Zhang 2021): multibeam swaths and odometry in,
corrected pose and seabed map out.

Inputs, each in time order (times: seconds on the odometry clock, i.e. the gateway's receive
stamps):

* **odometry** (:class:`~auvgw.fusion.Odometry`, the fusion stage's ``nav/odometry``): its pose
  ``(x, y, heading)`` (NED m, rad) joins a short history used to place each swath;
* **multibeam swaths**: Kongsberg XYZ 88 (kind ``xyz88``) and Depth (kind ``depth``) datagrams
  of the configured device (or of any device). Their beam depths are from the transmit
  transducer, so the seabed depth is ``transducer depth + beam depth`` (XYZ 88
  ``transducer_depth``, Depth ``transducer_depth_total``). A swath's time is its *ping* time:
  the datagram's own clock mapped onto the odometry clock by a
  :class:`~auvgw.ground.devicetime.DeviceClock` (as the fusion maps the INS's), not its receive
  stamp, which comes later by the sonar's, the emulator's and the transport's delay (issue 28:
  at 1.7 m/s each 0.1 s of it placed a swath 0.17 m further along track, the opposite way on
  neighbouring lines); a datagram without a valid time keeps its receive stamp. A swath waits
  until the odometry covers its time, then goes to
  :class:`~auvgw.slam.bathymetric.online.OnlineBathy` with the odometry pose interpolated at
  that time; the odometry displacement since the
  previous used swath is the filter's control ``u`` (eq. 2). A swath is used only once the
  vehicle has moved ``min_ping_spacing_m`` since the last used one (the paper pings at 1 Hz
  at 2.2 m/s; a 5 Hz multibeam at 1.7 m/s would make the T_p = 20 swath submap 7 m long).

Published (envelopes of :mod:`auvgw.slam.outputs` messages) on ``auv/<v>/slam/bathymetric/``:

* ``pose`` after every used swath: ``t``, ``x``, ``y`` (the filter's corrected position),
  ``heading`` (the odometry's: the filter estimates position only), ``cov`` (2 x 2, the particle
  cloud's covariance, m^2), ``dr`` ``[x, y]`` (the odometry at the same time), ``ping``;
* ``map`` every ``map_period_pings`` used swaths and at flush: a DEM tile
  (:func:`~auvgw.slam.bathymetric.evaluate.grid_dem`, mean depth per ``grid_cell_m`` cell) of
  every sounding placed by the corrected trajectory inside the bounding box of the latest
  ``map_period_pings`` swaths (at flush: of the whole map): ``t``, ``cell_m``, ``x0``, ``y0``
  (corner, cell ``[i][j]`` centred at ``x0 + (i + 0.5) cell, y0 + (j + 0.5) cell``), ``depth``
  (rows over x, ``null`` where empty), ``pings``, ``loops`` (accepted, rejected);
* ``cloud`` with each ``map``: the latest ``map_period_pings`` swaths' soundings (every
  ``cloud_beam_stride``-th beam) placed by the corrected trajectory, ``points`` ``[[x, y,
  depth], ...]`` (m, NED, depth down);
* ``track`` at flush, before the whole map: the *smoothed* trajectory, the filter's estimate of
  the whole path once every closure is in (mtm-pf's mean trajectory corrected by every accepted
  closure, eqs. 15-22), where ``pose`` is the *filtered* one (each ping's estimate when it was
  made, which a later closure cannot move): ``t`` (the used swaths' times), ``x``, ``y`` (NED
  m), ``closures_t`` (time of the ping each accepted closure was made at), ``loops``.

Counters on ``auv/<v>/status/slam-bathymetric``. A malformed payload is counted and logged,
never stops the worker; a swath with fewer than 2 valid soundings is counted (``bad_swaths``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field

from auvgw.drivers.kongsberg import XYZ88, Depth
from auvgw.fusion.odometry import Odometry
from auvgw.ground.devicetime import DeviceClock
from auvgw.health import device_time_s
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import grid_dem
from auvgw.slam.bathymetric.online import OnlineBathy
from auvgw.slam.history import HeldSamples, StateHistory
from auvgw.slam.outputs import Cloud, Dem, PoseEstimate, Track
from auvgw.stages.base import BusCounters, PipelineStage, StageConfig

log = logging.getLogger(__name__)

__all__ = ["BathymetricStage", "BathymetricStageConfig", "BathymetricStats", "swath_soundings"]

PIPELINE = "bathymetric"
SWATH_KINDS = ("xyz88", "depth")
#: a swath the stage takes (the messages of :data:`SWATH_KINDS`)
Swath = XYZ88 | Depth


#: BathyConfig values the online stage uses unless its ``filter`` says otherwise
ONLINE_DEFAULTS: dict[str, Any] = {"drift_estimate": False}


class BathymetricStageConfig(StageConfig):
    """Settings of the bathymetric stage.

    ``multibeam_device``: the gateway device whose swaths are used (None: the first seen);
    ``n_particles``, ``seed``: the filter's particles and random seed; ``filter``: any other
    :class:`~auvgw.slam.bathymetric.config.BathyConfig` value by name (``radius_m``, ``t_p``...);
    ``n_beams``: soundings kept per swath (resampled evenly across track);
    ``min_ping_spacing_m``: travel (odometry, m) between used swaths; ``map_period_pings``: used
    swaths between map publications; ``cloud_beam_stride``: beam decimation of the cloud;
    ``odometry_window_s``: odometry history kept to place swaths; ``max_pending_swaths``: swaths
    waiting for odometry before the oldest is dropped."""

    multibeam_device: str | None = None
    n_particles: int = Field(100, ge=1)
    seed: int = 0
    filter: dict[str, Any] = Field(default_factory=dict)
    n_beams: int = Field(141, ge=2)
    min_ping_spacing_m: float = Field(2.0, ge=0)
    map_period_pings: int = Field(20, ge=1)
    cloud_beam_stride: int = Field(4, ge=1)
    odometry_window_s: float = Field(60.0, gt=0)
    max_pending_swaths: int = Field(200, ge=1)

    def bathy_config(self) -> BathyConfig:
        """The filter's settings (``filter`` overrides, then ``n_particles``). Online,
        ``drift_estimate`` is off unless ``filter`` turns it on: its drift model is a bias
        constant in the world frame (eq. 28), while a vehicle's INS + DVL error (heading bias,
        DVL scale and misalignment) turns with each leg."""
        return BathyConfig(**{**ONLINE_DEFAULTS, **self.filter, "n_particles": self.n_particles})


@dataclass
class BathymetricStats(BusCounters):
    """Counters of the stage (``received``: envelopes decoded)."""

    odometry: int = 0  #: odometry samples used
    swaths: int = 0  #: multibeam swaths received (of the configured device)
    pings: int = 0  #: swaths given to the filter
    spacing_skipped: int = 0  #: swaths skipped: less than min_ping_spacing_m since the last
    before_odometry: int = 0  #: swaths older than the odometry history (dropped)
    pending_dropped: int = 0  #: swaths dropped because too many waited for odometry
    bad_swaths: int = 0  #: swaths with fewer than 2 valid soundings
    published: int = 0  #: pose publications
    maps: int = 0  #: map (DEM tile + cloud) publications
    #: swaths placed at their own (ping) time rather than their receive stamp
    ping_timed: int = 0
    #: receive stamp minus the mapped ping time over those swaths (s, odometry clock): times
    #: the vehicle speed, how far along track the receive stamp would have placed them
    stamp_delay_mean_s: float = 0.0
    stamp_delay_max_s: float = 0.0


def swath_soundings(msg: Swath) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(across, along, depth)`` (m: starboard, forward, down from the water surface) of the
    valid beams of a decoded XYZ 88 or Depth datagram: the beam depth (from the transmit
    transducer) plus the transducer depth."""
    beams = msg.beams
    valid = beams.valid if hasattr(beams, "valid") else np.asarray(beams.depth) != 0
    draft = getattr(msg, "transducer_depth_total", None)
    if draft is None:
        draft = msg.transducer_depth
    valid = np.asarray(valid, bool)
    return (
        np.asarray(beams.across, float)[valid],
        np.asarray(beams.along, float)[valid],
        np.asarray(beams.depth, float)[valid] + float(draft),
    )


class BathymetricStage(PipelineStage):
    """Odometry + multibeam swaths -> mtm-pf (see the module docstring and
    :class:`~auvgw.stages.base.PipelineStage`)."""

    name = PIPELINE
    outputs = ("pose", "map", "cloud", "track")
    bulk_outputs = frozenset({"map", "cloud", "track"})
    stats_type = BathymetricStats
    stats: BathymetricStats
    config: BathymetricStageConfig

    def setup(self) -> None:
        cfg = self.config
        self.bathy = cfg.bathy_config()
        self.online = OnlineBathy(self.bathy, np.random.default_rng(cfg.seed), cfg.n_beams)
        #: time of each ping given to the filter (s, odometry clock)
        self.ping_times: list[float] = []
        self._odo = StateHistory(3, angles=(2,))  # x, y (m NED), heading (rad)
        self._swaths: HeldSamples[Swath] = HeldSamples(cfg.max_pending_swaths)
        self._last_xy: tuple[float, float] | None = None
        self._ping_clock = DeviceClock()  # the multibeam's clock onto the odometry clock
        self.sources["swath"] = cfg.multibeam_device

    def input_keys(self) -> list[str]:
        """Odometry and the multibeam's XYZ 88 and Depth datagrams."""
        dev = self.config.multibeam_device or "*"
        return [self.keys.odometry(), *(self.keys.sensor(dev, k) for k in SWATH_KINDS)]

    # -- in-process use ------------------------------------------------------------------------
    def feed_odometry(self, o: Odometry) -> None:
        """One odometry sample (in time order; a stale one is ignored)."""
        with self._lock:
            self.stats.odometry += 1
            if not self._odo.append(o.t, (o.x, o.y, o.heading)):
                return
            self._drain()
            self._odo.trim(o.t - self.config.odometry_window_s)

    def feed_swath(self, t: float, msg: Swath) -> None:
        """One decoded XYZ 88 / Depth datagram received at ``t`` (s, odometry clock); placed at
        its ping time (its own clock mapped onto the odometry clock), or at ``t`` if it has
        none."""
        with self._lock:
            self.stats.swaths += 1
            t = self._ping_time(t, msg)
            first = self._odo.first_t
            if first is not None and t < first:
                self.stats.before_odometry += 1
                return
            self.stats.pending_dropped += self._swaths.hold(t, msg)
            self._drain()

    def feed(self, device: str, t_recv_ns: int, message: object) -> None:
        """One decoded gateway message (``on_message`` signature): swaths of the multibeam (the
        configured one, else the first seen) are used, everything else ignored."""
        if isinstance(message, XYZ88 | Depth) and self.from_source("swath", device):
            self.feed_swath(t_recv_ns * 1e-9, message)

    def _ping_time(self, t_recv: float, msg: Swath) -> float:
        """The ping time of a swath received at ``t_recv`` (s, odometry clock): its device time
        through the multibeam's clock; ``t_recv`` for a datagram without one."""
        t_dev = device_time_s(msg)
        if t_dev is None:
            return t_recv
        t = self._ping_clock.to_common(t_dev, t_recv)
        st = self.stats
        st.ping_timed += 1
        delay = t_recv - t
        st.stamp_delay_mean_s += (delay - st.stamp_delay_mean_s) / st.ping_timed
        st.stamp_delay_max_s = max(st.stamp_delay_max_s, delay)
        return t

    def _drain(self) -> None:
        for t, msg in self._swaths.release(self._odo.last_t):
            pose = self._odo.at(t)
            if pose is None:
                self.stats.before_odometry += 1
                continue
            x, y, h = (float(v) for v in pose)
            last = self._last_xy
            if last is not None and math.hypot(x - last[0], y - last[1]) < (
                self.config.min_ping_spacing_m
            ):
                self.stats.spacing_skipped += 1
                continue
            try:
                across, along, depth = swath_soundings(msg)
                est = self.online.add_ping(x, y, h, across, along, depth)
            except ValueError as exc:
                self.stats.bad_swaths += 1
                log.debug("bathymetric: swath at t = %.3f s not used: %s", t, exc)
                continue
            self._last_xy = (x, y)
            self.ping_times.append(t)
            self.stats.pings += 1
            self._publish_pose(t, est, h, (x, y))
            if self.stats.pings % self.config.map_period_pings == 0:
                self._publish_map(t, self.config.map_period_pings)

    # -- outputs ---------------------------------------------------------------------------------
    def _publish_pose(
        self, t: float, est: np.ndarray, heading: float, dr: tuple[float, float]
    ) -> None:
        f = self.online.filter
        cloud = getattr(f, "x", None)
        cov = np.cov(cloud.T) if cloud is not None and len(cloud) > 1 else np.zeros((2, 2))
        hd = math.remainder(heading, math.tau)
        self.stats.published += 1
        self.track.append((t, float(est[0]), float(est[1]), hd))
        self.publish_message("pose", PoseEstimate(
            t, float(est[0]), float(est[1]), hd, cov=np.asarray(cov, float),
            dr=(float(dr[0]), float(dr[1])), ping=self.online.pings - 1), t)  # fmt: skip

    def _loops(self) -> tuple[int, int]:
        loops = self.online.filter.loops
        acc = sum(1 for lp in loops if lp.accepted)
        return acc, len(loops) - acc

    def _publish_map(self, t: float, last_pings: int | None) -> None:
        """DEM tile over the latest ``last_pings`` swaths (None: the whole map) and the cloud."""
        pts = self.online.map_points()
        if not len(pts):
            return
        recent = self.online.map_points(last_pings)
        if last_pings is not None:
            lo, hi = recent[:, :2].min(0), recent[:, :2].max(0)
            inside = np.all((pts[:, :2] >= lo) & (pts[:, :2] <= hi), axis=1)
            pts = pts[inside]
        grid, (x0, y0) = grid_dem(pts, self.bathy.grid_cell_m)
        self.stats.maps += 1
        self.publish_message("map", Dem(t, self.bathy.grid_cell_m, float(x0), float(y0),
                                        np.round(np.asarray(grid, float), 3), self.online.pings,
                                        self._loops()), t)  # fmt: skip
        n_b = self.online.n_beams
        stride = self.config.cloud_beam_stride
        cloud = recent.reshape(-1, n_b, 3)[:, ::stride].reshape(-1, 3)
        self.publish_message("cloud", Cloud(t, np.round(cloud, 3)), t)

    def _publish_track(self) -> None:
        """The smoothed trajectory (``track``, see the module docstring)."""
        n = self.online.pings
        xy = np.round(self.online.filter.trajectory()[:n], 3)
        times = self.ping_times[:n]
        closures = [times[lp.t_end] for lp in self.online.filter.loops if lp.accepted]
        track = Track(np.asarray(times, dtype=np.float64), xy[:, 0], xy[:, 1],
                      np.asarray(closures, dtype=np.float64), self._loops())  # fmt: skip
        self.publish_message("track", track, times[-1])

    def status_fields(self) -> dict[str, object]:
        """Particles, pings in the filter and loop closures (accepted, rejected)."""
        acc, rej = self._loops()
        return {"algorithm": "mtm-pf", "n_particles": self.bathy.n_particles,
                "pings": self.online.pings, "loops_accepted": acc, "loops_rejected": rej,
                "bytes_held": self.online.filter.bytes_held()}  # fmt: skip

    def flush(self) -> None:
        """End of data: swaths still waiting for odometry are dropped (counted as
        ``pending_dropped``); the smoothed trajectory and the whole map are published."""
        with self._lock:
            self.stats.pending_dropped += self._swaths.clear()
            if self.online.pings > 0 and self.ping_times:
                self._publish_track()
                self._publish_map(self.ping_times[-1], None)
