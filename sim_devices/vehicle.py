"""Vehicle kinematics, guidance and the ground-truth trajectory of a scenario.

Frames and units follow :mod:`auvgw.config.scenario`: NED metres, heading in radians from north
towards east, body axes x forward (surge ``u``), y starboard (sway ``v``), z down (heave ``w``,
here the vertical speed), yaw rate ``r`` in rad/s.

* :func:`motion_step`: the papers' motion model (Cui 2020 eq. 2 without noise, Mu 2022 eq. 3),
  vectorised so it also moves particles.
* AUV (``motion: "auv"``): line-of-sight guidance along the waypoint legs with a turn-rate
  limit, crab angle into a water current, depth or terrain-following altitude with a vertical
  speed limit (:func:`simulate_auv`).
* Tim Bailey's simulator vehicle (``motion: "bicycle"``): his ``compute_steering`` (steer-rate
  and max-steer limits, waypoint switching at a radius, loops) and ``vehicle_model`` at his
  ``dt`` (:func:`simulate_bicycle`).

The trajectory is computed once, deterministically, into a :class:`Truth` (ground truth at
every step); emulators read it at any time with :meth:`Truth.at` (a fast path: the angles are
unwrapped once, not per call). Noise only ever comes from a
passed-in :class:`numpy.random.Generator` (:func:`control_noise`, :func:`noisy_odometry`).
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from auvgw.config.scenario import Scenario, Vehicle
from auvgw.sim_devices.world import TerrainModel, World, wrap_angle

__all__ = [
    "GRAVITY",
    "TRUTH_FIELDS",
    "RouteError",
    "Truth",
    "TruthSample",
    "bicycle_step",
    "compute_steering",
    "control_noise",
    "motion_step",
    "noisy_odometry",
    "route_targets",
    "simulate",
    "simulate_auv",
    "simulate_bicycle",
]

GRAVITY = 9.80665
FArray = np.ndarray

#: fields of :class:`Truth` / :class:`TruthSample`, in order
TRUTH_FIELDS = (
    "t", "x", "y", "z", "heading", "roll", "pitch", "u", "v", "w", "yaw_rate", "altitude",
    "seabed_depth", "roll_rate", "pitch_rate", "vn", "ve", "vd", "an", "ae", "ad", "speed",
    "steer",
)  # fmt: skip

_ANGLES = ("heading", "roll", "pitch", "steer")
_ANGLE_IDX = tuple(TRUTH_FIELDS.index(f) for f in _ANGLES)
#: the fields of motion: zero once the route has ended (the vehicle stops where it ended)
MOTION_FIELDS = ("u", "v", "w", "yaw_rate", "roll_rate", "pitch_rate", "vn", "ve", "vd", "an", "ae",
           "ad", "speed", "steer")  # fmt: skip
_MOTION_IDX = tuple(TRUTH_FIELDS.index(f) for f in MOTION_FIELDS)
_TWO_PI = 2.0 * math.pi


class RouteError(RuntimeError):
    """The vehicle could not complete its route (a waypoint it cannot reach)."""


def motion_step(
    x: FArray | float,
    y: FArray | float,
    z: FArray | float,
    heading: FArray | float,
    u: FArray | float,
    v: FArray | float,
    w: FArray | float,
    r: FArray | float,
    dt: float,
) -> tuple[FArray, FArray, FArray, FArray]:
    """One step of the papers' kinematic model: body velocities (surge ``u``, sway ``v``, m/s),
    vertical speed ``w`` (m/s, down) and yaw rate ``r`` (rad/s) held for ``dt`` seconds.

    ``x += (u cos h - v sin h) dt``, ``y += (u sin h + v cos h) dt``, ``z += w dt``,
    ``h += r dt`` (wrapped). Works on scalars or arrays (particles).
    """
    c, s = np.cos(heading), np.sin(heading)
    return (
        np.asarray(x + (u * c - v * s) * dt),
        np.asarray(y + (u * s + v * c) * dt),
        np.asarray(z + w * dt),
        np.asarray(wrap_angle(heading + r * dt)),
    )


# -- ground truth ----------------------------------------------------------------------------


@dataclass(frozen=True)
class TruthSample:
    """Ground truth at one instant (see :class:`Truth` for the fields)."""

    t: float
    x: float
    y: float
    z: float
    heading: float
    roll: float
    pitch: float
    u: float
    v: float
    w: float
    yaw_rate: float
    altitude: float
    seabed_depth: float
    roll_rate: float
    pitch_rate: float
    vn: float
    ve: float
    vd: float
    an: float
    ae: float
    ad: float
    speed: float
    steer: float

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x, y, heading): the 2-D pose of the SLAM papers."""
        return (self.x, self.y, self.heading)

    @property
    def position(self) -> FArray:
        """(x, y, z) NED, metres."""
        return np.array([self.x, self.y, self.z])


