"""The actuators' controller emulator: thruster, rudder and stern plane on CAN (``actuators.dbc``).

:class:`ActuatorModel` (pure) is the controller's physics. Each axis (shaft speed rpm, rudder
rad, stern plane rad) follows its command as a first-order lag with time constant ``tau_s``,
its speed limited to ``rate`` per second, the command saturated at ``limit``; inside the dead
band (``|command - position| <= dead_band``) the axis does not move, so it settles within the
dead band of its command. A command timeout (no command for ``command_timeout_s`` vehicle
seconds) stops the thruster (command 0) and sets the ``command_timeout`` fault bit until the
next command; the fins hold their last command. Faults from the scenario's fault windows
(:meth:`~auvgw.sim_devices.faults.FaultInjector.actuator_faults`): ``rudder_jam`` /
``stern_jam`` freeze the fin where it is; ``thruster_silent`` (the motor driver stops
answering) lets the shaft coast down (command 0, no current). Motor current is
``idle_a + k_a * (rpm / 1000)^2``; beyond ``max_current_a`` the ``overcurrent`` bit is set.

:class:`ActuatorEmulator` is the device: an emulated SLCAN adapter (``<port_dir>/actuators``)
on which the host's ``ActuatorCommand`` frames arrive (applied at the vehicle time they arrive)
and ``ActuatorState`` feedback leaves at ``rate_hz`` (20 Hz). In a closed-loop scenario
(``vehicle.mode = "dynamics"``) it is the truth's input: each dynamics step reads the model's
rudder, stern plane and shaft speed (:meth:`ActuatorEmulator.inputs`). ``on_applied(seq)``
(optional) is told the sequence number of every command applied.

:class:`CommandGate` is the lock-step sim's side of a command's way back: a controller's answer
that carries the ``seq`` of its newest command counts only once the controller has applied that
command (or a newer one), so vehicle time never runs on while a command is still on its way.

Options: ``can_bitrate`` (500000), ``max_rpm`` (1525), ``rpm_rate`` (rpm/s, 1000),
``rpm_tau_s`` (0.3), ``rpm_dead_band`` (5), ``max_fin_deg`` (20), ``fin_rate_dps`` (30),
``fin_tau_s`` (0.1), ``fin_dead_band_deg`` (0.2), ``command_timeout_s`` (1.0),
``max_current_a`` (6.0), ``idle_a`` (0.3), ``k_a`` (A per (krpm)^2, 2.0), ``rpm`` (initial
shaft speed and command; default the scenario's ``vehicle.dynamics.rpm``).
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers.actuators import COMMAND_TYPE, FAULT_BITS, SEQ_MODULO, actuators_can
from auvgw.drivers.can_codec import CanCodecError, CanFrame
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.emulator import Emulator, SimContext

__all__ = ["ActuatorEmulator", "ActuatorLimits", "ActuatorModel", "AxisLimits", "CommandGate",
           "Reading"]

#: longest integration sub-step of the axes, vehicle s
SUBSTEP_S = 0.005


@dataclass(frozen=True)
class AxisLimits:
    """One axis: saturation ``limit``, ``rate`` limit (per s), first-order ``tau_s`` (s) and
    ``dead_band``, in the axis's units (rpm, or rad for a fin)."""

    limit: float
    rate: float
    tau_s: float
    dead_band: float

    def __post_init__(self) -> None:
        if not (self.limit > 0 and self.rate > 0 and self.tau_s > 0 and self.dead_band >= 0):
            raise ValueError(f"actuator axis limits must be positive: {self}")


@dataclass(frozen=True)
class ActuatorLimits:
    """The controller's limits (defaults: a REMUS 100 class vehicle; fins 20 deg, the dynamics
    model's limit, and 1525 rpm, its top-speed shaft speed)."""

    thruster: AxisLimits = AxisLimits(1525.0, 1000.0, 0.3, 5.0)
    fin: AxisLimits = AxisLimits(math.radians(20), math.radians(30), 0.1, math.radians(0.2))
    command_timeout_s: float = 1.0
    max_current_a: float = 6.0
    idle_a: float = 0.3
    k_a: float = 2.0  #: A per (1000 rpm)^2


@dataclass(frozen=True)
class Reading:
    """What the controller measures at one instant: shaft ``rpm``, ``rudder`` and ``stern``
    (rad), motor ``current_a``, the fault word ``faults`` and the last applied ``cmd_seq``."""

    t: float
    rpm: float
    rudder: float
    stern: float
    current_a: float
    faults: int
    cmd_seq: int


def _axis_step(x: float, cmd: float, lim: AxisLimits, h: float) -> float:
    """One sub-step of ``h`` s of an axis at ``x`` towards ``cmd`` (see the module docstring)."""
    target = min(max(cmd, -lim.limit), lim.limit)
    e = target - x
    if abs(e) <= lim.dead_band:
        return x
    dx = e * (1.0 - math.exp(-h / lim.tau_s))  # exact first-order response over h
    cap = lim.rate * h
    return x + (cap if dx > cap else -cap if dx < -cap else dx)


