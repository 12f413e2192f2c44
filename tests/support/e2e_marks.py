"""The ``e2e`` mark cannot rot (a pytest plugin, loaded by tests/conftest.py): a test not marked
``e2e`` that starts a process, a pty or a Zenoh session, in its body or in a fixture it sets up,
fails, naming what it started, so ``make test-fast`` (``-m "not e2e"``) never runs one. The calls
themselves still run; the plugin only notes them."""

from __future__ import annotations

import contextlib
import multiprocessing.process
import os
import subprocess
import threading
from collections.abc import Callable, Generator, Iterator
from typing import Any

import pytest
import zenoh

#: (owner, attribute, what a call starts): the calls only an ``e2e`` test may make
TRIPWIRES: list[tuple[Any, str, str]] = [
    (subprocess.Popen, "_execute_child", "a process"),  # run, check_output, Popen
    (multiprocessing.process.BaseProcess, "start", "a process"),  # Process, pools
    (os, "openpty", "a pty"),  # pty.openpty too
    (zenoh, "open", "a Zenoh session"),
]


def _wire(real: Callable[..., Any], what: str, started: list[str],
          earlier: set[threading.Thread]) -> Callable[..., Any]:  # fmt: skip
    def wire(*args: Any, **kwargs: Any) -> Any:
        if threading.current_thread() not in earlier:
            started.append(what)
        return real(*args, **kwargs)

    return wire


@contextlib.contextmanager
def watch(started: list[str]) -> Iterator[None]:
    """Append to ``started`` what each tripwire call inside the block starts: on this thread or
    on one started inside the block. A thread that was already running (left by an earlier test:
    a pool, a supervisor) is not this block's: s41 saw an unmarked test blamed for a process
    such a thread started while it ran, under two workers and two CPU burners."""
    earlier = set(threading.enumerate()) - {threading.current_thread()}
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in TRIPWIRES]
    for (owner, name, real), (_, _, what) in zip(saved, TRIPWIRES, strict=True):
        setattr(owner, name, _wire(real, what, started, earlier))
    try:
        yield
    finally:
        for owner, name, real in saved:
            setattr(owner, name, real)


def _unmarked_e2e_fails(item: pytest.Item) -> Generator[None, object, object]:
    if item.get_closest_marker("e2e"):
        return (yield)
    started: list[str] = []
    with watch(started):
        result = yield
    if started:
        pytest.fail(
            f"{item.nodeid} started {' and '.join(sorted(set(started)))} but is not marked e2e: "
            "move its module to tests/e2e/ or mark it (pytestmark = pytest.mark.e2e, or "
            "@pytest.mark.e2e on the test)",
            pytrace=False,
        )
    return result


pytest_runtest_setup = pytest.hookimpl(wrapper=True)(_unmarked_e2e_fails)
pytest_runtest_call = pytest.hookimpl(wrapper=True)(_unmarked_e2e_fails)
pytest_runtest_teardown = pytest.hookimpl(wrapper=True)(_unmarked_e2e_fails)
