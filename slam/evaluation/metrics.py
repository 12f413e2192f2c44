"""Accuracy metrics of the papers' tables: path RMSE (total, x, y), feature RMSE, mean Neff,
run time, real-time factor and the VB paper's accuracy ``RMSE / distance x 100`` (eq. 50).

Pooling over Monte Carlo runs: an RMSE over several runs is the root of the mean squared error
over all runs and all epochs (scans) of the runs, i.e. ``sqrt(mean of per-run MSE)`` for runs of
equal length. The pose error is taken after every scan's update. The feature error matches each
estimated feature to its true feature: by id with known association, otherwise by a minimum-cost
assignment (Hungarian) on distance; it is computed on the final map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["RunResult", "Summary", "feature_errors", "summarise"]


@dataclass
class RunResult:
    """One filter on one simulated run. Arrays are per scan: ``est``/``truth (n, 3)``,
    ``neff (n,)``; ``map_mean (L, 2)`` and ``map_ids (L,)`` the final map."""

    algorithm: str
    run: int
    est: np.ndarray
    truth: np.ndarray
    neff: np.ndarray
    map_mean: np.ndarray
    map_ids: np.ndarray
    landmarks: np.ndarray
    runtime_s: float
    duration_s: float
    distance_m: float
    noise: tuple[float, float] = (1.0, 0.0)
    #: vehicle time of each scan, seconds
    t: np.ndarray | None = None
    extra: dict[str, float] = field(default_factory=dict)

    def path_errors(self) -> np.ndarray:
        """``(n, 2)`` position errors (x, y) in metres."""
        return self.est[:, :2] - self.truth[:, :2]


def feature_errors(mean: np.ndarray, ids: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distances (m) of estimated features to the true ones (by id, else by assignment)."""
    if len(mean) == 0:
        return np.zeros(0)
    if np.all(ids >= 0):
        return np.linalg.norm(mean - truth[ids], axis=1)
    d = np.linalg.norm(mean[:, None, :] - truth[None, :, :], axis=-1)
    r, c = linear_sum_assignment(d)
    return d[r, c]


@dataclass(frozen=True)
class Summary:
    """Pooled metrics of one algorithm over runs (metres, seconds)."""

    algorithm: str
    runs: int
    path: float
    path_x: float
    path_y: float
    feature: float
    neff: float
    runtime_s: float
    realtime_factor: float
    accuracy_pct: float


def summarise(results: list[RunResult]) -> Summary:
    """Pool the runs of one algorithm (see the module docstring)."""
    if not results:
        raise ValueError("no runs to summarise")
    e = np.concatenate([r.path_errors() for r in results])
    fe = np.concatenate([feature_errors(r.map_mean, r.map_ids, r.landmarks) for r in results])
    neff = np.concatenate([r.neff for r in results])
    runtime = float(np.mean([r.runtime_s for r in results]))
    duration = float(np.mean([r.duration_s for r in results]))
    distance = float(np.mean([r.distance_m for r in results]))
    path = float(np.sqrt(np.mean(np.sum(e * e, axis=1))))
    return Summary(
        algorithm=results[0].algorithm,
        runs=len(results),
        path=path,
        path_x=float(np.sqrt(np.mean(e[:, 0] ** 2))),
        path_y=float(np.sqrt(np.mean(e[:, 1] ** 2))),
        feature=float(np.sqrt(np.mean(fe * fe))) if fe.size else math.nan,
        neff=float(np.nanmean(neff)) if np.any(np.isfinite(neff)) else math.nan,
        runtime_s=runtime,
        realtime_factor=duration / runtime if runtime > 0 else math.inf,
        accuracy_pct=100.0 * path / distance if distance > 0 else math.nan,
    )
