"""The gateway's parts in one process: backoff, health accounting, the shared decode path,
configuration loading (paths, bus checks), the subscriber's typed rebuild, and the
in-process gateway reconnecting to a ``socket://`` device that drops the link."""

from __future__ import annotations

import json
import threading

import pytest

from auvgw.bus import decode_envelope, encode_envelope
from auvgw.config.gateway import (
    ConfigError,
    load_gateway_config,
    parse_gateway_config,
)
from auvgw.decoding import (
    DeviceDecoder,
    make_decoders,
    message_kind,
    pack_can_raw,
    unpack_can_raw,
)
from auvgw.drivers.formats import get_format
from auvgw.drivers.spec import to_jsonable
from auvgw.drivers.transports import Chunk
from auvgw.health import Backoff, DeviceHealth
from auvgw.subscribe import typed_message
from auvgw.testing import local_decoded, pd0_frames, wait_until


def test_backoff_doubles_to_the_cap_and_resets():
    b = Backoff(0.2, 1.0)
    assert [b.next_delay() for _ in range(5)] == [0.2, 0.4, 0.8, 1.0, 1.0]
    b.reset()
    assert b.next_delay() == 0.2


def test_health_rate_is_counted_over_the_device_times_so_a_late_burst_reads_true():
    """A 100 Hz INS whose frames stall for 2 s of the stamp clock, then arrive in a burst
    (200 frames in 0.1 s) and 4.5 s on time: the rate over the 5 s window is the device's
    100 Hz, where the count of stamps reads 130 Hz; a device clock that restarts starts a new
    span."""
    h = DeviceHealth("ins", "hn100", window_s=5.0)
    t0 = 1_000_000_000_000
    stamps = [t0 + k * 10_000_000 for k in range(300)]  # 3 s on time
    stamps += [stamps[-1] + 2_000_000_000 + k * 500_000 for k in range(1, 201)]  # the burst
    stamps += [stamps[-1] + k * 10_000_000 for k in range(1, 451)]  # on time again
    for k, stamp in enumerate(stamps):
        h.seen(stamp, "hn100.Nav", t_device_s=50.0 + k * 0.01)
    now = stamps[-1] + 5_000_000
    counted = sum(1 for s in stamps if s >= now - 5_000_000_000)
    assert counted / 5.0 > 125  # what a count of receive stamps would say
    assert h.rate_hz(now) == pytest.approx(100.0)
    h.seen(now + 10_000_000, "hn100.Nav", t_device_s=0.0)  # the device clock restarted
    h.seen(now + 20_000_000, "hn100.Nav", t_device_s=0.02)
    assert h.rate_hz(now + 20_000_000) == pytest.approx(50.0)  # 2 samples, 0.02 s: the new span
    h.seen(now + 30_000_000, "hn100.Status")  # a message type without a device time
    snap = h.snapshot(now + 30_000_000)  # seen for less than a window: no rate yet
    assert "hn100.Status" not in snap["rates_hz"] and snap["rate_hz"] is None
    later = now + 5_030_000_000  # a whole window after it: counted per window
    assert h.snapshot(later)["rates_hz"]["hn100.Status"] == 0.2


