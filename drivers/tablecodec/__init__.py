"""Frame tables loaded from TOML: a site replaces the file, not the code.

Two table kinds, both compiled into a project message class (``drivers/spec.py``: one
``wire(...)`` field per row, ``@message``) so that decode and encode walk exactly one table:

* :class:`BinaryFrameSpec` -- a fixed-size binary frame: sync bytes, optional length field,
  byte order, a checksum of a named kind over a declared byte range, and the fields (name, wire
  type, byte offset from the frame start, scale, units, description). Every byte of the frame
  must belong to the sync, the length field, a field or the checksum, so
  ``encode(decode(frame)) == frame`` holds for every valid frame.
* :class:`AsciiLineSpec` -- an ASCII line ``<start><header><sep><f1><sep>...<delim>HH<term>``
  whose numeric fields have a declared width, number of decimals and sign rule, so the text
  form of each value is unique and ``encode(decode(line)) == line``.

Table units are those of ``raw * scale`` as the vendor manual states them (``deg``, ``mg``,
``0.1 ms`` = ``scale = 0.1, units = "ms"``); decoded messages carry SI (see :data:`UNITS`).
Every error in a table is a :class:`TableError` naming the file, the entry and what is expected.

The package is cut along the module's sections: ``units``, ``checksums``, ``reading`` (TOML
files and sections), ``rows`` (field rows), ``flags`` (status bits), ``messages`` (the message
class of a table), ``codec`` (the codec and framer bases every table kind shares), ``binary``
and ``ascii`` (the two table kinds); every public name is importable from here.
"""

from __future__ import annotations

from auvgw.drivers.tablecodec.ascii import (
    AsciiLineCodec,
    AsciiLineFramer,
    AsciiLineSpec,
    LineError,
    parse_ascii_table,
    parse_line,
)
from auvgw.drivers.tablecodec.binary import (
    BinaryFrameCodec,
    BinaryFrameFramer,
    BinaryFrameSpec,
    parse_binary_table,
)
from auvgw.drivers.tablecodec.checksums import CHECKSUMS, ChecksumKind
from auvgw.drivers.tablecodec.codec import TableCodec, TableFramer, shipped_codec
from auvgw.drivers.tablecodec.flags import FlagsSpec
from auvgw.drivers.tablecodec.messages import build_message_class
from auvgw.drivers.tablecodec.reading import TableError, load_toml
from auvgw.drivers.tablecodec.rows import AsciiFieldSpec, FieldSpec
from auvgw.drivers.tablecodec.units import UNITS, si_units

__all__ = [
    "CHECKSUMS",
    "UNITS",
    "AsciiFieldSpec",
    "AsciiLineCodec",
    "AsciiLineFramer",
    "AsciiLineSpec",
    "BinaryFrameCodec",
    "BinaryFrameFramer",
    "BinaryFrameSpec",
    "ChecksumKind",
    "FieldSpec",
    "FlagsSpec",
    "LineError",
    "TableCodec",
    "TableError",
    "TableFramer",
    "build_message_class",
    "load_toml",
    "parse_ascii_table",
    "parse_binary_table",
    "parse_line",
    "shipped_codec",
    "si_units",
]
