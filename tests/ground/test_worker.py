"""The Worker base (auvgw.ground.worker): bounded queue with counted drops, drain at stop, error
accounting, the tick; and that no user of it overrides its public methods."""

from __future__ import annotations

import gc
import importlib
import inspect
import pkgutil
import threading

from auvgw.ground.worker import Inbox, Worker
from auvgw.testing import wait_until
from auvgw.testing.overrides import overrides, subclasses


class _Recorder(Worker[int]):
    """Records what it handles; waits on ``gate`` for each item; item -13 raises."""

    worker_name = "test-recorder"

    def __init__(self, queue_size: int, period_s: float | None = None) -> None:
        super().__init__(queue_size, period_s=period_s)
        self.gate = threading.Event()
        self.seen: list[int] = []
        self.events: list[str] = []
        self.threads: set[str] = set()
        self.ticks = 0

    def _work_item(self, item: int) -> None:
        self.gate.wait(30)
        self.threads.add(threading.current_thread().name)
        if item == -13:
            raise ValueError("thirteen")
        self.seen.append(item)

    def _work_tick(self) -> None:
        self.ticks += 1

    def _work_started(self) -> None:
        self.events.append("started")

    def _work_finished(self) -> None:
        self.events.append(f"finished after {len(self.seen)}")

    def _work_describe(self, item: int) -> str:
        return f"item {item}"


def test_a_full_queue_refuses_and_counts_every_item_it_drops() -> None:
    w = _Recorder(queue_size=5)
    w.start_worker()
    assert w.submit(0)
    wait_until(lambda: w.worker_stats().handled == 1, 10, what="the first item taken")
    # the worker is held in item 0: five fit, the next three are refused
    accepted = [w.submit(i) for i in range(1, 9)]
    assert accepted == [True] * 5 + [False] * 3
    assert (w.worker_stats().dropped, w.worker_stats().queued) == (3, 5)
    w.gate.set()
    assert w.stop_worker(timeout_s=10)
    assert w.seen == [0, 1, 2, 3, 4, 5]
    st = w.worker_stats()
    assert (st.handled, st.dropped, st.errors, st.queued) == (6, 3, 0, 0)


def test_stop_drains_the_queue_on_the_worker_then_refuses() -> None:
    w = _Recorder(queue_size=100)
    w.start_worker()
    for i in range(50):
        assert w.submit(i)
    w.gate.set()
    assert w.stop_worker(timeout_s=10)
    assert w.seen == list(range(50)) and not w.worker_alive
    assert w.events == ["started", "finished after 50"]
    assert w.threads == {"test-recorder"}
    assert not w.submit(99) and w.worker_stats().dropped == 1
    assert w.stop_worker() and w.seen == list(range(50))  # twice: nothing more


def test_a_worker_never_started_is_drained_on_the_stopping_thread() -> None:
    w = _Recorder(queue_size=0)  # unbounded
    w.gate.set()
    for i in range(20):
        w.submit(i)
    assert not w.worker_started
    assert w.stop_worker()
    assert w.seen == list(range(20)) and w.threads == {threading.current_thread().name}
    assert w.events == ["started", "finished after 20"]


def test_an_item_that_raises_is_counted_and_the_worker_goes_on(caplog) -> None:
    w = _Recorder(queue_size=100)
    w.gate.set()
    w.start_worker()
    for i in (11, 12, -13, 14, -13, 15):
        w.submit(i)
    assert w.stop_worker(timeout_s=10)
    assert w.seen == [11, 12, 14, 15]
    st = w.worker_stats()
    assert (st.handled, st.errors) == (6, 2)
    assert st.last_error == "item -13: ValueError: thirteen"
    assert any("item -13: ValueError: thirteen" in r.getMessage() for r in caplog.records)


def test_the_tick_runs_on_the_worker_between_items() -> None:
    w = _Recorder(queue_size=10, period_s=0.01)
    w.gate.set()
    w.start_worker()
    wait_until(lambda: w.ticks >= 3, 10, what="three ticks with an empty queue")
    w.submit(1)
    wait_until(lambda: w.seen == [1], 10, what="an item between ticks")
    assert w.stop_worker(timeout_s=10)


def test_the_inbox_alone_counts_what_it_refuses() -> None:
    box: Inbox[str] = Inbox(2)
    assert [box.put(s) for s in "abc"] == [True, True, False]
    box.close()
    assert not box.put("d") and box.dropped == 2
    assert [box.get(0), box.get(0)] == ["a", "b"]  # what was queued stays to be taken


# -- no user overrides the base's public methods ------------------------------------------------

#: the Worker's public methods and properties (a subclass never redefines one)
PUBLIC = sorted(n for n, v in vars(Worker).items()
                if not n.startswith("_") and (callable(v) or isinstance(v, property)))  # fmt: skip


def _overrides(classes: set[type]) -> list[str]:
    return overrides(classes, PUBLIC)


def _import_users() -> None:
    for pkg in ("auvgw.stages", "auvgw.viz"):
        mod = importlib.import_module(pkg)
        for info in pkgutil.iter_modules(mod.__path__, f"{pkg}."):
            importlib.import_module(info.name)
    for name in ("auvgw.recording", "auvgw.subscribe"):
        importlib.import_module(name)


def test_no_worker_overrides_the_public_methods() -> None:
    assert {"start_worker", "stop_worker", "submit", "worker_stats"} <= set(PUBLIC)
    _import_users()
    subs = subclasses(Worker)
    names = {c.__qualname__ for c in subs}
    # the users: every bus stage, the Rerun logger's thread and the MCAP writer
    assert {"Stage", "VizStage", "FusionStage", "RerunLogger", "McapRecorder"} <= names
    assert _overrides(subs) == []


def test_the_override_check_finds_a_planted_override() -> None:
    class Bad(Worker[int]):
        def submit(self, item: int) -> bool:  # type: ignore[misc]
            return False

    assert _overrides({Bad}) == [f"{__name__}.{Bad.__qualname__}.submit"]
    assert inspect.getattr_static(Worker, "submit") is not inspect.getattr_static(Bad, "submit")
    del Bad
    gc.collect()  # out of Worker.__subclasses__() again


def test_a_drain_past_its_limit_drops_the_rest_and_counts_it(caplog) -> None:
    # a stage far behind on a loaded host drained for longer than its supervisor's grace and was
    # killed unflushed: with limit_s the backlog left at the limit is dropped, counted and logged
    w = _Recorder(queue_size=100)
    w.start_worker()
    for i in range(50):
        w.submit(i)
    wait_until(lambda: w.worker_stats().handled == 1, 10, what="item 0 taken (held on the gate)")
    stopper = threading.Thread(target=w.stop_worker, kwargs={"timeout_s": 30, "limit_s": 0.2})
    stopper.start()
    # past the limit (item 0 still held) the stopper waits for the item in hand, then drops
    wait_until(lambda: w._w_discard, 30, what="the drain's limit passed")
    w.gate.set()  # item 0 ends; the 49 behind it are dropped unhandled
    stopper.join(30)
    assert not stopper.is_alive() and not w.worker_alive
    assert w.seen == [0] and w.worker_discarded == 49
    assert w.events == ["started", "finished after 1"]
    assert "49 items still queued after the 0.2 s drain limit dropped" in caplog.text
