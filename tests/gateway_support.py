"""Helpers of the gateway tests: free ports, pty devices behind a symlink, child processes.

Every child process is started through :class:`Procs` (a fixture in the tests) which kills
what is still running when the test ends, whatever happened.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VENV_BIN = REPO / ".venv" / "bin"
AUVGW = str(VENV_BIN / "auvgw")
PYTHON = str(VENV_BIN / "python")
SUBSCRIBER = str(Path(__file__).with_name("gateway_subscriber_proc.py"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def wait_until(pred, timeout: float = 60.0, interval: float = 0.05, what: str = "condition"):
    """Poll ``pred`` until it returns a truthy value; fail with ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


class PtyDevice:
    """An emulated serial device: a raw pty whose slave is reached through a stable symlink.

    ``unplug()`` closes the pty (the reader sees the device vanish) and removes the symlink;
    ``plug()`` creates a fresh pty behind the same symlink, as a USB adapter coming back.
    """

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master: int | None = None
        self.slave: int | None = None
        self.plug()

    def plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self.master, self.slave = master, slave
        tmp = self.link.with_name(self.link.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self.master, self.slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = None

    def write(self, data: bytes) -> None:
        assert self.master is not None, "device unplugged"
        view = memoryview(data)
        while view:
            n = os.write(self.master, view)
            view = view[n:]

    def close(self) -> None:
        self.unplug()


class Proc:
    """A child process whose stdout lines are collected by a thread (stderr goes to a file)."""

    def __init__(self, args: list[str], log: Path, env: dict[str, str] | None = None) -> None:
        self.args = args
        self.log = log
        self._err = open(log, "wb")  # noqa: SIM115 - closed in stop()
        self.p = subprocess.Popen(
            args,
            stdout=subprocess.PIPE,
            stderr=self._err,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            cwd=REPO,
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
        rc = self.p.wait(timeout)
        self._t.join(5)
        return rc

    def stop(self) -> int | None:
        """Terminate (then kill) if still running; returns the exit code."""
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(10)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self._err.close()
        return self.p.returncode


class Procs:
    """Starts child processes and stops them all at the end (the tests' fixture)."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[Proc] = []

    def start(self, args: list[str], name: str, env: dict[str, str] | None = None) -> Proc:
        p = Proc(args, self.tmp / f"{name}.stderr", env)
        self.procs.append(p)
        return p

    def gateway(self, config: Path, name: str = "gateway", *extra: str) -> Proc:
        return self.start([AUVGW, "-v", "run", "--config", str(config), *extra], name)

    def subscriber(self, name: str = "subscriber", *args: str) -> Proc:
        return self.start([PYTHON, SUBSCRIBER, *args], name)

    def stop_all(self) -> None:
        for p in reversed(self.procs):
            p.stop()


def write_gateway_toml(
    path: Path,
    vehicle: str,
    bus: dict,
    devices: dict[str, dict],
    status_period_s: float = 0.2,
) -> Path:
    """A gateway TOML (written with json-compatible inline values)."""
    lines = [
        f"vehicle = {json.dumps(vehicle)}",
        f"status_period_s = {status_period_s}",
        "",
        "[bus]",
    ]
    lines += [f"{k} = {json.dumps(v)}" for k, v in bus.items()]
    for name, dev in devices.items():
        lines += ["", f"[devices.{name}]"]
        for k, v in dev.items():
            if isinstance(v, dict):
                inner = ", ".join(f"{ik} = {json.dumps(iv)}" for ik, iv in v.items())
                lines.append(f"{k} = {{ {inner} }}")
            else:
                lines.append(f"{k} = {json.dumps(v)}")
    path.write_text("\n".join(lines) + "\n")
    return path


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def pd0_frames(shared_data: Path, n: int | None = None) -> list[bytes]:
    """Verified PD0 ensembles of the real Workhorse file, as bytes."""
    from auvgw.drivers.formats import get_format

    frames, _ = get_format("pd0").frames_of_file(shared_data / "pd0" / "RDI_withBT.000")
    out = [f.data for f in frames]
    return out[:n] if n is not None else out


def local_decoded(frames: list[bytes]) -> list[dict]:
    """What the gateway should publish for these frames, decoded here (JSON-normalised)."""
    from auvgw.drivers.formats import get_format
    from auvgw.drivers.spec import to_jsonable

    fmt = get_format("pd0")
    return [json.loads(json.dumps(to_jsonable(m))) for f in frames for m in fmt.decode(f)]


if __name__ == "__main__":  # pragma: no cover - manual use
    sys.exit("helpers only")


def frame_counters(seqs: list[int]) -> list[int]:
    """The per-device frame counters of raw sequence numbers (``session_id << 32 | n``), after
    checking they all carry the same non-zero gateway session id."""
    sessions = {s >> 32 for s in seqs}
    assert len(sessions) <= 1 and 0 not in sessions, sessions
    return [s & 0xFFFFFFFF for s in seqs]
