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

from pathlib import Path
from typing import Any

from auvgw.drivers.formats import Format
from auvgw.drivers.framing import ErrorPolicy
from auvgw.drivers.tablecodec import (
    AsciiLineCodec,
    AsciiLineFramer,
    AsciiLineSpec,
    build_message_class,
    load_toml,
    parse_ascii_table,
    shipped_codec,
)
from auvgw.paths import config_file

__all__ = ["FORMAT", "REQUIRED_FIELDS", "AcousticCodec", "AcousticFramer", "default_codec"]

#: fields every acoustic table must declare: name -> decoded units ('' = integer count)
REQUIRED_FIELDS: dict[str, str] = {
    "counter": "", "range": "m", "bearing": "rad", "depression": "rad", "beacon": "",
}  # fmt: skip

_DOC = """Acoustic beacon reply (one ASCII line).

range: slant range in m; bearing: from the bow, clockwise, rad; depression: below the
horizontal, rad; beacon: transponder id; counter: reply count."""


class AcousticCodec(AsciiLineCodec):
    """Acoustic reply lines under one table: :meth:`framer`, :meth:`decode`, :meth:`encode`."""

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> AcousticCodec:
        """Load a table (default: the shipped ``config/acoustic.toml``); errors name the file
        and the entry."""
        path = Path(path) if path is not None else config_file("acoustic.toml")
        return cls.from_spec(parse_ascii_table(load_toml(path), str(path), REQUIRED_FIELDS))

    @classmethod
    def from_spec(cls, spec: AsciiLineSpec) -> AcousticCodec:
        msg_type = build_message_class(
            "AcousticReply", spec.fields, doc=f"{_DOC}\n\nTable: {spec.source}",
            module=__name__, source=spec.source,
        )  # fmt: skip
        return cls(spec, msg_type, name="acoustic")

    def framer(
        self, policy: ErrorPolicy | str = ErrorPolicy.LOG, source: str = "", **_ignored: Any
    ) -> AcousticFramer:
        """A fresh framer for this codec's table."""
        return AcousticFramer(self, policy=policy, source=source)


#: the shipped table's codec, read on first use; ``CODEC`` and ``AcousticReply`` (its message class)
#: are served by the module ``__getattr__``
default_codec, __getattr__ = shipped_codec(AcousticCodec.from_toml, "AcousticReply")


class AcousticFramer(AsciiLineFramer):
    """Acoustic framer: start char .. terminator; checksum, field count and number forms
    verified."""

    def __init__(
        self,
        codec: AcousticCodec | None = None,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
    ) -> None:
        spec = (codec or default_codec()).spec
        super().__init__(spec, policy=policy, source=source, name="acoustic")


FORMAT = Format.of_codec(
    "acoustic",
    "an acoustic beacon (transponder/USBL) ASCII capture (auvgw assumed layout, "
    "config/acoustic.toml)",
    default_codec,
)
