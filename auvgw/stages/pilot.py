"""The autopilot stage: the fusion's odometry (and the actuators' feedback) in; actuator commands,
set-points and the autopilot's state out.

Inputs:

* **odometry** (``auv/<v>/nav/odometry``, :class:`~auvgw.fusion.Odometry`): position NED,
  attitude, body velocity and rates become a :class:`~auvgw.control.autopilot.NavFix`; its time
  ``t`` (s, the odometry clock) is the autopilot's vehicle time;
* **actuator feedback** (:class:`~auvgw.control.autopilot.ActuatorFeedback`, measured rpm, fin
  angles, fault word): the gateway's ``ActuatorState`` samples of the ``actuators_device``
  (``auv/<v>/sensor/<device>/actuatorstate``, stamped on the odometry's clock), or in-process
  through :meth:`PilotStage.feed_actuators` / :meth:`PilotStage.post_actuators`.

The autopilot steps on the odometry, every ``control_period_s`` of its time (the feedback is
latched for the next step); while no odometry arrives a timer (host clock) steps it on from the
last odometry's time plus the host time since, so a silent navigation is caught in
``nav_timeout_s`` + one period and the vehicle surfaces. Against a lock-step sim
(``lockstep_clock``: the sim's clock file, :mod:`auvgw.ground.simclock`) the timer counts
*vehicle* time instead (a stalled host then delays nothing in vehicle time), and every odometry
sample is answered on ``auv/<v>/pilot/ack`` (``{"t": s, "seq": n}``: the odometry time acted
on, held back to half the feedback timeout past the newest actuator feedback when the feedback
is checked; the sequence number of the newest command sent, with :class:`BusCommands`; type
``PilotAck``), which lets the sim's clock run on once its controller has that command. Each step's
:class:`~auvgw.control.autopilot.ActuatorCommand` goes to the ``sink`` (a
:data:`~auvgw.control.autopilot.CommandSink`; :class:`BusCommands` puts it on
``auv/<v>/cmd/<device>`` as the actuators' ``ActuatorCommand``, which the gateway checks and
sends on CAN) and is published.

Published (JSON): ``auv/<v>/pilot/command`` (``t``, ``rpm``, ``rudder``, ``stern`` rad; type
``PilotCommand``) and ``auv/<v>/pilot/state`` (``t``, ``mode``, ``leg``, ``n_legs``,
``cross_track`` m, ``along_track`` m, ``heading_d`` / ``pitch_d`` rad, ``depth_d`` m,
``speed_d`` m/s, ``abort_reason``, ``abort_detail``; type ``PilotState``) every step; counters
on ``auv/<v>/status/pilot``.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Protocol, runtime_checkable

import zenoh
from pydantic import Field

from auvgw.control.autopilot import (
    ActuatorCommand,
    ActuatorFeedback,
    Autopilot,
    AutopilotConfig,
    CommandSink,
    NavFix,
)
from auvgw.control.mission import Mission
from auvgw.fusion.odometry import Odometry
from auvgw.stages.base import BusCounters, Stage, StageConfig

__all__ = ["ACK", "BusCommands", "PilotStage", "PilotStageConfig", "PilotStats", "nav_fix"]


#: the output a lock-step sim waits on (``auv/<v>/pilot/ack``)
ACK = "ack"


class PilotStageConfig(StageConfig):
    """Settings of the pilot stage: ``control_period_s`` (s of odometry time between steps);
    the abort thresholds the command line sets (``nav_timeout_s``, ``max_depth`` m,
    ``feedback_timeout_s``: 0 = no actuator feedback expected, so no fin or thruster checks)."""

    control_period_s: float = Field(0.05, gt=0)
    #: the device whose feedback the stage takes and whose command key it writes
    actuators_device: str = Field("actuators", min_length=1, max_length=64)
    nav_timeout_s: float = Field(0.5, gt=0)
    max_depth: float = Field(60.0, gt=0)
    feedback_timeout_s: float = Field(0.5, ge=0)
    #: the fin servos' slew rate (deg/s) the jam check expects: the vehicle's controller's (the
    #: emulated one's ``fin_rate_dps``, 30 by default)
    fin_rate_dps: float = Field(30.0, gt=0, le=1000)
    #: the fin servos' time constant (s) the jam check expects (the emulated one's
    #: ``fin_tau_s``, 0.1 by default): while a fin moves it runs rate x tau behind a pure slew
    fin_tau_s: float = Field(0.1, ge=0, le=10)
    #: a lock-step sim's clock file: the timer counts its vehicle time, odometry is answered
    lockstep_clock: str | None = Field(None, min_length=1, max_length=4096)

    def autopilot(self) -> AutopilotConfig:
        return AutopilotConfig(nav_timeout_s=self.nav_timeout_s, max_depth=self.max_depth,
                               feedback_timeout_s=self.feedback_timeout_s,
                               fin_rate=math.radians(self.fin_rate_dps),
                               fin_tau=self.fin_tau_s)  # fmt: skip


@runtime_checkable
class ActuatorStateLike(Protocol):
    """The actuators' ``ActuatorState`` sample (the DBC's, decoded): what the stage reads of it
    (rpm, rudder and stern plane rad, fault word, the ``cmd_seq`` last applied)."""

    @property
    def shaft_rpm(self) -> float: ...
    @property
    def rudder(self) -> float: ...
    @property
    def stern(self) -> float: ...
    @property
    def faults(self) -> int: ...
    @property
    def cmd_seq(self) -> int: ...


@dataclass
class PilotStats(BusCounters):
    """Counters of the stage (``received``: odometry samples used)."""

    feedback: int = 0  #: actuator feedback samples
    steps: int = 0  #: autopilot steps (each one command)
    timer_steps: int = 0  #: of them, steps the timer made while no input came


def nav_fix(o: Odometry) -> NavFix:
    """The autopilot's view of one fusion odometry sample."""
    u, v, w = o.velocity_body
    p, q, r = o.angular_rate
    return NavFix(o.t, o.x, o.y, o.z, o.roll, o.pitch, o.heading, u, v, w, p, q, r)


