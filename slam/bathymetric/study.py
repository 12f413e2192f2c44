"""Monte Carlo studies of the bathymetric filters: every algorithm of run ``i`` sees the same
simulated survey (common random numbers, ``SeedSequence([seed, i])``); each filter draws from
``SeedSequence([seed, i, crc32(name)])``. Tables of the paper's measures and PNG plots."""

from __future__ import annotations

import functools
import math
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import BathyResult, grid_dem, run_filter
from auvgw.slam.bathymetric.simulate import BathyRun, DRModel, simulate_survey
from auvgw.slam.evaluation.executor import map_unordered

__all__ = ["BathyStudy", "format_bathy_table", "monte_carlo", "plot_bathy", "run_one", "summary"]


@dataclass(frozen=True)
class BathyStudy:
    """``runs`` surveys of ``scenario``, each filtered by every algorithm with ``config``."""

    scenario: Scenario
    algorithms: tuple[str, ...]
    runs: int
    config: BathyConfig = field(default_factory=BathyConfig)
    seed: int = 0
    max_pings: int | None = None
    nav: DRModel = field(default_factory=DRModel)  # the DR error model (simulate.DRModel)


@functools.lru_cache(maxsize=2)
def _survey(
    scn_json: str, seed: int, run: int, max_pings: int | None, nav: DRModel | None = None
) -> tuple[BathyRun, Any]:
    from auvgw.sim_devices.world import World

    scn = Scenario.model_validate_json(scn_json)
    world = World.from_scenario(scn)
    rng = np.random.default_rng(np.random.SeedSequence([seed, run]))
    return simulate_survey(scn, rng, dr=nav, max_pings=max_pings, world=world), world


def run_one(study: BathyStudy, run: int, algorithm: str) -> BathyResult:
    """Run ``run`` of ``study`` through ``algorithm``."""
    sim, world = _survey(
        study.scenario.model_dump_json(), study.seed, run, study.max_pings, study.nav
    )
    rng = np.random.default_rng(
        np.random.SeedSequence([study.seed, run, zlib.crc32(algorithm.encode())])
    )
    res, _ = run_filter(algorithm, sim, study.config, rng, run=run, depth_fn=world.depth)
    return res


def _task(args: tuple[BathyStudy, int, str]) -> BathyResult:
    return run_one(*args)


def monte_carlo(
    study: BathyStudy,
    executor: Executor | None = None,
    progress: Callable[[BathyResult], None] | None = None,
) -> list[BathyResult]:
    """Every (run, algorithm) of ``study`` on ``executor`` (None: here); ordered by (run,
    algorithm)."""
    tasks = [(study, i, a) for i in range(study.runs) for a in study.algorithms]
    res = map_unordered(_task, tasks, executor, progress)
    order = {a: i for i, a in enumerate(study.algorithms)}
    res.sort(key=lambda r: (r.run, order[r.algorithm]))
    return res


def _prf(tp: int, fp: int, fn: int) -> tuple[float, float, float]:
    p = tp / (tp + fp) if tp + fp else math.nan
    r = tp / (tp + fn) if tp + fn else math.nan
    f1 = 2 * p * r / (p + r) if p + r > 0 else math.nan
    return p, r, f1


def _false_shares(results: Sequence[BathyResult]) -> list[float]:
    """Per run with closures: the share of them that truth labels false (A22)."""
    out = []
    for r in results:
        n = r.tp + r.fp + r.tn + r.fn
        if n:
            out.append((r.fp + r.tn) / n)
    return out


