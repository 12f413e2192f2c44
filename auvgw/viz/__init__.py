"""Rerun visualisation: the logger (Rerun only), the shipped blueprint and the bus stage.

``auvgw.viz.logger.RerunLogger`` takes plain arrays and device times and never blocks its caller;
``auvgw.viz.blueprint.default_blueprint`` is the layout sent with every recording;
``auvgw.viz.stage.VizStage`` maps bus envelopes to logger calls. See ``docs/viz.md``.

The names below load lazily, so ``import auvgw.viz.options`` (the CLI) does not import the
Rerun SDK (about 0.8 s).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what the names below are, for type checkers (loaded lazily at run time)
    from auvgw.viz.blueprint import VIEW_NAMES, default_blueprint
    from auvgw.viz.entities import TIMELINE
    from auvgw.viz.logger import LoggerStats, RerunLogger
    from auvgw.viz.options import VizOptions

__all__ = [
    "TIMELINE",
    "VIEW_NAMES",
    "LoggerStats",
    "RerunLogger",
    "VizOptions",
    "default_blueprint",
]

_WHERE = {
    "TIMELINE": "auvgw.viz.entities",
    "VIEW_NAMES": "auvgw.viz.blueprint",
    "default_blueprint": "auvgw.viz.blueprint",
    "LoggerStats": "auvgw.viz.logger",
    "RerunLogger": "auvgw.viz.logger",
    "VizOptions": "auvgw.viz.options",
}


def __getattr__(name: str) -> object:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'auvgw.viz' has no attribute {name!r}")
