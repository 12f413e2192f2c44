"""MS3A triaxial fluxgate magnetometer ASCII lines, defined by a table in ``config/ms3a.toml``.

No public protocol of the MS3A exists: the shipped table is the project's *assumed* line
``$MS3A,<counter>,<Bx>,<By>,<Bz>*HH\\r\\n`` (``docs/protocols/ms3a.md``). A site with the vendor
manual writes its own table and loads it with :meth:`Ms3aCodec.from_toml`.

Decoded :data:`Ms3aSample` messages carry the sample ``counter`` and the flux density ``bx``,
``by``, ``bz`` in **nT** along the sensor axes (``b_tesla`` gives the vector in T);
``raw_value(msg, "bx")`` is the integer on the wire (last printed digit = 1).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from auvgw.drivers.formats import Format
from auvgw.drivers.tablecodec import AsciiLineCodec, AsciiLineFramer, shipped_codec

__all__ = ["FORMAT", "REQUIRED_FIELDS", "Ms3aCodec", "Ms3aFramer", "default_codec"]

#: fields every MS3A table must declare: name -> decoded units ('' = integer count)
REQUIRED_FIELDS: dict[str, str] = {"counter": "", "bx": "nT", "by": "nT", "bz": "nT"}

_DOC = """MS3A magnetometer sample (one ASCII line).

bx, by, bz: magnetic flux density in nT along the sensor x, y, z axes; counter: sample count."""


def _b_nt(self: Any) -> np.ndarray:
    return np.array([self.bx, self.by, self.bz], dtype=np.float64)


def _b_tesla(self: Any) -> np.ndarray:
    return _b_nt(self) * 1e-9


_b_nt.__doc__ = "(bx, by, bz) in nT, sensor axes"
_b_tesla.__doc__ = "(bx, by, bz) in T, sensor axes"
_EXTRA = {"b_nt": property(_b_nt), "b_tesla": property(_b_tesla)}


class Ms3aCodec(AsciiLineCodec, device="ms3a"):
    """MS3A lines under one table (shipped: ``config/ms3a.toml``): :meth:`framer`,
    :meth:`decode`, :meth:`encode`; a site table loads with :meth:`from_toml`."""

    DOC = _DOC
    EXTRA = _EXTRA
    REQUIRED_FIELDS = REQUIRED_FIELDS


#: the shipped table's codec, read on first use; ``CODEC`` and ``Ms3aSample`` (its message class)
#: are served by the module ``__getattr__``
default_codec, __getattr__ = shipped_codec(Ms3aCodec.from_toml, Ms3aCodec.MESSAGE)


class Ms3aFramer(AsciiLineFramer, shipped=default_codec):
    """MS3A framer: start char .. terminator; checksum, field count and number forms verified."""


FORMAT = Format.of_codec(
    "ms3a",
    "an MS3A magnetometer ASCII capture (auvgw assumed layout, config/ms3a.toml)",
    default_codec,
)
