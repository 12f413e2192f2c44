"""Emulated Tritech MSIS head: silent unless polled, HeadCommand settings, transducer stepping,
sector reversal, and the echo model against the world's walls and point features."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.drivers import seanet as sn
from auvgw.drivers.spec import raw_value
from auvgw.sim_devices.msis import MsisHead, make_echo, quantise
from auvgw.sim_devices.world import World

UNITS = sn.ANGLE_UNITS_PER_TURN


def decode_all(data: bytes) -> list:
    """Every message in ``data``; any bad frame fails the test."""
    framer = sn.SeaNetFramer(policy="raise")
    msgs = [m for f in framer.feed(data) for m in sn.decode(f.data)]
    assert framer.finish() == []
    return msgs


def configured_head(t: float = 0.0, **cmd) -> tuple[MsisHead, sn.HeadCommand]:
    """A powered head that has accepted ``head_command(**cmd)`` and is ready to ping."""
    head = MsisHead(config_delay_s=0.05)
    head.power_up(t)
    command = sn.head_command(**cmd)
    ack = decode_all(head.feed(sn.encode(command), t + 0.01))
    assert [type(m) for m in ack] == [sn.Alive] and ack[0].no_params and ack[0].sent_cfg
    ready = decode_all(head.tick(t + 0.1))
    assert len(ready) == 1 and ready[0].ready
    return head, command


def ping(head: MsisHead, t: float, time_ms: int = 0) -> sn.HeadData:
    """One mtSendData; the head must answer with exactly one mtHeadData."""
    msgs = decode_all(head.feed(sn.encode(sn.send_data(time_ms)), t))
    assert len(msgs) == 1 and isinstance(msgs[0], sn.HeadData), msgs
    return msgs[0]


def bearing_units(hd: sn.HeadData) -> int:
    return sn.rad_to_angle(hd.bearing)


# -- silence and the protocol ------------------------------------------------------------------


def test_power_up_sends_one_alive_without_parameters():
    head = MsisHead()
    assert head.feed(sn.encode(sn.send_version()), 0.0) == b""  # powered off: nothing
    msgs = decode_all(head.power_up(5.0))
    assert len(msgs) == 1
    alive = msgs[0]
    assert isinstance(alive, sn.Alive)
    assert alive.head_inf == 0x4A and alive.no_params and not alive.ready
    assert alive.alive_info == 0x80
    assert (alive.tx_node, alive.rx_node, alive.node) == (sn.HEAD_NODE, sn.HOST_NODE, sn.HEAD_NODE)


def test_head_is_silent_unless_polled_except_periodic_alive():
    head = MsisHead(alive_period_s=1.0)
    head.power_up(0.0)
    # ticks in the first second: nothing; at 1 s of silence: one mtAlive; then silent again
    assert b"".join(head.tick(k / 8) for k in range(1, 8)) == b""
    msgs = decode_all(head.tick(1.0))
    assert [type(m) for m in msgs] == [sn.Alive] and msgs[0].head_time == pytest.approx(1.0)
    assert head.tick(1.5) == b""
    # 10 s of ticks without a poll: only mtAlive, about one a second, never mtHeadData
    out = b"".join(head.tick(k / 8) for k in range(9, 88))  # 1.125 .. 10.875 s
    msgs = decode_all(out)
    assert len(msgs) == 9 and all(isinstance(m, sn.Alive) for m in msgs)
    # mtSendData before configuration: no mtHeadData (counted as ignored)
    assert head.feed(sn.encode(sn.send_data(0)), 11.0) == b""
    assert head.stats.polls == 1 and head.stats.head_data == 0 and head.stats.ignored == 1


def test_garbage_in_nothing_out_and_counted():
    head = MsisHead()
    head.power_up(0.0)
    rng = np.random.default_rng(7)
    garbage = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes().replace(b"@", b"#")
    assert head.feed(garbage, 0.1) == b""
    assert head.stats.skipped_bytes == 3000 and head.stats.bad_frames == 0
    # packets with a sync and a broken header / terminator are bad frames
    bad_len = b"@00ZZ" + bytes(10)
    good = sn.encode(sn.send_version())
    bad_lf = good[:-1] + b"\x00"
    assert head.feed(bad_len + bad_lf, 0.2) == b""
    assert head.stats.bad_frames == 2
    # a valid packet right after the garbage is still answered
    msgs = decode_all(head.feed(garbage[:100] + good, 0.3))
    assert [type(m) for m in msgs] == [sn.VersionData]
    assert head.stats.head_data == 0


def test_head_ignores_other_nodes_and_head_messages():
    head, _ = configured_head()
    for packet in (
        sn.encode(sn.send_data(0, rx=3)),  # for another head
        sn.encode(sn.send_version(tx=5)),  # not from the host
        sn.encode(sn.head_data(np.zeros(10, np.uint8), 0.0)),  # another head's data
        sn.encode(sn.alive(1.0)),
        sn.encode(sn.send_bb_user()),  # not emulated
    ):
        assert head.feed(packet, 1.0) == b""
    assert head.stats.ignored == 5 and head.stats.head_data == 0


def test_version_and_reboot():
    head = MsisHead(serial_number=4321, software_version=9)
    head.power_up(0.0)
    (ver,) = decode_all(head.feed(sn.encode(sn.send_version()), 0.5))
    assert isinstance(ver, sn.VersionData)
    assert (ver.serial_number, ver.software_version, ver.node_id) == (4321, 9, sn.HEAD_NODE)
    head2, _ = configured_head()
    ping(head2, 1.0)
    (alive,) = decode_all(head2.feed(sn.encode(sn.reboot()), 2.0))
    assert alive.no_params and head2.stats.reboots == 1
    assert head2.config is None and head2.position == 0
    assert head2.feed(sn.encode(sn.send_data(0)), 2.1) == b""  # parameters are gone


def test_stop_alives():
    head = MsisHead(alive_period_s=1.0)
    head.power_up(0.0)
    stop = sn.SeaNetRaw(
        tx_node=255, rx_node=2, byte_count=3, sequence=0x80, node=2, msg_type=66, payload=b""
    )
    assert head.feed(sn.encode(stop), 0.1) == b""
    assert b"".join(head.tick(t) for t in np.arange(0.2, 5.0, 0.1)) == b""
    head.feed(sn.encode(sn.reboot()), 5.0)  # a reset turns them on again
    assert decode_all(head.tick(6.0))


def test_send_data_sets_the_head_clock():
    head, _ = configured_head()
    ping(head, 1.0, time_ms=36_000_000)  # 10:00:00.000
    (alive,) = decode_all(head.tick(2.5))
    assert alive.head_time == pytest.approx(36_001.5)
    assert alive.ready and head.ping_duration_s() > 0.04


# -- HeadCommand settings in HeadData -------------------------------------------------------


@pytest.mark.parametrize("adc8", [True, False])
def test_head_data_agrees_with_head_command(adc8):
    head, cmd = configured_head(
        range_m=50.0, n_bins=400, adc8on=adc8, gain=0.55, step=math.radians(0.9)
    )
    hd = ping(head, 1.0)
    assert len(hd.bins) == cmd.n_bins == 400
    assert hd.adc8on is adc8 and hd.hd_ctrl == cmd.hd_ctrl
    assert hd.range_scale_raw == cmd.range_scale_raw and hd.range_m == 50.0
    assert hd.ad_interval == cmd.ad_interval
    assert raw_value(hd, "ad_interval") == round(2 * 50 / 1500 / 400 / 640e-9) == 260
    # the bins span the commanded range
    assert hd.bin_length(1500.0) * len(hd.bins) == pytest.approx(50.0, rel=2e-3)
    centres = head.bin_ranges()
    assert np.diff(centres) == pytest.approx(np.full(399, hd.bin_length(1500.0)))
    assert centres[0] == pytest.approx(hd.bin_length(1500.0) / 2)
    assert raw_value(hd, "step") == 16 and hd.gain == cmd.gain_ch1
    assert (hd.left_limit, hd.right_limit) == (cmd.left_limit, cmd.right_limit)
    assert int(hd.bins.max()) <= (255 if adc8 else 15)


def test_odd_bin_count_in_4bit_mode_is_padded_to_even():
    head, _ = configured_head(n_bins=101, adc8on=False)
    hd = ping(head, 1.0)
    assert len(hd.bins) == 102 and hd.data_bytes == 51 and hd.bins[-1] == 0


def test_quantise_gain_and_4bit_mapping():
    _, cmd8 = configured_head(gain=0.4)
    inten = np.array([0.0, 0.25, 0.5, 1.0])
    assert list(quantise(inten, cmd8)) == [0, 64, 128, 255]
    cmd_hi = sn.head_command(gain=0.5)  # +8 dB
    # 80 dB * [0.1, 0.3, 0.55, 1] + 8 dB = 16, 32, 52, 88 dB -> x 255/80
    assert list(quantise(np.array([0.1, 0.3, 0.55, 1.0]), cmd_hi)) == [51, 102, 166, 255]
    cmd4 = sn.head_command(adc8on=False, ad_low=10.0, ad_span=40.0, gain=0.4)
    # 80 dB * intensity: 0 -> below ADLow -> 0; 30 dB -> (30-10)/40*15 = 7.5 -> 8; 50 dB -> 15
    got = quantise(np.array([0.0, 30 / 80, 50 / 80, 1.0]), cmd4)
    assert list(got) == [0, round((30 - cmd4.ad_low) / cmd4.ad_span * 15), 15, 15]


# -- stepping and sectors ---------------------------------------------------------------------


def test_continuous_scan_steps_and_wraps():
    head, _ = configured_head(step=32 * sn.RAD_PER_ANGLE_UNIT, continuous=True)
    bearings = [bearing_units(ping(head, 1 + 0.01 * k)) for k in range(250)]
    assert bearings[:3] == [0, 32, 64]
    assert all((b - a) % UNITS == 32 for a, b in itertools.pairwise(bearings))
    assert bearings[200] == 0  # 200 x 32 = 6400: a full turn


def test_continuous_scan_left_turns_anticlockwise():
    head, _ = configured_head(step=8 * sn.RAD_PER_ANGLE_UNIT, scan_right=False)
    bearings = [bearing_units(ping(head, 1 + 0.01 * k)) for k in range(4)]
    assert bearings == [0, UNITS - 8, UNITS - 16, UNITS - 24]


def test_sector_scan_reverses_at_the_limits_across_north():
    # sector 350 deg .. 10 deg (through the forward mark), 1.8 deg steps
    head, cmd = configured_head(
        continuous=False,
        left_limit=math.radians(350.0),
        right_limit=math.radians(10.0),
        step=32 * sn.RAD_PER_ANGLE_UNIT,
    )
    left, right = raw_value(cmd, "left_limit"), raw_value(cmd, "right_limit")
    assert (left, right) == (6222, 178)
    hds = [ping(head, 1 + 0.01 * k) for k in range(40)]
    offs = [(bearing_units(h) - left) % UNITS for h in hds]
    span = (right - left) % UNITS  # 356
    # the head was centred (0 = offset 178, inside the sector) and scans right from there
    expected, o, d = [], 178, 1
    for _ in range(40):
        expected.append(o)
        o += 32 * d
        if o >= span:
            o, d = span, -1
        elif o <= 0:
            o, d = 0, 1
    assert offs == expected
    assert 0 in offs and span in offs and all(0 <= x <= span for x in offs)
    codes = {sn.SweepCode.AT_LEFT_LIMIT: 0, sn.SweepCode.AT_RIGHT_LIMIT: span}
    for h, x in zip(hds, offs, strict=True):
        assert h.sweep_code == next((c for c, v in codes.items() if v == x), sn.SweepCode.NORMAL)


def test_sector_scan_starts_at_the_left_limit_when_outside():
    head, _ = configured_head(
        continuous=False,
        left_limit=math.radians(45.0),
        right_limit=math.radians(90.0),
        step=16 * sn.RAD_PER_ANGLE_UNIT,
    )
    first = ping(head, 1.0)
    assert bearing_units(first) == 800 and first.sweep_code == sn.SweepCode.AT_LEFT_LIMIT
    assert bearing_units(ping(head, 1.01)) == 816


@settings(max_examples=50, deadline=None)
@given(
    left=st.integers(0, UNITS - 1),
    span=st.integers(1, UNITS - 1),
    step=st.integers(1, 128),
    n=st.integers(2, 120),
)
def test_sector_property(left, span, step, n):
    """Bearings stay in the sector; each move is one step, or shorter to land on a limit,
    and the direction reverses exactly at the limits."""
    head, _ = configured_head(
        continuous=False,
        left_limit=left * sn.RAD_PER_ANGLE_UNIT,
        right_limit=((left + span) % UNITS) * sn.RAD_PER_ANGLE_UNIT,
        step=step * sn.RAD_PER_ANGLE_UNIT,
    )
    offs = [(bearing_units(ping(head, 1 + 0.01 * k)) - left) % UNITS for k in range(n)]
    assert all(0 <= o <= span for o in offs)
    direction = None
    for a, b in itertools.pairwise(offs):
        move = b - a
        assert move != 0 or span == 0
        assert abs(move) == step or b in (0, span), (a, b)
        d = 1 if move > 0 else -1
        if direction is not None and d != direction:
            assert a in (0, span)  # reversals only at a limit
        direction = d


# -- echo model --------------------------------------------------------------------------------


def bins_centres(range_m: float = 30.0, n: int = 300) -> np.ndarray:
    return (np.arange(n) + 0.5) * range_m / n


def wall_world(x: float) -> World:
    """One wall across the north axis at ``x`` m."""
    return World(lines=[[x, -50.0, x, 50.0]])


def test_echo_from_a_wall_peaks_at_its_range_bin():
    rng = np.random.default_rng(1)
    r = bins_centres()
    for wall in (4.27, 12.33, 27.81):
        echo = make_echo(wall_world(wall), lambda: (0.0, 0.0, 0.0), rng, speckle=0.0)
        inten = echo(0.0, r)
        assert int(np.argmax(inten)) == int(wall / 0.1)
        assert inten.max() > 0.4 and np.median(inten) < 0.15
    # the same through the head, over the wire: HeadData's brightest bin
    echo = make_echo(wall_world(12.33), lambda: (0.0, 0.0, 0.0), rng, speckle=0.0)
    head = MsisHead(echo, config_delay_s=0.0)
    head.power_up(0.0)
    head.feed(sn.encode(sn.head_command(range_m=30.0, n_bins=300)), 0.1)
    head.tick(0.2)
    hd = ping(head, 0.3)
    assert int(np.argmax(hd.bins)) == 123 and hd.bins.max() > 100


def test_echo_speckle_keeps_the_peak_and_falls_with_range():
    rng = np.random.default_rng(2)
    r = bins_centres()
    peaks = {}
    for wall in (5.03, 25.03):
        echo = make_echo(wall_world(wall), lambda: (0.0, 0.0, 0.0), rng)
        pings = np.array([echo(0.0, r) for _ in range(60)])
        idx = pings.argmax(axis=1)
        assert np.median(idx) == int(wall / 0.1)
        assert np.mean(np.abs(idx - int(wall / 0.1)) <= 1) > 0.9
        peaks[wall] = np.median(pings[:, int(wall / 0.1)])
        assert 0 < np.std(pings[:, int(wall / 0.1)]) < 0.2  # speckle varies the level
    assert peaks[5.03] > peaks[25.03] + 0.1  # spreading and absorption


def test_echo_noise_floor_without_targets():
    rng = np.random.default_rng(3)
    echo = make_echo(World(), lambda: (0.0, 0.0, 0.0), rng, noise_floor=0.1)
    inten = np.array([echo(0.0, bins_centres()) for _ in range(20)])
    # mean power at the floor: mean of the log a little below it (Rayleigh), no peaks
    assert 0.05 < inten.mean() < 0.1 and inten.max() < 0.25
    quiet = make_echo(World(), lambda: (0.0, 0.0, 0.0), rng, noise_floor=0.0, speckle=0.0)
    assert not quiet(0.0, bins_centres()).any()


def test_echo_oblique_wall_is_weaker_and_wider():
    rng = np.random.default_rng(4)
    r = bins_centres()
    normal = make_echo(wall_world(15.03), lambda: (0.0, 0.0, 0.0), rng, speckle=0.0, noise_floor=0)
    # a wall through (15.03, 0) at 60 deg incidence
    d = np.array([math.cos(math.radians(30)), math.sin(math.radians(30))]) * 40
    oblique_world = World(lines=[[15.03 - d[0], -d[1], 15.03 + d[0], d[1]]])
    oblique = make_echo(oblique_world, lambda: (0.0, 0.0, 0.0), rng, speckle=0.0, noise_floor=0)
    a, b = normal(0.0, r), oblique(0.0, r)
    assert abs(int(np.argmax(b)) - 150) <= 3 and int(np.argmax(a)) == 150
    assert b.max() < a.max() - 0.05  # cos^2 of the incidence
    assert np.count_nonzero(b > b.max() - 0.1) > np.count_nonzero(a > a.max() - 0.1)


def test_echo_follows_pose_bearing_and_beam_width():
    rng = np.random.default_rng(5)
    r = bins_centres()
    world = World(points=[[10.0, 0.0]], point_radius=0.27)  # a post 10 m north
    pose = [0.0, 0.0, math.pi / 2]  # heading east

    def at(bearing_deg: float) -> np.ndarray:
        echo = make_echo(world, lambda: tuple(pose), rng, speckle=0.0, noise_floor=0.0)
        return echo(math.radians(bearing_deg), r)

    assert not at(0.0).any()  # looking east: nothing
    hit = at(270.0)  # east + 270 deg = north
    assert int(np.argmax(hit)) == 97  # the post's face at 9.73 m
    assert at(271.0).max() > 0.5 * hit.max()  # inside the 3 deg beam
    assert at(270.0 + 6.0).max() == 0.0  # beyond twice the beam width: not seen
    pose[:] = [10.0, 20.0, -math.pi / 2]  # 20 m east of the post, heading west: dead ahead
    assert int(np.argmax(at(0.0))) == 197
    inv = make_echo(
        world, lambda: (0.0, 0.0, math.pi / 2), rng, speckle=0.0, noise_floor=0.0, inverted=True
    )
    assert int(np.argmax(inv(math.radians(90.0), r))) == 97  # inverted: the bearing turns back


# -- range / bearing noise and the VB noise bursts -----------------------------------------------


def test_noise_bursts_multiply_the_range_error_variance_by_n():
    """A target at 12.33 m in every direction (a clean, narrow echo) and fine bins (2 cm): the
    brightest bin's range minus the truth is the ping's range error. With 0.1 m range noise
    and bursts (n = 3, p = 0.2) from the emulator's fault injector, the burst pings' error
    variance is ~3 times the clean pings' (seeded; 3 standard errors of tolerance)."""
    from auvgw.config.scenario import FaultSettings
    from auvgw.sim_devices.faults import FaultInjector

    def echo(bearing: float, ranges: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * ((ranges - 12.33) / 0.03) ** 2)

    faults = FaultInjector(FaultSettings(noise_burst_n=3.0, noise_burst_p=0.2),
                           np.random.default_rng(8))  # fmt: skip
    head = MsisHead(echo, config_delay_s=0.0, range_sigma_m=0.1, rng=np.random.default_rng(9),
                    noise_scale=faults.sigma_multiplier)  # fmt: skip
    head.power_up(0.0)
    head.feed(sn.encode(sn.head_command(range_m=20.0, n_bins=1000)), 0.0)
    head.tick(0.0)
    err, burst = [], []
    for i in range(2500):
        hd = ping(head, 0.1 + i * 0.03)
        r = (int(np.argmax(hd.bins)) + 0.5) * hd.bin_length(1500.0)
        err.append(r - 12.33)
        burst.append(head.last_ping_noise[2] > 1.0)
        assert head.last_ping_noise[1] == 0.0  # no bearing noise asked for
    err, burst = np.array(err), np.array(burst)
    # the counters: every ping drew once, the bursts are counted by the head and the injector
    assert faults.counts.noise_samples == 2500
    assert head.stats.burst_pings == faults.counts.noise_bursts == burst.sum()
    assert 0.17 < burst.mean() < 0.23
    clean, noisy = err[~burst].var(), err[burst].var()
    assert clean == pytest.approx(0.1**2, rel=0.1)
    se = math.sqrt(2 / burst.sum() + 2 / (~burst).sum())  # relative SE of the ratio
    assert noisy / clean == pytest.approx(3.0, rel=3 * se)
    # without noise figures nothing moves: the echo is placed exactly, bursts or not
    quiet = MsisHead(echo, config_delay_s=0.0, noise_scale=faults.sigma_multiplier)
    quiet.power_up(0.0)
    quiet.feed(sn.encode(sn.head_command(range_m=20.0, n_bins=1000)), 0.0)
    quiet.tick(0.0)
    hds = [ping(quiet, 0.1 + 0.03 * i) for i in range(50)]
    peaks = {int(np.argmax(hd.bins)) for hd in hds}
    assert len(peaks) == 1
    assert abs((peaks.pop() + 0.5) * hds[0].bin_length(1500.0) - 12.33) < hds[0].bin_length(1500.0)


