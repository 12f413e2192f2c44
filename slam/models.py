"""Vehicle motion and feature observation models shared by the landmark SLAM filters.

Frames and units: 2-D pose ``(x, y, heading)`` in metres and radians, heading measured from +x
towards +y (see ``config/scenario.py``: +x north, +y east, so heading is the usual clockwise-from-
north yaw; Tim Bailey's maps use the same formulas with his x, y read as ours). Every function
broadcasts over leading dimensions, so one call serves all particles (and all sigma points, all
observations) at once: poses are ``(..., 3)``, features ``(..., 2)``, controls ``(..., n_u)``.

Models (equation numbers of Mu et al. 2022, "VB-AUFastSLAM", and Cui et al. 2020, "VRFastSLAM"):

* :class:`VelocityModel` - eq. (3) of the VB paper: body velocities (forward ``vx``, starboard
  ``vy``, m/s) and yaw rate ``w`` (rad/s) from DVL and INS.
* :class:`BicycleModel` - Tim Bailey's simulator vehicle: speed ``V`` (m/s) and steer angle ``G``
  (rad) on a wheelbase ``L``.
* :class:`RangeBearing` - eq. (4) of the VB paper: range (m) and bearing (rad, from the heading,
  positive towards +y) of a point feature ``(mx, my)``.
* :class:`LineFeature` - a line in normal form ``x cos(theta) + y sin(theta) = rho`` (the VR
  paper's (rho, theta) features from MSIS Hough voting), observed in the vehicle frame as
  ``rho_v = rho - x cos(theta) - y sin(theta)`` (signed distance, m) and
  ``theta_v = theta - heading`` (rad). The signed form keeps the model smooth; the simulator
  produces observations in the same form.

Process noise enters additively on the controls (``u + n``, ``n ~ N(0, Q)``), as in the VB
paper's augmented state (eqs. 5-6), so ``Q`` is ``n_u x n_u``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from auvgw.ground.geometry import wrap_angle

__all__ = [
    "BicycleModel",
    "LineFeature",
    "MotionModel",
    "ObservationModel",
    "RangeBearing",
    "VelocityModel",
    "wrap_angle",
]



class MotionModel(ABC):
    """``x_k = f(x_{k-1}, u_k, dt)``: pose ``(..., 3)``, control ``(..., n_u)``, step ``dt`` s."""

    #: number of control inputs
    n_u: int

    @abstractmethod
    def f(self, x: np.ndarray, u: np.ndarray, dt: float, wrap: bool = True) -> np.ndarray:
        """Next pose (heading wrapped into [-pi, pi) unless ``wrap`` is false)."""

    @abstractmethod
    def jacobians(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(df/dx (..., 3, 3), df/du (..., 3, n_u))`` at ``(x, u)``."""


class BicycleModel(MotionModel):
    """Bailey's vehicle: ``x += V dt cos(phi + G)``, ``y += V dt sin(phi + G)``,
    ``phi += V dt sin(G) / L``; controls ``u = (V m/s, G rad)``."""

    n_u = 2

    def __init__(self, wheelbase_m: float = 4.0) -> None:
        self.wheelbase = float(wheelbase_m)

    def f(self, x: np.ndarray, u: np.ndarray, dt: float, wrap: bool = True) -> np.ndarray:
        v, g = u[..., 0], u[..., 1]
        phi = x[..., 2]
        a = phi + g
        vdt = v * dt
        out = np.empty(np.broadcast_shapes(x.shape, (*u.shape[:-1], 3)))
        out[..., 0] = x[..., 0] + vdt * np.cos(a)
        out[..., 1] = x[..., 1] + vdt * np.sin(a)
        h = phi + vdt * np.sin(g) / self.wheelbase
        out[..., 2] = wrap_angle(h) if wrap else h
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        v, g = u[..., 0], u[..., 1]
        a = x[..., 2] + g
        s, c = np.sin(a), np.cos(a)
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        fx = np.zeros((*shape, 3, 3))
        fx[..., 0, 0] = fx[..., 1, 1] = fx[..., 2, 2] = 1.0
        fx[..., 0, 2] = -v * dt * s
        fx[..., 1, 2] = v * dt * c
        fu = np.zeros((*shape, 3, 2))
        fu[..., 0, 0] = dt * c
        fu[..., 0, 1] = -v * dt * s
        fu[..., 1, 0] = dt * s
        fu[..., 1, 1] = v * dt * c
        fu[..., 2, 0] = dt * np.sin(g) / self.wheelbase
        fu[..., 2, 1] = v * dt * np.cos(g) / self.wheelbase
        return fx, fu


