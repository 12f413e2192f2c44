"""Scaled unscented transform (van der Merwe), batched over leading dimensions.

Sigma points follow eq. (7) of the VB paper (and filterpy's ``MerweScaledSigmaPoints``): point 0
is the mean, points ``1..n`` add the columns of ``sqrt((n + lambda) P)`` and ``n+1..2n`` subtract
them, ``lambda = alpha^2 (n + kappa) - n``; weights are eq. (9).

The VB paper's tiny ``alpha`` (0.002 for the pose, 0.001 for features) gives a centre weight near
``-1e6``; the moments are therefore computed relative to the central point, which is
algebraically identical to eqs. (11)-(12) but free of cancellation:
``mean = Y0 + d``, ``cov = w sum_j e_j e_j^T + (sum(wc) - 2) d d^T`` with ``e_j = Y_j - Y0`` and
``d = w sum_j e_j`` (``w`` the common weight of the non-central points).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from auvgw.slam.models import wrap_angle

__all__ = ["UTParams", "sigma_points", "sqrt_psd", "ut_cross", "ut_moments"]


@dataclass(frozen=True)
class UTParams:
    """Scaling parameters; defaults are the VB paper's pose values (alpha 0.002, beta 2,
    kappa 0)."""

    alpha: float = 0.002
    beta: float = 2.0
    kappa: float = 0.0

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        """``(wm, wc, n + lambda)`` for an ``n``-dimensional state (eq. 9)."""
        return _weights(self, n)


@lru_cache(maxsize=64)
def _weights(p: UTParams, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    lam = p.alpha**2 * (n + p.kappa) - n
    c = n + lam
    wm = np.full(2 * n + 1, 0.5 / c)
    wc = wm.copy()
    wm[0] = lam / c
    wc[0] = lam / c + (1.0 - p.alpha**2 + p.beta)
    wm.setflags(write=False)
    wc.setflags(write=False)
    return wm, wc, c


def _safe_sqrt(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(a, 0.0))


def _safe_div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a / np.where(b > 1e-150, b, np.inf)


def _chol_small(p: np.ndarray) -> np.ndarray:
    """Closed-form batched Cholesky of symmetric positive semi-definite 2x2 or 3x3 matrices;
    a zero (or round-off negative) pivot gives a zero column instead of an error."""
    n = p.shape[-1]
    out = np.zeros(p.shape)
    l11 = _safe_sqrt(p[..., 0, 0])
    l21 = _safe_div(p[..., 1, 0], l11)
    l22 = _safe_sqrt(p[..., 1, 1] - l21 * l21)
    out[..., 0, 0], out[..., 1, 0], out[..., 1, 1] = l11, l21, l22
    if n == 3:
        l31 = _safe_div(p[..., 2, 0], l11)
        l32 = _safe_div(p[..., 2, 1] - l31 * l21, l22)
        out[..., 2, 0], out[..., 2, 1] = l31, l32
        out[..., 2, 2] = _safe_sqrt(p[..., 2, 2] - l31 * l31 - l32 * l32)
    return out


def sqrt_psd(p: np.ndarray, jitter: float = 1e-12) -> np.ndarray:
    """A batched matrix square root ``A`` with ``A A^T = P`` (Cholesky, lower triangular).

    2x2 and 3x3 matrices (poses, features) use a closed form that tolerates semi-definite input
    (a freshly sampled particle pose has ``P = 0``). Larger ones are symmetrised and given a tiny
    relative diagonal jitter (``jitter`` times the mean variance, plus 1e-30); if Cholesky still
    fails the symmetric eigen-square-root with clipped eigenvalues is used."""
    n = p.shape[-1]
    if n in (2, 3):
        return _chol_small(p)
    ps = 0.5 * (p + np.swapaxes(p, -1, -2))
    scale = np.trace(ps, axis1=-2, axis2=-1)[..., None, None] / n
    ps = ps + (jitter * np.abs(scale) + 1e-30) * np.eye(n)
    try:
        return np.linalg.cholesky(ps)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(ps)
        return v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def sigma_points(mean: np.ndarray, cov: np.ndarray, params: UTParams) -> np.ndarray:
    """``(..., 2n+1, n)`` sigma points of ``N(mean (..., n), cov (..., n, n))`` (eq. 7)."""
    n = mean.shape[-1]
    _, _, c = params.weights(n)
    a = sqrt_psd(cov) * np.sqrt(c)  # columns are the offsets
    cols = np.swapaxes(a, -1, -2)  # (..., n, n): row j = column j of sqrt((n+lambda) P)
    m = mean[..., None, :]
    return np.concatenate([m, m + cols, m - cols], axis=-2)


def _deviations(y: np.ndarray, angular: tuple[bool, ...] | None) -> np.ndarray:
    e = y[..., 1:, :] - y[..., :1, :]
    if angular is not None:
        for i, ang in enumerate(angular):
            if ang:
                e[..., i] = wrap_angle(e[..., i])
    return e


def ut_moments(
    y: np.ndarray,
    params: UTParams,
    angular: tuple[bool, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean and covariance of transformed sigma points ``y (..., 2n+1, d)`` (eqs. 11-12).

    Returns ``(mean (..., d), cov (..., d, d), e (..., 2n, d), delta (..., d))`` where ``e`` are
    the deviations from the central point and ``delta = mean - y0``; pass them to
    :func:`ut_cross`. Components flagged in ``angular`` are wrapped."""
    n = (y.shape[-2] - 1) // 2
    wm, wc, _ = params.weights(n)
    w = wm[1]
    e = _deviations(y, angular)
    delta = w * e.sum(axis=-2)
    mean = y[..., 0, :] + delta
    if angular is not None:
        for i, ang in enumerate(angular):
            if ang:
                mean[..., i] = wrap_angle(mean[..., i])
    c0 = wc.sum() - 2.0
    cov = w * (np.swapaxes(e, -1, -2) @ e) + c0 * delta[..., :, None] * delta[..., None, :]
    return mean, cov, e, delta


def ut_cross(
    ex: np.ndarray, dx: np.ndarray, ey: np.ndarray, dy: np.ndarray, params: UTParams
) -> np.ndarray:
    """Cross-covariance ``(..., nx, ny)`` of two sets of sigma-point deviations from
    :func:`ut_moments` (eq. 24)."""
    n = ex.shape[-2] // 2
    wm, wc, _ = params.weights(n)
    c0 = wc.sum() - 2.0
    return wm[1] * (np.swapaxes(ex, -1, -2) @ ey) + c0 * dx[..., :, None] * dy[..., None, :]
