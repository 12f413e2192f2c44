"""Adapters: decoded device messages -> fusion samples, and device clocks -> the common clock.

Pure functions and small state machines over the codecs' immutable messages (no transports):

* :func:`ins_from_hn100`: an HN-100 solution, serial (:data:`auvgw.drivers.hn100.Hn100Nav`) or CAN
  (the DBC's epoch sample ``HN100_Sample``; same field names) -> :class:`InsSample` at the
  DEVICE time (``time``, s since power-up).
* :func:`dvl_from_pd0`: a PD0 :class:`~auvgw.drivers.pd0.Ensemble` -> :class:`DvlSample` at the
  device time of the variable leader's RTC, with the velocity in the frame the fixed leader names
  (EX bits 3-4), bottom lock from the valid beams, altitude and the DVL's pressure depth.
* any other message type of role ``attitude`` or ``velocity`` (a site's own device, registered
  through the ``auvgw.devices`` entry point) is read by its role's members
  (:class:`~auvgw.drivers.roles.Attitude`, :class:`~auvgw.drivers.roles.Velocity`): the types
  read by an adapter of their own are :data:`OWN_ADAPTERS`.
* :class:`DeviceClock`: maps one device's own clock onto the common clock (host receive time)
  from (device time, receive time) pairs; :class:`MessageAdapter` does all of it per device, as
  the bus stage and the offline recording mode both use it (so both give identical samples).

PD0 frames (Pathfinder DVL Guide, coordinate transformation; ``sim_devices/dvl.py`` follows it):

==========  ===========================================  =========================================
EX frame    0x0600 / 0x5803 velocity axes                DvlSample
==========  ===========================================  =========================================
beam        closing speed along beams 1-4 (+ toward      ``"instrument"``: least squares over the
            the transducer, whoever moves; no negation)  valid beams (3 or 4) with the Janus
                                                         geometry (beam angle, convex/concave)
instrument  X (beam 1 -> 2), Y (beam 4 -> 3), Z (up,     ``"instrument"``: RDI instrument axes;
            toward the face), error                      the mounting rotation maps them to body
                                                         axes (:data:`RDI_DOWN_BEAM3_FORWARD_DEG`)
ship        starboard, forward, mast, error; levelled    ``"body"``: un-levelled with the variable
            by pitch and roll when tilts are used (EX    leader's pitch and roll (what the DVL
            bit 2)                                       used), then (forward, starboard, down)
earth       east, north, up, error                       ``"body"``: un-rotated with the variable
                                                         leader's heading (and tilts)
==========  ===========================================  =========================================

0x0600 carries the bottom moving relative to the instrument in the transformed frames, so its
three axes are negated (:attr:`~auvgw.drivers.pd0.BottomTrack.vehicle_velocity`); 0x5803 (the
high-resolution velocity, 0.01 mm/s, preferred when present and valid) is already the instrument
over the bottom. Ship and earth velocities become ``"body"`` axes on the assumption that the
DVL's own heading alignment (EA) makes its ship axes the vehicle's; the filter still applies the
configured lever arm to them.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from auvgw.drivers import pd0, registry, roles
from auvgw.drivers.spec import WIRE_TYPES
from auvgw.fusion.frames import beam_matrix
from auvgw.fusion.samples import DvlSample, InsSample
from auvgw.ground.devicetime import ClockStats, DeviceClock
from auvgw.ground.errors import DataError

__all__ = [
    "ATTITUDE_TYPES",
    "INS_TYPES",
    "OWN_ADAPTERS",
    "PD0_TYPES",
    "PD6_VELOCITY_TYPES",
    "RDI_DOWN_BEAM3_FORWARD_DEG",
    "VELOCITY_TYPES",
    "AdapterError",
    "AdapterStats",
    "ClockStats",
    "DeviceClock",
    "MessageAdapter",
    "attitude_from_pd0",
    "attitude_from_pd6",
    "beam_matrix",
    "dvl_from_pd0",
    "dvl_from_pd6",
    "dvl_from_velocity",
    "ins_from_hn100",
    "ins_time_wrap",
    "ins_usable",
    "janus_angle",
]

#: message type names (``TYPE`` or class name) of INS solutions (the registry's role ``ins``)
INS_TYPES = registry.types_with_role("ins")
#: message type names of DVL messages this module adapts
PD0_TYPES = frozenset({"pd0.Ensemble"})
#: PD6 bottom-track velocity sentences -> DvlSample frame
PD6_VELOCITY_TYPES = {"pd6.BI": "instrument", "pd6.BS": "body", "pd6.BE": "earth"}
#: every message type that can be an attitude source (the registry's role ``attitude``: INS;
#: a DVL's compass: PD0 variable leader, PD6 ``:SA``)
ATTITUDE_TYPES = registry.types_with_role("attitude")
#: every message type that can be a velocity source (the registry's role ``velocity``)
VELOCITY_TYPES = registry.types_with_role("velocity")
#: role -> the types of that role read by an adapter of their own, not by the role's members
#: (:data:`auvgw.drivers.roles.ROLE_PROTOCOLS`): PD0 carries its attitude in the variable leader
#: and its velocity in beams and leaders, PD6 its bottom track in each sentence's own axes
OWN_ADAPTERS: dict[str, frozenset[str]] = {
    "attitude": PD0_TYPES,
    "velocity": PD0_TYPES | frozenset(PD6_VELOCITY_TYPES),
}

#: ``DvlMount.rotation_deg`` (roll, pitch, yaw) of RDI instrument axes (X starboard, Y forward,
#: Z up) for a down-facing DVL with beam 3 forward: ``Rz(90) Ry(0) Rx(180)`` maps (X, Y, Z) to
#: body (forward, starboard, down)
RDI_DOWN_BEAM3_FORWARD_DEG = (180.0, 0.0, 90.0)

#: Janus angle of the fixed leader's system configuration bits 8-9 (Pathfinder/Workhorse guides)
_BEAM_ANGLES_DEG = {0: 15.0, 1: 20.0, 2: 30.0}
#: EZ sensor source bit of the depth sensor (ED computed from the pressure sensor)
_EZ_DEPTH = 0x40


class AdapterError(DataError):
    """A message the fusion cannot use as it is (names the message and what is missing)."""


# -- INS -----------------------------------------------------------------------------------------


def _missing(msg: Any, protocol: type) -> AdapterError:
    """The error of a message that lacks a role's members (called once a read has failed, so
    the good path pays nothing): it names the first missing one."""
    missing = [n for n in roles.members(protocol) if not hasattr(msg, n)] or ["?"]
    return AdapterError(
        f"{type(msg).__name__}: no field {missing[0]!r} (a message of role "
        f"{roles.role_of(protocol)!r} needs {', '.join(roles.members(protocol))})"
    )


def ins_usable(msg: Any) -> bool:
    """The INS says its attitude is good: binary frame ``aligned`` and not ``error``; CAN
    ``alignment`` FINE and ``error`` OK. Messages without these flags count as usable."""
    if hasattr(msg, "aligned") and not msg.aligned:
        return False
    alignment = getattr(msg, "alignment", "FINE")
    if alignment not in ("FINE", 2):
        return False
    error = getattr(msg, "error", False)
    return error in (False, 0, "OK")


def ins_from_hn100(msg: roles.Ins, t: float | None = None) -> InsSample:
    """An HN-100 solution (serial ``Hn100Nav`` or CAN ``HN100_Sample``, SI) as an InsSample.

    ``t``: the sample's time on the common clock; default the DEVICE time ``msg.time`` (s).
    Heading is passed on as the INS reports it (0..2 pi; the filter wraps). The specific force
    is None when any component is invalid (NaN); NaN attitude or rates make the sample unusable
    (:meth:`InsSample.is_finite`), which the filter counts and drops.
    """
    try:
        accel = (float(msg.accel_x), float(msg.accel_y), float(msg.accel_z))
        return InsSample(
            t=float(msg.time) if t is None else float(t),
            roll=float(msg.roll),
            pitch=float(msg.pitch),
            heading=float(msg.heading),
            rates=(float(msg.rate_x), float(msg.rate_y), float(msg.rate_z)),
            accel=accel if all(math.isfinite(a) for a in accel) else None,
        )
    except AttributeError:
        raise _missing(msg, roles.Ins) from None


def ins_time_wrap(msg_type: type) -> float | None:
    """Period (s) after which the ``time`` field of an HN-100 message class wraps: ``2^bits x
    scale`` of an unsigned integer wire field (the shipped table: u32 of 100 us, 4.97 days);
    None when the class does not say (CAN: a 48-bit microsecond counter, 8.9 years)."""
    if not dataclasses.is_dataclass(msg_type):
        return None
    for f in dataclasses.fields(msg_type):
        if f.name != "time":
            continue
        w = f.metadata.get("wire")
        if w is None or not w.type.startswith("u") or w.type not in WIRE_TYPES:
            return None
        return float(2 ** int(w.type[1:])) * float(w.scale)
    return None


# -- DVL -----------------------------------------------------------------------------------------


def janus_angle(fixed: pd0.FixedLeader) -> float:
    """Beam angle from the vertical, rad: the fixed leader's beam angle (Workhorse), else the
    system configuration bits 8-9 (15, 20, 30 deg)."""
    if fixed.beam_angle is not None and fixed.beam_angle > 0.0:
        return float(fixed.beam_angle)
    code = (fixed.system_config >> 8) & 3
    if code not in _BEAM_ANGLES_DEG:
        raise AdapterError(
            "pd0 fixed leader: system configuration says 'other' beam angle (bits 8-9 = 3) and "
            "the block has no beam-angle byte; beam coordinates cannot be converted"
        )
    return math.radians(_BEAM_ANGLES_DEG[code])


def _bt_velocity(ens: pd0.Ensemble, frame: pd0.CoordinateFrame, high_res: bool) -> list[float]:
    """The 4 bottom-track components as the instrument moving over the bottom (beam: closing
    speeds as on the wire), preferring 0x5803 when valid; NaN when bad. Plain floats: the
    adapter works on four numbers, where numpy's per-call cost is most of the work (the ROS 2
    bridge runs it for every ensemble, docs/ros2.md#cost)."""
    hr = ens.bt_high_res
    beam = frame is pd0.CoordinateFrame.BEAM
    if high_res and hr is not None:
        v = np.asarray(hr.vehicle_velocity, dtype=float).tolist()
        good = [math.isfinite(x) for x in v]
        if (sum(good) >= 3) if beam else all(good[:3]):
            return v
    bt = ens.bottom_track
    if bt is None:
        return [math.nan] * 4
    return np.asarray(bt.velocity if beam else bt.vehicle_velocity, dtype=float).tolist()


