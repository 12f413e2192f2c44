"""TOML table reading: the file, its sections, typed lookups and unknown-key checks."""

from __future__ import annotations

import re
import struct
import tomllib
from pathlib import Path
from typing import Any

from auvgw.drivers.spec import (
    WIRE_TYPES,
)
from auvgw.ground.errors import ConfigError


class TableError(ConfigError):
    """A frame table that cannot be used; the message names the file, the entry and the fix."""


_MISSING: Any = object()
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_INT_TYPES = {t: struct.calcsize(c) for t, c in WIRE_TYPES.items() if not t.startswith("f")}


def _int_limits(wire_type: str) -> tuple[int, int]:
    bits = 8 * _INT_TYPES[wire_type]
    if wire_type.startswith("u"):
        return 0, 2**bits - 1
    return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1


def load_toml(path: str | Path) -> dict[str, Any]:
    """The parsed TOML document at ``path`` (:class:`TableError` naming the file on failure)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise TableError(f"{path}: cannot read table: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TableError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TableError(f"{path}: not valid TOML: {exc}") from None


class _Section:
    """One TOML table under validation: typed lookups, then a check for unknown keys."""

    def __init__(self, source: str, where: str, data: Any) -> None:
        if not isinstance(data, dict):
            raise TableError(f"{source}: {where}: expected a table, got {data!r}")
        self.source = source
        self.where = where
        self.data = data
        self.known: list[str] = []

    def error(self, problem: str) -> TableError:
        return TableError(f"{self.source}: {self.where}: {problem}")

    def get(self, key: str, kinds: tuple[type, ...], expected: str, default: Any = _MISSING) -> Any:
        self.known.append(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(f"missing {key!r}; expected {expected}")
            return default
        value = self.data[key]
        if (isinstance(value, bool) and bool not in kinds) or not isinstance(value, kinds):
            raise self.error(f"{key} = {value!r}; expected {expected}")
        return value

    def section(self, key: str) -> _Section:
        """The required sub-table ``[key]``."""
        sub = self.optional_section(key)
        if sub is None:
            raise self.error(f"missing table [{key}]")
        return sub

    def optional_section(self, key: str) -> _Section | None:
        """The sub-table ``[key]``, or None when absent."""
        self.known.append(key)
        if key not in self.data:
            return None
        where = f"{self.where[:-1]}.{key}]" if self.where.startswith("[") else f"[{key}]"
        return _Section(self.source, where, self.data[key])

    def finish(self) -> None:
        extra = sorted(set(self.data) - set(self.known))
        if extra:
            raise self.error(
                f"unknown key(s) {', '.join(extra)}; expected only {', '.join(self.known)}"
            )
