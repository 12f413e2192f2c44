"""Teledyne RDI Pathfinder 600 kHz DVL emulator: PD0 ensembles on a paced pty.

Each ping (``rate_hz``, default 5 Hz; one bottom-track ping per ensemble, BP1) the emulator
samples the ground truth and builds one PD0 ensemble with the project's codec
(:mod:`auvgw.drivers.pd0`: messages + :func:`~auvgw.drivers.pd0.encode`), as a Pathfinder in a
typical AUV configuration sends it: fixed leader (58 bytes), variable leader (77 bytes),
bottom track 0x0600 (81 bytes); optionally a few water-profile cells (0x0100-0x0400), the
high-resolution velocity 0x5803 (#BJ h) and the range block 0x5804 (#BJ r).

Mounting: down-facing, at the vehicle reference point, beam 3 forward (heading alignment EA 0),
Janus angle 30 deg, convex. RDI instrument axes are then X = starboard (beam 1 -> beam 2),
Y = forward (beam 4 -> beam 3), Z = up (toward the transducer face); ship axes are starboard,
forward, mast, levelled by pitch and roll when tilts are used (EX bit 2); earth axes are east,
north, up.

Geometry and lock: each of the four beams (30 deg from the instrument vertical, rotated by the
true attitude) is intersected with the world's terrain
(:func:`~auvgw.sim_devices.world.first_crossing`: sampled every 0.25 m, not a flat-seabed
approximation). A beam detects the bottom when its vertical range (slant range x cos 30 deg,
in instrument axes, not tilt-corrected, as the 0x0600 "BT Range") lies in
[``min_altitude_m`` 0.2, ``max_altitude_m`` 89]. Bottom lock needs four detecting beams, or
three when 3-beam solutions are allowed (EX bit 1; the error velocity is then 0, as the
Pathfinder stops computing it). Without lock the four velocities are bad (-32768 on the wire);
a beam that does not detect the bottom reports range 0 (bad), a beam that does keeps its range
(as RDI instruments do: a ping can see the bottom on two beams and still have no velocity).
In a ``bottom_lock_loss`` fault window no beam detects anything.

Velocity: the vehicle's velocity over ground (truth NED velocity) expressed in the configured
frame (``options.frame``: beam, instrument, ship (default, the Pathfinder's EX10111) or earth),
ship and earth using the reported attitude. In instrument, ship and earth coordinates 0x0600
carries the bottom relative to the instrument, i.e. MINUS that velocity, and 0x5803 the
instrument over the bottom (plus sign). In beam coordinates both carry the closing speed along
each beam, ``v . u_i`` for the outward beam unit vector ``u_i`` (RDI beam velocities are
positive toward the transducer, whoever moves), so there is no negation.
White noise ``noise.velocity_mps`` (0.002 m/s, 1 sigma) per output component (per beam in beam
coordinates; the error velocity of a 4-beam solution is that noise alone), times ``sqrt(n)``
in a VB noise burst (the burst scales every noise of that ping). A component beyond +-10 m/s
is bad (the Pathfinder's velocity range; BQ-32768).

Instrument errors (off by default; ``devices.dvl.noise``): ``scale_factor_pct`` (a Doppler
scale-factor error: every velocity times ``1 + pct / 100``) and ``misalignment_deg`` (the
reported velocity turned by this angle about the vehicle's vertical, positive clockwise seen
from above, i.e. to starboard: an instrument mounted turned by minus that angle whose alignment
was not calibrated). Both act on the instrument-axes velocity over the bottom and through the
water before anything else, so every output frame (beam, instrument, ship, earth), the water
mass layer, the water profile and the distances made good carry the same error, and a
dead reckoning on them drifts like one on a real Pathfinder (long-term accuracy +-0.4 %
+-0.2 cm/s). They are constant over a run and draw nothing from the generators.

Other contents: ranges with ``noise.range_m`` (0.01 m); the variable leader's depth (dm) and
pressure (daPa) from the optional pressure sensor: true depth + ``noise.depth_m`` (0.02 m);
attitude = truth + ``noise.heading_deg/pitch_deg/roll_deg`` (0 by default: the AUV feeds its
INS attitude to the DVL, EZ selects it; pitch and roll in ship frame, EP..,1); RTC = the
device clock (``ctx.epoch`` + vehicle time + clock jumps) in hundredths; ensemble numbers from
1; water-mass layer (BK, ``options.water_mass``) and water cells from the scenario's uniform
current; distance made good in 0x5803 integrates its velocities between pings.

Options (``devices.dvl.options``): ``frame`` ("ship"), ``tilts`` (true), ``three_beam`` (true),
``baud`` (115200), ``serial`` (true: open the pty), ``max_altitude_m`` (89), ``min_altitude_m``
(0.2), ``bt_high_res`` (false), ``bt_range`` (false), ``water_mass`` (false), ``wm_min_m`` (8),
``wm_near_m`` (16), ``wm_far_m`` (24), ``cells`` (0), ``cell_size_m`` (1.0), ``blank_m``
(0.88), ``pressure_sensor`` (true), ``temperature_c`` (10), ``salinity_ppt`` (35),
``water_density`` (1025 kg/m^3), ``serial_number`` (10000), ``firmware_revision`` (0),
``sim_flag`` (false). Wire: serial ``<port_dir>/dvl`` (format pd0).

Sources: Teledyne RD Instruments, *Pathfinder DVL Guide* (April 2018): command defaults (BA24,
BC220, BE1000, BI5, BK0, BL80,160,240, BM8, BP1, BX1100, EX10111, #BJ 100 000 000), the
fixed-leader EX and EZ bits, the 0x0600/0x5803/0x5804 tables, the PD0 sign conventions and the
tilt signs (pitch + when beam 3 is higher, roll + when beam 1 is higher for a down-facing unit).
Firmware 67.xx identifies a Pathfinder (dolfyn's RDI reader); the profile settings (lag, code
repeats, transmit lag) are those of the 600 kHz Workhorse capture in ../shared.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import pd0
from auvgw.sim_devices.emulator import Emulator, SimContext
from auvgw.sim_devices.world import body_to_ned, first_crossing

__all__ = [
    "BEAMS_BODY",
    "BEAMS_INSTRUMENT",
    "DEFAULT_NOISE",
    "FIRMWARE_VERSION",
    "INSTRUMENT_ERROR",
    "JANUS_ANGLE",
    "MAX_VELOCITY",
    "SWAP",
    "SYSTEM_CONFIG",
    "DvlEmulator",
    "DvlPing",
    "frame_matrix",
    "instrument_error_matrix",
]

#: Janus angle of the Pathfinder's beams from the instrument vertical, rad
JANUS_ANGLE = math.radians(30.0)
_S, _C = math.sin(JANUS_ANGLE), math.cos(JANUS_ANGLE)

#: unit vectors of beams 1-4 out of the transducer, body axes (x forward, y starboard, z down),
#: for a down-facing unit with beam 3 forward: beam 1 port, 2 starboard, 3 forward, 4 aft
BEAMS_BODY = np.array([[0.0, -_S, _C], [0.0, _S, _C], [_S, 0.0, _C], [-_S, 0.0, _C]])

#: body (forward, starboard, down) <-> RDI instrument (X starboard, Y forward, Z up) of this
#: mounting, and NED <-> ENU: the same self-inverse permutation
SWAP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: the beam unit vectors in instrument axes (beam 2 along +X, beam 3 along +Y, all down -Z)
BEAMS_INSTRUMENT = BEAMS_BODY @ SWAP

#: largest velocity component reported, m/s (beyond it the value is bad: BQ-32768)
MAX_VELOCITY = 10.0
#: CPU firmware version of the Pathfinder family (its PD0 fixed leader byte 2)
FIRMWARE_VERSION = 67
#: system configuration word: 600 kHz, convex, sensor config 1, head attached, down-facing,
#: 30 deg beams, 4-beam Janus
SYSTEM_CONFIG = 0x424B

#: noise figures, 1 sigma: m/s, m, deg
DEFAULT_NOISE: dict[str, float] = {
    "velocity_mps": 0.002,
    "water_velocity_mps": 0.005,
    "range_m": 0.01,
    "depth_m": 0.02,
    "heading_deg": 0.0,
    "pitch_deg": 0.0,
    "roll_deg": 0.0,
}

#: constant instrument errors (off by default): Doppler scale factor in percent, heading
#: misalignment in deg (see the module docstring)
INSTRUMENT_ERROR: dict[str, float] = {"scale_factor_pct": 0.0, "misalignment_deg": 0.0}

#: velocity spikes of a low-cost DVL (off by default): probability per ping and the range of the
#: spike's magnitude (m/s, random direction in instrument axes), drawn from their own stream so
#: switching them on leaves every other draw unchanged
SPIKES: dict[str, float] = {"spike_p": 0.0, "spike_min_mps": 0.8, "spike_max_mps": 1.5}

_FRAMES = {f.name.lower(): f for f in pd0.CoordinateFrame}
#: EZ sensor source / sensors available bits of the Pathfinder (8 bits: EC, ED, EH, EP, ER, ES,
#: ET, EU from bit 7 down)
_EZ_EC, _EZ_ED, _EZ_EH, _EZ_EP, _EZ_ER, _EZ_ET = 0x80, 0x40, 0x20, 0x10, 0x08, 0x02
_GRAVITY = 9.80665
_CDEG = math.radians(0.01)
_S16_BAD = -32768
_S32 = 2**32
_NAN4 = np.full(4, math.nan)


# -- geometry ------------------------------------------------------------------------------------


def frame_matrix(
    frame: pd0.CoordinateFrame, heading: float, pitch: float, roll: float, tilts: bool
) -> np.ndarray:
    """3x3 matrix from RDI instrument axes (X starboard, Y forward, Z up, this mounting) to the
    axes of ``frame``: instrument (identity), ship (starboard, forward, mast; levelled by pitch
    and roll if ``tilts``) or earth (east, north, up). Angles in rad, RDI/ZYX sense."""
    if frame is pd0.CoordinateFrame.INSTRUMENT:
        return np.eye(3)
    if frame not in (pd0.CoordinateFrame.SHIP, pd0.CoordinateFrame.EARTH):
        raise ValueError(f"no 3-axis matrix for {frame.name} coordinates")
    p, r = (pitch, roll) if tilts else (0.0, 0.0)
    h = heading if frame is pd0.CoordinateFrame.EARTH else 0.0
    return SWAP @ body_to_ned(h, p, r) @ SWAP


def instrument_error_matrix(scale_factor_pct: float, misalignment_deg: float) -> np.ndarray:
    """3x3 matrix, RDI instrument axes (X starboard, Y forward, Z up) to themselves, taking the
    true velocity to the measured one: scaled by ``1 + scale_factor_pct / 100`` and turned by
    ``misalignment_deg`` about the vertical, clockwise seen from above (forward toward
    starboard)."""
    a = math.radians(misalignment_deg)
    c, s = math.cos(a), math.sin(a)
    # clockwise from above in body axes (x forward, y starboard, z down) is +a about z down
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (1.0 + scale_factor_pct / 100.0) * (SWAP @ rz @ SWAP)


# -- one ping --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DvlPing:
    """What one ping measured, in SI, before encoding.

    ``ensemble`` number (from 1); ``t`` vehicle time and ``device_time`` the DVL clock (POSIX
    s); ``lock`` bottom lock; ``detected`` per beam; ``range_m`` per-beam vertical range
    (instrument axes, NaN where not detected); ``slant_m`` along-beam range (NaN where none);
    ``velocity`` the instrument over the bottom in ``frame`` (4 components: beams 1-4 as closing
    speeds along the outward beams, or 3 axes + error; NaN bad); ``water_velocity`` the
    instrument through the water-mass layer (NaN when off or invalid); ``vertical_range``
    altitude from the detected beams accounting for tilt (NaN with fewer than 3, or when the
    0x5804 block that carries it is off); ``cell_velocity`` (cells, 4) the water relative to the
    instrument per cell (0x0100 sign, NaN bad); ``heading, pitch, roll`` reported attitude
    (rad); ``depth`` reported transducer depth (m); ``burst`` whether the ping's noise was a VB
    noise burst.
    """

    ensemble: int
    t: float
    device_time: float
    frame: pd0.CoordinateFrame
    lock: bool
    detected: np.ndarray
    range_m: np.ndarray
    slant_m: np.ndarray
    velocity: np.ndarray
    water_velocity: np.ndarray
    vertical_range: float
    cell_velocity: np.ndarray
    heading: float
    pitch: float
    roll: float
    depth: float
    burst: bool


# -- the emulator ----------------------------------------------------------------------------------


class DvlEmulator(Emulator):
    """The Pathfinder 600 kHz DVL (see the module docstring)."""

    kind: ClassVar[str] = "dvl"
    nominal_rate_hz: ClassVar[float] = 5.0

    def __init__(
        self, ctx: SimContext, settings: DeviceSettings | None = None, name: str | None = None
    ) -> None:
        super().__init__(ctx, settings, name)
        self.check_noise_keys([*DEFAULT_NOISE, *INSTRUMENT_ERROR, *SPIKES])
        self.sigma = {k: self.noise(k, v) for k, v in DEFAULT_NOISE.items()}
        self.spikes = {k: self.noise(k, v) for k, v in SPIKES.items()}
        if not 0.0 <= self.spikes["spike_p"] <= 1.0:
            raise ValueError(
                f"devices.dvl.noise.spike_p: a probability in [0, 1], got {self.spikes['spike_p']}"
            )
        self._spike_rng = self.ctx.rng(self.name + "/spikes")
        sf = self.noise("scale_factor_pct", 0.0)
        mis = self.noise("misalignment_deg", 0.0)
        if not -50.0 < sf < 50.0:
            raise ValueError(f"devices.dvl.noise.scale_factor_pct: within +-50 %, got {sf}")
        #: true -> measured velocity in instrument axes (None: no instrument error)
        self.instrument_error = (
            instrument_error_matrix(sf, mis) if sf != 0.0 or mis != 0.0 else None
        )
        frame_name = str(self.option("frame", "ship")).lower()
        if frame_name not in _FRAMES:
            raise ValueError(
                f"devices.dvl.options.frame: expected one of {', '.join(_FRAMES)}, "
                f"got {frame_name!r}"
            )
        self.frame = _FRAMES[frame_name]
        self.tilts = self.option("tilts", True)
        self.three_beam = self.option("three_beam", True)
        self.max_altitude = self.option("max_altitude_m", 89.0)
        self.min_altitude = self.option("min_altitude_m", 0.2)
        if not 0.0 <= self.min_altitude < self.max_altitude:
            raise ValueError(
                "devices.dvl.options: need 0 <= min_altitude_m < max_altitude_m, got "
                f"{self.min_altitude} and {self.max_altitude}"
            )
        self.high_res = self.option("bt_high_res", False)
        self.range_block = self.option("bt_range", False)
        self.water_mass = self.option("water_mass", False)
        self.wm_layer = (
            self.option("wm_min_m", 8.0),
            self.option("wm_near_m", 16.0),
            self.option("wm_far_m", 24.0),
        )
        self.cells = self.option("cells", 0)
        if not 0 <= self.cells <= 255:
            raise ValueError(f"devices.dvl.options.cells: 0..255, got {self.cells}")
        self.cell_size = self.option("cell_size_m", 1.0)
        self.blank = self.option("blank_m", 0.88)
        self.pressure_sensor = self.option("pressure_sensor", True)
        self.temperature = self.option("temperature_c", 10.0)
        self.salinity = self.option("salinity_ppt", 35.0)
        self.density = self.option("water_density", 1025.0)
        cn, ce = (float(c) for c in ctx.scenario.vehicle.current_mps)
        self.current_ned = np.array([cn, ce, 0.0])
        #: the next ensemble number, the accumulated distances made good (m), last ping time
        self.ensemble_number = 1
        self.bt_distance = np.zeros(4)
        self.wm_distance = np.zeros(4)
        self._last_t: float | None = None
        self.fixed_leader = self._fixed_leader()
        self.serial = None
        if self.option("serial", True):
            self.serial = self.add_serial("pd0", pd0.Pd0Framer, self.option("baud", 115200))

    # -- configuration ------------------------------------------------------------------------
    @property
    def coord_transform(self) -> int:
        """The EX byte: frame in bits 3-4, tilts bit 2, 3-beam bit 1, bin mapping bit 0."""
        return int(self.frame) << 3 | int(self.tilts) << 2 | int(self.three_beam) << 1 | 1

    def _fixed_leader(self) -> pd0.FixedLeader:
        tpp = round(100.0 / self.rate_hz)
        sensors = _EZ_EH | _EZ_EP | _EZ_ER | _EZ_ET | (_EZ_ED if self.pressure_sensor else 0)
        return pd0.FixedLeader(
            firmware_version=FIRMWARE_VERSION,
            firmware_revision=self.option("firmware_revision", 0),
            system_config=SYSTEM_CONFIG,
            real_sim_flag=int(self.option("sim_flag", False)),
            lag_length=53,
            n_beams=4,
            n_cells=self.cells,
            pings_per_ensemble=1 if self.cells else 0,  # WP0: no water profile
            cell_size=self.cell_size,
            blank_after_transmit=self.blank,
            profiling_mode=1,
            low_correlation_threshold=64,
            code_repeats=5,
            percent_good_min=0,
            error_velocity_max=2.0,
            tpp_minutes=tpp // 6000,
            tpp_seconds=tpp // 100 % 60,
            tpp_hundredths=tpp % 100,
            coord_transform=self.coord_transform,
            heading_alignment=0.0,
            heading_bias=0.0,
            sensor_source=_EZ_EC | sensors,
            sensors_available=sensors,
            bin1_distance=self.blank + self.cell_size,  # WF + (WT + WS) / 2 with WT = WS
            transmit_pulse_length=self.cell_size,
            ref_layer_start=1,
            ref_layer_end=5,
            false_target_threshold=50,
            spare_39=0,
            transmit_lag_distance=0.24,
            cpu_board_serial=bytes(8),
            system_bandwidth=0,
            system_power=0,
            spare_53=0,
            serial_number=self.option("serial_number", 10000),
            beam_angle=None,  # the Pathfinder's fixed leader is 58 bytes: no beam angle byte
        )

    # -- measurement --------------------------------------------------------------------------
    def _pd0_sign(self, v: np.ndarray) -> np.ndarray:
        """A velocity of the instrument relative to the bottom/water as PD0's 0x0600 and 0x0100
        carry it: the medium relative to the instrument (negated) in transformed frames; in
        beam coordinates unchanged (RDI beam velocities are positive toward the transducer, a
        closing speed whoever moves)."""
        return v if self.frame is pd0.CoordinateFrame.BEAM else -v

    def _to_frame(
        self, v_inst: np.ndarray, heading: float, pitch: float, roll: float
    ) -> np.ndarray:
        """A velocity in instrument axes as the 3 axes (or 4 beams) of the configured frame."""
        if self.frame is pd0.CoordinateFrame.BEAM:
            return BEAMS_INSTRUMENT @ v_inst
        return frame_matrix(self.frame, heading, pitch, roll, self.tilts) @ v_inst

    def measure(self, t: float) -> DvlPing:
        """One ping at vehicle time ``t`` (truth + noise); advances the ensemble number and the
        distances made good. Call with increasing ``t``."""
        s = self.truth(t)
        k = self.sigma_scale()
        sig = self.sigma
        g = self.rng.standard_normal(20 + 4 * self.cells) * k
        d2r = math.pi / 180.0
        rot = body_to_ned(s.heading, s.pitch, s.roll)
        pos = np.array([s.x, s.y, s.z])

        # beams against the terrain
        max_slant = self.max_altitude / _C * 1.01 + 0.01
        slant = first_crossing(
            self.ctx.world.terrain, pos, BEAMS_BODY @ rot.T, max_slant, step=0.25, iterations=10
        )
        vertical = slant * _C
        with np.errstate(invalid="ignore"):
            detected = (vertical >= self.min_altitude) & (vertical <= self.max_altitude)
        if self.faults.bottom_lock_lost(t):
            detected[:] = False
        n_good = int(detected.sum())
        lock = n_good == 4 or (self.three_beam and n_good == 3)
        # a detected range is never reported as 0 (the bad marker), whatever the noise
        rng_m = np.where(detected, np.maximum(vertical + g[0:4] * sig["range_m"], 0.01), math.nan)
        vrange = math.nan
        if n_good >= 3 and self.range_block:  # only the 0x5804 block carries it
            vrange = self._vertical_range(slant, detected, rot) + g[4] * sig["range_m"]
            vrange = max(vrange, 0.01)

        # reported attitude and depth
        heading = (s.heading + g[5] * sig["heading_deg"] * d2r) % (2 * math.pi)
        pitch = s.pitch + g[6] * sig["pitch_deg"] * d2r
        roll = s.roll + g[7] * sig["roll_deg"] * d2r
        depth = max(s.z + g[8] * sig["depth_m"], 0.0)

        # velocities: instrument axes, then the configured frame
        v_inst = SWAP @ rot.T @ np.array([s.vn, s.ve, s.vd])
        cur_inst = SWAP @ rot.T @ self.current_ned
        through_water = v_inst - cur_inst
        if self.instrument_error is not None:  # scale factor and misalignment: every frame
            v_inst = self.instrument_error @ v_inst
            through_water = self.instrument_error @ through_water
        velocity = _NAN4.copy()
        if lock:
            sp = self.spikes
            if sp["spike_p"] > 0.0 and self._spike_rng.random() < sp["spike_p"]:
                d = self._spike_rng.standard_normal(3)
                size = self._spike_rng.uniform(sp["spike_min_mps"], sp["spike_max_mps"])
                v_inst = v_inst + size * d / np.linalg.norm(d)
            velocity = self._solution(v_inst, heading, pitch, roll, g[9:13] * sig["velocity_mps"])
            if self.frame is pd0.CoordinateFrame.BEAM:
                velocity[~detected] = math.nan
            elif n_good == 3:
                velocity[3] = 0.0  # 3-beam solution: no error velocity
        water = _NAN4.copy()
        if self.water_mass and self._layer_valid(rng_m):
            water = self._solution(
                through_water, heading, pitch, roll, g[13:17] * sig["water_velocity_mps"]
            )
        cells = self._cells(through_water, heading, pitch, roll, rng_m, g[20:])

        # distances made good: velocities integrated over the time since the last ping
        dt_s = 0.0 if self._last_t is None else max(t - self._last_t, 0.0)
        self._last_t = t
        self.bt_distance += np.nan_to_num(velocity) * dt_s
        self.wm_distance += np.nan_to_num(water) * dt_s

        ping = DvlPing(
            ensemble=self.ensemble_number,
            t=t,
            device_time=self.ctx.epoch + self.device_time(t),
            frame=self.frame,
            lock=lock,
            detected=detected,
            range_m=rng_m,
            slant_m=slant,
            velocity=velocity,
            water_velocity=water,
            vertical_range=vrange,
            cell_velocity=cells,
            heading=heading,
            pitch=pitch,
            roll=roll,
            depth=depth,
            burst=k > 1.0,
        )
        self.ensemble_number += 1
        return ping

    def _solution(
        self, v_inst: np.ndarray, heading: float, pitch: float, roll: float, noise: np.ndarray
    ) -> np.ndarray:
        """Four output components (beams, or 3 axes + error velocity) of a vehicle velocity in
        instrument axes, plus ``noise`` (4,)."""
        out = self._to_frame(v_inst, heading, pitch, roll)
        if len(out) == 3:
            out = np.append(out, 0.0)
        out = out + noise
        out[np.abs(out) > MAX_VELOCITY] = math.nan  # BQ-32768: over the range limit is bad
        return out

    def _vertical_range(self, slant: np.ndarray, detected: np.ndarray, rot: np.ndarray) -> float:
        """Altitude accounting for tilt: the depth below the transducer, at its position, of
        the plane through the detected beams' bottom points (least squares for four)."""
        pts = (slant[detected, None] * BEAMS_BODY[detected]) @ rot.T  # NED offsets
        a = np.column_stack([np.ones(len(pts)), pts[:, 0], pts[:, 1]])
        return float(np.linalg.solve(a.T @ a, a.T @ pts[:, 2])[0])

    def _layer_valid(self, rng_m: np.ndarray) -> bool:
        """The water-mass layer [near, far] (shortened to stay above 85 % of the shortest bottom
        range) is at least its minimum size."""
        size, near, far = self.wm_layer
        bottom = float(np.nanmin(rng_m)) if np.isfinite(rng_m).any() else math.inf
        return min(far, 0.85 * bottom) - near >= size

    def _cells(
        self,
        through_water: np.ndarray,
        heading: float,
        pitch: float,
        roll: float,
        rng_m: np.ndarray,
        noise: np.ndarray,
    ) -> np.ndarray:
        """Water velocity relative to the instrument per cell (cells, 4), NaN beyond the
        side-lobe cutoff (85 % of the shortest bottom range, or the maximum altitude)."""
        if not self.cells:
            return np.zeros((0, 4))
        water_rel = self._to_frame(through_water, heading, pitch, roll)
        if len(water_rel) == 3:
            water_rel = np.append(water_rel, 0.0)
        water_rel = self._pd0_sign(water_rel)
        bottom = float(np.nanmin(rng_m)) if np.isfinite(rng_m).any() else self.max_altitude
        centres = self.blank + self.cell_size * np.arange(1, self.cells + 1)
        out = water_rel + noise.reshape(self.cells, 4) * self.sigma["water_velocity_mps"]
        out[centres > 0.85 * bottom] = math.nan
        out[np.abs(out) > MAX_VELOCITY] = math.nan
        return out

    # -- encoding -----------------------------------------------------------------------------
    def _rtc(self, posix: float) -> np.ndarray:
        cs = round(posix * 100.0)
        when = dt.datetime.fromtimestamp(cs // 100, tz=dt.UTC)
        return np.array(
            [when.year % 100, when.month, when.day, when.hour, when.minute, when.second, cs % 100],
            dtype=np.uint8,
        )

    def _variable_leader(self, p: DvlPing) -> pd0.VariableLeader:
        n = p.ensemble
        hdg = round(math.degrees(p.heading) * 100.0) % 36000  # 0.00 .. 359.99 deg
        depth = p.depth if self.pressure_sensor else 0.0
        return pd0.VariableLeader(
            ensemble_number=n & 0xFFFF,
            rtc=self._rtc(p.device_time),
            ensemble_number_msb=(n >> 16) & 0xFF,
            bit_result=0,
            speed_of_sound=round(self.ctx.world.sound_speed),
            depth=depth,
            heading=hdg * _CDEG,
            pitch=p.pitch,
            roll=p.roll,
            salinity=self.salinity,
            temperature=self.temperature,
            mpt_minutes=self.fixed_leader.tpp_minutes,
            mpt_seconds=self.fixed_leader.tpp_seconds,
            mpt_hundredths=self.fixed_leader.tpp_hundredths,
            heading_std=0.0,
            pitch_std=0.0,
            roll_std=0.0,
            adc=np.zeros(8, np.uint8),
            error_status=0,
            reserved_46=0,
            pressure=self.density * _GRAVITY * depth,  # gauge pressure, Pa
            pressure_variance=0.0,
            spare_56=0,
            rtc_y2k=np.zeros(8, np.uint8),  # Pathfinder: spare
            spare_65=0,
            health_status=0,
            leak_a_count=0,
            leak_b_count=0,
            tx_voltage=math.nan,  # not available
            tx_current=math.nan,
            transducer_impedance=math.nan,
        )

    def _amplitude(self, p: DvlPing) -> np.ndarray:
        """Bottom echo amplitude per beam, counts: falls with range; noise level when none."""
        amp = np.where(p.detected, 250.0 - 1.8 * np.nan_to_num(p.range_m), 12.0)
        amp = amp + self.rng.integers(-3, 4, 4)
        return np.clip(np.rint(amp), 0, 255).astype(np.uint8)

    def _bottom_track(self, p: DvlPing, amp: np.ndarray) -> pd0.BottomTrack:
        cm = np.where(p.detected, np.rint(np.nan_to_num(p.range_m) * 100.0), 0.0).astype(np.int64)
        good = p.detected.astype(np.uint8)
        water = self._pd0_sign(p.water_velocity)  # 0x0600: the layer relative to the instrument
        wm_ok = np.isfinite(water).any()
        size, near, far = self.wm_layer
        shortest = float(np.nanmin(p.range_m)) if p.detected.any() else math.inf
        return pd0.BottomTrack(
            pings_per_ensemble=1,
            delay_before_reacquire=0,
            correlation_min=220,
            amplitude_min=24,
            percent_good_min=0,
            mode=8,
            error_velocity_max=1.0,
            reserved_12=bytes(4),
            range_lsb=(cm & 0xFFFF) * 0.01,
            velocity=self._pd0_sign(p.velocity),  # 0x0600: the bottom relative to the instrument
            correlation=good * np.uint8(240),
            evaluation_amplitude=amp,
            percent_good=good * np.uint8(100),
            ref_layer_min=size,
            ref_layer_near=near,
            ref_layer_far=far,
            ref_velocity=water,
            ref_correlation=np.full(4, 200 if wm_ok else 0, np.uint8),
            ref_intensity=np.full(4, 90 if wm_ok else 0, np.uint8),
            ref_percent_good=np.full(4, 100 if wm_ok else 0, np.uint8),
            max_depth=110.0,  # BX1100 dm
            rssi=np.clip(amp.astype(int) - 10, 0, 255).astype(np.uint8),
            gain=int(shortest > 5.0),  # BI5: high gain above 5 m
            range_msb=(cm >> 16) * 655.36,
            reserved_81=None,  # the Pathfinder's bottom track is 81 bytes
        )

    @staticmethod
    def _wrap_s32(metres: np.ndarray) -> np.ndarray:
        """Distances in m as the s32 0.01 mm counters carry them (wrapping)."""
        raw = np.rint(metres * 1e5).astype(np.int64)
        return ((raw + 2**31) % _S32 - 2**31) * 1e-5

    def _high_res(self, p: DvlPing) -> pd0.BottomTrackHighRes:
        return pd0.BottomTrackHighRes(
            bt_velocity=p.velocity,  # 0x5803: the instrument over the bottom
            bt_distance=self._wrap_s32(self.bt_distance),
            wm_velocity=p.water_velocity,
            wm_distance=self._wrap_s32(self.wm_distance),
            speed_of_sound=round(self.ctx.world.sound_speed),  # m/s (the guide gives no unit)
        )

    def _range(self, p: DvlPing, amp: np.ndarray) -> pd0.BottomTrackRange:
        r = np.where(p.detected, np.nan_to_num(p.range_m), 0.0)
        d = p.detected
        pairs = [(r[0] + r[1]) / 2.0 if d[0] and d[1] else None,
                 (r[2] + r[3]) / 2.0 if d[2] and d[3] else None]  # fmt: skip
        valid = [x for x in pairs if x is not None]
        slant = sum(valid) / len(valid) if valid else math.nan
        delta = pairs[0] - pairs[1] if pairs[0] is not None and pairs[1] is not None else 0.0
        return pd0.BottomTrackRange(
            slant_range=slant,
            axis_delta_range=delta,
            vertical_range=p.vertical_range,
            percent_good_4beam=100 if d.all() else 0,
            percent_good_beams12=100 if pairs[0] is not None else 0,
            percent_good_beams34=100 if pairs[1] is not None else 0,
            raw_range=r,
            max_filter=np.clip(amp.astype(int) - 20, 0, 255).astype(np.uint8),
            max_amplitude=amp,
        )

    def _profile(self, p: DvlPing) -> dict[str, Any]:
        """The water-profile data types for ``self.cells`` cells (none when 0)."""
        if not self.cells:
            return {}
        n = self.cells
        good = np.isfinite(p.cell_velocity)
        dist = self.blank + self.cell_size * np.arange(1, n + 1)
        corr = np.where(
            good, self.rng.integers(100, 121, (n, 4)), self.rng.integers(10, 40, (n, 4))
        )
        echo = np.where(good, np.clip(160.0 - 2.0 * dist, 40, 255)[:, None], 50.0)
        echo = echo + self.rng.integers(-2, 3, (n, 4))
        if self.frame is pd0.CoordinateFrame.BEAM:
            pg = np.where(good, 100, 0)
        else:  # 3-beam solutions, rejected, more than one beam bad, 4-beam solutions
            ok = good.all(axis=1)
            pg = np.zeros((n, 4), int)
            pg[:, 2] = np.where(ok, 0, 100)
            pg[:, 3] = np.where(ok, 100, 0)
        return {
            "velocity": pd0.Velocity(velocity=p.cell_velocity),
            "correlation": pd0.Correlation(correlation=corr.astype(np.uint8)),
            "echo_intensity": pd0.EchoIntensity(
                intensity=np.clip(np.rint(echo), 0, 255).astype(np.uint8)
            ),
            "percent_good": pd0.PercentGood(percent_good=pg.astype(np.uint8)),
        }

    def ensemble(self, p: DvlPing) -> pd0.Ensemble:
        """The PD0 ensemble of one ping (the configured data types)."""
        amp = self._amplitude(p)
        return pd0.Ensemble(
            fixed_leader=self.fixed_leader,
            variable_leader=self._variable_leader(p),
            bottom_track=self._bottom_track(p, amp),
            bt_high_res=self._high_res(p) if self.high_res else None,
            bt_range=self._range(p, amp) if self.range_block else None,
            **self._profile(p),
        )

    def frame_at(self, t: float) -> bytes:
        """The encoded ensemble of the ping at vehicle time ``t`` (advances the state)."""
        return pd0.encode(self.ensemble(self.measure(t)))

    def tick(self, t: float) -> None:
        frame = self.frame_at(t)
        if self.serial is not None:
            self.serial.send(frame, t)
