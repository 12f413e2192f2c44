"""The message class of a table: one ``wire(...)`` field per row (``@message``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from auvgw.drivers.spec import (
    message,
)
from auvgw.drivers.tablecodec.flags import FlagsSpec
from auvgw.drivers.tablecodec.reading import TableError
from auvgw.drivers.tablecodec.rows import FieldSpec


def build_message_class(
    name: str,
    fields: Sequence[FieldSpec],
    *,
    byte_order: str = "<",
    doc: str = "",
    flags: FlagsSpec | None = None,
    module: str = "auvgw.drivers.tablecodec",
    namespace: Mapping[str, Any] | None = None,
    source: str = "",
) -> type:
    """A frozen ``@message`` dataclass with one ``wire(...)`` field per table row.

    Flags (if any) follow as ``bool`` fields derived from the status bits; passing a flag that
    disagrees with the status word raises ValueError.
    """
    extra = dict(namespace or {})
    names = [f.name for f in fields] + [flag for flag, _ in (flags.bits if flags else ())]
    clash = sorted(set(names) & set(extra))
    if clash:
        where = f"{source}: " if source else ""
        raise TableError(
            f"{where}field name(s) {', '.join(clash)} are reserved by {name} "
            f"(reserved: {', '.join(sorted(extra))})"
        )
    annotations: dict[str, Any] = {}
    ns: dict[str, Any] = {"__module__": module, "__qualname__": name}
    for f in fields:
        annotations[f.name] = f.python_type()
        ns[f.name] = f.wire()
    lines = [doc.strip(), "", "Fields [decoded units]:"]
    lines += [f"    {f.name} [{f.units or '1'}]: {f.description}" for f in fields]
    if flags is not None:
        bits = flags.bits
        status = flags.field
        for flag, bit in bits:
            annotations[flag] = bool
            ns[flag] = dataclasses.field(default=None, metadata={"flag_bit": bit})
            lines.append(f"    {flag} [bool]: bit {bit} of {status} (derived)")

        def __post_init__(self: Any) -> None:
            word = int(getattr(self, status))
            for flag, bit in bits:
                actual = bool((word >> bit) & 1)
                given = getattr(self, flag)
                if given is None:
                    object.__setattr__(self, flag, actual)
                elif bool(given) != actual:
                    raise ValueError(
                        f"{name}.{flag}={given!r} disagrees with bit {bit} of {status}=0x{word:x}"
                    )

        ns["__post_init__"] = __post_init__
    ns["__annotations__"] = annotations
    ns["__doc__"] = "\n".join(lines)
    ns.update(extra)
    cls = type(name, (), ns)
    return message(endian=byte_order)(cls)
