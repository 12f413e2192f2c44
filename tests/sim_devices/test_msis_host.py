"""The gateway's SeaNet polling driver: its state machine fed by hand, the full exchange with the
emulated head wired back to back in memory (lost replies, reboots, replugs), and the same over a
real pty with pyserial."""

from __future__ import annotations

import itertools
import math
import os
import select
import threading
import time
import tty

import numpy as np
import pytest
import serial

from auvgw.config.gateway import MsisPolling
from auvgw.config.scenario import FaultSettings
from auvgw.drivers import seanet as sn
from auvgw.drivers.seanet.host import HostState, SeaNetHost, command_from_config
from auvgw.drivers.spec import raw_value
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.faults import FaultInjector
from auvgw.sim_devices.msis import MsisHead, make_echo, serve_on_port
from auvgw.sim_devices.ports import PtyPort
from auvgw.sim_devices.world import World

UNITS = sn.ANGLE_UNITS_PER_TURN


def clock_ms(now: float) -> int:
    return round(now * 1000.0)


class Wire:
    """Collects what the host writes, decoded (each write must be whole valid packets)."""

    def __init__(self) -> None:
        self.packets: list[bytes] = []

    def __call__(self, data: bytes) -> None:
        self.packets.append(bytes(data))

    def take(self) -> list:
        msgs = [m for p in self.packets for m in sn.decode(p)]
        self.packets.clear()
        return msgs


def types(msgs: list) -> list[str]:
    return [m.TYPE for m in msgs]


# -- configuration ------------------------------------------------------------------------------


def test_command_from_config_converts_degrees_and_settings():
    cfg = MsisPolling(
        range_m=50.0,
        gain=0.5,
        step_deg=0.9,
        left_limit_deg=270.0,
        right_limit_deg=90.0,
        continuous=False,
        n_bins=401,
        adc8=False,
    )
    cmd = command_from_config(cfg)
    assert raw_value(cmd, "step") == 16
    assert (raw_value(cmd, "left_limit"), raw_value(cmd, "right_limit")) == (4800, 1600)
    assert cmd.n_bins == 402  # 4-bit bins come in pairs
    assert raw_value(cmd, "ad_interval") == round(2 * 50.0 / 1500.0 / 402 / 640e-9)
    assert raw_value(cmd, "range_scale_raw") == 500 and cmd.range_m == 50.0
    assert raw_value(cmd, "gain_ch1") == 105
    assert not cmd.adc8on and not cmd.continuous and cmd.scan_right
    default = command_from_config(MsisPolling())
    assert default.continuous and default.adc8on and default.n_bins == 300
    assert raw_value(default, "step") == 32  # 1.8 deg
    assert raw_value(default, "right_limit") == 0  # 360 deg wraps to the forward mark
    assert sn.encode(default) == sn.encode(SeaNetHost().command)


# -- the state machine, fed by hand -----------------------------------------------------------


def ready_host(**kw) -> tuple[SeaNetHost, Wire]:
    """A host taken through the sequence by hand, with one mtSendData outstanding at t=0.3."""
    host = SeaNetHost(MsisPolling(reply_timeout_s=0.5), time_ms=clock_ms, **kw)
    w = Wire()
    host.on_connect(w, 0.0)
    host.on_message(sn.alive(0.0, head_inf=0x4A), w, 0.1)
    host.on_message(sn.version_data(), w, 0.2)
    host.on_message(sn.alive(0.2, head_inf=0x8A), w, 0.3)
    w.take()
    assert host.state is HostState.PINGING
    return host, w


