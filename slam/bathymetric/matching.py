"""Submap matching shared by the filters: IDW interpolation (A1), the MSE gate (eq. 6), the mean
of per-point Gaussian densities (eqs. 7-8) and the weight indexation exponent (eqs. 9-12).
Everything is batched: a row per particle, a column per Mmap point, with a validity mask."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from auvgw.slam.bathymetric.config import BathyConfig

__all__ = ["alpha_exponent", "idw", "match_weights"]


def _near_rows(data: np.ndarray, q: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the rows of ``q`` (M, 2) that may have a sample of ``data`` (n, 2) within
    ``radius``, grouped by grid cell (neighbouring queries walk the same tree nodes: faster).
    A conservative test with square cells a hair wider than ``radius``: a sample within
    ``radius`` is always in the 3 x 3 cells around the row's cell. The rows left out have no
    sample in range (their IDW is (nan, False) without a query). Other dimensions (BPSLAM's
    particle label as a third coordinate): every row, in order."""
    if data.shape[1] != 2 or len(data) == 0:  # e.g. BPSLAM's (x, y, particle label)
        return np.arange(len(q))
    c = radius * 1.001  # margin against the rounding of coordinate / cell
    cx, cy = np.floor(data[:, 0] / c), np.floor(data[:, 1] / c)
    x0, y0 = cx.min() - 2, cy.min() - 2  # an outer ring of cells that stays empty
    nx, ny = int(cx.max() - x0) + 3, int(cy.max() - y0) + 3
    if nx * ny > 64 * len(data) + 4096:  # sparse samples: the grid would not pay
        return np.arange(len(q))
    occ = np.zeros(nx * ny, dtype=bool)
    flat = ((cx - x0) * ny + (cy - y0)).astype(np.intp)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            occ[flat + (dx * ny + dy)] = True
    # rows outside the grid (or not finite) land on the empty ring
    qx = np.nan_to_num(np.clip(np.floor(q[:, 0] / c) - x0, 0, nx - 1))
    qy = np.nan_to_num(np.clip(np.floor(q[:, 1] / c) - y0, 0, ny - 1))
    key = (qx * ny + qy).astype(np.intp)
    rows = np.flatnonzero(occ[key])
    key = key[rows]
    small = nx * ny <= 1 << 16  # radix sort of 16-bit keys: several times faster
    return rows[np.argsort(key.astype(np.uint16) if small else key, kind="stable")]


def _column_sums(a: np.ndarray) -> np.ndarray:
    """``a.T.sum(1)`` for ``a`` (k, m) C-contiguous, i.e. the sums over the k neighbours of m
    rows held column-wise, by whole-row adds in numpy's own order for a row of
    8 <= k <= 128 (eight running sums combined pairwise, then the tail): the same to the bit
    as numpy's row sums on the numpy this was checked with, and several times faster than a
    reduction over rows of eight (the IDW neighbours). Other k: numpy's row sums."""
    k = len(a)
    if not 8 <= k <= 128:
        return np.ascontiguousarray(a.T).sum(1)
    r = [a[j].copy() for j in range(8)]
    full = k - k % 8
    for i in range(8, full, 8):
        for j in range(8):
            r[j] += a[i + j]
    out = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for i in range(full, k):
        out += a[i]
    return out


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
    zero distance returns its own value. Rows without any sample in range are (nan, False); the
    tree is queried only for rows a grid test cannot rule out (:func:`_near_rows`)."""
    shape = query.shape[:-1]
    q = query.reshape(-1, query.shape[-1])
    z = np.full(len(q), np.nan)
    valid = np.zeros(len(q), dtype=bool)
    rows = _near_rows(tree.data, q, radius)
    if len(rows) == 0:
        return z.reshape(shape), valid.reshape(shape)
    k = min(k, tree.n)
    d, i = tree.query(q[rows], k=k, distance_upper_bound=radius)
    # neighbour-major (k, rows): every pass below reads contiguous memory. Each row is sorted
    # by distance; a missing neighbour has d = inf, i = n: weight 1 / inf^p = 0, value 0
    d = np.ascontiguousarray(d.reshape(len(rows), k).T)
    vals = np.append(values, 0.0)[i.reshape(len(rows), k).T]
    w = np.maximum(d, 1e-9)
    w **= power
    np.divide(1.0, w, out=w)
    hit = d[0] < 1e-9  # a sample at zero distance: its value alone
    if hit.any():
        w[:, hit] = d[:, hit] < 1e-9
    sw = _column_sums(w)
    w *= vals
    z[rows] = np.where(sw > 0, _column_sums(w) / np.where(sw > 0, sw, 1.0), np.nan)
    if min_neighbours <= k:
        valid[rows] = np.isfinite(d[min_neighbours - 1])
    return z.reshape(shape), valid.reshape(shape)


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
