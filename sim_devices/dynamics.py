"""6-DOF torpedo AUV dynamics in Fossen's form (Handbook of Marine Craft Hydrodynamics, 2021).

Pure numpy, no transports or clocks: the caller owns time and passes ``dt``.

Frames and units: ``eta = [x y z phi theta psi]`` in NED (metres, radians, ZYX Euler angles);
``nu = [u v w p q r]`` in body FRD (m/s, rad/s); the state is ``[nu, eta]`` (12 floats).
Inputs ``[rudder, stern, rpm]`` (rad, rad, rev/min) are saturated at the vehicle's limits.
The ocean current is a constant NED velocity (m/s); hydrodynamic forces use the relative
velocity ``nu_r = nu - [R^T v_c, 0]``.

Model (Fossen 2021, relative-velocity form for an irrotational current):
``M nu_r_dot + C_RB(nu_r) nu_r + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau``, with
``M = M_RB + M_A`` (rigid body, ch. 3; added mass), ``C_RB`` in its linear-velocity-independent
form (ch. 3), ``C_A`` in the skew-symmetric added-mass form, ``g`` the restoring forces (ch. 4),
cross-flow quadratic drag, body and fin lift (Prestero 2001) and the propeller.
Parameters come from ``config/vehicles/remus100.toml`` (Prestero 2001, the default) or
``remus100_fossen.toml`` (Fossen 2021, :class:`SpheroidHydro`); every number cites its source.
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
    "PITCH_LIMIT",
    "REMUS100_FILE",
    "REMUS100_FOSSEN_FILE",
    "PitchSingularityError",
    "SpheroidHydro",
    "VehicleParams",
    "coriolis",
    "coriolis_force",
    "energy",
    "forces",
    "load_params",
    "mass_matrix",
    "restoring",
    "rhs",
    "skew",
    "step",
]

Array = NDArray[np.float64]

REMUS100_FILE = Path(__file__).resolve().parent.parent / "config" / "vehicles" / "remus100.toml"
REMUS100_FOSSEN_FILE = REMUS100_FILE.with_name("remus100_fossen.toml")
"""Fossen's 2021 spheroid REMUS 100 (open-loop stable), the second published parameter set."""


def skew(a: Array) -> Array:
    """The cross-product matrix S(a), S(a) b = a x b (Fossen ch. 2)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@dataclass(frozen=True)
class SpheroidHydro:
    """Fossen's spheroid hydrodynamics (Handbook 2nd ed. 2021, 8.4.2; his REMUS 100 model),
    used instead of Prestero's derivatives when a parameter file says ``form = "spheroid"``.

    No Munk moment (the C_A entries of the pitch and yaw rows in u, v and p are zero, as in the
    source), diagonal linear damping ``lin`` (N s/m, N m s/rad; surge, sway and yaw times
    ``exp(-decay U_r)``), hull drag and lift in the vertical plane, strip-theory cross-flow
    drag in the horizontal plane, fins at ``x_fin`` and a propeller whose thrust falls linearly
    with the advance number. Inputs keep Prestero's signs (positive rudder: bow to port;
    positive stern plane: bow down); the source's are the opposite, so they are negated here.
    """

    rho: float
    area: float
    """S, planform area (m^2): the hull's lift and drag reference."""
    cd0: float
    cl_alpha: float
    """Hull lift slope (1/rad), pi AR / (1 + sqrt(1 + (AR/2)^2)), AR = D^2 / S."""
    induced: float
    """1 / (pi e AR): induced drag CD = cd0 + induced CL^2."""
    crossflow: float
    """1/2 rho D Cd_2D dx (kg/m^2): one strip's cross-flow drag per (v + x r)|v + x r|."""
    strips: tuple[float, ...]
    """x of the strip points (m), -L/2 .. L/2."""
    strip_moments: tuple[float, float, float, float]
    """sum of x^k over the strip points, k = 0..3 (the cross-flow sums when no strip changes
    the sign of its flow)."""
    lin: tuple[float, float, float, float, float, float]
    decay: float
    rudder: float
    """1/2 rho A_r CL_r (kg/m): rudder force per U^2 rad."""
    stern: float
    x_fin: float
    d_prop: float
    t_prop: float
    wake: float
    kt: tuple[float, float]
    """KT at J = 0 and its slope dKT/dJ (linear in the advance number J = Va / (n D))."""
    kq: tuple[float, float]


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
    """Yuvl = Zuwl (kg/m), body lift per u v (u w)."""
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
    spheroid: SpheroidHydro | None = None
    """Fossen's spheroid hydrodynamics; None: Prestero's derivatives (the fields above)."""
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
        msg = f"{path}: missing [{section}] {key} = {{value = ..., source = ...}}"
        raise ValueError(msg) from exc


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

    if "model" in t and v("model", "form") == "spheroid":
        return _load_spheroid(v)
    mass = float(v("rigid_body", "mass"))
    g = float(v("rigid_body", "gravity"))
    quad = tuple(float(v("damping", k)) for k in
                 ("Xuu", "Yvv", "Zww", "Yrr", "Zqq", "Mww", "Nvv", "Mqq", "Nrr", "Kpp"))
    c_fin = float(v("lift", "Yuudr"))
    x_fin = float(v("lift", "Nuudr")) / c_fin
    # body lift = Prestero's combined Yuv less the fins' -c; its centre x_cp makes Munk (the
    # C_A term, Yvdot - Xudot per u v) + fins (-c x_fin) + body lift equal the combined Nuv
    body_lift = float(v("lift", "Yuv")) + c_fin
    munk = float(v("added_mass", "Yvdot")) - float(v("added_mass", "Xudot"))
    x_cp = (float(v("lift", "Nuv")) - munk + c_fin * x_fin) / body_lift
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
        body_lift=body_lift,
        x_cp=x_cp,
        fin_lift=c_fin,
        x_fin=x_fin,
        thrust_coeff=drag / (n_cal * n_cal),
        torque_per_thrust=float(v("propulsion", "torque_per_thrust")),
        max_rudder=float(v("limits", "rudder")),
        max_stern=float(v("limits", "stern")),
        max_rpm=float(v("limits", "rpm")),
    )


