"""Where Monte Carlo trials run: in this process, on local worker processes, or on an existing
Dask cluster given by its scheduler address. Every trial seeds itself from its (study seed, run)
pair, so the results do not depend on where or in which order it ran."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["ExecutorError", "map_unordered", "open_executor"]

T = TypeVar("T")
R = TypeVar("R")


class ExecutorError(RuntimeError):
    """The executor could not be started (unreachable scheduler, dask not installed)."""


#: s to reach a Dask scheduler before giving up (a refused connection is retried until then)
DASK_CONNECT_TIMEOUT_S = 10.0


@contextmanager
def open_executor(jobs: int = 1, dask: Any = None) -> Iterator[Executor | None]:
    """``None`` (run in this process) for ``jobs <= 1`` without ``dask``; a process pool of
    ``jobs`` workers; or, with ``dask`` = ``tcp://host:8786`` (or a ``distributed.Client``),
    the cluster's ``concurrent.futures`` executor."""
    if dask is None:
        if jobs <= 1:
            yield None
            return
        with ProcessPoolExecutor(max_workers=jobs) as ex:
            yield ex
        return
    try:
        from distributed import Client as _Client
    except ImportError as exc:  # pragma: no cover - dask[distributed] is a dependency
        raise ExecutorError(
            "--dask needs dask[distributed]: pip install 'dask[distributed]'"
        ) from exc
    Client: Any = _Client  # distributed is untyped
    if isinstance(dask, Client):
        yield dask.get_executor(pure=False)
        return
    try:
        client = Client(dask, timeout=f"{DASK_CONNECT_TIMEOUT_S:g}s")
    except (OSError, TimeoutError) as exc:
        raise ExecutorError(f"--dask {dask}: cannot reach the Dask scheduler: {exc}") from exc
    try:
        yield client.get_executor(pure=False)
    finally:
        client.close()


def map_unordered(
    fn: Callable[[T], R],
    tasks: Iterable[T],
    executor: Executor | None,
    progress: Callable[[R], Any] | None = None,
) -> list[R]:
    """``fn`` over ``tasks`` on ``executor`` (``None``: here, in order); results in completion
    order, ``progress`` called with each."""
    out: list[R] = []
    if executor is None:
        it: Iterable[R] = (fn(t) for t in tasks)
    else:
        futures = [executor.submit(fn, t) for t in tasks]
        it = (f.result() for f in as_completed(futures))
    for r in it:
        out.append(r)
        if progress is not None:
            progress(r)
    return out
