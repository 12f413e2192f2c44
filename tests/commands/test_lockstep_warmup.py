"""The fusion's clock warm-up against a lock-step sim (issue 30): the warm-up holds every
sample of its first ``clock_warmup_s`` of receive time, stamped on the sim's clock; a sim that
holds vehicle time until the pilot answers odometry must let that much time pass first."""

from __future__ import annotations

import pytest

from auvgw.commands.demo_closed_loop import lockstep_first_s
from auvgw.commands.demo_parts import _fusion_config
from auvgw.drivers import hn100
from auvgw.fusion.adapters import MessageAdapter
from auvgw.sim_devices.clock import SimClock


def _nav(t: float) -> object:
    nav = hn100.Hn100Nav(seq=1, status=hn100.CODEC.status_word(aligned=True, dvl_aided=True),
                         time=t, roll=0.0, pitch=0.0, heading=0.0, rate_x=0.0, rate_y=0.0,
                         rate_z=0.0, accel_x=0.0, accel_y=0.0, accel_z=-9.8, vel_n=1.0,
                         vel_e=0.0, vel_d=0.0, latitude=0.0, longitude=0.0, depth=10.0)  # fmt: skip
    return hn100.CODEC.decode(hn100.CODEC.encode(nav))


def _fly(first: float, warmup_s: float, host_s: float = 12.0) -> SimClock:
    """INS at 100 Hz stamped on a lock-step clock (host time in 10 ms ticks), through the
    fusion's adapter; the 'pilot' answers every sample the adapter releases."""
    host = [0.0]
    clock = SimClock(speed=1.0, time_fn=lambda: host[0])
    clock.lockstep(0.15, 5.0, first)
    clock.start()
    adapter = MessageAdapter(dvl_device=None, latency_s={"ins": 0.005}, warmup_s=warmup_s)
    tick = 0
    while host[0] < host_s:
        host[0] += 0.01
        now = clock.now()
        while tick * 0.01 + 0.005 <= now:  # each frame received 5 ms after its device time
            for s in adapter.adapt_all("ins", tick * 0.01 + 0.005, _nav(tick * 0.01)):
                clock.answered(s.t)
            tick += 1
    return clock


def test_the_demo_fusions_warm_up_fits_in_the_lockstep_sims_first_hold():
    fusion = _fusion_config("auv1", (0.0, 0.0, 10.0), {})
    assert fusion.clock_warmup_s == pytest.approx(2.0)  # the demo's defaults: the warm-up is on
    # the cause: a first hold of 1 s stands the clock still inside the 2 s warm-up, and only
    # the 5 s hold timeouts move it on, a step at a time
    stuck = _fly(1.0, fusion.clock_warmup_s)
    assert stuck.hold_timeouts >= 2 and stuck.now() < 2.5
    # the fix: the first hold covers the warm-up; then every hold ends with an answer
    ok = _fly(lockstep_first_s(fusion), fusion.clock_warmup_s)
    assert ok.hold_timeouts == 0 and ok.now() > 11.0
    assert ok.answers > 1000
