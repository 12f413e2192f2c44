"""The Rerun view of AMB-SLAM: the magnetic stage's real outputs (30 s of the beacons scenario fed
in-process) through the viz stage into a .rrd, read back: estimated beacons with their 2-sigma
ellipses, the acoustic beacon, the true beacons, and each window's ranges as lines from the
vehicle to where the MLP places the beacon."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from auvgw.commands.demo_parts import _true_beacons
from auvgw.config.scenario import load_scenario
from auvgw.slam.magnetic.stream import stage_inputs
from auvgw.stages.magnetic import MagneticStage, config_from_scenario
from auvgw.subscribe import slam_output
from auvgw.viz.logger import RerunLogger
from auvgw.viz.readback import read_recording
from auvgw.viz.stage import VizStage

SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "beacons_amb.json"


def _to_map(x: float, y: float) -> tuple[float, float]:
    return (y, -x)  # NED map frame: (east, -north)


def test_beacons_ellipses_ranges_and_acoustic_beacon_read_back(tmp_path: Path) -> None:
    inputs = stage_inputs(SCENARIO, 1200)  # 30 s, 150 m: the first beacon passed
    sim = inputs.prep.sim
    path = tmp_path / "amb.rrd"
    logger = RerunLogger(rrd=path)
    viz = VizStage(logger, "auv1")
    published: list[tuple[str, dict]] = []

    def on_publish(key: str, payload: bytes, t_ns: int) -> None:
        published.append((key, slam_output(payload)))
        assert viz.handle_sample(key, payload, t_ns) == "logged", key

    cfg = config_from_scenario(SCENARIO, x0=tuple(float(x) for x in sim.truth[0]))
    stage = MagneticStage(cfg, on_publish=on_publish)
    scn = load_scenario(SCENARIO)
    truth_map = json.dumps({"t": 0.0, **_true_beacons(scn)}).encode()
    assert viz.handle_sample("auv/auv1/truth/map", truth_map, 0) == "logged"
    inputs.feed(stage)
    stage.flush()
    viz.stop()
    logger.close()
    rec = read_recording(path)

    # estimated beacons: the last landmark message, its points and one ellipse per beacon
    lms = [b for k, b in published if k.endswith("/landmarks")]
    last = lms[-1]
    assert len(last["mean"]) >= 1
    est = rec["map/slam/magnetic/landmarks"]
    pts = np.array(est.values("Points2D:positions")[-1])
    assert np.allclose(pts, [_to_map(x, y) for x, y in last["mean"]], atol=1e-3)
    ell = est.values("LineStrips2D:strips")[-1]
    assert len(ell) == len(last["mean"])
    for strip, (mx, my), cov in zip(ell, last["mean"], last["cov"], strict=True):
        # a 2-sigma ellipse: every vertex at Mahalanobis distance 2 from its beacon
        s = np.array(strip)
        d = np.column_stack([-s[:, 1] - mx, s[:, 0] - my])
        m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(np.array(cov)), d)
        assert np.allclose(np.sqrt(m2), 2.0, rtol=1e-3)
    # the true beacons and the acoustic beacon
    true_pts = np.array(rec["map/truth/landmarks"].values("Points2D:positions")[-1])
    assert len(true_pts) == len(scn.magnetic_beacons)
    ab = scn.acoustic_beacon
    assert ab is not None
    acoustic = rec["map/slam/magnetic/acoustic_beacon"].values("Points2D:positions")[-1]
    assert np.allclose(acoustic, [_to_map(ab.x, ab.y)])
    assert np.allclose(rec["map/truth/acoustic_beacon"].values("Points2D:positions")[-1],
                       [_to_map(ab.x, ab.y)])  # fmt: skip
    # ranges: per window, one line per observation from the vehicle to the ranged beacon
    obs = [b for k, b in published if k.endswith("/observations")]
    assert len(obs) > 5
    by_t: dict[float, list[dict]] = {}
    for o in obs:
        by_t.setdefault(o["t"], []).append(o)
    ranges = rec["map/slam/magnetic/ranges"]
    strips = ranges.values("LineStrips2D:strips")
    assert len(strips) == len(obs)  # logged at each observation, the window's lines so far
    t_last = max(by_t)
    final = [np.array(s) for s in strips[-len(by_t[t_last]) :]][-1]
    assert len(final) == len(by_t[t_last])
    for line, o in zip(final, by_t[t_last], strict=True):
        r, b = o["z"]
        end = (o["x"] + r * math.cos(o["heading"] + b), o["y"] + r * math.sin(o["heading"] + b))
        assert np.allclose(line, [_to_map(o["x"], o["y"]), _to_map(*end)], atol=1e-3)
        assert np.isclose(math.hypot(*(line[1] - line[0])), r) and 3.0 <= r <= 25.0
