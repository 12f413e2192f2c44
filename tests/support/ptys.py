"""Pty devices: an emulated serial port behind a stable symlink that can be unplugged."""

from __future__ import annotations

import contextlib
import os
import tty
from pathlib import Path

__all__ = ["PtyDevice"]


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
