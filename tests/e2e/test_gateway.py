"""End-to-end: ``auvgw run`` in one process reading a pty, a typed subscriber in another, the
test writing real PD0 ensembles (RDI_withBT.000) into the pty; peer-to-peer and through an
``auvgw router`` process. Content is compared with decoding the same frames locally."""

from __future__ import annotations

import json
import signal

import pytest

from auvgw.config.bus import BusConfig
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import (
    AUVGW,
    endpoint,
    frame_counters,
    free_port,
    local_decoded,
    pd0_frames,
    read_jsonl,
    wait_until,
    write_gateway_toml,
)


@pytest.fixture
def frames(shared_data):
    return pd0_frames(shared_data, 40)


def check_stream(got: list[dict], frames: list[bytes], vehicle: str) -> None:
    """The subscriber's envelopes are exactly the local decoding of ``frames``, in order."""
    expected = local_decoded(frames)
    assert len(got) == len(expected)
    assert frame_counters([g["seq"] for g in got]) == list(range(1, len(frames) + 1))
    assert all(g["typed"] for g in got)  # rebuilt as typed pd0.Ensemble messages
    assert {g["key"] for g in got} == {f"auv/{vehicle}/sensor/dvl/ensemble"}
    assert {(g["type"], g["device"]) for g in got} == {("pd0.Ensemble", "dvl")}
    t = [g["t_recv_ns"] for g in got]
    assert t == sorted(t)
    for i, (g, e) in enumerate(zip(got, expected, strict=True)):
        assert g["msg"] == e, f"ensemble #{i} differs"


def run_stream(procs, tmp_path, dvl, frames, gw_bus, sub_args, vehicle, test_bus) -> None:
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        vehicle,
        gw_bus,
        {"dvl": {"format": "pd0", "transport": {"kind": "serial", "url": str(dvl.link)}}},
    )
    procs.gateway(cfg)
    out = tmp_path / "sub.jsonl"
    sub = procs.subscriber(
        "sub", "--vehicle", vehicle, *sub_args, "--count", str(len(frames)), "--out", str(out)
    )
    with GatewaySubscriber(vehicle, test_bus) as me:
        wait_until(lambda: (me.status("dvl") or {}).get("connected"), what="dvl connected")
        sub.wait_line("READY", 60)
        for f in frames:
            dvl.write(f)
        done = sub.wait_line("DONE", 60)
    assert done.startswith(f"DONE {len(frames)} dropped=0"), done
    check_stream(read_jsonl(out), frames, vehicle)


def test_peer_gateway_and_subscriber_processes(procs, tmp_path, dvl, frames):
    port = free_port()
    ep = endpoint(port)
    run_stream(
        procs,
        tmp_path,
        dvl,
        frames,
        {"listen": [ep]},
        ["--connect", ep],
        "peer1",
        BusConfig(connect=[ep]),
    )


def test_through_a_router_process(procs, tmp_path, dvl, frames):
    router_ep = endpoint(free_port())
    router = procs.start([AUVGW, "router", "--listen", router_ep], "router")
    router.wait_line("auvgw router", 30)
    run_stream(
        procs,
        tmp_path,
        dvl,
        frames,
        {"mode": "peer", "connect": [router_ep]},  # the gateway: a peer joined to the router
        ["--mode", "client", "--connect", router_ep],  # the subscriber: a client of the router
        "routed",
        BusConfig(mode="client", connect=[router_ep]),
    )


