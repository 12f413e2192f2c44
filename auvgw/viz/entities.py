"""Entity paths of an auvgw recording (one place, shared by the logger, the blueprint and docs).

``map/...`` is the 2-D map (horizontal = east, vertical = north up; see ``docs/viz.md``),
``world/...`` the 3-D scene in NED metres, ``sonar/...`` the MSIS fan image in pixels, and
``ins``, ``dvl``, ``mag``, ``health`` hold time series.
"""

from __future__ import annotations

import functools

__all__ = [
    "APPLICATION_ID",
    "DEPTH_SCALE",
    "DVL_ALTITUDE",
    "DVL_BOTTOM_LOCK",
    "DVL_VELOCITY",
    "HEALTH_COUNTERS",
    "HEALTH_GROUPS",
    "INS_ATTITUDE",
    "MAG_CHANGE",
    "MAG_FIELD",
    "MAG_MAGNITUDE",
    "MAP",
    "MAP_BATHYMETRY",
    "MAP_GRID",
    "MEAN_DEPTH",
    "RAW_PING",
    "SONAR",
    "SONAR_BEAM",
    "SONAR_FAN",
    "SONAR_RINGS",
    "SONAR_VEHICLE",
    "SOUNDINGS",
    "TIMELINE",
    "VEHICLE",
    "VEHICLE_MAG",
    "VIZ_DROPPED",
    "WORLD",
    "events_path",
    "health_group",
    "health_path",
    "map_path",
    "raw_ping_path",
    "track_segment",
    "world_path",
]

#: the Rerun application id of every auvgw recording (blueprints are matched to it)
APPLICATION_ID = "auvgw"
#: the timeline every entity is logged on: device time, s (a timestamp unless told otherwise)
TIMELINE = "sensor_time"

MAP = "map"
WORLD = "world"
SONAR = "sonar"
#: the latest raw ping of each GeoSwath side: ``raw_ping/<device>/<port|starboard>``, a 2-D
#: chart (x return angle, deg from the vertical, port negative; y slant range, m, down), one
#: point per sample coloured by amplitude
RAW_PING = "raw_ping"

#: gridded mean depth on the map: the cells updated since the previous log, as discs in depth
#: colours (the layout accumulates them)
MAP_BATHYMETRY = f"{MAP}/bathymetry"
#: the gridded mean depths at the end of the recording (DepthImage, m, 0 = no sounding; pixel
#: (col, row) at map coordinates translation + (col, row) x cell); outside the views
MEAN_DEPTH = "bathymetry/mean_depth"
#: vehicle body frame: Transform3D (INS attitude, position of the navigation track)
VEHICLE = f"{WORLD}/vehicle"
#: magnetic field vector in the vehicle frame (Arrows3D, scaled)
VEHICLE_MAG = f"{VEHICLE}/magnetometer"
#: every multibeam sounding, NED (Points3D coloured by depth, accumulated by the blueprint)
SOUNDINGS = f"{WORLD}/multibeam/soundings"
SONAR_FAN = f"{SONAR}/fan"
SONAR_BEAM = f"{SONAR}/beam"
#: roll and pitch (deg) apart from the heading (0-360 deg), each on its own axis
INS_ATTITUDE = "ins/attitude"
INS_HEADING = "ins/heading"
DVL_VELOCITY = "dvl/velocity"
DVL_ALTITUDE = "dvl/altitude"
DVL_BOTTOM_LOCK = "dvl/bottom_lock"
MAG_FIELD = "mag/field"
MAG_MAGNITUDE = "mag/magnitude"
#: the logger's own drop counter (the stage's counters are the device ``viz`` health)
VIZ_DROPPED = "health/viz/logger_dropped"
#: the map's metre grid and scale bar (static, grown with the tracks)
MAP_GRID = f"{MAP}/grid"
#: the depth colour scale beside the soundings (3-D) and the sonar's range rings and vehicle
DEPTH_SCALE = f"{WORLD}/depth_scale"
SONAR_RINGS = f"{SONAR}/rings"
SONAR_VEHICLE = f"{SONAR}/vehicle"
#: the magnetometer's departure from its running mean (nT), where a few nT show
MAG_CHANGE = "mag/change"


@functools.lru_cache(maxsize=4096)
def track_segment(name: str) -> str:
    """Path segment of a trajectory name (``truth``, ``dead_reckoning``, ``slam/fastslam2``):
    lower case, characters other than letters, digits, ``_``, ``-`` and ``/`` become ``_``."""
    out = "".join(c if c.isalnum() or c in "_-/" else "_" for c in name.strip().lower())
    out = "/".join(p for p in out.split("/") if p)
    return out or "unnamed"


def map_path(name: str, what: str) -> str:
    """2-D map entity of trajectory ``name``: ``map/<name>/<what>``."""
    return f"{MAP}/{track_segment(name)}/{what}"


def raw_ping_path(device: str, side: int) -> str:
    """Raw-ping entity of one GeoSwath side (0 port, 1 starboard): ``raw_ping/<device>/<side>``."""
    return f"{RAW_PING}/{track_segment(device)}/{'starboard' if side == 1 else 'port'}"


def world_path(name: str, what: str) -> str:
    """3-D entity of trajectory ``name``: ``world/<name>/<what>``."""
    return f"{WORLD}/{track_segment(name)}/{what}"


#: health series groups, one view each (one unit per axis): message rates (Hz), age of the
#: newest sample and silence (s), transport lag (s), connected / stale flags (0/1), the fusion's
#: checks (shares of updates, NIS per degree of freedom) and its adapted DVL noise (m/s)
HEALTH_GROUPS: tuple[str, ...] = ("rate", "age", "lag", "flags", "checks", "noise")
#: every component's cumulative counters, as a table (TextDocument, markdown) at each time
HEALTH_COUNTERS = "health/counters"
#: the autopilot's views (auvgw.viz.stage, docs/pilot.md): entity path -> view name, one unit each
PILOT_VIEWS: dict[str, str] = {
    "pilot/track": "Pilot: cross-track, along-track, depth set-point (m)",
    "pilot/setpoints": "Pilot: heading and pitch set-points (deg)",
    "pilot/speed": "Pilot: speed set-point (m/s)",
    "pilot/fins": "Pilot: rudder and stern-plane commands (deg)",
    "pilot/shaft": "Pilot: shaft speed command (rpm)",
}


def health_group(metric: str) -> str | None:
    """The health view of a metric by its name (see :data:`HEALTH_GROUPS`), or None for a
    cumulative counter (frames, errors, updates: shown as text, never as a line; its series
    goes to ``health/count/<device>``, in no view)."""
    if metric.endswith(("rate_hz", "_hz")):
        return "rate"
    if metric.endswith(("age_s", "silent_s")):
        return "age"
    if metric.endswith("lag_s"):
        return "lag"
    if metric in ("connected", "stale"):
        return "flags"
    if metric.endswith("_share") or metric.startswith("nis"):
        return "checks"
    if metric.endswith("_mps"):
        return "noise"
    return None


def health_path(device: str, group: str = "rate") -> str:
    """Health series of one device in one group: ``health/<group>/<device>``."""
    return f"health/{group}/{track_segment(device)}"


def events_path(device: str) -> str:
    """Text events of one device: ``health/<device>/events``."""
    return f"health/{track_segment(device)}/events"
