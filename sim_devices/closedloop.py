"""Closed-loop ground truth: the 6-DOF dynamics integrated online from the actuators' state.

In a scenario with ``vehicle.mode = "dynamics"`` the truth is not precomputed from the route:
:class:`ClosedLoopTruth` integrates :func:`auvgw.sim_devices.dynamics.step` (RK4) at the fixed
step ``vehicle.dynamics.dt_s`` of vehicle time, on request. Whoever samples it (every emulator,
at its own ticks on the one simulation clock, and the truth log) calls :meth:`at`; the state
is integrated up to that time first, each step with the inputs ``[rudder rad, stern rad, rpm]``
its ``inputs(t)`` callable gives at the step's start (the actuator emulator's measured state,
:mod:`auvgw.sim_devices.actuators`; without one, the scenario's constant
``vehicle.dynamics.rpm`` and zero fins). The vehicle therefore moves on the world clock, so
``--speed`` scales it like everything else, and a command changes what every emulator reports
from the next step on.

A *captive* start (:meth:`ClosedLoopTruth.hold_captive`, what a lock-step sim does until the
controller under test first answers): the vehicle runs straight at its start attitude and body
velocity (position integrated, nothing else changes, the inputs unread), as on a launch rail,
until :meth:`ClosedLoopTruth.release`; the dynamics take over from that state. Without it a
controller that comes up late (the fusion's clock warm-up holds the first odometry back) leaves
the open-loop unstable vehicle uncontrolled for that long.

Sampling a past time (the sonar's ping time) interpolates the stored steps of the last
``history_s`` seconds. The fields are those of :class:`~auvgw.sim_devices.vehicle.Truth`:
``u, v`` are the body surge and sway over ground, ``w`` the vertical speed (down), ``yaw_rate,
roll_rate, pitch_rate`` the Euler angle rates (as in the scripted truth; they were the body rates
r, p, q, which the INS then turned as if Euler rates: 4 % of r and a q sin(roll) share wrong at
the 16 deg of roll the propeller torque gives), ``an, ae, ad`` the NED acceleration over the
last step, ``speed`` the speed through the water and ``steer`` 0. Pure apart from a lock: no
clock, no port.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Callable, Sequence

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.sim_devices import dynamics
from auvgw.sim_devices.vehicle import TRUTH_FIELDS, TruthSample
from auvgw.sim_devices.world import World

__all__ = ["ClosedLoopTruth", "Inputs", "euler_rates"]

#: ``inputs(t) -> (rudder rad, stern rad, shaft rpm)`` at vehicle time ``t``
Inputs = Callable[[float], Sequence[float]]

_TWO_PI = 2.0 * math.pi
_HEADING = TRUTH_FIELDS.index("heading")
_ROLL = TRUTH_FIELDS.index("roll")


def euler_rates(roll: float, pitch: float, p: float, q: float,
                r: float) -> tuple[float, float, float]:  # fmt: skip
    """ZYX Euler angle rates (roll, pitch, heading rates, rad/s) from the body rates ``p, q, r``
    (rad/s, FRD) at ``roll``, ``pitch`` (rad): Fossen 2021 eq. 2.41, ``T(Theta) omega``. The
    truth's ``roll_rate, pitch_rate, yaw_rate`` are these (the INS turns them back into body
    rates, :func:`auvgw.sim_devices.ins.body_rates`)."""
    sf, cf = math.sin(roll), math.cos(roll)
    ct, tt = math.cos(pitch), math.tan(pitch)
    a = q * sf + r * cf
    return p + a * tt, q * cf - r * sf, a / ct


class ClosedLoopTruth:
    """The vehicle's ground truth integrated online (see the module docstring).

    ``params``: the vehicle (default: ``vehicle.dynamics.params`` of the scenario);
    ``inputs``: see :data:`Inputs` (settable later with :meth:`set_inputs`).
    """

    #: lets callers tell it from the precomputed :class:`~auvgw.sim_devices.vehicle.Truth`
    online = True

    def __init__(
        self,
        scn: Scenario,
        world: World,
        params: dynamics.VehicleParams | None = None,
        inputs: Inputs | None = None,
    ) -> None:
        cfg = scn.vehicle.dynamics
        self.scenario = scn
        self.world = world
        self.params = (
            params
            if params is not None
            else dynamics.load_params(
                scn.resolve_path(cfg.params) if cfg.params else dynamics.REMUS100_FILE
            )
        )
        self.dt = float(cfg.dt_s)
        self.history_s = float(cfg.history_s)
        self.current = np.array([*scn.vehicle.current_mps, 0.0])
        self._const = (0.0, 0.0, float(cfg.rpm))
        self._inputs: Inputs = inputs if inputs is not None else (lambda _t: self._const)
        x, y, h = scn.start_pose
        self.state = np.zeros(12)
        self.state[0] = float(scn.vehicle.speed_mps)
        self.state[6:9] = (x, y, float(scn.vehicle.depth_m))
        self.state[11] = h
        self.steps = 0
        #: vehicle s the captive start ended at (None: not released yet, or never captive)
        self.released_at: float | None = None
        self._captive = False
        self._lock = threading.Lock()
        self._t = 0.0
        self._heading = h  # unwrapped
        self._roll = 0.0
        self._vel = self._ned_velocity(self.state)
        self._times: list[float] = []
        self._rows: list[list[float]] = []
        self._record(np.zeros(3))

    # -- the Truth interface ------------------------------------------------------------------
    @property
    def duration(self) -> float:
        """The run's length: the scenario's ``duration_s`` (vehicle s)."""
        return float(self.scenario.duration_s or 0.0)

    @property
    def time(self) -> float:
        """Vehicle time of the newest integrated step, s."""
        return self._t

    def set_inputs(self, inputs: Inputs) -> None:
        """Take the inputs from ``inputs(t)`` from the next step on."""
        with self._lock:
            self._inputs = inputs

    def hold_captive(self) -> None:
        """Run straight at the start attitude and velocity from the next step on, until
        :meth:`release` (see the module docstring)."""
        with self._lock:
            self._captive = True

    def release(self) -> None:
        """End the captive start: the dynamics integrate from the next step on (once)."""
        with self._lock:
            if self._captive:
                self._captive = False
                self.released_at = self._t

    def at(self, t: float) -> TruthSample:
        """The truth at vehicle time ``t`` (s): integrates up to it first if it is ahead of
        the newest step; linear between steps, angles along the shortest way."""
        with self._lock:
            while self._t < t - 1e-9:
                self._step()
            ts, rows = self._times, self._rows
            if t <= ts[0]:
                vals = list(rows[0])
            elif t >= ts[-1]:
                vals = list(rows[-1])
            else:
                i = bisect.bisect_right(ts, t) - 1
                w = (t - ts[i]) / (ts[i + 1] - ts[i])
                a, b = rows[i], rows[i + 1]
                vals = [p + w * (q - p) for p, q in zip(a, b, strict=True)]
        for k in (_HEADING, _ROLL, TRUTH_FIELDS.index("pitch")):
            vals[k] = (vals[k] + math.pi) % _TWO_PI - math.pi
        vals[0] = float(t)
        return TruthSample(*vals)

    # -- integration ---------------------------------------------------------------------------
    def _ned_velocity(self, s: np.ndarray) -> np.ndarray:
        r = dynamics.rotation(float(s[9]), float(s[10]), float(s[11]))
        return np.asarray(r @ s[0:3], dtype=float)

    def _step(self) -> None:
        if self._captive:  # on the rail: only the position moves, at the NED velocity
            new = self.state.copy()
            new[6:9] += self._vel * self.dt
        else:
            u = np.asarray(self._inputs(self._t), dtype=float)
            new = dynamics.step(self.params, self.state, u, self.dt, self.current)
        self._heading += (float(new[11]) - self._heading + math.pi) % _TWO_PI - math.pi
        self._roll += (float(new[9]) - self._roll + math.pi) % _TWO_PI - math.pi
        self.state = new
        self._t = round((self.steps + 1) * self.dt, 9)
        self.steps += 1
        vel = self._ned_velocity(new)
        acc = (vel - self._vel) / self.dt
        self._vel = vel
        self._record(acc)

    def _record(self, acc: np.ndarray) -> None:
        s = self.state
        x, y, z = float(s[6]), float(s[7]), float(s[8])
        seabed = float(self.world.terrain.depth(np.array([x]), np.array([y]))[0])
        vn, ve, vd = (float(v) for v in self._vel)
        phi_dot, theta_dot, psi_dot = euler_rates(float(s[9]), float(s[10]), float(s[3]),
                                                  float(s[4]), float(s[5]))  # fmt: skip
        rel = s[0:3] - dynamics.rotation(float(s[9]), float(s[10]), float(s[11])).T @ self.current
        row = {
            "t": self._t, "x": x, "y": y, "z": z, "heading": self._heading, "roll": self._roll,
            "pitch": float(s[10]), "u": float(s[0]), "v": float(s[1]), "w": vd,
            "yaw_rate": psi_dot, "altitude": seabed - z, "seabed_depth": seabed,
            "roll_rate": phi_dot, "pitch_rate": theta_dot, "vn": vn, "ve": ve, "vd": vd,
            "an": float(acc[0]), "ae": float(acc[1]), "ad": float(acc[2]),
            "speed": float(np.linalg.norm(rel)), "steer": 0.0,
        }  # fmt: skip
        self._times.append(self._t)
        self._rows.append([row[f] for f in TRUTH_FIELDS])
        keep = int(self.history_s / self.dt) + 2
        if len(self._times) > 2 * keep:  # trim in batches: amortised O(1) per step
            del self._times[:-keep], self._rows[:-keep]
