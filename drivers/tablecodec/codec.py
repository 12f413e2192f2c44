"""What every table kind shares: the codec and framer bases, the shipped codec read on first use."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Generic, Protocol, Self, TypeVar

from auvgw.drivers import registry
from auvgw.drivers.framing import ErrorPolicy, Framer
from auvgw.drivers.spec import (
    LAZY_TYPES,
)
from auvgw.drivers.tablecodec.messages import build_message_class
from auvgw.drivers.tablecodec.reading import load_toml
from auvgw.drivers.tablecodec.rows import FieldSpec
from auvgw.ground.paths import config_file


class _Table(Protocol):
    @property
    def source(self) -> str: ...

    @property
    def fields(self) -> Sequence[FieldSpec]: ...


S = TypeVar("S", bound=_Table)
F = TypeVar("F", bound=Framer)


class TableCodec(Generic[S, F]):
    """What a table-driven codec shares: the table ``spec``, the message class built from it, a
    ``name`` (logs, errors) and :meth:`framer`.

    A device's codec subclasses :class:`BinaryFrameCodec` or :class:`AsciiLineCodec` with
    ``device=<format>``: its shipped table (:attr:`TABLE`) and the message class's name
    (:attr:`MESSAGE`, its registered stream message type) come from the device registry
    (:mod:`auvgw.drivers.registry`); it gives in class attributes the message class's docstring
    (:attr:`DOC`) and extra members (:attr:`EXTRA`), and the fields every table of the device
    must declare (:attr:`REQUIRED_FIELDS`); :meth:`from_toml` and :meth:`from_spec` build it
    from those. A device's framer class subclasses the table
    kind's framer with ``shipped=default_codec`` (the codec used when it is given none)."""

    #: the framer of this table kind: ``framer_type(spec, policy=, source=, name=)``
    framer_type: Callable[..., F]
    #: a device's shipped table under ``config/``; its stem names the codec
    TABLE: ClassVar[str] = ""
    #: the name of the message class built from a table
    MESSAGE: ClassVar[str] = ""
    #: the message class's docstring (the table's source is appended)
    DOC: ClassVar[str] = ""
    #: extra members of the message class (properties)
    EXTRA: ClassVar[Mapping[str, Any]] = {}
    #: fields every table of the device must declare: name -> decoded units ('' = a count)
    REQUIRED_FIELDS: ClassVar[Mapping[str, str]] = {}

    def __init_subclass__(cls, device: str | None = None, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if device is None:
            return
        d = registry.device(device)
        stream = [m.type for m in d.messages if m.wire == "stream"]
        if d.table is None or len(stream) != 1:
            raise TypeError(f"{cls.__name__}: format {device!r} registers no table and one type")
        cls.TABLE, cls.MESSAGE = d.table, stream[0]

    def __init__(self, spec: S, message_type: type, name: str = "frame") -> None:
        self.spec = spec
        self.message_type = message_type
        self.name = name

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> Self:
        """Load a table (default: the shipped ``config/<TABLE>``).

        Raises :class:`TableError` naming the file, the entry and what is expected (unknown
        type, overlapping fields, field beyond the frame, a required field missing, ...).
        """
        path = Path(path) if path is not None else config_file(cls.TABLE)
        return cls.from_spec(cls.parse_table(load_toml(path), str(path)))

    @classmethod
    def parse_table(cls, doc: Mapping[str, Any], source: str) -> S:
        """Validate a parsed TOML table of this kind read from ``source``."""
        raise NotImplementedError

    @classmethod
    def message_options(cls, spec: S) -> dict[str, Any]:
        """Keyword arguments of :func:`build_message_class` that the table kind adds."""
        return {}

    @classmethod
    def from_spec(cls, spec: S) -> Self:
        """The codec of a validated table, its message class (:attr:`MESSAGE`) built from it."""
        msg_type = build_message_class(
            cls.MESSAGE,
            spec.fields,
            doc=f"{cls.DOC}\n\nTable: {spec.source}",
            module=cls.__module__,
            namespace=cls.EXTRA,
            source=spec.source,
            **cls.message_options(spec),
        )
        return cls(spec, msg_type, name=Path(cls.TABLE).stem)

    def framer(
        self,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        **_ignored: Any,
    ) -> F:
        """A fresh framer for this table."""
        return self.framer_type(self.spec, policy=policy, source=source, name=self.name)


class TableFramer(Framer, Generic[S]):
    """A framer whose sync, size and checks come from a table: a spec, a codec's or (a device
    framer, declared ``class Hn100Framer(BinaryFrameFramer, shipped=default_codec)``) the
    shipped codec's when given none. ``name`` defaults to the codec's."""

    #: the codec whose table a device framer uses when given none
    shipped: ClassVar[Callable[[], TableCodec[Any, Any]] | None] = None
    spec: S

    def __init_subclass__(
        cls, shipped: Callable[[], TableCodec[Any, Any]] | None = None, **kw: Any
    ) -> None:
        super().__init_subclass__(**kw)
        cls.shipped = shipped or cls.shipped

    def __init__(
        self,
        table: S | TableCodec[S, Any] | None = None,
        policy: ErrorPolicy | str = ErrorPolicy.LOG,
        source: str = "",
        name: str | None = None,
    ) -> None:
        shipped = type(self).shipped
        if table is None:
            if shipped is None:
                raise TypeError(f"{type(self).__name__} needs a table")
            table = shipped()
        if isinstance(table, TableCodec):
            name = name or table.name
            table = table.spec
        self.spec = table
        self.name = name or self.name
        super().__init__(policy=policy, source=source, max_frame_size=self.use_table(table))

    def use_table(self, spec: S) -> int:
        """Take the sync and what the checks need from ``spec``; the largest frame (bytes)."""
        raise NotImplementedError


class _Codec(Protocol):
    message_type: type


C = TypeVar("C", bound=_Codec)


def shipped_codec(
    build: Callable[[], C], type_name: str
) -> tuple[Callable[[], C], Callable[[str], Any]]:
    """A table-driven driver's shipped codec, read on first use (importing the driver reads no
    file): ``default_codec()`` (built once) and the module ``__getattr__`` that serves ``CODEC``
    and ``type_name``, the shipped table's message class (a site table builds its own class of
    that name). ``type_name`` joins :data:`~auvgw.drivers.spec.LAZY_TYPES`, so a bus envelope
    naming it rebuilds the class."""
    codec = functools.cache(build)
    LAZY_TYPES[type_name] = lambda: codec().message_type

    def module_getattr(name: str) -> Any:
        if name == "CODEC":
            return codec()
        if name == type_name:
            return codec().message_type
        raise AttributeError(f"no attribute {name!r}")

    return codec, module_getattr
