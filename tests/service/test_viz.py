"""Rerun logger and blueprint: record a short synthetic run, read the .rrd back, check content."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import rerun.blueprint as rrb
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.viz import entities as ent
from auvgw.viz.blueprint import VIEW_NAMES, default_blueprint, save_blueprint
from auvgw.viz.entities import PILOT_VIEWS
from auvgw.viz.logger import (
    RerunLogger,
    VizOptions,
    attitude_quaternion,
    depth_colours,
    ellipse_strips,
)
from auvgw.viz.readback import health_metrics, read_recording, read_views
from auvgw.viz.synthetic import Rates, SyntheticWorld, synthetic_calls
from auvgw.viz.views import VIEWS

T0 = 1_700_000_000.0
DURATION = 12.0
NS = 1e9


def _image(row_buffer, fmt) -> np.ndarray:
    f = fmt[0]
    raw = np.asarray(row_buffer[0], dtype=np.uint8)
    if f["channel_datatype"] == 34:  # F32
        raw = raw.view(np.float32)
    return raw.reshape(f["height"], f["width"])


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, list, dict]:
    """12 s of the synthetic run through the logger, read back."""
    path = tmp_path_factory.mktemp("viz") / "run.rrd"
    calls = synthetic_calls(DURATION, t0=T0)
    logger = RerunLogger(rrd=path, options=VizOptions(queue_size=len(calls) + 10))
    queued = sum(bool(getattr(logger, n)(*a, **kw)) for n, a, kw in calls)
    logger.close()
    assert queued == len(calls)
    st_ = logger.stats()
    assert (st_.processed, st_.dropped, st_.errors) == (len(calls), 0, 0)
    return path, calls, read_recording(path)


def _calls(calls, name):
    return [(a, kw) for n, a, kw in calls if n == name]


def test_entity_paths(recording) -> None:
    _, _, rec = recording
    expected = {
        ent.INS_ATTITUDE, ent.INS_HEADING, ent.VEHICLE, ent.DVL_VELOCITY, ent.DVL_ALTITUDE,
        ent.DVL_BOTTOM_LOCK,
        ent.MAG_FIELD, ent.MAG_MAGNITUDE, ent.VEHICLE_MAG, ent.SOUNDINGS, ent.MAP_BATHYMETRY,
        ent.MEAN_DEPTH, ent.SONAR_FAN, ent.SONAR_BEAM, "map/truth/track", "world/truth/track",
        "map/truth/pose",
        "map/dead_reckoning/track", "map/dead_reckoning/pose", "map/slam/fastslam2/track",
        "map/slam/fastslam2/landmarks",
        "map/slam/fastslam2/lines", "map/slam/fastslam2/line_cov", "map/slam/fastslam2/particles",
        "health/rate/ins", "health/flags/ins", "health/count/ins", ent.HEALTH_COUNTERS,
        "health/mbes/events", ent.MAP_GRID, ent.DEPTH_SCALE, ent.SONAR_RINGS, ent.MAG_CHANGE,
    }  # fmt: skip
    assert expected <= set(rec)
    assert {p for p in rec if not rec[p].static and not len(rec[p])} <= {"__properties"}


def test_row_counts_per_stream(recording) -> None:
    _, calls, rec = recording
    n_att = len(_calls(calls, "attitude"))
    assert n_att == DURATION * 100
    assert len(rec[ent.INS_ATTITUDE]) == n_att
    assert len(rec[ent.VEHICLE]) == n_att / 5  # transform at 20 Hz, series at 100 Hz
    assert len(rec[ent.DVL_VELOCITY]) == len(_calls(calls, "dvl")) == DURATION * 5
    assert len(rec[ent.MAG_FIELD]) == len(rec[ent.VEHICLE_MAG]) == DURATION * 20
    swaths = _calls(calls, "swath")
    assert len(rec[ent.SOUNDINGS]) == len(swaths) == DURATION * 5
    n_points = [len(p) for p in rec[ent.SOUNDINGS].values("Points3D:positions")]
    assert n_points == [256] * len(swaths)
    n_slam = len(_calls(calls, "landmarks"))
    for what in ("landmarks", "lines", "line_cov", "particles"):
        assert len(rec[f"map/slam/fastslam2/{what}"]) == n_slam
    parts = rec["map/slam/fastslam2/particles"].values("Points2D:positions")
    assert {len(p) for p in parts} == {min(Rates().particles, VizOptions().max_particles)}
    # health: one unit per view (rates, flags); the cumulative counters in no view, as a table
    health = health_metrics(rec, "dvl")
    assert len(health) == DURATION
    assert health[0][1] == {"rate_hz": 5.0, "bad_frames": 0.0, "connected": 1.0}
    assert rec["health/rate/dvl"].static["SeriesLines:names"] == ["dvl rate_hz"]
    assert rec["health/flags/dvl"].static["SeriesLines:names"] == ["dvl connected"]
    table = rec[ent.HEALTH_COUNTERS].values("TextDocument:text")[-1][0]
    assert "| dvl | bad_frames 0 |" in table


def test_values_against_truth(recording) -> None:
    _, calls, rec = recording
    world = SyntheticWorld()
    # INS attitude in degrees, in time order
    att = np.array(rec[ent.INS_ATTITUDE].values("Scalars:scalars"))
    first = _calls(calls, "attitude")[100][0]
    assert rec[ent.INS_ATTITUDE].times[100] == pytest.approx(first[0] * NS, abs=1e3)
    assert att[100] == pytest.approx([math.degrees(first[1]), math.degrees(first[2])], abs=1e-9)
    # the heading on its own axis, 0-360 deg, at the same time
    hdg = np.array(rec[ent.INS_HEADING].values("Scalars:scalars"))
    assert rec[ent.INS_HEADING].times[100] == rec[ent.INS_ATTITUDE].times[100]
    assert hdg[100] == pytest.approx([math.degrees(first[3]) % 360.0], abs=1e-9)
    # vehicle transform: the attitude quaternion
    q = rec[ent.VEHICLE].values("Transform3D:quaternion")[20][0]
    assert rec[ent.VEHICLE].times[20] == rec[ent.INS_ATTITUDE].times[100]
    assert q == pytest.approx(attitude_quaternion(*first[1:4]), abs=1e-6)
    # DVL altitude = seabed depth below the vehicle
    times = rec[ent.DVL_ALTITUDE].times / NS - T0
    x, y, _ = world.pose(times)
    alt = np.array(rec[ent.DVL_ALTITUDE].values("Scalars:scalars"))[:, 0]
    assert alt == pytest.approx(world.seabed(x, y) - world.depth_m, abs=1e-6)
    # magnitude series = |B|
    b = np.array(rec[ent.MAG_FIELD].values("Scalars:scalars"))
    mag = np.array(rec[ent.MAG_MAGNITUDE].values("Scalars:scalars"))[:, 0]
    assert mag == pytest.approx(np.linalg.norm(b, axis=1))
    # the departure from a running mean (10 s), where a few nT show against tens of thousands
    change = np.array(rec[ent.MAG_CHANGE].values("Scalars:scalars"))
    t = rec[ent.MAG_FIELD].times / NS
    mean = b[0].copy()
    for k in range(1, len(b)):
        mean += (1.0 - math.exp(-(t[k] - t[k - 1]) / 10.0)) * (b[k] - mean)
    assert change[-1] == pytest.approx(b[-1] - mean, abs=1e-6)
    assert change[0] == pytest.approx([0.0, 0.0, 0.0])


def test_truth_track_is_the_truth_path(recording) -> None:
    _, _, rec = recording
    world = SyntheticWorld()
    strips = rec["map/truth/track"].values("LineStrips2D:strips")
    verts = [np.asarray(s[0]) for s in strips]
    # consecutive segments join: each starts where the previous one ended
    for a, b in itertools.pairwise(verts):
        assert b[0] == pytest.approx(a[-1])
    uv = np.concatenate([verts[0], *[v[1:] for v in verts[1:]]])
    north, east = -uv[:, 1], uv[:, 0]  # map stores (east, -north)
    step = np.hypot(np.diff(north), np.diff(east))
    assert step.min() >= VizOptions().track_min_step_m - 1e-4
    # every vertex lies on the circle of the synthetic path
    r = np.hypot(north, east - world.radius_m)
    assert r == pytest.approx(world.radius_m, abs=1e-3)
    end = world.pose(np.array([DURATION - 0.01]))
    assert north[-1] == pytest.approx(end[0][0], abs=0.2)
    assert east[-1] == pytest.approx(end[1][0], abs=0.2)


def test_soundings_and_grid_follow_the_seabed(recording) -> None:
    _, _, rec = recording
    world = SyntheticWorld()
    pts = np.concatenate([np.asarray(p) for p in rec[ent.SOUNDINGS].values("Points3D:positions")])
    assert pts[:, 2] == pytest.approx(world.seabed(pts[:, 0], pts[:, 1]), abs=0.3)
    colours = np.concatenate([np.asarray(c) for c in rec[ent.SOUNDINGS].values("Points3D:colors")])
    assert len(np.unique(colours)) > 20  # coloured by depth, not one colour
    grid = rec[ent.MEAN_DEPTH]
    assert len(grid) == 1  # the product, at the end
    img = _image(grid.values("DepthImage:buffer")[-1], grid.values("DepthImage:format")[-1])
    u0, v0, _ = grid.values("Transform3D:translation")[-1][0]
    cell = grid.values("Transform3D:scale")[-1][0][0]
    rows, cols = np.nonzero(img)
    assert len(rows) > 1000
    east = u0 + (cols + 0.5) * cell
    north = -(v0 + (rows + 0.5) * cell)
    # a 1 m cell averages soundings up to 0.7 m from its centre: the seabed slope is < 0.1
    assert img[rows, cols] == pytest.approx(world.seabed(north, east), abs=0.2)
    # the map shows every updated cell as a disc in depth colours, accumulated over the run
    shown = rec[ent.MAP_BATHYMETRY]
    assert len(shown) == 3  # at the first ping, after 10 s, at the end
    discs = np.concatenate([np.asarray(p) for p in shown.values("Points2D:positions")])
    cells = {(round((u - u0) / cell - 0.5), round((v - v0) / cell - 0.5)) for u, v in discs}
    assert cells == set(zip(cols.tolist(), rows.tolist(), strict=True))
    last = np.asarray(shown.values("Points2D:colors")[-1])
    assert len(np.unique(last)) > 20


def test_landmark_ellipses_are_two_sigma(recording) -> None:
    _, calls, rec = recording
    (_, _, mean, cov, ids), _ = _calls(calls, "landmarks")[-1]
    lm = rec["map/slam/fastslam2/landmarks"]
    assert lm.values("Points2D:labels")[-1] == [str(i) for i in ids]
    pos = np.asarray(lm.values("Points2D:positions")[-1])
    assert pos == pytest.approx(np.column_stack([mean[:, 1], -mean[:, 0]]), abs=1e-4)
    strips = rec["map/slam/fastslam2/landmarks"].values("LineStrips2D:strips")[-1]
    assert len(strips) == len(mean)
    e = np.asarray(strips[0])
    # half extent along east (u) is 2 sigma_east, along north (v) 2 sigma_north
    assert (e[:, 0].max() - e[:, 0].min()) / 2 == pytest.approx(
        2 * math.sqrt(cov[0, 1, 1]), rel=0.01
    )
    assert (e[:, 1].max() - e[:, 1].min()) / 2 == pytest.approx(
        2 * math.sqrt(cov[0, 0, 0]), rel=0.01
    )


def test_sonar_fan_accumulates_and_resets(tmp_path) -> None:
    """A continuous 360 deg scan: a ring at half range, a wedge only in the second sweep."""
    path = tmp_path / "fan.rrd"
    opts = VizOptions(fan_pixels=128, fan_period_s=1e9)  # log only completed sweeps (+ close)
    logger = RerunLogger(rrd=path, options=opts)
    step = math.radians(3.6)  # 100 pings a turn
    ring = np.zeros(300, dtype=np.uint8)
    ring[148:152] = 200
    for i in range(150):
        bins = ring.copy()
        if i >= 100 and 110 <= i < 120:  # second sweep: a target at 36-72 deg, far range
            bins[250:260] = 255
        logger.msis_ping(T0 + i / 30, (i * step) % (2 * math.pi), bins, 50.0, step)
    logger.close()
    fan = read_recording(path)[ent.SONAR_FAN]
    assert len(fan) == 3  # logged at t0 (first line), the completed sweep, and at close
    fmt = fan.values("SegmentationImage:format")
    first_sweep = _image(fan.values("SegmentationImage:buffer")[1], fmt[1])
    last = _image(fan.values("SegmentationImage:buffer")[2], fmt[2])
    c, rad = (128 - 1) / 2, 64.0
    yy, xx = np.mgrid[0:128, 0:128]
    r = np.hypot(xx - c, c - yy) / rad
    ang = np.degrees(np.mod(np.arctan2(xx - c, c - yy), 2 * np.pi))
    on_ring = np.abs(r - 0.5) < 0.003
    assert (first_sweep[on_ring] == 200).mean() > 0.95  # the whole ring after one turn
    assert first_sweep[r > 0.8].max() < 255  # no wedge in the first sweep
    wedge = (r > 0.84) & (r < 0.86) & (ang > 42) & (ang < 66)
    assert (last[wedge] == 255).all()  # second sweep paints the wedge ...
    assert (last[on_ring & (ang > 190)] == 0).all()  # ... and was reset: half a turn only
    # the levels as the head sent them, drawn in the colours of an annotation context whose
    # scale runs from just below the sweep's median level (black) to its strongest echo (a
    # display gain); no return black
    ctx = read_recording(path)[ent.SONAR].values("AnnotationContext:context")[-1][0]
    colour = {c["class_id"]: c["class_description"]["info"]["color"] for c in ctx}
    lo = int(np.median(last[last > 0])) - 1
    assert colour[0] == 0x000000FF  # no return: black
    assert colour[lo] == 0x000004FF  # just below the median level: the bottom of the scale
    assert colour[255] == 0xFCFFA4FF  # the strongest echo: the top of the scale
    red = [colour[v] >> 24 for v in range(lo, 256)]
    assert red == sorted(red) and red[1] > red[0]  # darker to brighter between
    rings = read_recording(path)[f"{ent.SONAR_RINGS}/labels"].static
    assert rings["Points2D:labels"] == ["12.5 m", "25 m", "37.5 m", "50 m"]


def test_blueprint_names_its_views(tmp_path, recording) -> None:
    bp_file = save_blueprint(tmp_path / "auvgw.rbl")
    views = read_views(bp_file)
    assert sorted(name for _, name, _ in views) == sorted([*VIEW_NAMES, *PILOT_VIEWS.values()])
    assert {(o, n) for _, n, o in views} >= set(PILOT_VIEWS.items())  # one unit per pilot view
    kinds = {name.split(" (")[0]: (cls, origin) for cls, name, origin in views}  # no units
    assert kinds["Map"] == ("2D", "map")
    assert kinds["Swath & bathymetry"] == ("3D", "world")
    assert kinds["Sonar fan"] == ("2D", "sonar")
    assert kinds["Roll & pitch"] == ("TimeSeries", "ins/attitude")
    assert kinds["Heading"] == ("TimeSeries", "ins/heading")
    # m/s, metres and the 0/1 lock flag each on their own axis
    assert kinds["DVL velocity"] == ("TimeSeries", "dvl/velocity")
    assert kinds["Altitude"] == ("TimeSeries", "dvl/altitude")
    assert kinds["Bottom lock"] == ("TimeSeries", "dvl/bottom_lock")
    assert kinds["Magnetic field minus its 10 s mean"] == ("TimeSeries", "mag/change")
    # health: one view per unit, the counters as text
    assert kinds["Message rate"] == ("TimeSeries", "health/rate")
    assert kinds["Transport lag"] == ("TimeSeries", "health/lag")
    assert kinds["Connected & stale"] == ("TimeSeries", "health/flags")
    assert kinds["Counters"] == ("TextDocument", "health/counters")
    assert not any(o.startswith("health/count/") or o == "health" for c, o in kinds.values()
                   if c == "TimeSeries")  # fmt: skip
    # the recording carries the layout, re-sent with the SLAM track once it appeared
    path, _, _ = recording
    every = sorted([*VIEW_NAMES, *PILOT_VIEWS.values()])
    assert sorted(name for _, name, _ in read_views(path)) == every
    bp = default_blueprint(["slam/fastslam2"])
    names = {v.name for v in _views(bp.root_container)}
    assert names == set(every)
    map_view = next(v for v in _views(bp.root_container) if v.name.startswith("Map"))
    assert {"map/truth/track", "map/slam/fastslam2/track"} <= set(map_view.visualizer_overrides)


def _views(container):
    for c in container.contents:
        if isinstance(c, rrb.Container):
            yield from _views(c)
        else:
            yield c


def test_full_queue_drops_with_a_counter(tmp_path) -> None:
    path = tmp_path / "drops.rrd"
    logger = RerunLogger(rrd=path, options=VizOptions(queue_size=10), autostart=False)
    results = [logger.dvl(T0 + i * 0.2, (1.0, 0.0, 0.0), 10.0) for i in range(50)]
    assert results == [True] * 10 + [False] * 40  # returned at once, nothing consumed the queue
    assert results.count(False) == logger.stats().dropped == 40
    assert logger.stats().dropped_by_kind == {"dvl": 40}
    logger.close()
    assert not logger.dvl(T0 + 99, (1.0, 0.0, 0.0))  # closed: dropped too
    st_ = logger.stats()
    assert (st_.processed, st_.dropped) == (10, 41)
    rec = read_recording(path)
    assert len(rec[ent.DVL_VELOCITY]) == 10
    assert rec[ent.VIZ_DROPPED].values("Scalars:scalars")[-1] == [40.0]


def test_inconsistent_arrays_are_refused_at_the_call(tmp_path) -> None:
    logger = RerunLogger(rrd=tmp_path / "bad.rrd")
    with pytest.raises(ValueError, match=r"lines: arrays of different lengths.*rho.*2.*theta.*1"):
        logger.lines("x", T0, [1.0, 2.0], [0.0])
    with pytest.raises(ValueError, match="landmarks"):
        logger.landmarks("x", T0, np.zeros((3, 2)), cov=np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="swath"):
        logger.swath(T0, [0.0, 1.0], [0.0], [1.0, 1.0])
    logger.close()
    assert logger.stats().processed == 0


def test_failing_item_is_counted_not_fatal(tmp_path) -> None:
    """The logging thread survives an item it cannot log (white box: a malformed item)."""
    path = tmp_path / "bad.rrd"
    logger = RerunLogger(rrd=path)
    logger.landmarks("x", T0, np.zeros((3, 2)), cov=np.zeros((3, 2, 2)), ids=[1, 2, 3])
    assert logger._put("lines", ("x", T0, np.ones(2)), T0)  # too few arguments
    logger.dvl(T0 + 1, (0.5, 0.0, 0.0), 3.0)
    logger.close()
    st_ = logger.stats()
    assert (st_.processed, st_.errors) == (3, 1) and "lines" in st_.last_error
    rec = read_recording(path)
    assert len(rec[ent.DVL_VELOCITY]) == 1 and len(rec["map/x/landmarks"]) == 1


def test_every_view_is_one_class_and_one_row(tmp_path) -> None:
    """The logger's table of views: one row per class, kinds unique, each class with a logging
    method of its own, and each kind what one of the logger's methods queues (white box)."""
    kinds = [v.kind for v in VIEWS]
    assert len(set(kinds)) == len(kinds) and all(kinds)
    assert all("log" in vars(v) for v in VIEWS), [v.__name__ for v in VIEWS if "log" not in vars(v)]
    logger = RerunLogger(rrd=tmp_path / "kinds.rrd", autostart=False)
    xy = np.zeros((2, 2))
    logger.trajectory("truth", T0, 0.0, 0.0)
    logger.landmarks("truth", T0, xy)
    logger.lines("truth", T0, [1.0], [0.0])
    logger.particles("slam/x", T0, xy)
    logger.ranges("slam/x", T0, (0.0, 0.0), xy)
    logger.acoustic_beacon("truth", T0, 1.0, 2.0)
    logger.attitude(T0, 0.0, 0.0, 0.0)
    logger.dvl(T0, (0.0, 0.0, 0.0))
    logger.magnetometer(T0, (1.0, 2.0, 3.0))
    logger.msis_ping(T0, 0.0, np.zeros(10), 10.0)
    logger.raw_ping("gs", T0, 0, [1.0], [2.0], [3.0])
    logger.swath(T0, [0.0], [0.0], [10.0])
    logger.seabed("slam/x", T0, [[0.0, 0.0, 10.0]])
    logger.dem("slam/x", T0, 0.0, 0.0, 1.0, [[10.0]])
    logger.health("ins", T0, {"rate_hz": 1.0})
    logger.series("pilot/leg", T0, {"leg": 1.0})
    logger.event("ins", T0, "hello")
    queued = sorted(kind for kind, _, _ in list(logger._w_inbox.queue.queue))
    assert queued == sorted(kinds)
    logger.close()
    assert (logger.stats().processed, logger.stats().errors) == (len(kinds), 0)


