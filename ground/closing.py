"""One home for the ``with`` protocol of everything released by ``close()``."""

from __future__ import annotations

from typing import Self

__all__ = ["Closing"]


class Closing:
    """Mixin: ``with obj:`` gives ``obj`` and calls ``obj.close()`` on the way out, also on an
    exception (which propagates). A subclass defines ``close``; one that acquires on entry
    overrides ``__enter__``."""

    def close(self) -> object:
        """Release what the object holds."""
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
