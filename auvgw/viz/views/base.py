"""The base of a Rerun view: what one thing shown owns (entity paths, state, logging code)."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

from auvgw.viz.options import VizOptions
from auvgw.viz.scene import Scene

__all__ = ["View"]


class View:
    """One thing shown in the recording (a trajectory, the sonar fan, a device's health...).

    A view gives :attr:`kind` (the name its :class:`~auvgw.viz.logger.RerunLogger` calls are
    queued under), ``log(...)`` (one call's values, on the logging thread) and, when it holds
    data back, :meth:`flush`. Its entity paths, its state and its logging code are its own;
    what views share (the recording's time, batched streams, the map, the depth scale, the
    vehicle frame) is the :class:`~auvgw.viz.scene.Scene`.
    """

    #: the logger's name for this view's calls (its row in :data:`auvgw.viz.views.VIEWS`)
    kind: ClassVar[str] = ""
    #: one queued call's values, on the logging thread
    log: Callable[..., None]

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.options: VizOptions = scene.options

    def flush(self, final: bool, t_last: float) -> None:
        """Send what is held back (every ``flush_period_s`` of device time; ``final`` at the
        end); ``t_last``: the newest data time (s)."""