def test_options_and_outputs_are_checked(tmp_path) -> None:
    with pytest.raises(ValueError, match="needs an output"):
        RerunLogger()
    with pytest.raises(ValueError, match="map_frame"):
        RerunLogger(rrd=tmp_path / "x.rrd", options=VizOptions(map_frame="enu"))  # type: ignore[arg-type]


def test_xy_frame_maps_y_up(tmp_path) -> None:
    path = tmp_path / "xy.rrd"
    logger = RerunLogger(rrd=path, options=VizOptions(map_frame="xy", time_kind="duration"))
    for i in range(30):
        logger.trajectory("truth", float(i), float(i), 2.0 * i, heading=0.0)
    logger.close()
    rec = read_recording(path)
    verts = np.concatenate(
        [np.asarray(s[0]) for s in rec["map/truth/track"].values("LineStrips2D:strips")]
    )
    assert verts[-1] == pytest.approx([29.0, -58.0])  # (x, -y)
    pose = rec["map/truth/pose"]
    assert pose.values("Arrows2D:vectors")[-1][0] == pytest.approx([3.0, 0.0])
    assert pose.times[-1] == 29 * NS


@settings(max_examples=100, deadline=None)
@given(
    sx=st.floats(0.01, 100.0), sy=st.floats(0.01, 100.0), rho=st.floats(-0.95, 0.95),
    cx=st.floats(-1e3, 1e3), cy=st.floats(-1e3, 1e3), k=st.floats(1.0, 3.0),
)  # fmt: skip
def test_ellipse_vertices_sit_at_k_sigma(sx, sy, rho, cx, cy, k) -> None:
    cov = np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]])
    e = ellipse_strips(np.array([[cx, cy]]), cov[None], sigma=k, vertices=17)[0]
    d = e - [cx, cy]
    m = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    assert m == pytest.approx(np.full(17, k * k), rel=1e-6)
    assert e[0] == pytest.approx(e[-1])  # closed


