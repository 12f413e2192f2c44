"""MS3A magnetometer emulator: the magnetic field at the sensor on serial (ASCII) and CAN.

Each tick: the field at the vehicle's true position (NED, tesla) is the scenario's Earth field
plus every magnetic beacon's dipole field at that vehicle time
(:meth:`~auvgw.sim_devices.world.World.magnetic_field`, AC beacons oscillating at their
frequency), rotated into the sensor frame (= body axes: x forward, y starboard, z down) by the
true attitude, ``B_body = R(heading, pitch, roll)^T B_ned``, plus white noise of
``noise.field_nt`` (1 nT, times ``sqrt(n)`` in a VB noise burst) per axis, reported in nT. A
field beyond the line format's +-999999.9 nT saturates (CAN status ``OVERRANGE``).

Options (:class:`~auvgw.sim_devices.emulator.SerialCanEmulator`): ``serial`` (true), ``can``
(true), ``baud`` (38400), ``can_bitrate`` (500000), ``table`` (a site MS3A table, TOML).
Wires: serial ``<port_dir>/magnetometer`` (format ms3a), CAN adapter
``<port_dir>/magnetometer_can`` (DBC ``ms3a.dbc``, two frames per sample).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import ms3a
from auvgw.drivers.can_codec import ms3a_can
from auvgw.sim_devices.emulator import SerialCanEmulator, SimContext
from auvgw.sim_devices.world import body_to_ned

__all__ = ["DEFAULT_NOISE", "FULL_SCALE_NT", "MagSample", "MagnetometerEmulator"]

DEFAULT_NOISE: dict[str, float] = {"field_nt": 1.0}
#: largest magnitude per axis the ASCII line carries, nT
FULL_SCALE_NT = 999_999.9
_COUNTER_WRAP = 1_000_000


@dataclass(frozen=True)
class MagSample:
    """One output: ``counter``; ``b_nt`` the reported field (nT, sensor axes, noise and
    saturation applied); ``true_nt`` the noise-free field at the sensor (nT, sensor axes);
    ``overrange`` if an axis saturated; ``burst`` if a VB noise burst."""

    counter: int
    t: float
    b_nt: tuple[float, float, float]
    true_nt: tuple[float, float, float]
    overrange: bool
    burst: bool


class MagnetometerEmulator(SerialCanEmulator, device="ms3a"):
    """The MS3A magnetometer (see the module docstring)."""

    nominal_rate_hz = 20.0
    default_baud = 38400

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        self.sigma_nt = self.noise("field_nt", DEFAULT_NOISE["field_nt"])
        self.add_wires(ms3a.Ms3aCodec, ms3a.CODEC, ms3a_can)
        self.counter = 0

    def field_body(self, t: float) -> np.ndarray:
        """The noise-free field at the sensor at vehicle time ``t``, nT, sensor (body) axes."""
        s = self.truth(t)
        b_ned = self.ctx.world.magnetic_field(np.array([s.x, s.y, s.z]), t)
        return body_to_ned(s.heading, s.pitch, s.roll).T @ b_ned * 1e9

    def measure(self, t: float) -> MagSample:
        """The magnetometer output at vehicle time ``t``; advances the counter."""
        true = self.field_body(t)
        k = self.sigma_scale()
        b = true + self.rng.normal(0.0, self.sigma_nt * k, 3)
        over = bool(np.any(np.abs(b) > FULL_SCALE_NT))
        b = np.clip(b, -FULL_SCALE_NT, FULL_SCALE_NT)
        out = MagSample(
            counter=self.counter,
            t=t,
            b_nt=tuple(b.tolist()),  # type: ignore[arg-type]
            true_nt=tuple(true.tolist()),  # type: ignore[arg-type]
            overrange=over,
            burst=k > 1.0,
        )
        self.counter += 1
        return out

    def encode_serial(self, m: MagSample) -> bytes:
        """The ASCII line of one sample."""
        bx, by, bz = m.b_nt
        msg = self.codec.message_type(
            counter=m.counter % _COUNTER_WRAP, bx=bx, by=by, bz=bz
        )
        return self.codec.encode(msg)

    def encode_can(self, m: MagSample) -> list[Any]:
        """The CAN frames of one sample (sharing the counter mod 65536)."""
        assert self.can_codec is not None and self.can_codec.sample_type is not None
        bx, by, bz = m.b_nt
        sample = self.can_codec.sample_type(
            counter=m.counter % _COUNTER_WRAP % 65536,
            bx=bx,
            by=by,
            bz=bz,
            status="OVERRANGE" if m.overrange else "OK",
        )
        return self.can_codec.encode_sample(sample, strict=False)  # ranges checked by the codec