def test_sequence_step_by_step():
    host = SeaNetHost(MsisPolling(reply_timeout_s=0.5), time_ms=clock_ms)
    w = Wire()
    host.on_connect(w, 10.0)
    assert w.take() == [] and host.state is HostState.WAIT_ALIVE
    # the host's own packets echoed on a 2-wire line are ignored
    host.on_message(sn.send_version(), w, 10.05)
    assert w.take() == []
    host.on_message(sn.alive(3.0, head_inf=0x4A), w, 10.1)
    (sv,) = w.take()
    assert isinstance(sv, sn.SendVersion) and (sv.tx_node, sv.rx_node) == (255, 2)
    assert host.state is HostState.WAIT_VERSION
    host.on_message(sn.version_data(serial_number=77), w, 10.2)
    (cmd,) = w.take()
    assert sn.encode(cmd) == sn.encode(host.command)
    assert host.state is HostState.CONFIGURING
    host.on_message(sn.alive(3.2, head_inf=0xCA), w, 10.25)  # received, still NO_PARAMS
    host.on_idle(w, 12.0)
    assert w.take() == [] and host.state is HostState.CONFIGURING
    host.on_message(sn.alive(3.3, head_inf=0x8A), w, 12.1)  # parameters taken: ready
    (sd,) = w.take()
    assert isinstance(sd, sn.SendData) and raw_value(sd, "time") == 12100
    assert host.state is HostState.PINGING
    for k in range(5):
        host.on_message(sn.head_data(np.zeros(300, np.uint8), 0.0), w, 12.2 + k * 0.1)
        assert types(w.take()) == ["mtSendData"]
    host.on_message(sn.alive(4.0, head_inf=0x8A), w, 12.8)  # a configured alive: nothing
    assert w.take() == []
    st = host.status()
    assert st["state"] == "pinging" and st["pings_requested"] == 6 and st["replies"] == 5
    assert st["alives"] == 4 and st["versions"] == 1 and st["configured"] == 1
    assert st["serial_number"] == 77 and st["timeouts"] == 0


def test_no_alive_proceeds_after_the_alive_timeout():
    host = SeaNetHost(alive_timeout_s=2.0)
    w = Wire()
    host.on_connect(w, 0.0)
    host.on_idle(w, 1.99)
    assert w.take() == []
    host.on_idle(w, 2.0)
    assert types(w.take()) == ["mtSendVersion"] and host.stats.timeouts == 0


def test_reboot_on_connect():
    host = SeaNetHost(reboot_on_connect=True)
    w = Wire()
    host.on_connect(w, 0.0)
    assert types(w.take()) == ["mtReBoot"] and host.state is HostState.WAIT_ALIVE


def test_resend_then_restart_after_max_timeouts():
    host, w = ready_host(max_timeouts=3)
    host.on_idle(w, 0.79)  # reply_timeout 0.5 s from 0.3
    assert w.take() == []
    host.on_idle(w, 0.8)
    assert types(w.take()) == ["mtSendData"]
    host.on_idle(w, 1.3)
    assert types(w.take()) == ["mtSendData"]
    assert (host.stats.timeouts, host.stats.resends, host.stats.restarts) == (2, 2, 0)
    host.on_idle(w, 1.8)  # third in a row: reset the head and start again
    assert types(w.take()) == ["mtReBoot"] and host.state is HostState.WAIT_ALIVE
    assert (host.stats.timeouts, host.stats.restarts, host.stats.pings_requested) == (3, 1, 3)
    host.on_message(sn.alive(0.0, head_inf=0x4A), w, 2.0)
    assert types(w.take()) == ["mtSendVersion"]


def test_a_reply_resets_the_timeout_count():
    host, w = ready_host(max_timeouts=2)
    host.on_idle(w, 0.8)
    host.on_message(sn.head_data(np.zeros(4, np.uint8), 0.0), w, 0.9)
    host.on_idle(w, 1.4)
    assert types(w.take()) == ["mtSendData", "mtSendData", "mtSendData"]
    assert host.stats.restarts == 0 and host.stats.timeouts == 2


def test_version_and_configure_timeouts():
    host = SeaNetHost(MsisPolling(reply_timeout_s=0.5), alive_timeout_s=2.0, max_timeouts=2)
    w = Wire()
    host.on_connect(w, 0.0)
    host.on_message(sn.alive(0.0, head_inf=0x4A), w, 0.0)
    host.on_idle(w, 0.5)
    assert types(w.take()) == ["mtSendVersion", "mtSendVersion"]
    host.on_message(sn.version_data(), w, 0.6)
    host.on_idle(w, 2.6)  # no configured alive within alive_timeout_s: command again
    assert types(w.take()) == ["mtHeadCommand", "mtHeadCommand"]
    host.on_idle(w, 4.6)
    assert types(w.take()) == ["mtReBoot"] and host.stats.restarts == 1


