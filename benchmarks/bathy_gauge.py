"""What a relative method can correct (issue 28): each bathymetric run's trajectories kept as an
``.npz`` and scored raw and gauge-aligned, and the table over many runs.

    .venv/bin/python benchmarks/bathy_gauge.py RUN.npz [RUN.npz ...]

A heading error constant over the route turns the dead reckoning and every swath rigidly about
the known start: the map stays self-consistent and no closure can see it. So each estimate (dead
reckoning, SLAM filtered, SLAM smoothed) is also scored after the rotation about the start that
best fits it to the truth (:func:`auvgw.slam.bathymetric.evaluate.gauge_error`, yaw only), and the
*floor* is the raw error of the truth turned by dead reckoning's own fitted rotation: what a SLAM
that corrected everything else would still show (and, narrower, the truth turned by the mean
heading error on the swaths: the part that turns the track and the map alike). Ratios are
DR / SLAM (> 1: SLAM better) on three figures, raw and aligned: the final error (the filtered
estimate's last pose), the filtered RMSE and the smoothed RMSE.

The ``.npz`` files are :func:`auvgw.slam.bathymetric.evaluate.save_tracks`'s, written by
``screen_bathy_survey.py --save`` (offline: every second ping, the DR's INS heading error) and by
``auvgw demo`` as ``tracks.npz`` (end to end: every SLAM pose, the odometry's heading error).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.slam.bathymetric.evaluate import gauge_error, gauge_floor

#: the three DR / SLAM figures of the issue's bar: (name, DR's field, SLAM's field)
FIGURES = (("final", "dr_final", "filtered_final"),
           ("filtered RMSE", "dr_rmse", "filtered_rmse"),
           ("smoothed RMSE", "dr_rmse", "smoothed_rmse"))  # fmt: skip


def figures(tracks: Any) -> dict[str, float]:
    """One run's figures (m, deg) from its saved tracks (an ``np.load`` of :func:`save_tracks`'s
    file or a dict of the same arrays)."""
    truth = np.asarray(tracks["truth"], float)
    psi = np.asarray(tracks["heading_error_deg"], float)
    out = {"psi_mean_deg": float(psi.mean()), "psi_std_deg": float(psi.std())}
    for name in ("dr", "filtered", "smoothed"):
        g = gauge_error(np.asarray(tracks[name], float), truth)
        out.update({f"{name}_angle_deg": math.degrees(g.angle_rad), f"{name}_rmse": g.rmse_m,
                    f"{name}_final": g.final_m, f"{name}_al_rmse": g.aligned_rmse_m,
                    f"{name}_al_final": g.aligned_final_m})  # fmt: skip
    out["floor_rmse"], out["floor_final"] = gauge_floor(truth, math.radians(out["dr_angle_deg"]))
    # the part no closure can see at all: the swaths' mean heading error turns them and the
    # track alike (the DR's fitted yaw also holds the DVL's misalignment and the heading
    # error's changes, which turn the track and not the map)
    out["floor_psi_rmse"], out["floor_psi_final"] = gauge_floor(truth, math.radians(psi.mean()))
    # the best DR / SLAM a relative method could reach if the floor were all it kept
    for kind, fl in (("DR yaw", "floor"), ("mean heading error", "floor_psi")):
        out[f"ceiling {kind} final"] = out["dr_final"] / out[f"{fl}_final"]
        out[f"ceiling {kind} RMSE"] = out["dr_rmse"] / out[f"{fl}_rmse"]
    for label, dr, slam in FIGURES:
        out[f"raw {label}"] = out[dr] / out[slam]
        out[f"aligned {label}"] = (
            out[dr.replace("dr_", "dr_al_")] / out[slam.replace("_", "_al_", 1)]
        )
    return out


def row(name: str, f: dict[str, float]) -> str:
    """One run's table row."""
    return (f"| {name} | {f['psi_mean_deg']:+.2f} +- {f['psi_std_deg']:.2f} | "
            f"{f['dr_final']:.2f} / {f['dr_rmse']:.2f} | {f['dr_angle_deg']:+.3f} | "
            f"{f['dr_al_final']:.2f} / {f['dr_al_rmse']:.2f} | "
            f"{f['floor_final']:.2f} / {f['floor_rmse']:.2f} | "
            f"{f['floor_psi_final']:.2f} / {f['floor_psi_rmse']:.2f} | "
            f"{f['filtered_final']:.2f} / {f['filtered_rmse']:.2f} / {f['smoothed_rmse']:.2f} | "
            f"{f['smoothed_angle_deg']:+.3f} | "
            f"{f['filtered_al_final']:.2f} / {f['filtered_al_rmse']:.2f} / "
            f"{f['smoothed_al_rmse']:.2f} | "
            + " / ".join(f"{f['raw ' + lb]:.2f}" for lb, _, _ in FIGURES) + " | "
            + " / ".join(f"{f['aligned ' + lb]:.2f}" for lb, _, _ in FIGURES) + " |")  # fmt: skip