class VelocityModel(MotionModel):
    """Eq. (3) of the VB paper: ``u = (vx forward m/s, vy starboard m/s, w yaw rate rad/s)``."""

    n_u = 3

    def f(self, x: np.ndarray, u: np.ndarray, dt: float, wrap: bool = True) -> np.ndarray:
        vx, vy, w = u[..., 0] * dt, u[..., 1] * dt, u[..., 2] * dt
        phi = x[..., 2]
        s, c = np.sin(phi), np.cos(phi)
        out = np.empty(np.broadcast_shapes(x.shape, (*u.shape[:-1], 3)))
        out[..., 0] = x[..., 0] + vx * c - vy * s
        out[..., 1] = x[..., 1] + vx * s + vy * c
        out[..., 2] = wrap_angle(phi + w) if wrap else phi + w
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        vx, vy = u[..., 0] * dt, u[..., 1] * dt
        phi = x[..., 2]
        s, c = np.sin(phi), np.cos(phi)
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        fx = np.zeros((*shape, 3, 3))
        fx[..., 0, 0] = fx[..., 1, 1] = fx[..., 2, 2] = 1.0
        fx[..., 0, 2] = -vx * s - vy * c
        fx[..., 1, 2] = vx * c - vy * s
        fu = np.zeros((*shape, 3, 3))
        fu[..., 0, 0] = dt * c
        fu[..., 0, 1] = -dt * s
        fu[..., 1, 0] = dt * s
        fu[..., 1, 1] = dt * c
        fu[..., 2, 2] = dt
        return fx, fu


