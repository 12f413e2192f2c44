"""One simulation clock (vehicle time) for every emulator, at real time, k x faster, or as fast
as possible.

Vehicle time is in seconds from the scenario start. With ``speed`` k > 0 it advances k times
faster than the host's monotonic clock once :meth:`SimClock.start` is called. With ``speed`` 0
it is a discrete-event clock: time jumps to the earliest pending wake-up as soon as every
*participant* thread is waiting, so a run completes as fast as the CPU allows while every
device still sees a consistent time. Threads that drive the clock (the scheduler, an emulator
loop calling :meth:`SimClock.sleep_until`) register with :meth:`SimClock.participant`; a
thread that is not registered is only accounted for while it sleeps.

Periodic device ticks are scheduled in one place, :meth:`SimClock.every` / :meth:`SimClock.at`,
and dispatched in time order by :meth:`SimClock.run` (in the calling thread) or
:meth:`SimClock.start_thread`. A tick callback receives its exact scheduled vehicle time
(``t0 + n period``, no drift), so device timestamps stay exact even when a callback runs late;
late ticks are never skipped, they are counted (:attr:`SimClock.late_ticks`, :attr:`max_lag`).

Lock-step (:meth:`SimClock.lockstep`, speed > 0): vehicle time does not run past a *hold
limit*, the vehicle time the controller under test last answered (:meth:`SimClock.answered`)
plus a bounded step; while held the clock stands still, so a stalled host stretches wall time
instead of vehicle time. A hold longer than a wall timeout is counted
(:attr:`SimClock.hold_timeouts`) and released by one step, so a silent controller slows the run
but never hangs it. ``on_anchor`` is told every new anchor (for the processes that read the
clock through :mod:`auvgw.ground.simclock`).

Elastic pacing (:meth:`SimClock.elastic`, speed > 0), as HIL benches run when the host cannot
keep up: the same hold, driven by the clock's own dispatch instead of a controller. Vehicle time
never runs more than ``lag`` past the earliest tick not dispatched yet (this clock's, and
through :meth:`SimClock.report` those of other processes' clocks), so when dispatch falls behind
vehicle time stands still and wall time stretches: a tick leaves the host at most ``lag``
vehicle s after its time, instead of arbitrarily late. A clock in another process follows the
one that holds (:meth:`SimClock.follow`: its vehicle time read from the holder's clock file, its
own dispatch progress reported back), so every process reads one vehicle time.

Everything is thread-safe (one condition variable).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

__all__ = ["ClockStopped", "SimClock", "Task", "thread_cpu_s"]

log = logging.getLogger(__name__)
_CLK_TCK = os.sysconf("SC_CLK_TCK")


def thread_cpu_s(native_id: int | None) -> float:
    """CPU seconds (user + system) a running thread of this process has used so far, read
    from ``/proc`` (``native_id`` from ``threading.get_native_id()``; clock-tick resolution,
    10 ms); 0 when the thread is gone."""
    if native_id is None:
        return 0.0
    try:
        with open(f"/proc/self/task/{native_id}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK  # utime, stime


class ClockStopped(RuntimeError):
    """The clock was stopped while a thread waited on it."""


@dataclass(eq=False)
class Task:
    """A scheduled callback: ``callback(t)`` at vehicle time ``t``; periodic if ``period``."""

    callback: Callable[[float], object]
    t0: float
    period: float | None = None
    name: str = ""
    count: int = 0  # ticks dispatched so far
    cancelled: bool = False
    _clock: SimClock | None = field(default=None, repr=False)

    @property
    def next_time(self) -> float:
        """Vehicle time of the next tick, s."""
        return self.t0 + self.count * (self.period or 0.0)

    def cancel(self) -> None:
        """Stop this task (a tick already running finishes)."""
        self.cancelled = True
        if self._clock is not None:
            self._clock._wake()


class SimClock:
    """Vehicle time at ``speed`` x real time (0: as fast as possible), with a scheduler.

    ``start_time`` is the vehicle time at :meth:`start`; before it, :meth:`now` returns it and
    sleepers wait. ``time_fn`` is the host monotonic clock in seconds (injectable for tests).
    """

    def __init__(
        self,
        speed: float = 1.0,
        start_time: float = 0.0,
        time_fn: Callable[[], float] = time.monotonic,
    ) -> None:
        if speed < 0 or not math.isfinite(speed):
            raise ValueError(f"clock speed must be >= 0 (0 = as fast as possible), got {speed}")
        self._cv = threading.Condition(threading.RLock())
        self._speed = float(speed)
        self._time_fn = time_fn
        self._start_time = float(start_time)
        self._t_anchor = float(start_time)  # vehicle time at _real_anchor (or virtual time)
        self._real_anchor = 0.0
        self._started = False
        self._stopped = False
        self._actors: dict[int, int] = {}  # thread id -> nesting depth
        self._waiting: dict[int, float] = {}  # thread id -> wake-up time (inf: external event)
        self._heap: list[tuple[float, int, Task]] = []
        self._seq = itertools.count()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._thread_tid: int | None = None
        self._thread_cpu = 0.0
        self.late_ticks = 0
        self.max_lag = 0.0
        # lock-step: the hold limit (vehicle s), step (vehicle s), wall timeout (host s)
        self._limit = math.inf
        self._step = 0.0
        self._hold_timeout = math.inf
        self._held_since: float | None = None  # host s the current hold began
        self._on_anchor: Callable[[float, float, float, float], object] | None = None
        self.answers = 0  #: controller answers taken (lock-step)
        self.holds = 0  #: times vehicle time reached the hold limit and stood still
        self.held_s = 0.0  #: host s spent holding
        self.hold_timeouts = 0  #: holds released by the wall timeout, not by an answer
        self.timeout_times: list[float] = []  #: vehicle s of the first 20 of them
        # elastic pacing: the lag (vehicle s, 0: off), this clock's earliest undispatched tick
        # and the other dispatchers' (vehicle s); the limit moves in steps of _quantum
        self._elastic = 0.0
        self._quantum = 0.0
        self._pending = float(start_time)
        self._others = math.inf
        # following another process's clock: its state (t_anchor, host anchor, speed, limit),
        # and where this clock's own dispatch progress goes
        self._follow: Callable[[], tuple[float, ...] | None] | None = None
        self._on_pending: Callable[[float], object] | None = None
        self._follow_held = False

    # -- time ---------------------------------------------------------------------------------
    @property
    def speed(self) -> float:
        """Vehicle seconds per real second; 0 means as fast as possible."""
        return self._speed

    @property
    def started(self) -> bool:
        return self._started

    @property
    def stopped(self) -> bool:
        return self._stopped

    @property
    def started_at(self) -> float | None:
        """The host instant (``time_fn`` seconds) of vehicle time ``start_time`` at the
        current speed (None before :meth:`start`)."""
        with self._cv:
            if not self._started:
                return None
            if self._speed == 0:
                return self._real_anchor
            return self._real_anchor - (self._t_anchor - self._start_time) / self._speed

    def start(self, at: float | None = None) -> None:
        """Let vehicle time run: ``start_time`` is the vehicle time at the host instant ``at``
        (``time_fn`` seconds; default now). With ``at`` in the future, :meth:`now` is earlier
        than ``start_time`` until then and ticks wait for their time as usual (clocks in
        several processes share one ``at``). A second call changes nothing."""
        with self._cv:
            if not self._started:
                self._real_anchor = self._time_fn() if at is None else float(at)
                self._started = True
                if self._on_anchor is not None:
                    self._on_anchor(self._t_anchor, self._real_anchor, self._speed, self._limit)
                self._cv.notify_all()

    def stop(self) -> None:
        """Stop the clock: sleepers return ``False``, the scheduler loop ends."""
        with self._cv:
            self._stopped = True
            self._cv.notify_all()

    def _now(self) -> float:
        if not self._started or self._speed == 0:
            return self._t_anchor
        host = self._time_fn()
        if self._follow is not None:
            st = self._follow()
            if st is not None:  # the holder's clock (before its first anchor: this one's)
                t_anchor, host_anchor, speed, limit = st[:4]
                t = t_anchor + (host - host_anchor) * speed
                self._follow_held = t >= limit
                return min(t, limit)
        t = self._t_anchor + (host - self._real_anchor) * self._speed
        if t <= self._limit:
            return t
        # held at the limit: the clock stands still (re-anchored there) until it moves
        if self._held_since is None:  # since the host instant it reached the limit
            self._held_since = self._real_anchor + (self._limit - self._t_anchor) / self._speed
            self.holds += 1
        self._t_anchor, self._real_anchor = self._limit, host
        if host - self._held_since > self._hold_timeout:
            self.hold_timeouts += 1
            if len(self.timeout_times) < 20:
                self.timeout_times.append(self._limit)
            self._move_limit(self._limit + self._step, host)
        return self._t_anchor

    # -- lock-step ----------------------------------------------------------------------------
    def lockstep(self, step: float, timeout: float, first: float,
                 on_anchor: Callable[[float, float, float, float], object] | None = None,
                 ) -> None:  # fmt: skip
        """Turn lock-step on (speed > 0): vehicle time holds at ``first`` (vehicle s) until
        :meth:`answered`, then at each answer + ``step`` (s); a hold longer than ``timeout``
        host s moves the limit one ``step`` on and counts in :attr:`hold_timeouts`.
        ``on_anchor(t_anchor, host_anchor, speed, limit)`` is called with every new anchor
        (lock held: keep it short)."""
        if self._speed == 0:
            raise ValueError("lock-step needs a real-time clock (speed > 0)")
        if not (step > 0 and timeout > 0):
            raise ValueError(f"lock-step step and timeout must be > 0, got {step}, {timeout}")
        with self._cv:
            self._step, self._hold_timeout, self._on_anchor = float(step), float(timeout), on_anchor
            self._move_limit(float(first), self._time_fn())

    @property
    def limit(self) -> float:
        """The hold limit (vehicle s; inf: free-running)."""
        return self._limit

    def answered(self, t: float) -> None:
        """The controller has answered everything up to vehicle time ``t`` (s): vehicle time
        may run on to ``t`` + the lock-step step."""
        with self._cv:
            self.answers += 1
            if t + self._step > self._limit:
                self._move_limit(t + self._step, self._time_fn())

    # -- elastic pacing -------------------------------------------------------------------------
    def elastic(self, lag: float, timeout: float = 10.0,
                on_anchor: Callable[[float, float, float, float], object] | None = None,
                ) -> None:  # fmt: skip
        """Turn elastic pacing on (speed > 0, before :meth:`start`): vehicle time runs at most
        ``lag`` vehicle s past the earliest tick not dispatched yet (here or as told by
        :meth:`report`), and stands still while dispatch is behind. The hold limit moves in
        steps of ``lag / 4`` (with nothing left to dispatch and no end, it runs free). A hold
        longer than ``timeout`` host s (a dispatcher that never comes back) moves on by ``lag``
        and counts in :attr:`hold_timeouts`. ``on_anchor``: as for :meth:`lockstep` (every new
        anchor and limit, for the clock file)."""
        if self._speed == 0:
            raise ValueError("elastic pacing needs a real-time clock (speed > 0)")
        if not (lag > 0 and timeout > 0):
            raise ValueError(f"elastic lag and timeout must be > 0, got {lag}, {timeout}")
        with self._cv:
            self._elastic, self._quantum = float(lag), float(lag) / 4
            self._step, self._hold_timeout, self._on_anchor = float(lag), float(timeout), on_anchor
            self._move_limit(min(self._pending, self._others) + lag, self._time_fn())

    @property
    def elastic_lag(self) -> float:
        """The elastic pacing's lag (vehicle s; 0: not elastic)."""
        return self._elastic

    @property
    def following(self) -> bool:
        """Vehicle time is read from another clock (:meth:`follow`)."""
        return self._follow is not None

    def report(self, t: float) -> None:
        """Elastic pacing: every other dispatcher (another process's clock, see :meth:`follow`)
        has dispatched all its ticks before vehicle time ``t`` (s; inf: none left). Report
        once before :meth:`start` where others will (until then they count as done)."""
        with self._cv:
            self._others = float(t)
            self._pace()

    def _pace(self) -> None:
        """Move the elastic hold limit to the earliest pending tick + lag (lock held), in
        steps of the quantum; it never moves back."""
        if not self._elastic:
            return
        target = min(self._pending, self._others) + self._elastic
        if target >= self._limit + self._quantum:
            self._move_limit(target, self._time_fn())

    def follow(self, state: Callable[[], tuple[float, ...] | None],
               on_pending: Callable[[float], object] | None = None) -> None:  # fmt: skip
        """Read vehicle time from another clock (speed > 0): ``state()`` gives its ``(t_anchor,
        host anchor, speed, limit)`` (:class:`auvgw.ground.simclock.ClockState`; None until
        it is written, and this clock runs on its own); ``on_pending(t)`` is told the vehicle
        time of this clock's earliest undispatched tick as it moves (the holder's
        :meth:`report`). A sleeper polls every 2 ms host while the followed clock holds."""
        if self._speed == 0:
            raise ValueError("following a clock needs a real-time clock (speed > 0)")
        with self._cv:
            self._follow, self._on_pending = state, on_pending

    def _note_pending(self, t: float) -> None:
        """This clock's earliest undispatched tick is at vehicle time ``t`` (lock held)."""
        if t == self._pending:
            return
        self._pending = t
        if self._on_pending is not None:
            self._on_pending(t)
        self._pace()

    def _move_limit(self, limit: float, host: float) -> None:
        """Re-anchor at the current time (lock held), then move the limit and tell."""
        if self._started and self._speed > 0:  # where the clock is now, held or not
            t = self._t_anchor + (host - self._real_anchor) * self._speed
            self._t_anchor, self._real_anchor = min(self._limit, t), host
        if self._held_since is not None:
            self.held_s += host - self._held_since
            self._held_since = None
        self._limit = limit
        if self._on_anchor is not None and self._started:
            self._on_anchor(self._t_anchor, self._real_anchor, self._speed, limit)
        self._cv.notify_all()

    def now(self) -> float:
        """Current vehicle time, s."""
        with self._cv:
            return self._now()

    def set_speed(self, speed: float) -> None:
        """Change the speed factor at run time; vehicle time continues from where it is."""
        if speed < 0 or not math.isfinite(speed):
            raise ValueError(f"clock speed must be >= 0, got {speed}")
        with self._cv:
            self._t_anchor = self._now()
            self._real_anchor = self._time_fn()
            self._speed = float(speed)
            if self._on_anchor is not None:
                self._on_anchor(self._t_anchor, self._real_anchor, self._speed, self._limit)
            self._maybe_advance()
            self._cv.notify_all()

    def real_duration(self, vehicle_s: float) -> float:
        """Host seconds that ``vehicle_s`` vehicle seconds take at the current speed (0 when
        running as fast as possible)."""
        return 0.0 if self._speed == 0 else vehicle_s / self._speed

    # -- participants and waiting (the discrete-event part) -----------------------------------
    @contextmanager
    def participant(self) -> Iterator[None]:
        """Register the calling thread as one that drives time (speed 0: time only advances
        while every participant waits). Nestable."""
        me = threading.get_ident()
        with self._cv:
            self._actors[me] = self._actors.get(me, 0) + 1
        try:
            yield
        finally:
            with self._cv:
                self._actors[me] -= 1
                if self._actors[me] == 0:
                    del self._actors[me]
                self._maybe_advance()
                self._cv.notify_all()

    def _maybe_advance(self) -> None:
        """Speed 0: jump to the earliest wake-up once no participant is busy."""
        if self._speed != 0 or not self._started or self._stopped:
            return
        if any(a not in self._waiting for a in self._actors):
            return
        pending = [t for t in self._waiting.values() if math.isfinite(t)]
        if not pending:
            return
        target = min(pending)
        if target > self._t_anchor:
            self._t_anchor = target
            self._cv.notify_all()

    def _wait(self, deadline: float, interrupt: Callable[[], bool] | None = None) -> bool:
        """Block (lock held) until vehicle time reaches ``deadline``, ``interrupt()`` is true or
        the clock stops. Returns False if stopped."""
        me = threading.get_ident()
        self._waiting[me] = deadline
        try:
            while True:
                if self._stopped:
                    return False
                if interrupt is not None and interrupt():
                    return True
                if self._started and self._now() >= deadline:
                    return True
                if not self._started:
                    self._cv.wait()
                elif self._speed == 0:
                    self._maybe_advance()
                    if self._now() < deadline and not (interrupt is not None and interrupt()):
                        self._cv.wait()
                else:
                    remaining = (deadline - self._now()) / self._speed
                    if math.isfinite(self._limit):  # held: wake to judge the hold's timeout
                        remaining = min(remaining, 0.05)
                    if self._follow_held:  # the followed clock holds: poll its file
                        remaining = min(remaining, 0.002)
                    self._cv.wait(min(remaining, 3600.0) if math.isfinite(remaining) else None)
        finally:
            del self._waiting[me]
            if self._speed == 0:
                self._maybe_advance()

    def sleep_until(self, t: float) -> bool:
        """Sleep until vehicle time ``t``; False if the clock was stopped meanwhile."""
        with self._cv:
            return self._wait(t)

    def sleep(self, dt: float) -> bool:
        """Sleep ``dt`` vehicle seconds; False if the clock was stopped meanwhile."""
        with self._cv:
            return self._wait(self._now() + dt)

    def wait_for(self, predicate: Callable[[], bool], timeout: float | None = None) -> bool:
        """Wait (real time) until ``predicate()`` is true, e.g. for a host request, without
        holding up vehicle time. Returns the predicate's last value."""
        end = None if timeout is None else time.monotonic() + timeout
        with self._cv:
            me = threading.get_ident()
            self._waiting[me] = math.inf
            try:
                self._maybe_advance()
                while not predicate() and not self._stopped:
                    left = None if end is None else end - time.monotonic()
                    if left is not None and left <= 0:
                        break
                    self._cv.wait(left)
                return predicate()
            finally:
                del self._waiting[me]

    def notify(self) -> None:
        """Wake threads blocked in :meth:`wait_for` (call after changing what they test)."""
        self._wake()

    def _wake(self) -> None:
        with self._cv:
            self._cv.notify_all()

    # -- scheduler ----------------------------------------------------------------------------
    def _push(self, task: Task) -> Task:
        task._clock = self
        with self._cv:
            heapq.heappush(self._heap, (task.next_time, next(self._seq), task))
            self._cv.notify_all()
        return task

    def every(
        self,
        period: float,
        callback: Callable[[float], object],
        start: float | None = None,
        name: str = "",
    ) -> Task:
        """Call ``callback(t)`` at ``t = start + n period`` (vehicle s; ``start`` defaults to
        now). Rate in Hz is ``1 / period``."""
        if not period > 0:
            raise ValueError(f"period must be > 0, got {period}")
        t0 = self.now() if start is None else float(start)
        label = name or getattr(callback, "__name__", "")
        return self._push(Task(callback, t0, float(period), label))

    def at(self, t: float, callback: Callable[[float], object], name: str = "") -> Task:
        """Call ``callback(t)`` once at vehicle time ``t`` (now if it has passed)."""
        label = name or getattr(callback, "__name__", "")
        return self._push(Task(callback, float(t), None, label))

    def run(self, until: float | None = None) -> None:
        """Dispatch scheduled ticks in time order in this thread until vehicle time ``until``
        (or until :meth:`stop`). Starts the clock (now) if needed. A callback that raises
        stops the clock and the exception propagates from here."""
        self.start()
        with self.participant():
            while True:
                with self._cv:
                    task = self._next_task(until)
                    if task is None:
                        return
                t = task.next_time
                lag = self.now() - t
                if self._speed > 0 and lag > 0:
                    self.max_lag = max(self.max_lag, lag)
                    if lag > (task.period or 0.1):
                        self.late_ticks += 1
                try:
                    task.callback(t)
                except BaseException as exc:
                    self._error = exc
                    self.stop()
                    raise
                with self._cv:
                    task.count += 1
                    if task.period is not None and not task.cancelled:
                        heapq.heappush(self._heap, (task.next_time, next(self._seq), task))

    def _next_task(self, until: float | None) -> Task | None:
        """Pop the next task once it is due, sleeping until then (lock held); None when the
        clock stops or nothing is due before ``until``."""
        end = math.inf if until is None else until
        while True:
            while self._heap and self._heap[0][2].cancelled:
                heapq.heappop(self._heap)
            if self._stopped:
                return None
            head = self._heap[0][2] if self._heap else None
            head_t = self._heap[0][0] if self._heap else math.inf
            self._note_pending(min(head_t, end))
            if head is not None and head_t <= end and self._now() >= head_t:
                heapq.heappop(self._heap)
                return head
            if head_t > end and self._started and self._now() >= end:
                return None

            def changed(head: Task | None = head) -> bool:
                new = self._heap[0][2] if self._heap else None
                return new is not head or (head is not None and head.cancelled)

            self._wait(min(head_t, end), changed)

    def start_thread(self, until: float | None = None, name: str = "sim-clock") -> threading.Thread:
        """Run :meth:`run` in a daemon thread; :meth:`join` waits for it and re-raises."""
        th = threading.Thread(target=self._run_quietly, args=(until,), name=name, daemon=True)
        self._thread = th
        th.start()
        return th

    def _run_quietly(self, until: float | None) -> None:
        self._thread_tid = threading.get_native_id()
        try:
            self.run(until)
        except BaseException:
            log.exception("simulation clock: a scheduled callback failed")
        finally:
            self._thread_cpu = time.thread_time()
            self._thread_tid = None

    @property
    def thread_cpu_s(self) -> float:
        """CPU seconds the :meth:`start_thread` thread used (dispatch and every callback)."""
        return self._thread_cpu + thread_cpu_s(self._thread_tid)

    def join(self, timeout: float | None = None) -> None:
        """Wait for the scheduler thread; re-raise a callback's exception."""
        if self._thread is not None:
            self._thread.join(timeout)
        if self._error is not None:
            raise self._error

    def close(self) -> None:
        """Stop the clock and wait for the scheduler thread."""
        self.stop()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
