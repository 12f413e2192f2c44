"""Child processes of a test (gateway, router, subscriber), their output, and free ports.

Every child process is started through :class:`Procs` (the ``procs`` fixture of
``tests/conftest.py``), which stops what is still running when the test ends, whatever
happened (:func:`auvgw.ground.procs.stop_process`).
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from auvgw.ground.procs import endpoint, free_port, stop_process

__all__ = [
    "AUVGW",
    "PYTHON",
    "REPO",
    "SUBSCRIBER",
    "Proc",
    "Procs",
    "endpoint",
    "free_port",
    "run_demo_processes",
    "uart_overruns",
]

#: the repository (this file is tests/support/processes.py)
REPO = Path(__file__).resolve().parents[2]
VENV_BIN = REPO / ".venv" / "bin"
AUVGW = str(VENV_BIN / "auvgw")
PYTHON = str(VENV_BIN / "python")
SUBSCRIBER = str(REPO / "tests" / "gateway_subscriber_proc.py")


class Proc:
    """A child process whose stdout lines are collected by a thread (stderr goes to a file)."""

    def __init__(
        self, args: list[str], log: Path, env: dict[str, str] | None = None, cwd: Path = REPO
    ) -> None:
        self.args = args
        self.log = log
        self._err = open(log, "wb")  # noqa: SIM115 - closed in stop()
        self.p = subprocess.Popen(
            args,
            stdout=subprocess.PIPE,
            stderr=self._err,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            cwd=cwd,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.all_lines: list[str] = []
        self._t = threading.Thread(target=self._pump, daemon=True)
        self._t.start()

    def _pump(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.all_lines.append(line.rstrip("\n"))
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, prefix: str, timeout: float = 30.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or (self.p.poll() is not None and self.lines.empty()):
                raise AssertionError(
                    f"{self.args[:3]}: no line starting {prefix!r} (exit {self.p.poll()}); "
                    f"stderr:\n{self.stderr()}"
                )
            try:
                line = self.lines.get(timeout=min(left, 0.2))
            except queue.Empty:
                continue
            if line.startswith(prefix):
                return line

    def stderr(self) -> str:
        if not self._err.closed:
            self._err.flush()
        return self.log.read_text(errors="replace")[-4000:]

    def signal(self, sig: int = signal.SIGTERM) -> None:
        if self.p.poll() is None:
            self.p.send_signal(sig)

    def wait(self, timeout: float = 30.0) -> int:
        """The exit code; an AssertionError naming where the process is stuck (its Python
        stacks by ``py-spy dump``) and its stderr when it has not exited within ``timeout`` s."""
        try:
            rc = self.p.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.args[:2]} still running {timeout:g} s on:\n"
                                 f"{self.stacks()}\nstderr:\n{self.stderr()}") from None
        self._t.join(5)
        return rc

    def stacks(self) -> str:
        """Every thread's Python stack now (``py-spy dump``; what went wrong if it cannot)."""
        try:
            res = subprocess.run([str(VENV_BIN / "py-spy"), "dump", "--pid", str(self.p.pid)],
                                 capture_output=True, text=True, timeout=30)  # fmt: skip
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"(no stacks: {exc})"
        return res.stdout[-6000:] or f"(no stacks: {res.stderr.strip()[-500:]})"

    def stop(self) -> int | None:
        """Terminate (then kill) if still running; returns the exit code."""
        code, _ = stop_process(self.p, signal.SIGTERM, 10.0)
        self._err.close()
        return code


class Procs:
    """Starts child processes and stops them all at the end (the tests' fixture)."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[Proc] = []

    def start(
        self, args: list[str], name: str, env: dict[str, str] | None = None, cwd: Path = REPO
    ) -> Proc:
        """Start ``args`` (in ``cwd``, the repository by default); stderr to ``<name>.stderr``."""
        p = Proc(args, self.tmp / f"{name}.stderr", env, cwd)
        self.procs.append(p)
        return p

    def gateway(self, config: Path, name: str = "gateway", *extra: str) -> Proc:
        return self.start([AUVGW, "-v", "run", "--config", str(config), *extra], name)

    def subscriber(self, name: str = "subscriber", *args: str) -> Proc:
        return self.start([PYTHON, SUBSCRIBER, *args], name)

    def stop_all(self) -> None:
        for p in reversed(self.procs):
            p.stop()


def run_demo_processes(
    out: Path,
    scenario: str,
    duration_s: float,
    speed: float,
    timeout_s: float,
    viz: bool = False,
) -> tuple[int, str, dict[str, Any]]:
    """``auvgw demo --processes --scenario S`` into ``out``, waited for up to ``timeout_s``:
    (the demo's pid, its output, its ``summary.json``); it must exit 0. Without ``viz``,
    ``--no-viz``; with it the gateway records ``out/demo.rrd``."""
    demo = subprocess.Popen(
        [sys.executable, "-m", "auvgw", "demo", "--processes", "--scenario", scenario,
         "--duration", str(duration_s), "--speed", str(speed), "--out", str(out),
         *([] if viz else ["--no-viz"])],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        stdout, _ = demo.communicate(timeout=timeout_s)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    assert demo.returncode == 0, stdout
    return demo.pid, stdout, json.loads((out / "summary.json").read_text())


def uart_overruns(sim_log: Path) -> dict[str, int]:
    """Bytes each emulated port dropped because its host did not read it in time (``auvgw sim``'s
    end-of-run table, "dropped bytes"; a UART overrun, :mod:`auvgw.sim_devices.ports`), by
    channel name. A frame the overrun cut is a bad frame at the gateway, rightly: on a loaded
    machine a test allows bad frames only on a port that overran."""
    rows = re.finditer(r"^\s+(\S+)\s+samples\s+\d+\s+sent\s+\d+\s+bytes\s+\d+\s+dropped bytes"
                       r"\s+(\d+)", sim_log.read_text(errors="replace"), re.MULTILINE)  # fmt: skip
    return {m[1]: int(m[2]) for m in rows}

