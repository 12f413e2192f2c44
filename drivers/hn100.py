"""HN-100 INS binary navigation frame, defined entirely by a table in ``config/hn100.toml``.

No public protocol of the HN-100 exists: the shipped table is the project's *assumed* layout
(``docs/protocols/hn100.md``). A site with the vendor manual writes its own table and loads it
with :meth:`Hn100Codec.from_toml`; the message class, framer, decoder and encoder all follow it.

Decoded :data:`Hn100Nav` messages carry SI: time s (device clock), roll/pitch/heading rad,
angular rates rad/s and specific force m/s^2 in the body frame (x forward, y starboard, z down),
velocity m/s in local NED, latitude/longitude rad (WGS-84), depth m (positive down), the raw
status word and its flags ``aligned``, ``gnss_aided``, ``dvl_aided``, ``error``.
``raw_value(msg, name)`` gives any field's wire value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.tablecodec import BinaryFrameCodec, BinaryFrameFramer, shipped_codec

__all__ = [
    "FORMAT",
    "REQUIRED_FIELDS",
    "REQUIRED_FLAGS",
    "Hn100Codec",
    "Hn100Framer",
    "default_codec",
]

#: fields every HN-100 table must declare: name -> decoded units ('' = integer count)
REQUIRED_FIELDS: dict[str, str] = {
    "time": "s",
    "roll": "rad",
    "pitch": "rad",
    "heading": "rad",
    "rate_x": "rad/s",
    "rate_y": "rad/s",
    "rate_z": "rad/s",
    "accel_x": "m/s^2",
    "accel_y": "m/s^2",
    "accel_z": "m/s^2",
    "vel_n": "m/s",
    "vel_e": "m/s",
    "vel_d": "m/s",
    "latitude": "rad",
    "longitude": "rad",
    "depth": "m",
}
#: status bits every HN-100 table must name (in its [status] table, on any integer field)
REQUIRED_FLAGS: tuple[str, ...] = ("aligned", "gnss_aided", "dvl_aided", "error")

_DOC = """HN-100 navigation solution (one binary frame), SI units.

Body frame x forward, y starboard, z down; velocity in local NED; angles in rad; flags derived
from the status word (passing a flag that disagrees with it raises ValueError)."""


def _vec(*names: str) -> property:
    def get(self: Any) -> np.ndarray:
        return np.array([getattr(self, n) for n in names], dtype=np.float64)

    get.__doc__ = f"({', '.join(names)}) as a float64 array"
    return property(get)


_EXTRA = {
    "rates": _vec("rate_x", "rate_y", "rate_z"),
    "accel": _vec("accel_x", "accel_y", "accel_z"),
    "vel_ned": _vec("vel_n", "vel_e", "vel_d"),
}


class Hn100Codec(BinaryFrameCodec, device="hn100"):
    """HN-100 frames under one table (shipped: ``config/hn100.toml``): :meth:`framer`,
    :meth:`decode`, :meth:`encode`; a site table loads with :meth:`from_toml`."""

    DOC = _DOC
    EXTRA = _EXTRA
    REQUIRED_FIELDS = REQUIRED_FIELDS
    REQUIRED_FLAGS = REQUIRED_FLAGS


#: the shipped table's codec, read on first use; ``CODEC`` and ``Hn100Nav`` (its message class)
#: are served by the module ``__getattr__``
default_codec, __getattr__ = shipped_codec(Hn100Codec.from_toml, Hn100Codec.MESSAGE)


class Hn100Framer(BinaryFrameFramer, shipped=default_codec):
    """HN-100 framer: sync, size, length and checksum from the table or codec given (default:
    the shipped codec)."""


FORMAT = Format.of_codec(
    "hn100",
    "an HN-100 INS binary capture (auvgw assumed layout, config/hn100.toml)",
    default_codec,
    skips_checksum=True,
    layout=True,
)
