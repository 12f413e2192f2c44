"""Monte Carlo evaluation: the same simulated runs for every algorithm, seeded, optionally on
several processes.

Run ``i`` of a study is simulated from ``SeedSequence([seed, i])`` (so every algorithm sees the
same truth, controls and observations in run ``i``), and each filter draws its own randomness
from ``SeedSequence([seed, i, crc32(name)])``. Only the filter's ``predict``/``update`` calls
are timed.
"""

from __future__ import annotations

import math
import time
import zlib
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.slam.evaluation.executor import map_unordered, open_executor
from auvgw.slam.evaluation.metrics import RunResult
from auvgw.slam.evaluation.simulate import FeatureKind, SimRun, simulate
from auvgw.slam.landmark.base import LandmarkFilter, ParticleFilterSLAM
from auvgw.slam.landmark.registry import make_filter

__all__ = ["FilterDiverged", "Study", "drive", "monte_carlo", "run_one"]


class FilterDiverged(RuntimeError):
    """A filter failed numerically (singular innovation covariance, non-finite estimate) at
    scan ``scan`` (vehicle time ``t_s``); ``est``/``neff`` hold the scans before it."""

    def __init__(
        self, scan: int, t_s: float, reason: str, est: np.ndarray, neff: np.ndarray
    ) -> None:
        super().__init__(f"diverged at {t_s:.1f} s (scan {scan}): {reason}")
        self.scan, self.t_s, self.reason = scan, t_s, reason
        self.est, self.neff = est, neff


@dataclass(frozen=True)
class Study:
    """What to run: algorithms on ``runs`` simulations of ``scenario`` observing ``features``
    (``points`` or ``lines``) with dynamic noise ``(burst_n, burst_p)``; the filters assume
    ``r0_scale * R0`` as their nominal noise; with ``oracle_noise`` the particle filters are
    also told each observation's true covariance (the bound of what noise adaptation can
    gain)."""

    scenario: Scenario
    algorithms: tuple[str, ...]
    runs: int
    burst_n: float = 1.0
    burst_p: float = 0.0
    n_particles: int = 100
    association: str = "known"
    seed: int = 0
    r0_scale: float = 1.0
    max_steps: int | None = None
    features: FeatureKind = "points"
    oracle_noise: bool = False


