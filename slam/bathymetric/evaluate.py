"""Running a bathymetric filter over a simulated survey and measuring it against the truth:
position errors, run time, memory, loop closures against truth labels (A22), map registration
against the true terrain (A23), and the final map as a gridded DEM."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.filters import FILTERS, BathyFilter, rotate
from auvgw.slam.bathymetric.loops import loop_valid
from auvgw.slam.bathymetric.simulate import BathyRun

__all__ = [
    "BathyResult",
    "GaugeError",
    "error_budget",
    "gauge_error",
    "gauge_floor",
    "grid_dem",
    "label_loops",
    "run_filter",
    "save_tracks",
    "yaw_about_start",
]


@dataclass
class BathyResult:
    """What one filter did on one run (positions NED m, times s)."""

    algorithm: str
    run: int
    online: np.ndarray  # (T, 2) estimate after each ping
    final: np.ndarray  # (T, 2) final corrected trajectory
    truth: np.ndarray  # (T, 2)
    runtime_s: float
    duration_s: float
    distance_m: float
    bytes_held: int
    loops_accepted: int = 0
    loops_rejected: int = 0
    tp: int = 0
    fp: int = 0
    tn: int = 0
    fn: int = 0
    map_err_mean_m: float = float("nan")
    map_err_under_2m: float = float("nan")
    matched_mean: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def err_online(self) -> np.ndarray:
        return np.linalg.norm(self.online - self.truth, axis=1)

    @property
    def err_final(self) -> np.ndarray:
        return np.linalg.norm(self.final - self.truth, axis=1)

    @property
    def final_error_m(self) -> float:
        """Error at the end of the mission (of the corrected trajectory = online at the end)."""
        return float(self.err_final[-1])

    @property
    def rms_m(self) -> float:
        """RMS error over every point of the final trajectory."""
        return float(np.sqrt(np.mean(self.err_final**2)))

    @property
    def rtf(self) -> float:
        """Real-time factor: mission seconds per filter second."""
        return self.duration_s / self.runtime_s if self.runtime_s > 0 else float("inf")


def label_loops(f: BathyFilter, truth: np.ndarray) -> list[bool]:
    """Truth label of every loop closure (A22): valid when, after its jump, the loop-interval
    displacement error is at most max(3 m, half of what it was before)."""
    return [loop_valid(lc, truth) for lc in f.loops]


def error_budget(f: BathyFilter, sim: BathyRun) -> dict[str, float]:
    """Where the final error comes from (m, NED norms): the last accepted closure ends at
    ping ``t_c`` (0 when none); the final error is the final trajectory's error there
    (``err_at_last_closure_m``: what the closures left) plus what accrued after it
    (``accrued_since_m``: the final trajectory's displacement error over ``[t_c, T]``), of
    which ``dr_drift_since_m`` is dead reckoning's own (eq. 28: the bias the particles do not
    model)."""
    traj, truth, dr = f.trajectory(), sim.truth, f.dr
    last = [lc.t_end for lc in f.loops if lc.accepted]
    t_c, t_e = (max(last) if last else 0), len(traj) - 1

    def disp_err(x: np.ndarray) -> float:
        return float(np.linalg.norm((x[t_e] - x[t_c]) - (truth[t_e] - truth[t_c])))

    return {
        "last_closure_ping": float(t_c),
        "err_at_last_closure_m": float(np.linalg.norm(traj[t_c] - truth[t_c])),
        "accrued_since_m": disp_err(traj),
        "dr_drift_since_m": disp_err(dr[: t_e + 1]),
    }


def yaw_about_start(est: np.ndarray, truth: np.ndarray) -> float:
    """The rotation about the known start ``truth[0]`` (rad, positive from north towards east, as
    a heading) that best turns ``truth`` onto ``est`` ((T, 2) NED, m) in the least-squares sense:
    ``est ~ start + rotate(truth - start, angle)``. Yaw only, no translation: the start is known
    and depth is observed, so a constant heading error is the one direction a relative method
    cannot see (Zhang and Scaramuzza, "A Tutorial on Quantitative Trajectory Evaluation for
    Visual(-Inertial) Odometry", IROS 2018: align over the unobservable DOF only; the closed
    form of the best yaw). 0 when every point is at the start."""
    a = truth - truth[0]
    b = est - truth[0]
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    dot = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    return math.atan2(cross, dot) if (cross or dot) else 0.0


@dataclass(frozen=True)
class GaugeError:
    """An estimate's error against the truth, raw and gauge-aligned (m, horizontal NED):
    ``angle_rad``: its fitted yaw about the start (:func:`yaw_about_start`); ``rmse_m`` /
    ``final_m``: as it is; ``aligned_rmse_m`` / ``aligned_final_m``: once turned back by that
    angle about the start (what a relative method can be asked to correct)."""

    angle_rad: float
    rmse_m: float
    final_m: float
    aligned_rmse_m: float
    aligned_final_m: float


def gauge_error(est: np.ndarray, truth: np.ndarray) -> GaugeError:
    """:class:`GaugeError` of ``est`` against ``truth`` ((T, 2) NED, m, at the same times,
    ``truth[0]`` the known start)."""
    angle = yaw_about_start(est, truth)
    aligned = truth[0] + rotate(est - truth[0], -angle)
    raw = np.hypot(*(est - truth).T)
    err = np.hypot(*(aligned - truth).T)
    return GaugeError(angle, float(np.sqrt(np.mean(raw**2))), float(raw[-1]),
                      float(np.sqrt(np.mean(err**2))), float(err[-1]))  # fmt: skip


def gauge_floor(truth: np.ndarray, angle_rad: float) -> tuple[float, float]:
    """(RMSE, final error) m of the truth turned by ``angle_rad`` about its start: what an
    estimate that corrected everything but a rotation of that size about the start (dead
    reckoning's own, :func:`yaw_about_start`) would still show, raw."""
    turned = truth[0] + rotate(truth - truth[0], angle_rad)
    e = np.hypot(*(turned - truth).T)
    return float(np.sqrt(np.mean(e**2))), float(e[-1])


#: the positions a run's tracks file holds (:func:`save_tracks`)
TRACKS = ("truth", "dr", "filtered", "smoothed")


def save_tracks(path: Path, t: np.ndarray, heading_error_rad: np.ndarray, step: int = 1,
                **tracks: np.ndarray) -> None:  # fmt: skip
    """One run's positions for the gauge (issue 28) as ``path`` (``.npz``, compressed): ``t``
    (s), each of :data:`TRACKS` ((n, 2) NED m at ``t``, float32: dead reckoning, the SLAM's
    filtered and smoothed estimates; NaN where an estimate has none) and ``heading_error_deg``
    (the navigation's heading error at ``t``, from ``heading_error_rad``), every ``step``-th
    sample and the last."""
    keep = np.unique(np.r_[np.arange(0, len(t), step), len(t) - 1])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, t=t[keep], heading_error_deg=np.degrees(heading_error_rad[keep]),
                        **{k: tracks[k][keep].astype(np.float32) for k in TRACKS})  # fmt: skip


