"""The low-cost vehicle of ``config/scenarios/lowcost.json`` for the fusion: the world model's
truth (``auvgw.sim_devices.vehicle.simulate``) sampled at the AHRS rate, and sensor samples
with the scenario's low-cost figures (``auvgw.fusion.synthetic.simulate_sensors``: AHRS with
white noise and a heading-dependent compass deviation, DVL at 1.5 Hz with white noise, spikes
and a mounting yaw). Used by tests/service/test_fusion_lowcost.py,
benchmarks/study_fusion_lowcost.py and the calibration test.

Filters compared: the fusion with its DEFAULT noise settings (spec prior, VB-adapted DVL noise)
and the mounting given in the config; the same filter told the TRUE DVL noise (fixed, not
adapted); the OLD defaults (a 0.002 m/s DVL, fixed); and a PLAIN rotate-and-integrate of the DVL
(each fix rotated by the mounting and the AHRS attitude at its time, held until the next fix).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.fusion import DvlMount, FusionConfig, InitialState, NavFilter, run_filter_arrays
from auvgw.fusion.align import interpolate_ins
from auvgw.fusion.frames import body_to_ned, mount_matrix
from auvgw.fusion.synthetic import SensorNoise, SimulatedSensors, Trajectory, simulate_sensors
from auvgw.ground.paths import config_file
from auvgw.sim_devices.vehicle import simulate
from auvgw.sim_devices.world import World


def lowcost_scenario() -> Scenario:
    return Scenario.model_validate(json.loads(config_file("scenarios/lowcost.json").read_text()))


def truth_trajectory(scn: Scenario) -> Trajectory:
    """The world model's truth at the AHRS rate (``devices.ins.rate_hz``)."""
    tr = simulate(scn, World.from_scenario(scn))
    assert scn.devices.ins.rate_hz is not None  # the low-cost scenario names its AHRS rate
    step = max(1, round(1.0 / (scn.devices.ins.rate_hz * scn.vehicle.dt_s)))
    sl = slice(None, None, step)
    return Trajectory(
        t=tr.t[sl], x=tr.x[sl], y=tr.y[sl], z=tr.z[sl], heading=tr.heading[sl], u=tr.u[sl],
        v=tr.v[sl], w=np.zeros_like(tr.t[sl]), yaw_rate=tr.yaw_rate[sl], roll=tr.roll[sl],
        pitch=tr.pitch[sl],
    )


def sensor_noise(scn: Scenario, scale_factor: float = 1.0) -> SensorNoise:
    ins, dvl = scn.devices.ins.noise, scn.devices.dvl.noise
    return SensorNoise(
        heading_sigma_deg=ins["heading_deg"], heading_tau_s=0.0,
        attitude_sigma_deg=ins["roll_deg"], attitude_tau_s=0.0, gyro_sigma_dps=ins["rate_dps"],
        dvl_sigma_mps=dvl["velocity_mps"], dvl_spike_p=dvl["spike_p"],
        dvl_spike_mps=(dvl["spike_min_mps"], dvl["spike_max_mps"]),
        dvl_scale_factor=scale_factor,
        heading_deviation_deg=(ins["deviation_a1_deg"], ins["deviation_b1_deg"],
                               ins["deviation_a2_deg"], ins["deviation_b2_deg"]),
    )  # fmt: skip


def mount(scn: Scenario) -> DvlMount:
    """The DVL mounting of the scenario (its yaw ``misalignment_deg``), as the config gives it."""
    return DvlMount(rotation_deg=(0.0, 0.0, scn.devices.dvl.noise["misalignment_deg"]))


def sensors(
    scn: Scenario, truth: Trajectory, seed: int, fix_times=(), scale_factor: float = 1.0
) -> SimulatedSensors:
    return simulate_sensors(
        truth, np.random.default_rng(seed), noise=sensor_noise(scn, scale_factor),
        mount=mount(scn), dvl_rate_hz=scn.devices.dvl.rate_hz or 1.5, dvl_offset_s=0.123,
        fix_times=fix_times,
    )  # fmt: skip