def test_alive_without_parameters_while_pinging_restarts_configuration():
    host, w = ready_host()
    host.on_message(sn.alive(9.0, head_inf=0x4A), w, 1.0)  # the head has reset
    assert types(w.take()) == ["mtSendVersion"] and host.stats.restarts == 1
    host.on_message(sn.version_data(), w, 1.1)
    assert types(w.take()) == ["mtHeadCommand"]


def test_head_status_error_resends_the_command_and_stray_data_is_counted():
    host, w = ready_host()
    err = sn.head_data(np.zeros(4, np.uint8), 0.0, head_status=sn.HeadStatus.MOTOR_ERROR)
    host.on_message(err, w, 0.4)
    assert types(w.take()) == ["mtHeadCommand"] and host.stats.reconfigures == 1
    host.on_message(sn.head_data(np.zeros(4, np.uint8), 0.0), w, 0.5)  # not asked for now
    assert w.take() == [] and host.stats.unsolicited == 1
    host.on_message(sn.head_data(np.zeros(4, np.uint8), 0.0, tx=3), w, 0.5)  # other node
    assert host.stats.unsolicited == 1


# -- back to back with the emulated head ---------------------------------------------------------


class Bench:
    """Host and head wired back to back in memory, stepped in simulated time.

    ``drop_replies`` drops that many of the head's next mtHeadData packets on the way back."""

    def __init__(self, cfg: MsisPolling, head: MsisHead | None = None, **host_kw) -> None:
        self.head = head if head is not None else MsisHead(config_delay_s=0.05)
        self.host = SeaNetHost(cfg, time_ms=clock_ms, **host_kw)
        self.framer = sn.SeaNetFramer(policy="raise")
        self.t = 0.0
        self.to_head: list[bytes] = []
        self.sent: list = []  # host -> head, decoded
        self.got: list = []  # head -> host, decoded (delivered only)
        self.events: list = []  # (direction, message) in line order: ">" to head, "<" back
        self.drop_replies = 0
        self.dropped = 0

    def write(self, data: bytes) -> None:
        self.to_head.append(bytes(data))
        msgs = sn.decode(data)
        self.sent.extend(msgs)
        self.events.extend((">", m) for m in msgs)

    def deliver(self, data: bytes) -> None:
        for frame in self.framer.feed(data):
            for msg in sn.decode(frame.data):
                if isinstance(msg, sn.HeadData) and self.drop_replies:
                    self.drop_replies -= 1
                    self.dropped += 1
                    continue
                self.got.append(msg)
                self.events.append(("<", msg))
                self.host.on_message(msg, self.write, self.t)

    def start(self) -> None:
        self.host.on_connect(self.write, self.t)
        self.deliver(self.head.power_up(self.t))

    def step(self, dt: float = 0.02) -> None:
        self.t += dt
        pending, self.to_head = self.to_head, []
        for data in pending:
            self.deliver(self.head.feed(data, self.t))
        self.deliver(self.head.tick(self.t))
        self.host.on_idle(self.write, self.t)

    def run(self, seconds: float, dt: float = 0.02) -> None:
        for _ in range(round(seconds / dt)):
            self.step(dt)

    def head_data(self) -> list[sn.HeadData]:
        return [m for m in self.got if isinstance(m, sn.HeadData)]


