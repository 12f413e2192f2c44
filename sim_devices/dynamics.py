"""6-DOF torpedo AUV dynamics in Fossen's form (Handbook of Marine Craft Hydrodynamics, 2021).

Pure numpy, no transports or clocks: the caller owns time and passes ``dt``.

Frames and units: ``eta = [x y z phi theta psi]`` in NED (metres, radians, ZYX Euler angles);
``nu = [u v w p q r]`` in body FRD (m/s, rad/s); the state is ``[nu, eta]`` (12 floats).
Inputs ``[rudder, stern, rpm]`` (rad, rad, rev/min) are saturated at the vehicle's limits.
The ocean current is a constant NED velocity (m/s); hydrodynamic forces use the relative
velocity ``nu_r = nu - [R^T v_c, 0]``.

Model (Fossen 2021 eq. 10.?-style relative-velocity form, irrotational current):
``M nu_r_dot + C_RB(nu_r) nu_r + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau``, with
``M = M_RB + M_A`` (eq. 3.44, 6.45), ``C_RB`` the linear-velocity-independent form (eq. 3.60),
``C_A`` the skew-symmetric added-mass form (eq. 6.43), ``g`` the restoring forces (eq. 4.6),
cross-flow quadratic drag, body and fin lift (Prestero 2001) and the propeller.
Parameters come from ``config/vehicles/remus100.toml`` (every number cites its source).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "REMUS100_FILE",
    "VehicleParams",
    "coriolis",
    "energy",
    "load_params",
    "mass_matrix",
    "restoring",
    "rhs",
    "skew",
    "step",
]

Array = NDArray[np.float64]

REMUS100_FILE = Path(__file__).resolve().parent.parent / "config" / "vehicles" / "remus100.toml"


def skew(a: Array) -> Array:
    """The cross-product matrix S(a), S(a) b = a x b (Fossen eq. 2.10)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@dataclass(frozen=True)
class VehicleParams:
    """A vehicle's physical parameters (SI units, body FRD about the centre of buoyancy).

    ``damping``, ``lift`` and ``propulsion`` switch the dissipative and driving terms (the
    energy test turns them off); the numbers themselves come from :func:`load_params`.
    """

    mass: float
    weight: float
    buoyancy: float
    r_g: tuple[float, float, float]
    r_b: tuple[float, float, float]
    inertia: tuple[float, float, float]
    added: tuple[float, float, float, float, float, float, float, float]
    """Xudot Yvdot Zwdot Kpdot Mqdot Nrdot Yrdot Zqdot."""
    quad: tuple[float, float, float, float, float, float, float, float, float, float]
    """Xuu Yvv Zww Yrr Zqq Mww Nvv Mqq Nrr Kpp."""
    linear: tuple[float, float, float, float, float, float]
    body_lift: float
    """Yuvl = Zuwl = -1/2 rho d^2 c_ydb (kg/m)."""
    x_cp: float
    fin_lift: float
    """c = Yuudr (kg/(m rad)): fin force c u|u| alpha."""
    x_fin: float
    thrust_coeff: float
    """kT (N/rpm^2): T = kT n|n|."""
    torque_per_thrust: float
    max_rudder: float
    max_stern: float
    max_rpm: float
    damping: bool = True
    lift: bool = True
    propulsion: bool = True

    def conservative(self) -> VehicleParams:
        """The same vehicle with damping, lift and propulsion off (energy conserving)."""
        return replace(self, damping=False, lift=False, propulsion=False)


def _value(table: dict[str, Any], section: str, key: str, path: Path) -> Any:
    try:
        return table[section][key]["value"]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: missing [{section}] {key} = {{value = ..., source = ...}}") from exc


