"""HN-100 INS emulator: the navigation solution at 100 Hz on serial (binary frame) and CAN.

Each tick samples the ground truth and reports, with white Gaussian noise (sigmas from the
scenario's ``devices.ins.noise``, each multiplied by ``sqrt(n)`` in a VB noise burst):

* roll, pitch, heading (ZYX Euler, rad; heading from north towards east, 0..2 pi):
  ``roll_deg`` 0.02, ``pitch_deg`` 0.02, ``heading_deg`` 0.3 (the seed's figures, RMS);
* body angular rates (x forward, y starboard, z down) from the Euler rates,
  ``p = phi' - psi' sin(theta)``, ``q = theta' cos(phi) + psi' sin(phi) cos(theta)``,
  ``r = -theta' sin(phi) + psi' cos(phi) cos(theta)``: ``rate_dps`` 0.05;
* specific force in the body frame, ``f = R^T (a_ned - g_ned)`` with g_ned = (0, 0, 9.80665)
  (about (0, 0, -9.81) m/s^2 at rest): ``accel_mps2`` 0.01;
* NED velocity: ``vel_mps`` 0.01; position as WGS-84 latitude/longitude around the origin
  ``options.origin_lat_deg``/``origin_lon_deg`` (flat-earth, local radii): ``pos_m`` 0.5;
  depth: ``depth_m`` 0.02;
* time: the device clock since power-up (vehicle time plus clock jumps), status aligned and
  DVL-aided.

Slowly varying heading error (off by default). The white heading noise above averages out over
a few samples, so a dead reckoning on it hardly drifts; a real INS/AHRS heading error is
correlated over minutes (gyro bias instability, the alignment's residual). With
``heading_bias_deg`` > 0 the reported heading also carries a first-order Gauss-Markov error
``b``: ``db/dt = -b / tau + w``, discretised exactly between samples
(``b_k = e^{-dt/tau} b_{k-1} + sqrt(1 - e^{-2 dt/tau}) sigma w_k``), started from its
stationary distribution ``N(0, sigma^2)``: ``heading_bias_deg`` is the steady-state RMS
``sigma`` (deg) and ``heading_bias_tau_s`` the correlation time ``tau`` (s, default 300).
``heading_offset_deg`` adds a constant heading error (deg, default 0; e.g. a misaligned
mounting: it turns a SLAM map together with the track, so nothing but an absolute reference
can remove it). The error ``offset + b`` (rad, :attr:`InsSample.heading_error`) turns the
heading and the NED velocity (the INS resolves its velocity with its own heading); body rates,
specific force, position and depth are unaffected. It is drawn from its own generator and is
not scaled in noise bursts, so switching it on leaves every other draw unchanged.

Options (:class:`~auvgw.sim_devices.emulator.SerialCanEmulator`): ``serial`` (true), ``can``
(true), ``baud`` (115200), ``can_bitrate`` (500000), ``table`` (a site HN-100 table, TOML; the
gateway configuration then names it too), ``origin_lat_deg`` / ``origin_lon_deg`` (59.43,
10.47).
Wires: serial ``<port_dir>/ins`` (format hn100), CAN adapter ``<port_dir>/ins_can`` (DBC
``hn100.dbc``, one burst of 8 frames per epoch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import hn100
from auvgw.drivers.can_codec import hn100_can
from auvgw.sim_devices.emulator import SerialCanEmulator, SimContext
from auvgw.sim_devices.vehicle import GRAVITY, TruthSample
from auvgw.sim_devices.world import body_to_ned

__all__ = [
    "DEFAULT_NOISE",
    "HEADING_ERROR",
    "InsEmulator",
    "InsSample",
    "body_rates",
    "latlon",
    "specific_force",
]

#: noise sigmas (RMS) of the seed: angles in deg, rates deg/s, SI otherwise
DEFAULT_NOISE: dict[str, float] = {
    "heading_deg": 0.3,
    "roll_deg": 0.02,
    "pitch_deg": 0.02,
    "rate_dps": 0.05,
    "accel_mps2": 0.01,
    "vel_mps": 0.01,
    "pos_m": 0.5,
    "depth_m": 0.02,
}

#: the slowly varying heading error (off by default): steady-state RMS and constant offset in
#: deg, correlation time in s (see the module docstring)
HEADING_ERROR: dict[str, float] = {
    "heading_bias_deg": 0.0,
    "heading_bias_tau_s": 300.0,
    "heading_offset_deg": 0.0,
}

#: heading-dependent compass deviation of a magnetic AHRS (off by default), deg:
#: ``a1 sin(psi) + b1 cos(psi) + a2 sin(2 psi) + b2 cos(2 psi)`` of the true heading psi
DEVIATION: dict[str, float] = {
    "deviation_a1_deg": 0.0,
    "deviation_b1_deg": 0.0,
    "deviation_a2_deg": 0.0,
    "deviation_b2_deg": 0.0,
}

#: the device clock field wraps (u32 of 100 us ticks in the shipped table)
_TIME_TICKS = 10_000
_TIME_WRAP = 1 << 32
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3


def body_rates(s: TruthSample) -> np.ndarray:
    """Body angular rates (p, q, r) in rad/s from the truth's Euler angles and rates."""
    sr, cr = math.sin(s.roll), math.cos(s.roll)
    sp, cp = math.sin(s.pitch), math.cos(s.pitch)
    return np.array(
        [
            s.roll_rate - s.yaw_rate * sp,
            s.pitch_rate * cr + s.yaw_rate * sr * cp,
            -s.pitch_rate * sr + s.yaw_rate * cr * cp,
        ]
    )


