"""No bus stage overrides a public method of the base (issue 29) other than the hooks the base
marks as the subclass's (:func:`auvgw.stages.base.hook`: ``feed``, ``key``, ``on_start``,
``read_payload``, ``on_status``...): each declares what differs through them, and the base calls
them at defined points."""

from __future__ import annotations

import gc
import importlib
import inspect
import pkgutil
import threading
from typing import Any, ClassVar

import pytest

from auvgw.slam import pipelines
from auvgw.stages.base import BusCounters, Stage, StageConfig
from auvgw.testing import wait_until
from auvgw.testing.overrides import overrides, subclasses


def _is_hook(value: object) -> bool:
    return getattr(getattr(value, "fget", value), "__stage_hook__", False) is True


#: every public method and property of the base (its own and the Worker's) that is not a hook
PUBLIC = sorted({n for klass in Stage.__mro__ if klass is not object for n, v in vars(klass).items()
                 if not n.startswith("_") and (callable(v) or isinstance(v, property))
                 and not _is_hook(v)})  # fmt: skip
#: the hooks the base marks
HOOKS = sorted(n for n, v in vars(Stage).items() if _is_hook(v))


def _overrides(classes: set[type]) -> set[str]:
    return set(overrides(classes, PUBLIC))


def _import_stages() -> None:
    """Every module that defines a stage: the stages and viz packages, every pipeline's stage."""
    for pkg in ("auvgw.stages", "auvgw.viz"):
        mod = importlib.import_module(pkg)
        for info in pkgutil.iter_modules(mod.__path__, f"{pkg}."):
            importlib.import_module(info.name)
    for p in pipelines.PIPELINES:
        pipelines.load(p.stage)


def test_no_stage_overrides_a_public_method_of_the_base() -> None:
    # the base's own plumbing and the Worker's, whatever is added later
    assert {"start", "stop", "post", "post_odometry", "handle_sample", "publish", "publish_json",
            "publish_message", "publish_status", "counters", "from_source", "keep", "subscribe",
            "submit", "start_worker", "stop_worker", "worker_stats"} <= set(PUBLIC)  # fmt: skip
    assert {"key", "input_keys", "wanted", "feed", "feed_batch", "feed_odometry", "dispatch",
            "status_fields", "flush", "on_start", "on_stop", "accepts", "read_payload",
            "on_status", "component"} == set(HOOKS)  # fmt: skip
    _import_stages()
    subs = subclasses(Stage)
    names = {c.__qualname__ for c in subs}
    assert {"FusionStage", "PilotStage", "Ros2Bridge", "FoxgloveStage", "VizStage",
            "MagneticStage", "BathymetricStage", "SlamStage", "SwathStage"} <= names  # fmt: skip
    assert _overrides(subs) == set(), f"override the hooks ({', '.join(HOOKS)}) instead"


@pytest.mark.parametrize("name", PUBLIC)
def test_the_check_finds_a_planted_override(name: str) -> None:
    """An override of any public method of the base, planted in a subclass, is found."""
    original = inspect.getattr_static(Stage, name)
    bad = type("Bad", (Stage,), {name: original})
    assert _overrides({bad}) == {f"{__name__}.Bad.{name}"}
    assert bad in subclasses(Stage)
    del bad
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


class _Held(Stage):
    """In-process, no session: the first message fed waits on ``gate``."""

    name: ClassVar[str] = "held"

    def __init__(self) -> None:
        super().__init__(StageConfig(), BusCounters())
        self.gate = threading.Event()
        self.fed: list[int] = []
        self.flushed = False

    def feed(self, device: str, t_recv_ns: int, message: object) -> None:
        self.gate.wait(30)
        self.fed.append(t_recv_ns)

    def flush(self) -> None:
        self.flushed = True


def test_a_stop_past_its_drain_limit_drops_the_backlog_counts_it_and_flushes() -> None:
    """A stage far behind (a loaded host) asked to stop with ``drain_limit_s`` stops at the
    limit: the message in hand finishes, the backlog is counted in ``queue_dropped`` (in its last
    status), and it still flushes (issue stop40: a fusion killed after the demo's grace)."""
    stage = _Held()
    stage.start_worker()  # fed in-process: the worker without a session
    for i in range(20):
        stage.post("dev", i, None)
    wait_until(lambda: stage.worker_stats().handled == 1, 10, what="message 0 taken")
    stopper = threading.Thread(target=stage.stop, kwargs={"drain_limit_s": 0.2, "timeout_s": 30})
    stopper.start()
    wait_until(lambda: stage._w_discard, 30, what="the drain's limit passed")
    stage.gate.set()
    stopper.join(30)
    assert not stopper.is_alive() and stage.fed == [0] and stage.flushed
    counters = stage.counters()
    assert counters["stopped"] and counters["stage"]["queue_dropped"] == 19


