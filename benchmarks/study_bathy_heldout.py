"""The bathymetric held-out study (issue 28): rows ``preset/algorithm`` over ``--runs``
surveys (run ``i`` on scenario ``i mod len(--scenarios)``, common random numbers), the final
error of each run appended to ``OUT/runs.jsonl`` as it finishes, then ``OUT/tables.md`` and
``OUT/results.json``: per row the final error, and paired bootstrap intervals of the
differences / ratios of final error (BPSLAM vs DR, MTM-PF vs BPSLAM, literal vs engineered).

Tuning (base seed < 1000, tuning scenarios; ``--set`` allowed):

    nice -n 10 .venv/bin/python benchmarks/study_bathy_heldout.py --purpose tuning \\
        --scenarios bathy_survey --rows literal/bpslam --runs 2 --seed 0 \\
        --set bpslam_sigma_c2=0.1 --out /tmp/tune

Test (base seed >= 1000, test scenarios, parameters from the committed frozen file only):

    nice -n 10 .venv/bin/python benchmarks/study_bathy_heldout.py --purpose test \\
        --scenarios bathy_test_a,bathy_test_b,bathy_test_c --nav eq28 \\
        --rows engineered/mtm-pf,engineered/bpslam,engineered/dr --runs 20 --seed 1000 \\
        --out docs/results/bathymetric/heldout/eq28_engineered

``--report`` rebuilds the tables from ``OUT/runs.jsonl`` (a study cut short reports its whole
runs).

``--gauge`` also scores every run after the rotation about the known start that no relative
method can see (``heldout.gauge_fields``: each estimate's fitted yaw, its aligned final error and
RMSE, dead reckoning's fitted yaw and the floor it leaves); the report then adds the aligned
columns and the paired ratios on them beside the raw ones. The same alignment (each track's own
least-squares yaw about the start) is applied to every row alike, DR included.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.heldout import GAUGE_KEYS, SPLIT, load_frozen, paired_rows
from auvgw.slam.bathymetric.simulate import NAV_MODELS, DRModel
from auvgw.slam.evaluation.heldout import seed_split

FROZEN = Path("docs/results/bathymetric/heldout/frozen.json")


def _git_rev(path: Path) -> str:
    """The last commit of ``path``, or '' (uncommitted: refused for a test run)."""
    out = subprocess.run(
        ["git", "log", "-1", "--format=%h", "--", str(path)], capture_output=True, text=True
    )
    dirty = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", str(path)]).returncode
    return out.stdout.strip() if dirty == 0 else ""


def report(out: Path) -> None:
    """tables.md and results.json from OUT/runs.jsonl and OUT/meta.json."""
    meta = json.loads((out / "meta.json").read_text())
    recs = [json.loads(x) for x in (out / "runs.jsonl").read_text().splitlines() if x.strip()]
    rows = meta["rows"]
    by: dict[str, dict[int, dict[str, Any]]] = {r: {} for r in rows}
    for r in recs:
        by[r["row"]][r["run"]] = r
    whole = sorted(set.intersection(*(set(v) for v in by.values()))) if by else []
    finals = {r: [by[r][i]["final_error_m"] for i in whole] for r in rows}
    lines = [
        "Made by:", "", "```", meta["command"], "```", "",
        f"**Split: {meta['purpose']}.** Base seed {meta['seed']} ({seed_split(meta['seed'])} "
        f"seeds; test seeds are >= 1000), scenarios {', '.join(meta['scenarios'])} (run i on "
        f"scenario i mod {len(meta['scenarios'])}; tuning scenarios: {', '.join(SPLIT.tuning)}; "
        f"test scenarios: {', '.join(SPLIT.test)}), nav error model **{meta['nav']}**, N = "
        f"{meta['particles']}, {len(whole)} whole runs of {meta['runs']}. Parameters: "
        f"{meta['params']}. Common random numbers: run i of every row is the same survey and "
        "DR; 95 % intervals are percentile bootstraps (10000 resamples of the runs).", "",
        "| row | runs | final error mean +- std (m) | median | max | RMS of final trajectory (m) "
        "| resamplings / closures accepted per run | filter s per run |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in rows:
        rs = [by[r][i] for i in whole]
        if not rs:
            continue
        fe = np.array([x["final_error_m"] for x in rs])
        lines.append(
            f"| {r} | {len(rs)} | {fe.mean():.2f} +- {fe.std():.2f} | {np.median(fe):.2f} | "
            f"{fe.max():.2f} | {np.mean([x['rms_m'] for x in rs]):.2f} | "
            f"{np.mean([x['resamplings'] for x in rs]):.1f} / "
            f"{np.mean([x['loops_accepted'] for x in rs]):.1f} | "
            f"{np.mean([x['runtime_s'] for x in rs]):.1f} |"
        )
    scns = meta["scenarios"]
    if len(scns) > 1 and whole:
        lines += ["", "Final error by test scenario, mean (m) over its runs:", "",
                  "| row | " + " | ".join(scns) + " |", "|---|" + "---|" * len(scns)]  # fmt: skip
        for r in rows:
            cells = []
            for k in range(len(scns)):
                fe = [by[r][i]["final_error_m"] for i in whole if i % len(scns) == k]
                cells.append(f"{np.mean(fe):.2f} ({len(fe)})" if fe else "-")
            lines.append(f"| {r} | " + " | ".join(cells) + " |")
    keys = ("spread_before_m", "spread_lag1_m", "spread_lag10_m", "spread_lag30_m",
            "spread_lag100_m")  # fmt: skip
    lags = [k for k in keys if any(k in by[r].get(i, {}) for r in rows for i in whole)]
    if lags:
        lines += ["", "Cloud spread (m, RMS distance of the particles from their weighted "
                  "centre) just before and L pings after each resampling (MTM-PF: each accepted "
                  "closure), mean over the resamplings of a run, then over the runs (claim C4, "
                  "Fig. 11):", "", "| row | " + " | ".join(lags) + " |",
                  "|---|" + "---|" * len(lags)]  # fmt: skip
        for r in rows:
            vals = [[v for i in whole if (v := by[r][i].get(k, np.nan)) == v] for k in lags]
            if any(vals):  # rows without the log (older studies) are left out
                cells = [f"{np.mean(v):.2f}" if v else "-" for v in vals]
                lines.append(f"| {r} | " + " | ".join(cells) + " |")
    pairs = []
    for p in sorted({r.split("/")[0] for r in rows}):
        pairs += [(f"{p}/dr", f"{p}/bpslam"), (f"{p}/bpslam", f"{p}/mtm-pf")]
    pairs += [("engineered/dr", f"{p}/bpslam") for p in ("literal", "engineered_nodrift")]
    pairs += [
        ("engineered/dr", f"{p}/mtm-pf") for p in ("literal", "engineered", "engineered_nodrift")
    ]
    for a in ("bpslam", "mtm-pf"):
        pairs.append((f"literal/{a}", f"engineered/{a}"))
    pairs.append(("engineered_nodrift/mtm-pf", "engineered/mtm-pf"))
    for p in sorted({r.split("/")[0] for r in rows} - {"engineered", "literal"}):
        # ablations, claims, other drift models: against the engineered rows
        pairs += [(f"engineered/{a}", f"{p}/{a}") for a in ("mtm-pf", "bpslam")]
        pairs += [("engineered/bpslam", f"{p}/mtm-pf"), ("engineered/dr", f"{p}/mtm-pf")]
    pairs = list(dict.fromkeys(pairs))
    comp = paired_rows(finals, pairs)
    rms = {r: [by[r][i]["rms_m"] for i in whole] for r in rows}
    comp_rms = paired_rows(rms, pairs)
    lines += _paired_lines("final error", comp)
    lines += _paired_lines("RMS error of the final trajectory", comp_rms)
    gauge: dict[str, Any] = {}
    if whole and all(k in by[r][i] for r in rows for i in whole for k in GAUGE_KEYS):
        gauge = _gauge_lines(by, rows, whole, pairs, lines)
    (out / "tables.md").write_text("\n".join(lines) + "\n")
    (out / "results.json").write_text(
        json.dumps(
            {
                "meta": meta,
                "runs": whole,
                "finals": finals,
                "rms": rms,
                "paired": comp,
                "paired_rms": comp_rms,
                **gauge,
            },
            indent=1,
        )
    )
    print("\n".join(lines))


def _paired_lines(what: str, cs: list[dict[str, Any]]) -> list[str]:
    """The paired table of ``paired_rows``' comparisons ``cs`` (figure ``what``, m); none
    without comparisons."""
    if not cs:
        return []
    lines = [
        "", f"Paired {what}, other vs base:", "",
        "| other vs base | base mean (m) | other mean (m) | difference (m) [95 % CI] | "
        "ratio of means [95 % CI] | runs other lower |", "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for c in cs:
        lines.append(
            f"| {c['other']} vs {c['base']} | {c['base_mean']:.2f} | {c['other_mean']:.2f} "
            f"| {c['diff']:+.2f} [{c['diff_ci'][0]:+.2f}, {c['diff_ci'][1]:+.2f}] | "
            f"{c['ratio']:.3f} [{c['ratio_ci'][0]:.3f}, {c['ratio_ci'][1]:.3f}] | "
            f"{c['other_better']} of {c['runs']} |"
        )
    return lines


def _gauge_lines(
    by: dict[str, dict[int, dict[str, Any]]],
    rows: list[str],
    whole: list[int],
    pairs: list[tuple[str, str]],
    lines: list[str],
) -> dict[str, Any]:
    """Append the ``--gauge`` tables to ``lines`` (raw beside aligned per row, DR's fitted yaw
    and floor, paired ratios on the aligned final error and RMSE); return them for
    results.json."""

    def col(r: str, k: str) -> np.ndarray:
        return np.array([by[r][i][k] for i in whole], dtype=float)

    first = by[rows[0]]
    dr_yaw = np.array([first[i]["gauge_dr_yaw_deg"] for i in whole])
    fl_fin = np.array([first[i]["gauge_floor_final_m"] for i in whole])
    fl_rms = np.array([first[i]["gauge_floor_rms_m"] for i in whole])
    dr_row = next((r for r in rows if r.endswith("/dr")), None)
    dr_fin = col(dr_row, "final_error_m") if dr_row else np.full(len(whole), np.nan)
    lines += [
        "", "Gauge (issue 28): each row's track (the one the raw figures score) turned back by "
        "its own least-squares yaw about the known start, every row alike; the floor is the "
        "truth turned by DR's fitted yaw (what an estimate that corrected everything else would "
        f"still show). DR's fitted yaw: median {np.median(dr_yaw):+.3f} deg, range "
        f"[{dr_yaw.min():+.3f}, {dr_yaw.max():+.3f}], mean |yaw| {np.abs(dr_yaw).mean():.3f} deg; "
        f"floor final error mean {fl_fin.mean():.2f} m (median {np.median(fl_fin):.2f}), "
        f"floor RMSE mean {fl_rms.mean():.2f} m. Floor / DR's raw final error, ratio of means "
        f"{fl_fin.mean() / dr_fin.mean():.3f} (the raw ratio to DR of an estimate that corrected "
        f"everything but DR's fitted rotation); floor above 0.5 x DR's raw final error in "
        f"{int((fl_fin > 0.5 * dr_fin).sum())} of {len(whole)} runs.", "",
        "| row | final error raw / aligned, mean (m) | median raw / aligned | RMSE raw / aligned, "
        "mean (m) | fitted yaw median [range] (deg) | yaw against DR's: r, slope |",
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in rows:
        fe, fa, yaw = col(r, "final_error_m"), col(r, "gauge_final_m"), col(r, "gauge_yaw_deg")
        fit = (f"{np.corrcoef(dr_yaw, yaw)[0, 1]:.2f}, {np.polyfit(dr_yaw, yaw, 1)[0]:.2f}"
               if len(whole) > 2 and dr_yaw.std() > 0 and yaw.std() > 0 else "-")  # fmt: skip
        lines.append(
            f"| {r} | {fe.mean():.2f} / {fa.mean():.2f} | {np.median(fe):.2f} / "
            f"{np.median(fa):.2f} | {col(r, 'rms_m').mean():.2f} / "
            f"{col(r, 'gauge_rms_m').mean():.2f} | {np.median(yaw):+.3f} "
            f"[{yaw.min():+.3f}, {yaw.max():+.3f}] | {fit} |"
        )
    al_fin = {r: col(r, "gauge_final_m").tolist() for r in rows}
    al_rms = {r: col(r, "gauge_rms_m").tolist() for r in rows}
    comp, comp_rms = paired_rows(al_fin, pairs), paired_rows(al_rms, pairs)
    lines += _paired_lines("aligned final error", comp)
    lines += _paired_lines("aligned RMS error of the final trajectory", comp_rms)
    return {"gauge": {"aligned_final": al_fin, "aligned_rms": al_rms, "dr_yaw_deg":
                      dr_yaw.tolist(), "paired": comp, "paired_rms": comp_rms}}  # fmt: skip


def merge(dirs: list[Path], out: Path) -> None:
    """OUT/meta.json and OUT/runs.jsonl joining studies of the same surveys (seed, scenarios,
    nav model and N equal; rows differ), so their rows are paired run by run."""
    metas = [json.loads((d / "meta.json").read_text()) for d in dirs]
    keys = ("purpose", "seed", "scenarios", "nav", "particles")
    if any(tuple(m[k] for k in keys) != tuple(metas[0][k] for k in keys) for m in metas):
        raise SystemExit(f"--merge: {', '.join(map(str, dirs))} are not the same surveys")
    meta = {**metas[0], "rows": [r for m in metas for r in m["rows"]]}
    meta["command"] = "\n".join(m["command"] for m in metas)
    meta["params"] = "; ".join(dict.fromkeys(m["params"] for m in metas))
    meta["runs"] = min(m["runs"] for m in metas)
    out.mkdir(parents=True, exist_ok=True)
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    (out / "runs.jsonl").write_text("".join((d / "runs.jsonl").read_text() for d in dirs))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--purpose", choices=("tuning", "test"), required=True)
    ap.add_argument("--scenarios", default="bathy_survey")
    ap.add_argument("--nav", choices=NAV_MODELS, default="eq28")
    ap.add_argument("--rows", default="engineered/mtm-pf,engineered/bpslam,engineered/dr")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--frozen", type=Path, default=FROZEN)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--report", action="store_true", help="only rebuild the tables")
    ap.add_argument(
        "--gauge",
        action="store_true",
        help="also score each run aligned by its fitted yaw about the start (heldout.gauge_fields)",
    )
    ap.add_argument(
        "--resume",
        action="store_true",
        help="keep OUT/runs.jsonl's whole runs (same command) and run only the ones after them",
    )
    ap.add_argument(
        "--merge", default="", help="DIR,DIR,...: one table of studies of the same surveys"
    )
    args = ap.parse_args()
    if args.merge:
        merge([Path(d) for d in args.merge.split(",")], args.out)
    if args.report or args.merge:
        report(args.out)
        return 0
    frozen = load_frozen(args.frozen)
    rev = _git_rev(args.frozen)
    if args.purpose == "test" and (args.set or not rev):
        print(f"{args.frozen}: a test run takes only the committed frozen parameters "
              "(commit the file; no --set)", file=sys.stderr)  # fmt: skip
        return 2
    extra = dict(kv.split("=", 1) for kv in args.set)
    rows = []
    for name in args.rows.split(","):
        preset, alg = name.split("/")
        cfg = frozen.config(preset, alg, args.particles)
        if extra:
            cfg = BathyConfig.model_validate({**cfg.model_dump(), **extra})
        rows.append((preset, alg, cfg))
    scns = [load_scenario(f"config/scenarios/{n}.json") for n in args.scenarios.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    first, kept = 0, ""
    if args.resume and (args.out / "runs.jsonl").exists():
        old = json.loads((args.out / "meta.json").read_text())
        if (old["rows"] != [f"{p}/{a}" for p, a, _ in rows] or old["seed"] != args.seed
                or old.get("gauge", False) != args.gauge):  # fmt: skip
            print(f"--resume: {args.out} holds other rows, another seed or another --gauge",
                  file=sys.stderr)  # fmt: skip
            return 2
        recs = [json.loads(x) for x in (args.out / "runs.jsonl").read_text().splitlines() if x]
        done = [sum(r["run"] == i for r in recs) == len(rows) for i in range(args.runs)]
        first = done.index(False) if False in done else args.runs
        kept = "".join(json.dumps(r) + "\n" for r in recs if r["run"] < first)
    meta = {
        "command": " ".join(["python", *sys.argv]), "purpose": args.purpose, "seed": args.seed,
        "scenarios": [s.name for s in scns], "nav": args.nav, "particles": args.particles,
        "runs": args.runs, "rows": [f"{p}/{a}" for p, a, _ in rows], "gauge": args.gauge,
        "params": f"{args.frozen} at commit {rev or 'UNCOMMITTED'}"
        + (f", with {' '.join(args.set)}" if args.set else ""),
    }  # fmt: skip
    from auvgw.slam.bathymetric.heldout import run_rows

    if first:
        meta["command"] = f"{old['command']}\n{meta['command']}  # runs {first}-"
        if meta["params"] not in old["params"]:  # the frozen file moved on (presets added)
            meta["params"] = (
                f"{old['params']} (runs 0-{first - 1}); {meta['params']} (runs {first}-)"
            )
        else:
            meta["params"] = old["params"]
    (args.out / "meta.json").write_text(json.dumps(meta, indent=1))
    with open(args.out / "runs.jsonl", "w") as fh:
        fh.write(kept)
        fh.flush()  # a study stopped in its first new run keeps the runs it resumed from
        t0 = time.time()
        nav = DRModel(kind=args.nav)
        for i, preset, alg, res in run_rows(
            scns, rows, args.runs, args.seed, nav, args.purpose, first, args.gauge
        ):
            rec = {
                "run": i, "row": f"{preset}/{alg}", "scenario": scns[i % len(scns)].name,
                "final_error_m": res.final_error_m, "rms_m": res.rms_m,
                "runtime_s": res.runtime_s, "loops_accepted": res.loops_accepted,
                "resamplings": res.extra.get("resamplings", 0.0),
                **{k: v for k, v in res.extra.items() if k.startswith(("spread_", "gauge_"))},
            }  # fmt: skip
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            print(f"{time.time() - t0:7.0f}s run {i} {preset}/{alg}: "
                  f"{res.final_error_m:.2f} m ({res.runtime_s:.0f} s)", flush=True)  # fmt: skip
    report(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
