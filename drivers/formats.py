"""Wire formats: name -> framer factory and frame decoder (used by ``auvgw decode``, the gateway
and the replay tools).

Each codec module defines a module-level :class:`Format`; the names and where each lives come
from the device registry (:mod:`auvgw.drivers.registry`), which imports a codec module only when
its format is asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from auvgw.drivers import registry
from auvgw.drivers.framing import ErrorPolicy, Frame, Framer, read_file_frames
from auvgw.drivers.spec import WireLayout

__all__ = ["FORMATS", "Format", "format_from_table", "get_format"]


@dataclass(frozen=True)
class Format:
    """A wire format.

    ``framer(policy=..., source=...)`` makes a fresh framer; ``decode(frame_bytes)`` turns one
    verified frame into messages (raising :class:`~auvgw.drivers.framing.DecodeError` naming the
    field and offset when the content is inconsistent); ``encode(message)`` gives the bytes back.
    ``read_file`` overrides the default chunked framing of a file (container formats such as
    ``.V4LOG`` whose records wrap the frames); it returns the frames and the framer that counted.
    ``decode_verified(frame_bytes)`` (None: ``decode``) decodes a frame its own framer has just
    delivered, without checking its checksum a second time (:meth:`decode_frame`); ``decode``
    alone stays safe on any bytes. ``layout(frame_bytes)`` (None: no such path) tells where the
    fields of a frame its framer delivered sit (:class:`~auvgw.drivers.spec.WireLayout`, raising
    the error ``decode`` raises), so the gateway builds the envelope straight from the bytes.
    """

    name: str
    summary: str
    framer: Callable[..., Framer]
    decode: Callable[[bytes], Sequence[Any]]
    encode: Callable[[Any], bytes] | None = None
    read_file: Callable[..., tuple[Iterator[Frame], Framer]] | None = None
    decode_verified: Callable[[bytes], Sequence[Any]] | None = None
    layout: Callable[[bytes], WireLayout] | None = None

    def decode_frame(self, frame: bytes, verified: bool = False) -> Sequence[Any]:
        """``decode(frame)``; with ``verified`` (the frame came out of this format's framer,
        checksum checked there) through ``decode_verified`` where the format has one."""
        if verified and self.decode_verified is not None:
            return self.decode_verified(frame)
        return self.decode(frame)

    @classmethod
    def one_per_frame(
        cls,
        name: str,
        summary: str,
        framer: Callable[..., Framer],
        decode: Callable[..., Any],
        encode: Callable[[Any], bytes],
        skips_checksum: bool = False,
        layout: Callable[[bytes], WireLayout] | None = None,
    ) -> Format:
        """The format of a codec whose ``decode(frame)`` gives one message per frame;
        ``skips_checksum``: its ``decode(frame, verified=True)`` trusts the framer's checksum;
        ``layout``: as the attribute."""
        return cls(
            name, summary, framer, lambda frame: [decode(frame)], encode,
            decode_verified=(lambda frame: [decode(frame, verified=True)]) if skips_checksum
            else None, layout=layout,
        )  # fmt: skip

    @classmethod
    def of_codec(
        cls,
        name: str,
        summary: str,
        codec: Callable[[], Any],
        skips_checksum: bool = False,
        layout: bool = False,
    ) -> Format:
        """The format of a table-driven codec (one message per frame): framer, decode and
        encode from ``codec()``, called at each use (so the table is read on first use);
        ``skips_checksum`` as in :meth:`one_per_frame`; ``layout``: the codec has
        ``wire_layout(frame)``."""
        return cls(
            name=name,
            summary=summary,
            framer=lambda *a, **k: codec().framer(*a, **k),
            decode=lambda frame: [codec().decode(frame)],
            encode=lambda m: codec().encode(m),
            decode_verified=(lambda frame: [codec().decode(frame, verified=True)])
            if skips_checksum
            else None,
            layout=(lambda frame: codec().wire_layout(frame)) if layout else None,
        )

    def frames_of_file(
        self, path: str | Path, policy: ErrorPolicy | str = ErrorPolicy.IGNORE
    ) -> tuple[Iterator[Frame], Framer]:
        """The frames of a capture file and the framer whose stats count them."""
        if self.read_file is not None:
            return self.read_file(path, policy=policy)
        framer = self.framer(policy=policy, source=str(path))
        return read_file_frames(framer, path), framer


#: format name -> "module:attribute" of its :class:`Format` (from :mod:`auvgw.drivers.registry`)
#: (a device that only speaks CAN, such as the actuators, has no byte-stream format)
FORMATS: dict[str, str] = {d.format: d.codec for d in registry.DEVICES if d.codec is not None}


def get_format(name: str) -> Format:
    """The :class:`Format` called ``name`` (one of :data:`FORMATS`)."""
    codec = registry.device(name).codec
    if codec is None:
        raise KeyError(f"device {name!r} only speaks CAN (its DBC); no byte-stream format")
    fmt: Format = registry.load(codec)
    return fmt


def format_from_table(name: str, table: str | Path) -> Format:
    """Format ``name`` under a site's own table file (formats with a replaceable table only:
    the registry's ``table_codec``), so a site matches its firmware without a code change."""
    dev = registry.device(name)
    if dev.table_codec is None:
        known = ", ".join(d.format for d in registry.DEVICES if d.table_codec)
        raise KeyError(f"format {name!r} has no replaceable table (only {known})")
    codec = registry.load(dev.table_codec).from_toml(table)
    base = get_format(name)
    return Format.of_codec(
        name, f"{base.summary} [table {table}]", lambda: codec,
        skips_checksum=base.decode_verified is not None, layout=base.layout is not None,
    )  # fmt: skip
