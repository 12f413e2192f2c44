"""Simulation core: shipped scenarios, the world model, vehicle kinematics and the clock."""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.config.scenario import ObservationSettings, Scenario, ScenarioError, load_scenario
from auvgw.ground.paths import config_file
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.vehicle import (
    bicycle_step,
    compute_steering,
    control_noise,
    motion_step,
    route_targets,
    simulate,
)
from auvgw.sim_devices.world import (
    FlatTerrain,
    GridTerrain,
    ProceduralTerrain,
    SwathGeometry,
    World,
    cast_rays,
    cast_swath,
    dipole_field,
    terrain_from_settings,
)

SCENARIOS = sorted(Path(str(config_file("scenarios"))).glob("*.json"))
NEEDS_SHARED = {"webmap", "densemap"}


def _load(name: str) -> Scenario:
    return load_scenario(config_file(f"scenarios/{name}.json"))


# -- shipped scenarios -----------------------------------------------------------------------


def test_all_five_scenarios_are_shipped() -> None:
    assert {p.stem for p in SCENARIOS} >= {"harbour", "survey", "beacons", "webmap", "densemap"}


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenario_loads_builds_and_drives(path: Path, request: pytest.FixtureRequest):
    if path.stem in NEEDS_SHARED:
        request.getfixturevalue("shared_data")
    scn = load_scenario(path)
    assert scn.name == path.stem and scn.description
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    assert len(truth) > 100
    assert np.all(np.isfinite(truth.poses))
    assert np.all(truth.altitude > 0), "the vehicle never touches the seabed"
    assert np.all(np.diff(truth.t) > 0)
    # the route is driven: every waypoint is passed near at least once
    wps = np.asarray(scn.vehicle.waypoints)
    d = np.hypot(truth.x[:, None] - wps[:, 0], truth.y[:, None] - wps[:, 1]).min(axis=0)
    radius = max(scn.vehicle.accept_radius_m, scn.vehicle.lookahead_m)
    assert np.all(d < radius), d


def test_harbour_walls_are_always_in_msis_range() -> None:
    scn = _load("harbour")
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    assert len(world.lines) >= 8 and len(world.points) >= 5
    assert world.point_radius == pytest.approx(0.6)
    p = np.stack([truth.x, truth.y], 1)[::25]
    a, b = world.lines[:, :2], world.lines[:, 2:]
    e = b - a
    s = np.clip(((p[:, None] - a) * e).sum(-1) / (e * e).sum(-1), 0, 1)
    dist = np.linalg.norm(p[:, None] - (a + s[..., None] * e), axis=-1)
    assert dist.min() > 5.0, "the route never scrapes a wall"
    assert dist.min(axis=1).max() < 60.0, "some wall is always within the MSIS range"
    # a 360 deg scan from the start sees walls all round (the basin is closed but for its mouth)
    hits = world.cast(p[0], np.radians(np.arange(0, 360, 3.0)), 250.0)
    assert hits.hit.mean() > 0.85


def test_survey_is_half_an_hour_of_overlapping_lines() -> None:
    scn = _load("survey")
    truth = simulate(scn)
    assert 25 * 60 < truth.duration < 35 * 60
    assert scn.terrain.kind == "procedural" and scn.terrain.octaves >= 3
    # terrain following: altitude held within 0.5 m of the 15 m setpoint
    assert np.abs(truth.altitude - 15.0).max() < 0.5
    # swath (12 x altitude) is wider than the line spacing: neighbouring lines overlap
    ys = sorted({p[1] for p in scn.vehicle.waypoints[:10]})
    assert np.diff(ys).max() < 12 * 15.0 / 2
    # the current makes the vehicle crab: body sway is not zero
    assert np.abs(truth.v).max() > 0.05


def test_beacon_field_matches_the_amb_paper_layout() -> None:
    scn = _load("beacons")
    world = World.from_scenario(scn)
    assert len(scn.magnetic_beacons) == 20 and scn.acoustic_beacon is not None
    wps = np.asarray(scn.vehicle.waypoints)
    assert len(wps) == 10 and np.ptp(wps[:, 0]) == 500 and np.ptp(wps[:, 1]) == 500
    assert scn.vehicle.loops == 2
    # beacons lie on the seabed
    bz = world.beacon_positions[:, 2]
    assert (
        np.abs(bz - world.depth(world.beacon_positions[:, 0], world.beacon_positions[:, 1])).max()
        < 0.01
    )
    truth = simulate(scn, world)
    # every beacon comes within the 25 m observation range of the route
    d = np.hypot(
        truth.x[:, None] - world.beacon_positions[:, 0],
        truth.y[:, None] - world.beacon_positions[:, 1],
    )
    assert d.min(axis=0).max() < scn.observations.max_range_m


@pytest.mark.parametrize("name,n_landmarks", [("webmap", 35), ("densemap", 135)])
def test_bailey_scenarios_read_the_shared_maps(name: str, n_landmarks: int, shared_data: Path):
    scn = _load(name)
    src = json.loads((shared_data / "bailey" / f"{name}.json").read_text())
    assert scn.motion == "bicycle"
    assert [list(p) for p in scn.vehicle.waypoints] == src["waypoints"]
    assert len(scn.point_features()) == n_landmarks
    b, o = scn.bicycle, scn.observations
    assert (b.speed_mps, b.wheelbase_m, b.max_steer_deg, b.max_steer_rate_dps, b.dt_s) == (
        3.0, 4.0, 30.0, 20.0, 0.025)  # fmt: skip
    assert (o.max_range_m, o.sigma_range_m, o.sigma_bearing_deg, o.every_n_steps) == (30, 0.1, 1, 8)
    truth = simulate(scn)
    assert truth.t[1] == pytest.approx(0.025)
    # two loops: the first waypoint is visited twice (far apart in time), the last one ends it
    wp0 = np.asarray(src["waypoints"][0])
    near = np.flatnonzero(np.hypot(truth.x - wp0[0], truth.y - wp0[1]) < 1.0)
    assert near.size and (near.max() - near.min()) * 0.025 > 100
    last = np.asarray(src["waypoints"][-1])
    assert math.hypot(truth.x[-1] - last[0], truth.y[-1] - last[1]) < 1.0 + 3.0 * 0.025
    assert np.degrees(np.abs(truth.steer)).max() <= 30.0 + 1e-9