def _load_spheroid(v: Any) -> VehicleParams:
    """Fossen's spheroid REMUS 100 from its file: mass, inertia and added mass of a prolate
    spheroid (Lamb's k-factors), damping from time constants (Handbook 2021, 8.4.2)."""
    length, diam = float(v("rigid_body", "length")), float(v("rigid_body", "diameter"))
    rho, g = float(v("rigid_body", "rho")), float(v("rigid_body", "gravity"))
    a, b = length / 2.0, diam / 2.0
    mass = 4.0 / 3.0 * math.pi * rho * a * b * b
    ix, iy = 0.4 * mass * b * b, 0.2 * mass * (a * a + b * b)
    e = math.sqrt(1.0 - (b / a) ** 2)
    log_e = math.log((1.0 + e) / (1.0 - e))
    alpha0 = 2.0 * (1.0 - e * e) / e**3 * (0.5 * log_e - e)
    beta0 = 1.0 / (e * e) - (1.0 - e * e) / (2.0 * e**3) * log_e
    k1, k2 = alpha0 / (2.0 - alpha0), beta0 / (2.0 - beta0)
    dab = beta0 - alpha0
    k_prime = e**4 * dab / ((2.0 - e * e) * (2.0 * e * e - (2.0 - e * e) * dab))
    a44 = float(v("rigid_body", "added_roll_ratio")) * ix
    r_g = tuple(float(x) for x in v("rigid_body", "r_g"))
    area = float(v("damping", "planform")) * length * diam
    aspect = diam * diam / area
    n_strips = int(v("damping", "crossflow_strips"))
    dx = length / n_strips
    strips = tuple(-a + i * dx for i in range(n_strips + 1))
    ja = float(v("propulsion", "Ja_max"))
    kt0, kq0 = float(v("propulsion", "KT_0")), float(v("propulsion", "KQ_0"))
    hydro = SpheroidHydro(
        rho=rho,
        area=area,
        cd0=float(v("damping", "Cd")) * math.pi * b * b / area,
        cl_alpha=math.pi * aspect / (1.0 + math.sqrt(1.0 + (aspect / 2.0) ** 2)),
        induced=1.0 / (math.pi * float(v("damping", "oswald")) * aspect),
        crossflow=0.5 * rho * diam * float(v("damping", "Cd_2D")) * dx,
        strips=strips,
        strip_moments=(
            float(len(strips)), sum(strips), sum(x * x for x in strips), sum(x**3 for x in strips)
        ),
        lin=(0.0,) * 6,
        decay=float(v("damping", "decay")),
        rudder=0.5 * rho * float(v("fins", "A_rudder")) * float(v("fins", "CL_rudder")),
        stern=0.5 * rho * float(v("fins", "A_stern")) * float(v("fins", "CL_stern")),
        x_fin=-a,
        d_prop=float(v("propulsion", "D_prop")),
        t_prop=float(v("propulsion", "t_prop")),
        wake=float(v("propulsion", "wake")),
        kt=(kt0, (float(v("propulsion", "KT_max")) - kt0) / ja),
        kq=(kq0, (float(v("propulsion", "KQ_max")) - kq0) / ja),
    )
    weight = mass * g
    p = VehicleParams(
        mass=mass, weight=weight, buoyancy=weight, r_g=r_g, r_b=(0.0, 0.0, 0.0),  # type: ignore[arg-type]
        inertia=(ix, iy, iy),
        added=(-mass * k1, -mass * k2, -mass * k2, -a44, -k_prime * iy, -k_prime * iy, 0.0, 0.0),
        quad=(0.0,) * 10, linear=(0.0,) * 6, body_lift=0.0, x_cp=0.0,  # type: ignore[arg-type]
        fin_lift=0.0, x_fin=-a, thrust_coeff=0.0, torque_per_thrust=0.0,
        max_rudder=float(v("limits", "rudder")), max_stern=float(v("limits", "stern")),
        max_rpm=float(v("limits", "rpm")), spheroid=hydro,
    )
    if [float(x) for x in v("rigid_body", "r_b")] != [0.0, 0.0, 0.0]:
        raise ValueError("spheroid form: r_b must be the origin (CB at the CO, as in the source)")
    # linear damping from time constants and damping ratios, on the total mass matrix
    m = mass_matrix(p)
    zbg = r_g[2] * weight
    w_roll, w_pitch = math.sqrt(zbg / m[3, 3]), math.sqrt(zbg / m[4, 4])
    t_sway = float(v("damping", "T_sway"))
    lin = (
        m[0, 0] / float(v("damping", "T_surge")),
        m[1, 1] / t_sway,
        m[2, 2] / t_sway,
        m[3, 3] * 2.0 * float(v("damping", "zeta_roll")) * w_roll,
        m[4, 4] * 2.0 * float(v("damping", "zeta_pitch")) * w_pitch,
        m[5, 5] / float(v("damping", "T_yaw")),
    )
    return replace(p, spheroid=replace(hydro, lin=lin))


