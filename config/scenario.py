"""Scenario file: one JSON format for the world model, the SLAM evaluation harness and the tests.

Frames and units (the whole project uses them):

* local horizontal frame, metres: ``x`` north, ``y`` east, ``z`` down (NED); 2-D poses are
  ``(x, y, heading)`` with heading in radians measured from +x (north) towards +y (east), i.e.
  clockwise seen from above, as the VB paper's yaw. In scenario files angles are in **degrees**
  (fields end in ``_deg``) and converted on load.
* Tim Bailey's simulator maps use a plain (x, y) frame with counter-clockwise angles from +x; the
  formulas are identical when his x is read as our north and his y as our east, so his
  coordinates are used unchanged.

Load with :func:`load_scenario`; every validation error names the file, the field path and what
was expected.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    ValidationInfo,
    create_model,
    model_validator,
)

from auvgw.drivers import registry
from auvgw.ground.errors import ConfigError, format_validation_error, read_document

__all__ = [
    "AcousticBeacon",
    "BicycleMotion",
    "DeviceSettings",
    "Devices",
    "FaultSettings",
    "Features",
    "MagneticBeacon",
    "ObservationSettings",
    "SandField",
    "Scenario",
    "ScenarioError",
    "Terrain",
    "Vehicle",
    "load_scenario",
    "resolve_ref",
]

#: a coordinate or offset in the local frame, metres: within 100 km of the origin
Coord = Annotated[float, Field(ge=-1e5, le=1e5)]
#: a point (x north, y east), metres; a JSON array (tuples are not JSON: not strict)
XY = Annotated[tuple[Coord, Coord], Strict(False)]
Window = Annotated[tuple[float, float], Strict(False)]
#: a seed for numpy's generators (0 .. 2^32-1)
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]
#: the longest route a scenario may drive, vehicle seconds (a day; the truth is precomputed)
MAX_ROUTE_S = 86400.0
MAX_POINTS = 20_000
MAX_LIST = 1000


class ScenarioError(ConfigError):
    """A scenario file that cannot be used; the message names the file and the field."""


class _Model(BaseModel):
    # strict: no "yes" -> True, "3" -> 3 or 3.0 -> 3; every number finite
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


def resolve_ref(ref: str, source: str | None = None, label: str | None = None) -> Path:
    """A path named in a scenario: ``shared:rel`` is ``rel`` in ../shared/data; anything else is
    relative to the scenario file ``source`` (or absolute). ``label`` names the scenario in
    errors."""
    if ref.startswith("shared:"):
        from auvgw.ground.paths import shared_dir

        root = shared_dir()
        if root is None:
            raise ScenarioError(
                f"{source or label or '<scenario>'}: {ref!r} needs ../shared/data, not found "
                "(set AUVGW_SHARED)"
            )
        return root / "data" / ref.removeprefix("shared:")
    p = Path(ref)
    if not p.is_absolute() and source:
        p = Path(source).parent / p
    return p


class Dynamics(_Model):
    """The closed-loop vehicle (``vehicle.mode = "dynamics"``): the 6-DOF model integrated
    online at ``dt_s`` (vehicle s) from the actuators' state (docs/dynamics.md)."""

    params: str = Field(
        "",
        max_length=4096,
        description="vehicle parameter file (TOML, as config/vehicles/remus100.toml); '': "
        "the REMUS 100",
    )
    dt_s: float = Field(0.01, ge=0.001, le=0.1, description="integration step, vehicle s")
    rpm: float = Field(
        0.0, ge=-3000, le=3000, description="shaft speed without an actuators device, rpm"
    )
    history_s: float = Field(
        60.0, ge=1, le=3600, description="past truth kept for sampling earlier times, s"
    )


