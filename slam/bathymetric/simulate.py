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

__all__ = ["NAV_MODELS", "BathyRun", "DRModel", "simulate_survey", "swath_offsets"]


NAV_MODELS = ("eq28", "turning", "insdvl")


@dataclass(frozen=True)
class DRModel:
    """Synthetic dead reckoning from the truth: ``x_DR(t) = x_DR(t-1) + x_true(t) -
    x_true(t-1) + e(t)`` per ping (NED, m). ``kind`` chooses the step error ``e(t)``:

    - ``eq28``: the paper's eq. (28), ``N(bias_m, sigma_m^2)`` per axis (A21: both axes, one
      step per ping at 1 Hz): a constant world-frame bias.
    - ``turning`` (issue 28, a turning current): a world-frame bias of the same size
      (``bias_m`` per axis, so ``sqrt(2) bias_m`` long) whose direction turns from 45 deg
      (eq. 28's) through ``turn_deg`` at a constant rate over the mission, plus the same noise.
    - ``insdvl`` (issue 28, an INS + DVL-style error applied to the DR): each true step is
      scaled by ``1 + s`` (DVL scale factor, ``s ~ N(0, scale_sigma^2)`` per run) and rotated by
      ``mu + psi(t)`` (DVL-to-INS misalignment ``mu ~ N(0, misalign_sigma_deg^2)`` per run plus
      an INS heading error ``psi``, first-order Gauss-Markov of std ``heading_sigma_deg`` and
      time constant ``heading_tau_s``), plus the same white noise: a drift that turns with the
      vehicle (body frame). Swaths stay geo-referenced with the true heading (A30): only the
      DR carries the error.
    """

    bias_m: float = 0.012  # m_e, eq. (28)
    sigma_m: float = 0.01  # sigma_e, eq. (28)
    kind: str = "eq28"
    turn_deg: float = 180.0
    heading_sigma_deg: float = 1.0
    heading_tau_s: float = 900.0
    misalign_sigma_deg: float = 0.5
    scale_sigma: float = 0.005

    def __post_init__(self) -> None:
        if self.kind not in NAV_MODELS:
            raise ValueError(f"nav model {self.kind!r}: not one of {list(NAV_MODELS)}")

    def errors(self, truth: np.ndarray, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        """Step errors ``e(t)`` (T-1, 2) m of a DR over the true positions ``truth`` (T, 2) m
        sampled every ``dt_s`` s."""
        return self.errors_and_heading(truth, dt_s, rng)[0]

    def errors_and_heading(
        self, truth: np.ndarray, dt_s: float, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`errors` and the INS heading error ``psi`` (T-1,) rad of each step (``insdvl``;
        zeros for the world-frame kinds): what an online stage that rotates each swath by the
        navigation's heading adds to it (issue 28)."""
        d = np.diff(truth, axis=0)
        n = len(d)
        if self.kind == "eq28":
            return rng.normal(self.bias_m, self.sigma_m, (n, 2)), np.zeros(n)
        noise = rng.normal(0.0, self.sigma_m, (n, 2))
        if self.kind == "turning":
            ang = math.radians(45.0) + math.radians(self.turn_deg) * np.arange(n) / max(n - 1, 1)
            b = math.sqrt(2) * self.bias_m
            return b * np.column_stack([np.cos(ang), np.sin(ang)]) + noise, np.zeros(n)
        a = math.exp(-dt_s / self.heading_tau_s)
        sig = math.radians(self.heading_sigma_deg)
        psi = np.empty(n)
        psi[0] = rng.normal(0.0, sig)
        kicks = rng.normal(0.0, sig * math.sqrt(1 - a * a), n)
        for k in range(1, n):
            psi[k] = a * psi[k - 1] + kicks[k]
        rot = psi + rng.normal(0.0, math.radians(self.misalign_sigma_deg))
        s = 1.0 + rng.normal(0.0, self.scale_sigma)
        c, sn = np.cos(rot), np.sin(rot)
        moved = s * np.column_stack([c * d[:, 0] - sn * d[:, 1], sn * d[:, 0] + c * d[:, 1]])
        return moved - d + noise, psi


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
    steps = np.diff(truth, axis=0) + drm.errors(truth, 1.0 / rate, rng)
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
