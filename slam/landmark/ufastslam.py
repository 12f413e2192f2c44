"""Unscented FastSLAM (Kim, Sakthivel and Chung 2008), as described in section 3 of the VB paper.

* Pose prediction: the unscented transform over the augmented state ``[x; n_u]`` with covariance
  ``blockdiag(P, Q)`` (eqs. 5-12), once per motion step.
* Pose proposal (UPF): sigma points of the predicted pose ``N(x, P)`` are passed through the
  observation model of every known feature seen in the scan (eqs. 22-25); the stacked measurement
  is fused in one update (eqs. 26-29). Unlike eq. (26), the innovation covariance also carries the
  feature uncertainty ``S_f`` (computed with the feature sigma points at the pose mean), as in Kim
  et al. and FastSLAM 2.0 - without it new, uncertain features would over-correct the pose. The
  eqs. (22)-(24) reuse the predicted augmented sigma points; here the predict runs once per
  motion step and a scan comes every few steps, so the proposal draws fresh sigma points of the
  accumulated ``N(x, P)``. After sampling, ``P`` is reset (the particle's pose is a point).
* Features: UKF update at the sampled pose (eqs. 37-45) and unscented initialisation through the
  inverse observation model (eqs. 33-36).

Sigma-point scaling (VB paper): pose ``alpha = 0.002``, features ``alpha = 0.001``; ``beta = 2``,
``kappa = 0``.
"""

from __future__ import annotations

import numpy as np

from auvgw.slam.landmark.fastslam import FastSLAM2, ProposalTerms
from auvgw.slam.landmark.unscented import UTParams, sigma_points, sqrt_psd, ut_cross, ut_moments
from auvgw.slam.models import wrap_angle

__all__ = ["UFastSLAM"]

POSE_UT = UTParams(alpha=0.002, beta=2.0, kappa=0.0)
FEATURE_UT = UTParams(alpha=0.001, beta=2.0, kappa=0.0)
_POSE_ANGULAR = (False, False, True)


class UFastSLAM(FastSLAM2):
    """Unscented FastSLAM: UPF pose proposal, UKF features."""

    name = "ufastslam"

    def __init__(
        self,
        *args: object,
        pose_ut: UTParams = POSE_UT,
        feature_ut: UTParams = FEATURE_UT,
        **kwargs: object,
    ) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.pose_ut = pose_ut
        self.feature_ut = feature_ut
        nu = self.motion.n_u
        na = 3 + nu
        _, _, c = pose_ut.weights(na)
        lq = self._lq * np.sqrt(c)
        # control-noise part of the augmented sigma points (the same for every particle)
        self._aug_noise = np.zeros((2 * na + 1, nu))
        self._aug_noise[4 : 4 + nu] = lq.T
        self._aug_noise[4 + na : 4 + na + nu] = -lq.T
        self._aug_c = c

    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        """Eqs. (5)-(12): augmented unscented prediction of each particle's pose Gaussian."""
        assert self.pcov is not None
        nu = self.motion.n_u
        na = 3 + nu
        lp = np.swapaxes(sqrt_psd(self.pcov) * np.sqrt(self._aug_c), -1, -2)  # rows = columns
        off = np.zeros((self.n, 2 * na + 1, 3))
        off[:, 1:4] = lp
        off[:, 1 + na : 4 + na] = -lp
        chi = self.x[:, None, :] + off
        # headings are not wrapped here: the sigma points stay continuous around the central
        # one, so the deviations need no wrapping either; the mean is wrapped at the end
        y = self.motion.f(chi, np.asarray(u, dtype=float) + self._aug_noise, dt, wrap=False)
        mean, cov, _, _ = ut_moments(y, self.pose_ut)
        mean[:, 2] = wrap_angle(mean[:, 2])
        self.x = mean
        self.pcov = cov

    def _proposal_terms(
        self, mu: np.ndarray, cov: np.ndarray, z: np.ndarray, known: np.ndarray
    ) -> ProposalTerms:
        """Eqs. (22)-(25) for all observations at once. With the sigma-point deviations
        ``e_j`` (measurements) and ``a_j`` (pose) from the central point and
        ``d = w sum_j e_j``: ``S_x = w sum_j e_j e_j^T + c0 d d^T = U U^T`` with
        ``U = [sqrt(w) e_j, sqrt(c0) d]`` and ``P_xz = A U^T`` with ``A = [sqrt(w) a_j, 0]``
        (``c0 = beta - alpha^2``, see :mod:`~auvgw.slam.landmark.unscented`)."""
        assert self.pcov is not None
        n, m = known.shape
        chi = sigma_points(self.x, self.pcov, self.pose_ut)  # (N, 7, 3)
        zs = self.obs.h(chi[:, :, None, :], mu[:, None, :, :])  # (N, 7, m, 2)
        zhat, _, e, delta = ut_moments(np.moveaxis(zs, 1, 2), self.pose_ut, self.obs.angular)
        k = known[..., None]
        e = np.where(k[:, :, None, :], e, 0.0)  # (N, m, 6, 2)
        delta = np.where(k, delta, 0.0)
        wm, wc, _ = self.pose_ut.weights(3)
        sw, sc = np.sqrt(wm[1]), np.sqrt(max(wc.sum() - 2.0, 0.0))
        u = np.concatenate(
            [sw * np.moveaxis(e, 2, 3).reshape(n, 2 * m, 6), sc * delta.reshape(n, 2 * m, 1)],
            axis=-1,
        )
        a = np.concatenate(
            [sw * np.swapaxes(chi[:, 1:] - chi[:, :1], -1, -2), np.zeros((n, 3, 1))], axis=-1
        )
        v = np.where(k, self.obs.residual(z[None], zhat), 0.0)
        chi_m = sigma_points(mu, cov, self.feature_ut)  # (N, m, 5, 2)
        zm = self.obs.h(self.x[:, None, None, :], chi_m)
        _, sf, _, _ = ut_moments(zm, self.feature_ut, self.obs.angular)
        return ProposalTerms(v, u, a, sf)

    def _feature_terms(
        self, x: np.ndarray, mu: np.ndarray, cov: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eqs. (37)-(41): UKF terms of each landmark at the sampled pose."""
        chi_m = sigma_points(mu, cov, self.feature_ut)  # (N, m, 5, 2)
        zm = self.obs.h(x[:, None, None, :], chi_m)
        zhat, sf, e, delta = ut_moments(zm, self.feature_ut, self.obs.angular)
        a = chi_m[..., 1:, :] - chi_m[..., :1, :]
        pmz = ut_cross(a, np.zeros_like(delta), e, delta, self.feature_ut)
        return self.obs.residual(z[None], zhat), sf, pmz

    def _init_features(
        self, ri: np.ndarray, z: np.ndarray, r: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (33)-(36): unscented transform of ``N(z, R)`` through the inverse model."""
        gam = sigma_points(z, r, self.feature_ut)  # (M, 5, 2)
        y = self.obs.inverse(self.x[ri][:, None, :], gam)
        mean, cov, _, _ = ut_moments(y, self.feature_ut, self.obs.feature_angular)
        return mean, cov