HEADER = (
    "| run | heading error on the swaths, deg (mean +- std) | DR final / RMSE | DR fitted yaw, "
    "deg | DR aligned final / RMSE | floor final / RMSE | floor of the mean heading error, final / "
    "RMSE | SLAM final / filtered / smoothed RMSE "
    "| SLAM smoothed fitted yaw, deg | SLAM aligned final / filtered / smoothed RMSE | "
    "DR / SLAM raw (final / filtered / smoothed) | DR / SLAM aligned |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|"
)

#: the summary's columns: (label, key)
SUMMARY = (("|heading error mean|, deg", "abs_psi"), ("DR final", "dr_final"),
           ("DR RMSE", "dr_rmse"), ("|DR fitted yaw|, deg", "abs_dr_angle"),
           ("DR aligned final", "dr_al_final"), ("DR aligned RMSE", "dr_al_rmse"),
           ("floor final", "floor_final"), ("floor RMSE", "floor_rmse"),
           ("floor of the mean heading error, final", "floor_psi_final"),
           ("floor of the mean heading error, RMSE", "floor_psi_rmse"),
           ("SLAM final", "filtered_final"), ("SLAM filtered RMSE", "filtered_rmse"),
           ("SLAM smoothed RMSE", "smoothed_rmse"), ("SLAM aligned final", "filtered_al_final"),
           ("SLAM aligned filtered RMSE", "filtered_al_rmse"),
           ("SLAM aligned smoothed RMSE", "smoothed_al_rmse"),
           *((f"DR / SLAM {k}", k) for k in
             [f"{kind} {lb}" for kind in ("raw", "aligned") for lb, _, _ in FIGURES]),
           *((f"DR / floor ({k.split(' ', 1)[1]})", k) for k in
             [f"ceiling {fl} {fig}" for fl in ("DR yaw", "mean heading error")
              for fig in ("final", "RMSE")]))  # fmt: skip


def summary(runs: dict[str, dict[str, float]]) -> str:
    """Mean and median of every figure over ``runs`` (name -> :func:`figures`), and how many
    runs meet 2x on each ratio (and on all three, raw and aligned); DR / floor: the ratio a
    relative method that kept only the floor would reach (below 2: the bar out of its reach)."""
    for f in runs.values():
        f["abs_psi"], f["abs_dr_angle"] = abs(f["psi_mean_deg"]), abs(f["dr_angle_deg"])
    n = len(runs)
    lines = [f"over {n} runs | mean | median | runs >= 2x |", "|---|---|---|---|"]
    for label, key in SUMMARY:
        v = np.array([f[key] for f in runs.values()])
        ratio = key.startswith(("raw", "aligned", "ceiling"))
        met = f"{int((v >= 2.0).sum())} of {n}" if ratio else ""
        lines.append(f"| {label} | {v.mean():.2f} | {np.median(v):.2f} | {met} |")
    for kind in ("raw", "aligned"):
        every = sum(all(f[f"{kind} {lb}"] >= 2.0 for lb, _, _ in FIGURES) for f in runs.values())
        lines.append(f"| DR / SLAM {kind}: all three >= 2x | | | {every} of {n} |")
    return "| " + "\n".join(lines)


def table(runs: dict[str, dict[str, float]]) -> str:
    """The per-run table and the summary."""
    return "\n".join([HEADER, *(row(k, f) for k, f in runs.items()), "", summary(runs)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+", help="the .npz files of save_tracks")
    a = ap.parse_args()
    runs = {}
    for p in a.runs:
        with np.load(p) as z:
            runs[p.stem] = figures(z)
    print(table(runs))


if __name__ == "__main__":
    main()