@dataclass(frozen=True)
class Truth:
    """Ground truth at every motion step, arrays of equal length.

    ``t`` s; ``x, y, z`` NED m; ``heading, roll, pitch`` rad (ZYX Euler); ``u, v`` body surge
    and sway over ground, ``w`` vertical speed (down), m/s; ``yaw_rate, roll_rate, pitch_rate``
    rad/s; ``altitude`` above the seabed and ``seabed_depth`` below the surface, m; ``vn, ve,
    vd`` NED velocity m/s and ``an, ae, ad`` NED acceleration m/s^2 (kinematic, without
    gravity); ``speed`` the commanded speed (through water for the AUV, Bailey's V for the
    bicycle) and ``steer`` Bailey's steering angle G (rad, 0 for the AUV). Velocities and rates
    at step k are those applied from step k to k+1.
    """

    t: FArray
    x: FArray
    y: FArray
    z: FArray
    heading: FArray
    roll: FArray
    pitch: FArray
    u: FArray
    v: FArray
    w: FArray
    yaw_rate: FArray
    altitude: FArray
    seabed_depth: FArray
    roll_rate: FArray
    pitch_rate: FArray
    vn: FArray
    ve: FArray
    vd: FArray
    an: FArray
    ae: FArray
    ad: FArray
    speed: FArray
    steer: FArray

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        """Time of the last step, s."""
        return float(self.t[-1])

    @property
    def poses(self) -> FArray:
        """(N, 3) array of (x, y, heading)."""
        return np.stack([self.x, self.y, self.heading], axis=1)

    def sample(self, i: int) -> TruthSample:
        """The truth at step ``i``."""
        return TruthSample(**{f: float(getattr(self, f)[i]) for f in TRUTH_FIELDS})

    @cached_property
    def _table(self) -> tuple[list[float], FArray]:
        """The step times as a list and an (N, fields) table with the angles unwrapped,
        built on first use (the arrays are not to be changed afterwards)."""
        cols = [np.asarray(getattr(self, f), float) for f in TRUTH_FIELDS]
        for k in _ANGLE_IDX:
            cols[k] = np.unwrap(cols[k])
        return [float(v) for v in self.t], np.stack(cols, axis=1)

    @cached_property
    def _rest(self) -> FArray:
        """The last step's row with every motion field zero: the vehicle after its route."""
        row = self._table[1][-1].copy()
        row[list(_MOTION_IDX)] = 0.0
        return row

    def interp(self, t: FArray) -> Truth:
        """The truth at times ``t`` (s), linear between steps (angles along the shortest
        way), held at the first step before the trajectory; after the last step the vehicle
        rests where the route ended (velocities, rates, accelerations, speed and steer zero)."""
        tq = np.asarray(t, float)
        rows = self._table[1]
        after = tq > self.t[-1]
        out = {}
        for k, f in enumerate(TRUTH_FIELDS):
            v = np.interp(tq, self.t, rows[:, k])
            if k in _MOTION_IDX and np.any(after):
                v = np.where(after, 0.0, v)
            out[f] = wrap_angle(v) if f in _ANGLES else v
        out["t"] = tq
        return Truth(**out)

    def at(self, t: float) -> TruthSample:
        """The truth at time ``t`` (s), as :meth:`interp` gives it, for one instant: a
        bisection and one row blend, cheap enough for every emulator tick."""
        ts, rows = self._table
        if t <= ts[0]:
            row = rows[0]
        elif t == ts[-1]:
            row = rows[-1]
        elif t > ts[-1]:
            row = self._rest
        else:
            i = bisect.bisect_right(ts, t) - 1
            w = (t - ts[i]) / (ts[i + 1] - ts[i])
            row = rows[i] + w * (rows[i + 1] - rows[i])
        vals = row.tolist()
        for k in _ANGLE_IDX:
            vals[k] = (vals[k] + math.pi) % _TWO_PI - math.pi
        vals[0] = float(t)
        return TruthSample(*vals)

    def every(self, n: int) -> FArray:
        """Indices of the states after every ``n``-th step (n, 2n, ...): the observation
        instants of Bailey's simulator (``DT_OBSERVE = n * DT_CONTROLS``)."""
        return np.arange(n, len(self), n)

    def as_dict(self) -> dict[str, FArray]:
        return {f: getattr(self, f) for f in TRUTH_FIELDS}