def _altitude(ens: pd0.Ensemble) -> float:
    r = ens.bt_range
    if r is not None and math.isfinite(r.vertical_range):
        return float(r.vertical_range)
    bt = ens.bottom_track
    if bt is None:
        return math.nan
    good = [x for x in bt.range.tolist() if math.isfinite(x)]
    return sum(good) / len(good) if good else math.nan


def _body_from_ship(
    v: list[float], heading: float, pitch: float, roll: float
) -> tuple[float, float, float]:
    """A ship-frame vector (starboard, forward, mast; earth: east, north, up) as body FRD:
    ``R(heading, pitch, roll)^T SWAP v`` (rad), written out on three floats
    (:func:`~auvgw.ground.geometry.body_to_ned_matrix`'s ``R``)."""
    f, s, d = v[1], v[0], -v[2]  # SWAP: (forward, starboard, down) or (north, east, down)
    ch, sh = math.cos(heading), math.sin(heading)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return (
        ch * cp * f + sh * cp * s - sp * d,
        (ch * sp * sr - sh * cr) * f + (sh * sp * sr + ch * cr) * s + cp * sr * d,
        (ch * sp * cr + sh * sr) * f + (sh * sp * cr - ch * sr) * s + cp * cr * d,
    )


def dvl_from_pd0(ens: pd0.Ensemble, t: float | None = None, high_res: bool = True) -> DvlSample:
    """A PD0 ensemble as a DvlSample (see the module docstring for the frames).

    ``t``: the sample's time on the common clock; default the device time of the variable
    leader's RTC (POSIX s). Bottom lock: three valid axes (transformed frames) or at least three
    valid beams (beam frame); without lock the velocity is NaN. ``altitude``: the 0x5804
    vertical range, else the mean of the valid per-beam 0x0600 ranges (m). ``depth``: the
    variable leader's transducer depth when the fixed leader says it comes from the DVL's
    pressure sensor (EZ depth bit), else NaN.

    Raises :class:`AdapterError` without a fixed leader (the frame is unknown), without a
    variable leader when the frame or time needs it, or with an invalid clock and no ``t``.
    """
    fixed = ens.fixed_leader
    if fixed is None:
        raise AdapterError("pd0 ensemble without a fixed leader: coordinate frame unknown")
    var = ens.variable_leader
    if t is None:
        t = math.nan if var is None else var.device_time_s
        if not math.isfinite(t):
            raise AdapterError(
                "pd0 ensemble without a valid variable-leader clock (RTC); no device time"
            )
    frame = fixed.coordinate_frame
    raw = _bt_velocity(ens, frame, high_res)
    nan3 = (math.nan, math.nan, math.nan)
    if frame is pd0.CoordinateFrame.BEAM:
        beams = np.array(raw)
        good = np.isfinite(beams)
        lock = int(good.sum()) >= 3
        vel: tuple[float, ...] = nan3
        if lock:
            B = beam_matrix(janus_angle(fixed), convex=bool(fixed.system_config & 0x08))
            vel = tuple(np.linalg.lstsq(B[good], beams[good], rcond=None)[0].tolist())
        out_frame = "instrument"
    else:
        vel = tuple(raw[:3])
        lock = all(math.isfinite(x) for x in vel)
        if frame is pd0.CoordinateFrame.INSTRUMENT:
            out_frame = "instrument"
        else:
            if var is None:
                raise AdapterError(
                    f"pd0 ensemble in {frame.name.lower()} coordinates without a variable "
                    "leader: the attitude the DVL used is unknown"
                )
            pitch, roll = (var.pitch, var.roll) if fixed.tilts_used else (0.0, 0.0)
            heading = var.heading if frame is pd0.CoordinateFrame.EARTH else 0.0
            # ship/earth = SWAP R(heading, pitch, roll) v_body  =>  v_body = R^T SWAP v
            vel = _body_from_ship(raw, heading, pitch, roll)
            out_frame = "body"
    if not lock:
        vel = nan3
    depth = math.nan
    if var is not None and fixed.sensor_source & _EZ_DEPTH:
        depth = float(var.depth)
    a, b, c = vel
    return DvlSample(
        t=float(t),
        velocity=(a, b, c),
        bottom_lock=lock,
        frame=out_frame,  # type: ignore[arg-type]
        altitude=_altitude(ens),
        depth=depth,
    )


