"""The autopilot flying the 6-DOF dynamics model in-process, at a fixed step (tests, Monte Carlo).

:func:`fly` runs :class:`~auvgw.control.autopilot.Autopilot` against
:func:`auvgw.sim_devices.dynamics.step`: each step the autopilot gets a :class:`NavFix` built
from the true state (plus white noise of :class:`NavNoise`, drawn from the generator passed in)
and the :class:`ActuatorModel`'s feedback, and its command drives the fins (rate-limited servos)
and the shaft (first-order lag). Faults: a fin jammed from a time on, the shaft stopped from a
time on, navigation lost from a time on. The :class:`Flight` holds the truth, the commands and
the autopilot's status at every step, and the errors against the truth.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from auvgw.control.autopilot import (
    ActuatorCommand,
    ActuatorFeedback,
    Autopilot,
    AutopilotConfig,
    NavFix,
)
from auvgw.control.mission import Mission, Waypoint
from auvgw.ground.geometry import wrap_angle
from auvgw.sim_devices import dynamics as dyn

__all__ = [
    "ActuatorModel", "Flight", "NavNoise", "Override", "Trial", "cross_track", "fly", "hold",
    "trial", "trimmed_start",
]  # fmt: skip

Array = NDArray[np.float64]


@dataclass(frozen=True)
class NavNoise:
    """White noise (1 sigma) on the navigation the autopilot sees: ``position`` (m, north and
    east), ``depth`` (m), ``attitude`` (rad, roll, pitch, heading), ``velocity`` (m/s, body),
    ``rate`` (rad/s, body)."""

    position: float = 0.0
    depth: float = 0.0
    attitude: float = 0.0
    velocity: float = 0.0
    rate: float = 0.0


@dataclass(frozen=True)
class ActuatorModel:
    """The emulated actuators: fin servos slewing at ``fin_rate`` (rad/s), a shaft following its
    command with time constant ``rpm_tau`` (s). Faults: ``jam`` = (fin "rudder"/"stern", from
    t s, angle rad or None): that fin goes to the angle at once (None: stops where it is) and
    stays; ``thruster_stop`` (t s): the shaft stops and reports 0 rpm; ``fault`` = (word, from
    t s): the fault word reported. ``latency_s``: a command reaches them that much later (the
    bus, the gateway, CAN), and their feedback names the newest command applied (its time)."""

    fin_rate: float = math.radians(60.0)
    rpm_tau: float = 0.3
    latency_s: float = 0.0
    jam: tuple[str, float, float | None] | None = None
    thruster_stop: float | None = None
    fault: tuple[int, float] | None = None


@dataclass
class Flight:
    """A closed-loop run: per step ``t`` (s), ``states`` (N x 12, the dynamics state),
    ``commands`` (N x 3: rpm, rudder, stern rad), ``actuators`` (N x 3, the applied values),
    ``leg`` (the autopilot's leg), ``cross_track`` and ``depth_error`` (m, truth against the
    leg and its end waypoint's depth), ``mode``; ``abort_t`` / ``abort_reason`` ('' if none)."""

    t: Array
    states: Array
    commands: Array
    actuators: Array
    leg: NDArray[np.int64]
    cross_track: Array
    depth_error: Array
    mode: list[str]
    abort_t: float | None = None
    abort_reason: str = ""
    done_t: float | None = None
    extra: dict[str, float] = field(default_factory=dict)

    def running(self) -> NDArray[np.bool_]:
        """Steps flown under the autopilot (not waiting, surfacing or done)."""
        return np.array([m == "running" for m in self.mode])

    def rms(self, what: Array, mask: NDArray[np.bool_] | None = None) -> float:
        m = self.running() if mask is None else mask
        return float(np.sqrt(np.mean(what[m] ** 2))) if m.any() else math.nan


def cross_track(mission: Mission, leg: int, north: float, east: float) -> float:
    """Signed distance (m, + starboard) of a point from leg ``leg``'s line."""
    a, b = mission.leg(leg)
    dn, de = b.north - a.north, b.east - a.east
    n = math.hypot(dn, de)
    return (-de * (north - a.north) + dn * (east - a.east)) / n


def trimmed_start(mission: Mission) -> Array:
    """The dynamics state at the first waypoint, at its depth, heading along leg 0, moving at
    the leg's speed."""
    a, b = mission.leg(0)
    x = np.zeros(12)
    x[0] = b.speed
    x[6:9] = (a.north, a.east, a.depth)
    x[11] = math.atan2(b.east - a.east, b.north - a.north)
    return x


def _nav(t: float, x: Array, noise: NavNoise, rng: np.random.Generator | None) -> NavFix:
    vals = [x[6], x[7], x[8], x[9], x[10], x[11], x[0], x[1], x[2], x[3], x[4], x[5]]
    if rng is not None:
        sig = [noise.position] * 2 + [noise.depth] + [noise.attitude] * 3 + \
            [noise.velocity] * 3 + [noise.rate] * 3
        vals = [v + s * e for v, s, e in zip(vals, sig, rng.standard_normal(12), strict=True)]
    vals[5] = wrap_angle(vals[5])
    return NavFix(t, *(float(v) for v in vals))


def fly(
    mission: Mission,
    params: dyn.VehicleParams | None = None,
    config: AutopilotConfig | None = None,
    *,
    dt: float = 0.05,
    t_max: float | None = None,
    start: Array | None = None,
    current_ned: tuple[float, float, float] | None = None,
    noise: NavNoise | None = None,
    rng: np.random.Generator | None = None,
    actuators: ActuatorModel | None = None,
    nav_lost_at: float | None = None,
    stop_after_abort_s: float = 5.0,
) -> Flight:
    """Fly ``mission`` until it is done (plus a second), ``t_max`` s (default: twice its
    length at its slowest speed, plus 120 s), or ``stop_after_abort_s`` after an abort.

    ``start``: the initial dynamics state (default :func:`trimmed_start`); ``current_ned``:
    a constant current (m/s NED); ``noise`` with ``rng``: noisy navigation (truth without);
    ``nav_lost_at``: no navigation fix from that time (s) on.
    """
    p = params if params is not None else dyn.load_params()
    ap = Autopilot(mission, config or AutopilotConfig())
    act = actuators or ActuatorModel()
    if noise is not None and rng is None:
        raise ValueError("noisy navigation needs a random generator (rng)")
    if t_max is None:
        slow = min(w.speed for w in mission.waypoints)
        t_max = 2.0 * mission.length / slow + 120.0
    x = trimmed_start(mission) if start is None else np.array(start, dtype=float)
    vc = None if current_ned is None else np.array(current_ned, dtype=float)
    applied = [0.0, 0.0, 0.0]  # rudder, stern (rad), rpm
    in_flight: deque[ActuatorCommand] = deque()  # sent, not yet at the actuators (latency_s)
    acting: ActuatorCommand | None = None  # the newest command at the actuators
    ts, xs, cmds, acts, legs, xte, dze, modes = [], [], [], [], [], [], [], []
    flight_abort_t: float | None = None
    done_t: float | None = None
    n = round(t_max / dt)
    for i in range(n + 1):
        t = i * dt
        if nav_lost_at is None or t < nav_lost_at:
            ap.nav(_nav(t, x, noise or NavNoise(), rng if noise is not None else None))
        cmd_t = None if act.latency_s <= 0 else acting.t if acting is not None else -math.inf
        ap.feedback(_feedback(t, applied, act, cmd_t))
        cmd: ActuatorCommand = ap.step(t)
        st = ap.status
        ts.append(t)
        xs.append(x)
        cmds.append((cmd.rpm, cmd.rudder, cmd.stern))
        acts.append((applied[2], applied[0], applied[1]))
        legs.append(st.leg)
        xte.append(cross_track(mission, st.leg, x[6], x[7]))
        dze.append(x[8] - mission.leg(st.leg)[1].depth)
        modes.append(st.mode)
        if st.mode == "aborted" and flight_abort_t is None:
            flight_abort_t = t
        if st.mode == "done" and done_t is None:
            done_t = t
        if flight_abort_t is not None and t - flight_abort_t >= stop_after_abort_s:
            break
        if done_t is not None and t - done_t >= 1.0:
            break
        in_flight.append(cmd)
        while in_flight and in_flight[0].t <= t - act.latency_s + 1e-9:
            acting = in_flight.popleft()
        if acting is not None:
            applied = _actuate(t, dt, applied, acting, act)
        x = dyn.step(p, x, np.array(applied), dt, vc)
    return Flight(np.array(ts), np.array(xs), np.array(cmds), np.array(acts), np.array(legs),
                  np.array(xte), np.array(dze), modes, flight_abort_t, ap.abort_reason,
                  done_t)  # fmt: skip


def _feedback(t: float, applied: list[float], act: ActuatorModel,
              cmd_t: float | None = None) -> ActuatorFeedback:  # fmt: skip
    faults = act.fault[0] if act.fault is not None and t >= act.fault[1] else 0
    return ActuatorFeedback(t, applied[2], applied[0], applied[1], faults, cmd_t)


def _actuate(t: float, dt: float, applied: list[float], cmd: ActuatorCommand,
             act: ActuatorModel) -> list[float]:  # fmt: skip
    """The actuators one step on: servos slew toward the command unless jammed, the shaft
    lags its command unless stopped."""
    out = list(applied)
    step = act.fin_rate * dt
    for i, (name, target) in enumerate((("rudder", cmd.rudder), ("stern", cmd.stern))):
        if act.jam is not None and act.jam[0] == name and t >= act.jam[1]:
            out[i] = out[i] if act.jam[2] is None else act.jam[2]
            continue
        out[i] += min(max(target - out[i], -step), step)
    if act.thruster_stop is not None and t >= act.thruster_stop:
        out[2] = 0.0
    else:
        out[2] += (cmd.rpm - out[2]) * (1.0 - math.exp(-dt / act.rpm_tau))
    return out


#: ``(t s, (rudder rad, stern rad, rpm) from the loops) -> what is commanded``: a manoeuvre fixes
#: some of them and keeps the loops' values for the others
Override = Callable[[float, tuple[float, float, float]], tuple[float, float, float]]


def hold(
    params: dyn.VehicleParams,
    start: Array,
    seconds: float,
    override: Override,
    *,
    heading_d: float,
    depth_d: float,
    speed_d: float,
    pitch_d: Callable[[float], float | None] | None = None,
    yaw_rate_d: Callable[[float], float | None] | None = None,
    config: AutopilotConfig | None = None,
    dt: float = 0.05,
    actuators: ActuatorModel | None = None,
) -> tuple[Array, Array, Array]:
    """A manoeuvre: the autopilot's loops hold ``heading_d`` (rad), ``depth_d`` (m) and
    ``speed_d`` (m/s) on the axes ``override`` leaves alone (truth navigation); ``pitch_d(t)``
    (rad) and ``yaw_rate_d(t)`` (rad/s) replace the depth and heading loops' set-points where
    they are not None. Returns
    ``(t, states N x 12, commands N x 3 [rpm, rudder, stern])``; stops early (returning what it
    has) if the vehicle pitches past the Euler-angle limit."""
    wp = Waypoint(float(start[6]), float(start[7]), depth_d, speed_d)
    ap = Autopilot(Mission((wp, wp)), config or AutopilotConfig())
    act = actuators or ActuatorModel()
    x = np.array(start, dtype=float)
    applied = [0.0, 0.0, 0.0]
    ts, xs, cmds = [], [], []
    for i in range(round(seconds / dt) + 1):
        t = i * dt
        rudder, stern, rpm, _ = ap.loops(_nav(t, x, NavNoise(), None), dt if i else 0.0,
                                         heading_d, depth_d, speed_d,
                                         None if pitch_d is None else pitch_d(t),
                                         None if yaw_rate_d is None else yaw_rate_d(t))  # fmt: skip
        rudder, stern, rpm = override(t, (rudder, stern, rpm))
        ts.append(t)
        xs.append(x)
        cmds.append((rpm, rudder, stern))
        applied = _actuate(t, dt, applied, ActuatorCommand(t, rpm, rudder, stern), act)
        try:
            x = dyn.step(params, x, np.array(applied), dt)
        except dyn.PitchSingularityError:
            break
    return np.array(ts), np.array(xs), np.array(cmds)


@dataclass(frozen=True)
class Trial:
    """One Monte Carlo run of a mission (:func:`trial`): the ``current`` drawn (m/s NED), the
    start offsets (``offset`` m across leg 0, ``depth_offset`` m, ``heading_offset`` rad), the
    cross-track and depth error RMS against the truth (m), ``done_t`` (s, NaN if unfinished),
    ``abort_reason``."""

    run: int
    current: tuple[float, float, float]
    offset: float
    depth_offset: float
    heading_offset: float
    xte_rms: float
    depth_rms: float
    done_t: float
    abort_reason: str


def trial(mission: Mission, seed: int, run: int, max_current: float, noise: NavNoise,
          params: dyn.VehicleParams | None = None) -> Trial:  # fmt: skip
    """Run ``run`` of a Monte Carlo study seeded ``seed`` (its generator is
    ``default_rng([seed, run])``, so a run is the same wherever it runs): a constant current
    (direction uniform, speed uniform up to ``max_current`` m/s), a start up to 3 m across leg 0,
    0.5 m in depth and 5 deg in heading off the trimmed start, navigation with ``noise``."""
    rng = np.random.default_rng([seed, run])
    speed, direction = rng.uniform(0.0, max_current), rng.uniform(-math.pi, math.pi)
    off, dz, dpsi = rng.uniform(-3, 3), rng.uniform(-0.5, 0.5), math.radians(rng.uniform(-5, 5))
    x0 = trimmed_start(mission)
    h = x0[11]
    x0[6] -= off * math.sin(h)
    x0[7] += off * math.cos(h)
    x0[8] += dz
    x0[11] = wrap_angle(h + dpsi)
    cur = (speed * math.cos(direction), speed * math.sin(direction), 0.0)
    f = fly(mission, params, start=x0, current_ned=cur, noise=noise, rng=rng)
    return Trial(run, cur, off, dz, dpsi, f.rms(f.cross_track), f.rms(f.depth_error),
                 math.nan if f.done_t is None else f.done_t, f.abort_reason)  # fmt: skip
