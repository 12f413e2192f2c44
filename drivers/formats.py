"""Registry of wire formats: name -> framer factory and frame decoder (used by ``auvgw decode``,
the gateway and the replay tools).

Each codec module defines a module-level :class:`Format` (or several); the registry imports the
module only when the format is asked for.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from auvgw.drivers.framing import ErrorPolicy, Frame, Framer, read_file_frames

__all__ = ["FORMATS", "Format", "get_format"]


@dataclass(frozen=True)
class Format:
    """A wire format.

    ``framer(policy=..., source=...)`` makes a fresh framer; ``decode(frame_bytes)`` turns one
    verified frame into messages (raising :class:`~auvgw.drivers.framing.DecodeError` naming the
    field and offset when the content is inconsistent); ``encode(message)`` gives the bytes back.
    ``read_file`` overrides the default chunked framing of a file (container formats such as
    ``.V4LOG`` whose records wrap the frames); it returns the frames and the framer that counted.
    """

    name: str
    summary: str
    framer: Callable[..., Framer]
    decode: Callable[[bytes], Sequence[Any]]
    encode: Callable[[Any], bytes] | None = None
    read_file: Callable[..., tuple[Iterator[Frame], Framer]] | None = None

    def frames_of_file(
        self, path: str | Path, policy: ErrorPolicy | str = ErrorPolicy.IGNORE
    ) -> tuple[Iterator[Frame], Framer]:
        """The frames of a capture file and the framer whose stats count them."""
        if self.read_file is not None:
            return self.read_file(path, policy=policy)
        framer = self.framer(policy=policy, source=str(path))
        return read_file_frames(framer, path), framer


#: format name -> "module:attribute"
FORMATS: dict[str, str] = {
    "pd0": "auvgw.drivers.pd0:FORMAT",
    "pd6": "auvgw.drivers.pd6:FORMAT",
    "seanet": "auvgw.drivers.seanet:FORMAT",
    "v4log": "auvgw.drivers.v4log:FORMAT",
    "kongsberg": "auvgw.drivers.kongsberg:FORMAT",
    "hn100": "auvgw.drivers.hn100:FORMAT",
    "ms3a": "auvgw.drivers.ms3a:FORMAT",
    "acoustic": "auvgw.drivers.acoustic:FORMAT",
}


def get_format(name: str) -> Format:
    """The :class:`Format` called ``name`` (one of :data:`FORMATS`)."""
    try:
        target = FORMATS[name]
    except KeyError:
        raise KeyError(f"unknown format {name!r}; known: {', '.join(FORMATS)}") from None
    module, attr = target.split(":")
    return getattr(importlib.import_module(module), attr)


def format_from_table(name: str, table: str | Path) -> Format:
    """The ``hn100`` or ``ms3a`` format under a site's own table file (no code change needed)."""
    if name == "hn100":
        from auvgw.drivers.hn100 import Hn100Codec

        codec: Any = Hn100Codec.from_toml(table)
    elif name == "ms3a":
        from auvgw.drivers.ms3a import Ms3aCodec

        codec = Ms3aCodec.from_toml(table)
    else:
        raise KeyError(f"format {name!r} has no replaceable table (only hn100, ms3a)")
    base = get_format(name)
    return Format(
        name=name,
        summary=f"{base.summary} [table {table}]",
        framer=codec.framer,
        decode=lambda frame: [codec.decode(frame)],
        encode=codec.encode,
    )