def specific_force(s: TruthSample) -> np.ndarray:
    """Specific force in the body frame, m/s^2: ``R^T (a_ned - (0, 0, g))``."""
    r = body_to_ned(s.heading, s.pitch, s.roll)
    return r.T @ np.array([s.an, s.ae, s.ad - GRAVITY])


def latlon(x: float, y: float, lat0: float, lon0: float) -> tuple[float, float]:
    """WGS-84 latitude and longitude (rad) of local (x north, y east) m around (lat0, lon0)
    rad, with the meridian and prime-vertical radii at lat0 (flat earth, fine over km)."""
    s2 = math.sin(lat0) ** 2
    m = _WGS84_A * (1 - _WGS84_E2) / (1 - _WGS84_E2 * s2) ** 1.5
    n = _WGS84_A / math.sqrt(1 - _WGS84_E2 * s2)
    return lat0 + x / m, lon0 + y / (n * math.cos(lat0))


@dataclass(frozen=True)
class InsSample:
    """One INS output in SI: ``time`` device clock s; ``roll, pitch, heading`` rad;
    ``rates`` body rad/s; ``accel`` body specific force m/s^2; ``vel_ned`` m/s;
    ``latitude, longitude`` rad; ``depth`` m; ``seq`` the epoch counter; ``burst`` whether
    this sample's noise was a VB noise burst; ``heading_error`` the slowly varying part of the
    heading error (offset + Gauss-Markov bias, rad; the white noise not included)."""

    seq: int
    t: float
    time: float
    roll: float
    pitch: float
    heading: float
    rates: tuple[float, float, float]
    accel: tuple[float, float, float]
    vel_ned: tuple[float, float, float]
    latitude: float
    longitude: float
    depth: float
    burst: bool
    heading_error: float = 0.0