class Vehicle(_Model):
    """Route and speed. Waypoints are (x north, y east) in metres, visited in order.

    ``waypoints_file`` (e.g. ``shared:bailey/webmap.json``) names a JSON file with a
    ``waypoints`` list of [x, y]; it fills ``waypoints`` when the scenario is validated (give one
    or the other; a relative path is relative to the scenario file when loaded with
    :func:`load_scenario`, else to the working directory). ``current_mps`` is a uniform water
    current over ground (north, east): the vehicle keeps its speed through the water and crabs
    into the current, so its body sway velocity ``v`` is not zero. ``dt_s`` is the integration
    step of the motion model.
    """

    waypoints: list[XY] = Field(default_factory=list, max_length=MAX_POINTS)
    waypoints_file: str | None = Field(
        None,
        max_length=4096,
        description="JSON with a 'waypoints' list of [x, y]; replaces 'waypoints'",
    )
    speed_mps: float = Field(1.5, gt=0, le=10)
    depth_m: float = Field(
        5.0, ge=0, le=11000, description="commanded depth; ignored if altitude_m is set"
    )
    altitude_m: float | None = Field(None, gt=0, le=1000, description="terrain-following altitude")
    loops: int = Field(1, ge=1, le=1000, description="times the waypoint list is driven")
    closed: bool = Field(False, description="return to the first waypoint at the end of a loop")
    max_yaw_rate_dps: float = Field(10.0, ge=0.1, le=360, description="turn-rate limit, deg/s")
    accept_radius_m: float = Field(2.0, gt=0, le=1000, description="waypoint acceptance radius")
    start: Annotated[tuple[Coord, Coord, float], Strict(False)] | None = Field(
        None, description="initial (x, y, heading_deg); default: first waypoint facing the second"
    )
    lookahead_m: float = Field(
        10.0, ge=0.1, le=10000, description="line-of-sight guidance lookahead"
    )
    max_depth_rate_mps: float = Field(0.5, ge=0.001, le=10, description="vertical speed limit, m/s")
    current_mps: XY = Field((0.0, 0.0), description="water current (north, east), m/s")
    dt_s: float = Field(0.02, ge=0.001, le=1.0, description="motion model integration step, s")
    mode: Literal["route", "dynamics"] = Field(
        "route",
        description="route: the truth flies the waypoints (precomputed); dynamics: integrated "
        "online from the actuators (closed loop; starts at 'start' or the first waypoint, at "
        "depth_m and speed_mps)",
    )
    dynamics: Dynamics = Dynamics()

    @model_validator(mode="before")
    @classmethod
    def _load_waypoints_file(cls, data: object, info: ValidationInfo) -> object:
        if not isinstance(data, dict) or not data.get("waypoints_file"):
            return data
        ref = str(data["waypoints_file"])
        source = (info.context or {}).get("source")
        path = resolve_ref(ref, source)
        try:
            wps = [(float(p[0]), float(p[1])) for p in json.loads(path.read_text())["waypoints"]]
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            raise ValueError(
                f"waypoints_file {ref!r} ({path}): cannot read waypoints: {exc}"
            ) from exc
        given = data.get("waypoints")
        if given:  # allowed only as the same list (a dumped scenario validated again)
            try:
                same = [(float(p[0]), float(p[1])) for p in given] == wps
            except (TypeError, ValueError, IndexError):
                same = False
            if not same:
                raise ValueError("give 'waypoints' or 'waypoints_file', not both")
        return {**data, "waypoints": wps}

    @model_validator(mode="after")
    def _enough_waypoints(self) -> Vehicle:
        if len(self.waypoints) < 2:
            raise ValueError(
                f"needs at least 2 waypoints ('waypoints' or 'waypoints_file'), got "
                f"{len(self.waypoints)}"
            )
        if math.hypot(*self.current_mps) >= self.speed_mps:
            raise ValueError("current_mps must be slower than speed_mps (the vehicle makes way)")
        length = sum(
            math.dist(a, b) for a, b in zip(self.waypoints, self.waypoints[1:], strict=False)
        )
        if self.closed:
            length += math.dist(self.waypoints[-1], self.waypoints[0])
        route_s = self.loops * length / (self.speed_mps - math.hypot(*self.current_mps))
        if route_s > MAX_ROUTE_S:
            raise ValueError(
                f"the route takes about {route_s:.3g} s at speed_mps, over {MAX_ROUTE_S:g} s: "
                "fewer loops or waypoints, or a faster vehicle"
            )
        return self


