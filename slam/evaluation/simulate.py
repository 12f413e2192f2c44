"""The evaluation simulator: Tim Bailey's SLAM simulator, or an AUV on its waypoints, driven by a
:class:`~auvgw.config.scenario.Scenario`, with point or line observations.

Vehicle (``scenario.motion``):

* ``bicycle``: Bailey's car-like vehicle (:class:`~auvgw.slam.models.BicycleModel`) follows the
  waypoints at constant speed with his steering law (turn towards the current waypoint, steer
  rate and angle limited, switch waypoint inside the acceptance radius, repeat the route
  ``vehicle.loops`` times). Controls ``(V, G)`` with noise ``N(0, diag(sigma_v^2, sigma_G^2))``
  (``scenario.bicycle``).
* ``auv``: the AUV's line-of-sight guidance of :func:`auvgw.sim_devices.vehicle.simulate_auv`
  (waypoints, speed, turn-rate limit, current), integrated at the odometry step
  :attr:`AUVOdometry.dt_s` (0.1 s) so that the truth moves exactly by the VR paper's eq. (2)
  kinematics (:class:`~auvgw.slam.models.VelocityModel`, controls ``(u, v, r)``: DVL surge and
  sway, gyro yaw rate). The controls get white noise of ``sigma_uv`` (the VR paper's DVL
  velocity noise ``R_D = 0.04^2``) and ``sigma_r`` (0.01 rad/s; the paper gives 0.01 rad for its
  compass heading, our model integrates the yaw rate instead).

Observations every ``observations.every_n_steps`` control steps (``features``):

* ``points``: range-bearing of the point features within ``max_range_m`` and
  ``field_of_view_deg`` (180: the half plane ahead, as Bailey's ``get_observations``), noise
  ``N(0, R0)`` with ``R0 = diag(sigma_range^2, sigma_bearing^2)`` (``scenario.observations``).
* ``lines``: every wall segment of ``features.lines`` of which at least
  :attr:`LineSensor.min_length_m` (5 m) lies within :attr:`LineSensor.max_range_m` (50 m, the VR
  paper's MSIS range) and the field of view (360 deg: a scanning sonar) is observed as the
  infinite line through it (collinear segments, such as the two breakwater arms either side
  of a harbour mouth, are one line feature: their visible lengths add up),
  ``(rho_v, theta_v) =``
  :meth:`LineFeature.h <auvgw.slam.models.LineFeature.h>` of the true pose and the wall's normal
  form, plus noise ``N(0, diag(sigma_rho^2, sigma_theta^2))`` with the MSIS resolutions the VR
  paper gives (0.1 m, 1.8 deg; it states no line noise). The visible length is measured on
  points every 0.25 m along the segment. Walls do not occlude one another.

In both, with probability ``burst_p`` an observation's covariance is ``burst_n`` times the nominal
one (the VB paper's dynamic noise, Table 3). Everything is generated up front (:class:`SimRun`),
so the filters are timed alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from auvgw.config.scenario import Scenario, ScenarioError
from auvgw.slam.models import (
    BicycleModel,
    LineFeature,
    MotionModel,
    ObservationModel,
    RangeBearing,
    VelocityModel,
    wrap_angle,
)

__all__ = [
    "AUVOdometry",
    "FeatureKind",
    "LineSensor",
    "SimRun",
    "line_of_segment",
    "lines_of_segments",
    "simulate",
    "visible_lines",
]

FeatureKind = Literal["points", "lines"]


@dataclass(frozen=True)
class LineSensor:
    """Line observations of walls (the VR paper's MSIS with Hough line extraction, Sec. 4):
    range m, field of view deg (centred on the heading), noise of ``rho`` (m) and ``theta``
    (deg), the shortest visible wall length that yields a line (m) and the spacing of the points
    on which the visible length is measured (m)."""

    max_range_m: float = 50.0
    field_of_view_deg: float = 360.0
    sigma_rho_m: float = 0.1
    sigma_theta_deg: float = 1.8
    min_length_m: float = 5.0
    sample_m: float = 0.25


@dataclass(frozen=True)
class AUVOdometry:
    """Odometry of the ``auv`` motion: step (s) and white noise of the body velocities (m/s)
    and of the yaw rate (rad/s)."""

    dt_s: float = 0.1
    sigma_uv_mps: float = 0.04
    sigma_r_radps: float = 0.01


@dataclass(frozen=True)
class SimRun:
    """One simulated run. ``truth[k]`` is the true pose after ``k`` control steps; ``controls[k]``
    the noisy (measured) controls of step ``k`` (``(V, G)`` for the bicycle, ``(u, v, r)`` for
    the AUV); ``obs_step[i]`` the step after which scan ``i`` is taken: ``obs_z[i] (m, 2)``
    (range m / bearing rad for points, ``(rho_v m, theta_v rad)`` for lines) of the features
    ``obs_ids[i] (m,)``. ``landmarks (L, 2)`` are the true features: points ``(x, y)`` or lines
    ``(rho, theta)`` in the map frame; ``segments (S, 4)`` the wall segments of the lines and
    ``segment_line (S,)`` the line (index into ``landmarks``) of each segment; ``obs_scale[i]
    (m,)`` the variance multiple each observation was drawn with (``burst_n`` in a burst, else
    1): what an oracle would know of the dynamic noise."""

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
    motion: str = "bicycle"
    features: str = "points"
    segments: np.ndarray | None = None
    segment_line: np.ndarray | None = None
    obs_scale: list[np.ndarray] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        """Vehicle time of the run, seconds."""
        return self.dt * len(self.controls)

    @property
    def distance_m(self) -> float:
        """Length of the true path, metres."""
        return float(np.hypot(*np.diff(self.truth[:, :2], axis=0).T).sum())

    def motion_model(self) -> MotionModel:
        """The filters' motion model (the one that generated the truth)."""
        if self.motion == "auv":
            return VelocityModel()
        return BicycleModel(self.wheelbase)

    def obs_model(self) -> ObservationModel:
        """The filters' observation model."""
        return LineFeature() if self.features == "lines" else RangeBearing()


def line_of_segment(seg: np.ndarray) -> np.ndarray:
    """Normal form ``(rho m, theta rad)`` of the lines through segments ``(..., 4)``
    ``(x1, y1, x2, y2)``: ``x cos(theta) + y sin(theta) = rho`` with ``rho >= 0`` (the normal
    points from the origin to the line)."""
    seg = np.asarray(seg, dtype=float)
    d = seg[..., 2:] - seg[..., :2]
    length = np.hypot(d[..., 0], d[..., 1])
    if np.any(length <= 0):
        raise ValueError("a line feature has zero length (x1, y1 == x2, y2)")
    nx, ny = -d[..., 1] / length, d[..., 0] / length
    rho = nx * seg[..., 0] + ny * seg[..., 1]
    flip = rho < 0
    nx, ny, rho = np.where(flip, -nx, nx), np.where(flip, -ny, ny), np.abs(rho)
    out = np.empty((*seg.shape[:-1], 2))
    out[..., 0] = rho
    out[..., 1] = wrap_angle(np.arctan2(ny, nx))
    return out


def lines_of_segments(seg: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """The distinct lines through segments ``(S, 4)``: ``(lines (L, 2) (rho, theta), line
    index of each segment (S,))``; collinear segments share a line."""
    each = line_of_segment(seg).reshape(-1, 2)
    lines: list[np.ndarray] = []
    owner = np.empty(len(each), dtype=np.int64)
    for i, ln in enumerate(each):
        for j, other in enumerate(lines):
            if abs(ln[0] - other[0]) < tol and abs(wrap_angle(ln[1] - other[1])) < tol:
                owner[i] = j
                break
        else:
            owner[i] = len(lines)
            lines.append(ln)
    return np.array(lines).reshape(-1, 2), owner


def _segment_samples(seg: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points along every segment: ``(points (P, 2), segment index (P,), length each point
    stands for (S,))``."""
    pts: list[np.ndarray] = []
    idx: list[np.ndarray] = []
    each = np.empty(len(seg))
    for i, (x1, y1, x2, y2) in enumerate(seg):
        length = math.hypot(x2 - x1, y2 - y1)
        n = max(math.ceil(length / spacing), 1)
        t = (np.arange(n) + 0.5) / n
        pts.append(np.stack([x1 + t * (x2 - x1), y1 + t * (y2 - y1)], axis=1))
        idx.append(np.full(n, i))
        each[i] = length / n
    return np.concatenate(pts), np.concatenate(idx), each


def visible_lines(
    pose: np.ndarray, segments: np.ndarray, sensor: LineSensor = LineSensor()
) -> np.ndarray:
    """Indices of the lines (as :func:`lines_of_segments` numbers them) seen from
    ``pose (x, y, heading)`` among the wall segments ``(S, 4)``: at least
    ``sensor.min_length_m`` of the line's segments within range and field of view."""
    seg = np.asarray(segments, float).reshape(-1, 4)
    lines, owner = lines_of_segments(seg)
    pts, idx, each = _segment_samples(seg, sensor.sample_m)
    return _visible(np.asarray(pose, float), pts, owner[idx], each[idx], len(lines), sensor)


def _visible(
    p: np.ndarray,
    pts: np.ndarray,
    line: np.ndarray,
    length: np.ndarray,
    n_lines: int,
    sensor: LineSensor,
) -> np.ndarray:
    """Lines with at least ``min_length_m`` of sample points ``pts`` (each standing for
    ``length`` m of line ``line``) within range and field of view of pose ``p``."""
    d = pts - p[:2]
    ok = np.einsum("ij,ij->i", d, d) < sensor.max_range_m**2
    half_fov = math.radians(sensor.field_of_view_deg) / 2
    if half_fov < math.pi:
        ok &= np.abs(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - p[2])) < half_fov
    seen = np.bincount(line[ok], weights=length[ok], minlength=n_lines)
    return np.nonzero(seen >= sensor.min_length_m - 1e-9)[0]


def _bicycle_truth(
    scenario: Scenario, max_steps: int | None
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:
    """Bailey's loop: ``(dt, truth (n+1, 3), true controls (n, 2), sigmas, wheelbase)``."""
    b = scenario.bicycle
    wp = np.asarray(scenario.vehicle.waypoints, dtype=float)
    dt = b.dt_s
    rate, gmax = math.radians(b.max_steer_rate_dps), math.radians(b.max_steer_deg)
    accept = scenario.vehicle.accept_radius_m
    loops = scenario.vehicle.loops
    v = b.speed_mps
    wheelbase = BicycleModel(b.wheelbase_m).wheelbase
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
                wrap_angle(x[2] + v * dt * math.sin(g) / wheelbase),
            ]
        )
        truth.append(x)
        true_u.append((v, g))
    sigmas = np.array([b.sigma_v_mps, math.radians(b.sigma_steer_deg)])
    tu = np.array(true_u, dtype=float).reshape(-1, 2)
    return dt, np.array(truth), tu, sigmas, wheelbase


def _auv_truth(
    scenario: Scenario, odo: AUVOdometry, max_steps: int | None
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """The AUV's guidance at the odometry step: ``(dt, truth (n+1, 3), (u, v, r) (n, 3),
    sigmas)``."""
    from auvgw.sim_devices.vehicle import RouteError, simulate_auv
    from auvgw.sim_devices.world import World

    scn = scenario.model_copy(
        update={"vehicle": scenario.vehicle.model_copy(update={"dt_s": odo.dt_s})}
    )
    try:
        tr = simulate_auv(scn, World.from_scenario(scn))
    except RouteError as exc:
        raise ScenarioError(str(exc)) from None
    n = len(tr) - 1 if max_steps is None else min(len(tr) - 1, int(max_steps))
    truth = np.stack([tr.x, tr.y, tr.heading], axis=1)[: n + 1]
    tu = np.stack([tr.u, tr.v, tr.yaw_rate], axis=1)[:n]
    sigmas = np.array([odo.sigma_uv_mps, odo.sigma_uv_mps, odo.sigma_r_radps])
    return odo.dt_s, truth, tu, sigmas


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
    features: FeatureKind = "points",
    burst_n: float | None = None,
    burst_p: float | None = None,
    max_steps: int | None = None,
    control_noise: bool = True,
    sensor_noise: bool = True,
    line_sensor: LineSensor = LineSensor(),
    odometry: AUVOdometry = AUVOdometry(),
) -> SimRun:
    """Simulate one run of ``scenario`` (see the module docstring): ``features`` ``points`` or
    ``lines``; ``burst_n``/``burst_p`` override the scenario's dynamic noise; ``max_steps``
    truncates the run; the ``*_noise`` switches turn noise off (tests)."""
    if features not in ("points", "lines"):
        raise ValueError(f"features must be 'points' or 'lines', got {features!r}")
    ob = scenario.observations
    bn = ob.burst_n if burst_n is None else float(burst_n)
    bp = ob.burst_p if burst_p is None else float(burst_p)
    segments = segment_line = None
    if features == "lines":
        if not scenario.features.lines:
            raise ScenarioError(
                f"{scenario.source or scenario.name}: no line features (features.lines) to observe"
            )
        segments = np.asarray(scenario.features.lines, dtype=float).reshape(-1, 4)
        lm, segment_line = lines_of_segments(segments)
        sr, sb = line_sensor.sigma_rho_m, math.radians(line_sensor.sigma_theta_deg)
    else:
        lm = np.asarray(scenario.point_features(), dtype=float).reshape(-1, 2)
        sr, sb = ob.sigma_range_m, math.radians(ob.sigma_bearing_deg)
    r = np.diag([sr * sr, sb * sb])
    wheelbase = math.nan
    if scenario.motion == "bicycle":
        dt, truth_arr, tu, sig, wheelbase = _bicycle_truth(scenario, max_steps)
    else:
        dt, truth_arr, tu, sig = _auv_truth(scenario, odometry, max_steps)
    q = np.diag(sig * sig)
    noise = rng.standard_normal(tu.shape) * sig if control_noise else 0.0
    controls = tu + noise

    every = ob.every_n_steps
    steps = np.arange(every, len(tu) + 1, every)
    obs_z: list[np.ndarray] = []
    obs_ids: list[np.ndarray] = []
    obs_scale: list[np.ndarray] = []
    obs_model: ObservationModel
    if features == "lines":
        assert segments is not None and segment_line is not None
        obs_model = LineFeature()
        pts, pidx, each = _segment_samples(segments, line_sensor.sample_m)
        pline, plen = segment_line[pidx], each[pidx]
    else:
        obs_model = RangeBearing()
        rmax = ob.max_range_m
        half_fov = math.radians(ob.field_of_view_deg) / 2
    for k in steps:
        p = truth_arr[k]
        if features == "lines":
            vis = _visible(p, pts, pline, plen, len(lm), line_sensor)
        else:
            d = lm - p[:2]
            in_range = np.einsum("ij,ij->i", d, d) < rmax * rmax
            if half_fov >= math.pi:
                vis = np.nonzero(in_range)[0]
            else:
                bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - p[2])
                vis = np.nonzero(in_range & (np.abs(bearing) < half_fov))[0]
        z = obs_model.h(p, lm[vis])
        scale = np.ones(len(vis))
        if sensor_noise and len(vis):
            scale = np.where(rng.random(len(vis)) < bp, math.sqrt(bn), 1.0)
            z = z + rng.standard_normal(z.shape) * np.array([sr, sb]) * scale[:, None]
            z[:, 1] = wrap_angle(z[:, 1])
        obs_scale.append(scale * scale)
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
        wheelbase=wheelbase,
        burst_n=bn,
        burst_p=bp,
        motion=scenario.motion,
        features=features,
        segments=segments,
        segment_line=segment_line,
        obs_scale=obs_scale,
    )
