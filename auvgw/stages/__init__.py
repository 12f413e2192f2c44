"""Bus stages: processes (or in-process objects) that consume the gateway's decoded messages and
publish derived data on the bus (:mod:`auvgw.stages.fusion`: dead-reckoning odometry). Each is a
subclass of :class:`auvgw.stages.base.Stage` (queue, worker, status, liveliness, stop/flush)."""

from __future__ import annotations

import logging


def log_bad_payload(
    stage: str, key: str, exc: BaseException, seen: int, exc_info: bool = False
) -> None:
    """Log a malformed bus payload: the first one and every 100th as a warning (a flood of
    them must not flood the log; the stage's status counts them all); ``exc_info``: with the
    traceback (a message that decoded but failed in the stage's handling)."""
    level = logging.WARNING if seen % 100 == 0 else logging.DEBUG
    logging.getLogger(f"auvgw.stages.{stage}").log(
        level, "%s: malformed payload on %s (%d so far): %s: %s",
        stage, key, seen + 1, type(exc).__name__, exc, exc_info=exc_info and level > logging.DEBUG,
    )  # fmt: skip


class StampGuard:
    """Which bus stamps a stage takes: those consistent with its own clock (the newest stamp it
    took, ns), so one message from the far future or past cannot move the clock every later
    sample is judged by (issue 27: one forged stamp stopped the fusion's odometry for good).

    A stamp within ``max_jump_ns`` of the clock is taken (the clock follows the newest). One
    further away is refused and counted; ``confirm`` refused stamps in a row that agree with each
    other (each within ``max_jump_ns`` of the previous) are a real jump (a gateway restarted
    with another epoch, a paused simulator): the clock moves there and the next are taken. A
    forger must then outnumber the real sources ``confirm`` to one, in a row. The first stamp
    sets the clock; a forged first one is outvoted the same way. Not thread-safe: the stage's
    worker is its one caller."""

    __slots__ = ("_candidate", "_clock", "_run", "confirm", "max_jump_ns")

    def __init__(self, max_jump_s: float = 300.0, confirm: int = 20) -> None:
        self.max_jump_ns = int(max_jump_s * 1e9)
        self.confirm = confirm
        self._clock: int | None = None
        self._candidate = 0
        self._run = 0

    @property
    def clock_ns(self) -> int | None:
        """The newest stamp taken (None before the first)."""
        return self._clock

    def accept(self, t_ns: int) -> bool:
        """Whether a sample stamped ``t_ns`` is taken."""
        clock = self._clock
        if clock is None or abs(t_ns - clock) <= self.max_jump_ns:
            if clock is None or t_ns > clock:
                self._clock = t_ns
            self._run = 0
            return True
        if self._run and abs(t_ns - self._candidate) <= self.max_jump_ns:
            self._run += 1
        else:
            self._run = 1
        self._candidate = t_ns
        if self._run >= self.confirm:  # the sources agree on another time: follow them
            self._clock, self._run = t_ns, 0
        return False
