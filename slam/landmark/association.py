"""Data association: known (simulation), nearest neighbour with a Mahalanobis gate (eq. 49 of the
VB paper) and joint compatibility branch and bound (JCBB, Neira and Tardos 2001) for the EKF family.

Conventions: an association result gives, per observation, the index of a map landmark, ``-1``
for "new feature" (farther than ``gate_new`` from every landmark) or ``-2`` for "ignore"
(ambiguous: outside the acceptance gate but too close to a landmark to start a new one). Gates
are on the squared Mahalanobis distance ``D = v^T S^-1 v`` (eq. 49); the defaults are the
chi-square 99 % point for 2 dof (9.21) to accept and Bailey's simulator value 25 to augment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from auvgw.ground.geometry import chi2_ppf

__all__ = [
    "JCBB",
    "Association",
    "KnownAssociation",
    "NearestNeighbour",
    "jcbb",
    "resolve_conflicts",
]

CHI2_2DOF_99 = float(chi2_ppf(0.99, 2))


class Association:
    """Base class of association strategies (a filter is built with one)."""

    name = "base"


@dataclass(frozen=True)
class KnownAssociation(Association):
    """The observation ids are the true feature ids (simulation)."""

    name = "known"


@dataclass(frozen=True)
class NearestNeighbour(Association):
    """Each observation takes its nearest landmark by eq. (49) if ``D < gate_accept``; it starts a
    new landmark if ``D > gate_new`` for every landmark; otherwise it is ignored."""

    gate_accept: float = CHI2_2DOF_99
    gate_new: float = 25.0
    name = "nn"

    def assign(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``d (..., m, L)`` distances (``inf`` for absent landmarks) -> ``(slots (..., m),
        best distance (..., m))``."""
        if d.shape[-1] == 0:
            shape = d.shape[:-1]
            return np.full(shape, -1, dtype=np.int64), np.full(shape, np.inf)
        j = np.argmin(d, axis=-1)
        best = np.take_along_axis(d, j[..., None], axis=-1)[..., 0]
        slots = np.where(best < self.gate_accept, j, np.where(best > self.gate_new, -1, -2))
        return slots.astype(np.int64), best


@dataclass(frozen=True)
class JCBB(Association):
    """Joint compatibility branch and bound; individual gate ``gate_accept``, joint gate at
    probability ``joint_prob`` of the chi-square with ``2k`` dof; ``gate_new`` as for NN."""

    gate_accept: float = CHI2_2DOF_99
    gate_new: float = 25.0
    joint_prob: float = 0.99
    name = "jcbb"


def resolve_conflicts(slots: np.ndarray, best: np.ndarray) -> np.ndarray:
    """Make associations exclusive per row: when several observations of one scan claim the same
    landmark, the closest keeps it and the others are ignored (``-2``). ``slots, best (N, m)``."""
    n, m = slots.shape
    if m < 2:
        return slots
    out = slots.copy()
    rows = np.repeat(np.arange(n), m)
    s = slots.ravel()
    b = best.ravel()
    order = np.lexsort((b, s, rows))
    rs, ss = rows[order], s[order]
    dup = np.zeros(n * m, dtype=bool)
    dup[1:] = (rs[1:] == rs[:-1]) & (ss[1:] == ss[:-1]) & (ss[1:] >= 0)
    flat = out.ravel()
    flat[order[dup]] = -2
    return flat.reshape(n, m)


def jcbb(
    v: np.ndarray,
    hph: np.ndarray,
    r: np.ndarray,
    individual: np.ndarray,
    joint_prob: float = 0.99,
) -> tuple[np.ndarray, float]:
    """Joint compatibility branch and bound.

    ``v (m, L, 2)`` innovation of observation ``i`` against landmark ``j``; ``hph (L, 2, L, 2)``
    the blocks ``H_j P H_k^T`` of the predicted-measurement covariance; ``r (2, 2)`` the
    observation noise; ``individual (m, L)`` bool, individually compatible pairs. Returns
    ``(pairing (m,), joint NIS)`` with ``pairing[i]`` the landmark of observation ``i`` or
    ``-1``: the hypothesis with the most jointly compatible pairings (ties: smallest joint
    NIS), each landmark used at most once."""
    m = v.shape[0]
    thresholds = [0.0] + [float(chi2_ppf(joint_prob, 2 * k)) for k in range(1, m + 1)]
    cand = [np.nonzero(individual[i])[0] for i in range(m)]
    best_pairs: list[tuple[int, int]] = []
    best_nis = np.inf

    def joint_nis(pairs: list[tuple[int, int]]) -> float:
        js = [j for _, j in pairs]
        k = len(pairs)
        s = hph[np.ix_(js, [0, 1], js, [0, 1])].reshape(2 * k, 2 * k) + np.kron(np.eye(k), r)
        vv = np.concatenate([v[i, j] for i, j in pairs])
        return float(vv @ np.linalg.solve(s, vv))

    def rec(i: int, pairs: list[tuple[int, int]], nis: float) -> None:
        nonlocal best_pairs, best_nis
        if i == m:
            if len(pairs) > len(best_pairs) or (len(pairs) == len(best_pairs) and nis < best_nis):
                best_pairs, best_nis = list(pairs), nis
            return
        used = {j for _, j in pairs}
        for j in cand[i]:
            if int(j) in used:
                continue
            trial = [*pairs, (i, int(j))]
            d = joint_nis(trial)
            if d < thresholds[len(trial)]:
                rec(i + 1, trial, d)
        # the branch without a pairing for observation i can still win (bound)
        if len(pairs) + (m - i - 1) >= len(best_pairs):
            rec(i + 1, pairs, nis)

    rec(0, [], 0.0)
    pairing = np.full(m, -1, dtype=np.int64)
    for i, j in best_pairs:
        pairing[i] = j
    return pairing, (best_nis if best_pairs else 0.0)
