"""MSIS sonar features (Cui et al. 2020, sec. 2.2): beam preprocessing, motion compensation, the
180 deg sector buffer, Hough line voting with the arc and incidence rule, point features, and
the whole stage on the harbour scenario with the emulated MSIS head against ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from auvgw.config.scenario import load_scenario
from auvgw.drivers import seanet as sn
from auvgw.ground.paths import config_file
from auvgw.sim_devices.msis import MsisHead, make_echo
from auvgw.sim_devices.vehicle import simulate
from auvgw.sim_devices.world import World
from auvgw.slam.features import (
    BeamSettings,
    FeatureSettings,
    HoughSettings,
    LineFit,
    PointSettings,
    PoseTrack,
    ScanLines,
    SectorBuffer,
    SonarFeatureExtractor,
    SonarMount,
    cluster_returns,
    detect_returns,
    extract_lines,
    extract_points,
    fit_line,
    hough_votes,
    line_difference,
    line_refitter,
    merge_lines,
    place_returns,
    place_scan,
    preprocess_beam,
    scan_lines_from_head_data,
)
from auvgw.slam.features.points import segment_distance
from auvgw.slam.models import LineFeature, RangeBearing

DEG = math.pi / 180.0


def wall_line(seg) -> np.ndarray:
    """(rho, theta) of the infinite line through a segment (x1, y1, x2, y2), rho >= 0."""
    x1, y1, x2, y2 = seg
    th = math.atan2(x2 - x1, -(y2 - y1))
    rho = x1 * math.cos(th) + y1 * math.sin(th)
    if rho < 0:
        rho, th = -rho, th + math.pi
    return np.array([rho, (th + math.pi) % (2 * math.pi) - math.pi])


def tls_rms(x: np.ndarray, y: np.ndarray) -> float:
    """RMS distance of points to their own total-least-squares line, m."""
    p = np.stack([x - x.mean(), y - y.mean()])
    return float(math.sqrt(np.linalg.eigvalsh(p @ p.T / x.size)[0]))


# -- 2.2.1 on a hand-made beam ------------------------------------------------------------------


def test_threshold_local_maxima_and_min_distance_on_a_hand_made_beam():
    b = np.zeros(60)
    b[2] = 30  # strong but nearer than min_range (1 m): ring-down, ignored
    b[5:8] = [4, 6, 4]  # a local maximum below the threshold: removed (step 1)
    b[10:14] = [8, 12, 12, 9]  # plateau: its first bin is the maximum (step 2)
    b[14] = 10  # 0.75 m from bin 11: weaker, same object -> discarded (step 3)
    b[20:23] = [9, 11, 10]  # 2.5 m from bin 11: kept
    # greedy chain: A(40) > C(35) > B(30); A-C and C-B closer than 1 m, A-B farther:
    # C goes with A, then B survives because C is no longer there to suppress it
    b[30], b[33], b[36] = 40, 35, 30
    b[50] = 10
    b[51] = 10  # equal neighbours: a plateau of two, one return (the nearer)
    bins, ranges, inten = preprocess_beam(b, 0.25, BeamSettings(threshold=7.5, min_range_m=1.0))
    assert bins.tolist() == [11, 21, 30, 36, 50]
    assert ranges == pytest.approx((np.array([11, 21, 30, 36, 50]) + 0.5) * 0.25)
    assert inten.tolist() == [12, 11, 40, 30, 10]
    # each step alone
    only_thr = BeamSettings(threshold=7.5, min_range_m=1.0, min_distance_m=0.0)
    assert preprocess_beam(b, 0.25, only_thr)[0].tolist() == [11, 14, 21, 30, 33, 36, 50]
    low = BeamSettings(threshold=3.0, min_range_m=0.0, min_distance_m=0.0)
    assert preprocess_beam(b, 0.25, low)[0].tolist() == [2, 6, 11, 14, 21, 30, 33, 36, 50]
    # the strongest per ping only
    top2 = BeamSettings(threshold=7.5, min_range_m=1.0, max_returns=2)
    assert preprocess_beam(b, 0.25, top2)[0].tolist() == [30, 36]
    # nothing above the threshold: no returns; a NaN-padded ping is fine
    assert preprocess_beam(np.full(20, 2.0), 0.1, BeamSettings(threshold=7.5))[0].size == 0
    scan = ScanLines.from_pings([0.0, 0.1], [0.0, 0.1], [b, b[:20]], [0.25, 0.25])
    r = detect_returns(scan, BeamSettings(threshold=7.5, min_range_m=1.0))
    assert r.ping.tolist() == [0, 0, 0, 0, 0, 1]
    assert r.bin.tolist() == [11, 21, 30, 36, 50, 11]


def greedy_reference(inten: np.ndarray, thr: float, d_bins: float) -> list[int]:
    """Section 2.2.1 the slow obvious way: threshold, local maxima, then strongest first."""
    v = np.asarray(inten, float)
    cand = [
        k
        for k in range(v.size)
        if v[k] >= thr and (k == 0 or v[k] > v[k - 1]) and (k == v.size - 1 or v[k] >= v[k + 1])
    ]
    kept: list[int] = []
    for k in sorted(cand, key=lambda k: (-v[k], k)):
        if all(abs(k - j) >= d_bins for j in kept):
            kept.append(k)
    return sorted(kept)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.integers(0, 40), min_size=1, max_size=120),
    st.integers(5, 35),
    st.sampled_from([0.0, 0.3, 1.0, 2.2]),
)
def test_preprocessing_equals_the_greedy_rule(values, thr, min_dist):
    inten = np.array(values, float)
    bins, _, _ = preprocess_beam(
        inten, 0.1, BeamSettings(threshold=thr, min_distance_m=min_dist, min_range_m=0.0)
    )
    assert bins.tolist() == greedy_reference(inten, thr, min_dist / 0.1 - 1e-9)


def test_head_data_adapter_8_and_4_bit():
    c = 1490.0
    cmd8 = sn.head_command(range_m=20.0, n_bins=200, sound_speed=c)
    cmd4 = sn.head_command(range_m=20.0, n_bins=200, sound_speed=c, adc8on=False)
    bins8 = np.zeros(200, np.uint8)
    bins8[120] = 255
    bins4 = np.zeros(200, np.uint8)
    bins4[120] = 15
    # round trip through the wire, as the gateway sees them
    msgs = [sn.decode(sn.encode(sn.head_data(b, 1.0, config=k)))[0]
            for b, k in ((bins8, cmd8), (bins4, cmd4))]  # fmt: skip
    scan = scan_lines_from_head_data(msgs, [10.0, 10.1], c)
    blen = sn.bin_length(msgs[0].ad_interval, c)
    assert scan.bin_length == pytest.approx([blen, blen])
    assert scan.bearing == pytest.approx([1.0, 1.0], abs=2 * math.pi / 6400)
    assert scan.intensity[0, 120] == pytest.approx(80.0)  # 8-bit: 255 = 80 dB
    # 4-bit: ADLow + 15/15 ADSpan = 13 + 24 dB, and the floor sits at ADLow
    assert scan.intensity[1, 120] == pytest.approx(37.0, abs=0.5)
    assert scan.intensity[1, 0] == pytest.approx(13.0, abs=0.5)
    r = detect_returns(scan, BeamSettings(threshold=30.0))
    assert r.ping.tolist() == [0, 1]
    assert r.range_m == pytest.approx([120.5 * blen] * 2)
    raw = scan_lines_from_head_data(msgs, [10.0, 10.1], c, to_db=False)
    assert raw.intensity[0, 120] == 255 and raw.intensity[1, 120] == 15


# -- synthetic pings ----------------------------------------------------------------------------


def synthetic_scan(
    world: World,
    track: PoseTrack,
    times: np.ndarray,
    bearings: np.ndarray,
    rng: np.random.Generator,
    mount: SonarMount | None = None,
    bin_length: float = 0.1,
    n_bins: int = 500,
) -> ScanLines:
    """A small intensity model: the first hit of each beam's axis makes a peak of 30 - 10 dB
    per 50 m (x cos^2 of the incidence) two bins wide over a noise floor of 5 +- 1."""
    mount = mount if mount is not None else SonarMount()
    poses = track(times)
    sx, sy = mount.transducer(poses)
    ang = poses[:, 2] + mount.beam_angle(bearings)
    ranges = (np.arange(n_bins) + 0.5) * bin_length
    inten = 5.0 + rng.normal(0.0, 1.0, (times.size, n_bins))
    for i in range(times.size):
        h = world.cast((sx[i], sy[i]), np.array([ang[i]]), n_bins * bin_length)
        if h.hit[0]:
            level = (30.0 - 10.0 * h.range_m[0] / 50.0) * math.cos(h.incidence[0]) ** 2
            inten[i] += level * np.exp(-0.5 * ((ranges - h.range_m[0]) / bin_length) ** 2)
    return ScanLines(times, bearings, inten, bin_length)


def arc_track(start, heading, speed, yaw_rate, t_end, dt=0.02) -> PoseTrack:
    """Constant speed and yaw rate from ``start`` (x, y) at ``heading``."""
    t = np.arange(0.0, t_end + dt, dt)
    h = heading + yaw_rate * t
    if abs(yaw_rate) > 1e-12:
        x = start[0] + speed / yaw_rate * (np.sin(h) - math.sin(heading))
        y = start[1] - speed / yaw_rate * (np.cos(h) - math.cos(heading))
    else:
        x = start[0] + speed * t * math.cos(heading)
        y = start[1] + speed * t * math.sin(heading)
    return PoseTrack(t, np.stack([x, y, h], axis=1))


# -- 2.2.3 Hough voting ---------------------------------------------------------------------------


def test_one_return_votes_the_arc_and_incidence_cells_once():
    h = HoughSettings(theta_res_rad=1 * DEG, rho_res_m=0.1)
    _, cell, (n_theta, n_rho) = hough_votes([0.0], [0.0], [10 * DEG], [20.04], h)
    assert np.unique(cell).size == cell.size  # at most one vote per cell
    k, p = np.divmod(cell, n_rho)
    theta = np.where(k > n_theta // 2, k - n_theta, k) * DEG
    rho = (p + 0.5) * 0.1
    # normals within the beam width (3 deg) plus the incidence aperture (60 deg): +-31.5 deg
    assert theta.min() == pytest.approx(-21 * DEG) and theta.max() == pytest.approx(41 * DEG)
    # the tangent line at the arc (normal = beam axis) is voted at the measured range
    assert np.any((np.abs(theta - 10 * DEG) < 1e-9) & (np.abs(rho - 20.04) < 0.1))
    # at the outermost normal (31 deg off the axis) only the arc's edge 11..11.5 deg is within
    # the incidence limit (30 deg): rho = range * cos(incidence) over 30..29.5 deg
    edge = np.abs(theta - 41 * DEG) < 1e-9
    assert rho[edge].min() == pytest.approx(20.04 * math.cos(30 * DEG), abs=0.1)
    assert rho[edge].max() == pytest.approx(20.04 * math.cos(29.5 * DEG), abs=0.1)
    # near the axis, the arc's +-1.5 deg barely changes rho (20.04 .. 20.03 m): one cell
    assert np.count_nonzero(np.abs(theta - 10 * DEG) < 1e-9) == 1
    # a moved transducer shifts rho by its projection on the normal (step 4)
    _, cell2, (_, n_rho2) = hough_votes([3.0], [4.0], [10 * DEG], [20.04], h)
    k2, p2 = np.divmod(cell2, n_rho2)
    axis = k2 == 10
    assert (p2[axis] + 0.5) * 0.1 == pytest.approx(
        [20.04 + 3.0 * math.cos(10 * DEG) + 4.0 * math.sin(10 * DEG)], abs=0.1
    )


def test_hough_finds_a_known_line_in_synthetic_returns():
    rng = np.random.default_rng(3)
    # a wall x cos(th) + y sin(th) = rho seen from a static head at the origin, beams 1.8 deg
    # apart across +-30 deg of its normal, ranges with 5 cm noise, plus clutter
    rho_t, th_t = 17.3, 0.7
    ang = th_t + np.arange(-30, 31, 1.8) * DEG
    rng_m = rho_t / np.cos(ang - th_t) + rng.normal(0, 0.05, ang.size)
    clutter_a = rng.uniform(-math.pi, math.pi, 15)
    clutter_r = rng.uniform(2.0, 40.0, 15)
    a = np.r_[ang, clutter_a]
    r = np.r_[rng_m, clutter_r]
    z = np.zeros(a.size)
    fits = extract_lines(z, z, a, r, np.arange(a.size), HoughSettings(), sigma_r=0.05)
    assert len(fits) == 1
    f = fits[0]
    assert f.rho == pytest.approx(rho_t, abs=0.05)
    assert f.theta == pytest.approx(th_t, abs=0.3 * DEG)
    assert f.support.size >= ang.size - 2 and f.support.max() < ang.size  # no clutter
    # the covariance describes the error: within 3 sigma, and a few cm / tenths of a degree
    d = np.array([f.rho - rho_t, f.theta - th_t])
    assert d @ np.linalg.solve(f.covariance, d) < 9.0
    assert 0.002 < math.sqrt(f.covariance[0, 0]) < 0.05
    assert 0.02 * DEG < math.sqrt(f.covariance[1, 1]) < 0.5 * DEG
    # a corner: two walls, two lines, each with its own returns
    ang2 = th_t + math.pi / 2 + np.arange(-30, 31, 1.8) * DEG
    rng2 = 9.0 / np.cos(ang2 - th_t - math.pi / 2) + rng.normal(0, 0.05, ang2.size)
    a2, r2 = np.r_[ang, ang2], np.r_[rng_m, rng2]
    z2 = np.zeros(a2.size)
    fits2 = extract_lines(z2, z2, a2, r2, np.arange(a2.size), HoughSettings(), sigma_r=0.05)
    got = sorted((round(f.rho, 1), round(f.theta, 2)) for f in fits2)
    assert len(got) == 2
    assert got[0] == pytest.approx((9.0, th_t + math.pi / 2), abs=0.06)
    assert got[1] == pytest.approx((rho_t, th_t), abs=0.06)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(5.0, 45.0),
    st.floats(-math.pi, math.pi),
    st.floats(-4.0, 4.0),
    st.floats(-4.0, 4.0),
    st.integers(0, 2**32 - 1),
)
def test_hough_recovers_any_wall_seen_from_a_moving_head(rho_t, th_t, dx, dy, seed):
    # the head moves by (dx, dy) while its beam sweeps +-30 deg around the wall's normal (up
    # to 2 m/s over the 2.8 s this takes at 1.8 deg per 80 ms); 2 cm range noise
    rng = np.random.default_rng(seed)
    n = 35
    sx, sy = np.linspace(0.0, dx, n), np.linspace(0.0, dy, n)
    dist = rho_t - sx * math.cos(th_t) - sy * math.sin(th_t)  # each transducer to the wall
    assume(dist.min() > 2.0)  # not through the wall
    ang = th_t + np.linspace(-30, 30, n) * DEG
    along = sy * math.cos(th_t) - sx * math.sin(th_t) + dist * np.tan(ang - th_t)
    assume(np.ptp(along) > 3.0)  # a motion along the sweep can squeeze the seen stretch
    r = dist / np.cos(ang - th_t) + rng.normal(0, 0.02, n)
    fits = extract_lines(sx, sy, ang, r, np.arange(n), HoughSettings(), sigma_r=0.02)
    assert len(fits) == 1
    d = np.array(line_difference((fits[0].rho, fits[0].theta), (rho_t, th_t)))
    assert abs(d[0]) < 0.1 and abs(d[1]) < 1.0 * DEG
    assert d @ np.linalg.solve(fits[0].covariance, d) < 16.0  # 4 sigma


def test_merge_lines_joins_two_fits_of_one_wall_and_keeps_parallel_walls():
    # a pier: two parallel faces 8 m apart; the near face fitted from two halves of its returns
    rng = np.random.default_rng(4)
    ang = np.linspace(-30, 30, 41) * DEG
    r1 = 10.0 / np.cos(ang) + rng.normal(0, 0.03, ang.size)
    r2 = 18.0 / np.cos(ang) + rng.normal(0, 0.03, ang.size)
    a, r = np.r_[ang, ang], np.r_[r1, r2]
    z = np.zeros(a.size)
    px, py = r * np.cos(a), r * np.sin(a)
    ping = np.r_[np.arange(41), np.arange(41)]
    h = HoughSettings()
    sr = np.full(a.size, 0.03)
    halves = []
    for part in (np.arange(0, 20), np.arange(20, 41), np.arange(41, 82)):
        fit = _fit(px, py, a, r, sr, ping, h, part)
        halves.append(fit)
    merged = merge_lines(halves, line_refitter(px, py, a, r, sr, ping, h), h)
    assert len(merged) == 2
    near = min(merged, key=lambda f: f.rho)
    assert near.support.tolist() == list(range(41))
    assert near.covariance[1, 1] < min(halves[0].covariance[1, 1], halves[1].covariance[1, 1])
    assert near.rho == pytest.approx(10.0, abs=0.03) and abs(near.theta) < 0.2 * DEG
    far = max(merged, key=lambda f: f.rho)
    assert far.rho == pytest.approx(18.0, abs=0.05)
    del z


def _fit(px, py, a, r, sr, ping, h, part):
    """A LineFit from a subset of returns (what one Hough peak would give)."""
    rho0 = float(np.median(px[part]))
    got = fit_line(px, py, a, r, sr, rho0, 0.0, h, candidates=part)
    assert got is not None
    rho, theta, cov, sup, chi2 = got
    c, s = math.cos(theta), math.sin(theta)
    t = -px[sup] * s + py[sup] * c
    return LineFit(rho, theta, cov, sup.size, sup, np.unique(ping[sup]).size, t.min(), t.max(),
                   chi2)  # fmt: skip


def test_returns_beyond_the_incidence_rule_make_no_line():
    # a wall seen only at incidences 40..60 deg: its returns cannot vote for its own normal,
    # so no line (and certainly no wrong one) comes out
    th_t, rho_t = 0.0, 10.0
    ang = th_t + np.arange(40, 60, 1.8) * DEG
    r = rho_t / np.cos(ang - th_t)
    z = np.zeros(ang.size)
    assert extract_lines(z, z, ang, r, np.arange(ang.size), HoughSettings(), sigma_r=0.05) == []
    wide = HoughSettings(incidence_rad=130 * DEG)  # a head that hears walls up to 65 deg
    (f,) = extract_lines(z, z, ang, r, np.arange(ang.size), wide, sigma_r=0.05)
    assert f.rho == pytest.approx(rho_t, abs=0.05) and abs(f.theta) < 0.3 * DEG


# -- the sector buffer (2.2.2) ------------------------------------------------------------------


def test_sector_buffer_keeps_the_latest_180_degrees_and_frames_returns():
    buf = SectorBuffer()
    pose = np.array([5.0, -3.0, 0.4])
    for i in range(150):  # continuous clockwise scan, 1.8 deg per ping
        buf.push(0.1 * i, i * 1.8 * DEG, pose, [10.0 + i * 0.01], [50.0], 0.1)
    assert len(buf) == 101  # 100 steps of 1.8 deg = 180 deg
    br = buf.returns()
    assert np.ptp(br.path) == pytest.approx(math.pi)
    # B is the head's frame at the newest ping: its beam points along its bearing there
    assert br.path[-1] == pytest.approx(149 * 1.8 * DEG - 2 * math.pi)
    # positions in B turn back into the pose frame where the pings put them
    _, origin, psi, t_ref = buf.frame()
    assert t_ref == pytest.approx(14.9)
    c, s = math.cos(psi), math.sin(psi)
    wx = origin[0] + c * br.px - s * br.py
    wy = origin[1] + s * br.px + c * br.py
    bearing = np.arange(49, 150) * 1.8 * DEG
    rr = 10.0 + np.arange(49, 150) * 0.01
    assert wx == pytest.approx(5.0 + rr * np.cos(0.4 + bearing))
    assert wy == pytest.approx(-3.0 + rr * np.sin(0.4 + bearing))
    buf.remove(br.ids[:10])
    assert buf.n_returns == 91 and len(buf) == 101
    # a sector scan going back and forth over 120 deg keeps all of it, and no more than 180
    sec = SectorBuffer()
    path = np.r_[np.arange(0, 120, 1.8), np.arange(120, 0, -1.8), np.arange(0, 120, 1.8)]
    for i, b in enumerate(path):
        sec.push(0.1 * i, b * DEG, np.zeros(3), [], [], 0.1)
    assert len(sec) == path.size
    # stale beams go after max_age_s
    old = SectorBuffer(max_age_s=2.0)
    for i in range(40):
        old.push(0.1 * i, 0.5 * DEG * i, np.zeros(3), [], [], 0.1)
    assert len(old) == 21


# -- motion compensation ------------------------------------------------------------------------


def wall_scan(speed: float, yaw_rate: float, seed: int = 5):
    """One wall (x = 30 m, 200 m long) scanned by a head moving towards it while turning: one
    revolution, 1.8 deg per 80 ms ping, starting away from the wall."""
    world = World(lines=np.array([[30.0, -100.0, 30.0, 100.0]]))
    track = arc_track((0.0, -5.0), -20 * DEG, speed, yaw_rate, 20.0)
    n = 200
    times = 0.08 * np.arange(n)
    bearings = (120.0 + 1.8 * np.arange(n)) * DEG % (2 * math.pi)
    scan = synthetic_scan(world, track, times, bearings, np.random.default_rng(seed))
    return world, track, scan


def test_motion_compensation_gives_one_straight_wall():
    world, track, scan = wall_scan(speed=2.0, yaw_rate=4 * DEG)
    truth = wall_line(world.lines[0])
    fs = FeatureSettings(beam=BeamSettings(threshold=15.0), points=None, vote_every=1)
    beam = fs.beam
    returns = detect_returns(scan, beam)
    assert len(returns) > 40
    # per-ping poses: every return lies on the wall
    placed = place_returns(returns, track)
    assert np.abs(placed.x - 30.0).max() < 0.15
    # one pose for the whole scan (the newest): the returns smear over metres
    single = track(scan.t[-1:])[0]
    smeared = place_scan(scan, beam, single)
    assert np.abs(smeared.x - 30.0).max() > 3.0
    assert tls_rms(smeared.x, smeared.y) > 5 * tls_rms(placed.x, placed.y)

    # the whole stage: with per-ping poses, exactly one line, matching the wall seen from the
    # reference pose (the LineFeature measurement of the filters)
    lines = SonarFeatureExtractor(fs).run(scan, track).lines
    assert len(lines) == 1
    (obs,) = lines
    z_true = LineFeature().h(obs.pose, truth)
    drho, dth = line_difference((obs.rho, obs.theta), tuple(z_true))
    assert abs(drho) < 0.1 and abs(dth) < 0.5 * DEG
    assert obs.pose == pytest.approx(track(np.array([obs.t]))[0])
    rho_w, th_w, _ = obs.world()
    assert (rho_w, th_w) == pytest.approx(tuple(truth), abs=0.2)
    assert np.abs(obs.endpoints[:, 0] - 30.0).max() < 0.3

    # with a single pose the same data give no line on the wall (here one 45 deg off)
    lines_1 = SonarFeatureExtractor(fs).run(scan, single).lines
    for o in lines_1:
        drho, dth = line_difference((o.rho, o.theta), tuple(LineFeature().h(single, truth)))
        assert abs(drho) > 1.0 or abs(dth) > 3 * DEG


def test_mounted_head_observations_are_in_the_vehicle_frame():
    # a head 1.5 m forward and 0.4 m to port of the reference point, forward mark turned 90 deg
    # clockwise, upside down; the vehicle runs along a wall past an isolated pile, turning
    mount = SonarMount(x_m=1.5, y_m=-0.4, yaw_rad=90 * DEG, inverted=True)
    world = World(lines=np.array([[-100.0, 25.0, 100.0, 25.0]]), points=np.array([[12.0, -8.0]]),
                  point_radius=1.0)  # fmt: skip
    track = arc_track((0.0, 0.0), 0.0, 0.5, -0.5 * DEG, 50.0)
    n = 600  # three revolutions, the first starting at the wall's normal
    times = 0.08 * np.arange(n)
    bearings = (1.8 * np.arange(n)) * DEG % (2 * math.pi)
    scan = synthetic_scan(world, track, times, bearings, np.random.default_rng(11), mount)
    fs = FeatureSettings(
        beam=BeamSettings(threshold=15.0),
        points=PointSettings(target_radius_m=1.0),
        mount=mount,
        vote_every=2,
    )
    feats = SonarFeatureExtractor(fs).run(scan, track)
    assert len(feats.lines) == 2  # each time the wall's whole window has been scanned
    for o in feats.lines:
        z_true = LineFeature().h(o.pose, wall_line(world.lines[0]))
        drho, dth = line_difference((o.rho, o.theta), tuple(z_true))
        assert abs(drho) < 0.1 and abs(dth) < 0.5 * DEG
    assert len(feats.points) == 3  # one per revolution
    for p in feats.points:
        z_true = RangeBearing().h(p.pose, world.points[0])
        assert p.range_m == pytest.approx(z_true[0], abs=0.3)
        assert p.bearing == pytest.approx(z_true[1], abs=1.5 * DEG)
        assert p.position == pytest.approx(world.points[0], abs=0.3)


# -- point features -----------------------------------------------------------------------------


def test_cluster_returns_single_linkage():
    x = np.array([0.0, 0.5, 1.2, 5.0, 5.3, 9.0])
    y = np.zeros(6)
    assert cluster_returns(x, y, 0.8).tolist() == [0, 0, 0, 3, 3, 5]
    assert cluster_returns(x, y, 0.4).tolist() == [0, 1, 2, 3, 3, 5]
    assert cluster_returns(x[:1], y[:1], 1.0).tolist() == [0]


def test_point_features_from_a_pile_and_not_from_a_steep_wall():
    # a pile of radius 0.5 m at 20 m, bearing 30 deg, seen by 4 pings; and a wall seen at a
    # steep angle whose returns (speckle) come in pairs 0.2 m apart, 1.5 m from the next pair
    rng = np.random.default_rng(2)
    c = np.array([20 * math.cos(30 * DEG), 20 * math.sin(30 * DEG)])
    a_p = (30 + np.array([-2.7, -0.9, 0.9, 2.7])) * DEG
    r_p = np.hypot(*c) - 0.5 + rng.normal(0, 0.05, 4)
    along = np.array([0.0, 0.2, 1.7, 1.9, 3.4, 3.6])
    wx, wy = -10.0 + 0.0 * along, 12.0 + along  # the wall x = -10, from y = 12 on
    a_w, r_w = np.arctan2(wy, wx), np.hypot(wx, wy)
    a = np.r_[a_p, a_w]
    r = np.r_[r_p, r_w]
    ping = np.r_[0, 1, 2, 3, 10, 11, 12, 13, 14, 15]
    ping_dir = np.arange(20) * 1.8 * DEG
    z = np.zeros(a.size)
    ps = PointSettings(target_radius_m=0.5)
    (fit,) = extract_points(z, z, a, r, ping, ping_dir, ps, 0.1, 1.8 * DEG)
    assert fit.support.tolist() == [0, 1, 2, 3]
    assert fit.centre == pytest.approx(c, abs=0.15)
    e = fit.centre - c
    assert e @ np.linalg.solve(fit.covariance, e) < 9.0
    # without the isolation test the wall's pairs would pass for targets
    loose = PointSettings(target_radius_m=0.5, isolation_m=0.0)
    assert len(extract_points(z, z, a, r, ping, ping_dir, loose, 0.1, 1.8 * DEG)) == 4


# -- the harbour scenario with the emulated MSIS ------------------------------------------------

HARBOUR_S = 240.0
RANGE_M = 50.0


@pytest.fixture(scope="module")
def harbour():
    """Pings of the emulated Tritech head (SeaNet bytes, decoded as the gateway would) along
    the first minutes of the harbour route; sonar poses from the ground truth."""
    scn = load_scenario(config_file("scenarios/harbour.json"))
    scn = scn.model_copy(update={"duration_s": HARBOUR_S})
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    track = PoseTrack(truth.t, truth.poses)
    cmd = sn.head_command(range_m=RANGE_M, n_bins=400, sound_speed=world.sound_speed)
    head = MsisHead(sound_speed=world.sound_speed, config_delay_s=0.0)
    head.power_up(0.0)
    head.feed(sn.encode(cmd), 0.0)
    head.tick(0.0)
    period = head.ping_duration_s() + 0.005  # the ping plus the host's turnaround
    times = np.arange(0.0, truth.duration, period)
    poses = track(times)
    now = [0]
    head.echo = make_echo(world, lambda: tuple(poses[now[0]]), np.random.default_rng(21))
    framer = sn.SeaNetFramer(policy="raise")
    poll = sn.encode(sn.send_data(0))
    msgs = []
    for i, t in enumerate(times):
        now[0] = i
        msgs.extend(m for f in framer.feed(head.feed(poll, float(t))) for m in sn.decode(f.data))
    assert len(msgs) == times.size and all(isinstance(m, sn.HeadData) for m in msgs)
    scan = scan_lines_from_head_data(msgs, times, world.sound_speed)
    fs = FeatureSettings(
        beam=BeamSettings(threshold=20.0),  # dB: 12 dB over the noise floor
        points=PointSettings(target_radius_m=world.point_radius),
    )
    feats = SonarFeatureExtractor(fs).run(scan, track)
    return world, track, scan, feats, fs


def full_sector(world: World, pose: np.ndarray, j: int, window: float) -> bool:
    """Wall ``j`` fills the sector around its normal seen from ``pose``: the rays along the
    normal and at +-window around it all hit that wall first, within range."""
    n = wall_line(world.lines[j])
    normal = n[1]
    x, y = pose[0], pose[1]
    if x * math.cos(normal) + y * math.sin(normal) > n[0]:
        normal += math.pi  # the vehicle is on the far side of the origin
    hits = world.cast((x, y), normal + np.array([-window, 0.0, window]), RANGE_M)
    return bool(np.all((hits.kind == 1) & (hits.index == j)))


def test_harbour_lines_match_the_true_walls(harbour):
    world, _, _, feats, fs = harbour
    assert len(feats.lines) >= 12
    walls = np.array([wall_line(s) for s in world.lines])
    full, seen = [], set()
    for o in feats.lines:
        # the true wall the line lies on: the same direction, its supported segment on it
        errs = []
        mid = o.endpoints.mean(axis=0)
        for j, seg in enumerate(world.lines):
            z_true = LineFeature().h(o.pose, walls[j])
            drho, dth = line_difference((o.rho, o.theta), tuple(z_true))
            off = segment_distance(mid[:1], mid[1:], seg.reshape(1, 2, 2))[0]
            errs.append((abs(dth) + abs(drho) / 10 + off / 10, j, drho, dth, off))
        _, j, drho, dth, off = min(errs)
        seen.add(j)
        # every line is a real wall (no spurious lines): on it and along it
        assert off < 1.0 and abs(dth) < 3 * DEG and abs(drho) < 1.0, (o.t, j, drho, dth, off)
        if full_sector(world, o.pose, j, fs.hough.window):
            full.append((drho, dth))
    assert len(full) >= 10
    full = np.array(full)
    # walls seen over a full sector: rho within 0.5 m, theta within 2 deg
    assert np.abs(full[:, 0]).max() < 0.5
    assert np.abs(full[:, 1]).max() < 2 * DEG
    # the quays and the pier near the route's first legs are all found
    assert {0, 1, 3, 5} <= seen


def test_harbour_point_features_match_the_piles(harbour):
    world, _, _, feats, _ = harbour
    pts = feats.points
    assert len(pts) >= 6
    seen = set()
    nees_world, nees_z = [], []
    rb = RangeBearing()
    for p in pts:
        j = int(np.argmin(np.hypot(*(world.points - p.position).T)))
        seen.add(j)
        e = p.position - world.points[j]
        nees_world.append(e @ np.linalg.solve(p.position_covariance, e))
        # the measurement the filters take: range and bearing from the pose at the reference
        dz = p.z - rb.h(p.pose, world.points[j])
        dz[1] = (dz[1] + math.pi) % (2 * math.pi) - math.pi
        nees_z.append(dz @ np.linalg.solve(p.covariance, dz))
        # the covariance is tight (a 3 sigma test against a huge one would prove nothing)
        assert math.sqrt(np.linalg.eigvalsh(p.position_covariance).max()) < 0.6
    nees_world, nees_z = np.array(nees_world), np.array(nees_z)
    # every point feature is a true pile within 3 sigma of its reported covariance
    assert np.sqrt(nees_world).max() < 3.0
    assert np.sqrt(nees_z).max() < 3.0
    assert len(seen) >= 4
