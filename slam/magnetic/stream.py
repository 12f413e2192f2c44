"""A simulated run of a beacons scenario as the online magnetic stage's inputs, in arrival order
(tests and benchmarks of :class:`auvgw.stages.magnetic.MagneticStage`, in process or on the bus).

The evaluation's ``mlp`` track (:func:`~auvgw.slam.magnetic.evaluation.prepare`,
:func:`~auvgw.slam.magnetic.evaluation.magnetometer_stream`) gives the vehicle's truth, its
controls, the MS3A samples (20 Hz, body axes, nT) and the INS attitude with its errors. Here they
become what the bus carries: fusion-like :class:`~auvgw.fusion.Odometry` at every control step
(dead reckoning of the controls, NED m / rad, the INS attitude at that time, the step's
:class:`~auvgw.fusion.MotionIncrement`), the magnetometer samples once the odometry covers them,
and the acoustic replies at the scan times, received after the two-way travel time.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.slam.magnetic.evaluation import Prepared, Variant, magnetometer_stream, prepare

__all__ = ["StageInputs", "motion_increment", "odometry_sample", "stage_inputs"]


def odometry_sample(
    t: float, pose: np.ndarray, att: np.ndarray, inc: MotionIncrement | None
) -> Odometry:
    """Odometry at ``t`` s: ``pose (x, y, heading)`` (NED m, rad), ``att (heading, pitch, roll)``
    rad, the step's increment."""
    return Odometry(
        t=t, x=float(pose[0]), y=float(pose[1]), z=0.0, roll=float(att[2]), pitch=float(att[1]),
        heading=float(att[0]), velocity_ned=(0.0, 0.0, 0.0), velocity_body=(0.0, 0.0, 0.0),
        angular_rate=(0.0, 0.0, 0.0), covariance=np.eye(8), bottom_lock=True, coasting=False,
        dvl_age_s=0.0, depth_age_s=0.0, ins_gap=False, increment=inc,
    )  # fmt: skip


def motion_increment(t0: float, dt: float, a: np.ndarray, b: np.ndarray) -> MotionIncrement:
    """The body-frame increment from pose ``a`` to pose ``b`` (x, y, heading) over ``dt`` s."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = c * (b[0] - a[0]) + s * (b[1] - a[1]), -s * (b[0] - a[0]) + c * (b[1] - a[1])
    dh = math.remainder(b[2] - a[2], math.tau)
    return MotionIncrement(
        t0=t0, t1=t0 + dt, dx=dx, dy=dy, dz=0.0, dheading=dh, covariance=np.eye(3) * 1e-4,
        dt=dt, v_forward=dx / dt, v_starboard=dy / dt, yaw_rate=dh / dt,
    )  # fmt: skip


@dataclass
class StageInputs:
    """One simulated run: ``prep`` (the evaluation's run: ``prep.sim.truth``, ``dt``...), the
    dead-reckoning poses at every control step ``dr (K+1, 3)``, the MS3A stream ``t_mag (N,)``,
    ``b_body (N, 3)`` and the acoustic replies ``acoustic (M, 4)`` (receive time s, slant range
    m, bearing rad, depression rad)."""

    prep: Prepared
    dr: np.ndarray
    att: np.ndarray
    t_mag: np.ndarray
    b_body: np.ndarray
    acoustic: np.ndarray
    sound_speed_mps: float

    @property
    def duration_s(self) -> float:
        """Vehicle time covered, s."""
        return float(len(self.prep.sim.controls) * self.prep.sim.dt)

    def events(self, t0: float = 0.0) -> Iterator[tuple[str, tuple[Any, ...]]]:
        """``(kind, args)`` in arrival order, times shifted by ``t0`` s: ``("odometry",
        (Odometry,))``, ``("mag", (t, b_body))``, ``("acoustic", (t_recv, range, bearing,
        depression))`` (the stage's ``feed_*`` arguments)."""
        sim = self.prep.sim
        k_mag = k_ac = 0
        for k in range(len(sim.controls) + 1):
            t = k * sim.dt
            inc = None
            if k:
                inc = motion_increment(t0 + t - sim.dt, sim.dt, self.dr[k - 1], self.dr[k])
            yield "odometry", (odometry_sample(t0 + t, self.dr[k], self.att[k], inc),)
            while k_mag < len(self.t_mag) and self.t_mag[k_mag] <= t:
                yield "mag", (t0 + float(self.t_mag[k_mag]), self.b_body[k_mag])
                k_mag += 1
            while k_ac < len(self.acoustic) and self.acoustic[k_ac, 0] <= t:
                tr, r, b, d = self.acoustic[k_ac]
                yield "acoustic", (t0 + float(tr), float(r), float(b), float(d))
                k_ac += 1

    def feed(self, stage: Any, t0: float = 0.0) -> None:
        """Feed every event to ``stage`` (``feed_odometry``, ``feed_mag``, ``feed_acoustic``)."""
        for kind, args in self.events(t0):
            getattr(stage, f"feed_{kind}")(*args)


def stage_inputs(
    scenario: Path, max_steps: int | None = None, seed: int = 2, mag_seed: int = 9
) -> StageInputs:
    """Simulate ``max_steps`` control steps of ``scenario`` (a beacons scenario, e.g.
    ``beacons_amb.json``) as :class:`StageInputs` (see the module docstring)."""
    scn = load_scenario(scenario)
    v = Variant(track="mlp")
    prep = prepare(scn, v, seed=seed, run=0, max_steps=max_steps)
    sim = prep.sim
    ts, b_body, att, _ = magnetometer_stream(
        scn, sim, v, np.random.default_rng(mag_seed), np.ones(len(scn.magnetic_beacons), bool)
    )
    model = sim.motion_model()
    dr = [np.asarray(sim.truth[0], float)]
    for u in sim.controls:
        dr.append(np.asarray(model.f(dr[-1], u, sim.dt), float))
    att_u = np.column_stack([np.unwrap(att[:, 0]), att[:, 1], att[:, 2]])
    t_ctl = np.arange(len(dr)) * sim.dt
    att_ctl = np.column_stack([np.interp(t_ctl, ts, att_u[:, i]) for i in range(3)])
    c = scn.sound_speed_mps
    scan_t = sim.obs_step * sim.dt
    ok = ~np.isnan(prep.acoustic_z[:, 0])
    rng_m, brg = prep.acoustic_z[ok, 0], prep.acoustic_z[ok, 1]
    acoustic = np.column_stack([scan_t[ok] + 2 * rng_m / c, rng_m, brg, np.zeros(ok.sum())])
    return StageInputs(prep=prep, dr=np.asarray(dr), att=att_ctl, t_mag=ts, b_body=b_body,
                       acoustic=acoustic, sound_speed_mps=c)  # fmt: skip