class BicycleMotion(_Model):
    """Tim Bailey's simulator vehicle (his defaults): a steered car following waypoints."""

    speed_mps: float = Field(3.0, gt=0, le=50)
    wheelbase_m: float = Field(4.0, gt=0, le=100)
    max_steer_deg: float = Field(30.0, gt=0, le=89)
    max_steer_rate_dps: float = Field(20.0, gt=0, le=360)
    dt_s: float = Field(0.025, ge=0.001, le=1.0)
    sigma_v_mps: float = Field(0.3, ge=0, le=10)
    sigma_steer_deg: float = Field(3.0, ge=0, le=90)


class ObservationSettings(_Model):
    """Range-bearing observations of point features (the SLAM papers' eq. 4)."""

    max_range_m: float = Field(30.0, gt=0, le=10000)
    field_of_view_deg: float = Field(
        180.0, gt=0, le=360, description="seen within +-fov/2 of the heading (Bailey: 180)"
    )
    sigma_range_m: float = Field(0.1, ge=0, le=1000)
    sigma_bearing_deg: float = Field(1.0, ge=0, le=180)
    every_n_steps: int = Field(8, ge=1, le=100000, description="observe every n motion steps")
    #: the VB paper's dynamic noise: for each observation, with probability p its covariance
    #: is n times R0
    burst_p: float = Field(0.0, ge=0, le=1)
    burst_n: float = Field(1.0, ge=1, le=1e6)


class Features(_Model):
    """Point features (x, y) and line features (x1, y1, x2, y2): walls, piers, in metres."""

    points: list[XY] = Field([], max_length=MAX_POINTS)
    lines: list[Annotated[tuple[Coord, Coord, Coord, Coord], Strict(False)]] = Field(
        [], max_length=MAX_LIST
    )
    point_radius_m: float = Field(
        0.5,
        gt=0,
        le=100,
        description="radius of every point feature as a sonar target (piles, rocks)",
    )
    points_file: str | None = Field(
        None,
        max_length=4096,
        description="JSON with a 'landmarks' list of [x, y] (e.g. 'shared:bailey/webmap.json', "
        "resolved in ../shared/data), appended to points",
    )


class SandField(_Model):
    """A field of sand waves on a flat sandy bed inside a mixed terrain (metres, NED).

    Inside ``extent_m`` = (x_min, x_max, y_min, y_max) the mixed relief fades out (over ``edge_m``
    at the borders) and a :class:`sandwaves`-style wave of ``wavelength_m`` and ``relief_m``
    across ``direction_deg`` (deg from north) takes its place: crossings there match an alias
    one wavelength away about as well as the truth, crossings outside do not.
    """

    extent_m: Annotated[tuple[Coord, Coord, Coord, Coord], Strict(False)]
    relief_m: float = Field(1.5, gt=0, le=1000)
    wavelength_m: float = Field(40.0, ge=0.1, le=1e5)
    direction_deg: float = Field(30.0, ge=-360, le=360)
    edge_m: float = Field(
        20.0, gt=0, le=1e5, description="width of the fade at the field's borders"
    )
    seed: Seed = 0

    @model_validator(mode="after")
    def _extent_ordered(self) -> SandField:
        x0, x1, y0, y1 = self.extent_m
        if not (x0 < x1 and y0 < y1):
            raise ValueError(
                f"sand field extent_m {self.extent_m}: need x_min < x_max, y_min < y_max"
            )
        return self


