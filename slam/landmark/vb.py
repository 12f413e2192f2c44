"""VB-AFastSLAM and VB-AUFastSLAM (Mu et al. 2022): FastSLAM with variational-Bayes estimation
of the observation noise, per particle.

Each particle carries an inverse-Gamma posterior per measurement component (range, bearing):
shape ``eta (N, 2)`` and scale ``xi (N, 2)`` (eq. 13); the noise estimate is
``R = diag(xi / eta)`` (eq. 19, ``<sigma^-2>^-1`` under the posterior). At every scan:

1. forgetting (eqs. 20-21): ``eta <- rho eta``, ``xi <- rho xi``;
2. pose stage (eqs. 22-32): the proposal update is iterated with the noise estimate; after each
   pass ``xi = xi_prior + 1/2 sum_j E[(z_j - h_j)^2]`` over the known observations ``j`` and
   ``eta = eta_prior + m/2``;
3. feature stage (eqs. 37-45): starting from the pose stage's noise (eq. 30), the feature
   updates are iterated the same way (fewer passes), then applied with the final ``R``; the
   particle keeps that posterior (``eta``, ``xi``) for the next scan;
4. weights from the innovation covariance with the estimated ``R`` (eqs. 46-47).

Choices where the paper is inconsistent or garbled, following Sarkka and Nummenmaa (2009),
"Recursive noise adaptive Kalman filtering by variational Bayesian approximations":

* Initial values. Table 2 gives ``eta = 50, xi = 5`` while the text states ``R0 = diag(0.001,
  0.001)``; eq. (19) would start the filter at ``xi / eta = 0.1``. Sarkka-Nummenmaa choose the
  initial parameters so that ``xi0 / eta0`` is the prior guess of the variance, so by default
  ``eta0 = 50`` (the paper's value, which is also the steady state ``0.5 / (1 - rho)`` of one
  observation per step with ``rho = 0.99``) and ``xi0 = eta0 * diag(R0)``. An explicit ``xi0``
  reproduces eq. (19) literally (the paper's Table 6 experiments).
* Eq. (32) adds ``(z - z_pred)^2 + diag(S/2)`` with the prior prediction; Sarkka-Nummenmaa add
  ``1/2 E[(z - h(x))^2]`` under the current posterior, i.e.
  ``1/2 [(z - h(x_post))^2 + diag(H P_post H^T)]``. We use the latter; the expectation is the
  statistical linearisation of the stage's (unscented or Jacobian) terms:
  ``r = v - S Pzz^-1 v`` and ``C = S - S Pzz^-1 S`` with ``S`` the state part of the innovation
  covariance (pose and feature uncertainty), ``E = r^2 + diag(C)``.
* All observations of one scan share the particle's two variances (the Sarkka-Nummenmaa update
  with tied components): ``eta`` grows by ``m/2`` per scan of ``m`` known observations. The
  per-observation noise of eq. (30) is then the same for every observation of the scan.
* The forgetting is applied once per scan (the filter's "time step" for the noise).
* Eq. (47) is dimensionally inconsistent as printed; the weight is the FastSLAM 2.0 / UFastSLAM
  marginal likelihood ``N(v; 0, S_x + S_f + R)`` with the estimated ``R`` (eq. 46).
* A floor ``R >= floor * R0`` keeps the estimate positive definite when residuals vanish.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from auvgw.slam.landmark.base import LOG_2PI, inv2
from auvgw.slam.landmark.fastslam import FastSLAM2, LowRank, ProposalTerms
from auvgw.slam.landmark.ufastslam import UFastSLAM

__all__ = ["VBAFastSLAM", "VBAUFastSLAM", "VBSettings", "vb_noise_step"]


@dataclass(frozen=True)
class VBSettings:
    """Hyper-parameters of the VB noise estimate (VB paper Table 2 and section 3)."""

    rho: float = 0.99
    eta0: float = 50.0
    #: initial scale per component; ``None``: ``eta0 * diag(R0)`` (start at R0)
    xi0: tuple[float, float] | None = None
    pose_iterations: int = 3
    feature_iterations: int = 2
    floor: float = 1e-3
    #: weigh particles with the noise known before the scan (see the module docstring)
    predictive_weights: bool = True


def _diag2(d: np.ndarray) -> np.ndarray:
    """``(..., 2)`` -> ``(..., 2, 2)`` diagonal matrices."""
    out = np.zeros((*d.shape, 2))
    out[..., 0, 0] = d[..., 0]
    out[..., 1, 1] = d[..., 1]
    return out


def vb_noise_step(s: np.ndarray, v: np.ndarray, rdiag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Sarkka-Nummenmaa expectation for a linear(ised) Gaussian update.

    ``s (..., d, d)`` state part of the innovation covariance (``H P H^T``), ``v (..., d)``
    innovation, ``rdiag (..., d)`` current noise variances. Returns ``(E, Pzz)``:
    ``E = (z - H m_post)^2 + diag(H P_post H^T)`` per component and ``Pzz = S + R``.
    With ``Pzz = S + R``: ``z - H m_post = R Pzz^-1 v`` and
    ``H P_post H^T = S - S Pzz^-1 S = R - R Pzz^-1 R``."""
    pzz = s + rdiag[..., :, None] * np.eye(s.shape[-1])
    pinv = np.linalg.inv(pzz)
    return _expectation(rdiag, np.einsum("...ij,...j->...i", pinv, v), _diagonal(pinv)), pzz


def _diagonal(a: np.ndarray) -> np.ndarray:
    return np.diagonal(a, axis1=-2, axis2=-1)


