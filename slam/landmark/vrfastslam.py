"""VRFastSLAM (Cui et al. 2020): FastSLAM 2.0 whose resampling is replaced by variance reduction
of the weights with a simulated-annealing fading exponent.

When ``Neff < threshold`` (eq. 8; the paper: ``0.5 M``) the normalised weights ``w0`` are raised
to ``alpha_k = lambda / log2(k + k0)`` for ``k = 1, 2, ...`` (eq. 16, ``lambda = 0.8``,
``k0 = 1``) and renormalised, until ``Neff`` reaches the threshold. By the paper's theorem 1
(eq. 10) ``Neff(w^alpha)`` grows monotonically as ``alpha`` falls, and ``alpha_k -> 0`` gives
uniform weights, so the loop ends. Particles are never duplicated or discarded. Working in log
weights, ``w^alpha`` is ``alpha log w``.
"""

from __future__ import annotations

import math

import numpy as np

from auvgw.slam.landmark.fastslam import FastSLAM2

__all__ = ["VRFastSLAM", "neff_of", "variance_reduction"]


def neff_of(logw: np.ndarray) -> float:
    """Effective sample size (eq. 8) of log weights."""
    w = np.exp(logw - logw.max())
    w /= w.sum()
    return float(1.0 / np.sum(w * w))


def variance_reduction(
    logw: np.ndarray,
    threshold: float,
    lam: float = 0.8,
    k0: float = 1.0,
    max_steps: int = 2**62,
) -> tuple[np.ndarray, float, int]:
    """Eqs. (15)-(16): the first annealing exponent ``alpha_k`` with ``Neff >= threshold``.

    Returns ``(normalised log weights, alpha, k)``; ``alpha = 1, k = 0`` when no reduction was
    needed. The schedule falls only logarithmically; should even ``alpha_max_steps`` not reach
    the threshold (a few particles with weights hundreds of nats apart), ``alpha`` is found by
    bisection below it and ``k = -1`` is returned."""
    lw0 = logw - logw.max()
    if neff_of(lw0) >= threshold:
        return lw0 - np.log(np.exp(lw0).sum()), 1.0, 0

    def alpha_of(k: int) -> float:
        return min(1.0, lam / math.log2(k + k0))

    def ok(k: int) -> bool:
        return neff_of(alpha_of(k) * lw0) >= threshold

    # alpha_k falls with k and Neff(w^alpha) rises as alpha falls (theorem 1), so the first k
    # of the step-by-step schedule that reaches the threshold is found by bisection.
    lo, hi = 1, 1
    while not ok(hi) and hi < max_steps:
        lo, hi = hi + 1, min(2 * hi, max_steps)
    while lo < hi:
        mid = (lo + hi) // 2
        if ok(mid):
            hi = mid
        else:
            lo = mid + 1
    alpha = alpha_of(hi)
    if not ok(hi):
        lo_a, hi_a = 0.0, alpha
        for _ in range(60):
            mid_a = 0.5 * (lo_a + hi_a)
            if neff_of(mid_a * lw0) >= threshold:
                lo_a = mid_a
            else:
                hi_a = mid_a
        alpha, hi = lo_a, -1
    lw = alpha * lw0
    return lw - np.log(np.exp(lw).sum()), alpha, hi


class VRFastSLAM(FastSLAM2):
    """FastSLAM 2.0 with simulated-annealing variance reduction instead of resampling."""

    name = "vrfastslam"

    def __init__(
        self,
        *args: object,
        vr_threshold: float = 0.5,
        vr_lambda: float = 0.8,
        vr_k0: float = 1.0,
        **kwargs: object,
    ) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.vr_threshold = float(vr_threshold)
        self.vr_lambda = float(vr_lambda)
        self.vr_k0 = float(vr_k0)
        self.last_alpha = 1.0
        self.reduction_count = 0

    def _reduce_degeneracy(self, w: np.ndarray, rng: np.random.Generator) -> None:
        thr = self.vr_threshold * self.n
        if self._neff >= thr:
            return
        self.logw, self.last_alpha, _ = variance_reduction(
            self.logw, thr, self.vr_lambda, self.vr_k0
        )
        self.reduction_count += 1
