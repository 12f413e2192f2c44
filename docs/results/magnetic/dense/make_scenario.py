"""Writes config/scenarios/beacons_dense.json (docs/slam_magnetic.md, "Dense field").

``beacons_amb_v03.json``'s vehicle, sensor, acoustic beacon model, terrain and Earth field on a
closed 200 m x 100 m rectangle (two laps), with a magnetic beacon every ``SPACING_M`` of the
route, ``OFFSET_M`` to alternate sides: each beacon is visible (25 m, 180 deg ahead) from
``sqrt(25^2 - 5^2) = 24.5 m`` ahead until abeam, so the next one comes into view before the last
passes abeam and the vehicle is never without a beacon. Frequencies: the demodulator's six
channels (1.0-8.5 Hz, 1.5 Hz apart) reused beyond ``REUSE_M`` = 2 x 25 m (no two beacons on one
channel are ever in range together; 70 m, the paper field's margin, needs 7 channels at this
spacing). Run from the repository root: ``python docs/results/magnetic/dense/make_scenario.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from auvgw.slam.magnetic.demod import plan_frequencies

SPACING_M = 20.0
OFFSET_M = 5.0
REUSE_M = 50.0
ROUTE = [(0.0, 0.0), (200.0, 0.0), (200.0, 100.0), (0.0, 100.0), (0.0, 0.0)]
SEED_DEPTH = 7


def beacons_along(route: list[tuple[float, float]], spacing: float, offset: float) -> np.ndarray:
    """Points every ``spacing`` m of arc length along the polyline (the first half a spacing in),
    ``offset`` m to its left and right in turn (NED: left of a northward leg is west)."""
    wp = np.asarray(route, float)
    seg = np.diff(wp, axis=0)
    length = np.hypot(*seg.T)
    cum = np.r_[0.0, np.cumsum(length)]
    s = np.arange(spacing / 2, cum[-1], spacing)
    k = np.searchsorted(cum, s, side="right") - 1
    d = seg[k] / length[k, None]
    along = wp[k] + d * (s - cum[k])[:, None]
    side = np.where(np.arange(len(s)) % 2 == 0, 1.0, -1.0)
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1)
    return along + offset * side[:, None] * normal


def main() -> None:
    root = Path(__file__).resolve().parents[4]
    base = json.loads((root / "config/scenarios/beacons_amb_v03.json").read_text())
    xy = beacons_along(ROUTE, SPACING_M, OFFSET_M)
    freqs = plan_frequencies(xy, n_channels=6, reuse_distance_m=REUSE_M)
    z = 15.0 + np.random.default_rng(SEED_DEPTH).uniform(-0.2, 0.2, len(xy))
    scn = dict(base)
    scn["name"] = "beacons_dense"
    scn["description"] = (
        "A dense beacon field for the beacon-density claim (docs/slam_magnetic.md, 'Dense "
        "field'): beacons_amb_v03.json's vehicle (Table 4, sigma_V 0.3 m/s) and sensor (25 m, "
        "0.1 m, 1 deg, 5 Hz, 180 deg), on a closed 200 m x 100 m rectangle flown twice, with a "
        f"beacon every {SPACING_M:g} m of route {OFFSET_M:g} m to alternate sides, so one is "
        "always in view. Made by docs/results/magnetic/dense/make_scenario.py."
    )
    scn["vehicle"] = dict(base["vehicle"], waypoints=[list(p) for p in ROUTE])
    scn["magnetic_beacons"] = [
        {"x": round(float(x), 2), "y": round(float(y), 2), "z": round(float(zz), 2),
         "moment_am2": 500.0, "frequency_hz": float(f), "axis": [0.0, 0.0, 1.0]}
        for (x, y), zz, f in zip(xy, z, freqs, strict=True)
    ]  # fmt: skip
    scn["acoustic_beacon"] = dict(base["acoustic_beacon"], x=100.0, y=50.0)
    out = root / "config/scenarios/beacons_dense.json"
    out.write_text(json.dumps(scn, indent=2) + "\n")
    print(f"{out}: {len(xy)} beacons")


if __name__ == "__main__":
    main()
