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

__all__ = ["DepthSample", "DvlFrame", "DvlSample", "InsSample", "Vec3"]

Vec3 = tuple[float, float, float]

#: axes of a DVL velocity: "instrument" = the DVL's own x/y/z (rotated into body axes by the
#: configured mounting rotation); "body" = already in vehicle body axes (RDI "ship" coordinates
#: with the mounting rotation applied by the instrument). Beam coordinates are the adapter's job.
DvlFrame = Literal["instrument", "body"]


class InsSample(NamedTuple):
    """One INS output (HN-100 at ~100 Hz).

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
    """One DVL bottom-track output (Pathfinder at a few Hz).

    ``velocity``: velocity of the instrument over the seabed (the vehicle's motion sign, not the
    bottom's), m/s, in ``frame`` axes; a NaN component is missing (e.g. a bad beam) and is left
    out of the update. ``bottom_lock``: False when the DVL has no bottom track (the velocity is
    then ignored). ``altitude``: m above the seabed (NaN unknown). ``depth``: m below the surface
    from the DVL's pressure sensor (NaN when absent), at the DVL's lever arm.
    """

    t: float
    velocity: Vec3
    bottom_lock: bool = True
    frame: DvlFrame = "instrument"
    altitude: float = math.nan
    depth: float = math.nan


class DepthSample(NamedTuple):
    """Depth of a pressure sensor, m below the surface (positive down), at ``t`` s.

    ``sigma``: 1-sigma, m; NaN uses the configured ``depth_sigma_m``.
    """

    t: float
    depth: float
    sigma: float = math.nan
