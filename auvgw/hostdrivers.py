"""Host drivers: the exchanges a device needs from its host (e.g. the Tritech MSIS is polled).

A host driver sits beside a device's reader in the gateway. It never reads the port itself: the
gateway calls it on connect, for every decoded message and when the port has been idle for a
read timeout, and hands it ``write`` (the transport's write) and ``now`` (``time.monotonic()``,
seconds) so it stays testable without a port or a clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from auvgw.config.gateway import DeviceConfig

__all__ = ["HostDriver", "Write", "make_host_driver"]

#: sends bytes to the device (the transport's ``write``)
Write = Callable[[bytes], None]


class HostDriver(Protocol):
    """What the gateway calls; every method may write to the device."""

    def on_connect(self, write: Write, now: float) -> None:
        """The transport has just been (re)opened; start the exchange from the beginning."""

    def on_message(self, msg: Any, write: Write, now: float) -> None:
        """A message decoded from the device."""

    def on_idle(self, write: Write, now: float) -> None:
        """Called after every read, data or not (``now``: monotonic s); resend on timeout."""


def make_host_driver(cfg: DeviceConfig) -> HostDriver | None:
    """The host driver a device's format needs, or None for devices that stream on their own."""
    if cfg.format == "seanet":
        from auvgw.msis_host import SeaNetHost

        assert cfg.msis is not None  # DeviceConfig fills it for seanet
        return SeaNetHost(cfg.msis)
    return None
