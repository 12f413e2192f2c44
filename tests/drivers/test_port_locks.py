"""Every port locked for exclusive use, the SLCAN adapter included (issue 27): a real pty with
an emulated SLCAN adapter behind it, held by python-can's slcan interface in another process;
a second open (SLCAN or serial) is refused with one error naming the port and the holder, and
writes nothing to the adapter (its channel stays open for the holder)."""

from __future__ import annotations

import os
import re
import subprocess

import can
import pytest

from auvgw.drivers.portlock import PortLock, PortLockedError, lock_holder
from auvgw.drivers.transports import TransportOpenError, open_transport
from auvgw.testing import PYTHON, wait_until

pytestmark = pytest.mark.e2e

HOLDER = """
import sys
from auvgw.drivers.transports import open_transport
t = open_transport({"kind": "can", "interface": "slcan", "channel": sys.argv[1],
                    "bitrate": 500000, "options": {"sleep_after_open": 0}})
print("READY", flush=True)
sys.stdin.read()  # until the test closes our stdin
t.close()
"""


def _settled_commands(adapter) -> int:
    """The adapter's command count once two polls in a row see it unchanged (the holder's last
    set-up command may still be in the pty when its channel reads open)."""
    seen: list[int] = []

    def settled() -> bool:
        seen.append(adapter.stats.commands)
        return len(seen) >= 2 and seen[-1] == seen[-2]

    wait_until(settled, 10, what="the holder's set-up commands taken")
    return seen[-1]


def _slcan(path: str) -> dict:
    return {
        "kind": "can",
        "interface": "slcan",
        "channel": path,
        "bitrate": 500000,
        "options": {"sleep_after_open": 0},
    }


@pytest.fixture
def adapter(slcan_adapter):
    return slcan_adapter


def test_an_slcan_adapter_held_by_another_process_is_refused_naming_the_holder(adapter):
    holder = subprocess.Popen(
        [PYTHON, "-c", HOLDER, adapter.device],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().startswith("READY")
        wait_until(lambda: adapter.is_open, 10, what="the holder opened the channel")
        commands = _settled_commands(adapter)  # the holder's set-up may still be in flight
        assert lock_holder(adapter.device) is not None
        assert lock_holder(adapter.device).startswith(f"pid {holder.pid} (")

        with pytest.raises(TransportOpenError) as info:
            open_transport(_slcan(adapter.device))
        msg = str(info.value)
        assert "\n" not in msg
        assert msg.startswith("can slcan") and adapter.device in msg.split(": cannot open: ")[0]
        assert f"cannot open: {adapter.device} is locked for exclusive use" in msg
        assert f"held by pid {holder.pid} (" in msg and "-c" in msg

        # a serial transport (pyserial's exclusive lock) on the same device: the same lock
        with pytest.raises(TransportOpenError) as info:
            open_transport({"kind": "serial", "url": adapter.device, "baud": 115200})
        msg = str(info.value)
        assert re.search(rf"locked for exclusive use by pid {holder.pid} \(", msg), msg

        # the refused opens sent the adapter nothing: the holder's channel is still open
        assert adapter.stats.commands == commands and adapter.is_open
        assert adapter.send(can.Message(arbitration_id=0x10, data=b"\x01", is_extended_id=False))
    finally:
        holder.communicate("", timeout=30)
    assert holder.returncode == 0
    # released with the holder's close: the adapter opens again
    wait_until(lambda: lock_holder(adapter.device) is None, 10, what="lock released")
    t = open_transport(_slcan(adapter.device))
    try:
        wait_until(lambda: adapter.is_open, 10, what="channel reopened")
        assert (lock_holder(adapter.device) or "").startswith(f"pid {os.getpid()} (this process)")
    finally:
        t.close()
    assert lock_holder(adapter.device) is None


def test_port_lock_excludes_a_second_lock_in_the_same_process_and_releases(adapter):
    first = PortLock(adapter.path)
    try:
        with pytest.raises(PortLockedError, match=re.escape(f"{adapter.path} is locked")):
            PortLock(adapter.path)
    finally:
        first.release()
        first.release()  # twice is harmless
    PortLock(adapter.path).release()
    with pytest.raises(FileNotFoundError):
        PortLock(adapter.path + "-missing")
