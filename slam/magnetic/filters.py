"""AMB-SLAM, MB-SLAM and dead reckoning (Hou et al. 2019, Sec. 2.4) on the project's EKF-SLAM.

The state is eqs. (14)-(18): vehicle ``(x, y, phi)`` and the 2-D beacons; beacons are static,
eq. (13). The paper's equations are used with its errors corrected (reading notes A14-A16):

* prediction, eqs. (19)-(20): the filter's motion model (Table 4's bicycle,
  :class:`~auvgw.slam.models.BicycleModel`, or :class:`~auvgw.slam.models.VelocityModel`) with
  its own Jacobian; eq. (20)'s ``Dy cos(phi)`` entry should read ``Dx cos(phi)`` (A14);
* beacon observation, eq. (21) range and bearing, with the correct Jacobian of eq. (22)
  (:class:`~auvgw.slam.models.RangeBearing`; the printed signs are wrong, A15);
* EKF update, eqs. (23)-(27), with the prior ``P^-`` where the paper prints ``P^-1`` and
  ``P+ = P- - W S W^T`` where it prints ``+`` (A16); symmetrised;
* augmentation, eqs. (28)-(29), with the standard covariance ``G_v P_vv G_v^T + G_z R G_z^T`` and
  cross-covariances ``G_v P_vx`` (the paper gives none);
* unknown association: nearest neighbour with Table 4's gates read as Bailey's squared
  Mahalanobis distances (A12, A13): accept ``D^2 < 8``, new beacon ``D^2 > 28``, otherwise ignored.

The acoustic beacon (Sec. 2.4.2, no equation) is a range-bearing observation of a *known, fixed*
position (A17, A23): :meth:`MagneticSLAM.anchor_update` applies eqs. (23)-(27) with ``H`` non-zero
in the vehicle columns only (the anchor is not in the state). ``range-only`` is the
Conclusions' variant. AMB-SLAM uses it; MB-SLAM is the same filter without it (Sec. 3.4);
dead reckoning (``dr``) only predicts.

Two filters the paper does not have (issue 28, the fair baselines):

* ``acoustic-only``: the same EKF with the acoustic fixes and no magnetic beacons, the baseline
  that separates "an absolute acoustic fix against none" from what the magnetic beacons add;
* ``mb-slam-fej``: MB-SLAM as a first-estimates Jacobian EKF (Huang, Mourikis and Roumeliotis,
  "Analysis and improvement of the consistency of EKF-based SLAM", ICRA 2008). Plain EKF-SLAM
  linearises at the latest estimates, which gives the linearised system an observable global
  heading that the nonlinear one does not have: the filter gains heading information it cannot
  have and becomes overconfident (inconsistent). FEJ evaluates every Jacobian at the *first*
  estimate of each state: eq. (20)'s pose Jacobian with the displacement ``f(x_k|k) - x_k|k-1``
  (the propagated pose, not the updated one), and eq. (22)'s at the pose's prior at the scan and
  each beacon's estimate when it was added (eqs. 28-29). Innovations and the state still use the
  latest estimates (as in Huang et al.). The planar pose Jacobian form holds for both motion
  models (a pose increment rotated by the heading).
* ``mb-slam-oc``: MB-SLAM as an observability-constrained EKF (Huang, Mourikis and Roumeliotis,
  "Observability-based rules for designing consistent EKF SLAM estimators", IJRR 2010; the
  closed-form "smallest change of the Jacobian that meets the constraint" of Hesch et al.'s
  OC-VINS, 2014). Derivation in ``docs/slam_magnetic.md`` ("An observability-constrained
  MB-SLAM"); (O1)-(O5) below are its equations. Without an absolute fix the nonlinear system is
  unchanged by a planar translation and a rotation about the origin, so the linearised system
  must keep the 3 directions (O1) ``N = [[I2, J p], [0, 1], [I2, J m_1], ...]`` (``J`` the 90
  degree rotation) unobservable. The filter keeps the robot's null-space point at the pose's
  prior ``p_k|k-1`` and each beacon's at the point its augmentation Jacobian gives (O4);
  propagation (O2) ``Phi N_k = N_k+1`` has one solution of Phi's form, ``F[:2, 2] = J
  (p_k+1|k - p_k|k-1)`` (FEJ's); each observation's ``A = dh/dm`` (eq. 22 at the latest
  estimates) is changed as little as possible (Frobenius norm) so that (O3) ``H N = 0``:
  ``A* = A - (A w - e2) w^T / |w|^2``, ``w = J (m* - p*)``, with ``H = [-A*, (0, -1)^T | A*]``.
  FEJ meets the same constraint with ``A`` evaluated at the first estimates; OC keeps the
  latest estimates' ``A`` wherever the constraint allows. With the acoustic beacon the system
  is observable (range-bearing) or keeps only the rotation about the anchor (range-only): OC is
  built for MB-SLAM only.
"""

