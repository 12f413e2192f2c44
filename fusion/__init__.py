"""Navigation fusion: INS + DVL (+ pressure depth) dead reckoning, time alignment, frames and
lever arms. See ``docs/fusion.md``.

Algorithms only: no transports, no Zenoh, no Rerun. The same :class:`NavFilter` serves the bus
stage (online) and :func:`run_filter` (offline, recordings or arrays).
"""

from auvgw.fusion.config import DvlMount, FusionConfig, InitialState
from auvgw.fusion.ekf import STATE_NAMES, DeadReckoningEKF
from auvgw.fusion.navfilter import FusionStats, NavFilter
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.fusion.offline import (
    OdometryArrays,
    depth_from_arrays,
    dvl_from_arrays,
    ins_from_arrays,
    iter_filter,
    run_filter,
    run_filter_arrays,
)
from auvgw.fusion.samples import DepthSample, DvlSample, InsSample

__all__ = [
    "STATE_NAMES",
    "DeadReckoningEKF",
    "DepthSample",
    "DvlMount",
    "DvlSample",
    "FusionConfig",
    "FusionStats",
    "InitialState",
    "InsSample",
    "MotionIncrement",
    "NavFilter",
    "Odometry",
    "OdometryArrays",
    "depth_from_arrays",
    "dvl_from_arrays",
    "ins_from_arrays",
    "iter_filter",
    "run_filter",
    "run_filter_arrays",
]