def _finish_truth(
    t: FArray,
    x: FArray,
    y: FArray,
    heading: FArray,
    u: FArray,
    v: FArray,
    r: FArray,
    speed: FArray,
    steer: FArray,
    vehicle: Vehicle,
    terrain: TerrainModel,
) -> Truth:
    """Add the vertical channel (depth or altitude keeping) and the derived fields."""
    n = len(t)
    dt = float(t[1] - t[0]) if n > 1 else vehicle.dt_s
    seabed = terrain.depth(x, y)
    if vehicle.altitude_m is not None:
        zc = np.maximum(seabed - vehicle.altitude_m, 0.0)
    else:
        zc = np.full(n, float(vehicle.depth_m))
    wmax, tau = vehicle.max_depth_rate_mps, 2.0
    z = np.empty(n)
    w = np.zeros(n)
    z[0] = zc[0]
    zcl = zc.tolist()
    zi = zcl[0]
    for k in range(n - 1):
        wk = (zcl[k + 1] - zcl[k]) / dt + (zcl[k] - zi) / tau
        wk = wmax if wk > wmax else -wmax if wk < -wmax else wk
        w[k] = wk
        zi = max(zi + wk * dt, 0.0)
        z[k + 1] = zi
    if n > 1:
        w[-1] = w[-2]
    c, s = np.cos(heading), np.sin(heading)
    vn, ve = u * c - v * s, u * s + v * c
    pitch = np.arctan2(-w, np.hypot(u, v))
    roll = np.arctan(u * r / GRAVITY)

    def grad(a: FArray) -> FArray:
        return np.gradient(a, t) if n > 1 else np.zeros(n)

    return Truth(
        t=t, x=x, y=y, z=z, heading=heading, roll=roll, pitch=pitch, u=u, v=v, w=w,
        yaw_rate=r, altitude=seabed - z, seabed_depth=seabed, roll_rate=grad(roll),
        pitch_rate=grad(pitch), vn=vn, ve=ve, vd=w, an=grad(vn), ae=grad(ve), ad=grad(w),
        speed=speed, steer=steer,
    )  # fmt: skip


# -- AUV: line-of-sight guidance -------------------------------------------------------------


def route_targets(vehicle: Vehicle, starts_at_first: bool) -> list[tuple[float, float]]:
    """Waypoints in the order they are driven: the list ``loops`` times, each loop closed back
    to the first waypoint if ``closed``; the first one dropped if the vehicle starts there."""
    wps = [tuple(map(float, p)) for p in vehicle.waypoints]
    one = [*wps, wps[0]] if vehicle.closed else wps
    targets: list[tuple[float, float]] = []
    for p in one * vehicle.loops:
        if not targets or p != targets[-1]:
            targets.append(p)  # type: ignore[arg-type]
    return targets[1:] if starts_at_first else targets


