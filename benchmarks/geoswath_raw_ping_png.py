"""Draw the last GeoSwath raw ping of each side, as a recording's Rerun view shows it, to a PNG.

    .venv/bin/python benchmarks/geoswath_raw_ping_png.py RRD [--device geoswath] [--out F.png]

Reads ``raw_ping/<device>/{port,starboard}`` back from the ``.rrd`` (``auvgw demo --scenario
survey --multibeam geoswath`` writes one): x the return angle (deg, port negative), y the slant
range (m, down), each sample in the colour the recording gave it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from auvgw.viz.entities import raw_ping_path
from auvgw.viz.readback import read_recording


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rrd", type=Path)
    ap.add_argument("--device", default="geoswath")
    ap.add_argument("--out", type=Path, default=Path("raw_ping.png"))
    args = ap.parse_args()
    rec = read_recording(args.rrd)
    fig, ax = plt.subplots(figsize=(8, 5))
    for side in (0, 1):
        rows = rec.get(raw_ping_path(args.device, side))
        if rows is None or not len(rows.times):
            raise SystemExit(f"{args.rrd}: no raw ping of side {side} for {args.device}")
        xy = np.asarray(rows.values("Points2D:positions")[-1], dtype=np.float64)
        c = np.asarray(rows.values("Points2D:colors")[-1], dtype=np.uint32)  # RGBA packed
        rgb = np.stack([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255], axis=1) / 255.0
        ax.scatter(xy[:, 0], xy[:, 1], c=rgb, s=2)
    ax.set_facecolor("black")
    ax.invert_yaxis()
    ax.set_xlabel("return angle (deg from the vertical, port < 0)")
    ax.set_ylabel("slant range (m)")
    ax.set_title(f"{args.rrd.name}: the last raw ping of each side")
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