# -- scenario errors (new fields) ------------------------------------------------------------


def _write(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "s.json"
    p.write_text(json.dumps(data))
    return p


def test_waypoints_file_errors_name_the_field(tmp_path: Path) -> None:
    base = {"name": "x", "vehicle": {"waypoints_file": "missing.json"}}
    with pytest.raises(
        ScenarioError, match=r"s\.json: vehicle: .*waypoints_file 'missing\.json'"
    ):
        load_scenario(_write(tmp_path, base))
    (tmp_path / "route.json").write_text(json.dumps({"waypoints": [[0, 0], [10, 5], [20, 0]]}))
    scn = load_scenario(
        _write(tmp_path, {"name": "x", "vehicle": {"waypoints_file": "route.json"}})
    )
    assert scn.vehicle.waypoints == [(0, 0), (10, 5), (20, 0)]
    both = {"name": "x", "vehicle": {"waypoints_file": "route.json", "waypoints": [[0, 0], [1, 1]]}}
    with pytest.raises(ScenarioError, match="not both"):
        load_scenario(_write(tmp_path, both))
    again = Scenario.model_validate(scn.model_dump(), context={"source": str(tmp_path / "s.json")})
    assert again == scn, "a dumped scenario validates again"
    with pytest.raises(ScenarioError, match="at least 2 waypoints"):
        load_scenario(_write(tmp_path, {"name": "x", "vehicle": {}}))


def test_new_fields_are_validated(tmp_path: Path) -> None:
    veh = {"waypoints": [[0, 0], [10, 0]]}
    bad_relief = {
        "name": "x",
        "vehicle": veh,
        "terrain": {"kind": "procedural", "depth_m": 5, "relief_m": 6},
    }
    with pytest.raises(ScenarioError, match="relief_m"):
        load_scenario(_write(tmp_path, bad_relief))
    fast_current = {"name": "x", "vehicle": {**veh, "speed_mps": 1.0, "current_mps": [1.0, 0.5]}}
    with pytest.raises(ScenarioError, match="current_mps"):
        load_scenario(_write(tmp_path, fast_current))
    with pytest.raises(ScenarioError, match=r": terrain\.octaves: "):
        load_scenario(_write(tmp_path, {"name": "x", "vehicle": veh, "terrain": {"octaves": 0}}))


# -- terrain ---------------------------------------------------------------------------------


def test_procedural_terrain_is_seeded_bounded_and_has_the_right_gradient() -> None:
    t = ProceduralTerrain(40.0, 8.0, 150.0, seed=42, octaves=4)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-2000, 2000, (2, 20000))
    z = t.depth(x, y)
    assert z.shape == x.shape
    assert z.min() >= 32.0 and z.max() <= 48.0 and np.ptp(z) > 6.0
    assert np.array_equal(z, ProceduralTerrain(40.0, 8.0, 150.0, seed=42, octaves=4).depth(x, y))
    assert not np.allclose(z, ProceduralTerrain(40.0, 8.0, 150.0, seed=43, octaves=4).depth(x, y))
    gx, gy = t.gradient(x[:50], y[:50])
    h = 1e-4
    assert np.allclose(
        gx, (t.depth(x[:50] + h, y[:50]) - t.depth(x[:50] - h, y[:50])) / (2 * h), atol=1e-6
    )
    assert np.allclose(
        gy, (t.depth(x[:50], y[:50] + h) - t.depth(x[:50], y[:50] - h)) / (2 * h), atol=1e-6
    )
    assert t.depth(3.0, 4.0).shape == ()
    assert np.allclose(FlatTerrain(12.0).depth(x[:5], y[:5]), 12.0)


def test_grid_terrain_is_bilinear_and_loads_from_a_scenario(tmp_path: Path) -> None:
    grid = [[10.0, 12.0, 14.0], [20.0, 22.0, 24.0]]  # rows along x (north), columns along y
    g = GridTerrain(np.array(grid), cell_m=5.0, origin=(100.0, 200.0))
    assert g.depth(100.0, 200.0) == pytest.approx(10.0)
    assert g.depth(105.0, 210.0) == pytest.approx(24.0)
    assert g.depth(102.5, 202.5) == pytest.approx((10 + 12 + 20 + 22) / 4)
    assert g.depth(0.0, 0.0) == pytest.approx(10.0), "clamped to the edge outside the grid"
    assert g.bounds == (10.0, 24.0)
    gx, gy = g.gradient(102.5, 202.5)
    assert gx == pytest.approx(2.0) and gy == pytest.approx(0.4)
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    veh = {"waypoints": [[100, 200], [105, 210]]}
    terr = {"kind": "grid", "file": "grid.json", "cell_m": 5.0, "origin": [100, 200]}
    scn = load_scenario(_write(tmp_path, {"name": "g", "vehicle": veh, "terrain": terr}))
    assert World.from_scenario(scn).depth(105.0, 205.0) == pytest.approx(22.0)
    (tmp_path / "grid.json").write_text("[[1, 2], [3]]")
    with pytest.raises(ScenarioError, match=r"terrain\.file .*grid\.json"):
        World.from_scenario(load_scenario(tmp_path / "s.json"))


