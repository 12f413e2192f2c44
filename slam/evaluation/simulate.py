"""Tim Bailey's SLAM simulator, driven by a :class:`~auvgw.config.scenario.Scenario`.

A car-like vehicle (:class:`~auvgw.slam.models.BicycleModel`) follows the scenario's waypoints at
constant speed with Bailey's steering law (turn towards the current waypoint, steer rate and angle
limited, switch waypoint inside the acceptance radius, repeat the route ``vehicle.loops`` times).
The filter receives the controls with noise ``N(0, diag(sigma_v^2, sigma_G^2))``; every
``observations.every_n_steps`` steps it receives range-bearing observations of the point features
within ``max_range_m`` and ``field_of_view_deg`` (180: the half plane ahead of the vehicle, as in
Bailey's ``get_observations``), each with noise ``N(0, R0)``, except that with probability
``burst_p`` an observation's covariance is ``burst_n * R0`` (the VB paper's dynamic noise,
Table 3).

Everything is generated up front (:class:`SimRun`), so the filters are timed alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.slam.models import BicycleModel, RangeBearing, wrap_angle

__all__ = ["SimRun", "simulate"]


@dataclass(frozen=True)
class SimRun:
    """One simulated run. ``truth[k]`` is the true pose after ``k`` control steps; ``controls[k]``
    the noisy (measured) ``(V, G)`` of step ``k``; ``obs_step[i]`` the step after which scan ``i``
    (``obs_z[i] (m, 2)`` range m / bearing rad, ``obs_ids[i] (m,)`` feature indices) is taken."""

    dt: float
    truth: np.ndarray
    controls: np.ndarray
    true_controls: np.ndarray
    obs_step: np.ndarray
    obs_z: list[np.ndarray]
    obs_ids: list[np.ndarray]
    landmarks: np.ndarray
    q: np.ndarray
    r: np.ndarray
    wheelbase: float
    burst_n: float
    burst_p: float

    @property
    def duration_s(self) -> float:
        """Vehicle time of the run, seconds."""
        return self.dt * len(self.controls)

    @property
    def distance_m(self) -> float:
        """Length of the true path, metres."""
        return float(np.hypot(*np.diff(self.truth[:, :2], axis=0).T).sum())


def _steer(
    x: np.ndarray,
    wp: np.ndarray,
    iwp: int,
    accept: float,
    g: float,
    rate: float,
    gmax: float,
    dt: float,
) -> tuple[float, int]:
    """Bailey's ``compute_steering``: returns the new steer angle and waypoint index (-1 at the
    end of the route)."""
    cx, cy = wp[iwp]
    if (cx - x[0]) ** 2 + (cy - x[1]) ** 2 < accept * accept:
        iwp += 1
        if iwp >= len(wp):
            return g, -1
        cx, cy = wp[iwp]
    dg = wrap_angle(math.atan2(cy - x[1], cx - x[0]) - x[2] - g)
    max_delta = rate * dt
    dg = max(-max_delta, min(max_delta, dg))
    g = max(-gmax, min(gmax, g + dg))
    return g, iwp


def simulate(
    scenario: Scenario,
    rng: np.random.Generator,
    *,
    burst_n: float | None = None,
    burst_p: float | None = None,
    max_steps: int | None = None,
    control_noise: bool = True,
    sensor_noise: bool = True,
) -> SimRun:
    """Simulate one run of ``scenario`` (Bailey's simulator; ``scenario.bicycle`` settings,
    ``scenario.observations`` sensor). ``burst_n``/``burst_p`` override the scenario's dynamic
    noise; ``max_steps`` truncates the run; the ``*_noise`` switches turn noise off (tests)."""
    b = scenario.bicycle
    ob = scenario.observations
    bn = ob.burst_n if burst_n is None else float(burst_n)
    bp = ob.burst_p if burst_p is None else float(burst_p)
    lm = np.asarray(scenario.point_features(), dtype=float).reshape(-1, 2)
    wp = np.asarray(scenario.vehicle.waypoints, dtype=float)
    dt = b.dt_s
    sv, sg = b.sigma_v_mps, math.radians(b.sigma_steer_deg)
    q = np.diag([sv * sv, sg * sg])
    sr, sb = ob.sigma_range_m, math.radians(ob.sigma_bearing_deg)
    r = np.diag([sr * sr, sb * sb])
    model = BicycleModel(b.wheelbase_m)
    obs_model = RangeBearing()
    rate, gmax = math.radians(b.max_steer_rate_dps), math.radians(b.max_steer_deg)
    accept = scenario.vehicle.accept_radius_m
    loops = scenario.vehicle.loops
    v = b.speed_mps

    x = np.asarray(scenario.start_pose, dtype=float)
    g = 0.0
    iwp = 0
    truth = [x.copy()]
    true_u: list[tuple[float, float]] = []
    limit = max_steps if max_steps is not None else 10**7
    while len(true_u) < limit:
        g, iwp = _steer(x, wp, iwp, accept, g, rate, gmax, dt)
        if iwp < 0:
            loops -= 1
            if loops <= 0:
                break
            iwp = 0
        a = x[2] + g
        x = np.array(
            [
                x[0] + v * dt * math.cos(a),
                x[1] + v * dt * math.sin(a),
                wrap_angle(x[2] + v * dt * math.sin(g) / model.wheelbase),
            ]
        )
        truth.append(x)
        true_u.append((v, g))
    truth_arr = np.array(truth)
    tu = np.array(true_u, dtype=float).reshape(-1, 2)
    noise = rng.standard_normal(tu.shape) * np.array([sv, sg]) if control_noise else 0.0
    controls = tu + noise

    every = ob.every_n_steps
    steps = np.arange(every, len(tu) + 1, every)
    obs_z: list[np.ndarray] = []
    obs_ids: list[np.ndarray] = []
    rmax = ob.max_range_m
    half_fov = math.radians(ob.field_of_view_deg) / 2
    for k in steps:
        p = truth_arr[k]
        d = lm - p[:2]
        in_range = np.einsum("ij,ij->i", d, d) < rmax * rmax
        if half_fov >= math.pi:
            vis = np.nonzero(in_range)[0]
        else:
            bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - p[2])
            vis = np.nonzero(in_range & (np.abs(bearing) < half_fov))[0]
        z = obs_model.h(p, lm[vis])
        if sensor_noise and len(vis):
            scale = np.where(rng.random(len(vis)) < bp, math.sqrt(bn), 1.0)
            z = z + rng.standard_normal(z.shape) * np.array([sr, sb]) * scale[:, None]
            z[:, 1] = wrap_angle(z[:, 1])
        obs_z.append(z)
        obs_ids.append(vis)
    return SimRun(
        dt=dt,
        truth=truth_arr,
        controls=controls,
        true_controls=tu,
        obs_step=steps,
        obs_z=obs_z,
        obs_ids=obs_ids,
        landmarks=lm,
        q=q,
        r=r,
        wheelbase=model.wheelbase,
        burst_n=bn,
        burst_p=bp,
    )