class InsEmulator(SerialCanEmulator, device="hn100"):
    """The HN-100 INS (see the module docstring)."""

    nominal_rate_hz = 100.0
    default_baud = 115200

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        self.check_noise_keys([*DEFAULT_NOISE, *HEADING_ERROR, *DEVIATION])
        self.deviation = tuple(math.radians(self.noise(k, v)) for k, v in DEVIATION.items())
        self.sigma = {k: self.noise(k, v) for k, v in DEFAULT_NOISE.items()}
        d2r = math.pi / 180.0
        self.bias_sigma = self.noise("heading_bias_deg", 0.0) * d2r
        self.bias_tau = self.noise("heading_bias_tau_s", HEADING_ERROR["heading_bias_tau_s"])
        self.heading_offset = self.noise("heading_offset_deg", 0.0) * d2r
        if self.bias_sigma < 0:
            raise ValueError("devices.ins.noise.heading_bias_deg: must be >= 0 (an RMS)")
        if self.bias_sigma > 0 and not self.bias_tau > 0:
            raise ValueError(
                "devices.ins.noise.heading_bias_tau_s: the correlation time must be > 0 s, got "
                f"{self.bias_tau}"
            )
        #: the Gauss-Markov heading bias (rad) at vehicle time ``_bias_t`` (None: not drawn yet)
        self.heading_bias = 0.0
        self._bias_t: float | None = None
        self._bias_rng = self.ctx.rng(self.name + "/heading_bias")
        self.origin = (
            math.radians(self.option("origin_lat_deg", 59.43)),
            math.radians(self.option("origin_lon_deg", 10.47)),
        )
        self.add_wires(hn100.Hn100Codec, hn100.CODEC, hn100_can)
        self.status = self.codec.status_word(aligned=True, dvl_aided=True)
        self.seq = 0

    def heading_error(self, t: float) -> float:
        """The slowly varying heading error at vehicle time ``t``, rad: the constant offset plus
        the Gauss-Markov bias, propagated from the previous call (exact discretisation; a call
        with an earlier ``t`` keeps the bias)."""
        if self.bias_sigma > 0:
            if self._bias_t is None:  # stationary start
                self.heading_bias = float(self._bias_rng.normal(0.0, self.bias_sigma))
            elif t > self._bias_t:
                phi = math.exp(-(t - self._bias_t) / self.bias_tau)
                w = float(self._bias_rng.normal())
                self.heading_bias = phi * self.heading_bias + math.sqrt(1.0 - phi * phi) * (
                    self.bias_sigma * w
                )
            if self._bias_t is None or t > self._bias_t:
                self._bias_t = t
        return self.heading_offset + self.heading_bias

    def measure(self, t: float) -> InsSample:
        """The INS output at vehicle time ``t`` (truth plus noise); advances ``seq``."""
        s = self.truth(t)
        err = self.heading_error(t)
        if any(self.deviation):
            a1, b1, a2, b2 = self.deviation
            h = s.heading
            err += a1 * math.sin(h) + b1 * math.cos(h) + a2 * math.sin(2 * h) + b2 * math.cos(2 * h)
        k = self.sigma_scale()
        g = self.rng.normal(0.0, 1.0, 15) * k
        sig = self.sigma
        d2r = math.pi / 180.0
        rates = body_rates(s) + g[3:6] * sig["rate_dps"] * d2r
        accel = specific_force(s) + g[6:9] * sig["accel_mps2"]
        vn, ve = s.vn, s.ve
        if err != 0.0:  # the velocity resolved with the erroneous heading
            ce, se = math.cos(err), math.sin(err)
            vn, ve = ce * s.vn - se * s.ve, se * s.vn + ce * s.ve
        vel = np.array([vn, ve, s.vd]) + g[9:12] * sig["vel_mps"]
        lat, lon = latlon(s.x + g[12] * sig["pos_m"], s.y + g[13] * sig["pos_m"], *self.origin)
        ticks = round(self.device_time(t) * _TIME_TICKS) % _TIME_WRAP
        roll = (s.roll + g[0] * sig["roll_deg"] * d2r + math.pi) % (2 * math.pi) - math.pi
        out = InsSample(
            seq=self.seq,
            t=t,
            time=ticks / _TIME_TICKS,
            roll=roll,
            pitch=s.pitch + g[1] * sig["pitch_deg"] * d2r,
            heading=(s.heading + err + g[2] * sig["heading_deg"] * d2r) % (2 * math.pi),
            rates=tuple(rates.tolist()),  # type: ignore[arg-type]
            accel=tuple(accel.tolist()),  # type: ignore[arg-type]
            vel_ned=tuple(vel.tolist()),  # type: ignore[arg-type]
            latitude=lat,
            longitude=lon,
            depth=s.z + g[14] * sig["depth_m"],
            burst=k > 1.0,
            heading_error=err,
        )
        self.seq += 1
        return out

    def _fields(self, m: InsSample) -> dict[str, Any]:
        return {
            "time": m.time,
            "roll": m.roll,
            "pitch": m.pitch,
            "heading": m.heading,
            "rate_x": m.rates[0],
            "rate_y": m.rates[1],
            "rate_z": m.rates[2],
            "accel_x": m.accel[0],
            "accel_y": m.accel[1],
            "accel_z": m.accel[2],
            "vel_n": m.vel_ned[0],
            "vel_e": m.vel_ned[1],
            "vel_d": m.vel_ned[2],
            "latitude": m.latitude,
            "longitude": m.longitude,
            "depth": m.depth,
        }

    def encode_serial(self, m: InsSample) -> bytes:
        """The binary frame of one sample (the codec's table)."""
        msg = self.codec.message_type(seq=m.seq & 0xFFFF, status=self.status, **self._fields(m))
        return self.codec.encode(msg)

    def encode_can(self, m: InsSample) -> list[Any]:
        """The CAN frames of one sample (the DBC's epoch burst)."""
        assert self.can_codec is not None and self.can_codec.sample_type is not None
        sample = self.can_codec.sample_type(
            seq=m.seq & 0xFF,
            alignment="FINE",
            gnss_aided=0,
            dvl_aided=1,
            error="OK",
            reserved=0,
            **self._fields(m),
        )
        return self.can_codec.encode_sample(sample, strict=False)  # ranges checked by the codec