def summary(results: Sequence[BathyResult]) -> dict[str, float]:
    """The paper's measures over the runs of one algorithm (means unless named)."""
    fe = np.array([r.final_error_m for r in results])
    errs = np.concatenate([r.err_final for r in results])
    tp, fp, tn, fn = (sum(getattr(r, k) for r in results) for k in ("tp", "fp", "tn", "fn"))
    p, rc, f1 = _prf(tp, fp, fn)
    return {
        "runs": len(results),
        "final_error_mean_m": float(fe.mean()),
        "final_error_std_m": float(fe.std()),
        "rms_m": float(np.mean([r.rms_m for r in results])),
        "traj_error_mean_m": float(errs.mean()),
        "traj_error_p50_m": float(np.percentile(errs, 50)),
        "traj_error_p95_m": float(np.percentile(errs, 95)),
        "traj_error_max_m": float(errs.max()),
        "points_over_50m": float(np.mean([(r.err_final > 50).sum() for r in results])),
        "point_std_m": float(
            np.mean(np.linalg.norm(np.std([r.final for r in results], axis=0), axis=1))
        )
        if len({len(r.final) for r in results}) == 1
        else math.nan,
        "runtime_s": float(np.mean([r.runtime_s for r in results])),
        "realtime_factor": float(np.mean([r.rtf for r in results])),
        "memory_mb": float(np.mean([r.bytes_held for r in results]) / 1e6),
        "matched_per_ping": float(np.mean([r.matched_mean for r in results])),
        "loops_accepted": float(np.mean([r.loops_accepted for r in results])),
        "loops_rejected": float(np.mean([r.loops_rejected for r in results])),
        # share of a run's closures that truth labels false (fp + tn), mean over runs with any
        "false_share": float(np.mean(shares)) if (shares := _false_shares(results)) else math.nan,
        "loops_overturned": float(np.mean([r.extra.get("loops_overturned", 0) for r in results])),
        "weak_crossings": float(np.mean([r.extra.get("weak_crossings", 0) for r in results])),
        # error budget (evaluate.error_budget), means over runs
        **{
            k: float(np.mean([r.extra.get(k, math.nan) for r in results]))
            for k in (
                "last_closure_ping",
                "err_at_last_closure_m",
                "accrued_since_m",
                "dr_drift_since_m",
            )
        },
        "tp": tp,
        "fp": fp,
        "tn": tn,
        "fn": fn,
        "precision": p,
        "recall": rc,
        "f1": f1,
        "map_err_mean_m": float(np.mean([r.map_err_mean_m for r in results])),
        "map_under_2m_pct": float(100 * np.mean([r.map_err_under_2m for r in results])),
        "error_over_distance_pct": float(
            100 * np.mean([r.rms_m / r.distance_m for r in results if r.distance_m > 0])
        ),
    }


ROWS = [
    ("Final error, mean (m)", "final_error_mean_m", "{:.2f}"),
    ("Final error, std (m)", "final_error_std_m", "{:.2f}"),
    ("RMS error, final trajectory (m)", "rms_m", "{:.2f}"),
    (
        "Trajectory error p50 / p95 / max (m)",
        ("traj_error_p50_m", "traj_error_p95_m", "traj_error_max_m"),
        "{:.1f}",
    ),
    ("Points > 50 m per run", "points_over_50m", "{:.0f}"),
    ("Std of trajectory points across runs (m)", "point_std_m", "{:.2f}"),
    ("RMSE / distance (%)", "error_over_distance_pct", "{:.3f}"),
    ("Run time (s)", "runtime_s", "{:.1f}"),
    ("Real-time factor", "realtime_factor", "{:.0f}x"),
    ("Memory held (MB)", "memory_mb", "{:.1f}"),
    ("Particles matched per ping", "matched_per_ping", "{:.1f}"),
    ("Loop closures accepted / rejected", ("loops_accepted", "loops_rejected"), "{:.1f}"),
    (
        "Closures overturned (counted as rejected) / weak crossings (no closure)",
        ("loops_overturned", "weak_crossings"),
        "{:.1f}",
    ),
    (
        "Error budget: last accepted closure (ping) / error there / accrued since (m)",
        ("last_closure_ping", "err_at_last_closure_m", "accrued_since_m"),
        "{:.1f}",
    ),
    ("DR drift since the last accepted closure (m)", "dr_drift_since_m", "{:.1f}"),
    ("Loop closures TP / FP / TN / FN", ("tp", "fp", "tn", "fn"), "{:d}"),
    ("Closures labelled false, share per run", "false_share", "{:.2f}"),
    ("LCCD precision / recall / F1", ("precision", "recall", "f1"), "{:.2f}"),
    ("Map registration error, mean (m)", "map_err_mean_m", "{:.2f}"),
    ("Soundings within 2 m (%)", "map_under_2m_pct", "{:.2f}"),
]