def test_sand_field_replaces_the_mixed_relief_inside_its_extent(tmp_path: Path) -> None:
    mixed = {"kind": "mixed", "depth_m": 30.0, "relief_m": 3.0, "wavelength_m": 120.0, "seed": 5}
    field = {"extent_m": [200, 400, -100, 600], "relief_m": 1.5, "wavelength_m": 40.0,
             "direction_deg": 0.0, "edge_m": 10.0, "seed": 6}  # fmt: skip
    veh = {"waypoints": [[0, 0], [10, 0]]}
    plain = load_scenario(_write(tmp_path, {"name": "m", "vehicle": veh, "terrain": mixed}))
    with_field = Scenario.model_validate(
        {**plain.model_dump(), "terrain": {**mixed, "sand_fields": [field]}}
    )
    t0 = terrain_from_settings(plain.terrain)
    t1 = terrain_from_settings(with_field.terrain)
    y = np.linspace(0.0, 500.0, 51)
    # far outside the field (> 6 edge widths): the mixed relief, unchanged
    for x in (0.0, 100.0, 600.0):
        assert np.allclose(t1.depth(np.full_like(y, x), y), t0.depth(np.full_like(y, x), y))
    # deep inside: the sand waves alone, crests across north (direction 0): depth repeats one
    # wavelength further north, to within the +-20 % amplitude modulation and crest waviness
    x = np.linspace(260.0, 300.0, 41)
    z, z_next = t1.depth(x, np.full_like(x, 250.0)), t1.depth(x + 40.0, np.full_like(x, 250.0))
    assert np.ptp(z) > 1.5 and np.abs(z - 30.0).max() <= 1.5 + 1e-9
    assert np.abs(z - z_next).max() < 0.5 * np.ptp(z)
    assert t1.bounds == (21.0, 39.0)
    bad = {**mixed, "sand_fields": [{**field, "extent_m": [400, 200, 0, 1]}]}
    with pytest.raises(ScenarioError, match=r"terrain\.sand_fields\.0.*x_min < x_max"):
        load_scenario(_write(tmp_path, {"name": "m", "vehicle": veh, "terrain": bad}))
    wrong_kind = {"kind": "flat", "sand_fields": [field]}
    with pytest.raises(ScenarioError, match="sand_fields need kind 'mixed'"):
        load_scenario(_write(tmp_path, {"name": "m", "vehicle": veh, "terrain": wrong_kind}))


# -- ray casting (MSIS) ----------------------------------------------------------------------


def test_ray_against_a_wall_gives_the_analytic_range_and_incidence() -> None:
    wall = np.array([[10.0, -100.0, 10.0, 100.0]])  # north of the origin, running east-west
    angles = np.radians([-60.0, -30.0, 0.0, 20.0, 45.0, 89.0, 180.0])
    hits = cast_rays((0.0, 0.0), angles, wall, np.zeros((0, 2)), 0.5, max_range=100.0)
    expect = 10.0 / np.cos(angles[:5])
    assert np.allclose(hits.range_m[:5], expect)
    assert np.allclose(hits.incidence[:5], np.abs(angles[:5]))
    assert list(hits.kind) == [1, 1, 1, 1, 1, 0, 0]  # 89 deg: 573 m > max range; 180: behind
    assert np.isinf(hits.range_m[5]) and np.isnan(hits.incidence[6])


def test_ray_against_points_and_nearest_wins() -> None:
    lines = np.array([[30.0, -10.0, 30.0, 10.0]])
    points = np.array([[20.0, 0.0], [20.0, 0.5], [-5.0, 0.0]])
    world = World(lines=lines, points=points, point_radius=1.0)
    hits = world.cast((0.0, 0.0), np.array([0.0]), 100.0)
    assert hits.kind[0] == 2 and hits.index[0] == 0 and hits.range_m[0] == pytest.approx(19.0)
    assert hits.incidence[0] == pytest.approx(0.0, abs=1e-7)
    # grazing the first pile: the ray passes 1 m to its side at 20 m, hitting the wall
    off = math.atan2(-1.2, 20.0)
    hits = world.cast((0.0, 0.0), np.array([off]), 100.0)
    assert hits.kind[0] == 1 and hits.range_m[0] == pytest.approx(30.0 / math.cos(off))
    # a ray starting inside a circle does not see that circle
    inside = World(points=np.array([[0.0, 0.0]]), point_radius=2.0).cast((0.5, 0.0), 0.0, 10.0)
    assert inside.kind[0] == 0
    angles, beam = world.beam((0.0, 0.0), 0.0, math.radians(3.0), 100.0, n_rays=5)
    assert np.allclose(np.degrees(angles[[0, -1]]), [-1.5, 1.5]) and beam.hit.all()


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50),
    st.floats(0, 2 * math.pi),
)  # fmt: skip
def test_ray_hit_point_lies_on_the_segment(x1: float, y1: float, x2: float, y2: float, a: float):
    seg = np.array([[x1, y1, x2, y2]])
    hits = cast_rays((0.3, -0.7), a, seg, np.zeros((0, 2)), 1.0)
    if hits.hit[0]:
        hx = 0.3 + hits.range_m[0] * math.cos(a)
        hy = -0.7 + hits.range_m[0] * math.sin(a)
        cross = (x2 - x1) * (hy - y1) - (y2 - y1) * (hx - x1)
        assert abs(cross) < 1e-6 * max(1.0, math.hypot(x2 - x1, y2 - y1)) * max(
            1.0, hits.range_m[0]
        )
        assert min(x1, x2) - 1e-6 <= hx <= max(x1, x2) + 1e-6


# -- multibeam swath -------------------------------------------------------------------------


