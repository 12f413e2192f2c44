"""Acoustic beacon (transponder / USBL) reply lines, defined by a table in ``config/acoustic.toml``.

The sixth device: one acoustic beacon at a known position on the seabed (AMB-SLAM, Hou et al.
2019, Sec. 2.4.2). No public line format was adopted (``docs/protocols/acoustic.md``): the
shipped table is the project's *assumed* line
``$ACRB,<counter>,<range>,<bearing>,<depression>,<beacon>*HH\\r\\n``; a site with a real device's
manual writes its own table and loads it with :meth:`AcousticCodec.from_toml`.

Decoded :data:`AcousticReply` messages carry ``counter``, the slant ``range`` in **m**, the
``bearing`` from the bow (clockwise) and the ``depression`` below the horizontal in **rad**, and
the ``beacon`` id.
"""

from __future__ import annotations

from auvgw.drivers.formats import Format
from auvgw.drivers.tablecodec import AsciiLineCodec, AsciiLineFramer, shipped_codec

__all__ = ["FORMAT", "REQUIRED_FIELDS", "AcousticCodec", "AcousticFramer", "default_codec"]

#: fields every acoustic table must declare: name -> decoded units ('' = integer count)
REQUIRED_FIELDS: dict[str, str] = {
    "counter": "", "range": "m", "bearing": "rad", "depression": "rad", "beacon": "",
}  # fmt: skip

_DOC = """Acoustic beacon reply (one ASCII line).

range: slant range in m; bearing: from the bow, clockwise, rad; depression: below the
horizontal, rad; beacon: transponder id; counter: reply count."""


class AcousticCodec(AsciiLineCodec, device="acoustic"):
    """Acoustic reply lines under one table (shipped: ``config/acoustic.toml``): :meth:`framer`,
    :meth:`decode`, :meth:`encode`; a site table loads with :meth:`from_toml`."""

    DOC = _DOC
    REQUIRED_FIELDS = REQUIRED_FIELDS


#: the shipped table's codec, read on first use; ``CODEC`` and ``AcousticReply`` (its message class)
#: are served by the module ``__getattr__``
default_codec, __getattr__ = shipped_codec(AcousticCodec.from_toml, AcousticCodec.MESSAGE)


class AcousticFramer(AsciiLineFramer, shipped=default_codec):
    """Acoustic framer: start char .. terminator; checksum, field count and number forms
    verified."""


FORMAT = Format.of_codec(
    "acoustic",
    "an acoustic beacon (transponder/USBL) ASCII capture (auvgw assumed layout, "
    "config/acoustic.toml)",
    default_codec,
)
