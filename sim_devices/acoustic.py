"""Acoustic beacon emulator (the sixth device): a USBL / transponder reply on a serial line.

Each tick (``rate_hz``, nominal 1 Hz: a two-way travel time over the 500 m field is up to
0.67 s, so one interrogation per second) the vehicle interrogates the scenario's
``acoustic_beacon``; the reply line (:mod:`auvgw.drivers.acoustic`) gives the slant range, the
bearing from the bow (clockwise) and the depression angle of the beacon at the ping time, with
white noise: range ``scenario.acoustic_beacon.sigma_range_m`` (or ``noise.range_m``), bearing
and depression ``noise.bearing_deg`` (1 deg). It leaves the line after the two-way travel
time at the scenario's sound speed (option ``delay``, true). Missed replies: beyond
``options.max_range_m`` (1000 m) there is none, and each reply is lost with probability
``options.miss_p`` (0.05, multipath / noise); the wire's own faults (``faults.dropout_p``,
corruption, garbage) come on top.

Options: ``baud`` (9600), ``max_range_m``, ``miss_p``, ``beacon_id`` (1), ``delay``.
Wire: serial ``<port_dir>/acoustic`` (format ``acoustic``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import acoustic
from auvgw.sim_devices.emulator import Emulator, SimContext
from auvgw.sim_devices.world import wrap_angle

__all__ = ["AcousticEmulator", "AcousticFix"]

_COUNTER_WRAP = 1_000_000


@dataclass(frozen=True)
class AcousticFix:
    """One reply: counter, vehicle time of the ping (s), slant range (m), bearing from the bow
    and depression (rad), noise-free range (m), and the two-way travel time (s)."""

    counter: int
    t: float
    range_m: float
    bearing: float
    depression: float
    true_range_m: float
    travel_s: float


class AcousticEmulator(Emulator):
    """The acoustic beacon transceiver (see the module docstring)."""

    kind = "acoustic"
    nominal_rate_hz = 1.0

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        if ctx.world.acoustic_beacon is None:
            raise ValueError("devices.acoustic: the scenario has no acoustic_beacon")
        self.check_noise_keys(("range_m", "bearing_deg"))
        self.sigma_range = self.noise("range_m", ctx.world.acoustic_sigma)
        self.sigma_angle = math.radians(self.noise("bearing_deg", 1.0))
        self.max_range = float(self.option("max_range_m", 1000.0))
        self.miss_p = float(self.option("miss_p", 0.05))
        self.beacon_id = int(self.option("beacon_id", 1))
        self.delay = bool(self.option("delay", True))
        self.codec = acoustic.CODEC
        self.serial = self.add_serial("acoustic", self.codec.framer, self.option("baud", 9600))
        self.counter = 0
        self.missed = 0

    def measure(self, t: float) -> AcousticFix | None:
        """The reply to a ping at vehicle time ``t`` (None: no reply); advances the counter."""
        s = self.truth(t)
        beacon = self.ctx.world.acoustic_beacon
        assert beacon is not None
        d = beacon - np.array([s.x, s.y, s.z])
        rng_true = float(np.linalg.norm(d))
        self.counter += 1
        if rng_true > self.max_range or self.rng.random() < self.miss_p:
            self.missed += 1
            return None
        k = self.sigma_scale()
        noise = self.rng.normal(0.0, 1.0, 3) * k
        bearing = wrap_angle(math.atan2(d[1], d[0]) - s.heading + noise[1] * self.sigma_angle)
        depression = math.atan2(d[2], math.hypot(d[0], d[1])) + noise[2] * self.sigma_angle
        return AcousticFix(
            counter=(self.counter - 1) % _COUNTER_WRAP, t=t,
            range_m=max(rng_true + noise[0] * self.sigma_range, 0.0), bearing=float(bearing),
            depression=float(depression), true_range_m=rng_true,
            travel_s=2.0 * rng_true / self.ctx.world.sound_speed,
        )  # fmt: skip

    def encode(self, m: AcousticFix) -> bytes:
        """The reply line of one fix."""
        msg = self.codec.message_type(counter=m.counter, range=m.range_m, bearing=m.bearing,
                                      depression=m.depression, beacon=self.beacon_id)  # fmt: skip
        return self.codec.encode(msg)

    def tick(self, t: float) -> None:
        m = self.measure(t)
        if m is None:
            return
        at = time.monotonic() + self.clock.real_duration(m.travel_s) if self.delay else None
        self.serial.send(self.encode(m), t, at=at)
