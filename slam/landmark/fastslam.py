"""FastSLAM 1.0 and FastSLAM 2.0 (Montemerlo et al. 2002/2003), vectorised over particles.

FastSLAM 1.0 samples each particle's pose from the motion model (controls plus noise ``N(0, Q)``),
weighs it by the likelihood of the observed known features (``N(v; 0, H P H^T + R)``) and updates
each feature with an EKF. FastSLAM 2.0 (the VR paper's base, "EKF as the recommended
distribution") carries a Gaussian pose ``N(x, P)`` per particle through the motion steps; at a scan
it conditions that Gaussian on all observations of known features (one joint EKF update with the
stacked ``2m``-dimensional measurement, pose uncertainty correlated across observations), samples
the pose from the result, weighs the particle with ``N(v; 0, H_x P H_x^T + H_m Sigma H_m^T + R)``
(Montemerlo's FastSLAM 2.0 weight, eqs. 46-47 of the VB paper) and updates the features at the
sampled pose. New features are initialised by the inverse observation model (``G R G^T``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from auvgw.slam.landmark.base import LOG_2PI, ParticleFilterSLAM, det2, inv2, quad2
from auvgw.slam.landmark.unscented import sqrt_psd
from auvgw.slam.models import wrap_angle

__all__ = ["FastSLAM1", "FastSLAM2", "LowRank", "ProposalTerms"]


class FastSLAM1(ParticleFilterSLAM):
    """FastSLAM 1.0: motion-model proposal, EKF features, resampling when Neff is low."""

    name = "fastslam1"

    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        self.x = self.motion.f(self.x, self._sample_controls(np.asarray(u, dtype=float), rng), dt)

    def _observe(
        self, z: np.ndarray, slots: np.ndarray, ids: np.ndarray | None, rng: np.random.Generator
    ) -> None:
        known, s, mu, cov = self._gather(slots)
        if known.any():
            v, sf, pmz = self._feature_terms(self.x, mu, cov, z)
            pzz = sf + self.r
            ll = -0.5 * quad2(v, inv2(pzz)) - 0.5 * np.log(det2(pzz)) - LOG_2PI
            self.logw = self.logw + np.where(known, ll, 0.0).sum(axis=1)
            mu_n, cov_n = self._feature_apply(mu, cov, v, sf, pmz, self.r)
            self._scatter(known, s, mu_n, cov_n)
        self._add_features(z, slots, ids)


@dataclass(frozen=True)
class ProposalTerms:
    """Terms of the joint pose update for ``m`` observations of known features:
    innovation ``v (N, m, 2)`` (zero where not known), pose part of its covariance as the
    low-rank factor ``U (N, 2m, k)`` (``S_x = U U^T``), cross-covariance factor ``A (N, 3, k)``
    (``P_xz = A U^T``, ``P = A A^T``) and the feature parts ``S_f (N, m, 2, 2)``."""

    v: np.ndarray
    u: np.ndarray
    a: np.ndarray
    sf: np.ndarray


class LowRank:
    """``Pzz = B + U U^T`` with ``B`` block diagonal (2 x 2 blocks ``(N, m, 2, 2)``) and ``U``
    of small rank ``k`` (3 for the EKF, 7 for the UKF): inverse and determinant through the
    Woodbury identity and the matrix determinant lemma, so nothing larger than ``k x k`` is
    factorised. ``v (N, m, 2)`` is the innovation."""

    def __init__(self, u: np.ndarray, blocks: np.ndarray, v: np.ndarray) -> None:
        n, m = v.shape[:2]
        k = u.shape[-1]
        self.blocks = blocks
        self.binv = inv2(blocks)
        self.g = (self.binv @ u.reshape(n, m, 2, k)).reshape(n, 2 * m, k)  # B^-1 U
        self.bv = np.einsum("nmij,nmj->nmi", self.binv, v).reshape(n, 2 * m)  # B^-1 v
        self.vf = v.reshape(n, 2 * m)
        self.m = np.swapaxes(u, -1, -2) @ self.g  # U^T B^-1 U
        self.t = self.m + np.eye(k)  # I + U^T B^-1 U
        y = np.einsum("nik,ni->nk", u, self.bv)  # U^T B^-1 v
        self.y = y
        self.z = np.linalg.solve(self.t, y[..., None])[..., 0]  # U^T Pzz^-1 v

    def pzz_inv_v(self) -> np.ndarray:
        """``Pzz^-1 v (N, 2m)``."""
        return self.bv - np.einsum("nik,nk->ni", self.g, self.z)

    def pzz_inv_diag(self) -> np.ndarray:
        """``diag(Pzz^-1) (N, 2m)``."""
        n, m = self.binv.shape[:2]
        d = np.diagonal(self.binv, axis1=-2, axis2=-1).reshape(n, 2 * m)
        w = np.linalg.solve(self.t, np.swapaxes(self.g, -1, -2))  # T^-1 G^T
        return d - np.einsum("nik,nki->ni", self.g, w)

    def quad(self) -> np.ndarray:
        """``v^T Pzz^-1 v (N,)``."""
        return np.einsum("ni,ni->n", self.vf, self.bv) - np.einsum("nk,nk->n", self.y, self.z)

    def logdet(self) -> np.ndarray:
        """``log det Pzz (N,)``."""
        _, ld = np.linalg.slogdet(self.t)
        return np.log(det2(self.blocks)).sum(axis=1) + ld


class FastSLAM2(ParticleFilterSLAM):
    """FastSLAM 2.0: per-particle Gaussian pose, proposal conditioned on the scan (EKF)."""

    name = "fastslam2"
    has_pose_cov = True

    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        u = np.asarray(u, dtype=float)
        fx, fu = self.motion.jacobians(self.x, u, dt)
        self.x = self.motion.f(self.x, u, dt)
        assert self.pcov is not None
        self.pcov = fx @ self.pcov @ np.swapaxes(fx, -1, -2) + fu @ self.q @ np.swapaxes(fu, -1, -2)

    # ------------------------------------------------------------------ scan
    def _observe(
        self, z: np.ndarray, slots: np.ndarray, ids: np.ndarray | None, rng: np.random.Generator
    ) -> None:
        self._noise_predict()
        known, s, mu, cov = self._gather(slots)
        assert self.pcov is not None
        if known.any():
            terms = self._proposal_terms(mu, cov, z, known)
            xpost, ppost, ll = self._pose_update(terms, known)
            self.logw = self.logw + ll
        else:
            xpost, ppost = self.x, self.pcov
        noise = np.einsum("nij,nj->ni", sqrt_psd(ppost), rng.standard_normal((self.n, 3)))
        self.x = xpost + noise
        self.x[:, 2] = wrap_angle(self.x[:, 2])
        self.pcov = np.zeros_like(self.pcov)
        if known.any():
            mu_n, cov_n = self._feature_update(mu, cov, z, known)
            self._scatter(known, s, mu_n, cov_n)
        self._add_features(z, slots, ids, self._new_feature_noise())

    def _noise_predict(self) -> None:
        """Hook: time update of the noise statistics (VB filters)."""

    def _new_feature_noise(self) -> np.ndarray | None:
        """Observation noise used to initialise new features (per particle), ``None``: R0."""
        return None

    def _proposal_terms(
        self, mu: np.ndarray, cov: np.ndarray, z: np.ndarray, known: np.ndarray
    ) -> ProposalTerms:
        """Linearised terms of the joint pose update (EKF): ``U = H_x L``, ``A = L`` with
        ``L L^T = P`` (so ``S_x = U U^T``, ``P_xz = A U^T``)."""
        assert self.pcov is not None
        xb = self.x[:, None, :]
        zhat = self.obs.h(xb, mu)
        hx, hm = self.obs.jacobians(xb, mu)
        v = np.where(known[..., None], self.obs.residual(z[None], zhat), 0.0)
        hx = np.where(known[..., None, None], hx, 0.0)
        n, m = known.shape
        lp = sqrt_psd(self.pcov)
        u = hx.reshape(n, 2 * m, 3) @ lp
        sf = hm @ cov @ np.swapaxes(hm, -1, -2)
        return ProposalTerms(v, u, lp, sf)

    def _joint_update(
        self, t: ProposalTerms, blocks: np.ndarray, known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Condition each particle's pose Gaussian on the stacked observations, innovation
        covariance ``U U^T + blockdiag(blocks)``: returns ``(mean (N, 3), cov (N, 3, 3),
        log-likelihood (N,))`` (eqs. 26-29, 46)."""
        assert self.pcov is not None
        lr = LowRank(t.u, blocks, t.v)
        kv = np.einsum("nik,nk->ni", t.a, lr.z)
        mean = self.x + kv
        mean[:, 2] = wrap_angle(mean[:, 2])
        cov = self.pcov - t.a @ np.linalg.solve(lr.t, lr.m) @ np.swapaxes(t.a, -1, -2)
        ll = -0.5 * lr.quad() - 0.5 * lr.logdet() - LOG_2PI * known.sum(axis=1)
        return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2)), ll

    def _pose_update(
        self, terms: ProposalTerms, known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        blocks = np.where(known[..., None, None], terms.sf + self.r, np.eye(2))
        return self._joint_update(terms, blocks, known)

    def _feature_update(
        self, mu: np.ndarray, cov: np.ndarray, z: np.ndarray, known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        v, sf, pmz = self._feature_terms(self.x, mu, cov, z)
        return self._feature_apply(mu, cov, v, sf, pmz, self.r)

    def _association_pose(self) -> np.ndarray:
        return self.x