class Terrain(_Model):
    """Seabed depth below the surface, metres (positive down).

    ``flat``: ``depth_m`` everywhere. ``procedural``: ``depth_m`` plus a seeded sum of sinusoids
    of ``relief_m`` amplitude and ``wavelength_m``; ``octaves`` > 1 adds finer, weaker layers
    (each half the wavelength and half the amplitude) for rough terrain, the total deviation
    staying within +-``relief_m``. ``mixed``: the procedural relief faded out over flat patches
    (``flat_fraction`` of the area) plus ``n_ridges`` linear ridges and ``n_mounds`` Gaussian
    mounds inside ``extent_m`` (varied relief for bathymetric SLAM). ``sandwaves``: one
    dominant wave of ``wavelength_m`` across ``direction_deg`` with weak modulation
    (self-similar relief that invites false loop closures); ``sand_fields`` put such waves on
    parts of a ``mixed`` terrain (:class:`SandField`). ``grid``: a depth grid from ``file``
    (``.npy`` or JSON list of rows) with cell size ``cell_m`` and its (x, y) origin at
    ``origin``; row i is x = origin_x + i cell_m, column j is y = origin_y + j cell_m.
    """

    kind: Literal["flat", "procedural", "grid", "mixed", "sandwaves"] = "flat"
    depth_m: float = Field(50.0, gt=0, le=11000)
    relief_m: float = Field(0.0, ge=0, le=1000)
    wavelength_m: float = Field(80.0, ge=0.1, le=1e5)
    octaves: int = Field(1, ge=1, le=8, description="procedural detail layers")
    seed: Seed = 0
    file: str | None = Field(None, max_length=4096)
    cell_m: float = Field(1.0, ge=0.01, le=1e4)
    origin: XY = (0.0, 0.0)
    flat_fraction: float = Field(
        0.3, ge=0, lt=1, description="mixed: share of the area that is a flat patch (no relief)"
    )
    n_ridges: int = Field(3, ge=0, le=50, description="mixed: linear ridges of relief_m height")
    n_mounds: int = Field(12, ge=0, le=500, description="mixed: Gaussian mounds of relief_m")
    extent_m: Annotated[tuple[Coord, Coord, Coord, Coord], Strict(False)] = Field(
        (-200.0, 1000.0, -200.0, 1000.0),
        description="mixed: (x_min, x_max, y_min, y_max) where ridges and mounds are placed",
    )
    direction_deg: float = Field(
        30.0,
        ge=-360,
        le=360,
        description="sandwaves: crest-normal direction of the dominant wave, deg from north",
    )
    sand_fields: list[SandField] = Field(
        [],
        max_length=64,
        description="mixed: sand-wave fields replacing the relief inside their extent",
    )

    @model_validator(mode="after")
    def _grid_needs_file(self) -> Terrain:
        if self.kind == "grid" and not self.file:
            raise ValueError("terrain kind 'grid' needs 'file'")
        x0, x1, y0, y1 = self.extent_m
        if self.kind == "mixed" and not (x0 < x1 and y0 < y1):
            raise ValueError(f"extent_m {self.extent_m}: need x_min < x_max, y_min < y_max")
        if self.sand_fields and self.kind != "mixed":
            raise ValueError(f"terrain kind {self.kind!r}: sand_fields need kind 'mixed'")
        for i, f in enumerate(self.sand_fields):
            if f.relief_m >= self.depth_m:
                raise ValueError(
                    f"sand_fields[{i}].relief_m ({f.relief_m}) must be less than depth_m "
                    f"({self.depth_m}): the seabed must stay below the surface"
                )
        if self.kind in ("procedural", "sandwaves") and self.relief_m >= self.depth_m:
            raise ValueError(
                f"relief_m ({self.relief_m}) must be less than depth_m ({self.depth_m}): "
                "the seabed must stay below the surface"
            )
        if self.kind == "mixed" and 3 * self.relief_m >= self.depth_m:
            raise ValueError(
                f"mixed terrain: 3 x relief_m ({3 * self.relief_m}) must be less than depth_m "
                f"({self.depth_m}): relief, ridges and mounds add up"
            )
        return self


