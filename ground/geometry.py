"""Angles, rotations and chi-square gates: the one home for the project's small numerics.

Conventions (``config/scenario.py``): local NED frame (x north, y east, z down, metres); body
axes x forward, y starboard, z down; attitude = ZYX Euler angles in radians (heading from north
towards east, pitch nose up, roll starboard down); ``C = Rz(heading) Ry(pitch) Rx(roll)`` maps
body vectors into NED. Pure numpy/math: algorithms, emulators and viewers all import it.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "TWO_PI",
    "body_to_ned_matrix",
    "chi2_ppf",
    "dcm_body_to_ned",
    "quaternion_zyx",
    "rot_x",
    "rot_y",
    "rot_z",
    "wrap_angle",
    "wrap_angles",
]

TWO_PI = 2.0 * math.pi


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: NDArray[np.floating]) -> NDArray[np.float64]: ...
def wrap_angle(a: float | NDArray[np.floating]) -> float | NDArray[np.float64]:
    """Angle(s) in radians wrapped into [-pi, pi): a float for a float, an array for an array."""
    if isinstance(a, np.ndarray):
        return wrap_angles(a)
    return (float(a) + math.pi) % TWO_PI - math.pi


def wrap_angles(a: NDArray[np.floating] | float) -> NDArray[np.float64]:
    """Angles in radians wrapped into [-pi, pi), always as a float array."""
    return (np.asarray(a, dtype=float) + math.pi) % TWO_PI - math.pi


def rot_x(a: float) -> NDArray[np.float64]:
    """Rotation matrix about x by ``a`` rad (roll)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> NDArray[np.float64]:
    """Rotation matrix about y by ``a`` rad (pitch)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> NDArray[np.float64]:
    """Rotation matrix about z by ``a`` rad (heading)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def body_to_ned_matrix(
    heading: float, pitch: float = 0.0, roll: float = 0.0
) -> NDArray[np.float64]:
    """``R = Rz(heading) Ry(pitch) Rx(roll)`` written out: body axes (x forward, y starboard,
    z down) -> NED, angles in rad (heading 0: body -> level). The emulators and the DVL adapter
    use it; equal to :func:`dcm_body_to_ned` but for rounding."""
    ch, sh = math.cos(heading), math.sin(heading)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return np.array(
        [
            [ch * cp, ch * sp * sr - sh * cr, ch * sp * cr + sh * sr],
            [sh * cp, sh * sp * sr + ch * cr, sh * sp * cr - ch * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def dcm_body_to_ned(roll: float, pitch: float, heading: float) -> NDArray[np.float64]:
    """``C = Rz(heading) Ry(pitch) Rx(roll)``: body-axes vector -> NED (angles in rad)."""
    return rot_z(heading) @ rot_y(pitch) @ rot_x(roll)


def quaternion_zyx(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of ``Rz(yaw) Ry(pitch) Rx(roll)`` (angles in rad)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def chi2_ppf(p: float, dof: int) -> float:
    """Chi-square quantile (``scipy.stats.chi2.ppf``) through ``scipy.special``, which imports in
    a fraction of the time ``scipy.stats`` takes (every command start paid for it)."""
    from scipy.special import gammaincinv

    return 2.0 * float(gammaincinv(dof / 2.0, p))