def load_params(path: Path = REMUS100_FILE) -> VehicleParams:
    """Load a vehicle parameter file (TOML, every entry ``{value, source}``)."""
    with path.open("rb") as f:
        t = tomllib.load(f)
    for section, entries in t.items():
        for key, entry in entries.items():
            if not isinstance(entry, dict) or not str(entry.get("source", "")).strip():
                raise ValueError(f"{path}: [{section}] {key} has no source")

    def v(s: str, k: str) -> Any:
        return _value(t, s, k, path)

    mass = float(v("rigid_body", "mass"))
    g = float(v("rigid_body", "gravity"))
    rho = float(v("rigid_body", "rho"))
    d = float(v("rigid_body", "diameter"))
    quad = tuple(float(v("damping", k)) for k in
                 ("Xuu", "Yvv", "Zww", "Yrr", "Zqq", "Mww", "Nvv", "Mqq", "Nrr", "Kpp"))
    c_fin = float(v("lift", "Yuudr"))
    # kT from the calibration point: at steady speed U the thrust balances the axial drag.
    u_cal = float(v("propulsion", "calib_speed"))
    n_cal = float(v("propulsion", "calib_rpm"))
    lin = [float(x) for x in v("damping", "linear")]
    drag = -quad[0] * u_cal * u_cal - lin[0] * u_cal
    return VehicleParams(
        mass=mass,
        weight=mass * g,
        buoyancy=float(v("rigid_body", "buoyancy")),
        r_g=tuple(float(x) for x in v("rigid_body", "r_g")),  # type: ignore[arg-type]
        r_b=tuple(float(x) for x in v("rigid_body", "r_b")),  # type: ignore[arg-type]
        inertia=tuple(float(x) for x in v("rigid_body", "inertia")),  # type: ignore[arg-type]
        added=tuple(float(v("added_mass", k)) for k in  # type: ignore[arg-type]
                    ("Xudot", "Yvdot", "Zwdot", "Kpdot", "Mqdot", "Nrdot", "Yrdot", "Zqdot")),
        quad=quad,  # type: ignore[arg-type]
        linear=tuple(lin),  # type: ignore[arg-type]
        body_lift=-0.5 * rho * d * d * float(v("lift", "body_lift_coeff")),
        x_cp=float(v("lift", "x_cp")),
        fin_lift=c_fin,
        x_fin=float(v("lift", "Nuudr")) / c_fin,
        thrust_coeff=drag / (n_cal * n_cal),
        torque_per_thrust=float(v("propulsion", "torque_per_thrust")),
        max_rudder=float(v("limits", "rudder")),
        max_stern=float(v("limits", "stern")),
        max_rpm=float(v("limits", "rpm")),
    )


def mass_matrices(p: VehicleParams) -> tuple[Array, Array]:
    """(M_RB, M_A): rigid-body (Fossen eq. 3.44) and added mass (eq. 6.45, hydrodynamic
    derivatives with their sign flipped)."""
    m = p.mass
    sg = skew(np.array(p.r_g))
    m_rb = np.zeros((6, 6))
    m_rb[:3, :3] = m * np.eye(3)
    m_rb[:3, 3:] = -m * sg
    m_rb[3:, :3] = m * sg
    m_rb[3:, 3:] = np.diag(p.inertia) - m * sg @ sg
    xu, yv, zw, kp, mq, nr, yr, zq = p.added
    m_a = -np.array([
        [xu, 0, 0, 0, 0, 0],
        [0, yv, 0, 0, 0, yr],
        [0, 0, zw, 0, zq, 0],
        [0, 0, 0, kp, 0, 0],
        [0, 0, zq, 0, mq, 0],
        [0, yr, 0, 0, 0, nr],
    ], dtype=float)
    return m_rb, m_a


def mass_matrix(p: VehicleParams) -> Array:
    """M = M_RB + M_A (6x6, symmetric positive definite)."""
    m_rb, m_a = mass_matrices(p)
    return m_rb + m_a