class MagneticBeacon(_Model):
    """A coil on the seabed: position (NED, m), dipole moment (A m^2) along ``axis``, frequency."""

    x: Coord
    y: Coord
    z: Coord = 0.0
    moment_am2: float = Field(gt=0, le=1e9)
    frequency_hz: float = Field(0.0, ge=0, le=1e5, description="0 = static (DC) field")
    axis: Annotated[tuple[float, float, float], Strict(False)] = (0.0, 0.0, 1.0)

    @model_validator(mode="after")
    def _axis_not_zero(self) -> MagneticBeacon:
        if not 1e-6 <= math.hypot(*self.axis) <= 1e6:
            raise ValueError(f"axis {self.axis}: needs a length between 1e-6 and 1e6")
        return self


class AcousticBeacon(_Model):
    """One acoustic transponder (USBL/LBL-style range source), position NED in metres."""

    x: Coord
    y: Coord
    z: Coord = 0.0
    sigma_range_m: float = Field(0.5, gt=0, le=1000)


class FaultSettings(_Model):
    """Fault knobs of one device (all off by default). Times are vehicle seconds [start, end)."""

    noise_burst_p: float = Field(0.0, ge=0, le=1, description="probability of a noise burst")
    noise_burst_n: float = Field(1.0, ge=1, le=1e6, description="covariance multiplier in a burst")
    dropout_p: float = Field(0.0, ge=0, le=1, description="probability a frame is not sent")
    garbage_p: float = Field(0.0, ge=0, le=1, description="probability of garbage before a frame")
    garbage_max_bytes: int = Field(32, ge=1, le=65536)
    corrupt_p: float = Field(0.0, ge=0, le=1, description="probability a frame is corrupted")
    truncate_p: float = Field(0.0, ge=0, le=1, description="probability a frame is cut short")
    undetected_p: float = Field(
        0.0, ge=0, le=1,
        description="probability a frame is corrupted in a way its framer still accepts (what "
        "no check can catch: a bit in the data, two changes that keep the checksum)",
    )  # fmt: skip
    bottom_lock_loss: list[Window] = Field([], max_length=MAX_LIST)
    unplug: list[Window] = Field([], max_length=MAX_LIST)
    stall: list[Window] = Field([], max_length=MAX_LIST)
    clock_jumps: list[Window] = Field(
        [],
        max_length=MAX_LIST,
        description="(time, jump_s): the device clock jumps by jump_s at time",
    )
    rudder_jam: list[Window] = Field(
        [], max_length=MAX_LIST, description="actuators: the rudder stays where it is"
    )
    stern_jam: list[Window] = Field(
        [], max_length=MAX_LIST, description="actuators: the stern plane stays where it is"
    )
    thruster_silent: list[Window] = Field(
        [],
        max_length=MAX_LIST,
        description="actuators: the thruster's motor driver stops answering (the shaft coasts)",
    )


class DeviceSettings(_Model):
    """One emulated device: on/off, rate, noise figures (named sigmas, SI or *_deg), faults."""

    enabled: bool = True
    rate_hz: float | None = Field(
        None, ge=0.001, le=1000, description="None: the device's nominal rate"
    )
    noise: dict[str, Annotated[float, Field(ge=0, le=1e6)]] = Field({}, max_length=64)
    faults: FaultSettings = FaultSettings()
    options: dict[str, Annotated[float, Field(ge=-1e9, le=1e9)] | int | str | bool] = Field(
        {}, max_length=64
    )


class _DevicesBase(_Model):
    """The scenario's ``devices``: one :class:`DeviceSettings` per emulator of the registry."""

    if TYPE_CHECKING:  # the fields come from the registry: each is a DeviceSettings

        def __getattr__(self, name: str) -> DeviceSettings: ...


