"""Emulators run in a test: a pyserial reader on an emulator's pty (:class:`SerialReader`), a
run of a :class:`~auvgw.sim_devices.runner.Runner` to its end (:func:`run_for`) and a device's
port by name (:func:`endpoint`), shared by tests/sim_devices/test_emulators.py and the device
tests that run one emulator."""

from __future__ import annotations

import threading
import time

import serial

from auvgw.sim_devices.emulator import CanChannel, Endpoint
from auvgw.sim_devices.runner import Runner

__all__ = ["SerialReader", "endpoint", "run_for"]


class SerialReader:
    """pyserial on a pty in a thread; reconnects (to the symlink) after an unplug."""

    def __init__(self, path: str, baud: int, reconnect: bool = False) -> None:
        self.path = path
        self.baud = baud
        self.reconnect = reconnect
        self.chunks: list[bytes] = []
        self.disconnects = 0
        self._stop = threading.Event()
        self._s = serial.Serial(path, baud, timeout=0.02)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._s.read(max(1, self._s.in_waiting))
            except (serial.SerialException, OSError):
                self.disconnects += 1
                self._s.close()
                if not self.reconnect:
                    return
                while not self._stop.is_set():
                    try:
                        self._s = serial.Serial(self.path, self.baud, timeout=0.02)
                        break
                    except (serial.SerialException, OSError):
                        time.sleep(0.002)
                continue
            if data:
                self.chunks.append(data)

    def data(self) -> bytes:
        return b"".join(self.chunks)

    def finish(self, quiet: float = 1.0, timeout: float = 10.0) -> bytes:
        """Wait until nothing arrived for ``quiet`` s, stop, return every byte."""
        end = time.monotonic() + timeout
        n = -1
        while time.monotonic() < end:
            if len(self.chunks) == n:
                break
            n = len(self.chunks)
            time.sleep(quiet)
        self._stop.set()
        self._thread.join(5)
        self._s.close()
        return self.data()

    def write(self, data: bytes) -> None:
        self._s.write(data)


def run_for(runner: Runner, duration: float) -> None:
    # python-can returns from Bus() once it wrote 'O'; the adapter may not have read it yet
    end = time.monotonic() + 10
    for em in runner.emulators.values():
        for ch in em.channels:
            while isinstance(ch, CanChannel) and not ch.adapter.is_open and time.monotonic() < end:
                time.sleep(0.005)
    runner.start(duration=duration)
    assert runner.wait(60), "the run did not end"
    runner.stop()
    runner.flush()


def endpoint(runner: Runner, name: str) -> Endpoint:
    return next(ep for ep in runner.endpoints() if ep.name == name)