def filter_config(scn: Scenario, truth: Trajectory, kind: str = "default") -> FusionConfig:
    """``default``: default noise settings; ``true``: told the true DVL noise (not adapted);
    ``old``: the previous defaults (0.002 m/s DVL, not adapted); ``nodev``: default settings
    with ``compass_deviation = "off"`` (the fusion before the deviation estimate)."""
    kw: dict = {
        "dvl": mount(scn),
        "initial": InitialState(position_m=(truth.x[0], truth.y[0], truth.z[0])),
        "heading_error_tau_s": 0.0,
    }
    if kind == "true":
        kw |= {"dvl_noise_adaptive": False, "dvl_velocity_percent": 0.0,
               "dvl_velocity_sigma_mps": scn.devices.dvl.noise["velocity_mps"]}
    elif kind == "old":
        kw |= {"dvl_noise_adaptive": False, "dvl_velocity_percent": 0.0,
               "dvl_velocity_sigma_mps": 0.002}
    elif kind == "nodev":
        kw |= {"compass_deviation": "off"}
    elif kind != "default":
        raise ValueError(kind)
    return FusionConfig(**kw)


def plain_integration(sim: SimulatedSensors, m: DvlMount) -> tuple[np.ndarray, np.ndarray]:
    """Rotate each DVL fix by the mounting and the AHRS attitude at its time and hold it until
    the next fix: positions (n, 2) at the AHRS times."""
    ins = sim.ins
    t_ins = np.array([s.t for s in ins])
    M = mount_matrix(m)
    tf, vf = [], []
    for d in sim.dvl:
        i = int(np.searchsorted(t_ins, d.t))
        if not 0 < i < len(ins) or not d.bottom_lock:
            continue
        a = interpolate_ins(ins[i - 1], ins[i], d.t)
        tf.append(d.t)
        vf.append(body_to_ned(M @ np.asarray(d.velocity), a.roll, a.pitch, a.heading)[:2])
    tf_a, vf_a = np.array(tf), np.array(vf)
    k = np.clip(np.searchsorted(tf_a, t_ins, side="right") - 1, -1, len(tf_a) - 1)
    v = np.where(k[:, None] >= 0, vf_a[np.maximum(k, 0)], 0.0)
    pos = np.zeros((len(t_ins), 2))
    pos[1:] = np.cumsum(v[:-1] * np.diff(t_ins)[:, None], axis=0)
    pos += np.array([sim.truth.x[0], sim.truth.y[0]])
    return t_ins, pos


@dataclass(frozen=True)
class RunErrors:
    final_m: float
    rms_m: float
    distance_m: float


def errors(x: np.ndarray, y: np.ndarray, truth: Trajectory) -> RunErrors:
    e = np.hypot(x - truth.x, y - truth.y)
    return RunErrors(float(e[-1]), float(np.sqrt(np.mean(e * e))), truth.distance())


def run(scn: Scenario, truth: Trajectory, seed: int) -> dict:
    """One seed: errors of every filter (``default``, ``true``, ``old``, ``nodev``, ``plain``, and
    ``oracle``: plain integration of the same seed drawn without spikes), the
    default filter's adapted DVL noise (m/s per axis), its diagnostics summary and its compass
    deviation estimate (``deviation``)."""
    sim = sensors(scn, truth, seed)
    out: dict = {}
    for kind in ("default", "true", "old", "nodev"):
        nav = NavFilter(filter_config(scn, truth, kind))
        o = run_filter_arrays(sim.ins, sim.dvl, nav=nav)
        out[kind] = errors(o.x, o.y, truth)
        if kind == "default":
            assert nav.ekf is not None
            out["adapted_sigma"] = nav.ekf.dvl_noise_sigma()
            out["diagnostics"] = nav.diagnostics.summary()
            out["deviation"] = out["diagnostics"]["compass_deviation"]
        if kind == "old":
            out["old_diagnostics"] = nav.diagnostics.summary()
    _, pos = plain_integration(sim, mount(scn))
    out["plain"] = errors(pos[:, 0], pos[:, 1], truth)
    # the same seed without spikes (drawn last: every other draw is identical): what a perfect
    # spike rejection could make of plain integration
    clean = simulate_sensors(
        truth, np.random.default_rng(seed), noise=replace(sensor_noise(scn), dvl_spike_p=0.0),
        mount=mount(scn), dvl_rate_hz=scn.devices.dvl.rate_hz or 1.5, dvl_offset_s=0.123,
    )  # fmt: skip
    _, pos = plain_integration(clean, mount(scn))
    out["oracle"] = errors(pos[:, 0], pos[:, 1], truth)
    return out
