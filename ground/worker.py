"""One home for "a bounded queue and one thread that handles its items in order".

:class:`Inbox` is the queue alone: fed without ever blocking the feeder (a Zenoh callback, a
caller that must not wait), it refuses an item when full and counts it. :class:`Worker` adds the
thread: it takes the items in arrival order, calls a periodic tick, drains what is queued at
stop and counts every item whose handling raised (logged, never stopping the thread).

The bus stages (:class:`auvgw.stages.base.Stage`), the Rerun logger's thread, the MCAP writer
and the subscriber's streams build on these two instead of each keeping its own loop.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Final, Generic, TypeVar, final

__all__ = ["Inbox", "Worker", "WorkerStats", "join_draining"]

log = logging.getLogger(__name__)

T = TypeVar("T")


def join_draining(
    worker: threading.Thread, q: queue.Queue[T], stall_s: float | None, limit_s: float | None = None
) -> bool:
    """Wait for ``worker`` to drain ``q`` and exit. It may take as long as it needs while it makes
    progress (the queue shrinks), up to ``limit_s`` seconds in all (None: no limit); it is given
    up on after ``stall_s`` seconds without progress (None: never), so a busy machine slows the
    drain down but never cuts it short before ``limit_s``. True if it exited."""
    if stall_s is None and limit_s is None:
        worker.join()
        return True
    stall = math.inf if stall_s is None else stall_s
    now = time.monotonic()
    end = now + (math.inf if limit_s is None else limit_s)
    last, deadline = q.qsize(), now + stall
    while worker.is_alive():
        worker.join(min(0.2, stall))
        size, now = q.qsize(), time.monotonic()
        if size < last:  # progress: the stall's clock starts again
            last, deadline = size, now + stall
        if now > min(deadline, end):
            return False
    return True


class Inbox(Generic[T]):
    """A queue of at most ``size`` items (0: unbounded) fed without blocking: :meth:`put` refuses
    an item when the queue is full or closed and counts it in :attr:`dropped`. Thread-safe."""

    def __init__(self, size: int) -> None:
        self.queue: queue.Queue[T] = queue.Queue(max(0, size))
        self._lock = threading.Lock()
        self._dropped = 0
        self._closed = False

    @property
    def dropped(self) -> int:
        """Items refused (queue full or closed)."""
        return self._dropped

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (every later :meth:`put` is refused)."""
        return self._closed

    def put(self, item: T) -> bool:
        """Queue ``item``; False (and counted) when the queue is full or closed."""
        if not self._closed:
            try:
                self.queue.put_nowait(item)
                return True
            except queue.Full:
                pass
        with self._lock:
            self._dropped += 1
        return False

    def get(self, timeout: float | None = None) -> T:
        """The next item, waiting up to ``timeout`` s (None: for ever); ``queue.Empty`` after."""
        return self.queue.get(timeout=timeout)

    def qsize(self) -> int:
        """Items waiting (approximate, as :meth:`queue.Queue.qsize`)."""
        return self.queue.qsize()

    def close(self) -> None:
        """Refuse every later item (those queued stay to be taken)."""
        self._closed = True


@dataclass(frozen=True, slots=True)
class WorkerStats:
    """A worker's counters: items handled (``errors`` of them raised), items refused because the
    queue was full or the worker stopping (``dropped``), items waiting (``queued``) and the last
    error as ``"<item>: <type>: <message>"``."""

    handled: int
    dropped: int
    errors: int
    queued: int
    last_error: str


class _Signal:
    """A queue marker (wakes the worker at stop)."""


_WAKE: Final = _Signal()


