"""Input samples of the navigation fusion, in SI units on one common clock.

These are the fusion's own small immutable types (named tuples: cheap to build at 100 Hz and
in bulk); adapters turn decoded device messages (HN-100,
PD0/PD6, pressure) into them. All times ``t`` are seconds on the gateway's common clock (the same
time base for every sensor; fusion aligns by these times, never by arrival order).

Frames (see ``config/scenario.py``): local NED (x north, y east, z down, metres); body axes
x forward, y starboard, z down; heading in radians from north towards east; attitude is the
ZYX Euler triple (heading, pitch, roll) rotating body axes into NED.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

__all__ = [
    "AttitudeSample",
    "DepthSample",
    "DvlFrame",
    "DvlSample",
    "InsSample",
    "PositionFix",
    "Vec3",
]

Vec3 = tuple[float, float, float]

#: axes of a DVL velocity: "beam" = closing speeds along the 3 or 4 Janus beams (converted with
#: the configured beam geometry, ``DvlMount.beam_angle_deg``); "instrument" = the DVL's own
#: x/y/z (rotated into body axes by the configured mounting rotation); "body" = already in
#: vehicle body axes (RDI "ship" coordinates with the mounting rotation applied by the
#: instrument); "earth" = north, east, down (the filter turns it into body axes with its own
#: attitude at the fix's time).
DvlFrame = Literal["beam", "instrument", "body", "earth"]


class InsSample(NamedTuple):
    """One attitude/heading sample: an INS output (HN-100 at ~100 Hz), an AHRS, or a DVL's own
    compass and tilt sensors (PD0 variable leader, PD6 ``:SA``). Also named
    :data:`AttitudeSample`; ``rates`` are zero when the source has no gyros.

    ``roll``, ``pitch``, ``heading``: rad, ZYX Euler angles body -> NED (heading from north
    towards east, pitch positive nose up, roll positive starboard down).
    ``rates``: body angular rate (p, q, r), rad/s, body axes.
    ``accel``: specific force (what an accelerometer reads, gravity reaction included: about
    (0, 0, -9.81) when level at rest), m/s^2, body axes; ``None`` when not available.
    """

    t: float
    roll: float
    pitch: float
    heading: float
    rates: Vec3 = (0.0, 0.0, 0.0)
    accel: Vec3 | None = None

    def is_finite(self) -> bool:
        """True when time, attitude and rates are all finite (a usable sample)."""
        r = self.rates
        # a sum of finite values is finite, any NaN or inf makes it non-finite
        return math.isfinite(self.t + self.roll + self.pitch + self.heading + r[0] + r[1] + r[2])


class DvlSample(NamedTuple):
    """One DVL bottom-track output (Pathfinder at a few Hz, a low-cost DVL at ~1.5 Hz).

    ``velocity``: velocity of the instrument over the seabed (the vehicle's motion sign, not the
    bottom's), m/s, in ``frame`` axes (3 components; 3 or 4 beam closing speeds, + towards the
    transducer, in ``"beam"``); a NaN component is missing (e.g. a bad beam: per-axis validity)
    and is left out of the update. ``fom``: the DVL's figure of merit, 1-sigma per component,
    m/s (NaN: none; then the spec noise). ``bottom_lock``: False when the DVL has no bottom
    track (the velocity is then ignored). ``altitude``: m above the seabed (NaN unknown).
    ``depth``: m below the surface from the DVL's pressure sensor (NaN when absent), at the
    DVL's lever arm.
    """

    t: float
    velocity: tuple[float, ...]
    bottom_lock: bool = True
    frame: DvlFrame = "instrument"
    altitude: float = math.nan
    depth: float = math.nan
    fom: float = math.nan


class DepthSample(NamedTuple):
    """Depth of a pressure sensor, m below the surface (positive down), at ``t`` s.

    ``sigma``: 1-sigma, m; NaN uses the configured ``depth_sigma_m``.
    """

    t: float
    depth: float
    sigma: float = math.nan


class PositionFix(NamedTuple):
    """A horizontal position fix of the vehicle reference point: local NED ``north``, ``east``
    (m) with 1-sigma ``sigma_m`` (m, per axis) at ``t`` s. ``source`` names the kind ("gnss" at
    the surface, "usbl", "beacon", ...) for the counters; convert latitude/longitude to the
    local frame before (flat earth around the origin)."""

    t: float
    north: float
    east: float
    sigma_m: float = 2.0
    source: str = "gnss"


#: the attitude/heading sample type (same as :class:`InsSample`)
AttitudeSample = InsSample