def test_full_exchange_back_to_back():
    cfg = MsisPolling(range_m=20.0, n_bins=200, step_deg=0.9, gain=0.5)
    b = Bench(cfg)
    b.start()
    b.run(0.2)
    # the order on the line: Alive -> SendVersion -> VersionData -> HeadCommand -> Alive (ack)
    # -> Alive (ready) -> SendData -> HeadData -> SendData -> ...
    assert types(b.got[:4]) == ["mtAlive", "mtVersionData", "mtAlive", "mtAlive"]
    assert not b.got[0].ready and b.got[2].sent_cfg and not b.got[2].ready and b.got[3].ready
    assert types(b.sent[:3]) == ["mtSendVersion", "mtHeadCommand", "mtSendData"]
    b.run(2.0)
    hds = b.head_data()
    polls = [m for m in b.sent if isinstance(m, sn.SendData)]
    assert len(hds) > 50
    # exactly one HeadData per SendData: strictly alternating on the line
    polling = [m.TYPE for _, m in b.events if isinstance(m, sn.SendData | sn.HeadData)]
    assert polling == ["mtSendData", "mtHeadData"] * len(hds) + ["mtSendData"]
    # the last mtSendData is still on its way to the head
    assert len(polls) == b.host.stats.pings_requested == len(hds) + 1
    assert b.head.stats.polls == b.head.stats.head_data == len(hds)
    assert b.host.stats.replies == len(hds) and b.host.stats.timeouts == 0
    # bearings step by the configured 16 units (0.9 deg), clockwise
    steps = [
        (sn.rad_to_angle(b2.bearing) - sn.rad_to_angle(b1.bearing)) % UNITS
        for b1, b2 in itertools.pairwise(hds)
    ]
    assert set(steps) == {16}
    # range, bins and ADInterval in HeadData agree with the command
    cmd = b.host.command
    for hd in hds:
        assert len(hd.bins) == cmd.n_bins == 200
        assert hd.ad_interval == cmd.ad_interval and hd.range_scale_raw == cmd.range_scale_raw
        assert hd.hd_ctrl == cmd.hd_ctrl and hd.gain == cmd.gain_ch1 == 0.5
    assert hds[0].bin_length(1500.0) * 200 == pytest.approx(20.0, rel=2e-3)
    # the head clock follows the host's mtSendData time
    assert b.head.head_time(b.t) == pytest.approx(b.t, abs=0.05)


def test_sector_scan_reverses_through_the_gateway_driver():
    cfg = MsisPolling(
        step_deg=1.8, left_limit_deg=315.0, right_limit_deg=45.0, continuous=False, n_bins=50
    )
    b = Bench(cfg)
    b.start()
    b.run(3.0)
    hds = b.head_data()
    left, right = 5600, 800
    span = (right - left) % UNITS  # 1600 = 90 deg, 50 steps of 32
    offs = [(sn.rad_to_angle(h.bearing) - left) % UNITS for h in hds]
    assert offs[0] == 800  # starts where it was: centred (bearing 0)
    assert all(0 <= o <= span for o in offs)
    turns = [
        i for i in range(1, len(offs) - 1) if (offs[i] - offs[i - 1]) * (offs[i + 1] - offs[i]) < 0
    ]
    assert len(turns) >= 2 and all(offs[i] in (0, span) for i in turns)
    assert {abs(offs[i + 1] - offs[i]) for i in range(len(offs) - 1)} == {32}
    at_limits = [h.sweep_code for h, o in zip(hds, offs, strict=True) if o in (0, span)]
    assert set(at_limits) <= {sn.SweepCode.AT_LEFT_LIMIT, sn.SweepCode.AT_RIGHT_LIMIT}
    assert len(at_limits) == len(turns) + (offs[-1] in (0, span))


def test_lost_reply_is_resent_and_the_scan_goes_on():
    b = Bench(MsisPolling(reply_timeout_s=0.3, n_bins=50))
    b.start()
    b.run(0.5)
    before = len(b.head_data())
    b.drop_replies = 1
    b.run(1.0)
    assert b.dropped == 1
    assert (b.host.stats.timeouts, b.host.stats.resends, b.host.stats.restarts) == (1, 1, 0)
    hds = b.head_data()
    assert len(hds) > before + 10
    # the lost line's bearing is missing, the transducer stepped on: one gap of two steps
    gaps = [
        (sn.rad_to_angle(y.bearing) - sn.rad_to_angle(x.bearing)) % UNITS
        for x, y in itertools.pairwise(hds)
    ]
    assert sorted(set(gaps)) == [32, 64] and gaps.count(64) == 1
    assert b.head.stats.polls == b.host.stats.pings_requested - 1  # the last one in flight
    assert b.head.stats.head_data == len(hds) + 1  # one answered, lost on the way back


def test_head_reset_mid_scan_is_reconfigured():
    b = Bench(MsisPolling(n_bins=50))
    b.start()
    b.run(0.5)
    n = len(b.head_data())
    b.deliver(b.head.power_up(b.t))  # a power glitch: the head forgets its parameters
    b.run(0.5)
    assert b.host.stats.restarts == 1 and b.head.stats.commands == 2
    assert len(b.head_data()) > n + 10
    # after the reset the scan starts again from the centre
    assert sn.rad_to_angle(b.head_data()[n].bearing) == 0