#: one settings table per emulator of the device registry, in its order (``ins``, ``dvl``,
#: ``msis``, ``multibeam``, ``magnetometer``, ``acoustic``); a device that needs a scenario
#: feature (the acoustic beacon) is off unless the scenario enables it
if TYPE_CHECKING:
    Devices = _DevicesBase
else:
    Devices = create_model(
        "Devices",
        __base__=_DevicesBase,
        __module__=__name__,
        **{
            em.key: (DeviceSettings, DeviceSettings(enabled=em.default_on))
            for em in registry.emulators()
        },
    )


class Scenario(_Model):
    """A whole scenario (see the module docstring for frames and units)."""

    name: str = Field(min_length=1, max_length=200)
    description: str = Field("", max_length=10000)
    seed: Seed = 0
    duration_s: float | None = Field(
        None, gt=0, le=MAX_ROUTE_S, description="None: until the route ends"
    )
    vehicle: Vehicle
    motion: Literal["auv", "bicycle"] = "auv"
    bicycle: BicycleMotion = BicycleMotion()
    observations: ObservationSettings = ObservationSettings()
    features: Features = Features()
    terrain: Terrain = Terrain()
    magnetic_beacons: list[MagneticBeacon] = Field([], max_length=MAX_LIST)
    acoustic_beacon: AcousticBeacon | None = None
    earth_field_nt: Annotated[tuple[Coord, Coord, Coord], Strict(False)] = (
        Field(  # nT: within +-1e5 as well (Earth's field is under 7e4 nT)
            (20000.0, 0.0, 45000.0), description="Earth field, NED components in nT"
        )
    )
    sound_speed_mps: Annotated[float, Field(gt=1300, lt=1700)] = 1500.0
    devices: Devices = Devices()

    #: set by load_scenario: the file the scenario came from (for resolving relative paths)
    source: str | None = None

    @model_validator(mode="after")
    def _closed_loop(self) -> Scenario:
        if self.vehicle.mode == "dynamics":
            if self.motion != "auv":
                raise ValueError("vehicle.mode 'dynamics' needs motion 'auv'")
            if self.duration_s is None:
                raise ValueError(
                    "vehicle.mode 'dynamics' needs duration_s (the vehicle has no route to end)"
                )
        return self

    def resolve_path(self, ref: str) -> Path:
        """A path named in the scenario: ``shared:rel`` is in ../shared/data, else relative to
        the scenario file (or absolute)."""
        return resolve_ref(ref, self.source, self.name)

    def point_features(self) -> list[XY]:
        """All point features: ``features.points`` plus those of ``features.points_file``."""
        pts = list(self.features.points)
        if self.features.points_file:
            path = self.resolve_path(self.features.points_file)
            try:
                data = json.loads(path.read_text())
                pts += [(float(p[0]), float(p[1])) for p in data["landmarks"]]
            except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
                raise ScenarioError(
                    f"{self.source}: features.points_file {path}: cannot read landmarks: {exc}"
                ) from exc
        return pts

    @property
    def start_pose(self) -> tuple[float, float, float]:
        """Initial (x, y, heading) in metres and radians."""
        if self.vehicle.start is not None:
            x, y, h = self.vehicle.start
            return (x, y, math.radians(h))
        (x0, y0), (x1, y1) = self.vehicle.waypoints[0], self.vehicle.waypoints[1]
        return (x0, y0, math.atan2(y1 - y0, x1 - x0))


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario JSON file; :class:`ScenarioError` names file and field."""
    path = Path(path)
    data = read_document(path, ScenarioError, "scenario file", "JSON")
    data.pop("source", None)
    try:
        scn = Scenario.model_validate({**data, "source": str(path)}, context={"source": str(path)})
    except ValidationError as exc:
        raise ScenarioError(format_validation_error(exc, str(path))) from exc
    return scn