def test_status_liveliness_and_config(procs, tmp_path, dvl, shared_data):
    good = pd0_frames(shared_data, 12)
    bad = bytearray(good[5])
    bad[len(bad) // 2] ^= 0xFF  # checksum no longer matches: one bad frame, its bytes skipped
    garbage = b"\x00garbage\x7f\x01 between frames"
    stream = b"".join(good[:5]) + bytes(bad) + garbage + b"".join(good[5:])
    port = free_port()
    ep = endpoint(port)
    missing = tmp_path / "no-such-port"
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "stat1",
        {"listen": [ep]},
        {
            "dvl": {"format": "pd0", "transport": {"kind": "serial", "url": str(dvl.link)}},
            "dvl2": {
                "format": "pd0",
                "transport": {"kind": "serial", "url": str(missing)},
                "backoff_initial_s": 0.1,
                "backoff_max_s": 0.4,
            },
        },
    )
    gateway = procs.gateway(cfg)
    with GatewaySubscriber("stat1", BusConfig(connect=[ep])) as me:
        # open, nothing sent yet (as the all-devices bench's devices in their warm-up): stale
        waiting = wait_until(
            lambda: (s := me.status("dvl")) and s["connected"] and s, what="dvl connected"
        )
        dvl.write(stream)
        st = wait_until(
            lambda: (s := me.status("dvl")) and s["frames"] == len(good) and s, what="12 frames"
        )
        alive = wait_until(lambda: (a := me.alive()) >= {"gateway", "dvl"} and a, what="tokens")
        gw = me.status()
        my_zid = str(me.session.zid())
        conf = me.config()
        st2 = me.status("dvl2")
        # clean shutdown on SIGINT: exit 0, tokens withdrawn, session closed (no hang)
        gateway.signal(signal.SIGINT)
        assert gateway.wait(30) == 0, gateway.stderr()
        wait_until(lambda: not (me.alive() & {"gateway", "dvl"}), what="tokens withdrawn")
    assert "SIGINT received: stopping" in gateway.stderr()
    assert "gateway stopped" in gateway.stderr()

    assert st["device"] == "dvl" and st["format"] == "pd0"
    assert str(dvl.link) in st["port"]
    assert st["connected"] is True and st["ended"] is False and st["stale"] is False
    assert st["messages"] == {"pd0.Ensemble": len(good)}
    assert st["bad_frames"] >= 1 and sum(st["bad_frame_reasons"].values()) == st["bad_frames"]
    assert st["skipped_bytes"] >= len(bad) + len(garbage)
    assert st["decode_errors"] == 0
    assert st["rate_hz"] > 0 and st["rates_hz"]["pd0.Ensemble"] == st["rate_hz"]
    assert st["connects"] == 1 and st["outages"] == 0
    assert st["last_seen_ns"] >= st["connected_since_ns"] > 0
    assert st["silent_s"] >= 0
    assert waiting["stale"] is True and waiting["frames"] == 0 and waiting["silent_s"] is None
    assert waiting["last_seen_ns"] is None and waiting["rates_hz"] == {}

    assert "dvl2" not in alive  # never connected: no token
    assert st2["connected"] is False and st2["stale"] is True
    assert str(missing) in st2["last_error"] and "cannot open" in st2["last_error"]
    assert st2["next_retry_s"] is not None and 0.1 <= st2["next_retry_s"] <= 0.4
    assert st2["frames"] == 0 and st2["last_seen_ns"] is None

    assert gw["vehicle"] == "stat1" and gw["v"] == 1 and gw["uptime_s"] > 0
    assert set(gw["devices"]) == {"dvl", "dvl2"}
    assert gw["bus"]["mode"] == "peer" and my_zid in gw["bus"]["peers"]
    assert gw["devices"]["dvl"]["frames"] == len(good)

    assert conf["vehicle"] == "stat1"
    assert conf["devices"]["dvl"]["format"] == "pd0"
    assert conf["devices"]["dvl"]["transport"]["url"] == str(dvl.link)


def test_file_source_ends_the_device_cleanly(procs, tmp_path, shared_data):
    """A file replayed without loop: every frame decoded, the device reported ended (no
    reconnect), and ``--exit-when-done`` exits 0."""
    frames = pd0_frames(shared_data, 30)
    cap = tmp_path / "dvl.pd0"
    cap.write_bytes(b"".join(frames) + frames[30 - 1][:100])  # ends inside a frame
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "file1",
        {},
        {"dvl": {"format": "pd0", "transport": {"kind": "file", "path": cap.name}}},
    )
    from auvgw.config.gateway import load_gateway_config
    from auvgw.drivers.spec import to_jsonable
    from auvgw.gateway import Gateway

    got = []
    config = load_gateway_config(cfg)  # relative file path: next to the configuration file
    assert config.devices["dvl"].transport.path == cap
    with Gateway(config, on_message=lambda dev, t, m: got.append((dev, to_jsonable(m)))) as gw:
        assert gw.finished.wait(30)
        st = gw.device_status("dvl")
    assert [json.loads(json.dumps(m)) for _, m in got] == local_decoded(frames)
    assert st["ended"] is True and st["connected"] is False
    assert st["connects"] == 1 and st["frames"] == 30
    assert st["bad_frames"] == 1  # the truncated tail, judged at the end of the stream
    assert "end of file" in st["last_error"]

    proc = procs.gateway(cfg, "gw-exit", "--exit-when-done", "--viz-rrd", str(tmp_path / "x.rrd"))
    assert proc.wait(60) == 0, proc.stderr()
    assert "dvl: end of stream" in proc.stderr()