def simulate_auv(scn: Scenario, world: World) -> Truth:
    """The AUV's trajectory through the scenario's waypoints (``motion: "auv"``).

    Line-of-sight guidance: desired course along the active leg plus ``atan(-e / lookahead)``
    for the cross-track error ``e``; heading = course minus the crab angle that cancels the
    current; yaw rate = heading error / 1 s, limited to ``max_yaw_rate_dps``. A waypoint is
    reached within ``accept_radius_m`` or when the vehicle has passed the end of its leg. The
    run ends at the last waypoint or at ``duration_s``.
    """
    veh = scn.vehicle
    dt = veh.dt_s
    U = veh.speed_mps
    cx, cy = (float(c) for c in veh.current_mps)
    rmax = math.radians(veh.max_yaw_rate_dps)
    x, y, h = scn.start_pose
    targets = route_targets(veh, veh.start is None)
    px, py = x, y
    lengths = [math.dist(a, b) for a, b in zip([(x, y), *targets[:-1]], targets, strict=True)]
    budget = 10.0 * (sum(lengths) / U + 120.0)
    if scn.duration_s is not None:
        budget = min(budget, scn.duration_s)
    n_max = int(budget / dt) + 1
    xs, ys, hs, us, vs, rs = [x], [y], [h], [], [], []
    i = 0
    for _ in range(n_max):
        # waypoint switching
        while i < len(targets):
            tx, ty = targets[i]
            ax, ay = tx - px, ty - py
            seg = math.hypot(ax, ay)
            along = ((x - px) * ax + (y - py) * ay) / seg if seg > 0 else 0.0
            if math.hypot(tx - x, ty - y) < veh.accept_radius_m or along >= seg:
                px, py = tx, ty
                i += 1
            else:
                break
        if i == len(targets):
            break
        alpha = math.atan2(ay, ax)
        e = -(x - px) * math.sin(alpha) + (y - py) * math.cos(alpha)
        course = alpha + math.atan2(-e, veh.lookahead_m)
        c_perp = -cx * math.sin(course) + cy * math.cos(course)
        h_cmd = course - math.asin(max(-1.0, min(1.0, c_perp / U)))
        err = (h_cmd - h + math.pi) % (2 * math.pi) - math.pi
        r = max(-rmax, min(rmax, err / 1.0))
        ch, sh = math.cos(h), math.sin(h)
        u = U + cx * ch + cy * sh
        v = -cx * sh + cy * ch
        x += (u * ch - v * sh) * dt
        y += (u * sh + v * ch) * dt
        h = (h + r * dt + math.pi) % (2 * math.pi) - math.pi
        xs.append(x)
        ys.append(y)
        hs.append(h)
        us.append(u)
        vs.append(v)
        rs.append(r)
    else:
        if scn.duration_s is None or budget < scn.duration_s:
            raise RouteError(
                f"{scn.source or scn.name}: vehicle did not reach waypoint {i} "
                f"{targets[i]} within {budget:.0f} s (now at {x:.1f}, {y:.1f})"
            )
    n = len(xs)
    last = (us[-1], vs[-1], rs[-1]) if us else (U, 0.0, 0.0)
    us.append(last[0])
    vs.append(last[1])
    rs.append(last[2])
    return _finish_truth(
        np.arange(n) * dt, np.array(xs), np.array(ys), np.array(hs), np.array(us),
        np.array(vs), np.array(rs), np.full(n, U), np.zeros(n), veh, world.terrain,
    )  # fmt: skip


# -- Tim Bailey's bicycle vehicle ------------------------------------------------------------


def compute_steering(
    x: float,
    y: float,
    heading: float,
    waypoints: list[tuple[float, float]],
    iwp: int,
    min_d: float,
    steer: float,
    max_rate: float,
    max_steer: float,
    dt: float,
) -> tuple[float, int]:
    """Bailey's ``compute_steering``: (new steer angle G in rad, waypoint index).

    If the vehicle is within ``min_d`` of waypoint ``iwp`` the index advances (returning -1,
    his 0, past the last waypoint, with G unchanged); then G turns towards the waypoint's
    bearing by at most ``max_rate * dt`` and is clipped to +-``max_steer``.
    """
    tx, ty = waypoints[iwp]
    if (tx - x) ** 2 + (ty - y) ** 2 < min_d**2:
        iwp += 1
        if iwp >= len(waypoints):
            return steer, -1
        tx, ty = waypoints[iwp]
    delta = (math.atan2(ty - y, tx - x) - heading - steer + math.pi) % (2 * math.pi) - math.pi
    limit = max_rate * dt
    delta = max(-limit, min(limit, delta))
    steer += delta
    return max(-max_steer, min(max_steer, steer)), iwp


def bicycle_step(
    x: FArray | float,
    y: FArray | float,
    heading: FArray | float,
    speed: FArray | float,
    steer: FArray | float,
    wheelbase: float,
    dt: float,
) -> tuple[FArray, FArray, FArray]:
    """Bailey's ``vehicle_model``: moves along ``heading + steer`` at ``speed`` for ``dt`` and
    turns by ``speed dt sin(steer) / wheelbase`` (vectorised over particles)."""
    a = heading + steer
    return (
        x + speed * dt * np.cos(a),
        y + speed * dt * np.sin(a),
        wrap_angle(heading + speed * dt * np.sin(steer) / wheelbase),
    )