class Worker(Generic[T]):
    """A bounded queue (:class:`Inbox`) and one thread handling its items in order.

    A subclass gives :meth:`_work_item` (one item) and, optionally, :meth:`_work_tick` (every
    ``period_s`` on the worker thread, host clock), :meth:`_work_started` and
    :meth:`_work_finished` (first and last thing on the worker thread) and :meth:`_work_describe`
    (an item in error messages). It never overrides the public methods (:func:`typing.final`;
    ``tests/ground/test_worker.py`` checks every subclass).

    ``queue_size``: items waiting before :meth:`submit` refuses (0: unbounded); ``period_s``:
    the tick period (None: no tick); ``thread_name``: the thread's name (default
    :attr:`worker_name`).
    """

    #: the thread's name (and the prefix of logged errors)
    worker_name: ClassVar[str] = "worker"

    def __init__(
        self, queue_size: int, *, period_s: float | None = None, thread_name: str | None = None
    ) -> None:
        self._w_inbox: Inbox[T | _Signal] = Inbox(queue_size)
        self._w_period_s = period_s
        self._w_thread_name = thread_name or self.worker_name
        self._w_thread: threading.Thread | None = None
        self._w_stopping = False  # set once by stop_worker (a bool: read per item, no call)
        self._w_discard = False  # the drain's limit passed: queued items are dropped, not handled
        self._w_discarded = 0
        self._w_finished = threading.Event()
        self._w_handled = 0
        self._w_errors = 0
        self._w_last_error = ""

    # -- what a subclass gives ------------------------------------------------------------------
    def _work_item(self, item: T) -> None:
        """Handle one item (on the worker thread); an exception is counted and logged."""
        raise NotImplementedError

    def _work_tick(self) -> None:
        """Every ``period_s`` (host clock) on the worker thread, between items."""

    def _work_started(self) -> None:
        """First thing on the worker thread (thread-local setup)."""

    def _work_finished(self) -> None:
        """Last thing on the worker thread, after the queue is drained at stop."""

    def _work_describe(self, item: T) -> str:
        """``item`` as named in error messages."""
        return type(item).__name__

    # -- the public side (never overridden) -----------------------------------------------------
    @final
    def start_worker(self) -> None:
        """Start the worker thread (idempotent; not after :meth:`stop_worker`)."""
        if self._w_thread is None and not self._w_stopping:
            t = threading.Thread(target=self._w_loop, name=self._w_thread_name, daemon=True)
            self._w_thread = t
            t.start()

    @final
    @property
    def worker_started(self) -> bool:
        """Whether :meth:`start_worker` started the thread."""
        return self._w_thread is not None

    @final
    @property
    def worker_alive(self) -> bool:
        """Whether the worker thread is running (started, not yet finished)."""
        return self._w_thread is not None and self._w_thread.is_alive()

    @final
    def submit(self, item: T) -> bool:
        """Queue ``item`` for the worker without blocking; False (counted as dropped) when the
        queue is full or the worker stopping."""
        return self._w_inbox.put(item)  # closed by stop_worker

    @final
    def stop_worker(self, timeout_s: float | None = 5.0, limit_s: float | None = None) -> bool:
        """Refuse new items, let the worker handle what is queued and end (for as long as it
        makes progress: ``timeout_s`` s without any gives up on it, None waits for ever; at most
        ``limit_s`` s in all, None: no limit, after which the items still queued are dropped
        unhandled, counted in :attr:`worker_discarded` and logged); never started: the queue is
        handled on the calling thread. True if the worker finished. Safe to call more than
        once."""
        if not self._w_stopping:
            self._w_inbox.close()
            self._w_stopping = True
            with contextlib.suppress(queue.Full):  # a full queue wakes the worker anyway
                self._w_inbox.queue.put_nowait(_WAKE)
            if self._w_thread is None:
                self._w_loop()
        t, q = self._w_thread, self._w_inbox.queue
        if t is not None and not join_draining(t, q, timeout_s, limit_s) and t.is_alive():
            if limit_s is not None and not self._w_discard:  # past the limit: drop the rest
                self._w_discard = True
                t.join(timeout_s)  # the item in hand finishes; the rest is dropped at once
                log.warning("%s: %d items still queued after the %.1f s drain limit dropped "
                            "unhandled", self._w_thread_name, self._w_discarded,
                            limit_s)  # fmt: skip
            if t.is_alive():
                log.warning("%s: the worker made no progress for %s s; stopping without it",
                            self._w_thread_name, timeout_s)  # fmt: skip
        return self._w_finished.is_set()

    @final
    @property
    def worker_discarded(self) -> int:
        """Items dropped unhandled at stop, past :meth:`stop_worker`'s ``limit_s``."""
        return self._w_discarded

    @final
    def worker_stats(self) -> WorkerStats:
        """The worker's counters now."""
        return WorkerStats(self._w_handled, self._w_inbox.dropped, self._w_errors,
                           self._w_inbox.qsize(), self._w_last_error)  # fmt: skip

    # -- the loop -------------------------------------------------------------------------------
    def _w_loop(self) -> None:
        self._w_guard(self._work_started, "start")
        period = self._w_period_s
        next_tick = math.inf if period is None else time.monotonic() + period
        q = self._w_inbox.queue
        while True:
            stopping = self._w_stopping
            try:
                if stopping:
                    item = q.get_nowait()
                else:
                    item = q.get(timeout=None if period is None
                                 else max(0.0, next_tick - time.monotonic()))  # fmt: skip
            except queue.Empty:
                if stopping:
                    break
                item = _WAKE
            if self._w_discard and not isinstance(item, _Signal):
                self._w_discarded += 1
            elif not isinstance(item, _Signal):
                self._w_handled += 1
                try:
                    self._work_item(item)
                except Exception as exc:  # one bad item must never stop the worker
                    self._w_error(self._work_describe(item), exc)
            if period is not None and time.monotonic() >= next_tick:
                self._w_guard(self._work_tick, "tick")
                next_tick = time.monotonic() + period
        self._w_guard(self._work_finished, "finish")
        self._w_finished.set()

    def _w_guard(self, fn: Callable[[], object], what: str) -> None:
        try:
            fn()
        except Exception as exc:
            self._w_error(what, exc)

    def _w_error(self, what: str, exc: Exception) -> None:
        self._w_errors += 1
        self._w_last_error = f"{what}: {type(exc).__name__}: {exc}"
        if self._w_errors <= 5 or self._w_errors % 100 == 0:  # a flood must not flood the log
            log.warning("%s: %s (%d errors so far)", self._w_thread_name, self._w_last_error,
                        self._w_errors, exc_info=True)  # fmt: skip