def attitude_from_pd0(ens: pd0.Ensemble, t: float) -> InsSample | None:
    """The DVL's own compass and tilts (PD0 variable leader, rad) as an attitude sample at
    ``t`` (no rates); None without a variable leader."""
    var = ens.variable_leader
    if var is None:
        return None
    return InsSample(t=float(t), roll=float(var.roll), pitch=float(var.pitch),
                     heading=float(var.heading))


def attitude_from_pd6(msg: roles.Attitude, t: float) -> InsSample:
    """An attitude message (a PD6 ``:SA`` sentence, any type of role ``attitude`` without an
    adapter of its own: roll, pitch, heading in rad) as an attitude sample at ``t`` (no
    rates)."""
    try:
        return InsSample(t=float(t), roll=float(msg.roll), pitch=float(msg.pitch),
                         heading=float(msg.heading))  # fmt: skip
    except AttributeError:
        raise _missing(msg, roles.Attitude) from None


def dvl_from_pd6(msg: Any, t: float) -> DvlSample:
    """A PD6 bottom-track velocity sentence as a DvlSample at ``t`` (PD6 carries no per-sentence
    device time: ``t`` is the receive time). ``:BI`` instrument X, Y, Z (transducer movement, as
    the PD0 instrument frame); ``:BS`` ship (transverse = starboard, longitudinal = forward,
    normal = up) -> body (forward, starboard, down), taken as not levelled; ``:BE`` (east, north,
    up) -> NED, ``"earth"``. Status ``V`` or a missing component (NaN) means no bottom lock."""
    name = str(getattr(msg, "TYPE", ""))
    frame = PD6_VELOCITY_TYPES.get(name)
    if frame is None:
        raise AdapterError(f"{name or type(msg).__name__}: not a PD6 bottom-track velocity")
    if frame == "instrument":
        v = (msg.x, msg.y, msg.z)
    elif frame == "body":
        v = (msg.longitudinal, msg.transverse, -msg.normal)
    else:
        v = (msg.north, msg.east, -msg.up)
    vel = tuple(float(c) for c in v)
    lock = msg.status == "A" and all(math.isfinite(c) for c in vel)
    if not lock:
        vel = (math.nan, math.nan, math.nan)
    return DvlSample(t=float(t), velocity=vel, bottom_lock=lock, frame=frame)  # type: ignore[arg-type]