from __future__ import annotations

import numpy as np

from auvgw.slam.landmark.association import KnownAssociation, NearestNeighbour
from auvgw.slam.landmark.ekfslam import EKFSLAM
from auvgw.slam.models import MotionModel, RangeBearing, wrap_angle

__all__ = [
    "GATE_AUGMENT",
    "GATE_REJECT",
    "MAGNETIC_ALGORITHMS",
    "FirstEstimateMotion",
    "MagneticSLAM",
    "make_magnetic",
    "null_space",
]

#: Table 4 "maximum distance for association 8 m": Bailey's GATE_REJECT, squared Mahalanobis (A12)
GATE_REJECT = 8.0
#: Table 4 "augment distance 28 m": Bailey's GATE_AUGMENT, squared Mahalanobis (A13)
GATE_AUGMENT = 28.0
MAGNETIC_ALGORITHMS = ("amb-slam", "acoustic-only", "mb-slam", "mb-slam-fej", "mb-slam-oc", "dr")


class FirstEstimateMotion(MotionModel):
    """``model`` with the first-estimates pose Jacobian (Huang et al. 2008): ``F`` from the
    displacement ``f(x, u) - first`` (``first`` the pose's prior, ``x`` its latest estimate),
    ``G`` (the control Jacobian) at ``x``. Planar poses: any model that moves the position by an
    increment rotated with the heading (bicycle, velocity)."""

    def __init__(self, model: MotionModel, first: np.ndarray) -> None:
        self.model = model
        self.first = first
        self.n_u = model.n_u

    def f(self, x: np.ndarray, u: np.ndarray, dt: float, wrap: bool = True) -> np.ndarray:
        return self.model.f(x, u, dt, wrap)

    def jacobians(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        _, fu = self.model.jacobians(x, u, dt)
        new = self.model.f(x, u, dt)
        fx = np.eye(3)
        fx[0, 2] = -(new[1] - self.first[1])
        fx[1, 2] = new[0] - self.first[0]
        return fx, fu


def null_space(p_robot: np.ndarray, m_points: np.ndarray) -> np.ndarray:
    """(O1): the ``(3 + 2 n, 3)`` basis of the directions a planar SLAM system without an
    absolute fix cannot observe (x, y translation; rotation about the origin), at the robot's
    point ``p_robot (2,)`` and the beacons' ``m_points (n, 2)`` (m, NED)."""
    pts = np.vstack([np.asarray(p_robot, float).reshape(1, 2), np.asarray(m_points).reshape(-1, 2)])
    n = np.zeros((1 + 2 * len(pts), 3))
    rows = np.r_[0, 3 + 2 * np.arange(len(pts) - 1)]
    for i, r in enumerate(rows):
        n[r : r + 2, :2] = np.eye(2)
        n[r : r + 2, 2] = (-pts[i, 1], pts[i, 0])  # J p
    n[2, 2] = 1.0
    return n


class MagneticSLAM(EKFSLAM):
    """EKF-SLAM over magnetic beacons with an optional known-position acoustic anchor.

    ``anchor_xy`` (m, NED) is the acoustic beacon; ``use_beacons=False`` ignores the magnetic
    beacons (dead reckoning when there is no anchor either); ``known``: observations come with
    their beacon ids (:meth:`update_each`), no gating (an evaluation of the filter alone);
    ``fej``: first-estimates Jacobians; ``oc``: observability-constrained (module docstring)."""

    def __init__(
        self,
        motion: MotionModel,
        q: np.ndarray,
        r: np.ndarray,
        *,
        x0: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        anchor_xy: tuple[float, float] | None = None,
        use_beacons: bool = True,
        gates: tuple[float, float] = (GATE_REJECT, GATE_AUGMENT),
        name: str = "amb-slam",
        known: bool = False,
        fej: bool = False,
        oc: bool = False,
    ) -> None:
        if oc and (fej or anchor_xy is not None):
            raise ValueError("oc is MB-SLAM's constraint: no acoustic anchor and not with fej")
        assoc = KnownAssociation() if known else NearestNeighbour(gates[0], gates[1])
        super().__init__(motion, RangeBearing(), q, r, x0=x0, association=assoc)
        self.name = name
        self.anchor = None if anchor_xy is None else np.asarray(anchor_xy, float).reshape(2)
        self.use_beacons = use_beacons
        self.fej = fej
        self.oc = oc
        #: FEJ and OC: the pose's first estimate at the current step (its prior, x_k|k-1; OC's
        #: robot null-space point)
        self.x_first = self.xs[:3].copy()
        #: FEJ: each beacon's first estimate (its position when added), (n_lm, 2)
        self.lm_first = np.zeros((0, 2))
        #: OC: each beacon's null-space point (O4), (n_lm, 2)
        self.lm_null = np.zeros((0, 2))

    def null_space(self) -> np.ndarray:
        """(O1) at the filter's null-space points (OC: the propagated null space)."""
        return null_space(self.x_first[:2], self.lm_null if self.oc else self.lm_first)

    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        """Eqs. (19)-(20); with ``fej`` the pose Jacobian uses the first estimates (module
        docstring): ``F = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]``, ``(dx, dy) = p_k+1|k -
        p_k|k-1`` (the EKF's own propagation, with :class:`FirstEstimateMotion`'s Jacobian)."""
        if not (self.fej or self.oc):  # OC: (O2) Phi N_k = N_k+1 has this one solution
            super().predict(u, dt, rng)
            return
        model = self.motion
        self.motion = FirstEstimateMotion(model, self.x_first)
        try:
            super().predict(u, dt, rng)
        finally:
            self.motion = model
        self.x_first = self.xs[:3].copy()

    def _h_blocks(self, lm_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. (21) at the latest estimates; eq. (22) at the first estimates with ``fej``, at the
        latest ones changed by (O5) with ``oc``."""
        zhat, hx, hm = super()._h_blocks(lm_idx)
        if self.fej:
            hx, hm = self.obs.jacobians(self.x_first, self.lm_first[lm_idx])
        elif self.oc:
            d = self.lm_null[lm_idx] - self.x_first[:2]  # m* - p*
            w = np.stack([-d[:, 1], d[:, 0]], axis=1)  # J (m* - p*)
            e2 = np.array([0.0, 1.0])
            # (O5): the smallest change of A with A w = e2, i.e. (O3) H N = 0 for the rotation
            # column (-A J p* + (0, -1) + A J m* = A w - e2); translation: -A + A = 0 by form
            miss = np.einsum("lij,lj->li", hm, w) - e2
            hm = hm - miss[:, :, None] * w[:, None, :] / np.einsum("li,li->l", w, w)[:, None, None]
            hx = hx.copy()
            hx[:, :, :2] = -hm
        return zhat, hx, hm

    def _add(self, z: np.ndarray, fid: int | None) -> None:
        super()._add(z, fid)
        m = self.xs[1 + 2 * self.n_lm : 3 + 2 * self.n_lm]
        self.lm_first = np.vstack([self.lm_first, m])
        # (O4): the augmentation eqs. (28)-(29) map N's robot rows to G_v [I2, J p*] = [I2, J (p*
        # + m - p)] (G_v's heading column J (m - p) at the latest pose p)
        self.lm_null = np.vstack([self.lm_null, self.x_first[:2] + m - self.xs[:2]])

    def update_each(
        self, z: np.ndarray, r: np.ndarray | None = None, ids: np.ndarray | None = None
    ) -> None:
        """Beacon observations ``z (m, 2)`` (range m, bearing rad), one at a time, each with
        its own covariance ``r (m, 2, 2)`` (e.g. the MLP's; default the filter's ``R0``).
        Association and augmentation use that covariance; ``ids (m,)``: the true beacons (a
        filter built with ``known=True`` needs them)."""
        if not self.use_beacons:
            return
        z = np.asarray(z, float).reshape(-1, 2)
        for j in range(len(z)):
            self.rdiag = np.diag(self.r0).copy() if r is None else np.diag(r[j]).copy()
            self.update(z[j : j + 1], np.random.default_rng(0),
                        None if ids is None else np.asarray(ids[j : j + 1]))  # fmt: skip
        self.rdiag = np.diag(self.r0).copy()

    def anchor_update(self, z: np.ndarray, r: np.ndarray) -> float:
        """Acoustic beacon observation ``z`` = (horizontal range m, bearing rad) or (range,)
        with covariance ``r`` (2x2 or 1x1): eqs. (23)-(27) with a vehicle-only Jacobian.
        Returns the squared Mahalanobis distance of the innovation."""
        if self.anchor is None:
            raise ValueError(f"{self.name}: no acoustic beacon position configured")
        z = np.atleast_1d(np.asarray(z, float))
        m = len(z)
        k = 3 + 2 * self.n_lm
        xv = self.xs[:3]
        rb = self.obs
        zhat = rb.h(xv, self.anchor[None])[0][:m]  # eq. (21) with a known landmark
        xj = self.x_first if self.fej else xv
        hx = rb.jacobians(xj, self.anchor[None])[0][0][:m]  # eq. (22), vehicle columns only
        v = z - zhat  # eq. (23)
        if m == 2:
            v[1] = wrap_angle(v[1])
        p = self.p[:k, :k]
        pht = p[:, :3] @ hx.T
        s = hx @ p[:3, :3] @ hx.T + np.asarray(r, float).reshape(m, m)  # eq. (24), P^- not P^-1
        w = np.linalg.solve(s, pht.T).T  # eq. (25)
        self.xs[:k] += w @ v  # eq. (26)
        self.xs[2] = wrap_angle(self.xs[2])
        pn = p - w @ s @ w.T  # eq. (27), minus (the paper prints +)
        self.p[:k, :k] = 0.5 * (pn + pn.T)
        return float(v @ np.linalg.solve(s, v))

    def forget_landmarks(self) -> None:
        """Drop every beacon from the state (the open-loop study: a revisit cannot close the
        loop because the earlier beacons are gone)."""
        k = 3 + 2 * self.n_lm
        self.p[3:k, :] = 0.0
        self.p[:, 3:k] = 0.0
        self.xs[3:k] = 0.0
        self.n_lm = 0
        self.lm_first = np.zeros((0, 2))
        self.lm_null = np.zeros((0, 2))
        self.ids.clear()
        self._id_index.clear()


def make_magnetic(
    name: str,
    motion: MotionModel,
    q: np.ndarray,
    r: np.ndarray,
    x0: np.ndarray | tuple[float, float, float],
    anchor_xy: tuple[float, float],
    gates: tuple[float, float] = (GATE_REJECT, GATE_AUGMENT),
    known: bool = False,
) -> MagneticSLAM:
    """``amb-slam`` (beacons + acoustic anchor), ``acoustic-only`` (the anchor, no beacons),
    ``mb-slam`` (beacons only), ``mb-slam-fej`` (MB-SLAM with first-estimates Jacobians),
    ``mb-slam-oc`` (MB-SLAM, observability-constrained) or ``dr``; ``known``: association by
    the observations' true ids (evaluation)."""
    if name not in MAGNETIC_ALGORITHMS:
        raise ValueError(f"unknown magnetic algorithm {name!r}; choose from {MAGNETIC_ALGORITHMS}")
    return MagneticSLAM(
        motion, q, r, x0=x0,
        anchor_xy=anchor_xy if name in ("amb-slam", "acoustic-only") else None,
        use_beacons=name not in ("dr", "acoustic-only"), gates=gates, name=name, known=known,
        fej=name.endswith("-fej"), oc=name.endswith("-oc"),
    )  # fmt: skip
