"""The roles of the device registry as Protocols: what a consumer reads of a message that plays a
role (:data:`auvgw.drivers.registry.ROLES`), so a message type declared with a role is checked to
have it, and the consumers' reads are typed.

Each member is a read-only property (a frozen dataclass field satisfies it) whose return type
carries its unit (``Annotated[float, "rad"]``: mypy sees a float, :func:`members` the unit).
Angles are radians, body axes FRD (forward, starboard, down), the earth frame NED.

==========  =================  ======================================================  =========
role        Protocol           members                                                 consumer
==========  =================  ======================================================  =========
``ins``     :class:`Ins`       ``time`` s (device clock), attitude, ``rate_x/y/z``     fusion
                               rad/s, ``accel_x/y/z`` m/s^2 (specific force, body)
attitude    :class:`Attitude`  ``roll``, ``pitch``, ``heading`` rad (from north,       fusion,
                               clockwise)                                              Rerun
velocity    :class:`Velocity`  ``time`` s (device clock), ``velocity`` m/s over the    fusion
                               bottom in ``frame`` axes, ``bottom_lock``
field       :class:`Field`     ``counter`` (sample count), ``bx``, ``by``, ``bz`` nT    magnetic
                               (sensor axes)                                           SLAM
range       :class:`Range`     ``range`` m, ``bearing`` rad (from the bow, clockwise),  magnetic
                               ``depression`` rad (below the horizontal)               SLAM
==========  =================  ======================================================  =========

A type whose consumer reads it through an adapter of its own (PD0 ensembles carry attitude and
bottom track in their leaders and beams; PD6 bottom-track sentences in their own axes) need not
have its role's members: fusion names those types (``fusion.adapters.OWN_ADAPTERS``). The
other roles (``sonar``, ``swath``, ``samples``, ``actuators``) have one consumer each that reads
its device's own message.
"""

from __future__ import annotations

import functools
import typing
from typing import Annotated, Literal, Protocol, get_type_hints

__all__ = [
    "ROLE_PROTOCOLS",
    "Attitude",
    "Field",
    "Ins",
    "Range",
    "Velocity",
    "VelocityFrame",
    "members",
    "role_of",
]

#: a plain count (no unit)
Count = Annotated[int, ""]
Seconds = Annotated[float, "s"]
Radians = Annotated[float, "rad"]
RadPerSecond = Annotated[float, "rad/s"]
MetresPerSecond2 = Annotated[float, "m/s^2"]
Metres = Annotated[float, "m"]
NanoTesla = Annotated[float, "nT"]
#: the axes of a :class:`Velocity`: the DVL's instrument axes, the body (FRD) or the earth (NED)
VelocityFrame = Literal["instrument", "body", "earth"]


class Attitude(Protocol):
    """Role ``attitude``: the vehicle's attitude (rad): roll and pitch of body FRD, heading from
    north clockwise (0 .. 2 pi or -pi .. pi; the consumers wrap)."""

    @property
    def roll(self) -> Radians: ...
    @property
    def pitch(self) -> Radians: ...
    @property
    def heading(self) -> Radians: ...


class Ins(Attitude, Protocol):
    """Role ``ins``: a full INS solution: the attitude at ``time`` (s, the device's own clock),
    body rates (rad/s, FRD) and specific force (m/s^2, FRD; NaN: invalid)."""

    @property
    def time(self) -> Seconds: ...
    @property
    def rate_x(self) -> RadPerSecond: ...
    @property
    def rate_y(self) -> RadPerSecond: ...
    @property
    def rate_z(self) -> RadPerSecond: ...
    @property
    def accel_x(self) -> MetresPerSecond2: ...
    @property
    def accel_y(self) -> MetresPerSecond2: ...
    @property
    def accel_z(self) -> MetresPerSecond2: ...


class Velocity(Protocol):
    """Role ``velocity``: the instrument's velocity over the bottom at ``time`` (s, the device's
    own clock), m/s, three components in ``frame`` axes (NaN: a missing component), and whether
    the device has bottom lock (False: the velocity is ignored)."""

    @property
    def time(self) -> Seconds: ...
    @property
    def velocity(self) -> tuple[float, float, float]: ...
    @property
    def frame(self) -> VelocityFrame: ...
    @property
    def bottom_lock(self) -> bool: ...


class Field(Protocol):
    """Role ``field``: one magnetometer sample: the flux density (nT) along the sensor's x, y, z
    axes and the sample ``counter`` (the magnetic stage times samples by it)."""

    @property
    def counter(self) -> Count: ...
    @property
    def bx(self) -> NanoTesla: ...
    @property
    def by(self) -> NanoTesla: ...
    @property
    def bz(self) -> NanoTesla: ...


class Range(Protocol):
    """Role ``range``: one acoustic fix of a beacon: slant ``range`` (m), ``bearing`` from the
    bow, clockwise (rad), ``depression`` below the horizontal (rad)."""

    @property
    def range(self) -> Metres: ...
    @property
    def bearing(self) -> Radians: ...
    @property
    def depression(self) -> Radians: ...


#: registry role -> the Protocol its messages satisfy (roles with one consumer of their own
#: device's message have none)
ROLE_PROTOCOLS: dict[str, type] = {
    "ins": Ins,
    "attitude": Attitude,
    "velocity": Velocity,
    "field": Field,
    "range": Range,
}


@functools.cache
def members(protocol: type) -> dict[str, tuple[object, str]]:
    """A role Protocol's members: name -> (type, unit), the unit ``""`` when it has none (a
    count, a flag, a tuple of m/s: see the docstring)."""
    out: dict[str, tuple[object, str]] = {}
    for klass in reversed(protocol.__mro__):
        for name, attr in vars(klass).items():
            if not isinstance(attr, property) or attr.fget is None:
                continue
            tp = get_type_hints(attr.fget, include_extras=True)["return"]
            if typing.get_origin(tp) is Annotated:
                out[name] = (tp.__origin__, str(tp.__metadata__[0]))
            else:
                out[name] = (tp, "")
    return out


def role_of(protocol: type) -> str:
    """The registry role whose Protocol ``protocol`` is (:data:`ROLE_PROTOCOLS`)."""
    return next(r for r, p in ROLE_PROTOCOLS.items() if p is protocol)