def test_bearing_noise_turns_the_beam_but_not_the_reported_bearing():
    """The echo is asked for the nominal bearing plus the ping's bearing error; the head still
    reports the nominal bearing: 2 deg of noise gives a 2 deg spread, none gives none."""
    for sigma in (0.0, 2.0):
        asked: list[float] = []

        def echo(bearing: float, ranges: np.ndarray, asked=asked) -> np.ndarray:
            asked.append(bearing)
            return np.zeros(len(ranges))

        head = MsisHead(echo, config_delay_s=0.0, bearing_sigma_deg=sigma,
                        rng=np.random.default_rng(4))  # fmt: skip
        head.power_up(0.0)
        head.feed(sn.encode(sn.head_command(range_m=20.0, n_bins=200)), 0.0)
        head.tick(0.0)
        reported = [ping(head, 0.1 + 0.03 * i).bearing for i in range(400)]
        d = np.degrees((np.array(asked) - np.array(reported) + math.pi) % (2 * math.pi) - math.pi)
        assert d.std() == pytest.approx(sigma, rel=0.1, abs=1e-9), sigma
        # the reported bearings are the transducer's steps (1.8 deg by default)
        steps = np.degrees(np.diff(np.unwrap(reported)))
        np.testing.assert_allclose(steps, 32 * 0.05625, atol=1e-6)


