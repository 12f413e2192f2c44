"""Bus stages: processes (or in-process objects) that consume the gateway's decoded messages and
publish derived data on the bus (:mod:`auvgw.stages.fusion`: dead-reckoning odometry). Each is a
subclass of :class:`auvgw.stages.base.Stage` (queue, worker, status, liveliness, stop/flush)."""

from __future__ import annotations

import logging
import queue
import threading
import time


def join_draining(worker: threading.Thread, q: queue.Queue, stall_s: float) -> bool:
    """Wait for ``worker`` to drain ``q`` and exit. It may take as long as it needs while it makes
    progress (the queue shrinks); it is given up on only after ``stall_s`` seconds without
    progress, so a busy machine slows the drain down but never cuts it short. True if it exited."""
    last, deadline = q.qsize(), time.monotonic() + stall_s
    while worker.is_alive():
        worker.join(min(0.2, stall_s))
        size = q.qsize()
        if size < last:
            last, deadline = size, time.monotonic() + stall_s
        elif time.monotonic() > deadline:
            return False
    return True


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