def dvl_from_velocity(msg: roles.Velocity) -> DvlSample:
    """A message of role ``velocity`` read by its role's members (a site's own DVL; PD0 and PD6
    have adapters of their own): at its device ``time`` (s), ``velocity`` (m/s) in ``frame``
    axes, NaN without ``bottom_lock``."""
    try:
        frame, vel = msg.frame, tuple(float(c) for c in msg.velocity)
        t, lock = float(msg.time), bool(msg.bottom_lock)
    except AttributeError:
        raise _missing(msg, roles.Velocity) from None
    if frame not in typing.get_args(roles.VelocityFrame):
        raise AdapterError(
            f"{type(msg).__name__}: frame {frame!r} is not one of "
            f"{', '.join(typing.get_args(roles.VelocityFrame))}"
        )
    if len(vel) != 3:
        raise AdapterError(f"{type(msg).__name__}: velocity has {len(vel)} components, not 3")
    lock = lock and all(math.isfinite(c) for c in vel)
    return DvlSample(t=t, velocity=vel if lock else (math.nan,) * 3, bottom_lock=lock,
                     frame=frame)  # fmt: skip


# -- clocks --------------------------------------------------------------------------------------


# -- per-device adapter ---------------------------------------------------------------------------

#: the warm-up releases its samples after this many at the latest (a paused clock)
_WARMUP_MAX_SAMPLES = 1000