def test_unplugged_head_times_out_then_restarts_when_it_is_back():
    b = Bench(MsisPolling(n_bins=50, reply_timeout_s=0.2), max_timeouts=3, alive_timeout_s=1.5)
    b.start()
    b.run(0.5)
    b.head.power_off()
    b.run(2.0)  # three timeouts: mtReBoot into the void, waiting for an mtAlive
    assert b.host.stats.restarts == 1 and b.host.state is HostState.WAIT_ALIVE
    assert types(b.sent[-1:]) == ["mtReBoot"]
    n = len(b.head_data())
    b.deliver(b.head.power_up(b.t))  # replugged
    b.run(1.0)
    assert b.host.state is HostState.PINGING and len(b.head_data()) > n + 10
    assert b.host.stats.configured == 2


def test_echo_of_a_wall_through_the_whole_chain():
    world = World(lines=[[8.04, -30.0, 8.04, 30.0]])  # a wall 8.04 m north
    rng = np.random.default_rng(11)
    head = MsisHead(
        make_echo(world, lambda: (0.0, 0.0, 0.0), rng, speckle=0.0), config_delay_s=0.05
    )
    b = Bench(MsisPolling(range_m=20.0, n_bins=200, step_deg=1.8), head=head)
    b.start()
    b.run(5.0)
    hds = b.head_data()
    # looking north (bearing 0) the brightest bin is the wall's; looking south nothing
    north = [h for h in hds if sn.rad_to_angle(h.bearing) == 0]
    south = [h for h in hds if sn.rad_to_angle(h.bearing) == 3200]
    assert north and south
    bin_len = north[0].bin_length(1500.0)
    for h in north:
        assert int(np.argmax(h.bins)) == int(8.04 / bin_len)
        assert h.bins.max() > 150
    for h in south:
        assert h.bins.max() < 80


# -- over a real pty ------------------------------------------------------------------------------


@pytest.mark.e2e
def test_exchange_over_a_real_pty():
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    head = MsisHead(alive_period_s=0.2, config_delay_s=0.02)
    stop = threading.Event()
    t0 = time.monotonic()
    errors: list[BaseException] = []

    def run_head() -> None:
        try:
            os.write(master, head.power_up(0.0))
            while not stop.is_set():
                ready, _, _ = select.select([master], [], [], 0.005)
                t = time.monotonic() - t0
                out = head.feed(os.read(master, 4096), t) if ready else b""
                out += head.tick(t)
                if out:
                    os.write(master, out)
        except BaseException as exc:  # surfaced by the test below
            errors.append(exc)

    cfg = MsisPolling(range_m=10.0, n_bins=64, step_deg=3.6, reply_timeout_s=0.5)
    host = SeaNetHost(cfg, alive_timeout_s=1.0)
    ser = serial.Serial(path, 115200, timeout=0.02)  # open (and flush) before the head speaks
    thread = threading.Thread(target=run_head, daemon=True)
    framer = sn.SeaNetFramer(policy="raise")
    got: list = []
    try:
        host.on_connect(ser.write, time.monotonic())
        thread.start()
        deadline = time.monotonic() + 20.0
        while sum(isinstance(m, sn.HeadData) for m in got) < 40 and time.monotonic() < deadline:
            data = ser.read(1)
            data += ser.read(ser.in_waiting)
            for frame in framer.feed(data):
                for msg in sn.decode(frame.data):
                    got.append(msg)
                    host.on_message(msg, ser.write, time.monotonic())
            host.on_idle(ser.write, time.monotonic())
    finally:
        stop.set()
        thread.join(2.0)
        ser.close()
        os.close(master)
        os.close(slave)
    assert not errors
    assert framer.stats.bad_frames == 0 and head.stats.bad_frames == 0
    hds = [m for m in got if isinstance(m, sn.HeadData)]
    assert len(hds) >= 40
    first = got.index(hds[0])
    assert {"mtVersionData", "mtAlive"} <= set(types(got[:first]))
    # one HeadData per SendData, bearing stepping by 64 units (3.6 deg) from the centre
    assert [sn.rad_to_angle(h.bearing) for h in hds[:40]] == [(64 * k) % UNITS for k in range(40)]
    assert all(len(h.bins) == 64 and h.ad_interval == host.command.ad_interval for h in hds)
    # the last mtSendData may still be on its way when the test stops
    assert head.stats.head_data == head.stats.polls
    assert host.stats.pings_requested - head.stats.polls in (0, 1)
    assert head.stats.head_data - host.stats.replies in (0, 1)
    assert host.stats.timeouts == 0 and host.stats.replies == len(hds)
    assert math.isclose(hds[0].range_m, 10.0)


