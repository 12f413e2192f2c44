"""DVL mounting yaw and scale factor from a run with position fixes (``auvgw fusion calibrate``).

Each DVL fix ``v_j`` (instrument axes turned into body axes by the configured mounting roll and
pitch - NOT its yaw - taken horizontally) is rotated by the attitude source's heading at its
time and held until the next fix (at most ``max_hold_s``): ``A_k = sum_j e^{i psi_j} v_j dt_j``
is the displacement the DVL reports from the start to position fix ``k`` (complex north + i
east). Between fixes ``k`` and ``k+1`` the DVL says ``A_{k+1} - A_k`` and the fixes say
``p_{k+1} - p_k``. For a vehicle near level, a mounting yaw ``gamma`` and a scale factor ``s``
(the DVL reads ``s`` times the true speed) give ``p_{k+1} - p_k = c (A_{k+1} - A_k) + noise``
with ``c = e^{i gamma} / s``. Every fix enters two successive differences, so the least squares
over the differences with independent fix noise is the fit ``p_k = p_0 + c A_k``: with both
centred, ``c = sum conj(A_k) p_k / sum |A_k|^2``, ``gamma = arg c`` and ``s = 1 / |c|``; their
1-sigma follow from the residual scatter (``var c = sigma_r^2 / sum |A_k|^2``, ``sigma_r^2 =
sum |p_k - p_0 - c A_k|^2 / (K - 2)``). That sigma assumes independent residuals: a slowly
varying heading error makes them correlated and the true spread larger.

A constant heading error of the attitude source looks like a mounting yaw and is absorbed into
``gamma`` (give the heading offset and declination in the config first). DVL fixes faster than
``max_speed_mps`` are left out (spikes); less than ``min_distance_m`` of DVL motion over the
fixes is an error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from auvgw.fusion.config import DvlMount
from auvgw.fusion.frames import beam_to_instrument, rot_x, rot_y
from auvgw.fusion.samples import DvlSample, InsSample, PositionFix
from auvgw.ground.errors import DataError

__all__ = ["CalibrationError", "DvlCalibration", "calibrate_dvl"]


class CalibrationError(DataError):
    """Not enough usable data for a calibration (says what is missing)."""


@dataclass(frozen=True)
class DvlCalibration:
    """Estimated DVL mounting yaw (deg, instrument -> body, as ``DvlMount.rotation_deg[2]``) and
    scale factor (as ``DvlMount.scale_factor``), with 1-sigma; ``fixes`` position fixes used;
    ``residual_m`` RMS horizontal misfit of the fixes, m; ``distance_m`` by the DVL."""

    yaw_deg: float
    yaw_sigma_deg: float
    scale_factor: float
    scale_sigma: float
    fixes: int
    residual_m: float
    distance_m: float

    def describe(self) -> str:
        """Human-readable result (what ``auvgw fusion calibrate`` prints)."""
        return (
            f"DVL mounting yaw  {self.yaw_deg:.2f} deg +- {self.yaw_sigma_deg:.2f} deg (1-sigma)\n"
            f"DVL scale factor  {self.scale_factor:.5f} +- {self.scale_sigma:.5f} "
            f"({100 * (self.scale_factor - 1):+.3f} % +- {100 * self.scale_sigma:.3f} %)\n"
            f"from {self.fixes} position fixes over {self.distance_m:.1f} m, residual "
            f"{self.residual_m:.2f} m RMS\n"
            f"config: [filter.dvl] rotation_deg = [r, p, {self.yaw_deg:.2f}], "
            f"scale_factor = {self.scale_factor:.5f}"
        )


def _dvl_body(d: DvlSample, mount: DvlMount) -> np.ndarray | None:
    """A fix as body-axes velocity without the mounting yaw (NaN -> None)."""
    v = np.asarray(d.velocity, dtype=float)
    if d.frame == "beam":
        v = beam_to_instrument(v, math.radians(mount.beam_angle_deg), mount.beam_convex)
    elif d.frame not in ("instrument", "body"):
        raise CalibrationError(
            f"DVL fix at t={d.t}: frame {d.frame!r} cannot be calibrated (the mounting yaw of "
            "earth-frame velocities is the DVL's own business)"
        )
    if not d.bottom_lock or not np.isfinite(v[:3]).all():
        return None
    v = v[:3]
    if d.frame != "body":
        r, p, _ = (math.radians(a) for a in mount.rotation_deg)
        v = rot_y(p) @ rot_x(r) @ v
    return v


def calibrate_dvl(
    ins: Sequence[InsSample],
    dvl: Sequence[DvlSample],
    fixes: Sequence[PositionFix],
    mount: DvlMount | None = None,
    max_speed_mps: float = 5.0,
    min_distance_m: float = 1.0,
    max_hold_s: float = 5.0,
) -> DvlCalibration:
    """Least-squares DVL mounting yaw and scale factor (see the module docstring). ``ins``:
    attitude samples (heading already corrected for offset/declination), ``dvl`` fixes,
    ``fixes`` position fixes, all on one clock; ``mount``: the configured roll, pitch and beam
    geometry (its yaw and scale are what is estimated). A DVL fix is held for at most
    ``max_hold_s``."""
    mount = mount or DvlMount()
    ins = sorted(ins, key=lambda s: s.t)
    fixes = sorted(fixes, key=lambda f: f.t)
    if len(ins) < 2:
        raise CalibrationError("calibration needs attitude samples (none or one given)")
    if len(fixes) < 3:
        raise CalibrationError(f"calibration needs at least 3 position fixes, got {len(fixes)}")
    t_ins = np.array([s.t for s in ins])
    head = np.unwrap(np.array([s.heading for s in ins]))
    tv, vv = [], []
    for d in sorted(dvl, key=lambda d: d.t):
        v = _dvl_body(d, mount)
        if v is None or math.hypot(v[0], v[1]) > max_speed_mps:
            continue
        if not t_ins[0] <= d.t <= t_ins[-1]:
            continue
        tv.append(d.t)
        vv.append(complex(v[0], v[1]) * np.exp(1j * np.interp(d.t, t_ins, head)))
    if len(tv) < 2:
        raise CalibrationError("calibration needs DVL fixes with bottom lock inside the attitude")
    t_d = np.array(tv)
    v_d = np.array(vv)
    # each fix held until the next one (at most max_hold_s): cumulative displacement at t_d
    hold = np.minimum(np.diff(t_d), max_hold_s)
    cum = np.concatenate([[0.0], np.cumsum(v_d[:-1] * hold)])

    def disp_at(t: float) -> complex:
        i = int(np.searchsorted(t_d, t, side="right")) - 1
        if i < 0:
            return 0j
        return complex(cum[i] + v_d[i] * min(t - t_d[i], max_hold_s))

    keep = [f for f in fixes if t_d[0] <= f.t <= t_d[-1] + max_hold_s]
    if len(keep) < 3:
        raise CalibrationError(
            f"calibration needs at least 3 position fixes inside the DVL data, got {len(keep)}"
        )
    A = np.array([disp_at(f.t) for f in keep])
    P = np.array([complex(f.north, f.east) for f in keep])
    span = float(np.sum(np.abs(np.diff(A))))
    if span < min_distance_m:
        raise CalibrationError(f"the DVL moved {span:.2f} m between the fixes: too little")
    # p_k = p0 + c A_k: centre both, then the complex least squares of c
    Ac = A - A.mean()
    Pc = P - P.mean()
    c = complex(np.sum(np.conj(Ac) * Pc) / np.sum(np.abs(Ac) ** 2))
    res = Pc - c * Ac
    k = len(A)
    sr2 = float(np.sum(np.abs(res) ** 2)) / (k - 2)
    var_c = sr2 / float(np.sum(np.abs(Ac) ** 2))
    sig_axis = math.sqrt(var_c / 2.0)  # per real component of c
    mag = abs(c)
    return DvlCalibration(
        yaw_deg=math.degrees(math.atan2(c.imag, c.real)),
        yaw_sigma_deg=math.degrees(sig_axis / mag),
        scale_factor=1.0 / mag,
        scale_sigma=sig_axis / (mag * mag),
        fixes=k,
        residual_m=math.sqrt(float(np.mean(np.abs(res) ** 2))),
        distance_m=span,
    )
