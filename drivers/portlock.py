"""Exclusive locks on serial devices (ttys, ptys), and who holds one.

The same lock as pyserial's ``exclusive=True``: ``flock(LOCK_EX | LOCK_NB)`` on the device, so a
serial transport (pyserial's lock) and an SLCAN adapter (:class:`PortLock`, taken on a file
descriptor of its own before python-can opens the port and writes its first command) exclude
each other and themselves across processes. The lock is advisory: a program that takes none
(``cat``, a python-can script) can still open the device; ``TIOCEXCL`` is not used because an
emulated port keeps its own slave descriptor open, so the flag would outlive the gateway (a
gateway killed with SIGKILL would lock its successor out).

:func:`lock_holder` names the process holding a device's lock, from ``/proc/locks``.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from pathlib import Path

__all__ = ["PortLock", "PortLockedError", "lock_holder"]


class PortLockedError(OSError):
    """Another process holds the device's exclusive lock; the message names the device and,
    where ``/proc/locks`` tells, the holder (pid and command line)."""

    def __str__(self) -> str:
        return str(self.strerror)


def _cmdline(pid: int) -> str:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return ""
    text = " ".join(raw.decode(errors="replace").replace("\0", " ").split())  # one line
    return text if len(text) <= 100 else text[:97] + "..."


def lock_holder(path: str | os.PathLike[str]) -> str | None:
    """``"pid N (command line)"`` of a process holding a ``flock`` on the device at ``path``
    (a symlink is followed), or None when none is found (no lock, or no ``/proc/locks``)."""
    try:
        st = os.stat(path)
        locks = Path("/proc/locks").read_text()
    except OSError:
        return None
    want = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    me = os.getpid()
    for line in locks.splitlines():
        # "1: FLOCK  ADVISORY  WRITE 1234 00:1a:10 0 EOF" (a blocked waiter has "->" after "1:")
        parts = line.split()
        if len(parts) < 6 or parts[1] != "FLOCK":
            continue
        try:
            pid = int(parts[4])
            major, minor, inode = parts[5].split(":")
            key = (int(major, 16), int(minor, 16), int(inode))
        except ValueError:
            continue
        if key == want:
            cmd = _cmdline(pid)
            mine = " (this process)" if pid == me else ""
            return f"pid {pid}{mine}" + (f" ({cmd})" if cmd else "")
    return None


class PortLock:
    """An exclusive ``flock`` on a device, held on a descriptor of its own until
    :meth:`release`. Raises :class:`PortLockedError` (naming the holder) when another open of
    the device holds it, ``OSError`` when the device cannot be opened."""

    def __init__(self, path: str) -> None:
        self.path = path
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK | os.O_CLOEXEC)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            holder = lock_holder(path)
            who = f"held by {holder}" if holder else "held by another process (lsof the path)"
            raise PortLockedError(exc.errno, f"{path} is locked for exclusive use, {who}") from None
        self._fd: int | None = fd

    def release(self) -> None:
        """Drop the lock (closing its descriptor); safe to call more than once."""
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)
