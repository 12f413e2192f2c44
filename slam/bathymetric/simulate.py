"""Bathymetric survey runs generated up front from a scenario: truth at every ping, the paper's
synthetic dead reckoning (eq. 28) and multibeam swaths sampled from the scenario's terrain.

Frames: NED metres, x north, y east, depths positive down; headings radians from north towards
east. A swath is stored as horizontal offsets from the vehicle (NED, already rotated by the
measured heading: the paper treats heading and attitude as error-free, A30) and the measured
seabed depth of each sounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.multibeam import DEFAULT_NOISE
from auvgw.sim_devices.vehicle import simulate as simulate_truth
from auvgw.sim_devices.world import World

__all__ = ["BathyRun", "DRModel", "simulate_survey", "swath_offsets"]


@dataclass(frozen=True)
class DRModel:
    """The paper's synthetic dead reckoning, eq. (28): per DR step and per axis,
    ``x_DR(t) = x_DR(t-1) + x_true(t) - x_true(t-1) + N(bias_m, sigma_m^2)`` (A21: both axes,
    one step per ping at 1 Hz)."""

    bias_m: float = 0.012  # m_e, eq. (28)
    sigma_m: float = 0.01  # sigma_e, eq. (28)


@dataclass
class BathyRun:
    """One simulated survey, ``T`` pings of ``B`` soundings.

    ``truth`` (T, 2) and ``dr`` (T, 2) horizontal positions (m); ``heading`` (T,) rad;
    ``offsets`` (T, B, 2) NED offsets of the soundings from the vehicle (m); ``depth`` (T, B)
    measured seabed depths (m, down); ``t`` (T,) s."""

    t: np.ndarray
    truth: np.ndarray
    dr: np.ndarray
    heading: np.ndarray
    offsets: np.ndarray
    depth: np.ndarray
    name: str = ""
    meta: dict[str, float] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.truth, axis=0), axis=1).sum())

    def controls(self) -> np.ndarray:
        """DR displacements between consecutive pings, (T-1, 2) m: the filters' u_t."""
        return np.diff(self.dr, axis=0)


def swath_offsets(heading: np.ndarray, across: np.ndarray) -> np.ndarray:
    """NED offsets (T, B, 2) of soundings at ``across`` (B,) metres to starboard of a vehicle
    heading ``heading`` (T,) rad."""
    stbd = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)  # (T, 2)
    return across[None, :, None] * stbd[:, None, :]


def simulate_survey(
    scn: Scenario,
    rng: np.random.Generator,
    dr: DRModel | None = None,
    max_pings: int | None = None,
    world: World | None = None,
) -> BathyRun:
    """Truth, eq. (28) DR and swaths for ``scn``, noise from ``rng``.

    Pings at ``devices.multibeam.rate_hz`` (default 1 Hz); ``options.n_beams`` (default 141)
    soundings equidistant across ``options.swath_factor`` (default 4) x the nominal water depth
    below the transducer; each sounding is the terrain depth at its footprint plus the
    emulator's noise ``sqrt(depth_m^2 + (range_frac r)^2)`` (devices.multibeam.noise). The
    footprint is the vertical projection of the beam (straight rays, no refraction)."""
    world = world if world is not None else World.from_scenario(scn)
    tr = simulate_truth(scn, world)
    mb = scn.devices.multibeam
    rate = mb.rate_hz or 1.0
    n_beams = int(mb.options.get("n_beams", 141))
    factor = float(mb.options.get("swath_factor", 4.0))
    sig_d = float(mb.noise.get("depth_m", DEFAULT_NOISE["depth_m"]))
    sig_r = float(mb.noise.get("range_frac", DEFAULT_NOISE["range_frac"]))
    t_end = float(tr.t[-1]) if scn.duration_s is None else min(float(tr.t[-1]), scn.duration_s)
    t = np.arange(0.0, t_end, 1.0 / rate)
    if max_pings is not None:
        t = t[:max_pings]
    x = np.interp(t, tr.t, tr.x)
    y = np.interp(t, tr.t, tr.y)
    z = np.interp(t, tr.t, tr.z)
    hd = np.unwrap(tr.heading)
    heading = np.interp(t, tr.t, hd)
    truth = np.column_stack([x, y])
    alt = max(scn.terrain.depth_m - float(np.mean(z)), 1.0)
    across = np.linspace(-factor * alt / 2, factor * alt / 2, n_beams)
    offsets = swath_offsets(heading, across)
    pts = truth[:, None, :] + offsets
    seabed = world.depth(pts[..., 0], pts[..., 1])
    rng_m = np.hypot(seabed - z[:, None], across[None, :])
    sigma = np.sqrt(sig_d**2 + (sig_r * rng_m) ** 2)
    depth = seabed + rng.normal(0.0, 1.0, seabed.shape) * sigma
    drm = dr or DRModel()
    steps = np.diff(truth, axis=0) + rng.normal(drm.bias_m, drm.sigma_m, (len(t) - 1, 2))
    dr_pos = np.vstack([truth[:1], truth[:1] + np.cumsum(steps, axis=0)])  # eq. (28)
    return BathyRun(
        t=t,
        truth=truth,
        dr=dr_pos,
        heading=np.asarray([math.remainder(h, 2 * math.pi) for h in heading]),
        offsets=offsets,
        depth=depth,
        name=scn.name,
        meta={"swath_half_width_m": float(across[-1]), "n_beams": float(n_beams)},
    )
