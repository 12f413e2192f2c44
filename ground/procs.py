"""Child processes and free ports: the one home of process supervision.

:func:`stop_process` is how every supervisor (``auvgw demo``, the emulator runner, the test
fixtures, the benchmarks) ends a child: a signal (SIGINT: the child's own clean stop; SIGTERM),
then SIGKILL after a grace period. :class:`Children` keeps a set of named ``python -m auvgw``
children with their logs. :func:`free_port` gives a loopback TCP port nobody listens on.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import IO, Any

__all__ = [
    "STOP_GRACE_S",
    "Children",
    "end_without_finalising",
    "ending_without_finalising",
    "endpoint",
    "free_endpoint",
    "free_port",
    "stop_process",
]

#: s a supervisor (:meth:`Children.stop`) gives a child between SIGINT and SIGKILL; a stage's
#: command drains its queue for half of it at most (:func:`auvgw.commands.run.serve_stage`)
STOP_GRACE_S = 15.0


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that was free a moment ago (the OS's choice)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def endpoint(port: int, host: str = "127.0.0.1") -> str:
    """The Zenoh TCP endpoint ``tcp/<host>:<port>``."""
    return f"tcp/{host}:{port}"


def free_endpoint(host: str = "127.0.0.1") -> str:
    """A Zenoh TCP endpoint on a free port of ``host``."""
    return endpoint(free_port(host), host)


def stop_process(
    proc: subprocess.Popen[Any], sig: int | None = signal.SIGTERM, grace_s: float = 10.0
) -> tuple[int, bool]:
    """Stop ``proc`` if it still runs: ``sig`` (None: none, it was asked to stop some other
    way), then SIGKILL after ``grace_s`` seconds. Returns ``(exit code, killed)``; the code is
    negative for a signal (POSIX)."""
    killed = False
    if proc.poll() is None:
        if sig is not None:
            proc.send_signal(sig)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            killed = True
            proc.kill()
            proc.wait()
    return proc.returncode, killed


class Children:
    """Named ``python -m auvgw ...`` children, each logging to ``OUT/<name>.log``; stopped with
    SIGINT (their clean stop), killed after a grace period; exit codes kept."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.exit_codes: dict[str, int | None] = {}
        self.killed: list[str] = []
        self._logs: list[IO[bytes]] = []

    def start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        """Start ``auvgw <argv>`` as ``name``, stdout and stderr to its log."""
        log_file = open(self.out / f"{name}.log", "wb")  # noqa: SIM115 (closed in close)
        self._logs.append(log_file)
        proc = subprocess.Popen([sys.executable, "-m", "auvgw", *argv], stdout=log_file,
                                stderr=subprocess.STDOUT)  # fmt: skip
        self.procs[name] = proc
        return proc

    def exited(self, but: tuple[str, ...] = ()) -> str | None:
        """The name of a child (not in ``but``) that has exited, if any."""
        return next((n for n, p in self.procs.items() if n not in but and p.poll() is not None),
                    None)  # fmt: skip

    def tail(self, name: str, n: int = 400) -> str:
        """The last ``n`` characters of a child's log, on one line."""
        try:
            text = (self.out / f"{name}.log").read_text(errors="replace")
        except OSError:
            return ""
        return text[-n:].strip().replace("\n", " | ")

    def stop(self, name: str, grace_s: float = STOP_GRACE_S) -> int | None:
        """SIGINT, then SIGKILL after ``grace_s``; the exit code (negative: signal)."""
        proc = self.procs.get(name)
        if proc is None:
            return None
        code, killed = stop_process(proc, signal.SIGINT, grace_s)
        if killed:
            self.killed.append(name)
        self.exit_codes[name] = code
        return code

    def close(self) -> None:
        """Stop every child still running and close the logs."""
        for name in list(self.procs):
            self.stop(name, grace_s=5.0)
        for f in self._logs:
            f.close()

    def report(self) -> dict[str, Any]:
        """Per child: pid, exit code and whether it had to be killed."""
        return {n: {"pid": p.pid, "exit_code": self.exit_codes.get(n, p.returncode),
                    "killed": n in self.killed} for n, p in self.procs.items()}  # fmt: skip


_END_WITHOUT_FINALISING = [False]


def end_without_finalising() -> None:
    """Called by a command whose clean stop is complete (every output flushed, its bus session
    closed): the ``auvgw`` entry point (:func:`auvgw.cli.entry`) then ends the process with
    ``os._exit``, without the interpreter's finalisation."""
    _END_WITHOUT_FINALISING[0] = True


def ending_without_finalising() -> bool:
    """Whether :func:`end_without_finalising` was called."""
    return _END_WITHOUT_FINALISING[0]
