"""The default Rerun layout shipped with auvgw: map, sonar fan, swath/bathymetry, time series.

Sent with every recording (file or live viewer), so a new user sees everything arranged:

* **Map** (2-D, ``map/**``): trajectories (accumulated from the start of the run to the time
  cursor), current poses with 2-sigma ellipses, landmarks and lines with their ellipses,
  particles and, underneath, the gridded mean depth (one disc per cell in depth colours).
* **Swath & bathymetry** (3-D, ``world/**``, NED): every multibeam sounding coloured by depth
  (accumulated), the 3-D trajectories, the vehicle frame with its magnetic field arrow.
* **Sonar fan** (2-D, ``sonar/**``): the MSIS scan accumulated over the current sweep.
* **INS attitude**, **DVL**, **Magnetometer**: time series over a window before the cursor.
* **Device health** and **Events**: per-device counters and text events.

Accumulation is a per-entity visible time range (``-inf .. cursor``) on the ``sensor_time``
timeline; entity overrides cannot use wildcards, so the layout names every trajectory it
accumulates (:func:`default_blueprint` ``tracks``); the logger re-sends the layout when a new
trajectory appears.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import rerun.blueprint as rrb

from auvgw.viz.entities import (
    APPLICATION_ID,
    DVL_ALTITUDE,
    INS_ATTITUDE,
    INS_HEADING,
    MAP,
    MAP_BATHYMETRY,
    SONAR,
    SOUNDINGS,
    TIMELINE,
    WORLD,
    map_path,
    world_path,
)

__all__ = ["DEFAULT_TRACKS", "VIEW_NAMES", "default_blueprint", "save_blueprint"]

#: the trajectories every layout accumulates (SLAM pipelines are added as they appear)
DEFAULT_TRACKS: tuple[str, ...] = ("truth", "dead_reckoning")

#: view names of the default layout, in reading order
VIEW_NAMES: tuple[str, ...] = (
    "Map",
    "Swath & bathymetry",
    "Sonar fan",
    "Roll & pitch",
    "Heading",
    "DVL velocity",
    "Altitude",
    "Magnetometer",
    "Device health",
    "Events",
)


def _history(timeline: str) -> rrb.VisibleTimeRanges:
    """Everything from the start of the timeline up to the time cursor."""
    return rrb.VisibleTimeRanges(
        timeline=timeline,
        start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )


def _window(timeline: str, seconds: float) -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        timeline,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )


def default_blueprint(
    tracks: Iterable[str] = DEFAULT_TRACKS,
    *,
    timeline: str = TIMELINE,
    series_window_s: float = 120.0,
) -> rrb.Blueprint:
    """The auvgw layout; ``tracks`` are the trajectory names whose line strips accumulate
    (``truth``, ``dead_reckoning``, ``slam/<pipeline>``); time series show the last
    ``series_window_s`` seconds before the cursor."""
    names = list(dict.fromkeys([*DEFAULT_TRACKS, *tracks]))
    history = _history(timeline)
    map_overrides = {map_path(n, "track"): history for n in names}
    map_overrides[MAP_BATHYMETRY] = history
    world_overrides = {world_path(n, "track"): history for n in names}
    world_overrides[SOUNDINGS] = history
    window = _window(timeline, series_window_s)
    views = rrb.Vertical(
        rrb.Horizontal(
            rrb.Spatial2DView(name=VIEW_NAMES[0], origin=MAP, overrides=map_overrides),
            rrb.Spatial3DView(name=VIEW_NAMES[1], origin=WORLD, overrides=world_overrides),
            rrb.Spatial2DView(name=VIEW_NAMES[2], origin=SONAR, background=[0, 0, 0]),
            column_shares=[2.0, 2.0, 1.4],
        ),
        rrb.Horizontal(
            # degrees of roll/pitch and of heading, m/s and metres: never on one axis
            rrb.Vertical(
                rrb.TimeSeriesView(name=VIEW_NAMES[3], origin=INS_ATTITUDE, time_ranges=window),
                rrb.TimeSeriesView(name=VIEW_NAMES[4], origin=INS_HEADING, time_ranges=window),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(
                    name=VIEW_NAMES[5],
                    origin="dvl",
                    contents=["+ $origin/**", f"- {DVL_ALTITUDE}"],
                    time_ranges=window,
                ),
                rrb.TimeSeriesView(name=VIEW_NAMES[6], origin=DVL_ALTITUDE, time_ranges=window),
            ),
            rrb.TimeSeriesView(name=VIEW_NAMES[7], origin="mag", time_ranges=window),
            rrb.Tabs(
                rrb.TimeSeriesView(name=VIEW_NAMES[8], origin="health"),
                rrb.TextLogView(name=VIEW_NAMES[9], origin="health"),
            ),
        ),
        row_shares=[3.0, 2.0],
    )
    # follow the newest data: live, the vehicle now; from a file, the whole run
    time_panel = rrb.TimePanel(state="collapsed", timeline=timeline, play_state="following")
    return rrb.Blueprint(views, time_panel, collapse_panels=True)


def save_blueprint(
    path: str | Path,
    tracks: Iterable[str] = DEFAULT_TRACKS,
    application_id: str = APPLICATION_ID,
) -> Path:
    """Write the layout as a ``.rbl`` file (open it in the viewer next to a recording)."""
    out = Path(path)
    default_blueprint(tracks).save(application_id, str(out))
    return out
