"""The USB-CAN adapter unplugged and replugged while ``auvgw run`` reads it (separate
processes): an emulated SLCAN adapter (:class:`auvgw.sim_devices.slcan.SlcanAdapter`, on a pty
behind a stable symlink) carries the MS3A magnetometer's CAN form (``ms3a.dbc``: two frames per
sample sharing ``Counter``); the gateway opens it with python-can's ``slcan`` interface; a
subscriber process collects the decoded samples while this process watches status and
liveliness."""

from __future__ import annotations

import can
import pytest

from auvgw.config.bus import BusConfig
from auvgw.drivers.can_codec import ms3a_can
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import (
    endpoint,
    free_port,
    read_jsonl,
    wait_until,
)

N_BEFORE = 20  # samples sent before the unplug (40 frames)
N_UNPLUGGED = 5  # samples the magnetometer produces while the adapter is out (never delivered)
N_AFTER = 30  # samples sent once the gateway has reopened the adapter
FIRST_AFTER = 1000  # counter of the first sample after the replug (a visible jump)


@pytest.fixture
def adapter(slcan_adapter):
    return slcan_adapter


def sample_frames(codec, counter: int) -> list[can.Message]:
    """The two CAN frames of one MS3A sample with this counter (field values follow it)."""
    s = codec.sample_type(
        counter=counter, bx=100.0 + counter, by=-200.5, bz=40000.0 - counter, status="OK"
    )
    return [
        can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=f.is_extended_id)
        for f in codec.encode_sample(s)
    ]


def test_can_adapter_unplug_and_replug_reported_and_resumed_without_loss(procs, tmp_path, adapter):
    codec = ms3a_can()
    ep = endpoint(free_port())
    cfg = tmp_path / "gw.toml"  # written by hand: the transport has a nested options table
    cfg.write_text(
        'vehicle = "canfault"\nstatus_period_s = 0.2\n'
        f'[bus]\nlisten = ["{ep}"]\n'
        '[devices.mag_can]\nformat = "can"\ndbc = "ms3a.dbc"\n'
        "backoff_initial_s = 0.05\nbackoff_max_s = 0.3\n"
        f'transport = {{ kind = "can", interface = "slcan", channel = "{adapter.device}", '
        "bitrate = 500000, options = { sleep_after_open = 0 } }\n"
    )
    gw = procs.gateway(cfg)
    out = tmp_path / "sub.jsonl"
    n_expected = N_BEFORE + N_AFTER
    sub = procs.subscriber(
        "sub",
        "--vehicle",
        "canfault",
        "--connect",
        ep,
        "--device",
        "mag_can",
        "--count",
        str(n_expected),
        "--out",
        str(out),
    )
    before = list(range(N_BEFORE))
    after = list(range(FIRST_AFTER, FIRST_AFTER + N_AFTER))
    with GatewaySubscriber("canfault", BusConfig(connect=[ep])) as me:
        wait_until(lambda: (me.status("mag_can") or {}).get("connected"), 60, what="connected")
        wait_until(lambda: adapter.is_open, 30, what="python-can opened the SLCAN channel")
        wait_until(lambda: "mag_can" in me.alive(), 30, what="mag_can token")
        sub.wait_line("READY", 60)
        for c in before:
            assert adapter.send_many(sample_frames(codec, c))
        wait_until(
            lambda: (me.status("mag_can") or {}).get("frames") == 2 * N_BEFORE, 30, what="frames"
        )

        adapter.unplug()
        down = wait_until(
            lambda: (s := me.status("mag_can")) and not s["connected"] and s,
            30,
            what="outage reported",
        )
        wait_until(lambda: "mag_can" not in me.alive(), 30, what="mag_can token withdrawn")
        assert "gateway" in me.alive()
        assert down["outages"] == 1 and down["connected"] is False
        assert down["last_error"], down
        # what the sensor produces while the cable is out goes nowhere (the adapter counts it)
        for c in range(N_BEFORE, N_BEFORE + N_UNPLUGGED):
            assert not adapter.send_many(sample_frames(codec, c))
        assert adapter.stats.dropped_closed == 2 * N_UNPLUGGED

        adapter.replug()
        up = wait_until(
            lambda: (s := me.status("mag_can")) and s["connected"] and s, 60, what="replug"
        )
        wait_until(lambda: adapter.is_open, 30, what="the SLCAN channel reopened")
        wait_until(lambda: "mag_can" in me.alive(), 30, what="mag_can token back")
        assert up["connects"] == 2 and up["outages"] == 1
        for c in after:
            assert adapter.send_many(sample_frames(codec, c))
        done = sub.wait_line("DONE", 60)
        final = wait_until(
            lambda: (s := me.status("mag_can"))["frames"] == 2 * n_expected and s,
            30,
            what="all frames counted",
        )

    assert done.startswith(f"DONE {n_expected} dropped=0"), done
    got = read_jsonl(out)
    assert {g["type"] for g in got} == {"MS3A_Sample"}
    counters = [g["msg"]["counter"] for g in got]
    assert counters == before + after
    # every sample sent after the replug arrived, in order, with its own values
    post = got[N_BEFORE:]
    assert [g["msg"]["counter"] for g in post] == list(range(FIRST_AFTER, FIRST_AFTER + N_AFTER))
    for g in got:
        c = g["msg"]["counter"]
        # the DBC's nT kept (0.1 nT resolution on the wire)
        assert g["msg"]["bx"] == pytest.approx(100.0 + c, abs=0.01)
        assert g["msg"]["by"] == pytest.approx(-200.5, abs=0.01)
        assert g["msg"]["bz"] == pytest.approx(40000.0 - c, abs=0.01)
        assert g["msg"]["status"] == "OK"
    assert final["bad_frames"] == 0 and final["connected"] is True
    assert adapter.stats.frames_to_host == 2 * n_expected
    err = gw.stderr()
    assert "mag_can: disconnected" in err and err.count("mag_can: connected on") == 2


