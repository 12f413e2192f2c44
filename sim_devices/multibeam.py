"""Multibeam emulator: GeoSwath-like swath bathymetry as Kongsberg XYZ 88 datagrams over UDP.

Each ping (``rate_hz``, 5 Hz nominal) casts the swath fan of an interferometric sonar at the
vehicle's true position and attitude against the terrain
(:func:`~auvgw.sim_devices.world.cast_swath`): ``n_beams`` beams (256) from port to starboard,
spaced evenly across track on a flat seabed (``spacing`` "equidistant", the interferometric
bins; or "equiangular"), the outermost reaching ``swath_factor``/2 (6) times the altitude each
side (GeoSwath: swath up to 12x water depth), none closer to vertical than ``nadir_gap_deg``
(0), none beyond ``max_range_m`` (300 m) slant range. Each valid beam reports depth below the
transducer (m, + down), across (m, + starboard) and along (m, + forward) in the heading-aligned
frame (attitude-corrected, as the sonar's XYZ 88 is); depth carries white noise of
``sqrt(depth_m^2 + (range_frac * slant range)^2)`` (0.05 m, 0.002), times ``sqrt(n)`` in a VB
noise burst; its quality factor is ``250 sd / range``, detection "phase" (interferometric),
reflectivity Lambertian ``-20 dB + 10 log10(cos^2 incidence)``. Beams without a hit are
invalid (detection info 0xC0). The header carries the true heading, the world's sound speed,
the transducer depth (vehicle depth), the ping counter, ``model`` (2040) and ``serial`` (1),
and the device clock (``epoch`` + vehicle time + clock jumps, UTC).

Options: ``udp_port`` (0: a free port), ``udp_host`` (the run's host), ``n_beams``,
``swath_factor``, ``max_range_m``, ``spacing``, ``nadir_gap_deg``, ``model``, ``serial``,
``sampling_frequency_hz`` (25000). Wire: UDP datagrams, one datagram per ping (format
kongsberg).
"""

from __future__ import annotations

import math

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import kongsberg
from auvgw.sim_devices.emulator import Emulator, SimContext
from auvgw.sim_devices.world import Swath, SwathGeometry

__all__ = ["DEFAULT_NOISE", "MultibeamEmulator"]

DEFAULT_NOISE: dict[str, float] = {"depth_m": 0.05, "range_frac": 0.002}


class MultibeamEmulator(Emulator):
    """The GeoSwath-class multibeam (see the module docstring)."""

    kind = "multibeam"
    nominal_rate_hz = 5.0
    prefetch = 2  # the swath cast is numpy work: overlap it with the other devices' ticks

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        spacing = self.option("spacing", "equidistant")
        if spacing not in ("equidistant", "equiangular"):
            raise ValueError(
                f"devices.{self.kind}.options.spacing: expected 'equidistant' or "
                f"'equiangular', got {spacing!r}"
            )
        self.geometry = SwathGeometry(
            n_beams=self.option("n_beams", 256),
            swath_factor=self.option("swath_factor", 12.0),
            max_range_m=self.option("max_range_m", 300.0),
            spacing=spacing,
            nadir_gap_deg=self.option("nadir_gap_deg", 0.0),
        )
        self.sigma_depth = self.noise("depth_m", DEFAULT_NOISE["depth_m"])
        self.range_frac = self.noise("range_frac", DEFAULT_NOISE["range_frac"])
        self.model = self.option("model", kongsberg.DEFAULT_MODEL)
        self.serial_number = self.option("serial", 1)
        self.sampling_frequency = self.option("sampling_frequency_hz", 25_000.0)
        self.pings = 0
        self.udp = self.add_udp(
            "kongsberg",
            kongsberg.KongsbergFramer,
            self.option("udp_port", 0),
            host=self.option("udp_host", ctx.udp_host),
        )

    def swath(self, t: float) -> Swath:
        """The noise-free swath at vehicle time ``t``."""
        s = self.truth(t)
        return self.ctx.world.swath((s.x, s.y, s.z), s.heading, self.geometry, s.pitch, s.roll)

    def ping(self, t: float) -> kongsberg.XYZ88:
        """One XYZ 88 message at vehicle time ``t`` (noise applied); advances the counter."""
        s = self.truth(t)
        sw = self.ctx.world.swath((s.x, s.y, s.z), s.heading, self.geometry, s.pitch, s.roll)
        valid = sw.valid
        rng_m = np.where(valid, sw.range_m, 1.0)
        sd = np.sqrt(self.sigma_depth**2 + (self.range_frac * rng_m) ** 2) * self.sigma_scale()
        depth = np.where(valid, sw.depth + self.rng.normal(0.0, 1.0, sd.shape) * sd, np.nan)
        quality = np.where(valid, np.clip(np.round(250.0 * sd / rng_m), 0, 254), 0)
        cos_inc = np.cos(np.where(valid, sw.incidence, 0.0))
        refl = np.where(valid, np.maximum(-20.0 + 10 * np.log10(cos_inc**2 + 1e-12), -60.0), 0)
        samples = np.where(valid, 2.0 * rng_m / self.ctx.world.sound_speed, 0.0)
        window = np.clip(np.round(samples * self.sampling_frequency * 0.02) + 4, 0, 65535)
        msg = kongsberg.make_xyz88(
            time=self.ctx.epoch + self.device_time(t),
            depth=depth,
            across=np.where(valid, sw.across, 0.0),
            along=np.where(valid, sw.along, 0.0),
            quality=quality,
            reflectivity=refl,
            detection_window=np.where(valid, window, 0),
            detection_info=1,
            heading=s.heading % (2 * math.pi),
            sound_speed=self.ctx.world.sound_speed,
            transducer_depth=s.z,
            sampling_frequency=self.sampling_frequency,
            model=self.model,
            ping_counter=self.pings & 0xFFFF,
            serial=self.serial_number,
        )
        self.pings += 1
        return msg

    def prepare(self, t: float) -> bytes:
        """The datagram of the ping at vehicle time ``t``."""
        return kongsberg.encode(self.ping(t))

    def send(self, prepared: bytes, t: float) -> None:
        self.udp.send(prepared, t)