class _Batched(Stage):
    """Batches of ``batch_s``: bus samples on ``hooked/in`` and posted messages, each noted with
    the number of batches taken before it."""

    name: ClassVar[str] = "batched"

    def __init__(self, session: Any, batch_s: float) -> None:
        super().__init__(StageConfig(), BusCounters(), session)
        self.batch_s = batch_s
        self.seen: list[tuple[str, int]] = []  # (what, batches taken before it)
        self.batches = 0

    def input_keys(self) -> list[str]:
        return [self.keys.all("hooked/in")]

    def read_payload(self, key: str, payload: bytes, t_arrival_ns: int | None) -> object:
        self.seen.append((payload.decode(), self.batches))
        return None

    def feed(self, device: str, t_recv_ns: int, message: object) -> None:
        self.seen.append((f"{device}:{message}", self.batches))

    def feed_batch(self, batch: Any) -> None:
        while batch:
            self.feed(*batch.popleft())
        self.batches += 1


@pytest.mark.e2e
@pytest.mark.parametrize("batch_s", [0.0, 3.0])
def test_bus_samples_wait_for_the_batch_with_the_posted_messages(batch_s: float) -> None:
    """With ``batch_s`` the bus samples that arrive while a batch waits are taken in that batch
    (in arrival order, before its posted messages): one worker run for both, as the ROS 2
    bridge's status samples ride its sensor batches (docs/ros2.md#cost); without, each sample
    is its own worker call as it arrives."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as s:
        stage = _Batched(s, batch_s)
        stage.start()
        pub = s.declare_publisher(stage.keys.all("hooked/in"))
        for i in range(5):
            pub.put(f"sample {i}".encode())
        if batch_s:  # the first sample started the batch's wait: the rest join it
            wait_until(lambda: len(stage._samples) == 5, 30, what="5 samples waiting")
        stage.post("dev", 1, "first")
        stage.post("dev", 2, "second")
        wait_until(lambda: len(stage.seen) == 7, 30, what="5 samples and 2 messages taken")
        stage.stop()
    samples = [w for w, _ in stage.seen if w.startswith("sample")]
    assert samples == [f"sample {i}" for i in range(5)]
    if batch_s:
        # one batch: the five samples (queued by the time it was taken) and both messages
        assert stage.seen == [(f"sample {i}", 0) for i in range(5)] + [
            ("dev:first", 0), ("dev:second", 0)]  # fmt: skip
        assert stage.batches == 1
    else:  # each went straight to the worker: no batch
        assert stage.seen[-2:] == [("dev:first", 0), ("dev:second", 0)] and stage.batches == 0


class _Stalled(Stage):
    """Batches of 50 ms, ``queue_size`` 5; the first batch's ``feed_batch`` waits on ``gate``."""

    name: ClassVar[str] = "stalled"

    def __init__(self) -> None:
        super().__init__(StageConfig(queue_size=5), BusCounters())
        self.batch_s = 0.05
        self.gate = threading.Event()
        self.taken: list[int] = []

    def feed_batch(self, batch: Any) -> None:
        while batch:
            self.taken.append(batch.popleft()[1])
        self.gate.wait(30)


def test_a_batch_behind_a_stalled_worker_is_bounded_and_counts_what_it_drops() -> None:
    """Posted messages wait in the batch at most ``queue_size`` deep while the worker is stuck
    (a loaded host, a slow sink): the rest are dropped and counted in ``queue_dropped``, the
    batch's memory never grows without bound; once the worker moves the held ones go out."""
    stage = _Stalled()
    stage.start_worker()
    stage.post("dev", 0, None)
    wait_until(lambda: stage.taken == [0], 10, what="the first batch taken (the worker stuck)")
    for i in range(1, 9):
        stage.post("dev", i, None)
    assert len(stage._batch) == 5 and stage.stats.queue_dropped == 3
    stage.gate.set()
    wait_until(lambda: len(stage.taken) == 6, 10, what="the held five taken")
    stage.stop()
    assert stage.taken == [0, 1, 2, 3, 4, 5] and stage.counters()["stage"]["queue_dropped"] == 3
