"""Pool the two eq28 test sets of the same engineered filters: base seed 1000
(``eq28_engineered``, preset ``engineered``) and base seed 2000 (``eq28_s39_all``, preset
``engineered_s39``, equal to ``engineered`` key by key: s39's tuning chose the same BPSLAM
jitter, 0.1 m^2). 40 independent runs, paired within each run; writes ``pooled_s39.md``.

Run from the repository root: python docs/results/bathymetric/heldout/pool_s39.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from auvgw.slam.evaluation.heldout import paired_bootstrap_arrays

HERE = Path(__file__).resolve().parent
#: (folder, preset) per test set
SETS = (("eq28_engineered", "engineered"), ("eq28_s39_all", "engineered_s39"))
#: (base, other): ratio other / base of the final error
PAIRS = (("dr", "bpslam"), ("dr", "mtm-pf"), ("bpslam", "mtm-pf"))


def finals(folder: str, row: str) -> list[float]:
    """Final errors (m) of ``row`` in ``folder``'s runs.jsonl, by run."""
    lines = (HERE / folder / "runs.jsonl").read_text().splitlines()
    recs = sorted((json.loads(x) for x in lines if x.strip()), key=lambda r: int(r["run"]))
    return [float(r["final_error_m"]) for r in recs if r["row"] == row]


def main() -> int:
    out = [
        "Made by: `python docs/results/bathymetric/heldout/pool_s39.py` (eq28, N = 100; "
        + " and ".join(f"`{f}` ({p})" for f, p in SETS)
        + "; 95 % percentile bootstrap over the runs, 10000 resamples)",
        "",
        "| other / base | runs | base mean (m) | other mean (m) | ratio [95 % CI] "
        "| runs other lower |",
        "|---|---|---|---|---|---|",
    ]
    for base, other in PAIRS:
        b = [x for f, p in SETS for x in finals(f, f"{p}/{base}")]
        o = [x for f, p in SETS for x in finals(f, f"{p}/{other}")]
        r = paired_bootstrap_arrays(b, o)
        lo, hi = r["ratio_ci"]
        out.append(
            f"| {other} / {base} | {r['runs']} | {r['base_mean']:.2f} | {r['other_mean']:.2f} "
            f"| {r['ratio']:.3f} [{lo:.3f}, {hi:.3f}] | {r['other_better']} of {r['runs']} |"
        )
    (HERE / "pooled_s39.md").write_text("\n".join(out) + "\n")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
