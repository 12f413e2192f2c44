"""Online estimate of a magnetic compass's heading-dependent deviation from the AHRS's own gyro.

A magnetic heading carries the classic compass deviation (the model of every compass swing)

    psi_c = psi + A + B sin psi + C cos psi + D sin 2psi + E cos 2psi + noise,

``psi`` the true magnetic heading. The gyro's integrated yaw rate ``psi_g`` follows the true
heading up to a slowly varying error ``delta`` (its start value and the integrated gyro bias
``b``): ``psi = psi_g - delta``. So the compass-minus-gyro heading

    z = psi_c - psi_g = -delta' + B sin psi + C cos psi + D sin 2psi + E cos 2psi + noise

(``delta' = delta - A``) is linear in the state ``x = (delta', b, B, C, D, E)``, and a small
Kalman filter estimates it: ``delta' <- delta' + b h`` plus the gyro's angle random walk, ``b``
a random walk. On a straight leg only ``-delta' + d(psi)`` is seen; every turn through new
headings makes the differences ``d(psi_2) - d(psi_1)`` observable, and with them B..E. The
constant A is a heading offset: without position fixes nothing distinguishes it from the true
heading, so it stays the config's ``heading_offset_deg`` (the estimate here has zero mean over
the headings, by the model).

The estimate is used (``correction``) only where it is confident: the 1-sigma of ``d(psi)`` at
the current heading below ``compass_deviation_max_sigma_deg``. A source without gyros (all
rates exactly zero, e.g. a DVL's compass) is never corrected. Pure computation; angles in
radians, times in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from auvgw.fusion.config import FusionConfig
from auvgw.fusion.frames import wrap_angle
from auvgw.ground.geometry import chi2_ppf

__all__ = ["CompassDeviationEstimator", "deviation_regressors"]

#: names of the estimated deviation coefficients, in state order (after delta and bias)
COEFFICIENTS = ("B_sin", "C_cos", "D_sin2", "E_cos2")


def _phi(psi: float) -> tuple[float, float, float, float]:
    s, c = math.sin(psi), math.cos(psi)
    return (s, c, 2.0 * s * c, c * c - s * s)


def deviation_regressors(psi: float) -> np.ndarray:
    """``(sin psi, cos psi, sin 2psi, cos 2psi)``: the deviation is their dot product with
    ``(B, C, D, E)``."""
    return np.array([math.sin(psi), math.cos(psi), math.sin(2 * psi), math.cos(2 * psi)])


_GRID = np.array([deviation_regressors(math.radians(a)) for a in range(0, 360, 5)])


class CompassDeviationEstimator:
    """Kalman filter of ``x = (delta', gyro bias, B, C, D, E)`` fed by attitude samples in time
    order (see the module docstring).

    ``coefficient_sigma``: prior 1-sigma of each of B..E (rad); ``compass_sigma``: white noise
    of one compass heading (rad); ``angle_random_walk``: gyro heading noise (rad/sqrt(s));
    ``bias_sigma``: prior 1-sigma of the yaw-rate bias (rad/s); ``bias_random_walk``: its drift
    (rad/s/sqrt(s)); ``interval_s``: time between updates (compass noise is seldom white at the
    sample rate); ``max_sigma``: the correction is applied where the 1-sigma of the deviation at
    the current heading is below it (rad); ``max_gap_s``: a longer interval between samples
    loses the gyro heading (delta' restarted); ``detect_chi2``: nothing is applied until the
    coefficients differ from zero, ``c^T P_c^-1 c`` above it (a chi-square quantile, 4 dof).
    """

    def __init__(
        self,
        coefficient_sigma: float,
        compass_sigma: float,
        angle_random_walk: float,
        bias_sigma: float,
        bias_random_walk: float,
        interval_s: float = 1.0,
        max_sigma: float = math.radians(1.0),
        max_gap_s: float = 2.0,
        detect_chi2: float = 0.0,
    ) -> None:
        self.compass_var = compass_sigma**2
        self.arw2 = angle_random_walk**2
        self.brw2 = bias_random_walk**2
        self.interval_s = interval_s
        self.max_sigma = max_sigma
        self.max_gap_s = max_gap_s
        self.detect_chi2 = detect_chi2
        self.x = np.zeros(6)
        self.P = np.diag([math.pi**2, bias_sigma**2] + [coefficient_sigma**2] * 4)
        self._delta_var0 = math.pi**2
        self.psi_gyro = math.nan  #: integrated heading of the gyro, rad (unwrapped)
        self._t = math.nan  #: time of the last sample
        self._rate = 0.0  #: heading rate of the last sample, rad/s
        self._t_update = -math.inf  #: time of the last Kalman update
        self._t_predict = math.nan  #: time the state was last propagated to
        self.updates = 0
        self.has_gyro = False  #: a sample with a non-zero rate was seen
        self.last_sigma = math.inf  #: 1-sigma of the deviation at the last heading, rad
        self.last_phi = (0.0, 0.0, 0.0, 0.0)  #: regressors at the last corrected heading
        self._refresh()

    @classmethod
    def from_config(cls, cfg: FusionConfig) -> CompassDeviationEstimator:
        """The estimator with the ``compass_*`` and ``gyro_*`` settings of ``cfg``."""
        r = math.radians
        return cls(
            coefficient_sigma=r(cfg.compass_deviation_prior_deg),
            compass_sigma=r(cfg.compass_noise_deg),
            angle_random_walk=r(cfg.gyro_angle_random_walk_deg_rt_s),
            bias_sigma=r(cfg.gyro_bias_sigma_dps),
            bias_random_walk=r(cfg.gyro_bias_random_walk_dps_rt_s),
            interval_s=cfg.compass_update_interval_s,
            max_sigma=r(cfg.compass_deviation_max_sigma_deg),
            detect_chi2=float(chi2_ppf(cfg.compass_deviation_detect_probability, 4)),
        )

    # ---- input ----------------------------------------------------------------------------
    def add(
        self, t: float, heading: float, roll: float, pitch: float, rates: Sequence[float]
    ) -> None:
        """One attitude sample: compass heading (rad, before any correction), roll and pitch
        (rad), body rates p, q, r (rad/s). Samples must come in time order."""
        p, q, r = rates[:3]
        rate = (q * math.sin(roll) + r * math.cos(roll)) / max(math.cos(pitch), 1e-6)
        self.has_gyro = self.has_gyro or p != 0.0 or q != 0.0 or r != 0.0
        if math.isnan(self._t):
            self.psi_gyro = heading
            self._t = self._t_predict = t
            self._rate = rate
        else:
            h = t - self._t
            if not h > 0:
                return
            if h > self.max_gap_s:  # the gyro heading is lost over the gap: restart delta'
                self._predict(t)
                self.psi_gyro = heading + self.x[0] - self.deviation(heading)
                self.P[0, :] = self.P[:, 0] = 0.0
                self.P[0, 0] = self._delta_var0
            else:
                self.psi_gyro += 0.5 * (self._rate + rate) * h
            self._t, self._rate = t, rate
        if self.has_gyro and t - self._t_update >= self.interval_s:
            self._update(t, heading)

    def _predict(self, t: float) -> None:
        h = t - self._t_predict
        if h <= 0:
            return
        F = np.eye(6)
        F[0, 1] = h
        self.x = F @ self.x
        P = F @ self.P @ F.T
        P[0, 0] += self.arw2 * h + self.brw2 * h**3 / 3.0
        P[0, 1] += self.brw2 * h * h / 2.0
        P[1, 0] += self.brw2 * h * h / 2.0
        P[1, 1] += self.brw2 * h
        self.P = P
        self._t_predict = t

    def _update(self, t: float, heading: float) -> None:
        self._predict(t)
        psi = wrap_angle(heading - self.deviation(heading))  # the deviation's argument
        H = np.concatenate([[-1.0, 0.0], deviation_regressors(psi)])
        z = wrap_angle(heading - self.psi_gyro)
        innovation = wrap_angle(z - float(H @ self.x))
        PH = self.P @ H
        s = float(H @ PH) + self.compass_var
        k = PH / s
        self.x = self.x + k * innovation
        self.P = self.P - np.outer(k, PH)
        self.P = 0.5 * (self.P + self.P.T)
        self._t_update = t
        self.updates += 1
        self._refresh()

    # ---- output ---------------------------------------------------------------------------
    def _refresh(self) -> None:
        """Cache the coefficients, their covariance and the confidence (per update, so that the
        per-sample outputs are plain float arithmetic)."""
        self._c: tuple[float, ...] = tuple(self.x[2:].tolist())
        self._Pc: list[list[float]] = self.P[2:, 2:].tolist()
        var = np.einsum("ij,jk,ik->i", _GRID, self.P[2:, 2:], _GRID)
        self.chi2 = float(self.x[2:] @ np.linalg.solve(self.P[2:, 2:], self.x[2:]))
        self.detected = self.has_gyro and self.updates > 0 and self.chi2 > self.detect_chi2
        self._confident = self.detected and bool(var.max() < self.max_sigma**2)

    def deviation(self, heading: float) -> float:
        """Estimated deviation (rad) at magnetic heading ``heading`` (rad)."""
        return sum(a * b for a, b in zip(_phi(heading), self._c, strict=True))

    def deviation_sigma(self, heading: float) -> float:
        """1-sigma of the estimated deviation at ``heading`` (rad)."""
        f = _phi(heading)
        var = sum(fi * sum(p * fj for p, fj in zip(row, f, strict=True))
                  for fi, row in zip(f, self._Pc, strict=True))  # fmt: skip
        return math.sqrt(max(var, 0.0))

    def confident_everywhere(self) -> bool:
        """A deviation is detected and its 1-sigma is below ``max_sigma`` at every heading
        (5 deg grid)."""
        return self._confident

    def correction(self, heading: float) -> float:
        """What to subtract from the compass heading ``heading`` (rad): the estimated deviation
        where one is detected and confident, else 0. Sets ``last_phi`` (regressors there)."""
        psi = wrap_angle(heading - self.deviation(heading))
        self.last_phi = _phi(psi)
        if not self.detected:
            self.last_sigma = math.inf
            return 0.0
        self.last_sigma = self.deviation_sigma(psi)
        return self.deviation(psi) if self.last_sigma < self.max_sigma else 0.0

    def status(self) -> dict[str, object]:
        """JSON-ready estimate: coefficients and 1-sigma (deg), gyro bias (deg/s), updates,
        whether the last correction was applied."""
        sig = np.sqrt(np.clip(np.diag(self.P), 0.0, None))
        return {
            "coefficients_deg": {
                n: math.degrees(float(v)) for n, v in zip(COEFFICIENTS, self.x[2:], strict=True)
            },
            "sigma_deg": {
                n: math.degrees(float(v)) for n, v in zip(COEFFICIENTS, sig[2:], strict=True)
            },
            "gyro_bias_dps": math.degrees(float(self.x[1])),
            "gyro_bias_sigma_dps": math.degrees(float(sig[1])),
            "sigma_at_heading_deg": (
                math.degrees(self.last_sigma) if math.isfinite(self.last_sigma) else None
            ),
            "chi2": self.chi2,
            "detected": self.detected,
            "applied": bool(self.last_sigma < self.max_sigma),
            "updates": self.updates,
            "has_gyro": self.has_gyro,
        }
