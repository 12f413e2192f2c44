"""The dead-reckoning filter: an error-state EKF around the INS attitude.

Why this form
-------------
The HN-100 is itself an inertial navigator: its heading is already the fused, gyro-integrated
heading. Integrating its yaw rate again and "correcting" with its heading would count the same
gyro twice and, because its heading error is slowly varying rather than white, make the filter
overconfident. So the INS attitude is the *nominal* attitude, and the filter estimates what the
INS cannot give: position, depth and velocity, plus the INS attitude errors that make the
position uncertain.

State (8), with the names used for the covariance of :class:`~auvgw.fusion.odometry.Odometry`::

    x, y, z      position of the vehicle reference point (the INS), NED, m
    heading      correction to the INS heading, rad: heading = INS heading + x[3]
    pitch        correction to the INS pitch, rad:   pitch   = INS pitch   + x[4]
    u, v, w      vehicle velocity over the seabed in body axes, m/s

Because heading = INS heading + correction and the INS heading is given, the covariance rows of
the corrections are directly those of heading and pitch.

Models
------
* Attitude errors: first-order Gauss-Markov, ``c(t+h) = exp(-h/tau) c(t) + n``, stationary RMS
  ``sigma`` (HN-100: heading 0.3 deg, pitch 0.02 deg); ``tau = 0`` is white, ``inf`` a constant
  bias. Nothing in INS + DVL + depth observes the heading error, so its variance stays at
  ``sigma^2`` and it is what makes the horizontal covariance grow with distance travelled.
* Velocity: body-frame random walk (an AUV keeps its body velocity through turns, so this holds
  in turns where a constant NED velocity would not); optionally driven by the INS specific force
  (``use_accelerations``: ``dv/dt = f + C^T g - omega x v``), never while coasting.
* Position: between two time points the heading is taken to change at a constant rate and the
  level-frame velocity linearly; the horizontal displacement is the exact integral of that,
  ``e^{i psi_a} h [l_a (f0 - f1) + l_b f1]`` (complex N + iE, ``f0, f1`` the arc weights of the
  heading change), so a constant-speed turn is integrated exactly (a circle), and a straight line
  with constant acceleration too (trapezoid). Depth integrates the vertical NED velocity.
* DVL: ``z = M^T (v + omega x r)`` in instrument axes (``z = v + omega x r`` for body-axes
  fixes), with ``M`` the mounting rotation, ``r`` the lever arm and ``omega`` the body rate at
  the DVL's own time; missing components are left out; innovations are gated (chi-square,
  or while the noise is learned the VB predictive: :func:`predictive_gate`).
* Depth: ``z = z_ref + (C r_p)_z`` for a pressure sensor at lever arm ``r_p``.

The covariance is propagated with the Jacobian of this step (``P <- F P F^T + Q``) and updated
with the Joseph form.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from auvgw.fusion.config import FusionConfig
from auvgw.fusion.frames import mount_matrix, wrap_angle
from auvgw.fusion.samples import DvlFrame, InsSample
from auvgw.ground.geometry import chi2_ppf

__all__ = [
    "N_STATE",
    "STATE_NAMES",
    "DeadReckoningEKF",
    "arc_weights",
    "gm_factor",
    "predictive_gate",
]

STATE_NAMES = ("x", "y", "z", "heading", "pitch", "u", "v", "w")
N_STATE = 8
IX, IY, IZ, IPSI, ITH, IU, IV, IW = range(N_STATE)
_VEL = slice(IU, IW + 1)
_NA_ROWS, _NA_COLS = N_STATE + 3, N_STATE + 8
_HALF_INV_SQRT3 = 0.5 / math.sqrt(3.0)

# Taylor coefficients of the arc weights f0(a) = int_0^1 e^{i a s} ds and
# f1(a) = int_0^1 s e^{i a s} ds: sum_n (i a)^n c_n
_N_SERIES = 9
_C0 = [1.0 / math.factorial(n + 1) for n in range(_N_SERIES)]
_C1 = [1.0 / (math.factorial(n) * (n + 2)) for n in range(_N_SERIES)]
_SERIES_LIMIT = 0.05


def arc_weights(a: float) -> tuple[complex, complex]:
    """``(f0, f1) = (int_0^1 e^{ias} ds, int_0^1 s e^{ias} ds)`` for a heading change ``a`` rad.

    The displacement over a step of length ``h`` with heading ``psi_a + a s`` and level velocity
    ``l_a + (l_b - l_a) s`` (as complex N + iE, ``s`` in [0, 1]) is
    ``e^{i psi_a} h (l_a (f0 - f1) + l_b f1)``.
    """
    if abs(a) < _SERIES_LIMIT:
        ia = 1j * a
        f0 = complex(_C0[-1])
        f1 = complex(_C1[-1])
        for n in range(_N_SERIES - 2, -1, -1):
            f0 = f0 * ia + _C0[n]
            f1 = f1 * ia + _C1[n]
        return f0, f1
    e = complex(math.cos(a), math.sin(a))
    f0 = (e - 1.0) / (1j * a)
    f1 = e / (1j * a) + (e - 1.0) / (a * a)
    return f0, f1


@functools.lru_cache(maxsize=4096)
def _f_gate(p: float, k: int, nu: float) -> float:
    from scipy.special import fdtri

    return k * float(fdtri(k, nu, p))


def predictive_gate(p: float, k: int, nu: float) -> float:
    """Gate on the NIS of ``k`` innovation components whose noise variance is only known as an
    inverse-gamma posterior of shape ``nu / 2`` (the VB estimate): the ``p`` quantile of ``k F(k,
    nu)``, the NIS of a ``k``-variate Student-t with ``nu`` degrees of freedom. Wide while the
    noise is still being learned (``nu`` small: 259 for ``k = 3, nu = 5, p = 0.9999``), the
    chi-square quantile as ``nu`` grows (23.4 at ``nu = 100``, chi-square 21.1). ``nu`` is rounded
    to 0.1 (cached)."""
    return _f_gate(p, k, round(nu, 1))


def gm_factor(h: float, tau: float) -> float:
    """``exp(-h / tau)`` of a Gauss-Markov process over ``h`` s (``tau`` 0: white, inf: bias)."""
    if tau == 0.0:
        return 0.0
    if math.isinf(tau):
        return 1.0
    return math.exp(-h / tau)


class DeadReckoningEKF:
    """The filter's state and its three operations: :meth:`propagate` between two INS states,
    :meth:`update_dvl` and :meth:`update_depth` at an aiding time (see the module docstring).

    The INS states given to it must be at the filter's own times: the caller interpolates the
    INS to aiding times (:func:`auvgw.fusion.align.interpolate_ins`).
    """

    def __init__(self, config: FusionConfig, ins0: InsSample) -> None:
        self.config = config
        self.t = ins0.t
        init = config.initial
        self._x = [*map(float, init.position_m), 0.0, 0.0, *map(float, init.velocity_body_mps)]
        self._sig_psi, self._tau_psi = config.gm("heading")
        self._sig_th, self._tau_th = config.gm("pitch")
        self.P = np.diag(
            [
                *(s * s for s in init.position_sigma_m),
                self._sig_psi**2,
                self._sig_th**2,
                *(init.velocity_sigma_mps**2,) * 3,
            ]
        )
        self._M = mount_matrix(config.dvl)
        self._Mt = self._M.T
        self._lever_t = tuple(float(c) for c in config.dvl.lever_arm_m)
        # DVL measurement Jacobians: instrument axes z = M^T (v + omega x r), body axes z = ...
        self._H_instr = np.zeros((3, N_STATE))
        self._H_instr[:, IU : IW + 1] = self._Mt
        self._H_body = np.zeros((3, N_STATE))
        self._H_body[:, IU : IW + 1] = np.eye(3)
        # VB inverse-gamma parameters of the DVL noise per measurement axis (set at the first
        # fix from the spec noise at that time)
        self._vb_a: np.ndarray = np.zeros(3)
        self._vb_b: np.ndarray | None = None
        p = config.dvl_gate_probability
        self._gate = {k: (float(chi2_ppf(p, k)) if p is not None else math.inf) for k in (1, 2, 3)}
        self._gate_p = p
        pp = config.position_gate_probability
        self._pos_gate = float(chi2_ppf(pp, 2)) if pp is not None else math.inf
        self._g = config.gravity_mps2
        self._eye = np.eye(N_STATE)
        # Work buffers of propagate. One product A Pa A^T gives the propagated covariance
        # (rows 0-7: [F | noise gains]) and the motion-increment covariance (rows 8-10: [L | ...])
        # with Pa = blockdiag(P, I): columns 8-13 carry the velocity random walk (and its
        # integral into position), column 14 the heading-error noise, column 15 the pitch one.
        self._A = np.zeros((_NA_ROWS, _NA_COLS))
        self._A[:N_STATE, :N_STATE] = np.eye(N_STATE)
        self._A_acc = False
        self._Pa = np.eye(_NA_COLS)
        self._h_last = math.nan
        self._gm_last = (1.0, 1.0, 0.0, 0.0)

    @property
    def x(self) -> np.ndarray:
        """State estimate (see :data:`STATE_NAMES`), a copy."""
        return np.array(self._x)

    # ---- derived quantities -------------------------------------------------------------
    def heading(self, ins: InsSample) -> float:
        """Estimated heading (rad, wrapped) given the INS sample at the filter time."""
        return wrap_angle(ins.heading + self._x[IPSI])

    def pitch(self, ins: InsSample) -> float:
        """Estimated pitch (rad) given the INS sample at the filter time."""
        return ins.pitch + self._x[ITH]

    def velocity_body(self) -> tuple[float, float, float]:
        """Estimated body velocity (u, v, w), m/s."""
        return (self._x[IU], self._x[IV], self._x[IW])

    def position(self) -> tuple[float, float, float]:
        """Estimated position (x, y, z) NED, m."""
        return (self._x[IX], self._x[IY], self._x[IZ])

    def shift_position(self, dn: float, de: float) -> None:
        """Move the horizontal position by (dn, de) m NED (a correction of the past heading;
        the covariance is unchanged)."""
        self._x[IX] += dn
        self._x[IY] += de

    # ---- propagation --------------------------------------------------------------------
    def _kin_accel(
        self, ins: InsSample, cth: float, sth: float, u: float, v: float, w: float
    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Kinematic body acceleration ``f + C^T g - omega x v`` (m/s^2) and its derivative with
        respect to pitch, at pitch with cosine ``cth`` and sine ``sth``."""
        assert ins.accel is not None
        fx, fy, fz = ins.accel
        p, q, r = ins.rates
        cr, sr = math.cos(ins.roll), math.sin(ins.roll)
        g = self._g
        acc = (
            fx - g * sth - (q * w - r * v),
            fy + g * sr * cth - (r * u - p * w),
            fz + g * cr * cth - (p * v - q * u),
        )
        return acc, (-g * cth, -g * sr * sth, -g * cr * sth)

    def propagate(self, a: InsSample, b: InsSample, coasting: bool) -> np.ndarray:
        """Advance from ``a.t`` (= the filter time) to ``b.t`` with the INS states at both ends.

        ``coasting``: no bottom lock, so the velocity is held and its random walk is the
        coasting one. Returns this step's contribution to the covariance of the motion increment
        (NED horizontal displacement, heading change), 3 x 3.

        Scalar arithmetic (it runs at the INS rate); one matrix product for the covariances.
        """
        h = b.t - a.t
        if not h > 0.0:
            raise ValueError(f"propagation needs b.t > a.t, got {a.t!r} -> {b.t!r} s")
        cfg = self.config
        n, e, d, cpsi, cth, u, v, w = self._x
        if h == self._h_last:  # the INS interval rarely changes: reuse its factors
            phi_p, phi_t, s_psi, s_th = self._gm_last
        else:
            phi_p = gm_factor(h, self._tau_psi)
            phi_t = gm_factor(h, self._tau_th)
            s_psi = self._sig_psi * math.sqrt(1.0 - phi_p * phi_p)
            s_th = self._sig_th * math.sqrt(1.0 - phi_t * phi_t)
            self._h_last, self._gm_last = h, (phi_p, phi_t, s_psi, s_th)
        cpsi_b, cth_b = phi_p * cpsi, phi_t * cth
        psi_a = a.heading + cpsi
        dpsi = wrap_angle(b.heading - a.heading) + (cpsi_b - cpsi)
        th_a, th_b = a.pitch + cth, b.pitch + cth_b
        cra, sra, cta, sta = math.cos(a.roll), math.sin(a.roll), math.cos(th_a), math.sin(th_a)
        crb, srb, ctb, stb = math.cos(b.roll), math.sin(b.roll), math.cos(th_b), math.sin(th_b)
        # level matrices Ry(pitch) Rx(roll) at both ends (rows: forward, starboard, down)
        ax = (cta, sta * sra, sta * cra)
        ay = (0.0, cra, -sra)
        az = (-sta, cta * sra, cta * cra)
        bx = (ctb, stb * srb, stb * crb)
        by = (0.0, crb, -srb)
        bz = (-stb, ctb * srb, ctb * crb)

        A = self._A
        hh = 0.5 * h
        use_acc = (
            cfg.use_accelerations and not coasting and a.accel is not None and b.accel is not None
        )
        if use_acc:
            acc_a, dg_a = self._kin_accel(a, cta, sta, u, v, w)
            acc_b, dg_b = self._kin_accel(b, ctb, stb, u, v, w)
            u1 = u + hh * (acc_a[0] + acc_b[0])
            v1 = v + hh * (acc_a[1] + acc_b[1])
            w1 = w + hh * (acc_a[2] + acc_b[2])
            pm = hh * (a.rates[0] + b.rates[0])  # h * mean body rate
            qm = hh * (a.rates[1] + b.rates[1])
            rm = hh * (a.rates[2] + b.rates[2])
            fvv = ((1.0, rm, -qm), (-rm, 1.0, pm), (qm, -pm, 1.0))  # I - h [omega]x
            fvt = tuple(hh * (dg_a[i] + phi_t * dg_b[i]) for i in range(3))
            A[_VEL, _VEL] = fvv
            A[_VEL, ITH] = fvt
            self._A_acc = True
            # rows of A_b fvv, and A_b fvt (velocity at b through v1)
            jbx = tuple(bx[0] * fvv[0][j] + bx[1] * fvv[1][j] + bx[2] * fvv[2][j] for j in range(3))
            jby = tuple(by[0] * fvv[0][j] + by[1] * fvv[1][j] + by[2] * fvv[2][j] for j in range(3))
            jbz = tuple(bz[0] * fvv[0][j] + bz[1] * fvv[1][j] + bz[2] * fvv[2][j] for j in range(3))
            gx = bx[0] * fvt[0] + bx[1] * fvt[1] + bx[2] * fvt[2]
            gy = by[0] * fvt[0] + by[1] * fvt[1] + by[2] * fvt[2]
            gz = bz[0] * fvt[0] + bz[1] * fvt[1] + bz[2] * fvt[2]
        else:
            u1, v1, w1 = u, v, w
            if self._A_acc:
                A[_VEL, _VEL] = np.eye(3)
                A[_VEL, ITH] = 0.0
                self._A_acc = False
            jbx, jby, jbz = bx, by, bz
            gx = gy = gz = 0.0
        lax = ax[0] * u + ax[1] * v + ax[2] * w
        lay = ay[1] * v + ay[2] * w
        laz = az[0] * u + az[1] * v + az[2] * w
        lbx = bx[0] * u1 + bx[1] * v1 + bx[2] * w1
        lby = by[1] * v1 + by[2] * w1
        lbz = bz[0] * u1 + bz[1] * v1 + bz[2] * w1
        f0, f1 = arc_weights(dpsi)
        rot = complex(math.cos(psi_a), math.sin(psi_a)) * h
        k0 = rot * (f0 - f1)
        k1 = rot * f1
        dc = k0 * complex(lax, lay) + k1 * complex(lbx, lby)
        dz = hh * (laz + lbz)

        # Jacobian of the displacement w.r.t. heading correction, pitch correction, velocity;
        # d(level velocity)/d(pitch) = (l_z, 0, -l_x), at b also through v1 (gravity leakage)
        c_th = k0 * laz + k1 * complex(phi_t * lbz + gx, gy)
        c_u = k0 * complex(ax[0], ay[0]) + k1 * complex(jbx[0], jby[0])
        c_v = k0 * complex(ax[1], ay[1]) + k1 * complex(jbx[1], jby[1])
        c_w = k0 * complex(ax[2], ay[2]) + k1 * complex(jbx[2], jby[2])
        zu, zv, zw = hh * (az[0] + jbz[0]), hh * (az[1] + jbz[1]), hh * (az[2] + jbz[2])

        # process noise: body-velocity random walk q (integrated into position: gains J/2 and
        # J/(2 sqrt 3) give q^2 h [[J J^T/3, J/2], [J^T/2, I]]), Gauss-Markov attitude errors
        q = cfg.coast_velocity_random_walk if coasting else cfg.velocity_random_walk
        sq = q * math.sqrt(h)
        g1, g2 = 0.5 * sq, sq * _HALF_INV_SQRT3
        A[0:3, 3:14] = (
            (-dc.imag, c_th.real, c_u.real, c_v.real, c_w.real,
             g1 * c_u.real, g1 * c_v.real, g1 * c_w.real,
             g2 * c_u.real, g2 * c_v.real, g2 * c_w.real),
            (dc.real, c_th.imag, c_u.imag, c_v.imag, c_w.imag,
             g1 * c_u.imag, g1 * c_v.imag, g1 * c_w.imag,
             g2 * c_u.imag, g2 * c_v.imag, g2 * c_w.imag),
            (0.0, hh * (-lax - phi_t * lbx + gz), zu, zv, zw,
             g1 * zu, g1 * zv, g1 * zw, g2 * zu, g2 * zv, g2 * zw),
        )  # fmt: skip
        A[IU, 8] = A[IV, 9] = A[IW, 10] = sq
        A[IPSI, IPSI] = phi_p
        A[IPSI, 14] = s_psi
        A[ITH, ITH] = phi_t
        A[ITH, 15] = s_th
        # increment rows: velocity and pitch errors move the body-frame displacement, the
        # heading error does not (it turns the whole path); the heading-change error is the
        # change of the heading correction over the step
        A[8:10, ITH:14] = A[0:2, ITH:14]
        A[10, IPSI] = phi_p - 1.0
        A[10, 14] = s_psi

        Pa = self._Pa
        Pa[:N_STATE, :N_STATE] = self.P
        C = A @ Pa @ A.T
        self.P = C[:N_STATE, :N_STATE]
        self._x = [n + dc.real, e + dc.imag, d + dz, cpsi_b, cth_b, u1, v1, w1]
        self.t = b.t
        return C[N_STATE:, N_STATE:]

    # ---- updates ------------------------------------------------------------------------
    def reset_velocity_covariance(self, sigma: float) -> None:
        """Forget what is known about the velocity: its covariance becomes ``sigma^2 I`` (m/s)
        and uncorrelated with the rest (used to re-acquire after repeated gate rejections)."""
        P = self.P.copy()
        P[_VEL, :] = 0.0
        P[:, _VEL] = 0.0
        P[_VEL, _VEL] = sigma * sigma * np.eye(3)
        self.P = P

    def _update(self, H: np.ndarray, y: np.ndarray, R: np.ndarray, S_inv: np.ndarray) -> None:
        """Kalman update (Joseph form) with innovation ``y``, Jacobian ``H``, noise ``R`` and the
        inverse innovation covariance ``S_inv``."""
        P = self.P
        K = P @ H.T @ S_inv
        self._x = (np.array(self._x) + K @ y).tolist()
        IKH = self._eye - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (P + P.T)

    def dvl_innovation(
        self, velocity: tuple[float, ...], frame: DvlFrame, rates: tuple[float, ...]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(y, H, mask)`` of a DVL fix: innovation and Jacobian of its finite components."""
        z = np.array(velocity, dtype=float)
        mask = np.isfinite(z)
        p, q, r = rates
        rx, ry, rz = self._lever_t
        u, v, w = self._x[IU], self._x[IV], self._x[IW]
        at_dvl = np.array([u + q * rz - r * ry, v + r * rx - p * rz, w + p * ry - q * rx])
        H = self._H_instr if frame == "instrument" else self._H_body
        pred = H[:, _VEL] @ at_dvl
        return (z - pred)[mask], H[mask], mask

    def dvl_noise_sigma(self) -> tuple[float, float, float]:
        """Current DVL noise per measurement axis, 1-sigma m/s: the VB estimate ``sqrt(beta /
        alpha)`` when adapting (NaN before the first fix), else the configured spec floor."""
        if self._vb_b is None:
            if self.config.dvl_noise_adaptive:
                return (math.nan,) * 3
            s = self.config.dvl_velocity_sigma_mps
            return (s, s, s)
        v = np.sqrt(self._vb_b / self._vb_a)
        return (float(v[0]), float(v[1]), float(v[2]))

    def update_dvl(
        self,
        velocity: tuple[float, ...],
        frame: DvlFrame,
        rates: tuple[float, ...],
        force: bool = False,
        sigma: float | None = None,
    ) -> tuple[bool, float, np.ndarray]:
        """DVL velocity update at the filter time, with the body ``rates`` (rad/s) at that time.

        ``sigma``: the spec noise of this fix (1-sigma per axis, m/s; default the configured
        floor). Not adapting, it is the measurement noise. Adapting (``dvl_noise_adaptive``), the
        noise of each axis is an inverse-gamma ``IG(alpha, beta)`` (Sarkka & Nummenmaa 2009,
        "Recursive noise adaptive Kalman filtering by variational Bayesian approximations"):
        started at the spec with shape ``dvl_noise_prior_dof``, forgotten by ``rho`` per fix
        (``alpha <- rho alpha``, ``beta <- rho beta``), then ``alpha += 1/2`` and the fixed
        point ``R = diag(beta / alpha)`` -> Kalman update ``(m, P)`` -> ``beta = beta^- +
        (z - H m)^2 / 2 + diag(H P H^T) / 2`` iterated ``dvl_noise_iterations`` times.

        The gate is applied against the (adapted) noise before the update: adapting, the
        quantile of the VB predictive (:func:`predictive_gate`, ``dvl_gate_predictive``), else
        chi-square; a rejected fix changes nothing (a spike does not inflate the learned noise)
        unless ``force``. Adapting with ``dvl_noise_rescale``, the velocity covariance is then
        scaled by ``sqrt(mean(R_new / R_old))`` along the measured directions.
        Returns ``(accepted, NIS, innovation / sqrt(diag S))`` (NaN for missing components); a
        fix without any finite component returns ``(False, nan, nans)``.
        """
        y, H, mask = self.dvl_innovation(velocity, frame, rates)
        k = len(y)
        norm = np.full(3, math.nan)
        if k == 0:
            return False, math.nan, norm
        cfg = self.config
        if sigma is None:
            sigma = cfg.dvl_velocity_sigma_mps
        adaptive = cfg.dvl_noise_adaptive
        if adaptive:
            if self._vb_b is None:
                self._vb_a = np.full(3, cfg.dvl_noise_prior_dof)
                self._vb_b = self._vb_a * sigma * sigma
            rho = cfg.dvl_noise_forgetting
            a_pri = rho * self._vb_a
            b_pri = rho * self._vb_b
            r_diag = b_pri[mask] / a_pri[mask]
        else:
            r_diag = np.full(k, sigma * sigma)
        P = self.P
        HP = H @ P
        HPH = HP @ H.T
        S = HPH + np.diag(r_diag)
        S_inv = np.linalg.inv(S)
        nis = float(y @ S_inv @ y)
        norm[mask] = y / np.sqrt(np.diag(S))
        gate = self._gate[k]
        if adaptive:
            self._vb_a, self._vb_b = a_pri, b_pri  # the forgetting step happens at every fix
            if self._gate_p is not None and cfg.dvl_gate_predictive:
                gate = predictive_gate(self._gate_p, k, 2.0 * float(a_pri[mask].min()))
        if not force and nis > gate:
            return False, nis, norm
        if adaptive:
            a_post = a_pri.copy()
            a_post[mask] += 0.5
            b_post = b_pri.copy()
            for _ in range(cfg.dvl_noise_iterations):
                r_diag = b_post[mask] / a_post[mask]
                S = HPH + np.diag(r_diag)
                S_inv = np.linalg.inv(S)
                res = y - HPH @ S_inv @ y  # z - H m with m = x + K y
                HPmH = HPH - HPH @ S_inv @ HPH  # H (P - K S K^T) H^T
                b_post[mask] = b_pri[mask] + 0.5 * res * res + 0.5 * np.diag(HPmH)
            r_diag = b_post[mask] / a_post[mask]
            S_inv = np.linalg.inv(HPH + np.diag(r_diag))
            self._vb_a, self._vb_b = a_post, b_post
        self._update(H, y, np.diag(r_diag), S_inv)
        if adaptive and cfg.dvl_noise_rescale:
            # the velocity covariance was learned from fixes weighed with the previous noise
            # estimate: it scales with the noise (West & Harrison's variance learning), so a
            # velocity fitted to the first fixes under a too-small spec noise is not held with
            # a too-small covariance while the learned noise grows. Only the measured directions
            # (rows of H: orthonormal, a rotation's) are scaled, unmeasured ones keep theirs.
            d = math.sqrt(float(np.mean(r_diag / (b_pri[mask] / a_pri[mask]))))
            Hv = H[:, _VEL]
            D = np.eye(3) + (d - 1.0) * (Hv.T @ Hv)
            P = self.P
            P[_VEL, :] = D @ P[_VEL, :]
            P[:, _VEL] = P[:, _VEL] @ D
        return True, nis, norm

    def update_position(
        self, north: float, east: float, sigma: float, force: bool = False
    ) -> tuple[bool, float]:
        """Horizontal position fix (NED m, 1-sigma ``sigma`` m per axis) of the reference
        point, chi-square gated (``position_gate_probability``) unless ``force``; returns
        ``(accepted, NIS)``."""
        H = np.zeros((2, N_STATE))
        H[0, IX] = H[1, IY] = 1.0
        y = np.array([north - self._x[IX], east - self._x[IY]])
        R = sigma * sigma * np.eye(2)
        S_inv = np.linalg.inv(self.P[0:2, 0:2] + R)
        nis = float(y @ S_inv @ y)
        if not force and nis > self._pos_gate:
            return False, nis
        self._update(H, y, R, S_inv)
        return True, nis

    def update_depth(
        self, depth: float, sigma: float, lever_arm: tuple[float, float, float], ins: InsSample
    ) -> float:
        """Pressure-depth update (m, positive down, 1-sigma ``sigma``) of a sensor at
        ``lever_arm`` (m, body axes), with the INS state ``ins`` at the filter time; returns the
        innovation, m."""
        rx, ry, rz = lever_arm
        cr, sr = math.cos(ins.roll), math.sin(ins.roll)
        th = self.pitch(ins)
        cp, sp = math.cos(th), math.sin(th)
        pred = self._x[IZ] + (-sp * rx + cp * sr * ry + cp * cr * rz)
        H = np.zeros((1, N_STATE))
        H[0, IZ] = 1.0
        H[0, ITH] = -cp * rx - sp * sr * ry - sp * cr * rz
        y = np.array([depth - pred])
        R = np.array([[sigma * sigma]])
        S = float(H[0] @ self.P @ H[0]) + sigma * sigma
        self._update(H, y, R, np.array([[1.0 / S]]))
        return float(y[0])