def _expectation(rdiag: np.ndarray, pinv_v: np.ndarray, pinv_diag: np.ndarray) -> np.ndarray:
    """``E[(z - h(x))^2]`` under the posterior from ``R``, ``Pzz^-1 v``, ``diag(Pzz^-1)``."""
    r = rdiag * pinv_v
    return r * r + rdiag - rdiag * rdiag * pinv_diag


class _VBNoise:
    """Mixin: per-particle inverse-Gamma observation-noise posteriors for a FastSLAM 2.0-type
    filter (see the module docstring)."""

    n: int
    r: np.ndarray
    x: np.ndarray
    pcov: np.ndarray | None

    def _vb_init(self, settings: VBSettings | None) -> None:
        self.vb = settings or VBSettings()
        r0 = np.diag(self.r)
        xi0 = np.asarray(self.vb.xi0, dtype=float) if self.vb.xi0 else self.vb.eta0 * r0
        self.eta = np.full((self.n, 2), self.vb.eta0)
        self.xi = np.tile(xi0, (self.n, 1))
        self._rfloor = self.vb.floor * r0
        self._eta_post = self.eta
        self._xi_prior = self.xi
        self._xi_stage = self.xi

    def noise_estimate(self) -> np.ndarray:
        """Current noise variances ``(N, 2)`` of every particle (eq. 19)."""
        return np.maximum(self.xi / self.eta, self._rfloor)

    def _rdiag(self, xi: np.ndarray) -> np.ndarray:
        return np.maximum(xi / self._eta_post, self._rfloor)

    def _noise_predict(self) -> None:
        """Eqs. (20)-(21)."""
        self.eta = self.vb.rho * self.eta
        self.xi = self.vb.rho * self.xi
        self._eta_post = self.eta
        self._xi_prior = self.xi
        self._xi_stage = self.xi

    def _new_feature_noise(self) -> np.ndarray:
        return _diag2(self.noise_estimate())

    def _resample_extra(self, idx: np.ndarray) -> None:
        self.eta = self.eta[idx]
        self.xi = self.xi[idx]

    # -------------------------------------------------------------- pose stage (eqs. 22-32)
    def _pose_update(
        self, terms: ProposalTerms, known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, m = known.shape
        k4 = known[..., None, None]
        self._eta_post = self._eta_prior_plus(known)
        mask = np.repeat(known, 2, axis=1).astype(float)  # (N, 2m)
        xi = self._xi_prior
        for _ in range(self.vb.pose_iterations):
            rd = self._rdiag(xi)
            lr = LowRank(terms.u, np.where(k4, terms.sf + _diag2(rd)[:, None], np.eye(2)), terms.v)
            rvec = np.tile(rd, (1, m)) * mask
            e = _expectation(rvec, lr.pzz_inv_v(), lr.pzz_inv_diag())
            xi = self._xi_prior + 0.5 * e.reshape(n, m, 2).sum(axis=1)
        self._xi_stage = xi
        blocks = np.where(k4, terms.sf + _diag2(self._rdiag(xi))[:, None], np.eye(2))
        mean, cov, ll_post = self._joint_update(terms, blocks, known)  # type: ignore[attr-defined]
        if not self.vb.predictive_weights:
            return mean, cov, ll_post
        # importance weight: the predictive likelihood of the scan under the noise known before
        # it (prior R = xi-/eta-); weighing with the posterior R would let every particle
        # explain its own residuals away and flatten the weights
        r_prior = np.maximum(self._xi_prior / self.eta, self._rfloor)
        lr = LowRank(terms.u, np.where(k4, terms.sf + _diag2(r_prior)[:, None], np.eye(2)), terms.v)
        ll = -0.5 * lr.quad() - 0.5 * lr.logdet() - LOG_2PI * known.sum(axis=1)
        return mean, cov, ll

    def _eta_prior_plus(self, known: np.ndarray) -> np.ndarray:
        """Eq. (31) with tied components: ``eta = eta_prior + m/2``."""
        return self.eta + 0.5 * known.sum(axis=1)[:, None]

    # -------------------------------------------------------------- feature stage (eqs. 37-45)
    def _feature_update(
        self, mu: np.ndarray, cov: np.ndarray, z: np.ndarray, known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        v, sf, pmz = self._feature_terms(self.x, mu, cov, z)  # type: ignore[attr-defined]
        k = known[..., None]
        xi = self._xi_stage
        for _ in range(self.vb.feature_iterations):
            rd = np.broadcast_to(self._rdiag(xi)[:, None, :], v.shape)
            pinv = inv2(sf + _diag2(rd))
            e = _expectation(rd, np.einsum("...ij,...j->...i", pinv, v), _diagonal(pinv))
            xi = self._xi_prior + 0.5 * np.where(k, e, 0.0).sum(axis=1)
        self.eta = self._eta_post
        self.xi = xi
        rmat = _diag2(self._rdiag(xi))[:, None]
        return self._feature_apply(mu, cov, v, sf, pmz, rmat)  # type: ignore[attr-defined]


class VBAFastSLAM(_VBNoise, FastSLAM2):
    """VB-AFastSLAM: FastSLAM 2.0 (EKF proposal and features) with VB noise estimation."""

    name = "vb-afastslam"

    def __init__(self, *args: object, vb: VBSettings | None = None, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._vb_init(vb)


class VBAUFastSLAM(_VBNoise, UFastSLAM):
    """VB-AUFastSLAM: Unscented FastSLAM (UPF proposal, UKF features) with VB noise estimation."""

    name = "vb-aufastslam"

    def __init__(self, *args: object, vb: VBSettings | None = None, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._vb_init(vb)
