"""The bathymetric SLAM against dead reckoning end to end, on the emulated survey (issues 28,
31, 33): ``auvgw demo --scenario survey --processes`` (emulators, gateway, fusion, swath stage,
bathymetric stage, each its own OS process; the whole 1812 s route at 10x) once per seed and
multibeam, one run after the other, and a table of what each demo's ``summary.json`` says.

    nice -n 10 .venv/bin/python benchmarks/study_bathy_e2e.py [--seeds 1000 1001]
        [--multibeam xyz88 geoswath] [--purpose test] [--speed 10] [--out out/study_bathy_e2e]
        [--viz]

Seeds are the scenario's emulator seeds (``auvgw demo --seed``): ``--purpose test`` (default)
takes only held-out seeds (>= 1000), ``--purpose tuning`` only tuning seeds (below 1000), as
:mod:`auvgw.slam.evaluation.heldout` rules. The demo's bathymetric settings
(``auvgw.commands.bathy_run.DEMO_FILTER``) are what is measured; nothing here changes them.

Columns (metres, horizontal, against the emulator's ground truth): dead reckoning (the fusion
odometry, scored at the SLAM's pose times: the same instants) final error and RMSE; the SLAM
*filtered* estimate (each pose as the stage published it) final and RMSE; the *smoothed*
trajectory's RMSE (mtm-pf's mean trajectory after every accepted closure, published once at
the end); closures accepted / rejected and the vehicle time
of the first; DR / SLAM ratios (> 1: SLAM better); the fusion's INS gaps and INS clock resets
(a host too loaded to pace the emulators: each reset moves the INS clock forward by the lag,
and dead reckoning coasts over the gap). ``--viz`` keeps the Rerun recording (off by
default: it only loads the machine). Issue 28's gauge: each run's ``tracks.npz`` (the demo's,
every published pose) scored raw and after the best rotation about the start, printed as
``bathy_gauge``'s table at the end.
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
from bathy_gauge import figures, table
from study_bathy_heldout import _git_rev

from auvgw.slam.evaluation.heldout import seed_split

#: --multibeam name here -> ``auvgw demo --multibeam``
MULTIBEAMS = {"xyz88": "kongsberg", "geoswath": "geoswath"}


#: runs the demo with ``DEMO_FILTER`` updated from the JSON object in argv[1] (``--set``): the
#: demo hands its settings to the stage process (``slam run --set``)
PATCHED_DEMO = (
    "import json, sys; import auvgw.commands.bathy_run as d; "
    "d.DEMO_FILTER.update(json.loads(sys.argv.pop(1))); "
    "from auvgw.cli import main; sys.exit(main())"
)


def parse_sets(sets: list[str]) -> dict[str, Any]:
    """``key=json`` pairs (``radius_m=90``) as a dict of filter settings."""
    out: dict[str, Any] = {}
    for kv in sets:
        key, sep, value = kv.partition("=")
        if not sep:
            raise SystemExit(f"--set {kv}: expected key=value")
        out[key] = json.loads(value)
    return out


def run_one(
    out: Path,
    seed: int,
    multibeam: str,
    speed: float,
    viz: bool,
    scenario: str = "survey",
    sets: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One demo run; its summary.json, or ``{"error": ...}`` when it failed. ``sets``: filter
    settings over the demo's ``DEMO_FILTER`` (tuning runs)."""
    out.mkdir(parents=True, exist_ok=True)
    head = [sys.executable, "-c", PATCHED_DEMO, json.dumps(sets)] if sets else [
        sys.executable, "-m", "auvgw"]  # fmt: skip
    argv = [*head, "demo", "--scenario", scenario, "--processes",
            "--multibeam", MULTIBEAMS[multibeam], "--seed", str(seed), "--out", str(out),
            "--speed", str(speed), *([] if viz else ["--no-viz"])]  # fmt: skip
    t0 = time.monotonic()
    with open(out / "demo.log", "wb") as log:
        code = subprocess.run(argv, stdout=log, stderr=subprocess.STDOUT).returncode
    summary_path = out / "summary.json"
    if code != 0 or not summary_path.is_file():
        return {"error": f"exit {code}, see {out / 'demo.log'}", "wall_s": time.monotonic() - t0}
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    return summary