def test_depth_colours_scale() -> None:
    c = depth_colours(np.array([0.0, 50.0, 100.0, np.nan, 1e9]), 0.0, 100.0)
    assert c.dtype == np.uint8 and c.shape == (5, 3)
    assert c[0].tolist() == [48, 18, 59] and c[2].tolist() == [122, 4, 3]
    assert c[4].tolist() == c[2].tolist()  # clipped


def test_map_grid_scale_and_legend(tmp_path) -> None:
    """The map carries metre coordinates around what is drawn, a scale bar of one grid step and
    a legend naming every track in its colour; four tracks appearing one by one do not grow
    the grid (each re-logs the legend)."""
    path = tmp_path / "grid.rrd"
    logger = RerunLogger(rrd=path)
    for name in ("truth", "dead_reckoning", "slam/a", "slam/b"):
        for i in range(200):  # 200 m north, 100 m east
            logger.trajectory(name, T0 + i, 10.0 + i, 5.0 + 0.5 * i, 2.0, 0.0)
    logger.close()
    rec = read_recording(path)
    ticks = rec[f"{ent.MAP_GRID}/ticks"].static["Points2D:labels"]
    assert ticks == ["E 0 m", "E 50 m", "E 100 m", "N 200 m", "N 150 m", "N 100 m", "N 50 m",
                     "N 0 m"]  # fmt: skip
    assert rec[f"{ent.MAP_GRID}/scale"].static["LineStrips2D:labels"] == ["50 m"]
    legend = rec[f"{ent.MAP_GRID}/legend"].static
    assert legend["LineStrips2D:labels"] == [
        "truth", "dead reckoning", "SLAM a", "SLAM b", "true features"
    ]
    assert len(set(legend["LineStrips2D:colors"])) == 5  # every one its own colour