def test_swath_over_a_flat_seabed_is_geoswath_like() -> None:
    geom = SwathGeometry(n_beams=101, swath_factor=12.0)
    sw = cast_swath(FlatTerrain(30.0), (0.0, 0.0, 10.0), math.radians(30), geom, sound_speed=1500)
    assert sw.valid.all() and sw.altitude == pytest.approx(20.0)
    assert np.allclose(sw.depth, 20.0)
    assert np.allclose(sw.across, 20.0 * np.tan(sw.angle))
    assert np.allclose(sw.along, 0.0, atol=1e-9)
    assert sw.across.min() == pytest.approx(-120.0) and sw.across.max() == pytest.approx(120.0)
    assert np.array_equal(sw.side, np.where(sw.angle < 0, -1, 1))
    assert np.allclose(sw.twtt_s, 2 * sw.range_m / 1500)
    assert np.allclose(sw.incidence, np.abs(sw.angle))
    # the hit points are where the heading puts them: 30 deg from north, across to starboard
    assert np.allclose(sw.x, -sw.across * math.sin(math.radians(30)))
    # rolled 10 deg to starboard: each beam points 10 deg closer to port
    rolled = cast_swath(
        FlatTerrain(30.0),
        (0, 0, 10.0),
        0.0,
        SwathGeometry(n_beams=21, swath_factor=4),
        roll=math.radians(10),
    )
    expect = 20.0 * np.tan(rolled.angle - math.radians(10))
    assert np.array_equal(rolled.valid, np.abs(expect) <= 40.0), "beyond 4 x altitude / 2: cut"
    assert np.allclose(rolled.across[rolled.valid], expect[rolled.valid])
    narrow = cast_swath(
        FlatTerrain(30.0), (0, 0, 10.0), 0.0, SwathGeometry(n_beams=11, max_range_m=25.0)
    )
    assert np.array_equal(narrow.valid, np.abs(20 / np.cos(narrow.angle)) <= 25.0)


def test_swath_hits_lie_on_rough_terrain() -> None:
    t = ProceduralTerrain(40.0, 8.0, 150.0, seed=42, octaves=4)
    for pos, heading in [((0.0, 0.0, 25.0), 0.3), ((310.0, -120.0, 18.0), -2.0)]:
        sw = cast_swath(t, pos, heading, SwathGeometry(n_beams=128))
        assert sw.valid.sum() > 100
        ok = sw.valid
        assert np.allclose(sw.z[ok], t.depth(sw.x[ok], sw.y[ok]), atol=1e-4)
        assert np.all(np.diff(sw.across[ok]) > 0), "beams stay ordered port to starboard"
        assert np.allclose(
            sw.range_m[ok], np.sqrt(sw.depth[ok] ** 2 + sw.across[ok] ** 2 + sw.along[ok] ** 2)
        )


# -- magnetic and acoustic beacons -----------------------------------------------------------