def coriolis(p: VehicleParams, nu: Array) -> tuple[Array, Array]:
    """(C_RB(nu), C_A(nu)). C_RB is Fossen's eq. 3.60 (independent of the linear velocity, so
    the irrotational-current form holds); C_A is the skew-symmetric eq. 6.43 form."""
    m_rb, m_a = _cache(p).m_rb, _cache(p).m_a
    v1, w = nu[:3], nu[3:]
    sw = skew(w)
    sg = skew(np.array(p.r_g))
    i_b = m_rb[3:, 3:]
    c_rb = np.zeros((6, 6))
    c_rb[:3, :3] = p.mass * sw
    c_rb[:3, 3:] = -p.mass * sw @ sg
    c_rb[3:, :3] = p.mass * sg @ sw
    c_rb[3:, 3:] = -skew(i_b @ w)
    a = m_a[:3, :3] @ v1 + m_a[:3, 3:] @ w
    b = m_a[3:, :3] @ v1 + m_a[3:, 3:] @ w
    c_a = np.zeros((6, 6))
    c_a[:3, 3:] = -skew(a)
    c_a[3:, :3] = -skew(a)
    c_a[3:, 3:] = -skew(b)
    return c_rb, c_a


def rotation(phi: float, theta: float, psi: float) -> Array:
    """R_b^n (ZYX Euler angles, Fossen eq. 2.18): body FRD to NED."""
    cf, sf, ct, st, cp, sp = (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
                              math.cos(psi), math.sin(psi))
    return np.array([
        [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
        [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
        [-st, ct * sf, ct * cf],
    ])


def restoring(p: VehicleParams, eta: Array) -> Array:
    """g(eta): weight and buoyancy with CG/CB offsets (Fossen eq. 4.6), N and N m."""
    phi, theta = eta[3], eta[4]
    k = np.array([-math.sin(theta), math.cos(theta) * math.sin(phi),
                  math.cos(theta) * math.cos(phi)])  # NED down axis in body
    f_g = p.weight * k
    f_b = -p.buoyancy * k
    force = f_g + f_b
    moment = np.cross(np.array(p.r_g), f_g) + np.cross(np.array(p.r_b), f_b)
    return -np.concatenate([force, moment])


def potential(p: VehicleParams, eta: Array) -> float:
    """Potential energy of weight and buoyancy (J), zero at z = 0 level: the V with
    g(eta) = J^T dV/d eta."""
    phi, theta = eta[3], eta[4]
    k = np.array([-math.sin(theta), math.cos(theta) * math.sin(phi),
                  math.cos(theta) * math.cos(phi)])
    z_g = eta[2] + float(k @ np.array(p.r_g))
    z_b = eta[2] + float(k @ np.array(p.r_b))
    return -p.weight * z_g + p.buoyancy * z_b


def energy(p: VehicleParams, state: Array, current_ned: Array | None = None) -> float:
    """Mechanical energy 1/2 nu_r^T M nu_r + V(eta) (J)."""
    nu_r = _relative(state, current_ned)
    return float(0.5 * nu_r @ mass_matrix(p) @ nu_r) + potential(p, state[6:])


def _relative(state: Array, current_ned: Array | None) -> Array:
    nu = state[:6]
    if current_ned is None:
        return nu.copy()
    r = rotation(state[9], state[10], state[11])
    return nu - np.concatenate([r.T @ current_ned, np.zeros(3)])


class _Cache:
    """Constant matrices of one parameter set, computed once."""

    def __init__(self, p: VehicleParams) -> None:
        self.p = p
        self.m_rb, self.m_a = mass_matrices(p)
        self.m_inv = np.linalg.inv(self.m_rb + self.m_a)


_CACHE: dict[int, _Cache] = {}


def _cache(p: VehicleParams) -> _Cache:
    c = _CACHE.get(id(p))
    if c is None or c.p is not p:
        c = _Cache(p)
        _CACHE[id(p)] = c
    return c


def saturate(p: VehicleParams, inputs: Array) -> Array:
    """Clip [rudder rad, stern rad, rpm] at the actuator limits."""
    return np.array([
        min(max(inputs[0], -p.max_rudder), p.max_rudder),
        min(max(inputs[1], -p.max_stern), p.max_stern),
        min(max(inputs[2], -p.max_rpm), p.max_rpm),
    ])


def forces(p: VehicleParams, nu_r: Array, inputs: Array) -> Array:
    """Damping, lift, fin and propeller forces tau (N, N m) at relative velocity nu_r;
    ``inputs`` already saturated."""
    u, v, w, pr, q, r = nu_r
    tau = np.zeros(6)
    if p.damping:
        xuu, yvv, zww, yrr, zqq, mww, nvv, mqq, nrr, kpp = p.quad
        tau += np.array([
            xuu * u * abs(u),
            yvv * v * abs(v) + yrr * r * abs(r),
            zww * w * abs(w) + zqq * q * abs(q),
            kpp * pr * abs(pr),
            mww * w * abs(w) + mqq * q * abs(q),
            nvv * v * abs(v) + nrr * r * abs(r),
        ])
        tau += np.array(p.linear) * nu_r
    if p.lift:
        # body lift at x_cp (Prestero 2001 sec. 3.x, Hoerner)
        y_l = p.body_lift * u * v
        z_l = p.body_lift * u * w
        # fins at x_fin: effective angle of attack from the local flow (Prestero's fin lift)
        ua = abs(u)
        c, xf = p.fin_lift, p.x_fin
        y_f = c * (u * ua * inputs[0] - ua * (v + xf * r))
        z_f = c * (-u * ua * inputs[1] - ua * (w - xf * q))
        tau += np.array([0.0, y_l + y_f, z_l + z_f, 0.0,
                         -p.x_cp * z_l - xf * z_f, p.x_cp * y_l + xf * y_f])
    if p.propulsion:
        n = inputs[2]
        thrust = p.thrust_coeff * n * abs(n)
        tau[0] += thrust
        tau[3] += p.torque_per_thrust * thrust
    return tau


def rhs(p: VehicleParams, state: Array, inputs: Array, current_ned: Array | None = None) -> Array:
    """State derivative [nu_dot, eta_dot] (Fossen eq. 10.?-form with an irrotational current)."""
    nu, eta = state[:6], state[6:]
    phi, theta, psi = eta[3], eta[4], eta[5]
    r_bn = rotation(phi, theta, psi)
    vc_b = np.zeros(3) if current_ned is None else r_bn.T @ current_ned
    nu_r = nu - np.concatenate([vc_b, np.zeros(3)])
    c_rb, c_a = coriolis(p, nu_r)
    tau = forces(p, nu_r, inputs)
    nu_r_dot = _cache(p).m_inv @ (tau - (c_rb + c_a) @ nu_r - restoring(p, eta))
    # the current is constant in NED, so in body it turns with the vehicle: d/dt vc_b = -w x vc_b
    nu_dot = nu_r_dot + np.concatenate([-np.cross(nu[3:], vc_b), np.zeros(3)])
    # kinematics (Fossen eq. 2.40): p_dot = R nu1, Theta_dot = T(Theta) nu2
    cf, sf, ct, tt = math.cos(phi), math.sin(phi), math.cos(theta), math.tan(theta)
    t_mat = np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])
    eta_dot = np.concatenate([r_bn @ nu[:3], t_mat @ nu[3:]])
    return np.concatenate([nu_dot, eta_dot])


def step(
    p: VehicleParams,
    state: Array,
    inputs: Array,
    dt: float,
    current_ned: Array | None = None,
) -> Array:
    """One RK4 step of ``dt`` seconds; returns the new 12-state ``[nu, eta]`` (psi wrapped to
    (-pi, pi]). ``inputs = [rudder rad, stern rad, rpm]`` are saturated; ``current_ned`` m/s."""
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    x = np.asarray(state, dtype=float)
    if x.shape != (12,):
        raise ValueError(f"state must have 12 elements [nu, eta], got shape {x.shape}")
    u = saturate(p, np.asarray(inputs, dtype=float))
    vc = None if current_ned is None else np.asarray(current_ned, dtype=float)
    k1 = rhs(p, x, u, vc)
    k2 = rhs(p, x + 0.5 * dt * k1, u, vc)
    k3 = rhs(p, x + 0.5 * dt * k2, u, vc)
    k4 = rhs(p, x + dt * k3, u, vc)
    out = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    out[11] = math.atan2(math.sin(out[11]), math.cos(out[11]))
    return out
