"""The online magnetic-beacon SLAM stage (AMB-SLAM, Hou 2019): magnetometer, odometry and the
acoustic beacon in; pose, beacon map and beacon observations out.

Inputs, each in time order (times: seconds on the odometry clock, i.e. the gateway's receive
stamps):

* **odometry** (:class:`~auvgw.fusion.Odometry`, the fusion stage's ``nav/odometry``): its
  :class:`~auvgw.fusion.MotionIncrement` is the filter's control ``(v_forward, v_starboard,
  yaw_rate)`` over ``dt`` (the :class:`~auvgw.slam.models.VelocityModel`); its attitude
  ``(heading, pitch, roll)`` - the INS attitude the fusion stage carries - joins a short history
  used to rotate each magnetometer sample to NED;
* **magnetometer** (the decoded MS3A sample, kind ``magnetometer`` whatever the wire; ``b_nt``
  sensor axes = body axes): it waits until the odometry covers its time, then goes to
  :meth:`~auvgw.slam.magnetic.online.MagneticOnline.add_mag` with the attitude interpolated at
  its time;
* **acoustic** (``AcousticReply``: slant range m, bearing rad from the bow, depression): the
  reply is stamped at the receive time minus the two-way travel time (``2 range / c``), the
  slant range is made horizontal with the depression angle
  (``r cos(depression)``) and given to the anchor update with ``R = diag(sigma_range^2,
  sigma_bearing^2)``.

Published (JSON, the shapes of ``docs/viz.md``): ``auv/<v>/slam/magnetic/pose`` (``t``, ``x``,
``y``, ``heading``, ``cov`` 3x3) after every demodulated window (every ``hop_s`` of magnetometer
time) and at most every ``publish_period_s`` of odometry time; ``.../landmarks`` (``t``,
``mean``, ``cov``, ``ids``: the beacons) with each pose after a window; ``.../observations``
(one per demodulated beacon observation: ``t``, ``freq``, ``amp_nt``, ``snr``, ``z`` = [range m,
bearing rad], ``r``, plus ``x``, ``y``, ``heading`` of the pose it is seen from, for range
lines). Counters on ``auv/<v>/status/slam-magnetic``. A malformed payload is counted and
logged, never stops the worker.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field

from auvgw.bus import Envelope, Keys
from auvgw.fusion.odometry import Odometry
from auvgw.slam.history import StateHistory
from auvgw.slam.magnetic.filters import MAGNETIC_ALGORITHMS, make_magnetic
from auvgw.slam.magnetic.mlp import MLP
from auvgw.slam.magnetic.online import BeaconObservation, MagneticOnline
from auvgw.slam.models import VelocityModel
from auvgw.stages.base import BusCounters, Stage

log = logging.getLogger(__name__)

__all__ = ["MagneticStage", "MagneticStageConfig", "MagneticStats", "config_from_scenario"]

PIPELINE = "magnetic"
MAG_KIND = "magnetometer"
ACOUSTIC_KIND = "acousticreply"
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "config" / "magnetic_mlp.npz"


class MagneticStageConfig(BaseModel):
    """Settings of the magnetic stage.

    ``channels_hz``: the beacons' frequencies (Hz, the demodulator's plan); ``anchor_xy``: the
    acoustic beacon's NED position (m; None: no anchor, MB-SLAM behaviour); ``algorithm``
    ``amb-slam`` / ``mb-slam`` / ``dr``; ``model``: the MLP ``.npz``. Noise: control noise
    ``Q = diag(sigma_v^2, sigma_v^2, sigma_yaw_rate^2)`` (m/s, m/s, deg/s) per prediction,
    nominal beacon noise ``R = diag(sigma_range^2, sigma_bearing^2)`` (m, deg; each MLP
    observation carries its own covariance), acoustic ``acoustic_sigma_*``. ``sound_speed_mps``
    for the acoustic travel time.
    """

    model_config = ConfigDict(extra="forbid")

    vehicle: str = "auv1"
    algorithm: str = "amb-slam"
    channels_hz: list[float]
    anchor_xy: tuple[float, float] | None = None
    model: Path = DEFAULT_MODEL
    x0: tuple[float, float, float] | None = None
    sigma_v_mps: float = Field(0.05, gt=0)
    sigma_yaw_rate_dps: float = Field(0.2, gt=0)
    sigma_range_m: float = Field(2.0, gt=0)
    sigma_bearing_deg: float = Field(5.0, gt=0)
    acoustic_sigma_range_m: float = Field(1.0, gt=0)
    acoustic_sigma_bearing_deg: float = Field(2.0, gt=0)
    sound_speed_mps: float = Field(1500.0, gt=0)
    publish_period_s: float = Field(0.2, gt=0)
    odometry_window_s: float = Field(30.0, gt=0)
    max_pending_mag: int = Field(20_000, ge=1)
    status_period_s: float = Field(1.0, gt=0)
    queue_size: int = Field(100_000, ge=1)


def config_from_scenario(path: Path, **kw: Any) -> MagneticStageConfig:
    """Stage settings from a beacons scenario: the beacons' frequencies and the acoustic
    beacon's horizontal position."""
    from auvgw.config.scenario import load_scenario

    scn = load_scenario(path)
    freqs = sorted({float(b.frequency_hz) for b in scn.magnetic_beacons})
    ab = scn.acoustic_beacon
    anchor = (float(ab.x), float(ab.y)) if ab is not None else None
    return MagneticStageConfig(channels_hz=freqs, anchor_xy=anchor, **kw)


