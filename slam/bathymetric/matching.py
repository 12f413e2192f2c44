"""Submap matching shared by the filters: IDW interpolation (A1), the MSE gate (eq. 6), the mean
of per-point Gaussian densities (eqs. 7-8) and the weight indexation exponent (eqs. 9-12).
Everything is batched: a row per particle, a column per Mmap point, with a validity mask."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from auvgw.slam.bathymetric.config import BathyConfig

__all__ = ["alpha_exponent", "idw", "match_weights"]


def idw(
    tree: cKDTree,
    values: np.ndarray,
    query: np.ndarray,
    k: int = 8,
    radius: float = 4.0,
    power: float = 2.0,
    min_neighbours: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Shepard IDW (A1): ``z(q) = sum d_k^-p z_k / sum d_k^-p`` over the ``k`` nearest samples
    of ``tree`` within ``radius`` of each row of ``query`` (..., D). Returns ``(z, valid)`` of
    shape ``query.shape[:-1]``; ``valid`` needs ``min_neighbours`` samples in range. A sample at
    zero distance returns its own value."""
    shape = query.shape[:-1]
    q = query.reshape(-1, query.shape[-1])
    k = min(k, tree.n)
    d, i = tree.query(q, k=k, distance_upper_bound=radius)
    d, i = d.reshape(len(q), k), i.reshape(len(q), k)
    ok = np.isfinite(d)
    n_ok = ok.sum(1)
    vals = np.where(ok, values[np.minimum(i, tree.n - 1)], 0.0)
    exact = ok & (d < 1e-9)
    w = np.where(ok, 1.0 / np.maximum(d, 1e-9) ** power, 0.0)
    w = np.where(exact.any(1, keepdims=True), exact.astype(float), w)
    sw = w.sum(1)
    z = np.where(sw > 0, (w * vals).sum(1) / np.where(sw > 0, sw, 1.0), np.nan)
    return z.reshape(shape), (n_ok >= min_neighbours).reshape(shape)


def _terrain_alpha(
    z: np.ndarray, valid: np.ndarray, n: np.ndarray, s2: float, m2: float
) -> np.ndarray:
    """Eqs. (11)-(12) per row: the exponent from the terrain information of depths ``z``."""
    zm = np.where(valid, z, 0.0)
    mean = zm.sum(1) / np.maximum(n, 1)
    var = (np.where(valid, (z - mean[:, None]) ** 2, 0.0)).sum(1) / np.maximum(n, 1)
    delta2 = np.maximum(var - m2, 0.0)  # eq. (12), clamped (A4)
    den = (s2 + m2) * (delta2 + m2) + s2 * m2
    return np.where(den > 0, (s2 + m2) * delta2 / np.where(den > 0, den, 1.0), 1.0)  # eq. (11)


def alpha_exponent(
    z_pmap: np.ndarray, z_mmap: np.ndarray, valid: np.ndarray, cfg: BathyConfig
) -> np.ndarray:
    """alpha = min(alpha_pmap, alpha_mmap), eqs. (10)-(12), one per row."""
    n = valid.sum(1)
    s2, m2 = cfg.sigma_s_m**2, cfg.sigma_map2
    a_p = _terrain_alpha(z_pmap, valid, n, s2, m2)
    a_m = _terrain_alpha(z_mmap, valid, n, s2, m2)
    return np.minimum(a_p, a_m)  # eq. (10)


def match_weights(
    z_pmap: np.ndarray,
    z_mmap: np.ndarray,
    valid: np.ndarray,
    n_mmap: np.ndarray,
    cfg: BathyConfig,
    use_alpha: bool | None = None,
    fallback: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row (particle): ``(weight, gated_in, mse)``. ``z_pmap`` is the IDW of the Pmap at the
    Mmap points, ``z_mmap`` their own depths, ``valid`` (rows, M) the points inside the Pmap
    coverage; ``n_mmap`` the Mmap size of each row; ``fallback`` the weight of an unmatched
    particle (1/N), towards which alpha flattens with ``alpha_towards='fallback'``. Rows
    failing the gates (I > I_min and mse < mse_max, eq. 6) get ``gated_in = False`` (the
    caller gives them 1/N)."""
    n = valid.sum(1)
    dz2 = np.where(valid, (z_pmap - z_mmap) ** 2, 0.0)
    mse = dz2.sum(1) / np.maximum(n, 1)  # eq. (6)
    ok = (n > cfg.min_valid_fraction * n_mmap) & (mse < cfg.mse_max_m2) & (n > 0)
    s2 = cfg.sigma_s_m**2
    dens = np.where(valid, np.exp(-dz2 / (2 * s2)) / math.sqrt(2 * math.pi * s2), 0.0)  # eq. (8)
    w = dens.sum(1) / np.maximum(n, 1)  # eq. (7)
    if cfg.use_alpha if use_alpha is None else use_alpha:
        a = alpha_exponent(z_pmap, z_mmap, valid, cfg)
        w = w**a  # eq. (9)
        if cfg.alpha_towards == "fallback" and fallback is not None:
            w = w * fallback ** (1.0 - a)  # alpha = 0 -> the no-match weight (ours, A5)
    return w, ok, mse
