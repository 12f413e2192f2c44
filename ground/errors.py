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
from collections.abc import Callable, Collection, Mapping
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
    exc: ValidationError,
    where: str = "",
    rename: Callable[[str], str] | None = None,
    *,
    prefix: str = "",
    tags: Collection[str] = (),
    tagged: Collection[str] = (),
    explain: Callable[[tuple[str, ...], Mapping[str, Any]], str | None] | None = None,
) -> str:
    """One line per problem: ``where: field.path: what is wrong (got value)``, the one formatter
    of every settings, configuration and scenario model.

    ``where`` names the file (empty: no prefix); ``prefix`` goes before every field path
    (``transport`` -> ``transport.port``); ``rename`` maps a field path to what the user wrote
    (a command-line option, e.g. ``sound_speed_mps`` -> ``--sound-speed``). A union
    discriminated by ``kind``: pydantic puts the member's tag (one of ``tags``) in the path after
    the union's field (one of ``tagged``, or first for a bare union): it is dropped, and a
    missing or unknown tag reads as the ``kind`` field. ``explain(path, error)`` may give the
    message for an error instead (e.g. the keys a table takes, after an unknown one).
    """
    choices = ", ".join(repr(k) for k in tags)
    lines = []
    for err in exc.errors():
        parts = [str(p) for p in err["loc"]]
        loc = tuple(p for i, p in enumerate(parts)
                    if not (p in tags and (i == 0 or parts[i - 1] in tagged)))  # fmt: skip
        typ = err["type"]
        msg = err["msg"].removeprefix("Value error, ")
        got = err.get("input")
        quiet = typ in ("missing", "extra_forbidden") or isinstance(got, Mapping)
        special = explain(tuple(parts), err) if explain is not None else None
        if special is not None:
            msg, quiet = special, True
        elif typ == "missing":
            msg = "missing (required)"
        elif typ == "extra_forbidden":
            msg = "unknown key"  # (the path names it)
        elif typ == "union_tag_not_found":
            loc, msg = (*loc, "kind"), f"missing; must be one of {choices}"
        elif typ == "union_tag_invalid":
            tag = err.get("ctx", {}).get("tag")
            loc, msg, quiet = (*loc, "kind"), f"must be one of {choices}, got {tag!r}", True
        field = ".".join(p for p in (prefix, ".".join(loc)) if p) or "(top level)"
        if rename is not None:
            field = rename(field)
        tail = "" if quiet or repr(got) in msg else f" (got {got!r:.60})"
        lines.append(f"{where}: {field}: {msg}{tail}" if where else f"{field}: {msg}{tail}")
    return "\n".join(lines)


M = TypeVar("M", bound="BaseModel")

#: the largest settings, configuration or scenario file read (bytes): far above any real one
#: (the shipped ones are under 10 kB), far below what could exhaust memory
MAX_DOCUMENT_BYTES = 1 << 20
#: the deepest nesting of arrays and tables/objects accepted: the parsers recurse per level
#: (a 20,000-deep array is a RecursionError); real files nest 4 or 5 deep
MAX_DOCUMENT_DEPTH = 32


def _nesting(text: str, kind: str) -> tuple[int, int]:
    """The deepest ``[``/``{`` nesting of a TOML or JSON text outside strings and comments,
    and the character offset where it is first reached (a scan, no parsing)."""
    depth = deepest = at = 0
    quote = ""  # the open string's delimiter: '"', "'", '"""' or "'''"
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if quote:
            if c == "\\" and quote[0] == '"':
                i += 2
                continue
            if text.startswith(quote, i):
                i += len(quote)
                quote = ""
                continue
        elif c in "\"'" and (c == '"' or kind == "TOML"):
            triple = c * 3
            quote = triple if kind == "TOML" and text.startswith(triple, i) else c
            i += len(quote)
            continue
        elif c == "#" and kind == "TOML":
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        elif c in "[{":
            depth += 1
            if depth > deepest:
                deepest, at = depth, i
        elif c in "]}":
            depth -= 1
        i += 1
    return deepest, at


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
        with path.open("rb") as f:
            raw = f.read(MAX_DOCUMENT_BYTES + 1)
        if len(raw) > MAX_DOCUMENT_BYTES:
            raise error(f"{path}: too large for a {what} (over {MAX_DOCUMENT_BYTES} bytes)")
        text = raw.decode("utf-8")
    except FileNotFoundError as exc:
        raise error(f"{path}: cannot read: no such {what}") from exc
    except IsADirectoryError as exc:
        raise error(f"{path}: cannot read: is a directory, not a {what}") from exc
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text (UTF-8) file ({exc.reason} at byte {exc.start})") from exc
    deepest, at = _nesting(text, kind)
    if deepest > MAX_DOCUMENT_DEPTH:
        raise error(
            f"{path}: arrays/tables nested too deep ({deepest} levels at character {at}; at most "
            f"{MAX_DOCUMENT_DEPTH})"
        )
    try:
        data = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except RecursionError:  # a nesting the scan missed (e.g. dotted keys): still one line
        raise error(f"{path}: nested too deep to read") from None
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{path}: not valid {kind}: {exc}") from exc
    if not isinstance(data, dict):
        raise error(f"{path}: the top level must be a table (an object)")
    where = _nul_at(data)
    if where is not None:  # no path, port or name holds one: open() and bind() raise on it
        raise error(f"{path}: {where or '(top level)'}: contains a NUL character")
    return data


def _nul_at(value: Any, where: str = "") -> str | None:
    """The key path of the first string (key or value) holding a NUL character, if any."""
    if isinstance(value, str):
        return where if "\0" in value else None
    items: Any = ()
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list):
        items = ((f"[{i}]", v) for i, v in enumerate(value))
    for k, v in items:
        sub = f"{where}{k}" if k.startswith("[") or not where else f"{where}.{k}"
        if "\0" in k:
            return sub
        found = _nul_at(v, sub)
        if found is not None:
            return found
    return None


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
