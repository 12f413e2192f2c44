"""EKF-SLAM and the adaptive variants the VR paper compares against (Cui et al. 2020, section 4).

One joint Gaussian over ``[x, y, heading, m1x, m1y, ...]`` (metres, radians).

The VR paper names SHEKF-SLAM (its ref. [20], Sage and Husa 1969), STEKF-SLAM (refs. [21-24])
and CAEKF-SLAM ("combining" the two) but gives none of their equations or parameters (no
forgetting factor, fading factor or softening factor) and no wrong-``R0`` experiment: its Table 1
compares them with the noise statistics of its eq. (25) and says CAEKF-SLAM "estimates better
when the initial value of measurement noise is selected properly". The equations below are
therefore those of the cited originals:

* ``none`` - plain EKF-SLAM;
* ``sage-husa`` (SHEKF-SLAM) - Sage and Husa's noise statistics estimator with fading memory
  (forgetting factor ``b``, 0.95-0.99 in the literature, default 0.98), applied to the
  observation noise ``R``, the quantity the sonar's noise changes::

      d_k = (1 - b) / (1 - b^(k+1))
      R_k = (1 - d_k) R_{k-1} + d_k (v_k v_k^T - H_k P_k^- H_k^T)

  per component (range, bearing: ``R`` is diagonal for this sensor), ``v v^T - H P^- H^T``
  averaged over the scan's observations, one step per scan. The bracket can be negative (it is
  a difference) and is used as it is (unbiased); the *result* ``R_k`` is floored at
  ``floor * R0`` (default 0.01) so it stays positive definite. (Flooring each raw sample biases
  ``R`` upwards, +17 % on a linear-Gaussian toy with one observation per step.) New landmarks
  are initialised with the current ``R_k``;
* ``strong-tracking`` (STEKF-SLAM) - Zhou and Frank's suboptimal fading factor (strong tracking
  filter, 1996), with the process noise accumulated since the last scan ``Q_acc`` and
  ``A = Phi P Phi^T = P^- - Q_acc`` the propagated covariance::

      V_1 = v_1 v_1^T,  V_k = (rho V_{k-1} + v_k v_k^T) / (1 + rho)   (rho = 0.95)
      N_k = V_k - H Q_acc H^T - beta R_k                               (beta >= 1, softening)
      M_k = H A H^T
      lambda_k = max(1, tr N_k / tr M_k)
      P_k^- = lambda_k A + Q_acc

  The innovation dimension changes from scan to scan, so the traces are means over the scan's
  observations of traces weighted by ``R0^-1`` (range and bearing made dimensionless). The
  fading is applied to the vehicle rows and columns of ``A`` only, and there only in the
  directions the scan observes: ``P^- = T A T^T + Q_acc`` with ``T = diag(I3 + (sqrt(lambda)
  - 1) Pi, I)``, ``Pi = A_vv Hv^T (Hv A_vv Hv^T)^+ Hv`` (:func:`observed_fading`), which
  scales ``Hv A_vv Hv^T`` by ``lambda`` as Zhou's ``lambda A`` does and keeps the vehicle
  covariance given ``Hv x``. Fading the static map discards map information; fading the whole
  vehicle block (``D A D``, ``D = diag(sqrt(lambda) I3, I)``) grew the variance along a wall
  seen only as a line by ``lambda`` at every scan (harbour lines: path RMSE 2.24 m against
  EKF-SLAM's 1.10 m with the true ``R0``; singular ``S`` in 28 of 30 runs with ``0.1 R0``);
  fading the whole state diverged even on points when ``R0`` was too small. ``beta = 3``:
  with ``beta = 1`` the factor fires on the ordinary scatter of single-observation scans.
  ``lambda >= 1`` by construction, so the fading can only *inflate* ``P``: when the assumed
  ``R`` is too large the innovations are smaller than predicted, ``N_k < M_k`` and strong
  tracking is plain EKF. When the assumed ``R`` is too small it fires at every scan and
  inflates the pose covariance until ``H P H^T`` explains the missing noise, which raises a
  gain that is already too large (in a scalar random walk the error variance grows with the
  gain beyond the optimal one), so it is worse than EKF there: strong tracking is a remedy for
  model mismatch (abrupt changes, drift at loop closure), not for a wrong ``R``;
* ``combined`` (CAEKF-SLAM) - Sage-Husa first, then strong tracking with the adapted ``R_k``
  in ``N_k`` (the usual combination of the two estimators).

Association: ``known``, ``nn`` (eq. 49 with the full joint covariance) or ``jcbb``.
"""

