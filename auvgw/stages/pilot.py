"""The autopilot stage: the fusion's odometry (and the actuators' feedback) in; actuator commands,
set-points and the autopilot's state out.

Inputs:

* **odometry** (``auv/<v>/nav/odometry``, :class:`~auvgw.fusion.Odometry`): position NED,
  attitude, body velocity and rates become a :class:`~auvgw.control.autopilot.NavFix`; its time
  ``t`` (s, the odometry clock) is the autopilot's vehicle time;
* **actuator feedback** (:class:`~auvgw.control.autopilot.ActuatorFeedback`, measured rpm, fin
  angles, fault word): through :meth:`PilotStage.feed_actuators` / :meth:`PilotStage.post_actuators`
  (the source interface: the gateway's actuator device is wired to it when it publishes one).

The autopilot steps on the odometry, every ``control_period_s`` of its time (the feedback is
latched for the next step); while no odometry arrives a timer (host clock) steps it on from the
last odometry's time plus the host time since, so a silent navigation is caught in
``nav_timeout_s`` + one period and the vehicle surfaces. Each step's
:class:`~auvgw.control.autopilot.ActuatorCommand` goes to the ``sink`` (a
:data:`~auvgw.control.autopilot.CommandSink`; wiring it to the bus key
``auv/<v>/cmd/actuators`` is one line once the gateway takes commands) and is published.

Published (JSON): ``auv/<v>/pilot/command`` (``t``, ``rpm``, ``rudder``, ``stern`` rad; type
``PilotCommand``) and ``auv/<v>/pilot/state`` (``t``, ``mode``, ``leg``, ``n_legs``,
``cross_track`` m, ``along_track`` m, ``heading_d`` / ``pitch_d`` rad, ``depth_d`` m,
``speed_d`` m/s, ``abort_reason``, ``abort_detail``; type ``PilotState``) every step; counters
on ``auv/<v>/status/pilot``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

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

__all__ = ["PilotStage", "PilotStageConfig", "PilotStats", "nav_fix"]


class PilotStageConfig(StageConfig):
    """Settings of the pilot stage: ``control_period_s`` (s of odometry time between steps);
    the abort thresholds the command line sets (``nav_timeout_s``, ``max_depth`` m,
    ``feedback_timeout_s``: 0 = no actuator feedback expected, so no fin or thruster checks)."""

    control_period_s: float = Field(0.05, gt=0)
    nav_timeout_s: float = Field(0.5, gt=0)
    max_depth: float = Field(60.0, gt=0)
    feedback_timeout_s: float = Field(0.5, ge=0)

    def autopilot(self) -> AutopilotConfig:
        return AutopilotConfig(nav_timeout_s=self.nav_timeout_s, max_depth=self.max_depth,
                               feedback_timeout_s=self.feedback_timeout_s)  # fmt: skip


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
    outputs = ("command", "state")

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
        self._period_tol = self.config.control_period_s * (1.0 - 1e-6)  # inputs at the period
        self._t_input: float | None = None  # newest odometry time (s)
        self._host_input = 0.0  # host monotonic time it came
        self._timer_stop = threading.Event()
        self._timer: threading.Thread | None = None

    def key(self, what: str) -> str:
        """``auv/<v>/pilot/<what>``."""
        return f"{self.keys.base}/pilot/{what}"

    def input_keys(self) -> list[str]:
        return [self.keys.odometry()]

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

    def post_actuators(self, fb: ActuatorFeedback) -> None:
        """:meth:`feed_actuators` on the worker thread (after :meth:`start`)."""
        self._post(self.feed_actuators, (fb,))

    def _input(self, t: float) -> None:
        if self._t_input is None or t > self._t_input:
            self._t_input = t
            self._host_input = time.monotonic()
        # timer steps do not count here: an input that comes back steps at once
        if self._t_last_step is None or t - self._t_last_step >= self._period_tol:
            self._t_last_step = t
            self._step(t)

    def tick(self) -> None:
        """Step on the host clock while no odometry comes (the timer calls it on the worker)."""
        with self._lock:
            if self._t_input is None:
                return
            idle = time.monotonic() - self._host_input
            if idle >= self.config.control_period_s:
                self.stats.timer_steps += 1
                self._step(self._t_input + idle)

    def _step(self, t: float) -> None:
        cmd = self.autopilot.step(t)
        self.stats.steps += 1
        if self.sink is not None:
            self.sink(cmd)
        self.publish_json("command", command_json(cmd), t, "PilotCommand")
        self.publish_json("state", self.state_json(), t, "PilotState")

    def state_json(self) -> dict[str, Any]:
        """The autopilot's state as published on ``pilot/state``."""
        s = self.autopilot.status
        body = asdict(s)
        body.pop("command")
        return body

    def status_fields(self) -> dict[str, Any]:
        s = self.autopilot.status
        return {"mission": self.mission.name, "mode": s.mode, "leg": s.leg, "n_legs": s.n_legs,
                "abort_reason": s.abort_reason}  # fmt: skip

    # -- the timer ------------------------------------------------------------------------------
    def start_worker(self) -> None:
        super().start_worker()
        if self._timer is None:
            self._timer = threading.Thread(target=self._run_timer, name="pilot-timer", daemon=True)
            self._timer.start()

    def _run_timer(self) -> None:
        while not self._timer_stop.wait(self.config.control_period_s):
            self._enqueue(self.tick, ())

    def stop(self, flush: bool = True, timeout_s: float = 5.0) -> None:
        self._timer_stop.set()
        if self._timer is not None:
            self._timer.join()
        super().stop(flush, timeout_s)


def command_json(cmd: ActuatorCommand) -> dict[str, float]:
    """An actuator command as published on ``pilot/command``."""
    return asdict(cmd)
