"""An emulated GeoSwath survey processed into swaths and scored against the true terrain: shared
by tests/test_geoswath_processing.py (a short stretch) and benchmarks/geoswath_accuracy.py (the
long run whose numbers are in docs/results/geoswath/)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import Scenario, load_scenario
from auvgw.drivers import kongsberg
from auvgw.drivers.geoswath import default_codec
from auvgw.ground.paths import config_file
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.geoswath import GeoSwathEmulator
from auvgw.sim_devices.vehicle import Truth, simulate
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.swath_processing import SwathProcessing, SwathProcessor


@dataclass
class SurveyResult:
    """Per swath (rows) and across-track bin (columns): ``error`` (processed minus true seabed
    depth, m; NaN: empty bin), ``water_depth`` (true, m), ``across`` (bin centre, m), and the
    altitude of each swath (m); ``pings`` processed, ``swaths`` the XYZ 88 messages."""

    error: np.ndarray
    water_depth: np.ndarray
    across: np.ndarray
    altitude: np.ndarray
    pings: int
    swaths: list[kongsberg.XYZ88]
    dropped: dict[str, int]


@functools.cache
def _survey() -> tuple[Scenario, World, Truth]:
    """config/scenarios/survey.json, its world and route (simulated once per process: 1.7 s)."""
    scn = load_scenario(config_file("scenarios/survey.json"))
    world = World.from_scenario(scn)
    return scn, world, simulate(scn, world)


def survey_context(tmp: Path, options: dict[str, Any] | None = None) -> GeoSwathEmulator:
    """The GeoSwath emulator on config/scenarios/survey.json (``options``: its device options)."""
    scn, world, truth = _survey()
    data = scn.model_dump()
    data["devices"]["geoswath"] = {"enabled": True, "options": options or {}}
    ctx = SimContext(Scenario.model_validate(data), world, truth, SimClock(0), tmp / "ports")
    return GeoSwathEmulator(ctx)


def run_survey(
    em: GeoSwathEmulator, start_s: float, duration_s: float, cfg: SwathProcessing | None = None
) -> SurveyResult:
    """Ping from ``start_s`` for ``duration_s`` (vehicle time), process every ping through the
    wire (encode, decode) and score each binned sounding against the terrain under it (placed
    with the true pose at the swath's time)."""
    cfg = cfg or SwathProcessing(frequency_hz=em.frequency)
    codec = default_codec()
    proc = SwathProcessor(cfg)
    swaths: list[kongsberg.XYZ88] = []
    n = int(duration_s * em.rate_hz)
    try:
        for k in range(n):
            for datagram in em.prepare(start_s + k / em.rate_hz):
                swaths += proc.add(codec.decode_ping(datagram))
        swaths += proc.flush()
    finally:
        em.close()
    rows, depths, alts = [], [], []
    for m in swaths:
        s = em.truth(m.device_time - em.ctx.epoch)
        b = m.beams
        ch, sh = math.cos(m.heading), math.sin(m.heading)
        x = s.x + np.asarray(b.along, float) * ch - np.asarray(b.across, float) * sh
        y = s.y + np.asarray(b.along, float) * sh + np.asarray(b.across, float) * ch
        true = np.asarray(em.ctx.world.depth(x, y), float)
        est = np.asarray(b.depth, float) + m.transducer_depth
        rows.append(np.where(b.valid, est - true, math.nan))
        depths.append(np.where(b.valid, true, math.nan))
        alts.append(s.altitude)
    nb = cfg.n_bins
    centres = (np.arange(nb) + 0.5) / nb * 2.0 - 1.0  # in half-swaths
    return SurveyResult(
        error=np.array(rows).reshape(-1, nb),
        water_depth=np.array(depths).reshape(-1, nb),
        across=centres,
        altitude=np.array(alts),
        pings=proc.pings,
        swaths=swaths,
        dropped=dict(proc.dropped),
    )


def within(res: SurveyResult, frac: float = 0.01, centre: float = 0.8) -> tuple[float, int]:
    """Share of the binned soundings of the swath's centre ``centre`` (of its width) whose
    error is within ``frac`` of the water depth, and their count."""
    cols = np.abs(res.across) <= centre
    e, d = res.error[:, cols], res.water_depth[:, cols]
    ok = ~np.isnan(e)
    return float(np.mean(np.abs(e[ok]) <= frac * d[ok])), int(ok.sum())
