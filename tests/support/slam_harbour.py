"""The emulated harbour run of the landmark SLAM stage's tests: the harbour scenario for
:data:`DURATION_S` s, odometry drifting with a yaw-rate bias (:data:`YAW_BIAS`), the MSIS head's
pings decoded, every input fed in arrival order to a :class:`~auvgw.stages.slam.SlamStage` on this
thread (:func:`run_events`). :func:`harbour_run` is a module-scoped pytest fixture: a test module
imports it (tests/commands/test_slam_stage.py, test_slam_lines_online.py,
tests/slam/test_slam_online.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from auvgw.config.scenario import load_scenario
from auvgw.drivers import seanet as sn
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.ground.paths import config_file
from auvgw.sim_devices.msis import MsisHead, make_echo
from auvgw.sim_devices.vehicle import simulate
from auvgw.sim_devices.world import World
from auvgw.slam.features import PoseTrack
from auvgw.stages.slam import SlamStage, SlamStageConfig
from auvgw.subscribe import slam_output

__all__ = [
    "DURATION_S",
    "ODO_DT",
    "YAW_BIAS",
    "drifted",
    "harbour_run",
    "odometry_from_poses",
    "run_events",
]

DURATION_S = 150.0
ODO_DT = 0.1
YAW_BIAS = math.radians(0.05)  # rad/s of heading drift in the odometry


def odometry_from_poses(t: np.ndarray, poses: np.ndarray) -> list[Odometry]:
    """Odometry samples whose increments reproduce ``poses`` exactly (eq. 3)."""
    out, prev = [], None
    for k in range(len(t)):
        inc = None
        if k:
            dt = float(t[k] - t[k - 1])
            x0, y0, h0 = poses[k - 1]
            ddx, ddy = poses[k, 0] - x0, poses[k, 1] - y0
            c, s = math.cos(h0), math.sin(h0)
            dx, dy = c * ddx + s * ddy, -s * ddx + c * ddy
            dh = (poses[k, 2] - h0 + math.pi) % (2 * math.pi) - math.pi
            inc = MotionIncrement(
                t0=float(t[k - 1]),
                t1=float(t[k]),
                dx=dx,
                dy=dy,
                dz=0.0,
                dheading=dh,
                covariance=np.eye(3) * 1e-6,
                dt=dt,
                v_forward=dx / dt,
                v_starboard=dy / dt,
                yaw_rate=dh / dt,
            )
        out.append(Odometry(t=float(t[k]), x=float(poses[k, 0]), y=float(poses[k, 1]), z=4.0,
                            roll=0.0, pitch=0.0, heading=float(poses[k, 2]),
                            velocity_ned=(0.0, 0.0, 0.0), velocity_body=(1.0, 0.0, 0.0),
                            angular_rate=(0.0, 0.0, 0.0), covariance=np.eye(8) * 0.01,
                            bottom_lock=True, coasting=False, dvl_age_s=0.0, depth_age_s=0.0,
                            ins_gap=False, increment=inc))  # fmt: skip
        prev = out[-1]
    assert prev is not None
    return out


def drifted(t: np.ndarray, truth: np.ndarray, bias: float) -> np.ndarray:
    """Dead reckoning from the true body velocities with a constant yaw-rate bias."""
    out = np.empty_like(truth)
    out[0] = truth[0]
    for k in range(1, len(t)):
        x0, y0, h0 = truth[k - 1]
        ddx, ddy = truth[k, 0] - x0, truth[k, 1] - y0
        c, s = math.cos(h0), math.sin(h0)
        fwd, stb = c * ddx + s * ddy, -s * ddx + c * ddy
        dh = (truth[k, 2] - h0 + math.pi) % (2 * math.pi) - math.pi
        h = out[k - 1, 2]
        out[k, 0] = out[k - 1, 0] + fwd * math.cos(h) - stb * math.sin(h)
        out[k, 1] = out[k - 1, 1] + fwd * math.sin(h) + stb * math.cos(h)
        out[k, 2] = h + dh + bias * (t[k] - t[k - 1])
    return out


def run_events(cfg: SlamStageConfig, events: list[tuple]) -> tuple[SlamStage, list]:
    """A stage fed in-process (on this thread) with the events; its publications."""
    published: list[tuple[str, dict, int]] = []
    stage = SlamStage(cfg, on_publish=lambda k, p, t: published.append((k, slam_output(p), t)))
    for ev in events:
        if ev[0] == "odometry":
            stage.feed_odometry(ev[1])
        else:
            stage.feed(*ev[1:])
    stage.flush()
    return stage, published


@pytest.fixture(scope="module")
def harbour_run() -> tuple[object, ...]:
    """The harbour scenario run in-process: (world, track, dr, t_odo, stage, published, events,
    cfg)."""
    scn = load_scenario(config_file("scenarios/harbour.json"))
    scn = scn.model_copy(update={"duration_s": DURATION_S})
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    track = PoseTrack(truth.t, truth.poses)
    t_odo = np.arange(0.0, truth.duration, ODO_DT)
    true_odo = track(t_odo)
    dr = drifted(t_odo, true_odo, YAW_BIAS)
    odo = odometry_from_poses(t_odo, dr)

    cmd = sn.head_command(range_m=50.0, n_bins=400, sound_speed=world.sound_speed)
    head = MsisHead(sound_speed=world.sound_speed, config_delay_s=0.0)
    head.power_up(0.0)
    head.feed(sn.encode(cmd), 0.0)
    head.tick(0.0)
    period = head.ping_duration_s() + 0.005
    ping_t = np.arange(0.0, truth.duration, period)
    ping_pose = track(ping_t)
    now = [0]
    head.echo = make_echo(world, lambda: tuple(ping_pose[now[0]]), np.random.default_rng(21))
    framer = sn.SeaNetFramer(policy="raise")
    poll = sn.encode(sn.send_data(0))

    # the inputs in arrival order, as online: each ping before the odometry that covers it
    events: list[tuple] = []
    j = 0
    for i, tp in enumerate(ping_t):
        while j < len(odo) and odo[j].t < tp:
            events.append(("odometry", odo[j]))
            j += 1
        now[0] = i
        for f in framer.feed(head.feed(poll, float(tp))):
            for m in sn.decode(f.data):
                events.append(("message", "msis", int(tp * 1e9), m))
                events.append(("message", "other-head", int(tp * 1e9), m))  # ignored
    events.extend(("odometry", o) for o in odo[j:])
    cfg = SlamStageConfig(sound_speed_mps=world.sound_speed, target_radius_m=world.point_radius,
                          n_particles=30, seed=3)  # fmt: skip
    stage, published = run_events(cfg, events)
    return world, track, dr, t_odo, stage, published, events, cfg