def poll_over_serial(ser: serial.Serial, host: SeaNetHost, n_pings: int) -> list:
    """Drive ``host`` over the open port ``ser`` until ``n_pings`` mtHeadData arrived."""
    framer = sn.SeaNetFramer(policy="ignore")
    got: list = []
    host.on_connect(ser.write, time.monotonic())
    deadline = time.monotonic() + 20.0
    while sum(isinstance(m, sn.HeadData) for m in got) < n_pings:
        assert time.monotonic() < deadline, f"{host.status()}"
        data = ser.read(1)
        data += ser.read(ser.in_waiting)
        for frame in framer.feed(data):
            for msg in sn.decode(frame.data):
                got.append(msg)
                host.on_message(msg, ser.write, time.monotonic())
        host.on_idle(ser.write, time.monotonic())
    return got


@pytest.mark.e2e
@pytest.mark.parametrize("faulty", [False, True])
def test_head_served_on_a_pty_port_with_the_sim_clock(faulty):
    """serve_on_port: the head on a paced PtyPort, pings delayed on the simulation clock, the
    host polling with pyserial; with faults (garbage, corruption, dropouts) the host re-sends
    and never accepts a damaged scan line."""
    clock = SimClock(speed=4.0)
    world = World(lines=[[6.04, -30.0, 6.04, 30.0]])
    rng = np.random.default_rng(3)
    head = MsisHead(make_echo(world, lambda: (0.0, 0.0, 0.0), rng, speckle=0.0), alive_period_s=0.5)
    faults = None
    if faulty:
        settings = FaultSettings(garbage_p=0.3, corrupt_p=0.1, truncate_p=0.05, dropout_p=0.05)
        faults = FaultInjector(settings, np.random.default_rng(4), framer=sn.SeaNetFramer)
    # with faults the host must re-send soon; without, a reply late past 0.15 s is a thread
    # starved of CPU (a busy host), not a lost line: the test counts timeouts as losses
    cfg = MsisPolling(range_m=10.0, n_bins=50, step_deg=7.2,
                      reply_timeout_s=0.15 if faulty else 2.0)  # fmt: skip
    host = SeaNetHost(cfg, alive_timeout_s=1.0)
    # the serial side opens first: its open flushes input, the power-up mtAlive must follow
    with (
        PtyPort("msis", 115200, clock=clock) as port,
        serial.Serial(port.path, 115200, timeout=0.02) as ser,
    ):
        clock.start_thread()
        task = serve_on_port(head, port, clock, faults=faults)
        try:
            got = poll_over_serial(ser, host, 60)
        finally:
            task.cancel()
            clock.stop()
    hds = [m for m in got if isinstance(m, sn.HeadData)]
    assert len(hds) >= 60
    units = [sn.rad_to_angle(h.bearing) for h in hds]
    assert all(u % 128 == 0 for u in units)  # 7.2 deg steps from the centre
    assert all(len(h.bins) == 50 for h in hds)
    north = [h for h, u in zip(hds, units, strict=True) if u == 0]
    assert north and all(int(np.argmax(h.bins)) == int(6.04 / h.bin_length(1500.0)) for h in north)
    if not faulty:
        assert units[:30] == [(128 * k) % UNITS for k in range(30)]
        assert host.stats.timeouts == 0
    else:
        assert faults.counts.bad_frames + faults.counts.dropped > 0
        assert host.stats.timeouts > 0 and host.stats.resends > 0
        # a lost line leaves its bearing out; the transducer steps once per answered ping
        assert all(0 < (b - a) % UNITS <= 4 * 128 for a, b in itertools.pairwise(units))
