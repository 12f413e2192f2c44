"""No bus stage overrides the base's ``start`` or ``stop`` (issue 29): each declares what differs
through the hooks (:meth:`Stage.on_start`, :meth:`Stage.on_stop`, :meth:`Stage.keep`), which
the base calls at defined points."""

from __future__ import annotations

import gc
import importlib
import pkgutil
from typing import Any, ClassVar

import pytest

from auvgw.slam import pipelines
from auvgw.stages.base import BusCounters, Stage, StageConfig
from auvgw.testing.overrides import overrides, subclasses

#: the base's lifecycle methods a subclass never redefines
LIFECYCLE = ("start", "stop")


def _overrides(classes: set[type]) -> set[str]:
    return set(overrides(classes, LIFECYCLE))


def _import_stages() -> None:
    """Every module that defines a stage: the stages and viz packages, every pipeline's stage."""
    for pkg in ("auvgw.stages", "auvgw.viz"):
        mod = importlib.import_module(pkg)
        for info in pkgutil.iter_modules(mod.__path__, f"{pkg}."):
            importlib.import_module(info.name)
    for p in pipelines.PIPELINES:
        pipelines.load(p.stage)


def test_no_stage_overrides_start_or_stop() -> None:
    _import_stages()
    subs = subclasses(Stage)
    names = {c.__qualname__ for c in subs}
    assert {"FusionStage", "PilotStage", "Ros2Bridge", "FoxgloveStage", "VizStage",
            "MagneticStage", "BathymetricStage", "SlamStage", "SwathStage"} <= names  # fmt: skip
    assert _overrides(subs) == set(), "override the hooks (on_start, on_stop, keep) instead"


def test_the_check_finds_a_planted_override() -> None:
    class Bad(Stage):
        def stop(self, flush: bool = True, timeout_s: float = 5.0) -> None:
            super().stop(flush, timeout_s)

    assert _overrides({Bad}) == {f"{__name__}.{Bad.__qualname__}.stop"}
    assert Bad in subclasses(Stage)
    del Bad
    gc.collect()  # out of Stage.__subclasses__() again


class _Undeclared:
    def __init__(self, log: list[str], name: str) -> None:
        self.log, self.name = log, name

    def undeclare(self) -> None:
        self.log.append(f"undeclare {self.name}")


class _Hooked(Stage):
    name: ClassVar[str] = "hooked"
    status_schema: ClassVar[str | None] = "HookedStatus"

    def __init__(self, session: Any, log: list[str]) -> None:
        super().__init__(StageConfig(), BusCounters(), session)
        self.log = log

    def input_keys(self) -> list[str]:
        return [self.keys.all("hooked/in")]

    def on_start(self, subscribe: bool) -> None:
        # the worker runs, the subscriptions and the liveliness token are still to come
        self.log.append(f"on_start worker={self.worker_alive} decls={len(self._decls)}")
        self.keep(_Undeclared(self.log, "first"))
        self.keep(_Undeclared(self.log, "second"))

    def on_stop(self) -> None:
        self.log.append(f"on_stop worker={self.worker_alive}")

    def flush(self) -> None:
        self.log.append("flush")


@pytest.mark.e2e
def test_the_hooks_are_called_at_their_points() -> None:
    """``on_start`` once the worker runs and before the subscriptions and token; ``on_stop``
    first at stop, while the worker still runs; what ``keep`` holds is withdrawn after the
    flush, the last kept first; a second start or stop calls no hook again."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    log: list[str] = []
    with zenoh.open(conf) as s:
        stage = _Hooked(s, log)
        stage.start()
        stage.start()
        # the status queryable before on_start; the subscription and liveliness token after
        assert log == ["on_start worker=True decls=1"]
        assert len(stage._decls) == 5
        stage.stop()
        stage.stop()
    assert log == ["on_start worker=True decls=1", "on_stop worker=True", "flush",
                   "undeclare second", "undeclare first"]  # fmt: skip