def mass_matrices(p: VehicleParams) -> tuple[Array, Array]:
    """(M_RB, M_A): rigid-body (Fossen ch. 3) and added mass (the hydrodynamic
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
    """(C_RB(nu), C_A(nu)). C_RB is Fossen's ch. 3 form (independent of the linear velocity, so
    the irrotational-current form holds); C_A is the skew-symmetric form."""
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
    if p.spheroid is not None:  # the source's C_A: no Munk moment
        c_a[4, 0] = c_a[4, 3] = c_a[5, 0] = c_a[5, 1] = 0.0
    return c_rb, c_a


def rotation(phi: float, theta: float, psi: float) -> Array:
    """R_b^n (ZYX Euler angles, Fossen ch. 2): body FRD to NED."""
    cf, sf, ct, st, cp, sp = (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
                              math.cos(psi), math.sin(psi))
    return np.array([
        [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
        [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
        [-st, ct * sf, ct * cf],
    ])


def restoring(p: VehicleParams, eta: Array) -> Array:
    """g(eta): weight and buoyancy with CG/CB offsets (Fossen ch. 4), N and N m."""
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
    return float(-p.weight * z_g + p.buoyancy * z_b)


def energy(p: VehicleParams, state: Array, current_ned: Array | None = None) -> float:
    """Mechanical energy 1/2 nu_r^T M nu_r + V(eta) (J)."""
    nu_r = _relative(state, current_ned)
    return float(0.5 * nu_r @ mass_matrix(p) @ nu_r) + potential(p, state[6:])


def _relative(state: Array, current_ned: Array | None) -> Array:
    nu = state[:6]
    if current_ned is None:
        return nu.copy()
    r = rotation(state[9], state[10], state[11])
    out: Array = nu - np.concatenate([r.T @ current_ned, np.zeros(3)])
    return out


class _Cache:
    """Constant matrices of one parameter set, computed once."""

    def __init__(self, p: VehicleParams) -> None:
        self.p = p
        self.m_rb, self.m_a = mass_matrices(p)
        self.m_inv = np.linalg.inv(self.m_rb + self.m_a)
        self.i_b = self.m_rb[3:, 3:].tolist()
        self.m_a_rows = self.m_a.tolist()


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


Vec3 = tuple[float, float, float]


def _tau(p: VehicleParams, nu_r: tuple[float, ...], inputs: Vec3) -> list[float]:
    """Damping, lift, fin and propeller forces as floats (the hot path of :func:`rhs`)."""
    if p.spheroid is not None:
        return _tau_spheroid(p, p.spheroid, nu_r, inputs)
    u, v, w, pr, q, r = nu_r
    tau = [0.0] * 6
    if p.damping:
        xuu, yvv, zww, yrr, zqq, mww, nvv, mqq, nrr, kpp = p.quad
        lin = p.linear
        tau[0] = xuu * u * abs(u) + lin[0] * u
        tau[1] = yvv * v * abs(v) + yrr * r * abs(r) + lin[1] * v
        tau[2] = zww * w * abs(w) + zqq * q * abs(q) + lin[2] * w
        tau[3] = kpp * pr * abs(pr) + lin[3] * pr
        tau[4] = mww * w * abs(w) + mqq * q * abs(q) + lin[4] * q
        tau[5] = nvv * v * abs(v) + nrr * r * abs(r) + lin[5] * r
    if p.lift:
        # body lift (Prestero 2001, after Hoerner) acting at x_cp
        y_l = p.body_lift * u * v
        z_l = p.body_lift * u * w
        # fins at x_fin: lift c u|u| alpha, alpha the deflection less the local flow angle
        # (v + x_fin r sideways, w - x_fin q vertical); reproduces Prestero's fin derivatives
        ua = abs(u)
        c, xf = p.fin_lift, p.x_fin
        y_f = c * (u * ua * inputs[0] - ua * (v + xf * r))
        z_f = c * (-u * ua * inputs[1] - ua * (w - xf * q))
        tau[1] += y_l + y_f
        tau[2] += z_l + z_f
        tau[4] += -p.x_cp * z_l - xf * z_f
        tau[5] += p.x_cp * y_l + xf * y_f
    if p.propulsion:
        n = inputs[2]
        thrust = p.thrust_coeff * n * abs(n)
        tau[0] += thrust
        tau[3] += p.torque_per_thrust * thrust
    return tau


def _tau_spheroid(p: VehicleParams, s: SpheroidHydro, nu_r: tuple[float, ...],
                  inputs: Vec3) -> list[float]:
    """Fossen's spheroid forces (Handbook 2021, 8.4.2, as coded in his remus100 model)."""
    u, v, w, pr, q, r = nu_r
    tau = [0.0] * 6
    speed2 = u * u + v * v + w * w
    speed = math.sqrt(speed2)
    if p.damping:
        lin, k = s.lin, math.exp(-s.decay * speed)
        tau[0] -= lin[0] * k * u
        tau[1] -= lin[1] * k * v
        tau[2] -= lin[2] * w
        tau[3] -= lin[3] * pr
        tau[4] -= lin[4] * q
        tau[5] -= lin[5] * k * r
        # cross-flow drag by strip theory, horizontal plane only (as in the source)
        x_end = s.strips[-1]
        if abs(v) >= abs(r) * x_end:  # one sign along the hull: sums of (v + x r)^2 x^k
            m0, m1, m2, m3 = s.strip_moments
            sgn = 1.0 if v > 0 else -1.0
            y_h = sgn * (v * v * m0 + 2.0 * v * r * m1 + r * r * m2)
            n_h = sgn * (v * v * m1 + 2.0 * v * r * m2 + r * r * m3)
        else:
            y_h = n_h = 0.0
            for x in s.strips:
                vl = v + x * r
                f = vl * abs(vl)
                y_h += f
                n_h += x * f
        tau[1] -= s.crossflow * y_h
        tau[5] -= s.crossflow * n_h
    alpha = math.atan2(w, u)
    ca, sa = math.cos(alpha), math.sin(alpha)
    cl = s.cl_alpha * alpha
    dyn_p = 0.5 * s.rho * speed2 * s.area
    if p.damping:  # hull drag, parasitic and induced, along the flow
        f_drag = dyn_p * (s.cd0 + s.induced * cl * cl)
        tau[0] -= ca * f_drag
        tau[2] -= sa * f_drag
    if p.lift:
        f_lift = dyn_p * cl  # hull lift, normal to the flow, at the origin
        tau[0] += sa * f_lift
        tau[2] -= ca * f_lift
        d_r, d_s = -inputs[0], -inputs[1]  # the source's fin signs
        u_h2, u_v2 = u * u + v * v, u * u + w * w
        y_r = -s.rudder * u_h2 * d_r
        z_s = -s.stern * u_v2 * d_s
        tau[0] -= s.rudder * u_h2 * d_r * d_r + s.stern * u_v2 * d_s * d_s
        tau[1] += y_r
        tau[2] += z_s
        tau[4] += s.x_fin * z_s  # the source's moment arm and sign
        tau[5] += s.x_fin * y_r
    if p.propulsion:
        n = inputs[2] / 60.0
        j_term = s.wake * speed / s.d_prop * abs(n) if n > 0 else 0.0
        d4 = s.rho * s.d_prop**4
        tau[0] += (1.0 - s.t_prop) * d4 * (s.kt[0] * n * abs(n) + s.kt[1] * j_term)
        tau[3] += d4 * s.d_prop * (s.kq[0] * n * abs(n) + s.kq[1] * j_term)
    return tau