@dataclass
class MagneticStats(BusCounters):
    """Counters of the stage (``received``: envelopes decoded)."""

    odometry: int = 0  #: odometry samples used
    mag: int = 0  #: magnetometer samples given to the demodulator
    mag_before_odometry: int = 0  #: samples older than the odometry history (dropped)
    mag_dropped: int = 0  #: samples dropped because too many waited for odometry
    acoustic: int = 0  #: acoustic fixes used
    observations: int = 0  #: demodulated, ranged beacon observations
    published: int = 0  #: pose publications


class MagneticStage(Stage):
    """Odometry + magnetometer + acoustic beacon -> AMB-SLAM (see the module docstring).

    ``session``: publish on it (None: in-process only); ``on_publish(key, payload, t_ns)`` is
    called at every publication."""

    name = PIPELINE
    status_schema = "MagneticStatus"
    outputs = ("pose", "landmarks", "observations")
    stats: MagneticStats

    def __init__(
        self,
        config: MagneticStageConfig,
        session: zenoh.Session | None = None,
        on_publish: Callable[[str, bytes, int], object] | None = None,
    ) -> None:
        if config.algorithm not in MAGNETIC_ALGORITHMS:
            raise ValueError(
                f"unknown algorithm {config.algorithm!r}; choose from {MAGNETIC_ALGORITHMS}"
            )
        self.config = cfg = config
        super().__init__(
            Keys(cfg.vehicle), MagneticStats(), session,
            status_period_s=cfg.status_period_s, queue_size=cfg.queue_size, on_publish=on_publish,
        )  # fmt: skip
        self.net = MLP.load(cfg.model)
        self.online: MagneticOnline | None = None
        self.observations: list[BeaconObservation] = []
        #: published poses: (t s, x, y, heading)
        self.track: list[tuple[float, float, float, float]] = []
        self._att = StateHistory(3, angles=(0, 1, 2))  # heading, pitch, roll (rad)
        self._mags: deque[tuple[float, np.ndarray]] = deque()
        self._t_pub: float | None = None

    component = f"slam-{PIPELINE}"  # type: ignore[assignment]

    def key(self, what: str) -> str:
        """``auv/<v>/slam/magnetic/<what>``."""
        return self.keys.slam(PIPELINE, what)

    def input_keys(self) -> list[str]:
        """Odometry, the magnetometer and the acoustic beacon of any device."""
        return [self.keys.odometry(), self.keys.sensor("*", MAG_KIND),
                self.keys.sensor("*", ACOUSTIC_KIND)]  # fmt: skip

    # -- in-process use ------------------------------------------------------------------------
    def _make(self, o: Odometry) -> MagneticOnline:
        c = self.config
        q = np.diag([c.sigma_v_mps**2, c.sigma_v_mps**2, math.radians(c.sigma_yaw_rate_dps) ** 2])
        r = np.diag([c.sigma_range_m**2, math.radians(c.sigma_bearing_deg) ** 2])
        x0 = c.x0 if c.x0 is not None else (o.x, o.y, o.heading)
        anchor = c.anchor_xy if c.anchor_xy is not None else (math.nan, math.nan)
        name = c.algorithm if c.anchor_xy is not None or c.algorithm != "amb-slam" else "mb-slam"
        filt = make_magnetic(name, VelocityModel(), q, r, x0, anchor)
        return MagneticOnline(filt, self.net, np.asarray(c.channels_hz, float))

    def feed_odometry(self, o: Odometry) -> None:
        """One odometry sample (in time order)."""
        with self._lock:
            self.stats.odometry += 1
            last = self._att.last_t
            if last is not None and o.t <= last:
                return
            if self.online is None:
                self.online = self._make(o)
            elif o.increment is not None:
                inc = o.increment
                u = np.array([inc.v_forward, inc.v_starboard, inc.yaw_rate])
                self.online.add_odometry(o.t, u, inc.dt)
            self._att.append(o.t, (o.heading, o.pitch, o.roll))
            self._drain_mag()
            if self._t_pub is None or o.t - self._t_pub >= self.config.publish_period_s:
                self._publish_pose(o.t, landmarks=False)
            self._att.trim(o.t - self.config.odometry_window_s)

    def feed_mag(self, t: float, b_body_nt: np.ndarray) -> None:
        """One magnetometer sample (body axes, nT) at ``t`` (odometry clock)."""
        with self._lock:
            first = self._att.first_t
            if first is not None and t < first:
                self.stats.mag_before_odometry += 1
                return
            if len(self._mags) >= self.config.max_pending_mag:
                self._mags.popleft()
                self.stats.mag_dropped += 1
            self._mags.append((float(t), np.asarray(b_body_nt, float)))
            self._drain_mag()

    def feed_acoustic(
        self, t_recv: float, slant_m: float, bearing: float, depression: float
    ) -> None:
        """One acoustic reply received at ``t_recv``: slant range m, bearing rad from the bow,
        depression rad."""
        with self._lock:
            if self.online is None or self.config.anchor_xy is None:
                return
            c = self.config
            t = t_recv - 2.0 * slant_m / c.sound_speed_mps
            z = np.array([slant_m * math.cos(depression), bearing])
            r = np.diag(
                [c.acoustic_sigma_range_m**2, math.radians(c.acoustic_sigma_bearing_deg) ** 2]
            )
            self.online.add_acoustic(t, z, r)
            self.stats.acoustic += 1

    def feed(self, device: str, t_recv_ns: int, message: Any) -> None:
        """One decoded gateway message (``on_message`` signature): magnetometer samples and
        acoustic replies are used, everything else ignored."""
        from auvgw.decoding import message_kind

        kind = message_kind(message)
        if kind == MAG_KIND:
            self.feed_mag(t_recv_ns * 1e-9, np.asarray(message.b_nt, float))
        elif kind == ACOUSTIC_KIND:
            self.feed_acoustic(t_recv_ns * 1e-9, float(message.range), float(message.bearing),
                               float(message.depression))  # fmt: skip

    def _drain_mag(self) -> None:
        last = self._att.last_t
        if self.online is None or last is None:
            return
        while self._mags and self._mags[0][0] <= last:
            t, b = self._mags.popleft()
            att = self._att.at(t, hold_first=True)
            assert att is not None
            h, p, r = (float(v) for v in att)
            try:
                obs = self.online.add_mag(t, b, h, p, r)
            except ValueError:  # out of order
                self.stats.mag_before_odometry += 1
                continue
            self.stats.mag += 1
            x, y, hd = self.online.filt.xs[:3]
            for ob in obs:
                self.observations.append(ob)
                self.stats.observations += 1
                d = asdict(ob)
                d.update(x=float(x), y=float(y), heading=float(hd))
                self._put("observations", d, t)
            if obs or self._t_pub is None or t - self._t_pub >= self.config.publish_period_s:
                self._publish_pose(t, landmarks=True)

    # -- outputs ---------------------------------------------------------------------------------
    def _put(self, what: str, body: dict[str, Any], t: float) -> None:
        self.publish_json(what, body, t, f"Magnetic{what.capitalize()}")

    def _publish_pose(self, t: float, landmarks: bool) -> None:
        assert self.online is not None
        x, p = self.online.pose()
        self._t_pub = t
        self.stats.published += 1
        self.track.append((t, float(x[0]), float(x[1]), float(x[2])))
        self._put("pose", {"t": t, "x": float(x[0]), "y": float(x[1]), "heading": float(x[2]),
                           "cov": p.tolist()}, t)  # fmt: skip
        if landmarks:
            f = self.online.filt
            n = f.n_lm
            mean = f.xs[3 : 3 + 2 * n].reshape(n, 2)
            cov = [f.p[3 + 2 * i : 5 + 2 * i, 3 + 2 * i : 5 + 2 * i].tolist() for i in range(n)]
            self._put("landmarks", {"t": t, "mean": mean.tolist(), "cov": cov,
                                    "ids": list(range(n))}, t)  # fmt: skip

    def status_fields(self) -> dict[str, Any]:
        """Algorithm and the number of beacons mapped."""
        n = self.online.filt.n_lm if self.online is not None else 0
        return {"algorithm": self.config.algorithm, "landmarks": n}

    def flush(self) -> None:
        """Publish the current pose and beacon map (end of data)."""
        with self._lock:
            if self.online is not None and self._t_pub is not None:
                self._publish_pose(self._t_pub, landmarks=True)

    # -- on the bus ------------------------------------------------------------------------------
    def dispatch(self, env: Envelope, message: Any) -> None:
        """One decoded bus message (counted as received)."""
        with self._lock:
            self.stats.received += 1
        super().dispatch(env, message)

    #: one bus payload: decoded, dispatched; a malformed one is counted and logged
    handle = Stage.handle_sample
