"""Rotations, lever arms and angle wrapping (NED / body axes, radians).

Conventions (``config/scenario.py``): NED local frame; body axes x forward, y starboard, z down;
attitude = ZYX Euler (heading psi from north towards east, pitch theta nose up, roll phi
starboard down); ``C = Rz(psi) Ry(theta) Rx(phi)`` maps body vectors into NED.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from auvgw.fusion.config import DvlMount
from auvgw.fusion.samples import DvlSample, InsSample
from auvgw.ground.geometry import (
    dcm_body_to_ned,
    rot_x,
    rot_y,
    rot_z,
    wrap_angle,
    wrap_angles,
)

__all__ = [
    "beam_matrix",
    "beam_to_instrument",
    "body_to_ned",
    "dcm_body_to_ned",
    "dvl_to_body_velocity",
    "dvl_velocity_ned",
    "lever_arm_velocity",
    "mount_matrix",
    "rot_x",
    "rot_y",
    "rot_z",
    "wrap_angle",
    "wrap_angles",
]

def body_to_ned(
    v_body: Sequence[float] | np.ndarray, roll: float, pitch: float, heading: float
) -> np.ndarray:
    """A body-axes vector (e.g. velocity, m/s) expressed in NED."""
    return dcm_body_to_ned(roll, pitch, heading) @ np.asarray(v_body, dtype=float)


def mount_matrix(mount: DvlMount) -> np.ndarray:
    """``M``: DVL instrument axes -> body axes, from ``mount.rotation_deg`` (roll, pitch, yaw)."""
    r, p, y = (math.radians(a) for a in mount.rotation_deg)
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def lever_arm_velocity(omega: Sequence[float], lever_arm: Sequence[float]) -> np.ndarray:
    """``omega x r``: extra velocity (m/s, body axes) of a point at ``lever_arm`` (m, body axes)
    on a body rotating at ``omega`` (rad/s, body axes)."""
    return np.cross(np.asarray(omega, dtype=float), np.asarray(lever_arm, dtype=float))


def dvl_to_body_velocity(sample: DvlSample, omega: Sequence[float], mount: DvlMount) -> np.ndarray:
    """Vehicle (reference point) velocity in body axes from a DVL velocity, m/s.

    Inverts ``v_dvl = M^T (v + omega x r)`` (instrument frame) or ``v_dvl = v + omega x r``
    (body frame); ``omega`` is the body rate at the DVL's own time.
    """
    v = np.asarray(sample.velocity, dtype=float)
    if sample.frame == "instrument":
        v = mount_matrix(mount) @ v
    return v - lever_arm_velocity(omega, mount.lever_arm_m)


def dvl_velocity_ned(sample: DvlSample, ins_at_t: InsSample, mount: DvlMount) -> np.ndarray:
    """A DVL fix as vehicle velocity in NED (m/s), rotated by the attitude at the DVL's time.

    ``ins_at_t`` must be the INS state at ``sample.t`` (see
    :func:`auvgw.fusion.align.interpolate_ins`), never simply the latest INS sample.
    """
    if abs(ins_at_t.t - sample.t) > 1e-9:
        raise ValueError(
            f"INS attitude at t={ins_at_t.t!r} s used for a DVL fix at t={sample.t!r} s; "
            "interpolate the INS to the DVL time first"
        )
    v_body = dvl_to_body_velocity(sample, ins_at_t.rates, mount)
    return body_to_ned(v_body, ins_at_t.roll, ins_at_t.pitch, ins_at_t.heading)


def beam_matrix(angle: float, convex: bool = True) -> np.ndarray:
    """4 x 3 outward unit vectors of beams 1-4 in RDI instrument axes (X beam 1 -> 2, Y beam
    4 -> 3, Z toward the face): a closing speed along beam i is ``row_i . v_instrument``.
    ``angle``: Janus angle from the vertical, rad. ``convex``: beam 1 points to -X, beam 3 to
    +Y (concave: crossed)."""
    s, c = math.sin(angle), math.cos(angle)
    k = 1.0 if convex else -1.0
    return np.array(
        [[-k * s, 0.0, -c], [k * s, 0.0, -c], [0.0, k * s, -c], [0.0, -k * s, -c]]
    )


def beam_to_instrument(
    beams: Sequence[float] | np.ndarray, angle: float, convex: bool = True
) -> np.ndarray:
    """Instrument-axes velocity (m/s) from 3 or 4 beam closing speeds (NaN = bad beam) by least
    squares with the Janus geometry; all NaN with fewer than 3 good beams."""
    raw = np.asarray(beams, dtype=float)
    good = np.isfinite(raw)
    if raw.shape != (4,):
        raise ValueError(f"beam velocities: expected 4 beams (NaN = bad), got {raw.shape}")
    if int(good.sum()) < 3:
        return np.full(3, math.nan)
    B = beam_matrix(angle, convex)
    return np.linalg.lstsq(B[good], raw[good], rcond=None)[0]
