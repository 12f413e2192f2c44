"""One exception tree for auvgw, and one home for loading a settings file and formatting its
validation errors.

::

    AuvgwError
    |-- DataError (ValueError)        bad bytes, lines, files or recordings; names source, field,
    |   |                             byte offset where known (FrameError, DecodeError, WireError,
    |   |                             LineError, CanCodecError, AdapterError, LogError,
    |   |                             CalibrationError, RecordingError)
    |-- TransportError                a port, bus or socket that fails (TransportOpenError,
    |                                 Disconnected)
    |-- ConfigError (ValueError)      an unusable configuration, one line per problem naming the
    |                                 file and the field (TableError, TransportConfigError,
    |                                 ScenarioError, SettingsError)
    '-- UserError                     a problem the user can fix, printed by the CLI as one line
                                      (exit code 2)

``DataError`` and ``ConfigError`` stay ``ValueError`` s, so code that caught ``ValueError``
before still does. Catch :class:`AuvgwError` to catch anything auvgw raises on purpose.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:  # pydantic is imported when used: ``auvgw --help`` imports this module
    from pydantic import BaseModel, ValidationError

__all__ = [
    "AuvgwError",
    "ConfigError",
    "DataError",
    "TransportError",
    "UserError",
    "format_validation_error",
    "load_settings",
]


class AuvgwError(Exception):
    """The root of every exception auvgw raises on purpose."""


class DataError(AuvgwError, ValueError):
    """Input data that cannot be used: ``reason``, and where known ``source`` (file, port,
    device, codec), ``field`` (the field path, e.g. ``Hn100Nav.roll``) and ``offset`` (byte
    offset in the stream or frame). The message is ``source: field: reason`` (the reason says
    the bytes in words; ``offset`` is there for programs)."""

    def __init__(
        self,
        message: str,
        *,
        source: str | None = None,
        field: str | None = None,
        offset: int | None = None,
    ) -> None:
        super().__init__(": ".join(p for p in (source, field, message) if p))
        self.reason = message
        self.source = source
        self.field = field
        self.offset = offset


class TransportError(AuvgwError):
    """A transport failure; ``port`` names the device (path, URL, channel, address or file)."""

    def __init__(self, port: str, message: str) -> None:
        super().__init__(f"{port}: {message}")
        self.port = port


class ConfigError(AuvgwError, ValueError):
    """An unusable configuration; one line per problem, each naming the file and the field."""


class UserError(AuvgwError):
    """A problem the user can fix (bad file, bad option); printed as one line, exit code 2."""


def format_validation_error(
    exc: ValidationError, where: str = "", rename: Callable[[str], str] | None = None
) -> str:
    """One line per problem: ``where: field.path: what is wrong (got value)``.

    ``where`` names the file (empty: no prefix); ``rename`` maps a field path to what the user
    wrote (a command-line option, e.g. ``sound_speed_mps`` -> ``--sound-speed``).
    """
    lines = []
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if rename is not None:
            field = rename(field)
        typ = err["type"]
        msg = err["msg"].removeprefix("Value error, ")
        got = err.get("input")
        quiet = typ in ("missing", "extra_forbidden") or isinstance(got, Mapping)
        if typ == "missing":
            msg = "missing (required)"
        elif typ == "extra_forbidden":
            msg = "unknown key"
        tail = "" if quiet or repr(got) in msg else f" (got {got!r:.60})"
        lines.append(f"{where}: {field}: {msg}{tail}" if where else f"{field}: {msg}{tail}")
    return "\n".join(lines)


M = TypeVar("M", bound="BaseModel")


def read_document(
    path: str | Path,
    error: type[Exception] = ConfigError,
    what: str = "file",
    kind: str | None = None,
) -> dict[str, Any]:
    """The top-level table of a ``kind`` (``"TOML"`` or ``"JSON"``; None: JSON for ``.json``,
    else TOML) file. Every failure raises ``error`` naming the file (``what`` it should be, e.g.
    ``"configuration file"``): missing, a directory, not UTF-8 text, cannot read, not TOML/JSON
    (with the position), not a table."""
    path = Path(path)
    kind = kind or ("JSON" if path.suffix == ".json" else "TOML")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise error(f"{path}: cannot read: no such {what}") from exc
    except IsADirectoryError as exc:
        raise error(f"{path}: cannot read: is a directory, not a {what}") from exc
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text (UTF-8) file ({exc.reason} at byte {exc.start})") from exc
    try:
        data = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{path}: not valid {kind}: {exc}") from exc
    if not isinstance(data, dict):
        raise error(f"{path}: the top level must be a table (an object)")
    return data


def load_settings(
    path: str | Path,
    model: type[M],
    error: type[Exception] = ConfigError,
    table: str | None = None,
    context: Mapping[str, Any] | None = None,
) -> M:
    """Read a TOML (``.json``: JSON) settings file into ``model``. ``table``: the keys may sit
    under ``[table]`` (a section of a larger file) or at the top level. Every failure raises
    ``error`` naming the file: what :func:`read_document` refuses, and each invalid field on
    its own line (:func:`format_validation_error`)."""
    from pydantic import ValidationError

    data = read_document(path, error)
    if table is not None and isinstance(data.get(table), dict):
        data = data[table]
    try:
        return model.model_validate(data, context=dict(context) if context else None)
    except ValidationError as exc:
        raise error(format_validation_error(exc, str(path))) from None