@dataclass
class ActuatorModel:
    """The controller's state, advanced on request (see the module docstring).

    ``faults_at(t)`` names the fault windows active at vehicle time ``t`` (default none).
    """

    limits: ActuatorLimits = ActuatorLimits()
    rpm: float = 0.0
    faults_at: Callable[[float], frozenset[str]] = field(default=lambda _t: frozenset())
    t: float = 0.0
    rudder: float = 0.0
    stern: float = 0.0
    cmd_rpm: float = 0.0
    cmd_rudder: float = 0.0
    cmd_stern: float = 0.0
    cmd_seq: int = 0
    last_command_t: float = 0.0
    timed_out: bool = False
    commands: int = 0  #: commands received (applied or still pending)
    _pending: deque[tuple[float, float, float, float, int]] = field(
        default_factory=deque, repr=False)  # (arrival vehicle s, rpm, rudder, stern, seq)

    def __post_init__(self) -> None:
        self.cmd_rpm = self.rpm

    def command(self, t: float, rpm: float, rudder: float, stern: float, seq: int) -> None:
        """A command arriving at vehicle time ``t`` (rpm, rad, rad; its sequence number).

        It takes effect when the integration reaches ``t``: a reading for an earlier time (a
        feedback tick dispatched late on a busy host) does not see it yet. A command for a time
        the model has already passed takes effect at once."""
        self.commands += 1
        if t <= self.t:
            self._apply(t, rpm, rudder, stern, seq)
        else:
            self._pending.append((t, rpm, rudder, stern, seq))

    def _apply(self, t: float, rpm: float, rudder: float, stern: float, seq: int) -> None:
        self.cmd_rpm, self.cmd_rudder, self.cmd_stern = rpm, rudder, stern
        self.cmd_seq = seq % SEQ_MODULO
        self.last_command_t = max(t, self.t)
        self.timed_out = False

    def advance(self, t: float) -> None:
        """Integrate the axes up to vehicle time ``t`` (a time already passed: nothing),
        applying each pending command at its own time."""
        lim = self.limits
        while True:
            while self._pending and self._pending[0][0] <= self.t + 1e-12:
                self._apply(*self._pending.popleft())
            if self.t >= t - 1e-12:
                return
            h = min(SUBSTEP_S, t - self.t)
            if self._pending:
                h = min(h, self._pending[0][0] - self.t)
            active = self.faults_at(self.t)
            if self.t - self.last_command_t >= lim.command_timeout_s:
                self.timed_out = True
            rpm_cmd = 0.0 if self.timed_out or "thruster_silent" in active else self.cmd_rpm
            self.rpm = _axis_step(self.rpm, rpm_cmd, lim.thruster, h)
            if "rudder_jam" not in active:
                self.rudder = _axis_step(self.rudder, self.cmd_rudder, lim.fin, h)
            if "stern_jam" not in active:
                self.stern = _axis_step(self.stern, self.cmd_stern, lim.fin, h)
            self.t += h

    def inputs(self, t: float) -> tuple[float, float, float]:
        """``(rudder rad, stern rad, rpm)`` at vehicle time ``t``: the dynamics' inputs."""
        self.advance(t)
        return (self.rudder, self.stern, self.rpm)

    def read(self, t: float) -> Reading:
        """The measurement at vehicle time ``t`` (advances to it)."""
        self.advance(t)
        lim = self.limits
        active = self.faults_at(t)
        silent = "thruster_silent" in active
        current = 0.0 if silent else lim.idle_a + lim.k_a * (self.rpm / 1000.0) ** 2
        word = 0
        for name, on in (
            ("rudder_jammed", "rudder_jam" in active),
            ("stern_jammed", "stern_jam" in active),
            ("thruster_no_answer", silent),
            ("overcurrent", current > lim.max_current_a),
            ("command_timeout", self.timed_out),
        ):
            if on:
                word |= FAULT_BITS[name]
        return Reading(t, self.rpm, self.rudder, self.stern, current, word, self.cmd_seq)