def simulate_bicycle(scn: Scenario, world: World) -> Truth:
    """Bailey's simulator loop (``motion: "bicycle"``), noise-free truth.

    Starts at ``vehicle.start`` (his default is the origin facing +x), G = 0, waypoint 0;
    each control step runs :func:`compute_steering` (switch radius ``vehicle.accept_radius_m``,
    his ``AT_WAYPOINT`` = 1 m), restarts the waypoint list while loops remain, then moves the
    vehicle; it stops after the step on which the last waypoint of the last loop was reached
    (or at ``duration_s``). In the papers' model ``u = V cos G``, ``v = V sin G``,
    ``r = V sin G / wheelbase``.
    """
    b = scn.bicycle
    veh = scn.vehicle
    dt, V, wb = b.dt_s, b.speed_mps, b.wheelbase_m
    max_g, rate_g = math.radians(b.max_steer_deg), math.radians(b.max_steer_rate_dps)
    x, y, h = scn.start_pose
    wps = [tuple(map(float, p)) for p in veh.waypoints]
    total = sum(math.dist(a, c) for a, c in itertools.pairwise(wps))
    budget = 10.0 * veh.loops * (total + math.dist((x, y), wps[0])) / V + 600.0
    if scn.duration_s is not None:
        budget = min(budget, scn.duration_s)
    n_max = int(budget / dt) + 1
    loops = veh.loops
    iwp, g = 0, 0.0
    xs, ys, hs, gs = [x], [y], [h], []
    for _ in range(n_max):
        g, iwp = compute_steering(x, y, h, wps, iwp, veh.accept_radius_m, g, rate_g, max_g, dt)  # type: ignore[arg-type]
        if iwp == -1 and loops > 1:
            iwp = 0
            loops -= 1
        a = h + g
        x += V * dt * math.cos(a)
        y += V * dt * math.sin(a)
        h = (h + V * dt * math.sin(g) / wb + math.pi) % (2 * math.pi) - math.pi
        xs.append(x)
        ys.append(y)
        hs.append(h)
        gs.append(g)
        if iwp == -1:
            break
    else:
        if scn.duration_s is None or budget < scn.duration_s:
            raise RouteError(
                f"{scn.source or scn.name}: bicycle did not finish its route within "
                f"{budget:.0f} s (waypoint {iwp})"
            )
    gs.append(gs[-1] if gs else 0.0)
    n = len(xs)
    g_arr = np.array(gs)
    return _finish_truth(
        np.arange(n) * dt, np.array(xs), np.array(ys), np.array(hs), V * np.cos(g_arr),
        V * np.sin(g_arr), V * np.sin(g_arr) / wb, np.full(n, V), g_arr, veh, world.terrain,
    )  # fmt: skip


def simulate(scn: Scenario, world: World | None = None) -> Truth:
    """The ground-truth trajectory of a scenario (AUV or Bailey bicycle, per ``motion``)."""
    world = world if world is not None else World.from_scenario(scn)
    if scn.motion == "bicycle":
        return simulate_bicycle(scn, world)
    return simulate_auv(scn, world)


# -- noise (always from a passed-in generator) -----------------------------------------------


def control_noise(
    speed: FArray | float,
    steer: FArray | float,
    sigma_v: float,
    sigma_steer: float,
    rng: np.random.Generator,
) -> tuple[FArray, FArray]:
    """Bailey's ``add_control_noise``: (V + N(0, sigma_v^2), G + N(0, sigma_steer^2)), m/s and
    rad, for scalars or arrays."""
    v = np.asarray(speed, float)
    g = np.asarray(steer, float)
    return v + rng.normal(0.0, sigma_v, v.shape), g + rng.normal(0.0, sigma_steer, g.shape)


def noisy_odometry(
    truth: Truth,
    sigma_uv: float,
    sigma_r: float,
    rng: np.random.Generator,
) -> tuple[FArray, FArray, FArray]:
    """Body velocities and yaw rate as a DVL and gyro would report them: (u, v, r) of every
    step plus white noise of ``sigma_uv`` (m/s) and ``sigma_r`` (rad/s)."""
    n = len(truth)
    return (
        truth.u + rng.normal(0.0, sigma_uv, n),
        truth.v + rng.normal(0.0, sigma_uv, n),
        truth.yaw_rate + rng.normal(0.0, sigma_r, n),
    )
