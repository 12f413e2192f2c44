"""GeoSwath Plus emulator: raw interferometric pings (RDF broadcast form) over UDP.

Each ping of one side (``side`` 0 port, 1 starboard) is built from the world's terrain, sample by
sample: sample ``k`` has two-way time ``k * sample_interval`` wavelengths (``time``, u16; seconds
= wavelengths / frequency), hence slant range ``r = c t / 2`` at the world's sound speed. A fan
of rays (``fan`` angles from the body vertical out to ``max_angle_deg`` on that side, in the body
y-z plane, turned by the vehicle's roll, pitch and heading) is cast against the terrain
(:func:`~auvgw.sim_devices.world.first_crossing`); for each sample the first angle whose ray
reaches the seabed at range ``r`` is interpolated (the running maximum of range over angle:
shadowed seabed gives no return). That angle, as seen by the transducer (body frame, positive
outward from nadir on that side), is sent as its sine (``sine``, x 32767); the amplitude is
Lambertian in the grazing angle (``amplitude_scale * (cos^2 incidence + 0.05)``) with Rayleigh
speckle over a noise floor.

The interferometer's defects (all seeded from the scenario):

* angle noise ``sigma_angle_deg * (1 + nadir_k / max(sin angle, 0.05)) * (1 + range_k *
  (r / max_range)^2)``: growing towards nadir and at long range (noise figures ``angle_deg``,
  ``nadir_k``, ``range_k``; times ``sqrt(n)`` in a noise burst);
* a nadir gap: samples closer to vertical than ``nadir_gap_deg`` carry a random angle in the gap
  (strong amplitude: the nadir return);
* water-column returns: samples before the first bottom return carry random angles at the
  noise floor's amplitude;
* surface returns: a fraction ``surface_fraction`` of the samples past the range of the sea
  surface (the vehicle's depth) carry the surface's mirror angle (``sin = sqrt(1 - (z/r)^2)``,
  the phase of a return from above aliases to it) at a third of the seabed's amplitude;
* sides pinging ``alternate`` (one side per tick) or ``together`` (both per tick, same time).

Each ping also carries NAV (x easting, y northing, z = -depth, m: the vehicle's true position
in the local frame), MRU (roll, pitch, deg; heave 0), GYRO (heading, deg), ECHO (depth1 the
altitude under the transducer, depth2 the transducer depth, m) and MINISVS (the world's sound
speed) records, time-stamped with the device clock (``epoch`` + vehicle time + clock jumps).

Models (option ``model_khz``): 125, 250 (default), 500 kHz: the frequency, the maximum slant
range (390, 195, 95 m: half the vendor's swath width) and ``sample_interval`` 16 wavelengths.
Options: ``model_khz``, ``sides`` ("alternate"), ``max_range_m`` (the model's), ``fan`` (721),
``max_angle_deg`` (85), ``nadir_gap_deg`` (5), ``surface_fraction`` (0.02), ``lever_x_m``,
``lever_y_m``, ``lever_z_m`` (transducer in the body frame FRD, m; 0), ``udp_port`` (0: free),
``udp_host``. Wire: one UDP datagram per ping (format geoswath).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers.geoswath import GeoSwathFramer, GeoSwathPing, default_codec
from auvgw.sim_devices.emulator import Emulator, SimContext
from auvgw.sim_devices.vehicle import TruthSample
from auvgw.sim_devices.world import World, body_to_ned, first_crossing

__all__ = ["DEFAULT_NOISE", "MODELS", "GeoSwathEmulator", "SideSamples", "side_samples"]

#: frequency (Hz) -> maximum slant range (m) of the three GeoSwath Plus models
MODELS: dict[int, float] = {125_000: 390.0, 250_000: 195.0, 500_000: 95.0}
#: wavelengths per sample (the ``sample_interval`` header field)
SAMPLE_INTERVAL = 16
DEFAULT_NOISE: dict[str, float] = {"angle_deg": 0.08, "nadir_k": 0.15, "range_k": 2.0}
AMPLITUDE_SCALE = 20000.0
NOISE_FLOOR = 60.0
SINE_SCALE = 32767.0


@dataclass(frozen=True)
class SideSamples:
    """The raw samples of one side's ping: ``time`` (wavelengths), ``sine`` and ``amplitude``
    (wire values) and, for evaluation, the noise-free angle (rad, body frame, + outward; NaN
    where no seabed return) and slant range (m) of each sample."""

    time: np.ndarray
    sine: np.ndarray
    amplitude: np.ndarray
    true_angle: np.ndarray
    range_m: np.ndarray


def side_samples(
    world: World,
    position: np.ndarray,
    heading: float,
    pitch: float,
    roll: float,
    side: int,
    frequency: float,
    max_range_m: float,
    rng: np.random.Generator,
    *,
    fan: int = 721,
    max_angle_deg: float = 85.0,
    nadir_gap_deg: float = 5.0,
    surface_fraction: float = 0.02,
    noise: dict[str, float] | None = None,
    noise_scale: float = 1.0,
) -> SideSamples:
    """One side's raw samples from a transducer at ``position`` (NED, m) with the vehicle's
    attitude (rad); ``side`` 0 port, 1 starboard (see the module docstring for the model)."""
    nz = {**DEFAULT_NOISE, **(noise or {})}
    c = world.sound_speed
    wl_per_s = frequency
    n = int(min(2.0 * max_range_m / c * wl_per_s, 65535) // SAMPLE_INTERVAL)
    time_w = np.arange(1, n + 1) * SAMPLE_INTERVAL
    r = c * (time_w / wl_per_s) / 2.0
    sgn = 1.0 if side == 1 else -1.0
    theta = np.radians(np.linspace(0.0, max_angle_deg, fan))
    rot = body_to_ned(heading, pitch, roll)
    d = (rot @ np.stack([np.zeros_like(theta), sgn * np.sin(theta), np.cos(theta)])).T
    slant = first_crossing(world.terrain, position, d, max_range_m * 1.05, samples=24, exact=False)
    reach = np.where(np.isfinite(slant), slant, np.inf)
    env = np.maximum.accumulate(reach)  # a sample's return comes from the first angle reaching r
    first = float(env[0]) if np.isfinite(env[0]) else math.inf
    idx = np.searchsorted(env, r, side="left")
    bottom = (idx < fan) & (r >= first)
    i1 = np.clip(idx, 1, fan - 1)
    i0 = i1 - 1
    e0, e1 = env[i0], env[i1]
    span = np.where(np.isfinite(e1) & (e1 > e0), e1 - e0, 1.0)
    f = np.clip(np.where(np.isfinite(e0), (r - e0) / span, 1.0), 0.0, 1.0)
    ang = np.where(idx == 0, theta[0], theta[i0] + f * (theta[i1] - theta[i0]))
    true_angle = np.where(bottom, ang, np.nan)
    # the seabed point of each bottom sample, its incidence (Lambertian amplitude)
    a = np.where(bottom, ang, 0.0)
    dirs = rot @ np.stack([np.zeros_like(a), sgn * np.sin(a), np.cos(a)])  # (3, n)
    hx = position[0] + r * dirs[0]
    hy = position[1] + r * dirs[1]
    gx, gy = world.terrain.gradient_coarse(hx, hy)
    cos_inc = np.abs(-gx * dirs[0] - gy * dirs[1] + dirs[2]) / np.sqrt(gx * gx + gy * gy + 1.0)
    amp = AMPLITUDE_SCALE * (cos_inc**2 + 0.05)
    # the interferometer's angle noise: towards nadir, at long range
    sig = (math.radians(nz["angle_deg"]) * noise_scale
           * (1.0 + nz["nadir_k"] / np.maximum(np.sin(a), 0.05))
           * (1.0 + nz["range_k"] * (r / max_range_m) ** 2))  # fmt: skip
    meas = a + rng.normal(0.0, 1.0, n) * sig
    gap = math.radians(nadir_gap_deg)
    in_gap = bottom & (a < gap)
    meas = np.where(in_gap, rng.uniform(0.0, gap, n), meas)
    amp = np.where(in_gap, AMPLITUDE_SCALE * 1.5, amp)
    sine = np.where(bottom, np.sin(meas), rng.uniform(-1.0, 1.0, n))
    amp = np.where(bottom, amp, NOISE_FLOOR)
    # surface returns: the sea surface's mirror angle past its range
    depth = float(position[2])
    surf = (r > depth) & (rng.random(n) < surface_fraction) if depth > 0 else np.zeros(n, bool)
    if surf.any():
        mirror = np.sqrt(np.clip(1.0 - (depth / np.maximum(r, 1e-9)) ** 2, 0.0, 1.0))
        sine = np.where(surf, mirror, sine)
        amp = np.where(surf, np.maximum(amp, NOISE_FLOOR * 3) / 3.0, amp)
    speckle = rng.rayleigh(math.sqrt(2.0 / math.pi), n)  # mean 1
    amplitude = np.clip(np.round(amp * speckle + rng.uniform(0, NOISE_FLOOR, n)), 0, 65535)
    return SideSamples(
        time=time_w.astype(np.uint16),
        sine=np.clip(np.round(sine * SINE_SCALE), -32767, 32767).astype(np.int16),
        amplitude=amplitude.astype(np.uint16),
        true_angle=true_angle,
        range_m=r,
    )


class GeoSwathEmulator(Emulator):
    """The GeoSwath Plus interferometric sonar (see the module docstring)."""

    kind = "geoswath"
    nominal_rate_hz = 4.0
    prefetch = 2  # numpy work: overlap it with the other devices' ticks

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        khz = self.option("model_khz", 250)
        self.frequency = int(khz) * 1000
        if self.frequency not in MODELS:
            raise ValueError(
                f"devices.{self.kind}.options.model_khz: expected 125, 250 or 500, got {khz!r}"
            )
        self.max_range_m = self.option("max_range_m", MODELS[self.frequency])
        self.sides = self.option("sides", "alternate")
        if self.sides not in ("alternate", "together"):
            raise ValueError(
                f"devices.{self.kind}.options.sides: expected 'alternate' or 'together', "
                f"got {self.sides!r}"
            )
        self.fan = self.option("fan", 721)
        self.max_angle_deg = self.option("max_angle_deg", 85.0)
        self.nadir_gap_deg = self.option("nadir_gap_deg", 5.0)
        self.surface_fraction = self.option("surface_fraction", 0.02)
        self.lever = np.array([self.option(f"lever_{a}_m", 0.0) for a in "xyz"])
        self.check_noise_keys(DEFAULT_NOISE)
        self.noise_figures = {k: self.noise(k, v) for k, v in DEFAULT_NOISE.items()}
        self.codec = default_codec()
        self.pings = 0
        self.udp = self.add_udp(
            "geoswath",
            GeoSwathFramer,
            self.option("udp_port", 0),
            host=self.option("udp_host", ctx.udp_host),
            extra={"geoswath": {"model_khz": self.frequency // 1000}},
        )

    def transducer(self, s: TruthSample) -> np.ndarray:
        """The transducer's position (NED, m) for the vehicle state ``s``."""
        rot = body_to_ned(s.heading, s.pitch, s.roll)
        return np.array([s.x, s.y, s.z]) + rot @ self.lever

    def side_ping(self, t: float, side: int, number: int) -> tuple[GeoSwathPing, SideSamples]:
        """The ping of ``side`` at vehicle time ``t`` and its samples (with their truth)."""
        s = self.truth(t)
        pos = self.transducer(s)
        raw = side_samples(
            self.ctx.world, pos, s.heading, s.pitch, s.roll, side, self.frequency,
            self.max_range_m, self.rng, fan=self.fan, max_angle_deg=self.max_angle_deg,
            nadir_gap_deg=self.nadir_gap_deg, surface_fraction=self.surface_fraction,
            noise=self.noise_figures, noise_scale=self.sigma_scale(),
        )  # fmt: skip
        ts = self.ctx.epoch + self.device_time(t)
        altitude = float(self.ctx.world.depth(pos[0], pos[1])) - float(pos[2])
        arrays: dict[str, Any] = {
            "raa": {"time": raw.time, "sine": raw.sine, "amplitude": raw.amplitude},
            "nav": {"x": [s.y], "y": [s.x], "z": [-s.z], "time": [ts], "time_stamp": [ts],
                    "quality": [4]},
            "mru": {"roll": [math.degrees(s.roll)], "pitch": [math.degrees(s.pitch)],
                    "heave": [0.0], "time_stamp": [ts]},
            "gyro": {"heading": [math.degrees(s.heading) % 360.0], "time_stamp": [ts]},
            "echo": {"depth1": [altitude], "depth2": [float(pos[2])], "time_stamp": [ts]},
            "minisvs": {"velocity": [self.ctx.world.sound_speed], "time_stamp": [ts]},
        }  # fmt: skip
        header = {
            "ping_number": number & 0x7FFFFFFF,
            "ping_time": ts,
            "side": side,
            "ping_length": min(round(2000.0 * self.max_range_m / self.ctx.world.sound_speed),
                               65535),
            "sample_interval": SAMPLE_INTERVAL,
            "previous_ping_position": -1,
        }  # fmt: skip
        return self.codec.make_ping(header, arrays), raw

    def prepare(self, t: float) -> list[bytes]:
        """The datagrams (one per ping) of the tick at vehicle time ``t``."""
        sides = (0, 1) if self.sides == "together" else (self.pings % 2,)
        out = []
        for side in sides:
            ping, _ = self.side_ping(t, side, self.pings)
            out.append(self.codec.encode(ping))
        self.pings += 1
        return out

    def send(self, prepared: list[bytes], t: float) -> None:
        for datagram in prepared:
            self.udp.send(datagram, t)
