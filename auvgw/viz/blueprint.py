"""The default Rerun layout shipped with auvgw: map, sonar fan, swath/bathymetry, time series.

Sent with every recording (file or live viewer), so a new user sees everything arranged:

* **Map** (2-D, ``map/**``): trajectories (accumulated from the start of the run to the time
  cursor), current poses with 2-sigma ellipses, landmarks and lines with their ellipses,
  particles and, underneath, the gridded mean depth (one disc per cell in depth colours).
* **Swath & bathymetry** (3-D, ``world/**``, NED): every multibeam sounding coloured by depth
  (accumulated), the 3-D trajectories, the vehicle frame with its magnetic field arrow.
* **GeoSwath raw ping** (2-D, ``raw_ping/**``, under the swath view once a GeoSwath ping came):
  the latest ping of each side, slant range (m, down) against return angle (deg, port
  negative), one point per sample coloured by amplitude.
* **Sonar fan** (2-D, ``sonar/**``): the MSIS scan accumulated over the current sweep, with
  range rings and the vehicle at the centre.
* **INS attitude**, **DVL**, **Magnetometer**: time series over a window before the cursor, one
  unit per axis (flags on their own), units in the view names.
* **Health** (tabs): message rates, age and silence, transport lag, connection flags, the
  fusion's checks, one series per device in one colour across the tabs; the cumulative counters
  as a table (text); the events.

Accumulation is a per-entity visible time range (``-inf .. cursor``) on the ``sensor_time``
timeline; entity overrides cannot use wildcards, so the layout names every trajectory it
accumulates (:func:`default_blueprint` ``tracks``); the logger re-sends the layout when a new
trajectory appears.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import rerun.blueprint as rrb

from auvgw.viz.entities import (
    APPLICATION_ID,
    DVL_ALTITUDE,
    DVL_BOTTOM_LOCK,
    DVL_VELOCITY,
    HEALTH_COUNTERS,
    HEALTH_GROUPS,
    INS_ATTITUDE,
    INS_HEADING,
    MAG_CHANGE,
    MAG_MAGNITUDE,
    MAP,
    MAP_BATHYMETRY,
    PILOT_VIEWS,
    RAW_PING,
    SONAR,
    SOUNDINGS,
    TIMELINE,
    WORLD,
    map_path,
    world_path,
)

if TYPE_CHECKING:
    from rerun.datatypes import EntityPath

__all__ = ["DEFAULT_TRACKS", "RAW_PING_VIEW", "VIEW_NAMES", "default_blueprint", "save_blueprint"]

#: the trajectories every layout accumulates (SLAM pipelines are added as they appear)
DEFAULT_TRACKS: tuple[str, ...] = ("truth", "dead_reckoning")

#: view names of the default layout, in reading order (units in the names: one per axis)
VIEW_NAMES: tuple[str, ...] = (
    "Map (m; labels: tracks, landmark ids)",
    "Swath & bathymetry (NED m, colour = depth)",
    "Sonar fan (rings every quarter range)",
    "Roll & pitch (deg)",
    "Heading (deg)",
    "DVL velocity (m/s)",
    "Altitude (m)",
    "Bottom lock (1 = locked)",
    "Magnetic field minus its 10 s mean (nT)",
    "|B| (nT)",
    "Message rate (Hz)",
    "Age of newest sample & silence (s)",
    "Transport lag (s)",
    "Connected & stale (1 = yes)",
    "Fusion checks (share, NIS/dof)",
    "Fusion DVL noise (m/s)",
    "Counters",
    "Events",
)

#: the GeoSwath raw-ping view (in the layout once a raw ping was logged)
RAW_PING_VIEW = (
    "GeoSwath raw ping (x: return angle deg, port < 0; y: slant range m; colour: amplitude)"
)

#: the health views' origins, in the order of VIEW_NAMES[10:16] (health/<group>)
_HEALTH_VIEWS = tuple(f"health/{g}" for g in HEALTH_GROUPS)


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
    fan_pixels: int = 256,
    raw_ping: bool = False,
) -> rrb.Blueprint:
    """The auvgw layout; ``tracks`` are the trajectory names whose line strips accumulate
    (``truth``, ``dead_reckoning``, ``slam/<pipeline>``); time series show the last
    ``series_window_s`` seconds before the cursor; the sonar view frames the fan image
    (``fan_pixels`` square); ``raw_ping`` puts the GeoSwath raw-ping view under the swath."""
    names = list(dict.fromkeys([*DEFAULT_TRACKS, *tracks]))
    fan = (0.0, float(fan_pixels))
    history = _history(timeline)
    map_overrides: dict[EntityPath | str, rrb.VisibleTimeRanges] = {
        map_path(n, "track"): history for n in names
    }
    map_overrides[MAP_BATHYMETRY] = history
    world_overrides: dict[EntityPath | str, rrb.VisibleTimeRanges] = {
        world_path(n, "track"): history for n in names
    }
    world_overrides[SOUNDINGS] = history
    window = _window(timeline, series_window_s)
    legend = rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop, visible=True)
    no_legend = rrb.PlotLegend(visible=False)  # one series, or the name says which is which

    def series(i: int, origin: str, *, key: bool = True, **kw: object) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=VIEW_NAMES[i], origin=origin, time_ranges=window,
                                  plot_legend=legend if key else no_legend, **kw)  # type: ignore[arg-type]  # fmt: skip

    health = [
        rrb.TimeSeriesView(name=VIEW_NAMES[10 + i], origin=o, plot_legend=legend)
        for i, o in enumerate(_HEALTH_VIEWS)
    ]
    swath: rrb.Spatial3DView | rrb.Vertical = rrb.Spatial3DView(
        name=VIEW_NAMES[1], origin=WORLD, overrides=world_overrides
    )
    if raw_ping:  # the raw samples beside the swath they make
        swath = rrb.Vertical(swath, rrb.Spatial2DView(name=RAW_PING_VIEW, origin=RAW_PING,
                                                      background=[0, 0, 0]), row_shares=[1.6, 1.0])
    views = rrb.Vertical(
        rrb.Horizontal(
            rrb.Spatial2DView(
                name=VIEW_NAMES[0], origin=MAP, overrides=map_overrides, background=[20, 24, 32]
            ),
            swath,
            rrb.Spatial2DView(
                name=VIEW_NAMES[2],
                origin=SONAR,
                background=[0, 0, 0],
                visual_bounds=rrb.VisualBounds2D(x_range=fan, y_range=fan),
            ),
            column_shares=[2.2, 2.0, 1.2],
        ),
        rrb.Horizontal(
            # degrees of roll/pitch and of heading, m/s, metres and flags: never on one axis
            rrb.Vertical(series(3, INS_ATTITUDE), series(4, INS_HEADING, key=False)),
            rrb.Vertical(
                series(5, DVL_VELOCITY),
                series(6, DVL_ALTITUDE, key=False),
                series(
                    7,
                    DVL_BOTTOM_LOCK,
                    key=False,
                    axis_y=rrb.ScalarAxis(range=(-0.1, 1.1), zoom_lock=True),
                ),
                row_shares=[2.0, 1.0, 1.0],
            ),
            rrb.Vertical(series(8, MAG_CHANGE), series(9, MAG_MAGNITUDE, key=False)),
            rrb.Tabs(
                *health,
                rrb.TextDocumentView(name=VIEW_NAMES[16], origin=HEALTH_COUNTERS),
                rrb.TextLogView(name=VIEW_NAMES[17], origin="health"),
                *(rrb.TimeSeriesView(name=n, origin=o, time_ranges=window, plot_legend=legend)
                  for o, n in PILOT_VIEWS.items()),  # only the closed loop fills them
            ),
            column_shares=[1.0, 1.0, 1.0, 1.4],
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