class ObservationModel(ABC):
    """``z = h(x, m)`` for a 2-D feature ``m`` seen from pose ``x``; 2-D measurement."""

    #: which measurement components are angles (wrapped in innovations)
    angular: tuple[bool, bool]
    #: which feature components are angles (wrapped after updates)
    feature_angular: tuple[bool, bool] = (False, False)

    @abstractmethod
    def h(self, x: np.ndarray, m: np.ndarray) -> np.ndarray:
        """Predicted measurement ``(..., 2)``."""

    @abstractmethod
    def jacobians(self, x: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(dh/dx (..., 2, 3), dh/dm (..., 2, 2))``."""

    @abstractmethod
    def inverse(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Feature ``(..., 2)`` that would produce measurement ``z`` from pose ``x``."""

    @abstractmethod
    def inverse_jacobian(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``d inverse / dz (..., 2, 2)`` (to initialise a feature covariance ``G R G^T``)."""

    def residual(self, z: np.ndarray, zhat: np.ndarray) -> np.ndarray:
        """``z - zhat`` with angular components wrapped."""
        v = z - zhat
        for i, ang in enumerate(self.angular):
            if ang:
                v[..., i] = wrap_angle(v[..., i])
        return v

    def wrap_feature(self, m: np.ndarray) -> np.ndarray:
        """Feature(s) with angular components wrapped (in place, returned)."""
        for i, ang in enumerate(self.feature_angular):
            if ang:
                m[..., i] = wrap_angle(m[..., i])
        return m


class RangeBearing(ObservationModel):
    """Eq. (4) of the VB paper: ``r = |m - p|``, ``b = atan2(my - y, mx - x) - heading``."""

    angular = (False, True)

    def h(self, x: np.ndarray, m: np.ndarray) -> np.ndarray:
        dx = m[..., 0] - x[..., 0]
        dy = m[..., 1] - x[..., 1]
        out = np.empty((*np.broadcast_shapes(x.shape[:-1], m.shape[:-1]), 2))
        out[..., 0] = np.hypot(dx, dy)
        out[..., 1] = wrap_angle(np.arctan2(dy, dx) - x[..., 2])
        return out

    def jacobians(self, x: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx = m[..., 0] - x[..., 0]
        dy = m[..., 1] - x[..., 1]
        d2 = dx * dx + dy * dy
        d = np.sqrt(d2)
        shape = np.broadcast_shapes(x.shape[:-1], m.shape[:-1])
        hm = np.empty((*shape, 2, 2))
        hm[..., 0, 0] = dx / d
        hm[..., 0, 1] = dy / d
        hm[..., 1, 0] = -dy / d2
        hm[..., 1, 1] = dx / d2
        hx = np.empty((*shape, 2, 3))
        hx[..., :, :2] = -hm
        hx[..., 0, 2] = 0.0
        hx[..., 1, 2] = -1.0
        return hx, hm

    def inverse(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        a = z[..., 1] + x[..., 2]
        out = np.empty((*np.broadcast_shapes(x.shape[:-1], z.shape[:-1]), 2))
        out[..., 0] = x[..., 0] + z[..., 0] * np.cos(a)
        out[..., 1] = x[..., 1] + z[..., 0] * np.sin(a)
        return out

    def inverse_jacobian(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        a = z[..., 1] + x[..., 2]
        s, c = np.sin(a), np.cos(a)
        r = z[..., 0]
        g = np.empty((*np.broadcast_shapes(x.shape[:-1], z.shape[:-1]), 2, 2))
        g[..., 0, 0] = c
        g[..., 0, 1] = -r * s
        g[..., 1, 0] = s
        g[..., 1, 1] = r * c
        return g


class LineFeature(ObservationModel):
    """Line ``m = (rho m, theta rad)`` in the global frame, seen as
    ``(rho - x cos(theta) - y sin(theta), theta - heading)`` from pose ``(x, y, heading)``."""

    angular = (False, True)
    feature_angular = (False, True)

    def h(self, x: np.ndarray, m: np.ndarray) -> np.ndarray:
        th = m[..., 1]
        out = np.empty((*np.broadcast_shapes(x.shape[:-1], m.shape[:-1]), 2))
        out[..., 0] = m[..., 0] - x[..., 0] * np.cos(th) - x[..., 1] * np.sin(th)
        out[..., 1] = wrap_angle(th - x[..., 2])
        return out

    def jacobians(self, x: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = m[..., 1]
        s, c = np.sin(th), np.cos(th)
        shape = np.broadcast_shapes(x.shape[:-1], m.shape[:-1])
        hx = np.zeros((*shape, 2, 3))
        hx[..., 0, 0] = -c
        hx[..., 0, 1] = -s
        hx[..., 1, 2] = -1.0
        hm = np.zeros((*shape, 2, 2))
        hm[..., 0, 0] = 1.0
        hm[..., 0, 1] = x[..., 0] * s - x[..., 1] * c
        hm[..., 1, 1] = 1.0
        return hx, hm

    def inverse(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        th = wrap_angle(z[..., 1] + x[..., 2])
        out = np.empty((*np.broadcast_shapes(x.shape[:-1], z.shape[:-1]), 2))
        out[..., 0] = z[..., 0] + x[..., 0] * np.cos(th) + x[..., 1] * np.sin(th)
        out[..., 1] = th
        return out

    def inverse_jacobian(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        th = z[..., 1] + x[..., 2]
        g = np.zeros((*np.broadcast_shapes(x.shape[:-1], z.shape[:-1]), 2, 2))
        g[..., 0, 0] = 1.0
        g[..., 0, 1] = -x[..., 0] * np.sin(th) + x[..., 1] * np.cos(th)
        g[..., 1, 1] = 1.0
        return g
