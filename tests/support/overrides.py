"""Which subclasses redefine a base's methods (the bases whose public methods no subclass
overrides: ``Worker``, ``Stage``)."""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["overrides", "subclasses"]


def subclasses(cls: type) -> set[type]:
    """Every subclass of ``cls``, at any depth (those imported so far)."""
    out: set[type] = set()
    direct: list[type] = cls.__subclasses__()
    for sub in direct:
        out |= {sub, *subclasses(sub)}
    return out


def overrides(classes: Iterable[type], names: Iterable[str]) -> list[str]:
    """``module.Class.name`` of each of ``names`` a class in ``classes`` defines itself, sorted."""
    wanted = tuple(names)
    return sorted(f"{c.__module__}.{c.__qualname__}.{n}" for c in classes for n in wanted
                  if n in vars(c))  # fmt: skip
