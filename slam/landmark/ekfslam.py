"""EKF-SLAM and the adaptive variants the VR paper compares against (Cui et al. 2020, section 4).

One joint Gaussian over ``[x, y, heading, m1x, m1y, ...]`` (metres, radians). Variants:

* ``none`` - plain EKF-SLAM;
* ``sage-husa`` (SHEKF-SLAM) - the Sage-Husa noise statistics estimator with fading memory
  ``b``: ``R_k = (1 - d_k) R_{k-1} + d_k diag(v v^T - H P^- H^T)``, ``d_k = (1 - b) /
  (1 - b^(k+1))``, averaged over the scan's observations, per component (range, bearing),
  floored at ``floor * R0`` (the raw estimate can go negative). Applied to the observation noise
  ``R``, the quantity the sonar's noise changes;
* ``strong-tracking`` (STEKF-SLAM) - a suboptimal fading factor ``lambda_k = max(1, N_k / M_k)``
  (Zhou's strong tracking filter) with ``V_k = (rho V_{k-1} + a_k) / (1 + rho)``,
  ``a_k = mean_j v_j^T R0^-1 v_j``, ``N_k = V_k - beta tr(R0^-1 R)``,
  ``M_k = mean_j tr(R0^-1 H_j P^- H_j^T)``. The fading scales the vehicle block of the predicted
  covariance (``P <- D P D``, ``D = diag(sqrt(lambda) I3, I)``) - inflating the static map would
  discard map information - and is computed at each scan on the covariance accumulated since the
  last one;
* ``combined`` (CAEKF-SLAM) - Sage-Husa ``R`` first, then strong tracking with it.

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

__all__ = ["ADAPTIVE_MODES", "EKFSLAM"]

ADAPTIVE_MODES = ("none", "sage-husa", "strong-tracking", "combined")


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
        p[:3, :3] = fx @ p[:3, :3] @ fx.T + fu @ self.q @ fu.T
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
            lam = self._fading(v, hph)
            self.last_lambda = lam
            if lam > 1.0:
                dsc = np.ones(k)
                dsc[:3] = np.sqrt(lam)
                p *= dsc[:, None] * dsc[None, :]
                hph = h @ p @ h.T
        s = hph + np.kron(np.eye(m), np.diag(self.rdiag))
        pht = p @ h.T
        kg = np.linalg.solve(s, pht.T).T
        self.xs[:k] += kg @ v.reshape(-1)
        self.xs[2] = wrap_angle(self.xs[2])
        pn = p - kg @ s @ kg.T
        self.p[:k, :k] = 0.5 * (pn + pn.T)

    def _sage_husa(self, v: np.ndarray, hph: np.ndarray) -> None:
        d = (1.0 - self.sh_b) / (1.0 - self.sh_b ** (self._k + 1))
        diag = np.diagonal(hph).reshape(-1, 2)
        r_hat = (v * v - diag).mean(axis=0)
        r_hat = np.maximum(r_hat, self.sh_floor * np.diag(self.r0))
        self.rdiag = (1.0 - d) * self.rdiag + d * r_hat

    def _fading(self, v: np.ndarray, hph: np.ndarray) -> float:
        a = float(np.mean((v * v) @ self._w))
        self._v_st = a if self._v_st is None else (self.st_rho * self._v_st + a) / (1 + self.st_rho)
        n_k = self._v_st - self.st_beta * float(self._w @ self.rdiag)
        m_k = float(np.mean(np.diagonal(hph).reshape(-1, 2) @ self._w))
        if m_k <= 0:
            return 1.0
        return max(1.0, n_k / m_k)

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
