"""The bathymetric held-out protocol (issue 28): named tuning and test scenarios
(:data:`SPLIT`), tuning and test seeds (``slam.evaluation.heldout``), parameter presets frozen
in a committed file before any test run (:func:`load_frozen`), and paired comparisons of final
error with bootstrap intervals (:func:`paired_rows`).

A study row is ``(preset, algorithm)`` over ``runs`` surveys; run ``i`` uses scenario
``scenarios[i % len(scenarios)]`` and the survey seed ``SeedSequence([seed, i])`` with the nav
error model ``nav`` (``simulate.DRModel``), so every row of one (seed, scenarios, nav) sees the
same surveys: the comparisons are paired run by run. With ``gauge``, each run is also scored
after the rotation about the known start that no relative method can see (:func:`gauge_fields`).
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import BathyResult, gauge_error, gauge_floor, run_filter
from auvgw.slam.bathymetric.simulate import DRModel
from auvgw.slam.bathymetric.study import _survey
from auvgw.slam.evaluation.heldout import Split, paired_bootstrap_arrays

__all__ = [
    "GAUGE_KEYS",
    "SPLIT",
    "Frozen",
    "gauge_fields",
    "load_frozen",
    "paired_rows",
    "row_config",
    "run_rows",
]

#: tuning scenarios: every bathymetric parameter before issue 28 was chosen on these (seed 0);
#: test scenarios: new terrains (and one mirrored route) made for issue 28, never tuned on
SPLIT = Split(
    tuning=("bathy_survey", "bathy_sandfield", "bathy_sandwaves", "bathy_lccd"),
    test=(
        "bathy_test_a",
        "bathy_test_b",
        "bathy_test_c",
        # claim C14: the same terrains, routes cut before the tie lines (no crossings)
        "bathy_test_a_nocross",
        "bathy_test_b_nocross",
        "bathy_test_c_nocross",
    ),
)


@dataclass(frozen=True)
class Frozen:
    """The frozen-parameter file: per preset, the ``BathyConfig`` values shared by every
    filter (``common``) and per algorithm (``per_algorithm``)."""

    presets: dict[str, dict[str, Any]]
    path: str

    def config(self, preset: str, algorithm: str, n_particles: int) -> BathyConfig:
        return row_config(self.presets, preset, algorithm, n_particles)


def row_config(
    presets: dict[str, dict[str, Any]], preset: str, algorithm: str, n_particles: int
) -> BathyConfig:
    """The ``BathyConfig`` of one row: preset ``common`` values, then the algorithm's own."""
    if preset not in presets:
        raise ValueError(f"preset {preset!r}: not one of {sorted(presets)}")
    p = presets[preset]
    vals = {**p.get("common", {}), **p.get("per_algorithm", {}).get(algorithm, {})}
    return BathyConfig.model_validate({**vals, "n_particles": n_particles})


def load_frozen(path: Path) -> Frozen:
    """Read the frozen-parameter JSON (``{"presets": {name: {"common": {...},
    "per_algorithm": {alg: {...}}}}}``); every value is checked by building its configs."""
    try:
        data = json.loads(path.read_text())
        presets = data["presets"]
        for name in presets:
            for alg in ("mtm-pf", "bpslam", "dr"):
                row_config(presets, name, alg, 100)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a frozen-parameter file: {exc}") from None
    return Frozen(presets=presets, path=str(path))


#: the per-run record fields of :func:`gauge_fields`
GAUGE_KEYS = ("gauge_yaw_deg", "gauge_final_m", "gauge_rms_m", "gauge_dr_yaw_deg",
              "gauge_floor_final_m", "gauge_floor_rms_m")  # fmt: skip


def gauge_fields(est: np.ndarray, truth: np.ndarray, dr: np.ndarray) -> dict[str, float]:
    """One run's gauge figures ((T, 2) NED m at the same pings, ``truth[0]`` the known start):
    the estimate's least-squares yaw about the start (``gauge_yaw_deg``, deg, positive from north
    towards east; :func:`~auvgw.slam.bathymetric.evaluate.yaw_about_start`), its final error and
    RMSE once turned back by it (``gauge_final_m``, ``gauge_rms_m``, m), dead reckoning's own
    fitted yaw (``gauge_dr_yaw_deg``) and the floor: the final error and RMSE of the truth turned
    by that yaw (``gauge_floor_final_m``, ``gauge_floor_rms_m``: what an estimate that corrected
    everything but DR's rotation would show, raw). ``est`` is the track the raw figures score
    (``BathyResult.final``)."""
    g = gauge_error(est, truth)
    dr_yaw = gauge_error(dr, truth).angle_rad
    floor_rms, floor_final = gauge_floor(truth, dr_yaw)
    vals = (math.degrees(g.angle_rad), g.aligned_final_m, g.aligned_rmse_m,
            math.degrees(dr_yaw), floor_final, floor_rms)  # fmt: skip
    return dict(zip(GAUGE_KEYS, vals, strict=True))


def run_rows(
    scenarios: Sequence[Scenario],
    rows: Sequence[tuple[str, str, BathyConfig]],
    runs: int,
    seed: int,
    nav: DRModel,
    purpose: Literal["tuning", "test"],
    first: int = 0,
    gauge: bool = False,
) -> Iterator[tuple[int, str, str, BathyResult]]:
    """Every run ``first .. runs-1`` through every ``(preset, algorithm, config)`` row, run by run
    (so a study cut short still holds whole runs); refuses a seed or scenario outside
    ``purpose``'s split. The filter of row ``(preset, alg)`` on run ``i`` draws from
    ``SeedSequence([seed, i, crc32(alg)])``: the same draws in every preset. ``gauge`` adds
    :func:`gauge_fields` of the result's final trajectory (the track ``final_error_m`` and
    ``rms_m`` score) to its ``extra``."""
    for s in scenarios:
        SPLIT.check(seed, s.name, purpose)
    for i in range(first, runs):
        scn = scenarios[i % len(scenarios)]
        sim, world = _survey(scn.model_dump_json(), seed, i, None, nav)
        for preset, alg, cfg in rows:
            rng = np.random.default_rng(np.random.SeedSequence([seed, i, zlib.crc32(alg.encode())]))
            res, _ = run_filter(alg, sim, cfg, rng, run=i, depth_fn=world.depth)
            if gauge:
                res.extra.update(gauge_fields(res.final, res.truth, sim.dr[: len(res.truth)]))
            yield i, preset, alg, res


def paired_rows(
    finals: dict[str, list[float]], pairs: Sequence[tuple[str, str]]
) -> list[dict[str, Any]]:
    """Paired bootstrap of final error (m) for each ``(base, other)`` pair of row names present
    in ``finals`` (row name -> final error per run, in run order), over the runs both have."""
    out = []
    for base, other in pairs:
        if base in finals and other in finals:
            n = min(len(finals[base]), len(finals[other]))
            if n >= 2:
                c = paired_bootstrap_arrays(finals[base][:n], finals[other][:n])
                out.append({"base": base, "other": other, **c})
    return out