def format_bathy_table(
    title: str, sums: dict[str, dict[str, float]], markdown: bool = False
) -> str:
    """One column per algorithm, one row per measure."""
    algs = list(sums)
    rows = []
    for label, key, fmt in ROWS:
        keys = key if isinstance(key, tuple) else (key,)
        cells = []
        for a in algs:
            vals = [sums[a][k] for k in keys]
            cells.append(
                " / ".join(
                    "-"
                    if isinstance(v, float) and math.isnan(v)
                    else fmt.format(int(v) if fmt == "{:d}" else v)
                    for v in vals
                )
            )
        rows.append((label, cells))
    if markdown:
        out = [
            f"### {title}",
            "",
            "| measure | " + " | ".join(algs) + " |",
            "|---|" + "---|" * len(algs),
        ]
        out += [f"| {lab} | " + " | ".join(c) + " |" for lab, c in rows]
        return "\n".join(out) + "\n"
    w = max(len(r[0]) for r in rows)
    cw = max(12, *(len(c) for _, cs in rows for c in cs), *(len(a) for a in algs))
    out = [title, " " * w + "  " + "  ".join(a.rjust(cw) for a in algs)]
    out += [lab.ljust(w) + "  " + "  ".join(c.rjust(cw) for c in cs) for lab, cs in rows]
    return "\n".join(out) + "\n"


def plot_bathy(results: Sequence[BathyResult], study: BathyStudy, out: Path, title: str) -> None:
    """Three PNGs in ``out``: the DEM of run 0 of the first algorithm, trajectories of run 0,
    and the mean error over time of every algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    name = study.scenario.name
    sim, _ = _survey(study.scenario.model_dump_json(), study.seed, 0, study.max_pings, study.nav)
    r0 = [r for r in results if r.run == 0]
    first = r0[0]
    xy = first.final[:, None, :] + sim.offsets
    pts = np.column_stack([xy.reshape(-1, 2), sim.depth.reshape(-1)])
    grid, (x0, y0) = grid_dem(pts, study.config.grid_cell_m)
    fig, ax = plt.subplots(figsize=(7, 6))
    c = study.config.grid_cell_m
    im = ax.imshow(
        grid,
        origin="lower",
        cmap="viridis_r",
        extent=(y0, y0 + grid.shape[1] * c, x0, x0 + grid.shape[0] * c),
    )
    fig.colorbar(im, ax=ax, label="depth (m)")
    ax.set(xlabel="east (m)", ylabel="north (m)", title=f"{title}\n{first.algorithm} DEM, run 0")
    fig.savefig(out / f"{name}_map.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(first.truth[:, 1], first.truth[:, 0], "k-", lw=1.5, label="truth")
    for r in r0:
        ax.plot(r.final[:, 1], r.final[:, 0], lw=0.9, label=r.algorithm)
    ax.set(xlabel="east (m)", ylabel="north (m)", title=f"{title}\ntrajectories, run 0")
    ax.set_aspect("equal")
    ax.legend()
    fig.savefig(out / f"{name}_trajectories.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 4))
    for a in study.algorithms:
        rs = [r for r in results if r.algorithm == a]
        n = min(len(r.err_online) for r in rs)
        ax.plot(sim.t[:n], np.mean([r.err_online[:n] for r in rs], axis=0), label=f"{a} online")
        ax.plot(sim.t[:n], np.mean([r.err_final[:n] for r in rs], axis=0), "--", label=f"{a} final")
    ax.set(
        xlabel="time (s)",
        ylabel="position error (m)",
        title=f"{title}\nmean error over {study.runs} runs",
    )
    ax.legend(fontsize=8)
    fig.savefig(out / f"{name}_error.png", dpi=110)
    plt.close(fig)