def test_health_rate_of_an_untimed_type_is_its_sampling_rate_through_bursts():
    """A 20 Hz magnetometer (no time on its wire) read with stalls of 1.5 s, each followed
    by a burst: the count of stamps in the 5 s window swings around 20 Hz, the lower envelope
    of the stamps gives 20 Hz at every status (issue 33); a lone burst is no rate."""
    h = DeviceHealth("magnetometer", "ms3a", window_s=5.0)
    t0 = 1_000_000_000_000
    stamps = []
    for k in range(400):  # sampled every 50 ms; read on time except in 1.5 s of every 4 s
        t = t0 + k * 50_000_000
        stall_end = t0 + ((t - t0) // 4_000_000_000) * 4_000_000_000 + 1_500_000_000
        stamps.append(max(t, stall_end) if (t - t0) % 4_000_000_000 < 1_500_000_000 else t)
    counts, rates, fed = [], [], 0
    for now in range(t0 + 6_000_000_000, t0 + 19_000_000_000, 300_000_000):
        while fed < len(stamps) and stamps[fed] <= now:
            h.seen(stamps[fed], "Ms3aSample")
            fed += 1
        counts.append(sum(now - 5_000_000_000 <= s <= now for s in stamps) / 5.0)
        rates.append(h.rate_hz(now))
    assert max(abs(c - 20.0) for c in counts) >= 2.0  # what a count of stamps says
    assert rates == pytest.approx([20.0] * len(rates))
    burst = DeviceHealth("magnetometer", "ms3a", window_s=5.0)
    for _ in range(30):  # a backlog read in one chunk at connect
        burst.seen(t0, "Ms3aSample")
    assert burst.rate_hz(t0 + 100_000_000) is None


def test_health_rate_of_a_single_frame_before_a_stall_is_not_known_yet():
    """The first frame of a connection, then a stall: one timed sample is no rate (counted
    over the window it read 0.2 Hz for a 100 Hz INS, issue 33); the burst that follows reads
    the device's rate."""
    h = DeviceHealth("ins", "hn100", window_s=5.0)
    t0 = 1_000_000_000_000
    h.seen(t0, "hn100.Nav", t_device_s=1.17)
    snap = h.snapshot(t0 + 1_000_000_000)
    assert snap["rate_hz"] is None and snap["rates_hz"] == {}
    for k in range(1, 200):  # 2 s of samples read in 0.2 s after a 1.7 s stall
        h.seen(t0 + 1_700_000_000 + k * 1_000_000, "hn100.Nav", t_device_s=1.17 + k * 0.01)
    assert h.rate_hz(t0 + 2_000_000_000) == pytest.approx(100.0)


def test_health_counts_outages_connects_and_rates():
    h = DeviceHealth("dvl", "pd0", window_s=2.0)
    h.set_connected(False, "cannot open", retry_in_s=0.4)
    assert h.snapshot()["next_retry_s"] == 0.4 and h.outages == 0  # never up: no outage
    h.set_connected(True)
    t = 1_000_000_000_000
    for i in range(10):
        h.seen(t + i * 100_000_000, "pd0.Ensemble")
    snap = h.snapshot(t + 1_000_000_000, stale_after_s=2.0)
    assert snap["rate_hz"] == 10.0 and snap["messages"] == {"pd0.Ensemble": 10}
    assert snap["silent_s"] == pytest.approx(0.1) and snap["stale"] is False
    assert h.snapshot(t + 5_000_000_000, stale_after_s=2.0)["stale"] is True
    assert h.snapshot(t + 5_000_000_000)["rate_hz"] == 0.0  # outside the window
    h.set_connected(False, "disconnected")
    h.set_connected(True)
    assert (h.connects, h.outages) == (2, 1)
    h.set_ended("end of file")
    snap = h.snapshot()
    assert snap["ended"] and not snap["connected"] and snap["last_error"] == "end of file"


def test_decoder_counts_survive_reconnects_and_name_the_offset(shared_data):
    frames = pd0_frames(shared_data, 4)
    dec = DeviceDecoder("dvl", get_format("pd0"))
    items = dec.feed(Chunk(b"junk" + frames[0] + frames[1][:100], 1))
    assert [i.raw for i in items] == [frames[0]] and items[0].offset == 4
    dec.reset()  # a reconnect: the partial frame is forgotten, counts carry on
    items = dec.feed(Chunk(frames[2] + frames[3], 2))
    assert [i.raw for i in items] == frames[2:] and items[0].offset == 0
    c = dec.counts()
    assert (c.frames, c.skipped_bytes) == (3, 4)
    # checksum-valid frame whose content the codec rejects: an error naming the offset
    bad = dec.item(b"\x7f\x7f\x04\x00", 1234)
    assert bad.messages == () and "byte offset 1234" in bad.error


def test_can_raw_form_round_trips():
    raw = pack_can_raw(0x18FF1234, True, b"\x01\x02\x03")
    assert unpack_can_raw(raw) == (0x18FF1234, True, b"\x01\x02\x03")
    assert unpack_can_raw(pack_can_raw(0x123, False, b"")) == (0x123, False, b"")


def test_envelope_round_trip_gives_the_typed_message(shared_data):
    frame = pd0_frames(shared_data, 1)[0]
    msg = get_format("pd0").decode(frame)[0]
    assert message_kind(msg) == "ensemble"
    payload, enc = encode_envelope(msg, "dvl", 123, 7, wire="pd0")
    assert str(enc) == "application/msgpack;auvgw/3/pd0.Ensemble"
    v1 = json.dumps({"v": 1, "msg": to_jsonable(msg)}, separators=(",", ":")).encode()
    assert len(payload) < 0.3 * len(v1)  # positional, raw wire numbers and arrays, not text
    env = decode_envelope(payload, "auv/x/sensor/dvl/ensemble")
    assert (env.type, env.device, env.t_recv_ns, env.seq) == ("pd0.Ensemble", "dvl", 123, 7)
    assert env.wire == "pd0"
    typed = typed_message(env.type, env.body)
    assert type(typed) is type(msg)
    assert json.loads(json.dumps(to_jsonable(typed))) == local_decoded([frame])[0]
    assert typed_message("NoSuchType", {}) is None
    with pytest.raises(ValueError, match="envelope version"):
        decode_envelope(json.dumps({"v": 99}).encode())
    with pytest.raises(ValueError, match="not an envelope"):
        decode_envelope(b"\xc1 not msgpack")


def test_relative_paths_resolve_next_to_the_config_file(tmp_path):
    (tmp_path / "site.dbc").write_text('VERSION ""\n')
    cfg_path = tmp_path / "vehicle.toml"
    cfg_path.write_text(
        '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "file", path = "cap/dvl.bin" }\n'
        '[devices.ins]\nformat = "can"\ndbc = "site.dbc"\n'
        'transport = { kind = "can", interface = "virtual", channel = "c" }\n'
        '[devices.mag]\nformat = "can"\ndbc = "ms3a.dbc"\n'
        'transport = { kind = "can", interface = "virtual", channel = "c" }\n'
    )
    cfg = load_gateway_config(cfg_path)
    assert cfg.devices["dvl"].transport.path == tmp_path / "cap" / "dvl.bin"
    assert cfg.devices["ins"].dbc == str(tmp_path / "site.dbc")
    assert cfg.devices["mag"].dbc == "ms3a.dbc"  # not next to the file: a shipped database
    assert cfg.source == str(cfg_path)
    assert cfg.devices["dvl"].msis is None


def test_config_defaults_and_seanet_polling():
    cfg = parse_gateway_config(
        {"devices": {"sonar": {"format": "seanet", "transport": {"kind": "serial", "url": "x"}}}}
    )
    assert cfg.vehicle == "auv1" and cfg.bus.mode == "peer" and cfg.bus.listen == []
    assert cfg.devices["sonar"].msis is not None and cfg.devices["sonar"].msis.range_m == 30.0
    with pytest.raises(ConfigError, match="'gateway' is reserved"):
        parse_gateway_config(
            {"devices": {"gateway": {"format": "pd0", "transport": {"kind": "serial", "url": "x"}}}}
        )


def test_a_format_that_cannot_load_is_a_config_error_naming_the_field():
    cfg = parse_gateway_config(
        {
            "devices": {
                "ins": {
                    "format": "can",
                    "dbc": "surely-missing.dbc",
                    "transport": {"kind": "can", "interface": "virtual", "channel": "c"},
                }
            }
        },
        "v.toml",
    )
    with pytest.raises(ConfigError, match=r"^v\.toml: devices\.ins\.dbc: "):
        make_decoders(cfg)


@pytest.mark.e2e
def test_in_process_gateway_reopens_after_a_reader_error(shared_data):
    """``socket://`` to a local server that drops the connection: the device is reported
    disconnected, reopened with backoff, and frames from the second connection still flow."""
    import socket

    from auvgw.gateway import Gateway

    frames = pd0_frames(shared_data, 6)
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    port = srv.getsockname()[1]
    served = []

    gws = []

    def serve() -> None:
        for k, part in enumerate((frames[:3], frames[3:]), start=1):
            conn, _ = srv.accept()
            served.append(conn)
            # pyserial's open() discards what arrived before it finished: send once connected
            wait_until(lambda k=k: gws and gws[0].device_status("dvl")["connects"] == k)
            first = k == 1
            conn.sendall(b"".join(part))
            if first:  # the device drops the link once its frames are through
                wait_until(lambda: len(got) >= 3, what="first part decoded")
                conn.close()

    got = []
    cfg = parse_gateway_config(
        {
            "vehicle": "unit1",
            "devices": {
                "dvl": {
                    "format": "pd0",
                    "transport": {"kind": "serial", "url": f"socket://127.0.0.1:{port}"},
                    "backoff_initial_s": 0.05,
                }
            },
        }
    )
    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with Gateway(cfg, on_message=lambda d, ts, m: got.append(to_jsonable(m))) as gw:
            gws.append(gw)
            wait_until(lambda: len(got) == 6, what="both connections' frames")
            st = gw.device_status("dvl")
    finally:
        for c in served:
            c.close()
        srv.close()
    assert [json.loads(json.dumps(m)) for m in got] == local_decoded(frames)
    assert st["connects"] == 2 and st["outages"] == 1 and st["frames"] == 6


def test_the_documented_example_configuration_is_valid():
    import re
    import tomllib

    from auvgw.ground.paths import REPO_ROOT

    text = (REPO_ROOT / "docs" / "gateway.md").read_text()
    block = re.findall(r"```toml\n(.*?)```", text, re.S)[0]
    cfg = parse_gateway_config(tomllib.loads(block), "docs/gateway.md")
    assert set(cfg.devices) == {"dvl", "sonar", "mbes", "geoswath", "ins", "mag_can", "replayed"}
    assert {d.transport.kind for d in cfg.devices.values()} == {"serial", "udp", "can", "file"}
    assert cfg.devices["sonar"].msis is not None and cfg.devices["sonar"].msis.n_bins == 300
    gs = cfg.devices["geoswath"].geoswath
    assert gs is not None and gs.model_khz in (125, 250, 500)


@pytest.mark.e2e
def test_a_frame_whose_envelope_fails_still_goes_out_raw(shared_data, tmp_path, monkeypatch):
    """Raw first holds when building a frame's envelope raises (fault injected into the
    envelope encoder): its raw sample is on the bus, the reader error is reported, and the
    frames before it went out raw and decoded."""
    import auvgw.gateway as gateway_mod
    from auvgw.bus import open_session
    from auvgw.config.bus import BusConfig
    from auvgw.testing import endpoint, free_port

    frames = pd0_frames(shared_data, 4)
    cap = tmp_path / "dvl.pd0"
    cap.write_bytes(b"".join(frames))
    cfg = parse_gateway_config(
        {"vehicle": "fail1", "devices": {"dvl": {"format": "pd0", "transport": {
            "kind": "file", "path": str(cap), "byte_rate": 20000}}}}
    )  # fmt: skip
    real_pack = gateway_mod.pack_envelope  # (PD0's envelope is read from the frame's bytes)
    calls = []

    def failing_third(*args):
        calls.append(args)
        if len(calls) == 3:
            raise ValueError("injected envelope failure")
        return real_pack(*args)

    monkeypatch.setattr(gateway_mod, "pack_envelope", failing_third)
    raw, dec = [], []
    with open_session(BusConfig(listen=[endpoint(free_port())])) as s:
        subs = [
            s.declare_subscriber("auv/fail1/raw/dvl", lambda smp: raw.append(smp)),
            s.declare_subscriber("auv/fail1/sensor/dvl/**", lambda smp: dec.append(smp)),
        ]
        with gateway_mod.Gateway(cfg, s) as gw:
            wait_until(lambda: len(raw) >= 3, what="three raw frames")
            wait_until(lambda: "injected" in gw.device_status("dvl")["last_error"], what="error")
        for sub in subs:
            sub.undeclare()
    assert [r.payload.to_bytes() for r in raw[:3]] == frames[:3]
    assert len(dec) >= 2
    assert [decode_envelope(d.payload.to_bytes()).seq & 0xFFFFFFFF for d in dec[:2]] == [1, 2]


@pytest.mark.e2e
def test_a_frame_the_codec_rejects_goes_out_raw_only(shared_data, tmp_path):
    """Between good ensembles (a capture replayed in a loop), one with a good checksum whose
    layout the codec refuses (a data type 1 byte long): it goes out raw, no decoded sample is
    read from its bytes, the decode error is counted with the decoder's text, and the
    listeners and health see the good ones."""
    import struct

    from auvgw.bus import open_session
    from auvgw.config.bus import BusConfig
    from auvgw.drivers import pd0
    from auvgw.gateway import Gateway
    from auvgw.testing import endpoint, free_port

    frames = pd0_frames(shared_data, 3)
    bad = bytearray(frames[1])
    offsets = struct.unpack_from(f"<{bad[5]}H", bad, 6)
    struct.pack_into("<H", bad, 8, offsets[2] - 1)  # the variable leader: 1 byte long
    nbytes = bad[2] | bad[3] << 8
    struct.pack_into("<H", bad, nbytes, pd0.checksum(bad[:nbytes]))
    bad = bytes(bad)
    with pytest.raises(Exception, match="PD0") as err:
        pd0.decode(bad)
    cap = tmp_path / "dvl.pd0"
    cap.write_bytes(frames[0] + bad + frames[2])
    cfg = parse_gateway_config(
        {"vehicle": "rej1", "devices": {"dvl": {"format": "pd0", "transport": {
            "kind": "file", "path": str(cap), "byte_rate": 20000, "loop": True}}}}
    )  # fmt: skip
    raw, dec, heard = [], [], []
    with open_session(BusConfig(listen=[endpoint(free_port())])) as s:
        subs = [
            s.declare_subscriber("auv/rej1/raw/dvl", lambda smp: raw.append(smp)),
            s.declare_subscriber("auv/rej1/sensor/dvl/**", lambda smp: dec.append(smp)),
        ]
        with Gateway(cfg, s, on_message=lambda d, t, m: heard.append(m)) as gw:
            wait_until(lambda: len(raw) >= 3 and len(heard) >= 2, what="three raw, two decoded")
            wait_until(lambda: gw.device_status("dvl")["decode_errors"] >= 1, what="the error")
            st = gw.device_status("dvl")
        for sub in subs:
            sub.undeclare()
    assert [r.payload.to_bytes() for r in raw[:3]] == [frames[0], bad, frames[2]]
    seqs = [decode_envelope(d.payload.to_bytes()).seq & 0xFFFFFFFF for d in dec]
    assert seqs[:2] == [1, 3] and all(k % 3 != 2 for k in seqs)
    assert str(err.value) in st["last_error"] and "byte offset" in st["last_error"]
    assert st["bad_frames"] == 0 and st["frames"] >= 3 * st["decode_errors"]


@pytest.mark.e2e
def test_writes_closer_than_the_read_interval_are_read_together(tmp_path):
    """``read_interval_s``: while bytes keep coming, a serial port is read at most that often,
    so writes closer together are read (and stamped) together; every frame still comes out.
    Three HN-100 frames written 10 ms apart with a 1 s interval (the most the setting takes):
    the last two share the receive stamp of one read (s41: the first frame is read alone
    before the others are written; written at once, a late first read took two of them)."""
    import os
    import time

    from auvgw.gateway import Gateway
    from auvgw.testing.format_samples import hn100_frames
    from auvgw.testing.ptys import PtyDevice

    dev = PtyDevice(tmp_path / "ins")
    frames = hn100_frames(3)
    got: list[tuple[int, object]] = []
    cfg = parse_gateway_config(
        {"vehicle": "pace1", "devices": {"ins": {"format": "hn100", "read_interval_s": 1.0,
         "transport": {"kind": "serial", "url": str(dev.link)}}}}
    )  # fmt: skip
    assert parse_gateway_config(
        {"devices": {"d": {"format": "pd0", "transport": {"kind": "serial", "url": "x"}}}}
    ).devices["d"].read_interval_s == 0.005
    try:
        with Gateway(cfg, on_message=lambda d, t, m: got.append((t, m))) as gw:
            wait_until(lambda: gw.device_status("ins")["connected"], what="the port open")
            os.write(dev.master, frames[0])  # read alone: the next read waits the interval
            wait_until(lambda: len(got) == 1, what="the first frame")
            for f in frames[1:]:
                os.write(dev.master, f)
                time.sleep(0.01)
            wait_until(lambda: len(got) == 3, what="three frames")
    finally:
        dev.unplug()
    assert [m.seq for _, m in got] == [get_format("hn100").decode(f)[0].seq for f in frames]
    assert got[1][0] == got[2][0]
    with pytest.raises(ConfigError, match="read_interval_s"):
        parse_gateway_config({"devices": {"d": {"format": "pd0", "read_interval_s": -1,
                                                "transport": {"kind": "serial", "url": "x"}}}})


@pytest.mark.e2e
def test_silence_limit_learns_the_period_floors_at_stale_and_backs_off():
    """When an open but silent device is reopened (host seconds): ``reopen_silent_periods``
    times its period (configured, or the median interval of its frame-bearing reads), at
    least ``stale_after_s``, doubled per fruitless reopen up to 16 times; never for a file."""
    from auvgw.gateway import Gateway, _Device

    def device(transport: dict | None = None, **extra) -> _Device:
        tr = transport or {"kind": "serial", "url": "/dev/null"}
        dev = {"format": "pd0", "transport": tr, **extra}
        cfg = parse_gateway_config({"vehicle": "v", "devices": {"d": dev}})
        return _Device("d", cfg.devices["d"], DeviceHealth("d", "pd0"), None)  # type: ignore[arg-type]

    d = device(stale_after_s=0.5, reopen_silent_periods=10)
    assert Gateway.silence_limit(d) is None  # nothing learned yet
    d.frame_reads.extend([0.0, 0.2, 0.4])
    assert Gateway.silence_limit(d) == pytest.approx(2.0)  # 10 x 0.2 s
    d.frame_reads.extend([0.41, 0.42, 1.0, 1.2, 1.4])  # a burst and a gap: the median holds
    assert Gateway.silence_limit(d) == pytest.approx(2.0)
    d.silent_reopens = 2
    assert Gateway.silence_limit(d) == pytest.approx(8.0)
    d.silent_reopens = 9
    assert Gateway.silence_limit(d) == pytest.approx(32.0)  # capped at 16 x
    fast = device(stale_after_s=0.5, reopen_silent_periods=10, expected_period_s=0.01)
    assert Gateway.silence_limit(fast) == pytest.approx(0.5)  # never before it is stale
    assert Gateway.silence_limit(device(reopen_silent_periods=0, expected_period_s=1)) is None
    replay = device({"kind": "file", "path": "/dev/null"}, expected_period_s=1.0)
    assert Gateway.silence_limit(replay) is None