class PilotStage(Stage):
    """The autopilot on the bus (see the module docstring): ``mission`` flown with ``config``;
    ``sink`` gets every command; ``session`` None: in-process only."""

    name = "pilot"
    status_schema = "PilotStatus"
    outputs = ("command", "state", ACK)

    def __init__(
        self,
        mission: Mission,
        config: PilotStageConfig | None = None,
        session: zenoh.Session | None = None,
        *,
        sink: CommandSink | None = None,
        on_publish: Callable[[str, bytes, int], object] | None = None,
    ) -> None:
        self.config = config or PilotStageConfig()
        self.stats: PilotStats = PilotStats()
        super().__init__(self.config, self.stats, session, on_publish=on_publish)
        self.mission = mission
        self.autopilot = Autopilot(mission, self.config.autopilot())
        self.sink = sink
        self._t_last_step: float | None = None  # of the last input-driven step
        self._t_stepped: float | None = None  # of the last step, input or timer
        self._t_feedback: float | None = None  # newest actuator feedback time (s)
        self._period_tol = self.config.control_period_s * (1.0 - 1e-6)  # inputs at the period
        self._t_input: float | None = None  # newest odometry time (s)
        self._host_input: float | None = None  # the timer's clock when it came (s)
        self._clock: Callable[[], float | None] = time.monotonic
        if self.config.lockstep_clock is not None:
            from auvgw.ground.simclock import ClockFileReader

            self._clock = ClockFileReader(self.config.lockstep_clock).vehicle_s
        self._timer_stop = threading.Event()
        self._timer: threading.Thread | None = None

    def key(self, what: str) -> str:
        """``auv/<v>/pilot/<what>``."""
        return f"{self.keys.base}/pilot/{what}"

    def input_keys(self) -> list[str]:
        return [self.keys.odometry(), self.keys.sensor(self.config.actuators_device, "*")]

    def feed(self, device: str, t_recv_ns: int, message: object) -> object:
        """The actuators' ``ActuatorState`` (measured rpm, fin angles in rad, fault word) as
        feedback at its receive stamp; anything else is ignored."""
        if device == self.config.actuators_device and isinstance(message, ActuatorStateLike):
            sent_at = getattr(self.sink, "sent_at", None)
            cmd_t = sent_at(int(message.cmd_seq)) if sent_at is not None else None
            if sent_at is not None and cmd_t is None:
                cmd_t = -math.inf  # they echo no command of ours: applying none yet
            self.feed_actuators(ActuatorFeedback(
                t=t_recv_ns * 1e-9, rpm=float(message.shaft_rpm), rudder=float(message.rudder),
                stern=float(message.stern), faults=int(message.faults), cmd_t=cmd_t))  # fmt: skip
        return None

    # -- inputs ---------------------------------------------------------------------------------
    def feed_odometry(self, o: Odometry) -> None:
        with self._lock:
            self.stats.received += 1
            self.autopilot.nav(nav_fix(o))
            self._input(o.t)

    def feed_actuators(self, fb: ActuatorFeedback) -> None:
        """One actuator feedback sample (the source interface; ``fb.t`` on the odometry clock)."""
        with self._lock:
            self.stats.feedback += 1
            self.autopilot.feedback(fb)
            if self._t_feedback is None or fb.t > self._t_feedback:
                self._t_feedback = fb.t

    def post_actuators(self, fb: ActuatorFeedback) -> None:
        """:meth:`feed_actuators` on the worker thread (after :meth:`start`)."""
        self._post(self.feed_actuators, (fb,))

    def _input(self, t: float) -> None:
        if self._t_input is None or t > self._t_input:
            self._t_input = t
            self._host_input = self._clock()
        # timer steps do not count here: an input that comes back steps at once
        if self._t_last_step is None or t - self._t_last_step >= self._period_tol:
            self._t_last_step = t
            self._step(t)
        if self.config.lockstep_clock is not None:  # answered up to t (after its command)
            self.publish_json(ACK, self._ack(t), t, "PilotAck")

    def _ack(self, t: float) -> dict[str, float | int]:
        """The lock-step answer to odometry time ``t``: ``{"t": s}`` (:meth:`_ack_time`), plus
        ``seq``, the sequence number of the newest command sent, when the sink numbers them
        (:class:`BusCommands`): the sim counts the answer once its controller has applied it."""
        body: dict[str, float | int] = {"t": self._ack_time(t)}
        seq = getattr(self.sink, "seq", None)
        if isinstance(seq, int):
            body["seq"] = seq
        return body

    def _ack_time(self, t: float) -> float:
        """The time a lock-step sim may take as answered: the odometry's ``t``, held back to
        half the feedback timeout past the newest actuator feedback once feedback is judged
        (the sim then waits for a starved feedback path instead of the pilot calling the
        actuators silent; a really silent one still passes the timeout after the sim's hold
        timeouts)."""
        fto = self.config.feedback_timeout_s
        if fto > 0 and self._t_feedback is not None:
            return min(t, self._t_feedback + fto / 2)
        return t

    def tick(self) -> None:
        """Step on the timer's clock (host; vehicle in lock-step) while no odometry comes (the
        timer calls it on the worker)."""
        with self._lock:
            now = self._clock()
            if self._t_input is None or now is None:
                return
            if self._host_input is None:  # the lock-step clock appeared after the input
                self._host_input = now
            idle = now - self._host_input
            t = self._t_input + idle
            # a period on from the last step too: a lock-step clock stands still while the sim
            # holds, and stepping again at the same time would flood the actuators
            if idle >= self.config.control_period_s and (
                    self._t_stepped is None or t - self._t_stepped >= self._period_tol):
                self.stats.timer_steps += 1
                self._step(t)

    def _step(self, t: float) -> None:
        self._t_stepped = t
        cmd = self.autopilot.step(t)
        self.stats.steps += 1
        if self.sink is not None:
            self.sink(cmd)
        self.publish_json("command", command_json(cmd), t, "PilotCommand")
        self.publish_json("state", self.state_json(), t, "PilotState")

    def state_json(self) -> dict[str, object]:
        """The autopilot's state as published on ``pilot/state``."""
        s = self.autopilot.status
        body = asdict(s)
        body.pop("command")
        return body

    def status_fields(self) -> dict[str, object]:
        s = self.autopilot.status
        return {"mission": self.mission.name, "mode": s.mode, "leg": s.leg, "n_legs": s.n_legs,
                "abort_reason": s.abort_reason}  # fmt: skip

    # -- the timer ------------------------------------------------------------------------------
    def _work_started(self) -> None:  # the control timer runs while the worker does
        if self._timer is None and not self._timer_stop.is_set():
            self._timer = threading.Thread(target=self._run_timer, name="pilot-timer", daemon=True)
            self._timer.start()

    def _run_timer(self) -> None:
        while not self._timer_stop.wait(self.config.control_period_s):
            self._enqueue(self.tick, ())

    def on_stop(self) -> None:
        """The control timer first: no tick is queued once the queue drains."""
        self._timer_stop.set()
        if self._timer is not None:
            self._timer.join()