from __future__ import annotations

import numpy as np

from auvgw.slam.landmark.association import (
    JCBB,
    Association,
    KnownAssociation,
    NearestNeighbour,
    jcbb,
)
from auvgw.slam.landmark.base import LandmarkFilter, LandmarkMap, inv2, quad2
from auvgw.slam.models import MotionModel, ObservationModel, wrap_angle

__all__ = [
    "ADAPTIVE_MODES",
    "EKFSLAM",
    "fading_factor",
    "innovation_power",
    "observed_fading",
    "sage_husa_gain",
    "sage_husa_step",
]

ADAPTIVE_MODES = ("none", "sage-husa", "strong-tracking", "combined")


def sage_husa_gain(k: int, b: float) -> float:
    """Sage-Husa fading-memory weight ``d_k = (1 - b) / (1 - b^(k+1))`` for step ``k >= 1`` and
    forgetting factor ``0 < b < 1`` (``d_1 = 1 / (1 + b)``, tending to ``1 - b``)."""
    if not 0.0 < b < 1.0:
        raise ValueError(f"the Sage-Husa forgetting factor b must be in (0, 1), got {b}")
    return (1.0 - b) / (1.0 - b ** (k + 1))


def sage_husa_step(
    rdiag: np.ndarray, v: np.ndarray, hph_diag: np.ndarray, d: float, floor: np.ndarray
) -> np.ndarray:
    """One Sage-Husa update of a diagonal observation noise.

    ``rdiag (n,)`` the current variances, ``v (m, n)`` the innovations of one step's ``m``
    observations, ``hph_diag (m, n)`` the diagonals of their predicted covariances
    ``H P^- H^T`` (without ``R``), ``d`` the weight :func:`sage_husa_gain`, ``floor (n,)`` the
    lowest raw estimate accepted (keeps ``R`` positive definite). Returns
    ``(1 - d) R + d max(mean(v^2 - diag(H P^- H^T)), floor)``.
    """
    r_hat = (v * v - hph_diag).mean(axis=0)
    return np.maximum((1.0 - d) * rdiag + d * r_hat, floor)


def innovation_power(v: np.ndarray, w: np.ndarray) -> float:
    """``mean_j v_j^T diag(w) v_j``: the weighted trace of ``v v^T`` per observation,
    ``v (m, n)``, weights ``w (n,)`` (inverse nominal variances)."""
    return float(np.mean((v * v) @ w))


def fading_factor(
    v_k: float,
    hah_diag: np.ndarray,
    hqh_diag: np.ndarray,
    rdiag: np.ndarray,
    w: np.ndarray,
    beta: float,
) -> float:
    """Zhou's suboptimal fading factor ``max(1, tr N / tr M)``, ``N = V - H Q H^T - beta R``,
    ``M = H A H^T``, with traces weighted by ``w (n,)`` and averaged over the ``m``
    observations: ``v_k`` the smoothed :func:`innovation_power`, ``hah_diag (m, n)`` and
    ``hqh_diag (m, n)`` the diagonals of ``H A H^T`` and ``H Q_acc H^T``, ``rdiag (n,)`` the
    observation noise the filter uses, ``beta`` the softening factor. 1 when ``M <= 0``."""
    m_k = float(np.mean(hah_diag @ w))
    if m_k <= 0.0:
        return 1.0
    n_k = v_k - float(np.mean(hqh_diag @ w)) - beta * float(w @ rdiag)
    return max(1.0, n_k / m_k)


