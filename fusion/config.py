"""Configuration of the navigation fusion (pydantic, frozen): mounting, noise, buffering.

Defaults are the HN-100 and Pathfinder figures of Mu et al. 2022, Table 1 (yaw 0.3 deg RMS,
pitch/roll 0.02 deg RMS at 100 Hz; DVL +-0.2 cm/s; pressure sensor 0.01 % of range), with the
INS attitude errors modelled as first-order Gauss-Markov processes (see ``docs/fusion.md``).
Angles in the configuration are degrees (fields end in ``_deg``); everything else is SI.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["DvlMount", "FusionConfig", "InitialState"]

Vec3 = tuple[float, float, float]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DvlMount(_Model):
    """Where and how the DVL sits on the vehicle.

    ``lever_arm_m``: transducer centre relative to the vehicle reference point (the INS), body
    axes (x forward, y starboard, z down), metres. ``rotation_deg``: (roll, pitch, yaw) of the
    instrument axes relative to body axes, ZYX order, degrees; a vector in instrument axes maps
    to body axes as ``Rz(yaw) Ry(pitch) Rx(roll) v``. ``scale_factor``: the DVL reports
    ``scale_factor`` times the true velocity (1.01 = reads 1 % fast; the filter divides by it;
    ``auvgw fusion calibrate`` estimates it with the mounting yaw). ``beam_angle_deg`` and
    ``beam_convex``: Janus geometry for velocities given in beam coordinates.
    """

    lever_arm_m: Vec3 = (0.0, 0.0, 0.0)
    rotation_deg: Vec3 = (0.0, 0.0, 0.0)
    scale_factor: float = Field(1.0, gt=0.5, lt=1.5)
    beam_angle_deg: float = Field(30.0, gt=0, lt=90)
    beam_convex: bool = True


class InitialState(_Model):
    """Start of dead reckoning: position NED (m), body velocity (m/s) and their 1-sigma."""

    position_m: Vec3 = (0.0, 0.0, 0.0)
    position_sigma_m: Vec3 = Field((0.1, 0.1, 1.0), description="x, y, z 1-sigma, m")
    velocity_body_mps: Vec3 = (0.0, 0.0, 0.0)
    velocity_sigma_mps: float = Field(2.0, gt=0, description="per body axis, m/s")


class FusionConfig(_Model):
    """Everything the dead-reckoning filter needs besides the data (see ``docs/fusion.md``)."""

    dvl: DvlMount = DvlMount()
    depth_lever_arm_m: Vec3 = Field(
        (0.0, 0.0, 0.0), description="stand-alone pressure sensor, body axes from the INS, m"
    )
    initial: InitialState = InitialState()

    # attitude source calibration (added to the source's heading; true = magnetic + declination)
    heading_offset_deg: float = Field(
        0.0, ge=-180, le=180, description="added to the attitude source's heading, deg"
    )
    magnetic_declination_deg: float = Field(
        0.0, ge=-180, le=180, description="true north = magnetic heading + declination, deg"
    )

    # heading-dependent compass deviation, estimated online from the source's gyro
    # (fusion/deviation.py); the constant part is heading_offset_deg above
    compass_deviation: Literal["estimate", "off"] = Field(
        "estimate",
        description="estimate: learn B sin + C cos + D sin 2psi + E cos 2psi of the magnetic "
        "heading from the attitude source's yaw rate and subtract it where confident; off: no",
    )
    compass_deviation_back_correct: bool = Field(
        True,
        description="once the estimate is confident at every heading, also correct the "
        "position for the deviation of the steps before (a jump of the position)",
    )
    compass_deviation_prior_deg: float = Field(
        10.0, gt=0, description="prior 1-sigma of each deviation coefficient, deg"
    )
    compass_noise_deg: float = Field(
        1.0, gt=0, description="white noise of one compass heading for the estimate, deg"
    )
    compass_update_interval_s: float = Field(
        1.0, ge=0, description="time between updates of the deviation estimate, s"
    )
    compass_deviation_max_sigma_deg: float = Field(
        1.0, gt=0, description="apply the estimate where its 1-sigma at the heading is below, deg"
    )
    compass_deviation_detect_probability: float = Field(
        0.999,
        ge=0,
        lt=1,
        description="apply nothing until the coefficients differ from zero at this probability "
        "(chi-square, 4 dof; 0: always)",
    )
    gyro_angle_random_walk_deg_rt_s: float = Field(
        0.05, gt=0, description="yaw-rate noise of the attitude source, deg/sqrt(s)"
    )
    gyro_bias_sigma_dps: float = Field(
        0.1, gt=0, description="prior 1-sigma of the yaw-rate bias, deg/s"
    )
    gyro_bias_random_walk_dps_rt_s: float = Field(
        3e-4, ge=0, description="drift of the yaw-rate bias, deg/s/sqrt(s)"
    )

    # measurement noise. DVL as a sensor spec: per-axis sigma = sqrt(floor^2 + (pct |v|)^2);
    # the defaults are safe for a cheap DVL, and the noise is adapted online (VB, below)
    dvl_velocity_sigma_mps: float = Field(
        0.05, gt=0, description="DVL noise floor per axis, 1-sigma, m/s"
    )
    dvl_velocity_percent: float = Field(
        1.0, ge=0, description="DVL noise proportional to speed, % of |v| (1-sigma)"
    )
    dvl_noise_adaptive: bool = Field(
        True,
        description="learn the DVL noise online (variational Bayes, Sarkka & Nummenmaa 2009); "
        "the spec above is its prior",
    )
    dvl_noise_forgetting: float = Field(
        0.99, gt=0, le=1, description="VB forgetting factor rho per DVL fix (window 1/(1-rho))"
    )
    dvl_noise_prior_dof: float = Field(
        2.0, gt=0, description="VB prior strength: inverse-gamma shape alpha0 of the spec noise"
    )
    dvl_noise_rescale: bool = Field(
        True,
        description="scale the velocity covariance with the learned DVL noise at every fix "
        "(it was built with the previous noise estimate; West & Harrison's variance learning)",
    )
    dvl_gate_predictive: bool = Field(
        True,
        description="gate adapted DVL fixes against the VB predictive (Student-t: k F(k, 2 alpha) "
        "quantile), wide while the noise is still being learned; false: chi-square",
    )
    dvl_noise_iterations: int = Field(3, ge=1, description="VB fixed-point iterations per fix")
    position_gate_probability: float | None = Field(
        0.9999, gt=0, lt=1, description="chi-square gate on position fixes; None disables"
    )
    depth_sigma_m: float = Field(0.02, gt=0, description="pressure depth 1-sigma, m")

    # INS attitude error processes (Gauss-Markov: tau 0 = white, inf = constant bias)
    heading_error_sigma_deg: float = Field(0.3, ge=0, description="INS heading error RMS, deg")
    heading_error_tau_s: float = Field(300.0, ge=0, description="its correlation time, s")
    pitch_error_sigma_deg: float = Field(0.02, ge=0, description="INS pitch error RMS, deg")
    pitch_error_tau_s: float = Field(300.0, ge=0, description="its correlation time, s")

    # velocity process noise: random walk of the body velocity, m/s per sqrt(s)
    velocity_random_walk: float = Field(
        0.02, ge=0, description="while bottom-locked (manoeuvres between DVL fixes)"
    )
    coast_velocity_random_walk: float = Field(
        0.03, ge=0, description="while coasting (no bottom lock): trust in the held velocity"
    )
    use_accelerations: bool = Field(
        False,
        description="propagate the body velocity with the INS specific force between DVL fixes "
        "(held constant otherwise and always while coasting)",
    )
    gravity_mps2: float = Field(9.80665, gt=0)

    # bottom-lock policy and gating
    dvl_timeout_s: float = Field(
        1.0, gt=0, description="coasting when no DVL velocity was accepted for this long"
    )
    dvl_gate_probability: float | None = Field(
        0.9999, gt=0, lt=1, description="chi-square gate on DVL innovations; None disables"
    )
    dvl_gate_max_rejections: int = Field(
        5, ge=1, description="after this many consecutive rejections the next fix is accepted"
    )
    diagnostics_window_s: float = Field(
        60.0, gt=0, description="window of the rejection share and NIS consistency warnings, s"
    )

    # time alignment
    max_latency_s: float = Field(
        0.2,
        ge=0,
        description="fixed lag: a sample may arrive up to this long (in sample time) after the "
        "newest INS sample and still be used; output is delayed by the same amount",
    )
    max_pending: int = Field(4096, ge=1, description="bound of the aiding-sample buffer")
    max_ins_gap_s: float = Field(0.5, gt=0, description="longer INS intervals are flagged")

    def dvl_sigma(self, speed_mps: float) -> float:
        """Spec DVL noise per axis (1-sigma, m/s) at ``speed_mps``."""
        pct = 0.01 * self.dvl_velocity_percent * speed_mps
        return math.sqrt(self.dvl_velocity_sigma_mps**2 + pct * pct)

    def heading_correction(self) -> float:
        """Added to the attitude source's heading: offset + declination, rad."""
        return math.radians(self.heading_offset_deg + self.magnetic_declination_deg)

    def gm(self, which: str) -> tuple[float, float]:
        """(sigma rad, tau s) of the ``"heading"`` or ``"pitch"`` error process."""
        if which == "heading":
            return math.radians(self.heading_error_sigma_deg), self.heading_error_tau_s
        if which == "pitch":
            return math.radians(self.pitch_error_sigma_deg), self.pitch_error_tau_s
        raise ValueError(f"unknown error process {which!r}")