def test_a_slam_stages_status_row_lies_at_its_own_clock(tmp_path) -> None:
    """The SLAM stage's status carries its own clock (``t_stamp_ns``: the newest input stamp
    it took) and the Rerun stage puts its row there, not at the newest data time it has seen
    (the sensors run ahead of the stage); a status made before any input has no vehicle time
    and gives no row (it went at the host time of arrival: before vehicle time 0 in emulation)."""
    import json

    from auvgw.bus import encode_envelope
    from auvgw.fusion.odometry import Odometry
    from auvgw.stages.slam import SlamStage
    from auvgw.viz.stage import VizStage

    def odometry(t_ns: int) -> bytes:
        o = Odometry(t=t_ns / NS, x=1.0, y=2.0, z=4.0, roll=0.0, pitch=0.0, heading=0.3,
                     velocity_ned=(1.0, 0.0, 0.0), velocity_body=(1.0, 0.0, 0.0),
                     angular_rate=(0.0, 0.0, 0.0), covariance=np.eye(8), bottom_lock=True,
                     coasting=False, dvl_age_s=0.0, depth_age_s=0.0, ins_gap=False,
                     increment=None)  # fmt: skip
        return encode_envelope(o, "fusion", t_ns, 1)[0]

    slam = SlamStage()
    key = f"auv/auv1/status/{slam.component}"
    before = slam.counters()
    assert before["t_stamp_ns"] is None
    t_stage, t_data = int((T0 + 2.0) * NS), int((T0 + 9.0) * NS)
    slam.handle_sample("auv/auv1/nav/odometry", odometry(t_stage))
    after = slam.counters()
    assert after["t_stamp_ns"] == t_stage and after["stage"]["bad_payloads"] == 0
    path = tmp_path / "status.rrd"
    logger = RerunLogger(rrd=path)
    viz = VizStage(logger, "auv1")
    assert viz.handle_sample("auv/auv1/nav/odometry", odometry(t_data), t_data) == "logged"
    assert viz.handle_sample(key, json.dumps(before).encode(), t_data) == "ignored"
    assert viz.handle_sample(key, json.dumps(after).encode(), t_data) == "logged"
    viz.stop()
    logger.close()
    rows = health_metrics(read_recording(path), slam.component)
    assert [t for t, _ in rows] == [t_stage], [(t - t_stage) / NS for t, _ in rows]
    assert rows[0][1]["stage.received"] == after["stage"]["received"]
