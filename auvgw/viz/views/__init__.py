"""The Rerun logger's views, one small class each (:class:`~auvgw.viz.views.base.View`), and
:data:`VIEWS`, the logger's table of them.

A new view is one class (its entity paths, state and logging code) plus one row here and the
:class:`~auvgw.viz.logger.RerunLogger` method that queues its calls.
"""

from __future__ import annotations

from auvgw.viz.views.base import View
from auvgw.viz.views.bathymetry import Dem, Seabed, Swath
from auvgw.viz.views.health import Event, Health, Series
from auvgw.viz.views.map import AcousticBeacon, Landmarks, Lines, Particles, Ranges, Trajectory
from auvgw.viz.views.sensors import Attitude, Dvl, Magnetometer, RawPing, Sonar

__all__ = ["VIEWS", "View"]

#: every view, in flush order (the trajectories first: their segments widen the map's grid)
VIEWS: tuple[type[View], ...] = (
    Trajectory,
    Landmarks,
    Lines,
    Particles,
    Ranges,
    AcousticBeacon,
    Attitude,
    Dvl,
    Magnetometer,
    Sonar,
    RawPing,
    Swath,
    Seabed,
    Dem,
    Health,
    Series,
    Event,
)
