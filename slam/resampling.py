"""One home for particle resampling, shared by every particle filter of ``slam/`` (landmark
FastSLAM family, bathymetric SLAM)."""

from __future__ import annotations

import numpy as np

__all__ = ["systematic_resample"]


def systematic_resample(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by systematic (low-variance) resampling of normalised weights ``w (N,)``:
    one uniform draw ``u`` from ``rng``, then the particle whose cumulative weight first reaches
    ``(u + i) / N`` for ``i = 0 .. N-1`` (Thrun et al., Probabilistic Robotics, table 4.4; the
    bathymetric paper's A20). The last cumulative weight is set to 1 so rounding cannot leave
    a position past it."""
    n = w.shape[0]
    c = np.cumsum(w)
    c[-1] = 1.0
    return np.minimum(np.searchsorted(c, (rng.random() + np.arange(n)) / n), n - 1)
