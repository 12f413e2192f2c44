"""Waiting on a condition (never a fixed sleep: tests must hold on a busy machine)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

__all__ = ["wait_matched", "wait_until"]


def wait_until(
    pred: Callable[[], Any], timeout: float = 60.0, interval: float = 0.05, what: str = "condition"
) -> Any:
    """Poll ``pred`` until it returns a truthy value; fail with ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def wait_matched(*publishers: Any, timeout: float = 60.0) -> None:
    """Wait until every Zenoh publisher has a matching subscriber. A sample put before the
    remote subscriber's declaration has reached this session is routed nowhere (lost), and a
    process's own status reaching us says nothing about whether its subscriptions reached us."""
    wait_until(lambda: all(p.matching_status.matching for p in publishers), timeout,
               what="a subscriber for every publisher")  # fmt: skip
