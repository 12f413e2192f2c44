"""The gateway's in-process listeners: one small notifier instead of hand-wired closures.

Anything in the gateway's process that wants the decoded messages without a Zenoh hop (the
demo's fusion, SLAM and Rerun stages, the daemon's Rerun stage, a recorder, a test) subscribes
a callback ``(device, t_recv_ns, message)``; the gateway calls :meth:`Notifier.notify` once per
frame with the frame's decoded messages. ``t_recv_ns`` is the stamp published with the message
(host receive time, or the vehicle-paced time of the gateway's ``[clock]``).

Listeners run on the device's reader thread, in subscription order: keep them short (queue the
work: :meth:`auvgw.stages.base.Stage.post`). A listener that raises is logged and the others
still run; the gateway never stops a device for a listener's bug.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable

__all__ = ["Listener", "Notifier"]

log = logging.getLogger(__name__)

#: ``(device, t_recv_ns, message)``
Listener = Callable[[str, int, object], object]


class Notifier:
    """Hands each decoded message to every subscribed :data:`Listener`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._listeners: tuple[Listener, ...] = ()  # replaced, never mutated: no lock to read

    def __len__(self) -> int:
        return len(self._listeners)

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Add ``listener`` (after the others); returns the function that removes it."""
        with self._lock:
            self._listeners = (*self._listeners, listener)

        def unsubscribe() -> None:
            with self._lock:
                self._listeners = tuple(x for x in self._listeners if x is not listener)

        return unsubscribe

    def notify(self, device: str, t_recv_ns: int, messages: Iterable[object]) -> int:
        """Every message to every listener; returns how many calls raised (each is logged)."""
        listeners = self._listeners
        failed = 0
        if not listeners:
            return failed
        for msg in messages:
            for listener in listeners:
                try:
                    listener(device, t_recv_ns, msg)
                except Exception:  # a listener's bug must not reopen the device
                    failed += 1
                    log.exception("%s: listener %r failed", device, listener)
        return failed
