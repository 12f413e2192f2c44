"""Why MB-SLAM does or does not beat dead reckoning on a beacon field (docs/slam_magnetic.md,
"Where MB-SLAM's error comes from").

Per Monte Carlo run of :mod:`~auvgw.slam.magnetic.evaluation` (the generic track with known
association, so every estimated beacon has its true identity):

* **coverage**: beacon sightings, the share of 5 Hz scans with at least one, the longest stretch
  without any (s) and the dead-reckoning drift accumulated over it (m: the change of the DR
  position error from the stretch's first scan to its last);
* **MB-SLAM's error**: path RMSE on each lap beside dead reckoning's; the beacon map error at
  each beacon's first sighting (the vehicle's error then, inherited by the map); at the
  revisits (second-lap sightings) the vehicle error ``|e_v|``, the error of the beacon seen
  ``|e_b|`` and ``|e_v - e_b|``: small when the revisit re-localised the vehicle *on the map*
  (then its error is the map's), large when it failed to;
* **consistency**: mean NEES of MB-SLAM's position (2 when consistent) and heading (1), every
  10th scan.

``python -m auvgw.slam.magnetic.diagnose --scenario F --runs N [--variant K=V,...] --out FILE``
prints one row per run and the means, and writes them as markdown with the command.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from auvgw.config.scenario import Scenario, load_scenario
from auvgw.slam.magnetic.evaluation import (
    Prepared,
    Variant,
    parse_variant,
    prepare,
    render_table,
    run_filter,
)
from auvgw.slam.magnetic.filters import MagneticSLAM
from auvgw.slam.models import wrap_angle

__all__ = ["RunDiagnosis", "diagnose_run", "format_diagnoses", "longest_gap", "main"]


@dataclass(frozen=True)
class RunDiagnosis:
    """One run (module docstring); lengths in metres, times in seconds."""

    run: int
    sightings: int
    scans_with_sighting: float
    longest_gap_s: float
    gap_start_s: float
    dr_drift_over_gap_m: float
    dr_rmse: float
    mb_rmse: float
    dr_rmse_lap1: float
    mb_rmse_lap1: float
    dr_rmse_lap2: float
    mb_rmse_lap2: float
    map_error_first_sighting_m: float
    revisit_vehicle_error_m: float
    revisit_beacon_error_m: float
    revisit_difference_m: float
    mb_nees_position: float
    mb_nees_heading: float


def longest_gap(prep: Prepared) -> tuple[int, int]:
    """First and last scan index of the longest stretch of scans without a beacon sighting
    (``(0, -1)`` when every scan has one)."""
    best, start = (0, -1), -1
    for i, seen in enumerate([len(z) > 0 for z in prep.z] + [True]):
        if not seen and start < 0:
            start = i
        elif seen and start >= 0:
            if i - start > best[1] - best[0] + 1:
                best = (start, i - 1)
            start = -1
    return best


def _rmse(e: np.ndarray) -> float:
    return math.sqrt(float((e**2).sum(1).mean())) if len(e) else math.nan


def diagnose_run(scn: Scenario, v: Variant, seed: int, run: int) -> RunDiagnosis:
    """Run ``run`` of a study seeded ``seed`` (the evaluation's random numbers), with known
    association whatever ``v`` says."""
    v = replace(v, track="generic", association="known")
    prep = prepare(scn, v, seed, run)
    ids_of = prep.ids or []
    sim = prep.sim
    truth = sim.truth[sim.obs_step]
    lap2 = prep.lap2_scan
    first: dict[int, float] = {}
    revisit: list[tuple[float, float, float]] = []
    nees: list[tuple[float, float]] = []

    def on_scan(i: int, f: MagneticSLAM) -> None:
        ids = ids_of[i]
        e_v = f.xs[:2] - truth[i, :2]
        if len(ids):
            lm = f.landmarks()
            where = {int(b): j for j, b in enumerate(lm.ids)}
            for b in map(int, ids):
                e_b = lm.mean[where[b]] - sim.landmarks[b]
                if b not in first:
                    first[b] = float(np.hypot(*e_b))
                elif i >= lap2:
                    revisit.append((float(np.hypot(*e_v)), float(np.hypot(*e_b)),
                                    float(np.hypot(*(e_v - e_b)))))  # fmt: skip
        if i % 10 == 0:
            p = f.p[:3, :3]
            eh = wrap_angle(f.xs[2] - truth[i, 2])
            nees.append((float(e_v @ np.linalg.solve(p[:2, :2], e_v)), float(eh**2 / p[2, 2])))

    mb = run_filter("mb-slam", prep, v, run, on_scan)
    dr = run_filter("dr", prep, v, run)
    g0, g1 = longest_gap(prep)
    drift = float(np.hypot(*(dr.err[g1] - dr.err[g0]))) if g1 >= g0 else 0.0
    rv = np.array(revisit).reshape(-1, 3)
    rv_mean = rv.mean(0) if len(rv) else np.full(3, math.nan)
    ne = np.array(nees).reshape(-1, 2).mean(0)
    dt_scan = float(np.median(np.diff(sim.obs_step))) * sim.dt
    return RunDiagnosis(
        run=run,
        sightings=int(sum(len(z) for z in prep.z)),
        scans_with_sighting=float(np.mean([len(z) > 0 for z in prep.z])),
        longest_gap_s=(g1 - g0 + 1) * dt_scan,
        gap_start_s=float(sim.obs_step[g0] * sim.dt) if g1 >= g0 else math.nan,
        dr_drift_over_gap_m=drift,
        dr_rmse=dr.rmse[0],
        mb_rmse=mb.rmse[0],
        dr_rmse_lap1=_rmse(dr.err[:lap2]),
        mb_rmse_lap1=_rmse(mb.err[:lap2]),
        dr_rmse_lap2=_rmse(dr.err[lap2:]),
        mb_rmse_lap2=_rmse(mb.err[lap2:]),
        map_error_first_sighting_m=float(np.mean(list(first.values()))) if first else math.nan,
        revisit_vehicle_error_m=float(rv_mean[0]),
        revisit_beacon_error_m=float(rv_mean[1]),
        revisit_difference_m=float(rv_mean[2]),
        mb_nees_position=float(ne[0]),
        mb_nees_heading=float(ne[1]),
    )


_COLUMNS = [
    ("run", "run", "{:d}"),
    ("sightings", "sightings", "{:d}"),
    ("scans_with_sighting", "scans with one", "{:.0%}"),
    ("longest_gap_s", "longest gap s", "{:.0f}"),
    ("gap_start_s", "gap from s", "{:.0f}"),
    ("dr_drift_over_gap_m", "DR drift over gap m", "{:.1f}"),
    ("dr_rmse", "DR RMSE", "{:.1f}"),
    ("mb_rmse", "MB RMSE", "{:.1f}"),
    ("dr_rmse_lap1", "DR lap 1", "{:.1f}"),
    ("mb_rmse_lap1", "MB lap 1", "{:.1f}"),
    ("dr_rmse_lap2", "DR lap 2", "{:.1f}"),
    ("mb_rmse_lap2", "MB lap 2", "{:.1f}"),
    ("map_error_first_sighting_m", "MB map err at 1st sighting", "{:.1f}"),
    ("revisit_vehicle_error_m", "revisit abs(e_v)", "{:.1f}"),
    ("revisit_beacon_error_m", "revisit abs(e_b)", "{:.1f}"),
    ("revisit_difference_m", "revisit abs(e_v - e_b)", "{:.1f}"),
    ("mb_nees_position", "MB NEES pos (2)", "{:.1f}"),
    ("mb_nees_heading", "MB NEES hdg (1)", "{:.1f}"),
]


def format_diagnoses(title: str, rows: list[RunDiagnosis], markdown: bool = True) -> str:
    """Markdown (or text) table: one row per run, then the mean over runs."""
    body = []
    for r in rows:
        d = asdict(r)
        body.append([fmt.format(d[k]) for k, _, fmt in _COLUMNS])
    mean = {k: float(np.mean([asdict(r)[k] for r in rows])) for k, _, _ in _COLUMNS[1:]}
    body.append(["mean"] + [fmt.format(round(mean[k]) if fmt == "{:d}" else mean[k])
                            for k, _, fmt in _COLUMNS[1:]])  # fmt: skip
    return render_table(title, [h for _, h, _ in _COLUMNS], body, markdown)


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m auvgw.slam.magnetic.diagnose",
                                 description=__doc__.split("\n\n")[0])  # fmt: skip
    ap.add_argument("--scenario", type=Path, required=True)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", default="default", help="e.g. density=first-half")
    ap.add_argument("--out", type=Path, help="markdown file to write")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    scn = load_scenario(args.scenario)
    v = parse_variant(args.variant)
    rows = [diagnose_run(scn, v, args.seed, i) for i in tqdm(range(args.runs), file=sys.stderr)]
    cmd = " ".join(["python -m auvgw.slam.magnetic.diagnose", *(argv or sys.argv[1:])])
    title = f"{scn.name}: {replace(v, association='known').label}, {args.runs} runs"
    text = f"Made by:\n\n```\n{cmd}\n```\n\n{format_diagnoses(title, rows)}"
    print(format_diagnoses(title, rows, markdown=False))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