SPREAD_LAGS = (1, 10, 30, 100)


def spread_after_resampling(f: BathyFilter) -> dict[str, float]:
    """Claim C4 (Fig. 11): the cloud's spread (m, :meth:`BathyFilter.cloud_std`) just before
    each resampling (``spread_before_m``) and ``L`` pings after it (``spread_lag{L}_m``), means
    over the run's resamplings that have ``L`` pings after them (NaN without any)."""
    at = np.asarray(f.resampled_at, dtype=int)
    out = {"spread_before_m": float(f.spread[at - 1].mean()) if len(at) else math.nan}
    for lag in SPREAD_LAGS:
        k = at[at + lag < f.t]
        out[f"spread_lag{lag}_m"] = float(f.spread[k + lag].mean()) if len(k) else math.nan
    return out


def map_registration(points: np.ndarray, depth_fn: object) -> tuple[float, float]:
    """(mean |z - z_true(x_hat, y_hat)|, share < 2 m) of soundings placed by an estimate (A23)."""
    err = np.abs(points[:, 2] - depth_fn(points[:, 0], points[:, 1]))  # type: ignore[operator]
    return float(err.mean()), float((err < 2.0).mean())


def grid_dem(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, tuple[float, float]]:
    """Mean depth per ``cell_m`` cell of (P, 3) soundings: ``(grid, (x0, y0))`` with
    ``grid[i, j]`` at x = x0 + (i + 0.5) cell, y = y0 + (j + 0.5) cell; NaN where empty."""
    x0, y0 = float(points[:, 0].min()), float(points[:, 1].min())
    i = ((points[:, 0] - x0) // cell_m).astype(int)
    j = ((points[:, 1] - y0) // cell_m).astype(int)
    shape = (i.max() + 1, j.max() + 1)
    s = np.zeros(shape)
    c = np.zeros(shape)
    np.add.at(s, (i, j), points[:, 2])
    np.add.at(c, (i, j), 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(c > 0, s / c, np.nan), (x0, y0)


def run_filter(
    name: str,
    sim: BathyRun,
    cfg: BathyConfig,
    rng: np.random.Generator,
    run: int = 0,
    depth_fn: object = None,
    progress: object = None,
) -> tuple[BathyResult, BathyFilter]:
    """Drive filter ``name`` over ``sim``; only the filter's own calls are timed."""
    f = FILTERS[name](cfg, len(sim.t), rng)
    if cfg.lccd and cfg.lccd_mode == "oracle":
        f.oracle_truth = sim.truth  # diagnostic only: the truth labels decide (A22)
    u = sim.controls()
    t0 = time.perf_counter()
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    for k in range(1, len(sim.t)):
        f.step(u[k - 1], sim.offsets[k], sim.depth[k])
        if progress is not None and k % 100 == 0:
            progress(k)  # type: ignore[operator]
    spent = time.perf_counter() - t0
    labels = label_loops(f, sim.truth)
    acc = [lc.accepted for lc in f.loops]
    res = BathyResult(
        algorithm=name,
        run=run,
        online=f.estimates.copy(),
        final=f.trajectory().copy(),
        truth=sim.truth,
        runtime_s=spent,
        duration_s=sim.duration_s,
        distance_m=sim.distance_m,
        bytes_held=f.bytes_held(),
        loops_accepted=sum(acc),
        loops_rejected=len(acc) - sum(acc),
        tp=sum(a and v for a, v in zip(acc, labels, strict=True)),
        fp=sum(a and not v for a, v in zip(acc, labels, strict=True)),
        tn=sum(not a and not v for a, v in zip(acc, labels, strict=True)),
        fn=sum(not a and v for a, v in zip(acc, labels, strict=True)),
        matched_mean=float(f.matched.mean()),
        extra={
            "loops_overturned": float(sum(lc.overturned for lc in f.loops)),
            "weak_crossings": float(getattr(f, "weak_crossings", 0)),
            "resamplings": float(getattr(f, "resamplings", len(f.loops))),
            **error_budget(f, sim),
            **spread_after_resampling(f),
        },
    )
    if depth_fn is not None:
        res.map_err_mean_m, res.map_err_under_2m = map_registration(f.map_points(), depth_fn)
    return res, f
