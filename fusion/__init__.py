"""Navigation fusion: attitude (INS, AHRS, DVL compass) + DVL (+ pressure depth, position
fixes) dead reckoning with learned DVL noise, time alignment, frames, lever arms, diagnostics and
DVL calibration. See ``docs/fusion.md``.

Algorithms only: no transports, no Zenoh, no Rerun. The same :class:`NavFilter` serves the bus
stage (online, ``auvgw.stages.fusion``) and :func:`run_filter` (offline, recordings or arrays);
:mod:`auvgw.fusion.adapters` turns decoded HN-100 and PD0 messages into its samples and maps the
device clocks onto the host clock.
"""

from auvgw.fusion import offline
from auvgw.fusion.config import DvlMount, FusionConfig, InitialState
from auvgw.fusion.diagnostics import FusionDiagnostics
from auvgw.fusion.ekf import STATE_NAMES, DeadReckoningEKF
from auvgw.fusion.navfilter import FusionStats, NavFilter
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.fusion.offline import *  # noqa: F403 - its __all__ joins ours
from auvgw.fusion.samples import AttitudeSample, DepthSample, DvlSample, InsSample, PositionFix

__all__ = [
    "STATE_NAMES",
    "AttitudeSample",
    "DeadReckoningEKF",
    "DepthSample",
    "DvlMount",
    "DvlSample",
    "FusionConfig",
    "FusionDiagnostics",
    "FusionStats",
    "InitialState",
    "InsSample",
    "MotionIncrement",
    "NavFilter",
    "Odometry",
    "PositionFix",
]
__all__ += offline.__all__

if __name__ != "auvgw.fusion":
    raise ImportError(f"import auvgw.fusion, not {__name__}: the folder is mapped (setup.py)")