def forces(p: VehicleParams, nu_r: Array, inputs: Array) -> Array:
    """Damping, lift, fin and propeller forces tau (N, N m) at the relative velocity nu_r;
    ``inputs`` already saturated."""
    u = (float(inputs[0]), float(inputs[1]), float(inputs[2]))
    return np.array(_tau(p, tuple(float(x) for x in nu_r), u))


def _cross(a: Vec3, b: Vec3) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def coriolis_force(p: VehicleParams, nu: Array) -> Array:
    """(C_RB(nu) + C_A(nu)) nu as a vector, without building the matrices (same terms as
    :func:`coriolis`: m w x v - m w x (r_g x w); m r_g x (w x v) + w x (I_b w); and
    -a x w; -a x v - b x w with a, b the added-mass momenta)."""
    c = _cache(p)
    return np.array(_coriolis_force(p, c, tuple(float(x) for x in nu)))


def _coriolis_force(p: VehicleParams, c: _Cache, nu: tuple[float, ...]) -> list[float]:
    v1 = (nu[0], nu[1], nu[2])
    w = (nu[3], nu[4], nu[5])
    m = p.mass
    rg = p.r_g
    wxv = _cross(w, v1)
    wxrgw = _cross(w, _cross(rg, w))
    ib = c.i_b
    ibw = (ib[0][0] * w[0] + ib[0][1] * w[1] + ib[0][2] * w[2],
           ib[1][0] * w[0] + ib[1][1] * w[1] + ib[1][2] * w[2],
           ib[2][0] * w[0] + ib[2][1] * w[1] + ib[2][2] * w[2])
    rgwv = _cross(rg, wxv)
    wibw = _cross(w, ibw)
    am = c.m_a_rows
    ab = [sum(am[i][j] * nu[j] for j in range(6)) for i in range(6)]
    a = (ab[0], ab[1], ab[2])
    b = (ab[3], ab[4], ab[5])
    axw = _cross(a, w)
    axv = _cross(a, v1)
    bxw = _cross(b, w)
    if p.spheroid is not None:  # the zeroed Munk entries of C_A (see coriolis)
        munk_m = -a[2] * nu[0] - b[2] * nu[3]
        munk_n = a[1] * nu[0] - a[0] * nu[1]
        axv = (axv[0], axv[1] + munk_m, axv[2] + munk_n)
    return [
        m * (wxv[0] - wxrgw[0]) - axw[0],
        m * (wxv[1] - wxrgw[1]) - axw[1],
        m * (wxv[2] - wxrgw[2]) - axw[2],
        m * rgwv[0] + wibw[0] - axv[0] - bxw[0],
        m * rgwv[1] + wibw[1] - axv[1] - bxw[1],
        m * rgwv[2] + wibw[2] - axv[2] - bxw[2],
    ]