def row(seed: int, multibeam: str, s: dict[str, Any]) -> str:
    """One table row from a demo summary."""
    if "error" in s:
        return f"| {seed} | {multibeam} | {s['error']} |"
    nav = s["navigation"]
    # dead reckoning at the SLAM's pose times (summaries before it: at its own samples, whose
    # last came up to 1.2 s after the SLAM's last pose)
    dr = nav.get("dead_reckoning_at_slam") or nav["dead_reckoning"]
    flt, smo = nav["slam"], nav.get("slam_smoothed")
    slam = s.get("slam") or {}
    closures = nav.get("closures_vehicle_s") or []
    first = f"{closures[0]:.0f}" if closures else "-"
    smo_rmse = smo["rmse_m"] if smo else float("nan")
    fusion = s.get("fusion") or {}
    gaps = (fusion.get("filter") or {}).get("ins_gaps", "-")
    resets = ((fusion.get("clocks") or {}).get("ins") or {}).get("resets", "-")
    buf = fusion.get("buffer") or {}
    compass = ((fusion.get("diagnostics") or {}).get("compass_deviation") or {}).get("applied")
    return (
        f"| {seed} | {multibeam} | {dr['final_m']:.2f} | {dr['rmse_m']:.2f} | "
        f"{flt['final_m']:.2f} | {flt['rmse_m']:.2f} | {smo_rmse:.2f} | "
        f"{slam.get('loops_accepted', 0)} / {slam.get('loops_rejected', 0)} | {first} | "
        f"{dr['final_m'] / flt['final_m']:.2f} | {dr['rmse_m'] / flt['rmse_m']:.2f} | "
        f"{dr['rmse_m'] / smo_rmse:.2f} | {gaps} / {resets} | {buf.get('ins_duplicate', '-')} / "
        f"{buf.get('aiding_late', '-')} | {'yes' if compass else 'no'} | {s['wall_s']:.0f} |"
    )


HEADER = (
    "| seed | multibeam | DR final | DR RMSE | SLAM filtered final | SLAM filtered RMSE | "
    "SLAM smoothed RMSE | closures acc / rej | first closure (vehicle s) | DR/SLAM final | "
    "DR/SLAM RMSE filtered | DR/SLAM RMSE smoothed | INS gaps / clock resets | "
    "INS duplicates / DVL aiding_late | compass deviation applied | wall s |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001])
    ap.add_argument("--multibeam", nargs="+", choices=sorted(MULTIBEAMS),
                    default=["xyz88", "geoswath"])  # fmt: skip
    ap.add_argument("--purpose", choices=("test", "tuning"), default="test")
    ap.add_argument("--out", type=Path, default=Path("out/study_bathy_e2e"))
    ap.add_argument("--speed", type=float, default=10.0,
                    help="x real time (the demo's 10; a loaded machine needs less: at 10x with "
                    "a load average of 16 on 2 cores the fusion lost INS frames and dead "
                    "reckoning ended 211 m off)")  # fmt: skip
    ap.add_argument("--viz", action="store_true", help="keep each run's Rerun recording")
    ap.add_argument("--scenario", default="survey", help="shipped scenario name or JSON file")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=JSON",
                    help="a filter setting over the demo's DEMO_FILTER (tuning runs only)")
    ap.add_argument("--frozen", nargs=2, metavar=("FILE", "VARIANT"),
                    help="settings over DEMO_FILTER: VARIANT of a committed JSON file of "
                    "variants (screen_bathy_survey.py --frozen's); test runs too")  # fmt: skip
    a = ap.parse_args()
    sets = parse_sets(a.sets)
    if sets and a.purpose != "tuning":
        ap.error("--set: settings are tuned on tuning seeds only; freeze them in the demo")
    if a.frozen:
        if sets:
            ap.error("--frozen and --set: one or the other")
        path = Path(a.frozen[0])
        rev = _git_rev(path)
        if not rev:
            ap.error(f"--frozen {path}: not committed (freeze the settings first)")
        sets = json.loads(path.read_text())[a.frozen[1]]
        print(f"frozen settings: {path} [{a.frozen[1]}] at commit {rev}: {sets}", flush=True)
    wrong = [s for s in a.seeds if seed_split(s) != a.purpose]
    if wrong:
        ap.error(f"--purpose {a.purpose}: seeds {wrong} are not {a.purpose} seeds (test >= 1000)")
    rows = []
    gauged: dict[str, dict[str, float]] = {}
    for seed in a.seeds:
        for mb in a.multibeam:
            s = run_one(a.out / f"{mb}-{seed}", seed, mb, a.speed, a.viz, a.scenario, sets)
            rows.append(row(seed, mb, s))
            print(rows[-1], flush=True)
            tracks = a.out / f"{mb}-{seed}" / "tracks.npz"
            if "error" not in s and tracks.is_file():
                with np.load(tracks) as z:
                    gauged[f"{mb}-{seed}"] = figures(z)
    print(f"\nauvgw demo --scenario {a.scenario} --processes --speed {a.speed:g}, {a.purpose} "
          f"seeds {a.seeds}, settings {sets or 'of the demo'}; metres")  # fmt: skip
    print(HEADER)
    print("\n".join(rows))
    if gauged:
        print("\nthe gauge (tracks.npz; m, deg):")
        print(table(gauged))


if __name__ == "__main__":
    main()