@pytest.mark.e2e
def test_emulated_head_takes_scenario_noise_and_bursts(tmp_path, caplog):
    """Through the simulator (``make_msis``): ``devices.msis.noise`` and the per-ping burst
    multiplier of the emulator (counted in its ``noise_samples``); unknown noise keys are an
    error; bursts without any noise to scale log a warning."""
    from auvgw.config.scenario import Scenario
    from auvgw.sim_devices.clock import SimClock
    from auvgw.sim_devices.emulator import SimContext
    from auvgw.sim_devices.msis import make_emulator as make_msis
    from auvgw.sim_devices.vehicle import simulate

    def emulator(msis: dict, sub: str):
        scn = Scenario.model_validate({
            "name": "msis-noise", "vehicle": {"waypoints": [[0, 0], [50, 0]]},
            "features": {"lines": [[20, -10, 20, 10]]}, "devices": {"msis": msis},
        })  # fmt: skip
        world = World.from_scenario(scn)
        ctx = SimContext(scn, world, simulate(scn, world), SimClock(0), tmp_path / sub)
        return make_msis(ctx, scn.devices.msis)

    em = emulator({"noise": {"range_m": 0.2, "bearing_deg": 0.5},
                   "faults": {"noise_burst_n": 4.0, "noise_burst_p": 1.0}}, "a")  # fmt: skip
    try:
        head = em.head
        assert head.range_sigma_m == 0.2 and head.bearing_sigma == pytest.approx(math.radians(0.5))
        head.power_up(0.0)
        head.feed(sn.encode(sn.head_command(range_m=30.0, n_bins=300)), 0.0)
        head.tick(0.5)  # the motor re-centred: ready
        for i in range(5):
            ping(head, 0.6 + 0.1 * i)
            assert head.last_ping_noise[2] == 2.0  # sqrt(4): every ping a burst
        assert em.stats()["noise_samples"] == em.stats()["noise_bursts"] == 5
        assert head.stats.burst_pings == 5
    finally:
        em.close()
    with pytest.raises(ValueError, match=r"devices\.msis\.noise\.sigma_range_m.*range_m"):
        emulator({"noise": {"sigma_range_m": 0.05}}, "b")
    with caplog.at_level("WARNING"):
        emulator({"faults": {"noise_burst_n": 3.0, "noise_burst_p": 0.2}}, "c").close()
    assert "bursts change nothing" in caplog.text