@dataclass
class AdapterStats:
    """Counters of a :class:`MessageAdapter` (messages)."""

    ins: int = 0  #: INS samples produced
    dvl: int = 0  #: DVL samples produced
    ins_not_aligned: int = 0  #: INS solutions flagged not aligned / in error (dropped)
    ignored: int = 0  #: messages of a second INS/DVL device or of another type
    errors: int = 0  #: messages an adapter rejected (AdapterError)
    last_error: str = ""
    devices: dict[str, str] = field(default_factory=dict)  #: device -> role ("ins", "dvl")


class MessageAdapter:
    """Decoded messages of named devices -> samples on the common clock (host receive time, s).

    Sources are named, never guessed: ``ins_device`` (the attitude source, ``[fusion] attitude``)
    and ``dvl_device`` (the velocity source, ``velocity``) are gateway device names, by default
    ``"ins"`` and ``"dvl"``. Whatever order messages arrive in, only the named devices feed the
    filter (an HN-100 on serial AND CAN, or two INS, is one source: the other is counted as
    ignored), so live, replay and offline runs choose the same ones. The attitude source may be
    an INS (HN-100 serial or CAN) or a DVL's compass (PD0 variable leader, PD6 ``:SA``); the
    velocity source a PD0 or PD6 DVL. Every device has its own :class:`DeviceClock`
    (``latency_s[device]`` its fixed delay, ``clock`` keyword arguments for all); PD6 sentences
    carry no device time, so theirs is the receive time minus the latency.
    ``require_aligned``: drop INS solutions the INS flags as not aligned or in error.
    """

    def __init__(
        self,
        ins_device: str | None = "ins",
        dvl_device: str | None = "dvl",
        latency_s: Mapping[str, float] | None = None,
        clock: Mapping[str, Any] | None = None,
        require_aligned: bool = True,
        high_res: bool = True,
        warmup_s: float = 0.0,
    ) -> None:
        self.ins_device = ins_device or "ins"
        self.dvl_device = dvl_device or "dvl"
        self.latency_s = dict(latency_s or {})
        self.clock_args = dict(clock or {})
        self.require_aligned = require_aligned
        self.high_res = high_res
        self.clocks: dict[str, DeviceClock] = {}
        self.stats = AdapterStats()
        self.warmup_s = float(warmup_s)
        #: receive time (s) the warm-up ends at (None: not begun, -inf: over)
        self._warm_end: float | None = None
        #: held samples: (device, sample, the clock offset it was mapped with)
        self._held: list[tuple[str, InsSample | DvlSample, float]] = []

    def roles(self, device: str, msg: Any) -> tuple[bool, bool]:
        """``(attitude, velocity)``: what a message of ``device`` gives the filter."""
        name = str(getattr(msg, "TYPE", type(msg).__name__))
        return (
            device == self.ins_device and name in ATTITUDE_TYPES,
            device == self.dvl_device and name in VELOCITY_TYPES,
        )

    def role(self, device: str, msg: Any) -> str | None:
        """``"ins"``, ``"dvl"`` or None (ignored) for a message of ``device`` (attitude first
        when a device is both)."""
        att, vel = self.roles(device, msg)
        return "ins" if att else "dvl" if vel else None

    def _clock(self, device: str, msg_type: type, role: str) -> DeviceClock:
        c = self.clocks.get(device)
        if c is None:
            args = dict(self.clock_args)
            if role == "ins":
                args.setdefault("wrap_s", ins_time_wrap(msg_type))
            c = DeviceClock(latency_s=self.latency_s.get(device, 0.0), **args)
            self.clocks[device] = c
            self.stats.devices[device] = role
        return c

    def adapt(self, device: str, t_recv_s: float, msg: Any) -> InsSample | DvlSample | None:
        """The (first) sample of one decoded message received at ``t_recv_s`` (s), or None
        when it is ignored or unusable (counted); see :meth:`adapt_all`."""
        out = self.adapt_all(device, t_recv_s, msg)
        return out[0] if out else None

    def adapt_all(
        self, device: str, t_recv_s: float, msg: Any
    ) -> list[InsSample | DvlSample]:
        """The samples of one decoded message received at ``t_recv_s`` (s): attitude and/or
        velocity (a PD0 ensemble of a DVL that is both sources gives both); empty when it is
        ignored or unusable (counted), or while the device's clock is warming up.

        Warm-up (``warmup_s`` > 0): a device's clock offset is the smallest receive delay seen,
        and the first frames after a port opens arrive late (a backlog, a cold pipeline). Mapped
        at once, they would stand ``delta`` late on the common clock until a faster frame
        lowers the offset; the INS samples after it then fall on times the filter has passed
        and the motion between is lost (``delta`` x speed of position). So every sample of the
        first ``warmup_s`` s of receive time (from the first message of any device) is held,
        and all are released together, in the order they came, each re-timed with its device's
        offset learnt over the window. A device first heard after the window is not held."""
        out = self._adapt_all(device, t_recv_s, msg)
        if not out:
            return out
        if self._warm_end is None:
            if self.warmup_s <= 0:
                return out
            self._warm_end = t_recv_s + self.warmup_s
        if not self._held and t_recv_s >= self._warm_end:
            return out
        off = self.clocks[device].offset or 0.0
        self._held.extend((device, s, off) for s in out)
        if t_recv_s < self._warm_end and len(self._held) < _WARMUP_MAX_SAMPLES:
            return []
        return self.flush()

    def flush(self) -> list[InsSample | DvlSample]:
        """Release the samples still held in the warm-up (its end, or the end of the data),
        each re-timed with its device's offset as learnt now; see :meth:`adapt_all`."""
        held, self._held = self._held, []
        self._warm_end = -math.inf if self._warm_end is not None else None
        out = []
        for d, s, o in held:
            off = self.clocks[d].offset or 0.0
            # a move below 1 us is the clock's skew creep over the window, not a late frame
            out.append(s if abs(off - o) < 1e-6 else s._replace(t=s.t + (off - o)))
        return out

    def _adapt_all(
        self, device: str, t_recv_s: float, msg: Any
    ) -> list[InsSample | DvlSample]:
        att, vel = self.roles(device, msg)
        if not (att or vel):
            self.stats.ignored += 1
            return []
        name = str(getattr(msg, "TYPE", type(msg).__name__))
        out: list[InsSample | DvlSample] = []
        try:
            if name in INS_TYPES:
                if self.require_aligned and not ins_usable(msg):
                    self.stats.ins_not_aligned += 1
                    return []
                s = ins_from_hn100(msg)
                t = self._clock(device, type(msg), "ins").to_common(s.t, t_recv_s)
                self.stats.ins += 1
                return [s._replace(t=t)]
            if name in PD0_TYPES:
                d = dvl_from_pd0(msg, high_res=self.high_res)
                role = "ins" if att else "dvl"
                t = self._clock(device, type(msg), role).to_common(d.t, t_recv_s)
                if att:
                    a = attitude_from_pd0(msg, t)
                    if a is not None:
                        self.stats.ins += 1
                        out.append(a)
                if vel:
                    self.stats.dvl += 1
                    out.append(d._replace(t=t))
                return out
            if vel and name not in PD6_VELOCITY_TYPES:
                # a velocity type without an adapter of its own: its role's members
                d = dvl_from_velocity(msg)
                t = self._clock(device, type(msg), "dvl").to_common(d.t, t_recv_s)
                if att:
                    self.stats.ins += 1
                    out.append(attitude_from_pd6(msg, t))
                self.stats.dvl += 1
                return [*out, d._replace(t=t)]
            # PD6 and any other attitude type: no device time in the message
            t = self._clock(device, type(msg), "ins" if att else "dvl").to_common(
                t_recv_s, t_recv_s
            )
            if att:
                self.stats.ins += 1
                return [attitude_from_pd6(msg, t)]
            self.stats.dvl += 1
            return [dvl_from_pd6(msg, t)]
        except AdapterError as exc:
            self.stats.errors += 1
            self.stats.last_error = f"{device}: {exc}"
            return []