def drive(
    f: LandmarkFilter,
    sim: SimRun,
    rng: np.random.Generator,
    extra: dict[str, np.ndarray] | None = None,
    oracle_noise: bool = False,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Run filter ``f`` through ``sim``: ``(estimates after each scan (n, 3), Neff (n,),
    seconds spent in the filter)``.

    ``Neff`` (eq. 8 of the VR paper) is the filter's :attr:`~LandmarkFilter.neff`: the effective
    sample size of the normalised weights after the scan's weight update, *before* resampling or
    variance reduction; the same definition for every particle filter. If ``extra`` is given it
    receives, per scan and after resampling or variance reduction, ``neff_post`` (Neff of the
    weights the filter carries on: ``N`` right after a resampling) and ``distinct`` (the number
    of distinct particle poses: resampling duplicates particles, variance reduction does not);
    ``nan`` for filters without particles. With ``oracle_noise`` a particle filter gets each
    observation's true covariance ``R0 x sim.obs_scale``. Raises :class:`FilterDiverged` when the
    filter fails numerically."""
    n_scans = len(sim.obs_step)
    est = np.empty((n_scans, 3))
    neff = np.empty(n_scans)
    post = np.full(n_scans, np.nan)
    distinct = np.full(n_scans, np.nan)
    pf = f if isinstance(f, ParticleFilterSLAM) and extra is not None else None
    oracle = oracle_noise and isinstance(f, ParticleFilterSLAM)
    is_scan = np.zeros(len(sim.controls) + 1, dtype=bool)
    is_scan[sim.obs_step] = True
    controls = sim.controls
    dt = sim.dt
    oi = 0
    spent = 0.0
    t0 = time.perf_counter()
    for k in range(len(controls)):
        try:
            f.predict(controls[k], dt, rng)
            if is_scan[k + 1]:
                kw = {"r": sim.r * sim.obs_scale[oi][:, None, None]} if oracle else {}
                f.update(sim.obs_z[oi], rng, sim.obs_ids[oi], **kw)
        except (np.linalg.LinAlgError, FloatingPointError) as e:
            raise FilterDiverged(oi, (k + 1) * dt, str(e), est[:oi], neff[:oi]) from e
        if is_scan[k + 1]:
            spent += time.perf_counter() - t0
            est[oi] = f.estimate()
            if not np.all(np.isfinite(est[oi])):
                raise FilterDiverged(oi, (k + 1) * dt, "non-finite pose", est[:oi], neff[:oi])
            neff[oi] = f.neff
            if pf is not None:
                post[oi] = pf.neff_of_weights()
                distinct[oi] = len(np.unique(pf.x, axis=0))
            oi += 1
            t0 = time.perf_counter()
    spent += time.perf_counter() - t0
    if extra is not None:
        extra["neff_post"] = post
        extra["distinct"] = distinct
    return est, neff, spent


def _filter_seed(seed: int, run: int, name: str) -> np.random.Generator:
    return np.random.default_rng([seed, run, zlib.crc32(name.encode())])


def run_one(study: Study, run: int, algorithm: str) -> RunResult:
    """Simulate run ``run`` of ``study`` and evaluate one algorithm on it."""
    sim = simulate(
        study.scenario,
        np.random.default_rng([study.seed, run]),
        burst_n=study.burst_n,
        burst_p=study.burst_p,
        max_steps=study.max_steps,
        features=study.features,
    )
    f = make_filter(
        algorithm,
        sim.motion_model(),
        sim.obs_model(),
        sim.q,
        sim.r * study.r0_scale,
        n_particles=study.n_particles,
        x0=sim.truth[0],
        association=study.association,
    )
    extra: dict[str, np.ndarray] = {}
    diverged = ""
    try:
        rng = _filter_seed(study.seed, run, algorithm)
        est, neff, spent = drive(f, sim, rng, extra, study.oracle_noise)
        lm = f.landmarks()
        map_mean, map_ids = lm.mean, lm.ids
    except FilterDiverged as e:
        est, neff, spent, diverged = e.est, e.neff, math.nan, str(e)
        map_mean, map_ids = np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        n = len(est)
        extra = {"neff_post": np.full(n, np.nan), "distinct": np.full(n, np.nan)}
    return RunResult(
        algorithm=algorithm,
        run=run,
        est=est,
        truth=sim.truth[sim.obs_step][: len(est)],
        neff=neff,
        map_mean=map_mean,
        map_ids=map_ids,
        landmarks=sim.landmarks,
        runtime_s=spent,
        duration_s=sim.duration_s,
        distance_m=sim.distance_m,
        noise=(study.burst_n, study.burst_p),
        t=sim.obs_step * sim.dt,
        features=sim.features,
        neff_post=extra["neff_post"],
        distinct=extra["distinct"],
        segments=sim.segments,
        diverged=diverged,
    )


def _task(args: tuple[Study, int, str]) -> RunResult:
    return run_one(*args)


def monte_carlo(
    study: Study,
    jobs: int = 1,
    progress: Callable[[RunResult], None] | None = None,
    executor: Executor | None = None,
) -> list[RunResult]:
    """All runs x algorithms of ``study`` on ``jobs`` processes, or on ``executor`` when given
    (e.g. a Dask cluster's, :func:`~auvgw.slam.evaluation.executor.open_executor`);
    ``progress`` is called with each finished result. Results come back ordered by (run,
    algorithm), identical wherever they ran."""
    tasks = [(study, i, a) for i in range(study.runs) for a in study.algorithms]
    if executor is not None:
        results = map_unordered(_task, tasks, executor, progress)
    else:
        with open_executor(jobs) as ex:
            results = map_unordered(_task, tasks, ex, progress)
    order = {a: i for i, a in enumerate(study.algorithms)}
    results.sort(key=lambda r: (r.run, order[r.algorithm]))
    return results