def test_dipole_field_falls_with_the_cube_of_range() -> None:
    m = np.array([[0.0, 0.0, 500.0]])
    pos = np.array([[10.0, 20.0, 15.0]])
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(20, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for r in (3.0, 7.5, 20.0):
        b1 = dipole_field(pos + r * dirs, pos, m)[0]
        b2 = dipole_field(pos + 2 * r * dirs, pos, m)[0]
        assert np.allclose(np.linalg.norm(b1, axis=1) / np.linalg.norm(b2, axis=1), 8.0)
    # on the axis 2 mu0 m / (4 pi r^3) along m; on the equator mu0 m / (4 pi r^3) against m
    on_axis = dipole_field(pos + np.array([0, 0, -5.0]), pos, m)[0, 0]
    assert np.allclose(on_axis, [0, 0, 2e-7 * 500 / 125])
    equator = dipole_field(pos + np.array([5.0, 0, 0]), pos, m)[0, 0]
    assert np.allclose(equator, [0, 0, -1e-7 * 500 / 125])


def test_world_field_is_earth_plus_beacons_and_ac_beacons_oscillate() -> None:
    world = World(
        beacon_positions=[[0, 0, 20.0], [100, 0, 20.0]],
        beacon_moments=[[0, 0, 500.0], [0, 0, 300.0]],
        beacon_frequencies=[0.0, 2.0],
        earth_field=[20e-6, 1e-6, 45e-6],
    )
    p = np.array([[3.0, 4.0, 10.0], [90.0, 0.0, 14.0]])
    each = dipole_field(p, world.beacon_positions, world.beacon_moments)
    assert np.allclose(world.magnetic_field(p), world.earth_field + each.sum(0))
    assert world.magnetic_field(p[0]).shape == (3,)
    at = world.beacon_fields(p, t=0.125)  # cos(2 pi 2 0.125) = 0 for the 2 Hz beacon
    assert np.allclose(at[0], each[0]) and np.allclose(at[1], 0.0, atol=1e-20)
    assert np.allclose(world.beacon_fields(p, t=0.25)[1], -each[1])


def test_acoustic_range_and_travel_time() -> None:
    scn = _load("beacons")
    world = World.from_scenario(scn)
    ab = world.acoustic_beacon
    p = ab + np.array([30.0, 40.0, -5.0])
    assert world.acoustic_range(p) == pytest.approx(math.sqrt(30**2 + 40**2 + 25))
    assert world.acoustic_travel_time(p) == pytest.approx(world.acoustic_range(p) / 1510.0)
    with pytest.raises(ValueError, match="no acoustic beacon"):
        World().acoustic_range(p)


def test_point_observations_field_of_view_and_noise_bursts() -> None:
    world = World(points=[[10.0, 0.0], [0.0, 10.0], [-10.0, -1.0], [100.0, 100.0]])
    pose = (0.0, 0.0, math.radians(45.0))
    idx, r, b = world.observe_points(pose, 30.0)
    assert list(idx) == [0, 1, 2]
    assert np.allclose(r[:2], [10.0, 10.0]) and np.allclose(np.degrees(b[:2]), [-45.0, 45.0])
    idx, _, _ = world.observe_points(pose, 30.0, field_of_view=math.pi)  # Bailey's half-plane
    assert list(idx) == [0, 1]
    assert list(world.observe_points(pose, 10.0)[0]) == [], "range strictly less than max"
    assert list(world.observe_points(pose, 10.001)[0]) == [0, 1]
    calm = ObservationSettings(sigma_range_m=0.1, sigma_bearing_deg=1.0)
    mixed = ObservationSettings(
        sigma_range_m=0.1, sigma_bearing_deg=1.0, burst_p=0.3, burst_n=100.0
    )
    rng = np.random.default_rng(9)
    e_calm = np.concatenate(
        [world.observe_points_noisy(pose, calm, rng)[1][:2] - 10 for _ in range(2000)]
    )
    assert 0.095 < np.std(e_calm) < 0.105
    e, bursts = [], []
    for _ in range(3000):
        _, r, _, burst = world.observe_points_noisy(pose, mixed, rng)
        e.append(r - 10.0)
        bursts.append(burst)
    e, bursts = np.concatenate(e), np.concatenate(bursts)
    assert abs(bursts.mean() - 0.3) < 0.02, "bursts are drawn per observation"
    assert np.std(e[bursts]) / np.std(e[~bursts]) == pytest.approx(10.0, rel=0.1)
    a = world.observe_points_noisy(pose, mixed, np.random.default_rng(1))
    bb = world.observe_points_noisy(pose, mixed, np.random.default_rng(1))
    assert np.array_equal(a[1], bb[1]) and np.array_equal(a[3], bb[3])


# -- kinematics ------------------------------------------------------------------------------


def test_motion_model_matches_a_hand_computation() -> None:
    h = math.radians(30.0)
    x, y, z, hh = motion_step(1.0, 2.0, 3.0, h, u=2.0, v=0.5, w=0.1, r=0.2, dt=0.5)
    assert x == pytest.approx(1.0 + (2.0 * math.cos(h) - 0.5 * math.sin(h)) * 0.5)
    assert y == pytest.approx(2.0 + (2.0 * math.sin(h) + 0.5 * math.cos(h)) * 0.5)
    assert z == pytest.approx(3.05) and hh == pytest.approx(h + 0.1)
    # vectorised over particles, identical to the scalar step
    hs = np.array([h, -3.1, 3.1])
    xs, ys, _, hv = motion_step(
        np.ones(3), np.full(3, 2.0), np.zeros(3), hs, 2.0, 0.5, 0.0, 0.2, 0.5
    )
    assert xs[0] == pytest.approx(x) and ys[0] == pytest.approx(y)
    assert np.all(hv >= -math.pi) and np.all(hv < math.pi)
    assert hv[2] == pytest.approx(3.1 + 0.1 - 2 * math.pi)


def test_truth_is_the_motion_model_integrated() -> None:
    scn = _load("survey")
    truth = simulate(scn)
    k = np.arange(0, len(truth) - 1, 97)
    x, y, z, h = motion_step(
        truth.x[k], truth.y[k], truth.z[k], truth.heading[k], truth.u[k], truth.v[k], truth.w[k],
        truth.yaw_rate[k], scn.vehicle.dt_s,
    )  # fmt: skip
    assert np.allclose(x, truth.x[k + 1], atol=1e-9) and np.allclose(y, truth.y[k + 1], atol=1e-9)
    assert np.allclose(z, truth.z[k + 1], atol=1e-9)
    assert np.allclose(np.angle(np.exp(1j * (h - truth.heading[k + 1]))), 0, atol=1e-9)
    assert np.allclose(truth.vn, np.gradient(truth.x, truth.t), atol=0.05)


def _square(**vehicle: object) -> Scenario:
    veh = {"waypoints": [[0, 0], [100, 0], [100, 100], [0, 100]], "speed_mps": 2.0, **vehicle}
    return Scenario.model_validate({"name": "sq", "vehicle": veh})


def test_waypoint_following_with_turn_limit_and_current() -> None:
    scn = _square(max_yaw_rate_dps=12.0, current_mps=[0.3, -0.4], closed=True, depth_m=7.0)
    truth = simulate(scn)
    assert np.degrees(np.abs(truth.yaw_rate)).max() <= 12.0 + 1e-9
    assert np.abs(truth.v).max() > 0.2, "the current makes the vehicle crab"
    assert np.allclose(truth.z, 7.0) and np.allclose(truth.pitch, 0.0)
    # ground speed along the legs: through-water speed plus the current
    ground = np.hypot(truth.vn, truth.ve)
    assert ground.min() > 1.5 and ground.max() < 2.6
    # mid-leg the track stays on the leg (LOS guidance with crab compensation)
    on_leg1 = (truth.x > 30) & (truth.x < 70) & (np.abs(truth.y) < 20)
    assert on_leg1.sum() > 100 and np.abs(truth.y[on_leg1]).max() < 0.5
    # closed: it comes back to the first waypoint and stops there
    assert math.hypot(truth.x[-1], truth.y[-1]) < scn.vehicle.accept_radius_m + 0.1
    assert route_targets(scn.vehicle, starts_at_first=True) == [
        (100, 0),
        (100, 100),
        (0, 100),
        (0, 0),
    ]


def test_truth_interpolation_across_the_heading_wrap() -> None:
    scn = _square(start=[50, -30, 175.0])
    truth = simulate(scn)
    s = truth.at(0.5 * (truth.t[3] + truth.t[4]))
    assert s.x == pytest.approx(0.5 * (truth.x[3] + truth.x[4]))
    i = int(np.flatnonzero(np.abs(np.diff(truth.heading)) > math.pi)[0])
    mid = truth.at(0.5 * (truth.t[i] + truth.t[i + 1]))
    assert abs(mid.heading) > math.pi - 0.1, "interpolated the short way round"
    assert truth.at(-5.0).x == truth.x[0] and truth.at(1e9).x == truth.x[-1]
    assert list(truth.every(8)[:3]) == [8, 16, 24]


def test_after_its_route_the_vehicle_rests_where_it_ended() -> None:
    """Past the last step the pose is held and every motion field is zero (a DVL emulated past
    the route used to report the last step's 1.7 m/s while the truth stood still)."""
    truth = simulate(_square(start=[50, -30, 175.0]))
    end = truth.t[-1]
    last = truth.at(end)
    assert last.speed > 0 and math.hypot(last.vn, last.ve) > 0.5
    s = truth.at(end + 10.0)
    assert (s.x, s.y, s.heading) == pytest.approx((last.x, last.y, last.heading))
    assert s.u == s.v == s.vn == s.ve == s.yaw_rate == s.speed == s.an == 0.0
    both = truth.interp(np.array([end - 1.0, end + 10.0]))  # the array path agrees
    assert both.u[0] == pytest.approx(truth.u[-2], rel=0.2) and both.u[1] == 0.0
    assert both.vn[1] == both.ve[1] == both.yaw_rate[1] == 0.0
    assert (both.x[1], both.y[1]) == pytest.approx((last.x, last.y))


# -- Bailey's bicycle ------------------------------------------------------------------------


def test_compute_steering_and_vehicle_model_by_hand() -> None:
    rate, maxg, dt = math.radians(20), math.radians(30), 0.025
    g, i = compute_steering(0, 0, 0, [(0.0, 10.0)], 0, 1.0, 0.0, rate, maxg, dt)
    assert i == 0 and g == pytest.approx(rate * dt)  # steer-rate limited
    g, i = compute_steering(0, 0, 0, [(0.0, 10.0)], 0, 1.0, math.radians(29.9), rate, maxg, dt)
    assert g == pytest.approx(maxg)  # max-steer limited
    g, i = compute_steering(0, 0, 0, [(0.5, 0.0), (10.0, 0.0)], 0, 1.0, 0.1, rate, maxg, dt)
    assert i == 1 and g == pytest.approx(0.1 - rate * dt)  # switched, turning back to 0
    g, i = compute_steering(9.8, 0, 0, [(0.5, 0.0), (10.0, 0.0)], 1, 1.0, 0.1, rate, maxg, dt)
    assert (g, i) == (0.1, -1)
    x, y, h = bicycle_step(1.0, 2.0, 0.5, 3.0, 0.2, 4.0, 0.025)
    assert x == pytest.approx(1.0 + 0.075 * math.cos(0.7))
    assert y == pytest.approx(2.0 + 0.075 * math.sin(0.7))
    assert h == pytest.approx(0.5 + 0.075 * math.sin(0.2) / 4.0)


def test_bicycle_truth_is_his_model_in_the_papers_form(shared_data: Path) -> None:
    scn = _load("webmap")
    truth = simulate(scn)
    k = np.arange(0, len(truth) - 1, 53)
    x, y, h = bicycle_step(
        truth.x[k], truth.y[k], truth.heading[k], 3.0, truth.steer[k], 4.0, 0.025
    )
    assert np.allclose(x, truth.x[k + 1]) and np.allclose(y, truth.y[k + 1])
    xm, ym, _, hm = motion_step(
        truth.x[k],
        truth.y[k],
        0,
        truth.heading[k],
        truth.u[k],
        truth.v[k],
        0,
        truth.yaw_rate[k],
        0.025,
    )
    assert np.allclose(xm, x) and np.allclose(ym, y) and np.allclose(hm, h)
    # the steer angle never changes faster than 20 deg/s
    assert np.degrees(np.abs(np.diff(truth.steer))).max() <= 20 * 0.025 + 1e-9
    vn, gn = control_noise(truth.speed, truth.steer, 0.3, math.radians(3), np.random.default_rng(4))
    assert 0.27 < np.std(vn - 3.0) < 0.33
    assert 2.7 < np.degrees(np.std(gn - truth.steer)) < 3.3


# -- clock -----------------------------------------------------------------------------------


def test_clock_speed_factor_with_an_injected_host_clock() -> None:
    host = [100.0]
    c = SimClock(speed=10.0, start_time=5.0, time_fn=lambda: host[0])
    assert c.now() == 5.0
    c.start()
    host[0] += 0.3
    assert c.now() == pytest.approx(8.0)
    c.set_speed(2.0)
    host[0] += 1.0
    assert c.now() == pytest.approx(10.0)
    c.set_speed(0.0)
    host[0] += 50.0
    assert c.now() == pytest.approx(10.0), "speed 0: time only moves by events"
    assert c.real_duration(4.0) == 0.0
    with pytest.raises(ValueError):
        SimClock(speed=-1)


def test_lockstep_holds_vehicle_time_until_answered_and_times_out_a_silent_controller(
    tmp_path: Path,
) -> None:
    from auvgw.ground.simclock import ClockFileReader, ClockFileWriter

    host = [100.0]
    c = SimClock(speed=4.0, time_fn=lambda: host[0])
    writer = ClockFileWriter(tmp_path / "clock")
    reader = ClockFileReader(tmp_path / "clock")
    assert reader.state() is None, "nothing published yet"
    c.lockstep(0.15, 5.0, 1.0, lambda *a: writer.publish(*a, epoch_ns=7_000_000_000))
    c.start()
    host[0] += 0.1
    assert c.now() == pytest.approx(0.4)
    host[0] += 3.0  # a stalled controller: vehicle time stands at the first limit
    assert c.now() == pytest.approx(1.0) and c.holds == 1
    c.answered(0.8)  # an answer inside the limit moves nothing
    assert c.limit == 1.0
    c.answered(2.0)  # vehicle time runs on from where it stood, not from the host clock
    assert c.limit == pytest.approx(2.15)
    host[0] += 0.2
    assert c.now() == pytest.approx(1.8) and c.held_s == pytest.approx(2.85)
    # the file carries every anchor; a reader computes the same time from its own host clock
    st = reader.state()
    assert st is not None and st[2] == 4.0 and st[3] == pytest.approx(2.15)
    assert st.vehicle_s(host[0]) == pytest.approx(1.8)
    assert st.vehicle_s(host[0] - 5.0) == pytest.approx(1.0), "no extrapolation back"
    assert st.vehicle_s(host[0] + 60.0) == pytest.approx(2.15), "held at the limit"
    # a hold longer than the timeout moves one step on and is counted
    host[0] += 1.0
    assert c.now() == pytest.approx(2.15) and c.holds == 2
    host[0] += 4.0  # 4.9 s after it reached the limit
    assert c.now() == pytest.approx(2.15) and c.hold_timeouts == 0
    host[0] += 0.2
    assert c.now() == pytest.approx(2.15) and c.hold_timeouts == 1
    host[0] += 0.01
    assert c.now() == pytest.approx(2.19) and c.limit == pytest.approx(2.3)
    # the gateway's clock on that file: stamps and its silence watchdog's clock stand at the
    # limit while the sim holds there (this host's clock is long past the fake anchors)
    from auvgw.config.gateway import ClockConfig

    gw = ClockConfig(time_scale=4.0, epoch_ns=7_000_000_000, sim_clock=str(tmp_path / "clock"))
    assert gw.stamp(time.time_ns()) == 7_000_000_000 + 2_300_000_000
    assert gw.paced_monotonic() == pytest.approx(2.3 / 4.0)
    with pytest.raises(ValueError):
        SimClock(speed=0).lockstep(0.15, 5.0, 1.0)
    writer.close()
    reader.close()


def test_lockstep_answers_wait_for_the_command_they_carry() -> None:
    """The command's way back (issue 30): an answer counts once the emulated actuators have
    applied its command's seq, or a newer one (a lost command is covered by the next)."""
    from auvgw.drivers.actuators import SEQ_MODULO
    from auvgw.sim_devices.actuators import CommandGate

    host = [0.0]
    c = SimClock(speed=1.0, time_fn=lambda: host[0])
    c.lockstep(0.15, 5.0, 1.0)
    c.start()
    gate = CommandGate(c.answered)
    gate.answered(0.5, None)  # no command yet (a pilot before its first step): counts at once
    gate.answered(0.6, 0)
    assert c.answers == 2 and c.limit == 1.0
    gate.answered(1.0, 1)  # command 1 still crossing the gateway and the CAN bus
    gate.answered(1.05, 1)
    gate.answered(1.1, 2)
    assert c.answers == 2 and c.limit == 1.0 and gate.pending == 3 and gate.waited == 3
    host[0] = 2.0
    assert c.now() == pytest.approx(1.0), "held: the answers do not count yet"
    gate.applied(1)  # the answers of command 1 pass, not command 2's
    assert c.answers == 4 and c.limit == pytest.approx(1.2) and gate.pending == 1
    gate.answered(1.2, 3)
    gate.applied(3)  # command 2 lost on its way: command 3 covers both answers
    assert c.answers == 6 and c.limit == pytest.approx(1.35) and gate.pending == 0
    gate.answered(1.3, 3)  # applied already: counts at once
    assert c.answers == 7 and c.limit == pytest.approx(1.45)
    # the sequence wraps: SEQ_MODULO - 1 is older than 2, and 5 is newer than 3
    gate.applied(SEQ_MODULO - 1)
    gate.answered(1.4, 2)
    assert gate.pending == 1
    gate.applied(5)
    assert gate.pending == 0 and c.limit == pytest.approx(1.55)
    assert c.hold_timeouts == 0


def _slow_ticks(clock: SimClock, host_s: float, n_slow: int) -> list[float]:
    """Run ``clock`` (50x) to vehicle 0.3 s with a 100 Hz tick whose first ``n_slow``
    callbacks take ``host_s`` host s each (a loaded host); each tick's lag, vehicle s."""
    lags: list[float] = []

    def tick(t: float) -> None:
        lags.append(clock.now() - t)
        if len(lags) <= n_slow:
            time.sleep(host_s)

    clock.every(0.01, tick, start=0.0)
    clock.run(until=0.3)
    return lags


def test_elastic_clock_holds_vehicle_time_on_its_dispatch_where_a_free_one_runs_late() -> None:
    # 10 host ms per tick at 50x is 0.5 vehicle s per 0.01 s tick: a free clock falls behind
    free = SimClock(speed=50.0)
    lags = _slow_ticks(free, 0.01, 10)
    assert max(lags) > 4.0 and free.late_ticks >= 10 and free.holds == 0
    elastic = SimClock(speed=50.0)
    elastic.elastic(0.2)
    lags = _slow_ticks(elastic, 0.01, 10)
    assert len(lags) == 31, "every tick dispatched"
    # vehicle time never ran more than the lag past the tick being dispatched
    assert max(lags) <= 0.2 + 1e-9
    assert elastic.holds >= 1 and elastic.held_s > 0 and elastic.hold_timeouts == 0
    assert elastic.late_ticks == sum(lag > 0.01 for lag in lags)
    with pytest.raises(ValueError):
        SimClock(speed=0).elastic(0.2)


def test_elastic_clock_in_another_process_holds_the_one_shared_clock(tmp_path: Path) -> None:
    """A device process's clock follows the holder's clock file and reports its dispatch on
    the board; the holder (polled as DeviceProcesses does) stands still while it is behind,
    and the gateway stamps that held time."""
    from auvgw.config.gateway import ClockConfig
    from auvgw.ground.simclock import ClockFileReader, ClockFileWriter, DispatchBoard

    holder = SimClock(speed=50.0)
    writer = ClockFileWriter(tmp_path / "clock")
    start = time.monotonic() + 0.05
    holder.elastic(0.2, on_anchor=lambda *a: writer.publish(*a, epoch_ns=10**18))
    writer.publish(0.0, start, 50.0, holder.limit, 10**18)
    board = DispatchBoard(tmp_path / "clock.dispatch", 2)
    assert board.least([0, 1]) == 0.0 and board.least([]) == math.inf
    board.report(1, math.inf)  # a second device with nothing left to send
    device = SimClock(speed=50.0)
    reader = ClockFileReader(tmp_path / "clock")
    device.follow(reader.state, lambda t: board.report(0, t))
    assert device.following and not holder.following
    stop = threading.Event()
    stamps: list[float] = []
    gateway = ClockConfig(time_scale=50.0, epoch_ns=10**18, sim_clock=str(tmp_path / "clock"))

    def poll() -> None:
        while not stop.wait(0.001):
            holder.report(board.least([0, 1]))
            stamps.append((gateway.stamp(time.time_ns()) - 10**18) / 1e9 - board.pending(0))

    holder.report(board.least([0, 1]))  # before the start: the device has sent nothing
    holder.start(at=start)
    holder.start_thread(until=0.3)  # the holder's own dispatch (DeviceProcesses: the truth's)
    device.start(at=start)
    poller = threading.Thread(target=poll, daemon=True)
    poller.start()
    try:
        lags = _slow_ticks(device, 0.01, 10)
    finally:
        stop.set()
        poller.join(5)
    assert len(lags) == 31 and max(lags) <= 0.2 + 1e-9
    assert holder.holds >= 1 and holder.hold_timeouts == 0
    # the gateway's stamps never ran more than the lag past what the device had dispatched
    assert stamps and max(stamps) <= 0.2 + 1e-6
    assert board.pending(0) == pytest.approx(0.3)  # reached the end
    holder.close()
    # a writer the host stops in the middle of an update (an odd sequence number, issue 33's
    # loaded host): the readers keep the value before it instead of failing
    import struct

    state = reader.state()
    for m in (board._map, writer._map):
        m[0:8] = struct.pack("<Q", 10**6 + 1)
    assert board.pending(0) == pytest.approx(0.3) and reader.state() == state
    for f in (writer, reader, board):
        f.close()


def test_clock_start_at_a_given_host_instant() -> None:
    host = [100.0]
    c = SimClock(speed=10.0, time_fn=lambda: host[0])
    assert c.started_at is None
    c.start(at=100.5)  # vehicle time 0 half a real second from now
    assert c.now() == pytest.approx(-5.0) and c.started_at == 100.5
    host[0] = 101.0
    assert c.now() == pytest.approx(5.0)
    c.start(at=200.0)  # already running: no change
    assert c.now() == pytest.approx(5.0)
    # a tick at vehicle time 0 waits for the instant (a real clock, 50 x real time)
    real = SimClock(speed=50.0)
    real.start(at=time.monotonic() + 0.2)
    fired: list[float] = []
    real.at(0.0, lambda t: (fired.append(real.now()), real.stop()))
    real.run()
    assert fired and fired[0] >= 0.0, "not dispatched before vehicle time 0"


def test_clock_as_fast_as_possible_dispatches_every_tick_in_order() -> None:
    c = SimClock(speed=0)
    log: list[tuple[str, float, float]] = []
    c.every(0.01, lambda t: log.append(("ins", t, c.now())))
    c.every(1 / 7, lambda t: log.append(("dvl", t, c.now())), start=0.05)
    c.at(3.3, lambda t: log.append(("once", t, c.now())))
    seen: list[tuple[float, float]] = []

    def worker() -> None:
        with c.participant():
            t = 0.0
            while t < 10.0 and c.sleep_until(t := t + 0.25):
                seen.append((t, c.now()))

    th = threading.Thread(target=worker)
    th.start()
    c.run(until=100.0)
    th.join(5.0)
    assert c.now() == 100.0
    ts = [e[1] for e in log]
    assert ts == sorted(ts) and all(e[1] == e[2] for e in log)
    assert sum(e[0] == "ins" for e in log) == 10001
    assert [e[1] for e in log if e[0] == "dvl"][:3] == pytest.approx(
        [0.05, 0.05 + 1 / 7, 0.05 + 2 / 7]
    )
    assert [e for e in log if e[0] == "once"] == [("once", 3.3, 3.3)]
    assert len(seen) == 40 and all(a == b for a, b in seen), "a participant sees exact times"


def test_clock_real_time_runs_k_times_faster() -> None:
    c = SimClock(speed=20.0)
    ticks: list[float] = []
    c.every(0.1, ticks.append)
    t0 = time.monotonic()
    c.run(until=1.0)
    real = time.monotonic() - t0
    assert ticks == pytest.approx([0.1 * i for i in range(11)])
    assert c.now() >= 1.0
    assert real >= 1.0 / 20.0 - 0.01, "never runs ahead of 20 x real time"


def test_clock_stop_wakes_sleepers_and_callback_errors_propagate() -> None:
    c = SimClock(speed=1.0)
    c.start()
    result: list[bool] = []
    th = threading.Thread(target=lambda: result.append(c.sleep_until(1e9)))
    th.start()
    c.stop()
    th.join(5.0)
    assert result == [False]

    c2 = SimClock(speed=0)
    c2.every(1.0, lambda t: 1 / 0 if t >= 3 else None)
    with pytest.raises(ZeroDivisionError):
        c2.run(until=10.0)
    assert c2.stopped and c2.now() == 3.0


def test_clock_external_events_are_scheduled_while_running() -> None:
    """A host request (another thread) schedules a reply, as the polled MSIS will."""
    c = SimClock(speed=50.0)
    replies: list[float] = []
    ticks: list[float] = []
    c.every(0.5, ticks.append)
    th = c.start_thread()
    while c.now() < 1.0:
        time.sleep(0.001)
    asked = c.now()
    c.at(asked + 0.2, replies.append)
    end = time.monotonic() + 10
    while not replies and time.monotonic() < end:
        time.sleep(0.001)
    c.close()
    c.join()
    assert replies == [pytest.approx(asked + 0.2)]
    assert ticks[:3] == [0.0, 0.5, 1.0]
    assert not th.is_alive()


def test_the_documented_example_scenario_loads_and_drives(tmp_path: Path) -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "scenarios.md").read_text()
    example = doc.split("## A small example", 1)[1].split("```json", 1)[1].split("```", 1)[0]
    scn = load_scenario(_write(tmp_path, json.loads(example)))
    truth = simulate(scn)
    assert math.hypot(truth.x[-1] - 80, truth.y[-1] - 30) < scn.vehicle.accept_radius_m + 0.1
    hits = World.from_scenario(scn).cast((40.0, 0.0), math.pi / 2, 50.0)  # east, onto the pier
    assert hits.kind[0] == 1 and hits.range_m[0] == pytest.approx(15.0)