def observed_fading(a: np.ndarray, hv: np.ndarray, lam: float) -> np.ndarray:
    """``T = I + (sqrt(lambda) - 1) Pi`` with ``Pi = A Hv^T (Hv A Hv^T)^+ Hv`` the
    ``A``-orthogonal projector onto the vehicle directions the scan observes: ``T A T^T = A +
    (lambda - 1) Pi A`` scales ``Hv A Hv^T`` by ``lambda`` and leaves unobserved directions (along
    a wall seen as a line) alone. ``a (3, 3)`` the vehicle block of ``A``, ``hv (2m, 3)``."""
    ah = a @ hv.T
    pi = ah @ np.linalg.pinv(hv @ ah, hermitian=True) @ hv
    return np.eye(3) + (np.sqrt(lam) - 1.0) * pi


class EKFSLAM(LandmarkFilter):
    """EKF-SLAM with optional Sage-Husa and/or strong-tracking adaptation."""

    def __init__(
        self,
        motion: MotionModel,
        obs: ObservationModel,
        q: np.ndarray,
        r: np.ndarray,
        *,
        x0: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        association: Association | None = None,
        adaptive: str = "none",
        sh_forgetting: float = 0.98,
        sh_floor: float = 0.01,
        st_rho: float = 0.95,
        st_beta: float = 3.0,
        capacity: int = 64,
    ) -> None:
        if adaptive not in ADAPTIVE_MODES:
            raise ValueError(f"adaptive must be one of {ADAPTIVE_MODES}, got {adaptive!r}")
        if not 0.0 < sh_forgetting < 1.0:
            raise ValueError(f"sh_forgetting (b) must be in (0, 1), got {sh_forgetting}")
        if st_beta < 1.0:
            raise ValueError(f"st_beta (softening factor) must be >= 1, got {st_beta}")
        if not 0.0 < st_rho <= 1.0:
            raise ValueError(f"st_rho must be in (0, 1], got {st_rho}")
        self.name = {"none": "ekf", "sage-husa": "shekf", "strong-tracking": "stekf"}.get(
            adaptive, "caekf"
        )
        self.motion = motion
        self.obs = obs
        self.q = np.asarray(q, dtype=float).reshape(motion.n_u, motion.n_u)
        self.r0 = np.asarray(r, dtype=float).reshape(2, 2)
        self.rdiag = np.diag(self.r0).copy()
        self.association = association or KnownAssociation()
        self.adaptive = adaptive
        self.sh_b = float(sh_forgetting)
        self.sh_floor = float(sh_floor)
        self.st_rho = float(st_rho)
        self.st_beta = float(st_beta)
        self._qacc = np.zeros((3, 3))
        n = 3 + 2 * max(int(capacity), 4)
        self.xs = np.zeros(n)
        self.xs[:3] = np.asarray(x0, dtype=float)
        self.p = np.zeros((n, n))
        self.n_lm = 0
        self.ids: list[int] = []
        self._id_index: dict[int, int] = {}
        self._k = 0
        self._v_st: float | None = None
        self.last_lambda = 1.0
        self._w = 1.0 / np.diag(self.r0)

    # ------------------------------------------------------------------ interface
    @property
    def neff(self) -> float:
        return float("nan")

    def estimate(self) -> np.ndarray:
        return self.xs[:3].copy()

    def landmarks(self) -> LandmarkMap:
        k = self.n_lm
        mean = self.xs[3 : 3 + 2 * k].reshape(k, 2).copy()
        idx = 3 + 2 * np.arange(k)
        cov = np.empty((k, 2, 2))
        for a in range(2):
            for b in range(2):
                cov[:, a, b] = self.p[idx + a, idx + b]
        return LandmarkMap(mean, cov, np.array(self.ids, dtype=np.int64))

    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        u = np.asarray(u, dtype=float)
        k = 3 + 2 * self.n_lm
        fx, fu = self.motion.jacobians(self.xs[:3], u, dt)
        self.xs[:3] = self.motion.f(self.xs[:3], u, dt)
        p = self.p
        qk = fu @ self.q @ fu.T
        p[:3, :3] = fx @ p[:3, :3] @ fx.T + qk
        self._qacc = fx @ self._qacc @ fx.T + qk
        if k > 3:
            p[:3, 3:k] = fx @ p[:3, 3:k]
            p[3:k, :3] = p[:3, 3:k].T

    def update(
        self, z: np.ndarray, rng: np.random.Generator, ids: np.ndarray | None = None
    ) -> None:
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        if z.shape[0] == 0:
            return
        pairing = self._associate(z, ids)
        known = np.nonzero(pairing >= 0)[0]
        if known.size:
            self._update_known(z[known], pairing[known])
        new = np.nonzero(pairing == -1)[0]
        known_ids = ids is not None and isinstance(self.association, KnownAssociation)
        for j in new:
            self._add(z[j], int(ids[j]) if known_ids else None)  # type: ignore[index]

    # ------------------------------------------------------------------ pieces
    def _h_blocks(self, lm_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted measurements ``(L, 2)`` and Jacobians ``hx (L, 2, 3)``, ``hm (L, 2, 2)``."""
        mu = self.xs[3 + 2 * lm_idx[:, None] + np.arange(2)]
        xv = self.xs[:3]
        zhat = self.obs.h(xv, mu)
        hx, hm = self.obs.jacobians(xv, mu)
        return zhat, hx, hm

    def _dense_h(self, lm_idx: np.ndarray, hx: np.ndarray, hm: np.ndarray) -> np.ndarray:
        k = 3 + 2 * self.n_lm
        h = np.zeros((len(lm_idx), 2, k))
        h[:, :, :3] = hx
        cols = 3 + 2 * lm_idx
        rows = np.arange(len(lm_idx))
        h[rows, :, cols] = hm[:, :, 0]
        h[rows, :, cols + 1] = hm[:, :, 1]
        return h

    def _associate(self, z: np.ndarray, ids: np.ndarray | None) -> np.ndarray:
        a = self.association
        m = z.shape[0]
        if isinstance(a, KnownAssociation):
            if ids is None:
                raise ValueError("known association needs the observation ids")
            return np.array([self._id_index.get(int(i), -1) for i in ids], dtype=np.int64)
        if self.n_lm == 0:
            return np.full(m, -1, dtype=np.int64)
        lm = np.arange(self.n_lm)
        zhat, hx, hm = self._h_blocks(lm)
        h = self._dense_h(lm, hx, hm).reshape(2 * self.n_lm, -1)
        k = h.shape[1]
        hph = (h @ self.p[:k, :k] @ h.T).reshape(self.n_lm, 2, self.n_lm, 2)
        idx = np.arange(self.n_lm)
        s = hph[idx, :, idx, :] + np.diag(self.rdiag)  # (L, 2, 2)
        v = self.obs.residual(z[:, None, :], zhat[None])  # (m, L, 2)
        d = quad2(v, inv2(s)[None])  # (m, L)
        best = d.min(axis=1)
        if isinstance(a, JCBB):
            pairing, _ = jcbb(v, hph, np.diag(self.rdiag), d < a.gate_accept, a.joint_prob)
            gate_new = a.gate_new
        elif isinstance(a, NearestNeighbour):
            j = d.argmin(axis=1)
            pairing = np.where(best < a.gate_accept, j, -2)
            gate_new = a.gate_new
            # exclusive: the closest observation keeps a contested landmark
            for lmk in np.unique(pairing[pairing >= 0]):
                claim = np.nonzero(pairing == lmk)[0]
                if claim.size > 1:
                    keep = claim[np.argmin(best[claim])]
                    pairing[claim[claim != keep]] = -2
        else:
            raise TypeError(f"{type(a).__name__} association is not supported by EKF-SLAM")
        unpaired = pairing < 0
        return np.where(unpaired, np.where(best > gate_new, -1, -2), pairing)

    def _update_known(self, z: np.ndarray, lm_idx: np.ndarray) -> None:
        m = len(lm_idx)
        k = 3 + 2 * self.n_lm
        zhat, hx, hm = self._h_blocks(lm_idx)
        v = self.obs.residual(z, zhat)  # (m, 2)
        h = self._dense_h(lm_idx, hx, hm).reshape(2 * m, k)
        p = self.p[:k, :k]
        hph = h @ p @ h.T
        self._k += 1
        if self.adaptive in ("sage-husa", "combined"):
            self._sage_husa(v, hph)
        if self.adaptive in ("strong-tracking", "combined"):
            # Zhou's N_k and M_k on A = P^- - Q_acc (module docstring)
            hx_d = h[:, :3]
            hqh = hx_d @ self._qacc @ hx_d.T
            lam = self._fading(v, hph - hqh, hqh)
            self.last_lambda = lam
            if lam > 1.0:  # P^- = T A T^T + Q_acc on the vehicle rows (module docstring)
                p[:3, :3] -= self._qacc
                t = observed_fading(p[:3, :3], hx_d, lam)
                p[:3, :] = t @ p[:3, :]
                p[:, :3] = p[:, :3] @ t.T
                p[:3, :3] += self._qacc
                hph = h @ p @ h.T
        self._qacc[:] = 0.0
        s = hph + np.kron(np.eye(m), np.diag(self.rdiag))
        pht = p @ h.T
        kg = np.linalg.solve(s, pht.T).T
        self.xs[:k] += kg @ v.reshape(-1)
        self.xs[2] = wrap_angle(self.xs[2])
        pn = p - kg @ s @ kg.T
        self.p[:k, :k] = 0.5 * (pn + pn.T)

    def _sage_husa(self, v: np.ndarray, hph: np.ndarray) -> None:
        d = sage_husa_gain(self._k, self.sh_b)
        diag = np.diagonal(hph).reshape(-1, 2)
        self.rdiag = sage_husa_step(self.rdiag, v, diag, d, self.sh_floor * np.diag(self.r0))

    def _fading(self, v: np.ndarray, hah: np.ndarray, hqh: np.ndarray) -> float:
        a = innovation_power(v, self._w)
        self._v_st = a if self._v_st is None else (self.st_rho * self._v_st + a) / (1 + self.st_rho)
        return fading_factor(
            self._v_st,
            np.diagonal(hah).reshape(-1, 2),
            np.diagonal(hqh).reshape(-1, 2),
            self.rdiag,
            self._w,
            self.st_beta,
        )

    def _add(self, z: np.ndarray, fid: int | None) -> None:
        k = 3 + 2 * self.n_lm
        if k + 2 > self.xs.shape[0]:
            n = 3 + 2 * (2 * self.n_lm)
            xs = np.zeros(n)
            xs[:k] = self.xs[:k]
            p = np.zeros((n, n))
            p[:k, :k] = self.p[:k, :k]
            self.xs, self.p = xs, p
        xv = self.xs[:3]
        m = self.obs.inverse(xv, z)
        gz = self.obs.inverse_jacobian(xv, z)
        eps = 1e-6
        gx = np.empty((2, 3))
        for c in range(3):  # the inverse model's pose Jacobian by central differences
            dx = np.zeros(3)
            dx[c] = eps
            gx[:, c] = (self.obs.inverse(xv + dx, z) - self.obs.inverse(xv - dx, z)) / (2 * eps)
        p = self.p
        self.xs[k : k + 2] = m
        p[k : k + 2, k : k + 2] = gx @ p[:3, :3] @ gx.T + gz @ np.diag(self.rdiag) @ gz.T
        p[k : k + 2, :k] = gx @ p[:3, :k]
        p[:k, k : k + 2] = p[k : k + 2, :k].T
        self._id_index[fid if fid is not None else -1 - self.n_lm] = self.n_lm
        self.ids.append(fid if fid is not None else -1)
        self.n_lm += 1
