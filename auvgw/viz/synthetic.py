"""A deterministic synthetic run for the Rerun logger (tests, benchmark, demo screenshot).

An AUV circles a 60 m radius at 1.5 m/s and 20 m depth over a rolling seabed (about 30 m deep),
inside a square harbour of four walls (line features) with twelve point landmarks. Every sensor
at its usual rate: INS 100 Hz, DVL 5 Hz, MSIS 30 pings/s of 300 bins (echoes from the walls and
landmarks), multibeam 5 Hz x 256 beams, magnetometer 20 Hz, health 1 Hz, a drifting dead
reckoning and a SLAM estimate (landmarks with covariances, particles) at 2 Hz. Frames: NED
metres, headings from north towards east (``VizOptions(map_frame="ned")``).

:func:`synthetic_calls` returns the logger calls in time order as ``(method name, args,
kwargs)`` so a benchmark can time the calls alone; :func:`log_synthetic_run` makes them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from auvgw.viz.logger import RerunLogger

__all__ = ["Rates", "SyntheticWorld", "iter_truth", "log_synthetic_run", "synthetic_calls"]

#: one logger call: (method name, positional arguments, keyword arguments)
Call = tuple[str, tuple[object, ...], dict[str, object]]


@dataclass(frozen=True)
class Rates:
    """Device rates (Hz) and sizes of the synthetic run."""

    ins_hz: float = 100.0
    dvl_hz: float = 5.0
    msis_hz: float = 30.0
    msis_bins: int = 300
    mbes_hz: float = 5.0
    mbes_beams: int = 256
    mag_hz: float = 20.0
    health_hz: float = 1.0
    slam_hz: float = 2.0
    nav_hz: float = 10.0
    particles: int = 100


@dataclass(frozen=True)
class SyntheticWorld:
    """The scene: circle path, seabed, walls (rho, theta) and landmarks (x, y), NED metres."""

    radius_m: float = 60.0
    speed_mps: float = 1.5
    depth_m: float = 20.0
    msis_range_m: float = 50.0
    swath_half_m: float = 55.0

    @property
    def omega(self) -> float:
        """Yaw rate (rad/s) of the circle, turning clockwise seen from above (starboard turn)."""
        return self.speed_mps / self.radius_m

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Truth (x north, y east, heading) at times ``t`` (s since the start)."""
        a = self.omega * np.asarray(t, dtype=np.float64)
        return self.radius_m * np.sin(a), self.radius_m * (1.0 - np.cos(a)), np.mod(a, 2 * np.pi)

    @staticmethod
    def seabed(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Seabed depth (m, down) at NED (x, y)."""
        return 30.0 + 3.0 * np.sin(x / 40.0) + 2.0 * np.cos(y / 25.0)

    @property
    def walls(self) -> tuple[np.ndarray, np.ndarray]:
        """Four harbour walls as (rho, theta): x = +-90 m, y = -30 m and y = 150 m."""
        return np.array([90.0, 90.0, 30.0, 150.0]), np.array([0.0, np.pi, -np.pi / 2, np.pi / 2])

    @property
    def landmarks(self) -> np.ndarray:
        """Twelve point features (12, 2)."""
        a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        r = np.where(np.arange(12) % 2 == 0, 35.0, 80.0)
        return np.column_stack([r * np.sin(a), 60.0 + r * np.cos(a)])


def _every(duration: float, hz: float, t0: float) -> np.ndarray:
    return t0 + np.arange(0.0, duration, 1.0 / hz)


def _msis_bins(world: SyntheticWorld, x: float, y: float, bearing_world: float, n: int,
               noise: np.ndarray) -> np.ndarray:  # fmt: skip
    """Echo amplitudes along one beam: the nearest wall and landmarks within the range."""
    bins = noise.copy()
    d = np.array([math.cos(bearing_world), math.sin(bearing_world)])
    rho, theta = world.walls
    nx, ny = np.cos(theta), np.sin(theta)
    denom = nx * d[0] + ny * d[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (rho - (nx * x + ny * y)) / denom
    s = s[(s > 0) & np.isfinite(s)]
    cell = world.msis_range_m / n
    if s.size and s.min() < world.msis_range_m:
        k = int(s.min() / cell)
        bins[k : k + 6] = 230
    rel = world.landmarks - np.array([x, y])
    along = rel @ d
    off = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0])
    hit = (along > 0) & (along < world.msis_range_m) & (off < 1.5)
    for a in along[hit]:
        k = int(a / cell)
        bins[k : k + 3] = 200
    return bins


def synthetic_calls(
    duration_s: float,
    *,
    t0: float = 1_700_000_000.0,
    rates: Rates | None = None,
    world: SyntheticWorld | None = None,
    seed: int = 1,
) -> list[Call]:
    """The logger calls of ``duration_s`` seconds of the synthetic run, sorted by device time."""
    r = rates or Rates()
    w = world or SyntheticWorld()
    rng = np.random.default_rng(seed)
    calls: list[tuple[float, int, Call]] = []

    def add(t: float, name: str, *args: object, **kwargs: object) -> None:
        calls.append((t, len(calls), (name, args, kwargs)))

    # INS attitude and the truth trajectory at the INS rate
    t = _every(duration_s, r.ins_hz, t0)
    x, y, h = w.pose(t - t0)
    roll = 0.02 * np.sin(0.7 * (t - t0))
    pitch = 0.01 * np.cos(0.5 * (t - t0))
    for i in range(len(t)):
        add(t[i], "attitude", t[i], roll[i], pitch[i], h[i])
        add(t[i], "trajectory", "truth", t[i], x[i], y[i], w.depth_m, h[i])
    # dead reckoning: truth plus a slowly growing drift, with its covariance
    t = _every(duration_s, r.nav_hz, t0)
    x, y, h = w.pose(t - t0)
    el = t - t0
    for i in range(len(t)):
        s2 = (0.05 + 0.01 * el[i]) ** 2
        add(t[i], "trajectory", "dead_reckoning", t[i], x[i] + 0.004 * el[i], y[i] - 0.003 * el[i],
            w.depth_m, h[i], np.diag([s2, 2 * s2]))  # fmt: skip
    # DVL: body velocity (forward, starboard, down) and altitude
    t = _every(duration_s, r.dvl_hz, t0)
    x, y, _ = w.pose(t - t0)
    alt = w.seabed(x, y) - w.depth_m
    vel = np.column_stack([np.full(len(t), w.speed_mps), np.zeros(len(t)), np.zeros(len(t))])
    vel += rng.normal(0.0, 0.003, vel.shape)
    for i in range(len(t)):
        add(t[i], "dvl", t[i], vel[i], alt[i], ("forward", "starboard", "down"), True)
    # MSIS: continuous scan, 1.8 deg steps
    step = math.radians(1.8)
    t = _every(duration_s, r.msis_hz, t0)
    x, y, h = w.pose(t - t0)
    noise = rng.integers(0, 40, (len(t), r.msis_bins)).astype(np.uint8)
    for i in range(len(t)):
        bearing = (i * step) % (2 * np.pi)
        bins = _msis_bins(w, x[i], y[i], h[i] + bearing, r.msis_bins, noise[i])
        add(t[i], "msis_ping", t[i], bearing, bins, w.msis_range_m, step)
    # multibeam: swath across track over the seabed
    t = _every(duration_s, r.mbes_hz, t0)
    x, y, h = w.pose(t - t0)
    across = np.linspace(-w.swath_half_m, w.swath_half_m, r.mbes_beams)
    for i in range(len(t)):
        xs = x[i] - across * math.sin(h[i])
        ys = y[i] + across * math.cos(h[i])
        depth = w.seabed(xs, ys) - w.depth_m + rng.normal(0.0, 0.05, len(across))
        add(t[i], "swath", t[i], np.zeros_like(across), across, depth,
            x=x[i], y=y[i], z=w.depth_m, heading=h[i])  # fmt: skip
    # magnetometer: Earth field turned into the body frame by the heading
    t = _every(duration_s, r.mag_hz, t0)
    _, _, h = w.pose(t - t0)
    for i in range(len(t)):
        b = np.array([20_000.0 * math.cos(h[i]), -20_000.0 * math.sin(h[i]), 44_000.0])
        add(t[i], "magnetometer", t[i], b + rng.normal(0.0, 5.0, 3))
    # SLAM estimate: pose, landmarks with shrinking covariances, particles, walls
    t = _every(duration_s, r.slam_hz, t0)
    x, y, h = w.pose(t - t0)
    lm = w.landmarks
    rho, theta = w.walls
    for i in range(len(t)):
        name = "slam/fastslam2"
        s = 2.0 / (1.0 + 0.2 * (t[i] - t0))
        cov = np.tile(np.diag([s * s, 0.5 * s * s]), (len(lm), 1, 1))
        cov[:, 0, 1] = cov[:, 1, 0] = 0.3 * s * s
        add(t[i], "trajectory", name, t[i], x[i] + 0.2, y[i] - 0.1, w.depth_m, h[i],
            np.diag([0.3, 0.3]))  # fmt: skip
        add(t[i], "landmarks", name, t[i], lm + rng.normal(0.0, 0.3 * s, lm.shape), cov,
            np.arange(len(lm)))  # fmt: skip
        lcov = np.tile(np.diag([0.25, 1e-4]), (len(rho), 1, 1))
        add(t[i], "lines", name, t[i], rho + rng.normal(0.0, 0.2, len(rho)), theta, lcov)
        cloud = np.column_stack([x[i], y[i]]) + rng.normal(0.0, 0.8, (r.particles, 2))
        add(t[i], "particles", name, t[i], cloud, rng.random(r.particles))
    # health of every device
    t = _every(duration_s, r.health_hz, t0)
    for i in range(len(t)):
        for dev, hz in (("ins", r.ins_hz), ("dvl", r.dvl_hz), ("msis", r.msis_hz),
                        ("mbes", r.mbes_hz), ("mag", r.mag_hz)):  # fmt: skip
            add(t[i], "health", dev, t[i], {"rate_hz": hz, "bad_frames": 0.0, "connected": 1.0})
    add(t0, "event", "mbes", t0, "connected on udp://0.0.0.0:5602")
    calls.sort(key=lambda c: (c[0], c[1]))
    return [c[2] for c in calls]


def iter_truth(
    duration_s: float,
    hz: float = 100.0,
    t0: float = 1_700_000_000.0,
    world: SyntheticWorld | None = None,
) -> Iterator[tuple[float, float, float]]:
    """Truth (t, x, y) at ``hz``, as :func:`synthetic_calls` logs it (for tests)."""
    w = world or SyntheticWorld()
    t = _every(duration_s, hz, t0)
    x, y, _ = w.pose(t - t0)
    yield from zip(t.tolist(), x.tolist(), y.tolist(), strict=True)


def log_synthetic_run(
    logger: RerunLogger,
    duration_s: float,
    *,
    t0: float = 1_700_000_000.0,
    rates: Rates | None = None,
    world: SyntheticWorld | None = None,
    seed: int = 1,
) -> int:
    """Make every call of :func:`synthetic_calls` on ``logger``; returns how many were queued."""
    queued = 0
    for name, args, kw in synthetic_calls(duration_s, t0=t0, rates=rates, world=world, seed=seed):
        queued += bool(getattr(logger, name)(*args, **kw))
    return queued