def rhs(p: VehicleParams, state: Array, inputs: Array, current_ned: Array | None = None) -> Array:
    """State derivative [nu_dot, eta_dot] with an irrotational current constant in NED.

    The kinetics are solved for the relative velocity, ``M nu_r_dot = tau - C(nu_r) nu_r -
    g(eta)`` (valid because C_RB does not depend on the linear velocity), then ``nu_dot =
    nu_r_dot - w x vc_b`` since the current turns with the body. ``inputs`` already saturated.
    """
    c = _cache(p)
    x = state.tolist()
    phi, theta, psi = x[9], x[10], x[11]
    cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    r_bn = (
        (cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
        (sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
        (-st, ct * sf, ct * cf),
    )
    if current_ned is None:
        vc_b = (0.0, 0.0, 0.0)
    else:
        vn = current_ned.tolist()
        vc_b = tuple(r_bn[0][i] * vn[0] + r_bn[1][i] * vn[1] + r_bn[2][i] * vn[2]
                     for i in range(3))
    nu_r = (x[0] - vc_b[0], x[1] - vc_b[1], x[2] - vc_b[2], x[3], x[4], x[5])
    ins = inputs.tolist()
    tau = _tau(p, nu_r, (ins[0], ins[1], ins[2]))
    cor = _coriolis_force(p, c, nu_r)
    # restoring forces g(eta): weight at r_g and buoyancy at r_b, NED down axis k in body
    k = r_bn[2]
    net = p.weight - p.buoyancy
    fg = (p.weight * k[0], p.weight * k[1], p.weight * k[2])
    fb = (-p.buoyancy * k[0], -p.buoyancy * k[1], -p.buoyancy * k[2])
    mg = _cross(p.r_g, fg)
    mb = _cross(p.r_b, fb)
    rhs_f = np.array([
        tau[0] - cor[0] + net * k[0],
        tau[1] - cor[1] + net * k[1],
        tau[2] - cor[2] + net * k[2],
        tau[3] - cor[3] + mg[0] + mb[0],
        tau[4] - cor[4] + mg[1] + mb[1],
        tau[5] - cor[5] + mg[2] + mb[2],
    ])
    nu_r_dot = (c.m_inv @ rhs_f).tolist()
    wxvc = _cross((x[3], x[4], x[5]), vc_b)
    u, v, w = x[0], x[1], x[2]
    tt = st / ct
    return np.array([
        nu_r_dot[0] - wxvc[0],
        nu_r_dot[1] - wxvc[1],
        nu_r_dot[2] - wxvc[2],
        nu_r_dot[3],
        nu_r_dot[4],
        nu_r_dot[5],
        # kinematics: position rate R nu1, Euler-angle rate T(Theta) nu2 (Fossen ch. 2)
        r_bn[0][0] * u + r_bn[0][1] * v + r_bn[0][2] * w,
        r_bn[1][0] * u + r_bn[1][1] * v + r_bn[1][2] * w,
        r_bn[2][0] * u + r_bn[2][1] * v + r_bn[2][2] * w,
        x[3] + (sf * x[4] + cf * x[5]) * tt,
        cf * x[4] - sf * x[5],
        (sf * x[4] + cf * x[5]) / ct,
    ])


PITCH_LIMIT = math.radians(85.0)
"""|theta| beyond which :func:`step` refuses to go on (Euler angles are singular at 90 deg)."""


class PitchSingularityError(ValueError):
    """The pitch left the range where the Euler-angle kinematics are valid."""


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
    if abs(out[10]) > PITCH_LIMIT:
        raise PitchSingularityError(
            f"pitch {math.degrees(out[10]):.1f} deg beyond +-{math.degrees(PITCH_LIMIT):.0f}: "
            "the ZYX Euler-angle kinematics are singular at +-90 deg (the vehicle looped)"
        )
    return out
