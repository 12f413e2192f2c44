"""Synthetic INS / DVL / depth samples from a truth trajectory, for tests of the fusion.

The interface is trajectory-agnostic: any :class:`Trajectory` (arrays of t, x, y, z, heading,
u, v, w, yaw_rate, optionally roll and pitch) can be turned into sensor samples with
:func:`simulate_sensors`; :func:`lawnmower` is one survey-like truth. The project's world model
(``sim_devices``) replaces this for end-to-end runs.

Noise (HN-100 / Pathfinder figures of Mu et al. 2022, Table 1, by default): INS heading and
roll/pitch errors are first-order Gauss-Markov processes with the stated RMS (0.3 deg, 0.02 deg)
and a correlation time; gyro and accelerometer outputs carry white noise; DVL components carry
white noise of 0.2 cm/s; the pressure depth white noise of 2 cm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from auvgw.fusion.config import DvlMount
from auvgw.fusion.frames import mount_matrix, wrap_angles
from auvgw.fusion.samples import DepthSample, DvlFrame, DvlSample, InsSample, PositionFix

__all__ = ["SensorNoise", "SimulatedSensors", "Trajectory", "lawnmower", "simulate_sensors"]


@dataclass(frozen=True)
class Trajectory:
    """Truth sampled at times ``t`` (s): position NED (m), heading (rad), body velocity
    (u, v, w) m/s, heading rate (rad/s), roll and pitch (rad; zero when None). Roll and pitch
    are taken as slowly varying (body rates are derived from the heading rate alone)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    yaw_rate: np.ndarray
    roll: np.ndarray | None = None
    pitch: np.ndarray | None = None

    def attitude(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(roll, pitch, heading)`` arrays (zeros for missing roll/pitch)."""
        zero = np.zeros_like(self.t)
        roll = zero if self.roll is None else self.roll
        pitch = zero if self.pitch is None else self.pitch
        return roll, pitch, self.heading

    def body_rates(self) -> np.ndarray:
        """(n, 3) body rates p, q, r (rad/s) for a heading rate at constant roll and pitch."""
        roll, pitch, _ = self.attitude()
        cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
        return np.stack([-sp, sr * cp, cr * cp], axis=1) * self.yaw_rate[:, None]

    def distance(self) -> float:
        """Horizontal path length, m."""
        return float(np.sum(np.hypot(np.diff(self.x), np.diff(self.y))))


def lawnmower(
    duration_s: float = 1800.0,
    speed_mps: float = 1.5,
    leg_m: float = 200.0,
    spacing_m: float = 20.0,
    rate_hz: float = 100.0,
    depth_m: float = 20.0,
    heading0: float = 0.0,
    start: tuple[float, float] = (0.0, 0.0),
) -> Trajectory:
    """A survey: straight legs of ``leg_m`` joined by half circles of diameter ``spacing_m``
    (right turn, then left turn), at constant speed and depth, sampled at ``rate_hz``."""
    n = round(duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    radius = spacing_m / 2.0
    r = speed_mps / radius
    t_leg = leg_m / speed_mps
    t_turn = math.pi / r
    period = 2.0 * (t_leg + t_turn)
    e_fwd = np.array([math.cos(heading0), math.sin(heading0)])
    e_side = np.array([-math.sin(heading0), math.cos(heading0)])
    k = np.floor(t / period)
    tau = t - k * period
    base = np.asarray(start, float)[None, :] + (k * 2.0 * spacing_m)[:, None] * e_side[None, :]
    p = np.empty((n, 2))
    psi = np.empty(n)
    rate = np.zeros(n)

    def arc(p0: np.ndarray, h0: float, w: float, s: np.ndarray) -> np.ndarray:
        rr = speed_mps / w
        return p0 + rr * np.stack(
            [np.sin(h0 + w * s) - math.sin(h0), -(np.cos(h0 + w * s) - math.cos(h0))], axis=1
        )

    ends = np.cumsum([t_leg, t_turn, t_leg, t_turn])
    ph = np.searchsorted(ends, tau, side="right").clip(0, 3)
    s = tau - np.concatenate([[0.0], ends[:3]])[ph]
    m = ph == 0
    p[m] = base[m] + speed_mps * s[m, None] * e_fwd
    psi[m] = heading0
    m = ph == 1
    p[m] = arc(base[m] + leg_m * e_fwd, heading0, r, s[m])
    psi[m] = heading0 + r * s[m]
    rate[m] = r
    m = ph == 2
    p[m] = base[m] + leg_m * e_fwd + spacing_m * e_side - speed_mps * s[m, None] * e_fwd
    psi[m] = heading0 + math.pi
    m = ph == 3
    p[m] = arc(base[m] + spacing_m * e_side, heading0 + math.pi, -r, s[m])
    psi[m] = heading0 + math.pi - r * s[m]
    rate[m] = -r
    return Trajectory(
        t=t,
        x=p[:, 0],
        y=p[:, 1],
        z=np.full(n, depth_m),
        heading=wrap_angles(psi),
        u=np.full(n, speed_mps),
        v=np.zeros(n),
        w=np.zeros(n),
        yaw_rate=rate,
    )


@dataclass(frozen=True)
class SensorNoise:
    """Sensor error figures (1-sigma); ``*_tau_s`` are Gauss-Markov correlation times (0 white,
    inf constant)."""

    heading_sigma_deg: float = 0.3
    heading_tau_s: float = 300.0
    attitude_sigma_deg: float = 0.02
    attitude_tau_s: float = 300.0
    gyro_sigma_dps: float = 0.01
    accel_sigma_mps2: float = 0.005
    dvl_sigma_mps: float = 0.002
    depth_sigma_m: float = 0.02
    #: share of DVL fixes that are spikes: a vector of random direction and a magnitude uniform
    #: in ``dvl_spike_mps`` (m/s) added to the fix (a low-cost DVL's wild pings)
    dvl_spike_p: float = 0.0
    dvl_spike_mps: tuple[float, float] = (0.8, 1.5)
    #: the DVL reads this multiple of the true velocity
    dvl_scale_factor: float = 1.0
    #: heading-dependent compass deviation, deg: ``a1 sin(psi) + b1 cos(psi) + a2 sin(2 psi) +
    #: b2 cos(2 psi)`` added to the heading (a magnetic compass near iron)
    heading_deviation_deg: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    #: position fixes (GNSS at the surface), 1-sigma per axis, m
    fix_sigma_m: float = 2.0


@dataclass(frozen=True)
class SimulatedSensors:
    """Samples of one simulated run, with the truth they came from."""

    ins: list[InsSample]
    dvl: list[DvlSample]
    depth: list[DepthSample]
    truth: Trajectory
    ins_heading_error: np.ndarray = field(repr=False)
    fixes: list[PositionFix] = field(default_factory=list)
    spikes: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False)


def _gauss_markov(
    rng: np.random.Generator, t: np.ndarray, sigma: float, tau: float
) -> np.ndarray:
    """A stationary first-order Gauss-Markov sequence at (uniform) times ``t``."""
    n = len(t)
    if sigma == 0.0:
        return np.zeros(n)
    if tau == 0.0:
        return sigma * rng.standard_normal(n)
    dt = float(t[1] - t[0]) if n > 1 else 1.0
    phi = 0.0 if math.isinf(dt / tau) else math.exp(-dt / tau)
    x0 = sigma * rng.standard_normal()
    if math.isinf(tau):
        return np.full(n, x0)
    drive = sigma * math.sqrt(1.0 - phi * phi) * rng.standard_normal(n)
    drive[0] = 0.0
    out, _ = lfilter([1.0], [1.0, -phi], drive, zi=[phi * x0])
    return out


def _interp(t: np.ndarray, tq: np.ndarray, a: np.ndarray) -> np.ndarray:
    return np.interp(tq, t, a)


def simulate_sensors(
    truth: Trajectory,
    rng: np.random.Generator,
    noise: SensorNoise | None = None,
    mount: DvlMount | None = None,
    dvl_rate_hz: float = 5.0,
    dvl_offset_s: float = 0.0037,
    dvl_frame: DvlFrame = "instrument",
    depth_rate_hz: float = 1.0,
    depth_lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    bottom_lock_loss: Sequence[tuple[float, float]] = (),
    gravity_mps2: float = 9.80665,
    fix_times: Sequence[float] = (),
) -> SimulatedSensors:
    """INS samples at the truth times, DVL fixes every ``1/dvl_rate_hz`` s from
    ``dvl_offset_s`` (off the INS grid on purpose), pressure depths at ``depth_rate_hz``.

    DVL fixes are ``M^T (v + omega x r) + noise`` in instrument axes (or body axes); during
    ``bottom_lock_loss`` intervals ``[t0, t1)`` they carry no lock and NaN velocity. ``noise``
    defaults to :class:`SensorNoise` (HN-100 / Pathfinder), ``mount`` to a DVL at the INS with
    its axes along the body axes. ``fix_times`` (s): horizontal position fixes of the truth
    with ``noise.fix_sigma_m`` (GNSS at the surface). The spikes, scale factor and compass
    deviation of ``noise`` are drawn after everything else, so switching them on leaves the
    other draws unchanged.
    """
    noise = noise or SensorNoise()
    mount = mount or DvlMount()
    t = truth.t
    roll, pitch, heading = truth.attitude()
    rates = truth.body_rates()
    v_body = np.stack([truth.u, truth.v, truth.w], axis=1)

    # INS: attitude with Gauss-Markov errors, noisy rates and specific force
    sig_h, sig_a = math.radians(noise.heading_sigma_deg), math.radians(noise.attitude_sigma_deg)
    e_h = _gauss_markov(rng, t, sig_h, noise.heading_tau_s)
    e_r = _gauss_markov(rng, t, sig_a, noise.attitude_tau_s)
    e_p = _gauss_markov(rng, t, sig_a, noise.attitude_tau_s)
    gyro = rates + math.radians(noise.gyro_sigma_dps) * rng.standard_normal(rates.shape)
    dv = np.gradient(v_body, t, axis=0) if len(t) > 1 else np.zeros_like(v_body)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    grav_body = gravity_mps2 * np.stack([-sp, sr * cp, cr * cp], axis=1)
    f = dv + np.cross(rates, v_body) - grav_body
    f = f + noise.accel_sigma_mps2 * rng.standard_normal(f.shape)
    a1, b1, a2, b2 = (math.radians(c) for c in noise.heading_deviation_deg)
    deviation = a1 * np.sin(heading) + b1 * np.cos(heading)
    deviation = deviation + a2 * np.sin(2 * heading) + b2 * np.cos(2 * heading)
    ins_heading = wrap_angles(heading + e_h + deviation)
    ins = list(
        map(
            InsSample,
            t.tolist(),
            (roll + e_r).tolist(),
            (pitch + e_p).tolist(),
            ins_heading.tolist(),
            zip(*gyro.T.tolist(), strict=True),
            zip(*f.T.tolist(), strict=True),
        )
    )

    # DVL at its own times: truth interpolated there
    td = np.arange(t[0] + dvl_offset_s, t[-1], 1.0 / dvl_rate_hz)
    vd = np.stack([_interp(t, td, v_body[:, i]) for i in range(3)], axis=1)
    wd = np.stack([_interp(t, td, rates[:, i]) for i in range(3)], axis=1)
    vd = vd + np.cross(wd, np.asarray(mount.lever_arm_m, float))
    if dvl_frame == "instrument":
        vd = vd @ mount_matrix(mount)  # rows: M^T v
    vd = noise.dvl_scale_factor * vd + noise.dvl_sigma_mps * rng.standard_normal(vd.shape)
    lock = np.ones(len(td), bool)
    for a, b in bottom_lock_loss:
        lock &= ~((td >= a) & (td < b))
    vd[~lock] = np.nan
    dvl = [
        DvlSample(t=a, velocity=v, bottom_lock=k, frame=dvl_frame)
        for a, v, k in zip(td.tolist(), zip(*vd.T.tolist(), strict=True), lock.tolist(),
                           strict=True)
    ]

    # pressure depth of a sensor at depth_lever_arm_m
    tp = np.arange(t[0] + 0.5 / depth_rate_hz, t[-1], 1.0 / depth_rate_hz)
    rx, ry, rz = depth_lever_arm_m
    arm_z = -sp * rx + cp * sr * ry + cp * cr * rz
    zp = _interp(t, tp, truth.z + arm_z) + noise.depth_sigma_m * rng.standard_normal(len(tp))
    depth = [DepthSample(t=a, depth=d) for a, d in zip(tp.tolist(), zp.tolist(), strict=True)]

    tf = np.asarray(fix_times, dtype=float)
    fn = _interp(t, tf, truth.x) + noise.fix_sigma_m * rng.standard_normal(len(tf))
    fe = _interp(t, tf, truth.y) + noise.fix_sigma_m * rng.standard_normal(len(tf))
    fixes = [
        PositionFix(a, n, e, noise.fix_sigma_m)
        for a, n, e in zip(tf.tolist(), fn.tolist(), fe.tolist(), strict=True)
    ]
    spikes = np.zeros(len(dvl), bool)
    if noise.dvl_spike_p > 0 and dvl:
        spikes = rng.random(len(dvl)) < noise.dvl_spike_p
        k = int(spikes.sum())
        direction = rng.standard_normal((k, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        size = rng.uniform(*noise.dvl_spike_mps, size=k)
        for i, dv in zip(np.flatnonzero(spikes).tolist(), (direction * size[:, None]).tolist(),
                         strict=True):
            d = dvl[i]
            if d.bottom_lock:
                dvl[i] = d._replace(velocity=tuple(a + b for a, b in zip(d.velocity, dv,
                                                                           strict=True)))
    return SimulatedSensors(
        ins=ins, dvl=dvl, depth=depth, truth=truth, ins_heading_error=e_h, fixes=fixes,
        spikes=spikes,
    )
