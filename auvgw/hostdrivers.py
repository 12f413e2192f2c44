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
from auvgw.drivers import registry

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
    """The host driver a device's format needs (the registry's ``host_driver``, made from the
    device's configuration), or None for devices that stream on their own."""
    if cfg.format == registry.CAN_FORMAT:
        return None
    target = registry.device(cfg.format).host_driver
    if target is None:
        return None
    driver: HostDriver = registry.load(target)(cfg)
    return driver