def test_a_silent_can_adapter_is_reopened_and_recovers_without_a_restart(procs, tmp_path, adapter):
    """The adapter stops delivering while its port stays open (its channel closed by a reset,
    as a second gateway's ``C`` on exit did): the device goes stale while ``connected``; after
    ``reopen_silent_periods`` periods (at least ``stale_after_s``) the gateway closes and
    reopens it, python-can opens the channel again, and the samples flow: ``reopens`` 1, the
    same gateway process, no outage (``connected`` throughout, one connect)."""
    import threading

    codec = ms3a_can()
    ep = endpoint(free_port())
    cfg = tmp_path / "gw.toml"
    cfg.write_text(
        'vehicle = "canquiet"\nstatus_period_s = 0.2\n'
        f'[bus]\nlisten = ["{ep}"]\n'
        '[devices.mag_can]\nformat = "can"\ndbc = "ms3a.dbc"\n'
        "stale_after_s = 0.5\nreopen_silent_periods = 100\n"
        f'transport = {{ kind = "can", interface = "slcan", channel = "{adapter.device}", '
        "bitrate = 500000, options = { sleep_after_open = 0 } }\n"
    )
    gw = procs.gateway(cfg)
    stop = threading.Event()

    def magnetometer() -> None:  # the device: 50 samples/s, whether the adapter delivers or not
        c = 0
        while not stop.wait(0.02):
            adapter.send_many(sample_frames(codec, c))
            c += 1

    feeder = threading.Thread(target=magnetometer, daemon=True)
    with GatewaySubscriber("canquiet", BusConfig(connect=[ep])) as me:
        wait_until(lambda: adapter.is_open, 60, what="python-can opened the SLCAN channel")
        feeder.start()
        try:
            wait_until(lambda: (me.status("mag_can") or {}).get("frames", 0) >= 50, 60, what="flow")
            adapter.reset()
            stale = wait_until(
                lambda: (s := me.status("mag_can")) and s["stale"] and s["connected"] and s,
                30,
                what="stale while connected",
            )
            back = wait_until(
                lambda: (s := me.status("mag_can")) and s["reopens"] == 1 and s["connected"] and s,
                30,
                what="reopened",
            )
            wait_until(lambda: adapter.is_open, 30, what="the channel opened again")
            wait_until(
                lambda: me.status("mag_can")["frames"] >= back["frames"] + 50, 30, what="frames"
            )
        finally:
            stop.set()
            feeder.join(5)
        final = me.status("mag_can")
        assert "mag_can" in me.alive()
    assert stale["reopens"] == 0
    assert final["reopens"] == 1 and final["connected"] is True and final["stale"] is False
    assert final["connects"] == 1 and final["outages"] == 0 and final["bad_frames"] == 0
    assert "no frame for" in final["last_error"] and "reopen_silent_periods" in final["last_error"]
    assert adapter.stats.dropped_closed > 0  # what the device sent while the channel was closed
    assert gw.p.poll() is None  # the same gateway process throughout
    err = gw.stderr()
    assert err.count("mag_can: no frame for") == 1 and err.count("mag_can: connected on") == 2
    assert err.count("WARNING auvgw.gateway: mag_can: frames again after 1 reopen(s)") == 1
