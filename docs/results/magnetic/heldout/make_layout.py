"""Writes config/scenarios/beacons_amb_layout2.json: a held-out beacon layout (issue 28).

``beacons_amb.json`` (the paper's field, vehicle, sensor, acoustic beacon and odometry) with its
20 beacons replaced by 20 new ones "distributed near the robot trajectory" as in the paper's
Sec. 3.3: uniformly random along the serpentine's arc length, up to ``OFFSET_M`` either side of
it, layout seed ``SEED`` (chosen before any run; no parameter was tuned on this layout).
Frequencies by the demodulator's plan. Run from the repository root:
``python docs/results/magnetic/heldout/make_layout.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from auvgw.slam.magnetic.demod import plan_frequencies

SEED = 1028
N_BEACONS = 20
OFFSET_M = 15.0


def main() -> None:
    root = Path(__file__).resolve().parents[4]
    base = json.loads((root / "config/scenarios/beacons_amb.json").read_text())
    wp = np.asarray(base["vehicle"]["waypoints"], float)
    seg = np.diff(wp, axis=0)
    length = np.hypot(*seg.T)
    cum = np.r_[0.0, np.cumsum(length)]
    rng = np.random.default_rng(SEED)
    s = np.sort(rng.uniform(0.0, cum[-1], N_BEACONS))
    k = np.minimum(np.searchsorted(cum, s, side="right") - 1, len(seg) - 1)
    d = seg[k] / length[k, None]
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1)
    xy = (
        wp[k]
        + d * (s - cum[k])[:, None]
        + rng.uniform(-OFFSET_M, OFFSET_M, (N_BEACONS, 1)) * normal
    )
    z = 15.0 + rng.uniform(-0.25, 0.25, N_BEACONS)
    freqs = plan_frequencies(xy)
    scn = dict(base)
    scn["name"] = "beacons_amb_layout2"
    scn["description"] = (
        "Held-out layout (issue 28): beacons_amb.json with 20 new beacons uniformly random along "
        f"the serpentine, up to {OFFSET_M:g} m either side (layout seed {SEED}). Made by "
        "docs/results/magnetic/heldout/make_layout.py."
    )
    scn["magnetic_beacons"] = [
        {"x": round(float(x), 2), "y": round(float(y), 2), "z": round(float(zz), 2),
         "moment_am2": 500.0, "frequency_hz": float(f), "axis": [0.0, 0.0, 1.0]}
        for (x, y), zz, f in zip(xy, z, freqs, strict=True)
    ]  # fmt: skip
    out = root / "config/scenarios/beacons_amb_layout2.json"
    out.write_text(json.dumps(scn, indent=2) + "\n")
    print(f"{out}: {len(xy)} beacons")


if __name__ == "__main__":
    main()
