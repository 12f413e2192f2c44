"""Missions: waypoints in a local NED frame, legs between them, a lawnmower generator, TOML files.

A mission is a list of :class:`Waypoint` (north, east, depth in metres, NED, depth positive
down; speed in m/s to fly *towards* that waypoint). Leg ``k`` runs from waypoint ``k`` to
waypoint ``k + 1``; the vehicle starts the mission on leg 0. A mission file (TOML) gives either
explicit ``[[waypoints]]`` or one ``[lawnmower]`` table (see ``docs/pilot.md``)::

    [mission]
    name = "survey"
    speed = 1.5              # m/s, default for every waypoint
    depth = 10.0             # m, default for every waypoint
    acceptance_radius = 5.0  # m

    [lawnmower]
    origin = [0.0, 0.0]      # north, east of the first waypoint (m)
    leg_length = 500.0       # m
    spacing = 30.0           # m between parallel legs
    legs = 4                 # survey lines
    heading = 0.0            # deg, direction of the first line (from north towards east)
    turn = "starboard"       # side of the first line the second one lies on

:func:`check_mission` returns every error at once, one :class:`MissionError` (file, leg,
field, message) each; :func:`load_mission` raises :class:`MissionFileError` carrying them.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "MAX_DEPTH_M",
    "MAX_SPEED_MPS",
    "MISSIONS_DIR",
    "Mission",
    "MissionError",
    "MissionFileError",
    "Waypoint",
    "check_mission",
    "lawnmower",
    "load_mission",
    "parse_mission",
]

#: the shipped mission files
MISSIONS_DIR = Path(__file__).resolve().parent.parent / "config" / "missions"
#: the mission checker's bounds: the REMUS 100 is rated to 100 m and tops out near 2.5 m/s
MAX_DEPTH_M = 100.0
MAX_SPEED_MPS = 2.5


@dataclass(frozen=True)
class Waypoint:
    """A point to reach: ``north``, ``east`` (m, local NED), ``depth`` (m, down), ``speed``
    (m/s through the water on the leg ending here)."""

    north: float
    east: float
    depth: float
    speed: float


@dataclass(frozen=True)
class Mission:
    """Waypoints (leg ``k`` = ``waypoints[k]`` to ``waypoints[k + 1]``) and the leg switch
    ``acceptance_radius`` (m: within it of the leg's end, or past the perpendicular at the end,
    the next leg starts)."""

    waypoints: tuple[Waypoint, ...]
    acceptance_radius: float = 5.0
    name: str = "mission"

    @property
    def n_legs(self) -> int:
        return max(0, len(self.waypoints) - 1)

    def leg(self, k: int) -> tuple[Waypoint, Waypoint]:
        """The start and end waypoints of leg ``k``."""
        return self.waypoints[k], self.waypoints[k + 1]

    @property
    def length(self) -> float:
        """Horizontal path length (m)."""
        return sum(math.hypot(b.north - a.north, b.east - a.east)
                   for a, b in zip(self.waypoints, self.waypoints[1:], strict=False))  # fmt: skip


@dataclass(frozen=True)
class MissionError:
    """One problem in a mission file: ``leg`` (None: the whole file), ``field`` and why."""

    file: str
    leg: int | None
    field: str
    message: str

    def __str__(self) -> str:
        where = "mission" if self.leg is None else f"leg {self.leg}"
        return f"{self.file}: {where}: {self.field}: {self.message}"


class MissionFileError(ValueError):
    """A mission file that cannot be flown; ``errors`` lists every problem found."""

    def __init__(self, errors: list[MissionError]) -> None:
        self.errors = errors
        super().__init__("\n".join(str(e) for e in errors))


def lawnmower(
    origin: tuple[float, float],
    leg_length: float,
    spacing: float,
    legs: int,
    heading_deg: float,
    depth: float,
    speed: float,
    turn: str = "starboard",
) -> tuple[Waypoint, ...]:
    """The waypoints of a lawnmower survey: ``legs`` parallel lines of ``leg_length`` m,
    ``spacing`` m apart, the first from ``origin`` (north, east m) along ``heading_deg``
    (degrees from north towards east), the next lines on the ``turn`` side ("starboard" or
    "port"), joined by short cross legs. ``2 * legs`` waypoints."""
    h = math.radians(heading_deg)
    along = (math.cos(h), math.sin(h))
    side = 1.0 if turn == "starboard" else -1.0
    across = (-math.sin(h) * side, math.cos(h) * side)
    out: list[Waypoint] = []
    for i in range(legs):
        ends = (0.0, leg_length) if i % 2 == 0 else (leg_length, 0.0)
        for a in ends:
            c = i * spacing
            north = origin[0] + a * along[0] + c * across[0]
            east = origin[1] + a * along[1] + c * across[1]
            out.append(Waypoint(north, east, depth, speed))
    return tuple(out)


_MISSION_KEYS = {"name", "speed", "depth", "acceptance_radius"}
_LAWNMOWER_KEYS = {"origin", "leg_length", "spacing", "legs", "heading", "depth", "speed", "turn"}
_WAYPOINT_KEYS = {"north", "east", "depth", "speed"}


def _number(errs: list[MissionError], file: str, leg: int | None, name: str, v: Any,
            lo: float, hi: float, lo_open: bool = False) -> float | None:  # fmt: skip
    if v is None:
        errs.append(MissionError(file, leg, name, "missing (and no default in [mission])"))
        return None
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        errs.append(MissionError(file, leg, name, f"must be a finite number, got {v!r}"))
        return None
    x = float(v)
    if x < lo or x > hi or (lo_open and x == lo):
        lo_s = f"> {lo:g}" if lo_open else f">= {lo:g}"
        errs.append(MissionError(file, leg, name, f"{x:g} out of range ({lo_s} and <= {hi:g})"))
        return None
    return x


def parse_mission(table: dict[str, Any], file: str = "<mission>") -> tuple[Mission | None,
                                                                            list[MissionError]]:
    """A mission from a parsed TOML table: ``(mission, [])``, or ``(None, errors)`` with every
    problem found (the good waypoints around a bad one are still checked)."""
    errs: list[MissionError] = []
    for key in sorted(set(table) - {"mission", "lawnmower", "waypoints"}):
        errs.append(MissionError(file, None, key, "unknown section"))
    head = table.get("mission", {})
    if not isinstance(head, dict):
        head = {}
        errs.append(MissionError(file, None, "mission", "must be a table"))
    for key in sorted(set(head) - _MISSION_KEYS):
        errs.append(MissionError(file, None, f"mission.{key}", "unknown field"))
    name = str(head.get("name", Path(file).stem))
    d_speed = (_number(errs, file, None, "mission.speed", head["speed"], 0.0, MAX_SPEED_MPS, True)
               if "speed" in head else None)  # fmt: skip
    d_depth = (_number(errs, file, None, "mission.depth", head["depth"], 0.0, MAX_DEPTH_M)
               if "depth" in head else None)  # fmt: skip
    radius = _number(errs, file, None, "mission.acceptance_radius",
                     head.get("acceptance_radius", 5.0), 0.0, 1000.0, True)  # fmt: skip
    has_wp, has_lm = "waypoints" in table, "lawnmower" in table
    wps: list[Waypoint | None] = []
    if has_wp == has_lm:
        errs.append(MissionError(file, None, "waypoints",
                                 "give either [[waypoints]] or [lawnmower], exactly one"))
    elif has_lm:
        wps = list(_parse_lawnmower(errs, file, table["lawnmower"], d_speed, d_depth))
    else:
        raw = table["waypoints"]
        if not isinstance(raw, list) or not all(isinstance(w, dict) for w in raw):
            errs.append(MissionError(file, None, "waypoints", "must be an array of tables"))
        else:
            wps = [_parse_waypoint(errs, file, i, w, d_speed, d_depth) for i, w in enumerate(raw)]
    if has_wp != has_lm and has_wp and len(wps) < 2:
        errs.append(MissionError(file, None, "waypoints", f"need at least 2, got {len(wps)}"))
    good = [w for w in wps if w is not None]
    if radius is not None and len(good) == len(wps):
        for k, (a, b) in enumerate(itertools.pairwise(good)):
            n = math.hypot(b.north - a.north, b.east - a.east)
            if n <= radius:
                errs.append(MissionError(file, k, "length", f"{n:.3g} m, not longer than the "
                                         f"acceptance radius {radius:g} m"))  # fmt: skip
    if errs or radius is None:
        return None, errs
    return Mission(tuple(good), radius, name), []


def _parse_waypoint(errs: list[MissionError], file: str, i: int, w: dict[str, Any],
                    d_speed: float | None, d_depth: float | None) -> Waypoint | None:  # fmt: skip
    """Waypoint ``i`` is the end of leg ``i - 1`` (the first one: leg 0's start, reported as
    leg 0)."""
    leg = max(0, i - 1)
    n0 = len(errs)
    for key in sorted(set(w) - _WAYPOINT_KEYS):
        errs.append(MissionError(file, leg, f"waypoints[{i}].{key}", "unknown field"))
    vals: dict[str, float | None] = {}
    for key, lo, hi, default, lo_open in (
        ("north", -1e6, 1e6, None, False),
        ("east", -1e6, 1e6, None, False),
        ("depth", 0.0, MAX_DEPTH_M, d_depth, False),
        ("speed", 0.0, MAX_SPEED_MPS, d_speed, True),
    ):
        vals[key] = _number(errs, file, leg, f"waypoints[{i}].{key}", w.get(key, default),
                            lo, hi, lo_open)  # fmt: skip
    if len(errs) > n0:
        return None
    return Waypoint(*(float(vals[k]) for k in ("north", "east", "depth", "speed")))  # type: ignore[arg-type]


def _parse_lawnmower(errs: list[MissionError], file: str, lm: Any, d_speed: float | None,
                     d_depth: float | None) -> tuple[Waypoint, ...]:  # fmt: skip
    if not isinstance(lm, dict):
        errs.append(MissionError(file, None, "lawnmower", "must be a table"))
        return ()
    n0 = len(errs)
    for key in sorted(set(lm) - _LAWNMOWER_KEYS):
        errs.append(MissionError(file, None, f"lawnmower.{key}", "unknown field"))
    origin = lm.get("origin", [0.0, 0.0])
    if (not isinstance(origin, list) or len(origin) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in origin)):
        errs.append(MissionError(file, None, "lawnmower.origin",
                                 f"must be [north, east] in metres, got {origin!r}"))
    length = _number(errs, file, None, "lawnmower.leg_length", lm.get("leg_length"), 0.0, 1e5, True)
    spacing = _number(errs, file, None, "lawnmower.spacing", lm.get("spacing"), 0.0, 1e4, True)
    legs = lm.get("legs")
    if isinstance(legs, bool) or not isinstance(legs, int) or not 1 <= legs <= 1000:
        errs.append(MissionError(file, None, "lawnmower.legs",
                                 f"must be an integer 1..1000, got {legs!r}"))
    heading = _number(errs, file, None, "lawnmower.heading", lm.get("heading", 0.0), -360.0, 360.0)
    depth = _number(errs, file, None, "lawnmower.depth", lm.get("depth", d_depth), 0.0, MAX_DEPTH_M)
    speed = _number(errs, file, None, "lawnmower.speed", lm.get("speed", d_speed), 0.0,
                    MAX_SPEED_MPS, True)  # fmt: skip
    turn = lm.get("turn", "starboard")
    if turn not in ("starboard", "port"):
        errs.append(MissionError(file, None, "lawnmower.turn",
                                 f"must be 'starboard' or 'port', got {turn!r}"))
    if len(errs) > n0:
        return ()
    assert None not in (length, spacing, heading, depth, speed)
    return lawnmower((float(origin[0]), float(origin[1])), length, spacing, legs,  # type: ignore[arg-type]
                     heading, depth, speed, turn)  # type: ignore[arg-type]


def load_mission(path: Path) -> Mission:
    """Read and check a mission file; :class:`MissionFileError` lists every problem."""
    return _load(path)


def check_mission(path: Path) -> list[MissionError]:
    """Every problem in a mission file (empty: it can be flown)."""
    try:
        _load(path)
    except MissionFileError as exc:
        return exc.errors
    return []


def _load(path: Path) -> Mission:
    file = str(path)
    try:
        with path.open("rb") as f:
            table = tomllib.load(f)
    except OSError as exc:
        err = MissionError(file, None, "file", exc.strerror or str(exc))
        raise MissionFileError([err]) from exc
    except tomllib.TOMLDecodeError as exc:
        raise MissionFileError([MissionError(file, None, "toml", str(exc))]) from exc
    mission, errs = parse_mission(table, file)
    if mission is None:
        raise MissionFileError(errs)
    return mission

