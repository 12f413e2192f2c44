"""The reference autopilot: ILOS waypoint guidance, heading, depth and speed loops, aborts.

Pure (no transports, no clock): the caller latches what the vehicle sees, :meth:`Autopilot.nav`
(a :class:`NavFix`: position NED, attitude, body velocity and rates) and
:meth:`Autopilot.feedback` (an :class:`ActuatorFeedback`: measured shaft rpm, fin angles, fault
word), then calls :meth:`Autopilot.step` ``(t)`` at the control rate with the vehicle time ``t``
(s, the clock the fixes are stamped in). ``step`` returns the :class:`ActuatorCommand` and keeps
:attr:`Autopilot.status`.

Sign conventions are the dynamics model's (``auvgw.sim_devices.dynamics``, Fossen): positive
rudder turns the bow to port (yaw rate < 0), positive stern plane pitches the bow down.

Loops (Fossen, Handbook of Marine Craft Hydrodynamics 2021, ch. 12 and 16):

* guidance: integral line-of-sight (ILOS, eqs. 12.108-12.111 in the 2021 edition's notation:
  ``psi_d = pi_h - atan((y_e + kappa y_int) / Delta)``, ``y_int' = Delta y_e / (Delta^2 +
  (y_e + kappa y_int)^2)``), so a constant cross current leaves no cross-track error;
* heading: a P loop on ``psi - psi_d`` giving a yaw-rate set-point bounded by
  ``max_yaw_rate`` (the unstable sway-yaw mode is only held inside a bounded turn rate), an
  inner PI loop on the yaw rate giving the rudder (its integral is the heading's, plus the
  rudder trim the propeller torque's roll needs);
* depth: an outer PI-D loop giving the pitch set-point (the depth set-point rate-limited), an
  inner PID on pitch giving the stern plane;
* speed: rpm feed-forward (``rpm_per_mps``) plus PI on the surge speed, slew-limited.

Every integrator uses conditional integration (anti-windup: it stops while the output is
saturated in the direction the error pushes).

Aborts (latched; action = surface: shaft off, rudder 0, stern plane at ``-surface_stern``,
i.e. bow up): navigation older than ``nav_timeout_s``; depth beyond ``max_depth``; a fault bit
of ``fault_mask`` set; a fin whose measured angle leaves a rate-limited model of its command
by ``fin_tolerance`` for ``fin_jam_s``; a shaft whose measured rpm leaves its command by
``rpm_tolerance`` for ``thruster_s``; no actuator feedback for ``feedback_timeout_s``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from auvgw.control.mission import Mission, Waypoint
from auvgw.ground.geometry import wrap_angle

__all__ = [
    "ABORT_REASONS",
    "ActuatorCommand",
    "ActuatorFeedback",
    "Autopilot",
    "AutopilotConfig",
    "CommandSink",
    "Ilos",
    "NavFix",
    "Pid",
    "PilotStatus",
]

#: every abort reason :attr:`PilotStatus.abort_reason` can hold
ABORT_REASONS = ("nav_lost", "depth_limit", "actuator_fault", "rudder_jammed", "stern_jammed",
                 "thruster", "actuators_silent")  # fmt: skip


@dataclass(frozen=True)
class NavFix:
    """Navigation as the autopilot sees it at time ``t`` (s): ``north``, ``east``, ``depth``
    (m, local NED), ``roll``, ``pitch``, ``heading`` (rad, ZYX Euler), body velocity ``u``,
    ``v``, ``w`` (m/s, FRD) and body rates ``p``, ``q``, ``r`` (rad/s)."""

    t: float
    north: float
    east: float
    depth: float
    roll: float
    pitch: float
    heading: float
    u: float
    v: float
    w: float
    p: float = 0.0
    q: float = 0.0
    r: float = 0.0

    @property
    def depth_rate(self) -> float:
        """Vertical speed (m/s, down) from the body velocity and attitude."""
        st, ct = math.sin(self.pitch), math.cos(self.pitch)
        sf, cf = math.sin(self.roll), math.cos(self.roll)
        return -st * self.u + ct * sf * self.v + ct * cf * self.w


@dataclass(frozen=True)
class ActuatorFeedback:
    """What the actuators report at time ``t`` (s): measured shaft ``rpm``, ``rudder`` and
    ``stern`` plane angles (rad) and the ``faults`` word (bits set: faults); ``cmd_t``: the time
    (s) of the newest command they had applied (their echo of its sequence number), so the
    checks compare them with what was asked then, whatever the loop's latency (None: ``t``;
    before the autopilot's start, e.g. ``-inf``: they apply none of its commands yet, and are
    not judged)."""

    t: float
    rpm: float
    rudder: float
    stern: float
    faults: int = 0
    cmd_t: float | None = None


@dataclass(frozen=True)
class ActuatorCommand:
    """The set-points sent at time ``t`` (s): shaft ``rpm``, ``rudder``, ``stern`` (rad)."""

    t: float
    rpm: float
    rudder: float
    stern: float


#: where the commands go (the bus key ``auv/<v>/cmd/actuators`` once the gateway takes them)
CommandSink = Callable[[ActuatorCommand], object]


@dataclass(frozen=True)
class PilotStatus:
    """The autopilot after a step: ``mode`` ("waiting" for navigation, "running", "done",
    "aborted"), the current ``leg`` (of ``n_legs``), ``cross_track`` (m, + starboard of the
    leg) and ``along_track`` (m from the leg's start), the set-points (``heading_d``,
    ``pitch_d`` rad, ``depth_d`` m, ``speed_d`` m/s), the ``command`` and ``abort_reason``."""

    t: float
    mode: str
    leg: int
    n_legs: int
    cross_track: float
    along_track: float
    heading_d: float
    pitch_d: float
    depth_d: float
    speed_d: float
    command: ActuatorCommand
    abort_reason: str = ""
    abort_detail: str = ""


@dataclass(frozen=True)
class AutopilotConfig:
    """Gains (SI units, radians), limits and abort thresholds; the defaults fly the REMUS 100
    model of ``config/vehicles/remus100.toml`` at 1-2 m/s (docs/pilot.md)."""

    # guidance
    lookahead: float = 12.0  #: ILOS Delta (m)
    ilos_kappa: float = 0.5  #: ILOS integral weight (1)
    ilos_int_limit: float = 30.0  #: |y_int| bound (m)
    # heading -> yaw-rate set-point (1/s), yaw rate -> rudder (rad per rad/s, per rad)
    heading_kp: float = 0.5
    max_yaw_rate: float = math.radians(8.0)
    yaw_rate_kp: float = 1.5
    yaw_rate_ki: float = 0.3
    # depth -> pitch set-point (rad per m, rad per m s, rad per m/s)
    depth_kp: float = 0.2
    depth_ki: float = 0.006
    depth_kd: float = 1.0
    depth_int_zone: float = 1.0  #: m of depth error within which the depth integral moves
    max_pitch_d: float = math.radians(25.0)
    depth_rate: float = 0.5  #: m/s the depth set-point moves at
    # pitch -> stern plane
    pitch_kp: float = 1.0
    pitch_ki: float = 0.3
    pitch_kd: float = 2.5
    # speed -> rpm
    rpm_per_mps: float = 610.0  #: feed-forward (rpm per m/s)
    speed_kp: float = 200.0
    speed_ki: float = 40.0
    rpm_slew: float = 400.0  #: rpm/s
    # actuator limits (the REMUS 100's)
    max_rudder: float = math.radians(20.0)
    max_stern: float = math.radians(20.0)
    max_rpm: float = 1525.0
    # aborts
    nav_timeout_s: float = 0.5
    max_depth: float = 60.0
    fault_mask: int = 0xFFFFFFFF
    fin_rate: float = math.radians(60.0)  #: fin servo slew rate (rad/s) of the expected model
    #: the fin servo's first-order time constant (s) of the expected model (0: a pure slew); a
    #: servo with a lag runs ``fin_rate * fin_tau`` behind a pure slew while it moves
    fin_tau: float = 0.0
    fin_tolerance: float = math.radians(3.0)
    fin_jam_s: float = 0.4
    rpm_tolerance: float = 150.0
    #: the shaft's first-order time constant (s) of the expected model (the emulated controller's
    #: 0.3 s; 0: none): a healthy shaft spinning up lies between the model before and after
    shaft_tau: float = 0.3
    thruster_s: float = 0.6
    feedback_timeout_s: float = 0.5  #: 0: no feedback expected (no fin/thruster checks)
    surface_stern: float = math.radians(15.0)  #: bow-up stern plane while surfacing (rad)


def _clip(x: float, lim: float) -> float:
    return min(max(x, -lim), lim)


@dataclass
class Pid:
    """``out = clip(ff + kp e + ki integral(e) + kd de, +-limit)`` with conditional
    integration: the integral stops growing while the output is saturated the way ``e``
    pushes it (anti-windup), and outside ``|e| <= zone``."""

    kp: float
    ki: float
    kd: float
    limit: float
    zone: float = math.inf
    """the integral moves only while ``|e| <= zone`` (a transient does not wind it up)"""
    integral: float = 0.0

    def update(self, e: float, de: float, dt: float, ff: float = 0.0) -> float:
        raw = ff + self.kp * e + self.ki * self.integral + self.kd * de
        out = _clip(raw, self.limit)
        free = out == raw or (raw > out and e < 0) or (raw < out and e > 0)
        if free and abs(e) <= self.zone:
            self.integral += e * dt
        return out


@dataclass
class Ilos:
    """Integral LOS (Fossen 2021 eqs. 12.108-12.111): the heading correction for cross-track
    error ``y_e`` (m, + starboard) with lookahead ``delta`` (m) and integral weight ``kappa``."""

    delta: float
    kappa: float
    limit: float
    y_int: float = 0.0

    def update(self, y_e: float, dt: float) -> float:
        """``-atan((y_e + kappa y_int) / delta)`` (rad), then the integral moves on."""
        a = y_e + self.kappa * self.y_int
        corr = -math.atan(a / self.delta)
        self.y_int = _clip(self.y_int + dt * self.delta * y_e / (self.delta ** 2 + a * a),
                           self.limit)  # fmt: skip
        return corr


@dataclass
class _Watch:
    """How long (s) a condition has held: ``since`` is when it started, None while it does not."""

    since: float | None = None

    def held(self, cond: bool, t: float) -> float:
        if not cond:
            self.since = None
            return 0.0
        if self.since is None:
            self.since = t
        return t - self.since


@dataclass
class _Expected:
    """A model of an actuator following its command (what a healthy one shows): a first-order
    lag of time constant ``tau`` (s; 0: none) whose speed is limited to ``rate`` per s."""

    rate: float
    tau: float = 0.0
    value: float = 0.0

    def follow(self, cmd: float, dt: float) -> float:
        e = cmd - self.value
        step = e if self.tau <= 0 else e * (1.0 - math.exp(-dt / self.tau))
        self.value += _clip(step, self.rate * dt)
        return self.value


@dataclass
class Autopilot:
    """The reference autopilot flying ``mission`` (see the module docstring)."""

    mission: Mission
    config: AutopilotConfig = field(default_factory=AutopilotConfig)

    def __post_init__(self) -> None:
        c = self.config
        self.yaw_rate_pid = Pid(c.yaw_rate_kp, c.yaw_rate_ki, 0.0, c.max_rudder)
        self.depth_pid = Pid(c.depth_kp, c.depth_ki, c.depth_kd, c.max_pitch_d, c.depth_int_zone)
        self.pitch_pid = Pid(c.pitch_kp, c.pitch_ki, c.pitch_kd, c.max_stern)
        self.speed_pid = Pid(c.speed_kp, c.speed_ki, 0.0, c.max_rpm)
        self.ilos = Ilos(c.lookahead, c.ilos_kappa, c.ilos_int_limit)
        self.leg = 0
        self.mode = "waiting"
        self.abort_reason = ""
        self.abort_detail = ""
        self._nav: NavFix | None = None
        self._fb: ActuatorFeedback | None = None
        self._t_prev: float | None = None
        self._t_start: float | None = None
        self._depth_ref: float | None = None
        self._rpm = 0.0
        self._cmd = ActuatorCommand(0.0, 0.0, 0.0, 0.0)
        #: the fins as a healthy servo shows them, driven by the commands the feedback says
        #: were applied, on the feedback's clock (:meth:`_check_actuators`)
        self._exp_fins = (_Expected(c.fin_rate, c.fin_tau), _Expected(c.fin_rate, c.fin_tau))
        self._fin_band = ((0.0, 0.0), (0.0, 0.0))  # (low, high) rad of each, the newest
        self._exp_rpm = _Expected(1e9, c.shaft_tau)  # no slew limit: a lag only
        self._rpm_band = (0.0, 0.0)  # (low, high) rpm, the newest
        self._fb_judged: float | None = None  # time of the newest feedback the model took
        self._watch = {k: _Watch() for k in ("rudder", "stern", "thruster")}
        #: (t, commanded rpm, rudder, stern) of the last steps: what the actuators were asked at
        #: time t (:class:`ActuatorFeedback` cmd_t names the newest they had applied)
        self._asked: deque[tuple[float, float, float, float]] = deque(maxlen=400)
        wp = self.mission.waypoints[0]
        self.status = PilotStatus(0.0, self.mode, 0, self.mission.n_legs, 0.0, 0.0, 0.0, 0.0,
                                  wp.depth, wp.speed, self._cmd)  # fmt: skip

    # -- inputs ---------------------------------------------------------------------------------
    def nav(self, fix: NavFix) -> None:
        """Latch a navigation fix (a fix older than the one held is ignored)."""
        if self._nav is None or fix.t >= self._nav.t:
            self._nav = fix

    def feedback(self, fb: ActuatorFeedback) -> None:
        """Latch the actuators' feedback (an older one than held is ignored)."""
        if self._fb is None or fb.t >= self._fb.t:
            self._fb = fb

    # -- the step -------------------------------------------------------------------------------
    def step(self, t: float) -> ActuatorCommand:
        """One control step at vehicle time ``t`` (s); returns the command (also in
        :attr:`status`)."""
        dt = 0.0 if self._t_prev is None else min(max(t - self._t_prev, 0.0), 1.0)
        self._t_prev = t
        if self._t_start is None:
            self._t_start = t
        if self.mode in ("aborted", "done"):
            return self._surface(t)
        self._check_actuators(t)
        nav = self._nav
        c = self.config
        if self.mode != "aborted":
            age = t - (nav.t if nav is not None else self._t_start)
            if age > c.nav_timeout_s:
                what = "no fix yet" if nav is None else f"last fix {age:.2f} s old"
                self._abort("nav_lost", f"{what} (limit {c.nav_timeout_s:g} s)")
            elif nav is not None and nav.depth > c.max_depth:
                self._abort("depth_limit", f"depth {nav.depth:.1f} m beyond {c.max_depth:g} m")
        if self.mode == "aborted":
            return self._surface(t)
        if nav is None:
            return self._hold(t)
        if self.mode == "waiting" and self._fb is not None:
            self._rpm = self._fb.rpm  # bumpless: the shaft speed slews on from where it is
        self.mode = "running"
        a, b, y_e, s = self._leg_geometry(nav)
        pi_h = math.atan2(b.east - a.east, b.north - a.north)
        heading_d = wrap_angle(pi_h + self.ilos.update(y_e, dt))
        rudder, stern, rpm, pitch_d = self.loops(nav, dt, heading_d, b.depth, b.speed)
        self._cmd = ActuatorCommand(t, rpm, rudder, stern)
        self.status = PilotStatus(t, self.mode, self.leg, self.mission.n_legs, y_e, s, heading_d,
                                  pitch_d, self.depth_ref, b.speed, self._cmd)  # fmt: skip
        return self._cmd

    @property
    def depth_ref(self) -> float:
        """The rate-limited depth set-point (m; NaN before the first fix)."""
        return math.nan if self._depth_ref is None else self._depth_ref

    def loops(self, nav: NavFix, dt: float, heading_d: float, depth_d: float, speed_d: float,
              pitch_d: float | None = None,
              yaw_rate_d: float | None = None) -> tuple[float, float, float, float]:  # fmt: skip
        """The heading, depth and speed loops one step ``dt`` (s) on toward ``heading_d`` (rad),
        ``depth_d`` (m) and ``speed_d`` (m/s): ``(rudder rad, stern rad, rpm, pitch_d rad)``;
        a ``pitch_d`` (rad) or ``yaw_rate_d`` (rad/s) given replaces the depth or heading
        loop's set-point. (:meth:`step` calls it with the guidance's set-points; the manoeuvres
        call it direct.)"""
        c = self.config
        r_d = (-_clip(c.heading_kp * wrap_angle(nav.heading - heading_d), c.max_yaw_rate)
               if yaw_rate_d is None else yaw_rate_d)  # fmt: skip
        rudder = self.yaw_rate_pid.update(nav.r - r_d, 0.0, dt)
        if self._depth_ref is None:
            self._depth_ref = nav.depth
        self._depth_ref += _clip(depth_d - self._depth_ref, c.depth_rate * dt)
        if pitch_d is None:
            pitch_d = self.depth_pid.update(nav.depth - self._depth_ref, nav.depth_rate, dt)
        stern = self.pitch_pid.update(nav.pitch - pitch_d, nav.q, dt)
        rpm_ff = c.rpm_per_mps * speed_d
        rpm_target = max(0.0, self.speed_pid.update(speed_d - nav.u, 0.0, dt, rpm_ff))
        self._rpm += _clip(rpm_target - self._rpm, c.rpm_slew * dt)
        return rudder, stern, self._rpm, pitch_d

    def _leg_geometry(self, nav: NavFix) -> tuple[Waypoint, Waypoint, float, float]:
        """The current leg's ends, cross-track (+ starboard) and along-track distance (m),
        switching legs on the acceptance circle or past the end's perpendicular."""
        while True:
            a, b = self.mission.leg(self.leg)
            dn, de = b.north - a.north, b.east - a.east
            length = math.hypot(dn, de)
            cn, ce = dn / length, de / length
            xn, xe = nav.north - a.north, nav.east - a.east
            s = cn * xn + ce * xe
            y_e = -ce * xn + cn * xe
            reached = math.hypot(nav.north - b.north, nav.east - b.east) <= \
                self.mission.acceptance_radius or s >= length
            if not reached:
                return a, b, y_e, s
            if self.leg + 1 >= self.mission.n_legs:
                self.mode = "done"
                return a, b, y_e, s
            self.leg += 1
            self.ilos.y_int = 0.0

    def _check_actuators(self, t: float) -> None:
        c = self.config
        fb = self._fb
        self._asked.append((t, self._cmd.rpm, self._cmd.rudder, self._cmd.stern))
        if c.feedback_timeout_s <= 0:
            return
        assert self._t_start is not None
        last = fb.t if fb is not None else self._t_start
        if t - last > c.feedback_timeout_s:
            self._abort("actuators_silent", f"no actuator feedback for {t - last:.2f} s "
                        f"(limit {c.feedback_timeout_s:g} s)")  # fmt: skip
            return
        if fb is None:
            return
        if fb.cmd_t is None:
            if fb.t < self._t_start + c.feedback_timeout_s:
                return  # feedback from before the first commands could reach the actuators
                # (their command timeout bit, fins at rest) says nothing of them
        elif fb.cmd_t < self._t_start:
            return  # they apply none of our commands yet (however long the way is)
        if fb.faults & c.fault_mask:
            self._abort("actuator_fault", f"fault word 0x{fb.faults:08x}")
            return
        _, rpm_asked, cmd_r, cmd_s = self._asked_at(fb.t if fb.cmd_t is None else fb.cmd_t)
        if self._fb_judged is None or fb.t > self._fb_judged:
            # the servo model follows the command the feedback says was applied, from the last
            # feedback to this one: whatever the loop's latency or a stall on the way, a healthy
            # fin is between the model's values before and after (it took the command somewhere
            # in that interval), within rate x tau of its lag
            h = 0.0 if self._fb_judged is None else fb.t - self._fb_judged
            band = []
            for model, meas, cmd in zip(self._exp_fins, (fb.rudder, fb.stern), (cmd_r, cmd_s),
                                        strict=True):  # fmt: skip
                if self._fb_judged is None:
                    model.value = meas  # where the fins are when the checks start
                before = model.value
                after = model.follow(cmd, h)
                band.append((min(before, after), max(before, after)))
            self._fin_band = (band[0], band[1])
            if self._fb_judged is None:
                self._exp_rpm.value = fb.rpm
            before = self._exp_rpm.value
            after = self._exp_rpm.follow(rpm_asked, h)
            self._rpm_band = (min(before, after), max(before, after))
            self._fb_judged = fb.t
        for (lo, hi), name, meas in zip(self._fin_band, ("rudder", "stern"),
                                        (fb.rudder, fb.stern), strict=True):  # fmt: skip
            off = max(lo - meas, meas - hi, 0.0)
            if self._watch[name].held(off > c.fin_tolerance, t) >= c.fin_jam_s:
                exp = hi if meas > hi else lo
                self._abort(f"{name}_jammed", f"measured {math.degrees(meas):.1f} deg, expected "
                            f"{math.degrees(exp):.1f} deg for {c.fin_jam_s:g} s")  # fmt: skip
                return
        lo, hi = self._rpm_band
        off = max(lo - fb.rpm, fb.rpm - hi, 0.0)
        if self._watch["thruster"].held(off > c.rpm_tolerance, t) >= c.thruster_s:
            self._abort("thruster", f"measured {fb.rpm:.0f} rpm, commanded {rpm_asked:.0f} "
                        f"rpm for {c.thruster_s:g} s")  # fmt: skip

    def _asked_at(self, t: float) -> tuple[float, float, float, float]:
        """The row of the command of time ``t`` (a step's row holds the command of the step
        before it): the first row after ``t``, or the newest. Searched from the newest: ``t``
        is a few steps old."""
        found = self._asked[-1]
        for row in reversed(self._asked):
            if row[0] <= t + 1e-9:
                break
            found = row
        return found

    def _abort(self, reason: str, detail: str) -> None:
        if self.mode != "aborted":
            self.mode = "aborted"
            self.abort_reason = reason
            self.abort_detail = detail

    def _hold(self, t: float) -> ActuatorCommand:
        self._cmd = ActuatorCommand(t, 0.0, 0.0, 0.0)
        self.status = _replace_status(self.status, t, self.mode, self._cmd, "", "")
        return self._cmd

    def _surface(self, t: float) -> ActuatorCommand:
        """Shaft off, rudder amidships, stern plane bow-up: the vehicle floats up."""
        self._rpm = 0.0
        self._cmd = ActuatorCommand(t, 0.0, 0.0, -self.config.surface_stern)
        self.status = _replace_status(self.status, t, self.mode, self._cmd, self.abort_reason,
                                      self.abort_detail)  # fmt: skip
        return self._cmd


def _replace_status(s: PilotStatus, t: float, mode: str, cmd: ActuatorCommand, reason: str,
                    detail: str) -> PilotStatus:  # fmt: skip
    return PilotStatus(t, mode, s.leg, s.n_legs, s.cross_track, s.along_track, s.heading_d,
                       s.pitch_d, s.depth_d, s.speed_d, cmd, reason, detail)  # fmt: skip
