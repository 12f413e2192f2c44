"""The online magnetic-beacon SLAM stage (AMB-SLAM, Hou 2019): magnetometer, odometry and the
acoustic beacon in; pose, beacon map and beacon observations out.

Inputs, each in time order (times: seconds on the odometry clock, i.e. the gateway's receive
stamps):

* **odometry** (:class:`~auvgw.fusion.Odometry`, the fusion stage's ``nav/odometry``): its
  :class:`~auvgw.fusion.MotionIncrement` is the filter's control ``(v_forward, v_starboard,
  yaw_rate)`` over ``dt`` (the :class:`~auvgw.slam.models.VelocityModel`); its attitude
  ``(heading, pitch, roll)`` - the INS attitude the fusion stage carries - joins a short history
  used to rotate each magnetometer sample to NED;
* **magnetometer** (the decoded MS3A sample, kind ``magnetometer`` whatever the wire, read as
  a :class:`~auvgw.drivers.roles.Field`: ``bx, by, bz`` nT, sensor axes = body axes; one
  device, ``mag_device`` or the first seen): it waits until the odometry covers its time, then
  goes to
  :meth:`~auvgw.slam.magnetic.online.MagneticOnline.add_mag` with the attitude interpolated at
  its time. Its time is the receive stamp, or with ``mag_rate_hz`` the sample clock
  ``clock_epoch_s + n / mag_rate_hz`` (``n`` the unwrapped MS3A counter): the demodulator is
  phase-locked to the beacons' drive, and a receive stamp's jitter (host ms times the speed of a
  faster-than-real-time run) turns into phase error at 8.5 Hz;
* **acoustic** (``AcousticReply``: slant range m, bearing rad from the bow, depression): the
  reply is stamped at the receive time minus the two-way travel time (``2 range / c``), the
  slant range is made horizontal with the depression angle
  (``r cos(depression)``) and given to the anchor update with ``R = diag(sigma_range^2,
  sigma_bearing^2)``.

Time origin: the beacons are driven ``m cos(2 pi f t)`` on the vehicle clock, whose zero is
``clock_epoch_s`` on the input clock (the gateway's ``[clock] epoch_ns``, 0 for inputs already on
the vehicle clock); every time is shifted by it before the demodulator and the filter and back on
output.

Published (envelopes of :mod:`auvgw.slam.outputs` messages): ``auv/<v>/slam/magnetic/pose`` (a
``PoseEstimate``: ``t``, ``x``, ``y``, ``heading``, ``cov`` 3x3; ``t`` the end of the odometry
applied, odometry composed over ``odometry_period_s`` per filter prediction) after every
demodulated window (every ``hop_s`` of magnetometer time; ``t_mag``: the sample that completed
it, for latency) and otherwise every ``publish_period_s`` of odometry time (``t_mag`` None);
``.../landmarks`` (a ``PointMap``: ``t``, ``mean``, ``cov``, ``ids``: the beacons;
``acoustic_beacon``: its known ``[x, y]``) with each pose after a window; ``.../observations``
(a ``BeaconRange`` per demodulated beacon observation: ``t``, ``freq``, ``amp_nt``, ``snr``,
``z`` = [range m, bearing rad], ``r``, plus ``x``, ``y``, ``heading`` of the pose it is seen
from, for range lines). Counters on ``auv/<v>/status/slam-magnetic``. A malformed payload is
counted and logged, never stops the worker.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from pydantic import Field

from auvgw.drivers import registry, roles
from auvgw.fusion.odometry import Odometry
from auvgw.slam.history import HeldSamples, Increment, StateHistory, compose_increments
from auvgw.slam.magnetic.filters import MAGNETIC_ALGORITHMS, make_magnetic
from auvgw.slam.magnetic.mlp import MLP
from auvgw.slam.magnetic.online import MagneticOnline
from auvgw.slam.models import VelocityModel
from auvgw.slam.outputs import BeaconRange, PointMap, PoseEstimate
from auvgw.stages.base import BusCounters, PipelineStage, StageConfig

log = logging.getLogger(__name__)

__all__ = ["MagneticStage", "MagneticStageConfig", "MagneticStats", "config_from_scenario"]

PIPELINE = "magnetic"
#: the key kinds of the device registry's roles ``field`` (MS3A on serial and CAN) and ``range``
#: (the acoustic beacon)
(MAG_KIND,) = registry.kinds_with_role("field")
(ACOUSTIC_KIND,) = registry.kinds_with_role("range")
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "config" / "magnetic_mlp.npz"


class MagneticStageConfig(StageConfig):
    """Settings of the magnetic stage.

    ``channels_hz``: the beacons' frequencies (Hz, the demodulator's plan); ``anchor_xy``: the
    acoustic beacon's NED position (m; None: no anchor, MB-SLAM behaviour); ``algorithm``
    ``amb-slam`` / ``mb-slam`` / ``dr``; ``model``: the MLP ``.npz``. Noise: control noise
    ``Q = diag(sigma_v^2, sigma_v^2, sigma_yaw_rate^2)`` (m/s, m/s, deg/s) per prediction,
    nominal beacon noise ``R = diag(sigma_range^2, sigma_bearing^2)`` (m, deg; each MLP
    observation carries its own covariance), acoustic ``acoustic_sigma_*``. ``sound_speed_mps``
    for the acoustic travel time. ``mag_device``: the gateway device of the magnetometer (None:
    the first seen; a serial and a CAN copy of one sensor must not both feed the demodulator).
    ``mag_rate_hz``: time the samples by their counter (wrapping at ``mag_counter_modulus``) at
    this rate from ``clock_epoch_s`` (None: by the receive stamp). ``clock_epoch_s``: the
    vehicle clock's zero on the input clock (s), the beacons' phase reference.
    """

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
    mag_device: str | None = None
    mag_rate_hz: float | None = Field(None, gt=0)
    mag_counter_modulus: int = Field(1_000_000, ge=2)
    clock_epoch_s: float = 0.0
    publish_period_s: float = Field(0.2, gt=0)
    odometry_window_s: float = Field(30.0, gt=0)
    odometry_period_s: float = Field(0.05, ge=0)
    max_pending_mag: int = Field(20_000, ge=1)


def config_from_scenario(path: Path, **kw: Any) -> MagneticStageConfig:
    """Stage settings from a beacons scenario: the beacons' frequencies, the acoustic beacon's
    horizontal position and the sound speed (``kw``: the other settings)."""
    from auvgw.config.scenario import load_scenario

    scn = load_scenario(path)
    freqs = sorted({float(b.frequency_hz) for b in scn.magnetic_beacons})
    ab = scn.acoustic_beacon
    anchor = (float(ab.x), float(ab.y)) if ab is not None else None
    kw.setdefault("sound_speed_mps", scn.sound_speed_mps)
    return MagneticStageConfig(channels_hz=freqs, anchor_xy=anchor, **kw)


#: acoustic fixes held while no odometry has come (10 min of the 1 Hz beacon)
MAX_PENDING_FIXES = 600


@dataclass
class MagneticStats(BusCounters):
    """Counters of the stage (``received``: envelopes decoded)."""

    odometry: int = 0  #: odometry samples used
    mag: int = 0  #: magnetometer samples given to the demodulator
    mag_other_device: int = 0  #: samples of another magnetometer device (ignored)
    mag_before_odometry: int = 0  #: samples older than the odometry history (dropped)
    mag_dropped: int = 0  #: samples dropped because too many waited for odometry
    acoustic: int = 0  #: acoustic fixes used
    acoustic_before_odometry: int = 0  #: fixes older than the first odometry (dropped)
    acoustic_dropped: int = 0  #: fixes dropped because too many waited for the first odometry
    observations: int = 0  #: demodulated, ranged beacon observations
    published: int = 0  #: pose publications


class MagneticStage(PipelineStage):
    """Odometry + magnetometer + acoustic beacon -> AMB-SLAM (see the module docstring and
    :class:`~auvgw.stages.base.PipelineStage`)."""

    name = PIPELINE
    outputs = ("pose", "landmarks", "observations")
    stats_type = MagneticStats
    stats: MagneticStats
    config: MagneticStageConfig

    def setup(self) -> None:
        cfg = self.config
        if cfg.algorithm not in MAGNETIC_ALGORITHMS:
            raise ValueError(
                f"unknown algorithm {cfg.algorithm!r}; choose from {MAGNETIC_ALGORITHMS}"
            )
        self.net = MLP.load(cfg.model)
        self.online: MagneticOnline | None = None
        self._att = StateHistory(3, angles=(0, 1, 2))  # heading, pitch, roll (rad)
        self._mags: HeldSamples[np.ndarray] = HeldSamples(cfg.max_pending_mag)
        #: acoustic fixes (z, r) at t that came before the first odometry sample did
        self._fixes: HeldSamples[tuple[np.ndarray, np.ndarray]] = HeldSamples(MAX_PENDING_FIXES)
        self._t_pub: float | None = None
        self._t_odo = -math.inf  # end of the odometry given to the filter (input clock, s)
        #: odometry increments being composed into one filter prediction
        self._incs: list[Increment] = []
        self._t0 = cfg.clock_epoch_s  # vehicle clock zero on the input clock, s
        self.sources["field"] = cfg.mag_device
        self._counter: tuple[int, int] | None = None  # (last raw counter, wraps * modulus)

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
                self._t_odo = o.t
                # the fixes that came before it (odometry lags the sensors)
                for t, (z, r) in self._fixes.release(math.inf):
                    self._add_fix(t, z, r, t_first=o.t)
            elif o.increment is not None:
                self._compose(o.t, o.increment)
            self._att.append(o.t, (o.heading, o.pitch, o.roll))
            self._drain_mag()
            if self._pose_due():
                self._publish_pose(landmarks=False)
            self._att.trim(o.t - self.config.odometry_window_s)

    def _compose(self, t: float, inc: Increment) -> None:
        """Compose odometry increments (``dx`` forward, ``dy`` starboard in the body frame at
        the start, m; ``dheading`` rad) over ``odometry_period_s`` into one filter prediction
        ending at ``t``, its control noise scaled by ``1/n`` (the variance of ``n`` steps)."""
        assert self.online is not None
        self._incs.append(inc)
        dx, dy, dh, dt = compose_increments(self._incs)
        if dt >= self.config.odometry_period_s - 1e-9 and dt > 0:
            self.online.add_odometry(t - self._t0, np.array([dx / dt, dy / dt, dh / dt]), dt,
                                     q_scale=1.0 / len(self._incs))  # fmt: skip
            self._incs.clear()
            self._t_odo = t

    def feed_mag(self, t: float, b_body_nt: np.ndarray) -> None:
        """One magnetometer sample (body axes, nT) at ``t`` (odometry clock)."""
        with self._lock:
            first = self._att.first_t
            if first is not None and t < first:
                self.stats.mag_before_odometry += 1
                return
            self.stats.mag_dropped += self._mags.hold(t, np.asarray(b_body_nt, float))
            self._drain_mag()

    def feed_acoustic(
        self, t_recv: float, slant_m: float, bearing: float, depression: float
    ) -> None:
        """One acoustic reply received at ``t_recv``: slant range m, bearing rad from the bow,
        depression rad."""
        c = self.config
        if c.anchor_xy is None:
            return
        t = t_recv - 2.0 * slant_m / c.sound_speed_mps
        z = np.array([slant_m * math.cos(depression), bearing])
        r = np.diag([c.acoustic_sigma_range_m**2, math.radians(c.acoustic_sigma_bearing_deg) ** 2])
        with self._lock:
            if self.online is None:  # held until the first odometry sample arrives
                self.stats.acoustic_dropped += self._fixes.hold(t, (z, r))
            else:
                self._add_fix(t, z, r, None)

    def _add_fix(self, t: float, z: np.ndarray, r: np.ndarray, t_first: float | None) -> None:
        """Give one acoustic fix at ``t`` (input clock, s) to the filter, unless it is older
        than the first odometry sample ``t_first`` (None: no check, the filter orders it)."""
        assert self.online is not None
        if t_first is not None and t < t_first:
            self.stats.acoustic_before_odometry += 1
            return
        self.online.add_acoustic(t - self._t0, z, r)
        self.stats.acoustic += 1

    def feed(self, device: str, t_recv_ns: int, message: object) -> None:
        """One decoded gateway message (``on_message`` signature): magnetometer samples and
        acoustic replies are used, everything else ignored."""
        from auvgw.decoding import message_kind

        kind = message_kind(message)
        if kind == MAG_KIND:
            # its kind's messages have the role (serial Ms3aSample, CAN MS3A_Sample: bx, by, bz nT)
            mag = cast("roles.Field", message)
            with self._lock:
                if not self.from_source("field", device):
                    self.stats.mag_other_device += 1
                    return
                t = self._mag_time(t_recv_ns, int(mag.counter))
            self.feed_mag(t, np.array([mag.bx, mag.by, mag.bz], float))
        elif kind == ACOUSTIC_KIND:
            fix = cast("roles.Range", message)
            self.feed_acoustic(t_recv_ns * 1e-9, float(fix.range), float(fix.bearing),
                               float(fix.depression))  # fmt: skip

    def _mag_time(self, t_recv_ns: int, counter: int) -> float:
        """A magnetometer sample's time on the input clock: its receive stamp, or with
        ``mag_rate_hz`` its unwrapped counter on the sample clock."""
        rate = self.config.mag_rate_hz
        if rate is None:
            return t_recv_ns * 1e-9
        mod = self.config.mag_counter_modulus
        last, base = self._counter if self._counter is not None else (counter, 0)
        if counter < last:
            base += mod
        self._counter = (counter, base)
        return self._t0 + (base + counter) / rate

    def _drain_mag(self) -> None:
        if self.online is None:
            return
        for t, b in self._mags.release(self._att.last_t):
            att = self._att.at(t, hold_first=True)
            assert att is not None
            h, p, r = (float(v) for v in att)
            try:
                horizon = self.online.horizon
                obs = self.online.add_mag(t - self._t0, b, h, p, r)
            except ValueError:  # out of order
                self.stats.mag_before_odometry += 1
                continue
            self.stats.mag += 1
            x, y, hd = self.online.filt.xs[:3]
            for ob in obs:
                self.stats.observations += 1
                self.publish_message("observations", BeaconRange(
                    ob.t + self._t0, ob.freq, ob.amp_nt, ob.snr, ob.z, np.asarray(ob.r, float),
                    float(x), float(y), float(hd)), t)  # fmt: skip
            if self.online.horizon != horizon:  # a window was demodulated
                self._publish_pose(landmarks=True, t_mag=t)

    # -- outputs ---------------------------------------------------------------------------------
    def _pose_due(self) -> bool:
        p = self.config.publish_period_s
        return self._t_pub is None or self._t_odo - self._t_pub >= p

    def _publish_pose(self, landmarks: bool, t_mag: float | None = None) -> None:
        """The pose at the end of the odometry given to the filter (``t``) and, with
        ``landmarks``, the beacon map; ``t_mag``: the magnetometer sample that completed the
        window it follows."""
        assert self.online is not None
        x, p = self.online.pose()
        t = self._t_odo
        self._t_pub = t
        self.stats.published += 1
        self.track.append((t, float(x[0]), float(x[1]), float(x[2])))
        self.publish_message("pose", PoseEstimate(t, float(x[0]), float(x[1]), float(x[2]),
                                                  cov=np.asarray(p, float), t_mag=t_mag), t)
        if landmarks:
            f = self.online.filt
            n = f.n_lm
            mean = np.asarray(f.xs[3 : 3 + 2 * n], float).reshape(n, 2)
            cov = np.array([f.p[3 + 2 * i : 5 + 2 * i, 3 + 2 * i : 5 + 2 * i] for i in range(n)],
                           float).reshape(n, 2, 2)  # fmt: skip
            anchor = self.config.anchor_xy
            self.publish_message("landmarks", PointMap(
                t, mean, cov, np.arange(n),
                acoustic_beacon=None if anchor is None else (float(anchor[0]), float(anchor[1])),
            ), t)  # fmt: skip

    def status_fields(self) -> dict[str, object]:
        """Algorithm and the number of beacons mapped."""
        n = self.online.filt.n_lm if self.online is not None else 0
        return {"algorithm": self.config.algorithm, "landmarks": n}

    def flush(self) -> None:
        """Publish the current pose and beacon map (end of data)."""
        with self._lock:
            if self.online is not None and self._t_pub is not None:
                self._publish_pose(landmarks=True)