class ActuatorEmulator(Emulator):
    """The actuators' controller on CAN (see the module docstring)."""

    kind = "actuators"
    nominal_rate_hz = 20.0

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        rpm0 = self.option("rpm", float(ctx.scenario.vehicle.dynamics.rpm))
        deg = math.radians
        limits = ActuatorLimits(
            thruster=AxisLimits(
                self.option("max_rpm", 1525.0), self.option("rpm_rate", 1000.0),
                self.option("rpm_tau_s", 0.3), self.option("rpm_dead_band", 5.0),
            ),
            fin=AxisLimits(
                deg(self.option("max_fin_deg", 20.0)), deg(self.option("fin_rate_dps", 30.0)),
                self.option("fin_tau_s", 0.1), deg(self.option("fin_dead_band_deg", 0.2)),
            ),
            command_timeout_s=self.option("command_timeout_s", 1.0),
            max_current_a=self.option("max_current_a", 6.0),
            idle_a=self.option("idle_a", 0.3),
            k_a=self.option("k_a", 2.0),
        )  # fmt: skip
        self.model = ActuatorModel(limits, rpm=rpm0, faults_at=self.faults.actuator_faults)
        self._model_lock = threading.Lock()
        self.codec = actuators_can()
        self._command_type: Any = self.codec.types[COMMAND_TYPE]
        self.host = Counter({"commands": 0, "bad_frames": 0, "other_frames": 0})
        self.counter = 0
        self.can = self.add_can(
            "actuators.dbc", self.option("can_bitrate", 500_000), name=self.name
        )
        self.can.adapter.on_frame = self._on_frame
        #: told the sequence number of every command applied (a lock-step :class:`CommandGate`)
        self.on_applied: Callable[[int], object] | None = None
        if isinstance(ctx.truth, ClosedLoopTruth):
            ctx.truth.set_inputs(self.inputs)

    def inputs(self, t: float) -> tuple[float, float, float]:
        """The closed-loop truth's inputs at vehicle time ``t`` (rudder, stern rad; rpm)."""
        with self._model_lock:
            return self.model.inputs(t)

    def _on_frame(self, frame: Any) -> None:
        """A frame the host sent (pty I/O thread): a command is applied now (vehicle time)."""
        try:
            msg = self.codec.decode_frame(frame)
        except CanCodecError:
            self.host["bad_frames"] += 1
            return
        if type(msg) is not self._command_type:
            self.host["other_frames"] += 1
            return
        with self._model_lock:
            self.model.command(self.clock.now(), msg.shaft_rpm, msg.rudder, msg.stern, msg.seq)
        self.host["commands"] += 1
        if self.on_applied is not None:
            self.on_applied(int(msg.seq))

    def measure(self, t: float) -> Reading:
        """The controller's reading at vehicle time ``t``."""
        with self._model_lock:
            return self.model.read(t)

    def encode(self, r: Reading) -> list[CanFrame]:
        """The two frames of one feedback sample."""
        assert self.codec.sample_type is not None
        sample = self.codec.sample_type(
            counter=self.counter % SEQ_MODULO, shaft_rpm=r.rpm, rudder=r.rudder, stern=r.stern,
            motor_current=min(r.current_a, 655.35), faults=r.faults, cmd_seq=r.cmd_seq,
        )  # fmt: skip
        self.counter += 1
        return self.codec.encode_sample(sample, strict=False)

    def tick(self, t: float) -> None:
        self.can.send(self.encode(self.measure(t)), t)

    def stats(self) -> dict[str, Any]:
        """The base counters plus the host's frames (commands applied, undecodable, other)."""
        return {**super().stats(), "host": dict(self.host)}


class CommandGate:
    """Lock-step answers gated on the command's way back: :meth:`answered` (vehicle s, the
    ``seq`` of the newest command the controller had sent when it answered; None or 0: none)
    passes to ``answered`` at once when the actuators' controller has already applied ``seq``
    or a newer command (:meth:`applied`), else when it does. Sequence numbers compare modulo
    ``SEQ_MODULO`` (newer: less than half the modulo ahead), so a lost command is covered by
    the next one applied. At most ``max_pending`` answers wait (the oldest passes first)."""

    def __init__(self, answered: Callable[[float], object], max_pending: int = 4096) -> None:
        self._answered = answered
        self._lock = threading.Lock()
        self._applied: int | None = None  # newest seq applied
        self._pending: deque[tuple[int, float]] = deque()  # (seq, vehicle s), in answer order
        self._max_pending = max_pending
        self.waited = 0  #: answers that waited for their command

    def _covers(self, seq: int) -> bool:
        a = self._applied
        return a is not None and (a - seq) % SEQ_MODULO < SEQ_MODULO // 2

    def answered(self, t: float, seq: int | None) -> None:
        """The controller answered up to vehicle time ``t`` after sending command ``seq``."""
        release: list[float] = []
        with self._lock:
            if not seq or (not self._pending and self._covers(seq % SEQ_MODULO)):
                release.append(t)
            else:
                self.waited += 1
                self._pending.append((seq % SEQ_MODULO, t))
                while len(self._pending) > self._max_pending:
                    release.append(self._pending.popleft()[1])
        for tr in release:
            self._answered(tr)

    def applied(self, seq: int) -> None:
        """The controller applied command ``seq``: the answers it covers pass, in order."""
        release: list[float] = []
        with self._lock:
            self._applied = seq % SEQ_MODULO
            while self._pending and self._covers(self._pending[0][0]):
                release.append(self._pending.popleft()[1])
        for tr in release:
            self._answered(tr)

    @property
    def pending(self) -> int:
        """Answers waiting for their command now."""
        with self._lock:
            return len(self._pending)
