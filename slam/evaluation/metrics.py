"""Accuracy metrics of the papers' tables: path RMSE (total, x, y), feature RMSE (points: distance
m; lines: the VR paper's Table 1 errors of ``rho`` in m and ``theta`` in deg, in the map frame),
mean Neff, run time, real-time factor and the VB paper's accuracy ``RMSE / distance x 100``
(eq. 50).

Pooling over Monte Carlo runs: an RMSE over several runs is the root of the mean squared error
over all runs and all epochs (scans) of the runs, i.e. ``sqrt(mean of per-run MSE)`` for runs of
equal length. The pose error is taken after every scan's update. The feature error matches each
estimated feature to its true feature: by id with known association, otherwise by a minimum-cost
assignment (Hungarian) on distance (lines: on ``drho^2 + (10 m x dtheta)^2``, the angle error
weighted as the displacement it makes 10 m along the line); it is computed on the final map.

Neff (eq. 8 of the VR paper, ``1 / sum w^2`` of the normalised weights) is taken at every scan
after the weight update and *before* resampling or variance reduction, for every filter
(``Mean Neff``). ``Neff after`` is the same after resampling / variance reduction (``N`` right
after a resampling, whose particles are copies); ``Distinct`` the number of distinct particles
then (the VR paper's Fig. 8 "diversity").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["RunResult", "Summary", "feature_errors", "line_errors", "summarise"]

#: metres per radian of theta error in the assignment cost of unlabelled lines
LINE_ASSIGN_LEVER_M = 10.0


@dataclass
class RunResult:
    """One filter on one simulated run. Arrays are per scan: ``est``/``truth (n, 3)``,
    ``neff (n,)`` (before resampling / variance reduction), ``neff_post``, ``distinct (n,)``
    (after); ``map_mean (L, 2)`` and ``map_ids (L,)`` the final map, ``landmarks`` the true
    features (``features``: ``points`` (x, y) or ``lines`` (rho, theta), map frame)."""

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
    features: str = "points"
    neff_post: np.ndarray | None = None
    distinct: np.ndarray | None = None
    #: wall segments (x1, y1, x2, y2) of line features, for plots
    segments: np.ndarray | None = None
    #: why and when the filter failed numerically (:class:`FilterDiverged`); ``""`` if not.
    #: The arrays then stop at that scan and the map is empty.
    diverged: str = ""

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


def line_errors(mean: np.ndarray, ids: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(L, 2)`` errors ``(rho m, theta rad wrapped)`` of estimated lines ``(rho, theta)``
    against the true ones (by id, else by assignment, see the module docstring)."""
    if len(mean) == 0:
        return np.zeros((0, 2))

    def diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = a - b
        d[..., 1] = (d[..., 1] + np.pi) % (2 * np.pi) - np.pi
        return d

    if np.all(ids >= 0):
        return diff(mean, truth[ids])
    d = diff(mean[:, None, :], truth[None, :, :])
    cost = d[..., 0] ** 2 + (LINE_ASSIGN_LEVER_M * d[..., 1]) ** 2
    r, c = linear_sum_assignment(cost)
    return d[r, c]


def _nanmean(arrays: list[np.ndarray | None]) -> float:
    vals = [a for a in arrays if a is not None]
    if not vals:
        return math.nan
    v = np.concatenate(vals)
    return float(np.nanmean(v)) if np.any(np.isfinite(v)) else math.nan


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
    #: line features: RMSE of rho (m) and theta (deg); nan for points
    feature_rho: float = math.nan
    feature_theta_deg: float = math.nan
    #: mean Neff after resampling / variance reduction, mean number of distinct particles
    neff_post: float = math.nan
    distinct: float = math.nan
    #: runs in which the filter failed numerically; the metrics pool the other runs
    diverged: int = 0
    #: path RMSE (m) of each pooled run, in run order (for paired comparisons between filters)
    path_runs: tuple[float, ...] = ()


def summarise(results: list[RunResult]) -> Summary:
    """Pool the runs of one algorithm (see the module docstring); runs in which the filter
    diverged are counted in ``diverged`` and left out of the metrics."""
    if not results:
        raise ValueError("no runs to summarise")
    failed = sum(1 for r in results if r.diverged)
    if failed == len(results):
        nan = math.nan
        return Summary(results[0].algorithm, 0, nan, nan, nan, nan, nan, nan, nan, nan,
                       diverged=failed)  # fmt: skip
    if failed:
        return replace(summarise([r for r in results if not r.diverged]), diverged=failed)
    errs = [r.path_errors() for r in results]
    e = np.concatenate(errs)
    lines = [r for r in results if r.features == "lines"]
    points = [r for r in results if r.features != "lines"]
    fe = np.concatenate(
        [np.zeros(0)] + [feature_errors(r.map_mean, r.map_ids, r.landmarks) for r in points]
    )
    le = np.concatenate(
        [np.zeros((0, 2))] + [line_errors(r.map_mean, r.map_ids, r.landmarks) for r in lines]
    )
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
        feature_rho=float(np.sqrt(np.mean(le[:, 0] ** 2))) if len(le) else math.nan,
        feature_theta_deg=(
            math.degrees(float(np.sqrt(np.mean(le[:, 1] ** 2)))) if len(le) else math.nan
        ),
        neff_post=_nanmean([r.neff_post for r in results]),
        distinct=_nanmean([r.distinct for r in results]),
        path_runs=tuple(float(np.sqrt(np.mean(np.sum(x * x, axis=1)))) for x in errs),
    )