class BusCommands:
    """A :data:`~auvgw.control.autopilot.CommandSink` that puts each command on
    ``auv/<v>/cmd/<device>`` as the actuators' DBC ``ActuatorCommand`` (rpm, rudder and stern
    plane in rad, a sequence number counting from 1; the gateway's gate starts a new stream
    after a quiet spell, so a restarted pilot is taken)."""

    def __init__(self, session: zenoh.Session, vehicle: str, device: str = "actuators") -> None:
        from auvgw.bus import Keys
        from auvgw.drivers.actuators import COMMAND_TYPE, SEQ_MODULO, actuators_can

        self._type = actuators_can().types[COMMAND_TYPE]
        self._modulo = SEQ_MODULO
        self._pub = session.declare_publisher(Keys(vehicle).cmd(device))
        # the first command is 1: the controller echoes 0 before it has applied any
        self.seq = 0
        self._sent: dict[int, float] = {}  # seq -> the command's time (s), the last 1024

    def sent_at(self, seq: int) -> float | None:
        """The time (s, the odometry clock) of the command sent with ``seq`` (None: unknown):
        the actuators echo the last one they applied, so the loop's latency is known."""
        return self._sent.get(seq)

    def __call__(self, cmd: ActuatorCommand) -> None:
        from auvgw.envelope import encode_envelope

        self.seq = (self.seq + 1) % self._modulo
        self._sent[self.seq] = cmd.t
        self._sent.pop((self.seq - 1024) % self._modulo, None)
        msg = self._type(seq=self.seq, shaft_rpm=cmd.rpm, rudder=cmd.rudder, stern=cmd.stern)
        self._pub.put(encode_envelope(msg, "pilot", round(cmd.t * 1e9), self.seq)[0])

    def close(self) -> None:
        """Withdraw the publisher."""
        self._pub.undeclare()


def command_json(cmd: ActuatorCommand) -> dict[str, float]:
    """An actuator command as published on ``pilot/command``."""
    return asdict(cmd)
