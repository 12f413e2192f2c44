"""Fusion output: :class:`Odometry` at the INS rate and the :class:`MotionIncrement` SLAM uses.

Both are immutable messages (``auvgw.drivers.spec.message``: frozen, array-aware equality,
registered for ``to_jsonable`` / ``from_jsonable``), the same objects online (published on
``auv/<v>/nav/odometry``) and offline (:func:`auvgw.fusion.offline.run_filter`).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from auvgw.drivers.spec import message
from auvgw.fusion.ekf import STATE_NAMES

__all__ = ["STATE_NAMES", "MotionIncrement", "Odometry"]


@message
class MotionIncrement:
    """Motion over one INS step ``[t0, t1]``, in the level body frame at ``t0``.

    ``dx`` forward and ``dy`` starboard (m, horizontal, axes turned by the heading at ``t0``),
    ``dz`` depth change (m, down), ``dheading`` (rad). ``covariance``: 3 x 3 over
    ``(dx, dy, dheading)`` - the marginal uncertainty of this step (velocity and attitude-error
    contributions; successive steps' errors are correlated through the velocity error, which the
    filter's full covariance carries).

    ``v_forward``, ``v_starboard`` (m/s), ``yaw_rate`` (rad/s) and ``dt`` (s) are the equivalent
    inputs of eq. (3) of Mu et al. 2022 (``V_x, V_y, W, dT``): fed to eq. (3) from the pose at
    ``t0`` they give exactly the filter's pose at ``t1`` (:meth:`apply`); their covariance is
    :attr:`input_covariance`.
    """

    TYPE = "MotionIncrement"

    t0: float
    t1: float
    dx: float
    dy: float
    dz: float
    dheading: float
    covariance: np.ndarray
    dt: float
    v_forward: float
    v_starboard: float
    yaw_rate: float

    @property
    def input_covariance(self) -> np.ndarray:
        """Covariance of ``(v_forward, v_starboard, yaw_rate)``: ``covariance / dt^2``."""
        return self.covariance / (self.dt * self.dt)

    def apply(self, x: float, y: float, heading: float) -> tuple[float, float, float]:
        """Eq. (3): the pose ``(x, y, heading)`` (m, m, rad) moved by this increment."""
        c, s = math.cos(heading), math.sin(heading)
        vdt_x, vdt_y = self.v_forward * self.dt, self.v_starboard * self.dt
        return (
            x + vdt_x * c - vdt_y * s,
            y + vdt_x * s + vdt_y * c,
            heading + self.yaw_rate * self.dt,
        )


@message
class Odometry:
    """Dead-reckoned navigation state at an INS time ``t`` (s, common clock).

    Pose: ``x``, ``y``, ``z`` NED (m) of the vehicle reference point; ``roll`` (INS), ``pitch``
    and ``heading`` (rad, heading wrapped to [-pi, pi)). ``velocity_ned`` and ``velocity_body``
    (m/s) over the seabed; ``angular_rate`` body (p, q, r) rad/s from the INS.
    ``covariance``: 8 x 8 over :data:`STATE_NAMES` ``(x, y, z, heading, pitch, u, v, w)``;
    :attr:`cov_xy` and :attr:`cov_pose2d` are its horizontal and ``(x, y, heading)`` blocks.

    Flags: ``bottom_lock`` (the latest DVL fix had bottom track), ``coasting`` (no DVL velocity
    accepted for ``dvl_timeout_s`` or lock lost: velocity held, covariance growing),
    ``dvl_age_s`` / ``depth_age_s`` (s since the last accepted fix, NaN if none), ``ins_gap`` (the
    INS interval ending here exceeded ``max_ins_gap_s``). ``increment``: the motion since the
    previous output (None for the first).
    """

    TYPE = "Odometry"
    STATE_NAMES: ClassVar[tuple[str, ...]] = STATE_NAMES

    t: float
    x: float
    y: float
    z: float
    roll: float
    pitch: float
    heading: float
    velocity_ned: tuple[float, float, float]
    velocity_body: tuple[float, float, float]
    angular_rate: tuple[float, float, float]
    covariance: np.ndarray
    bottom_lock: bool
    coasting: bool
    dvl_age_s: float
    depth_age_s: float
    ins_gap: bool
    increment: MotionIncrement | None

    @property
    def cov_xy(self) -> np.ndarray:
        """Horizontal position covariance (x, y), m^2."""
        return self.covariance[0:2, 0:2]

    @property
    def cov_pose2d(self) -> np.ndarray:
        """Covariance of the 2-D pose ``(x, y, heading)``."""
        idx = np.array([0, 1, 3])
        return self.covariance[np.ix_(idx, idx)]

    @property
    def pose2d(self) -> tuple[float, float, float]:
        """``(x, y, heading)``: the SLAM papers' vehicle state (eq. 1)."""
        return (self.x, self.y, self.heading)
