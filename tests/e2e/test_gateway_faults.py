"""Faults survived by ``auvgw run`` (separate processes): a device unplugged and replugged behind
the same symlink, and a subscriber that stops reading."""

from __future__ import annotations

from auvgw.config.bus import BusConfig
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import (
    PYTHON,
    endpoint,
    frame_counters,
    free_port,
    local_decoded,
    pd0_frames,
    read_jsonl,
    wait_until,
    write_gateway_toml,
)


def test_unplug_and_replug_reported_and_resumed_without_loss(procs, tmp_path, dvl, shared_data):
    frames = pd0_frames(shared_data, 60)
    before, after = frames[:25], frames[25:]
    # a second device keeps flowing while the first is out: a paced, looping capture file
    cap = tmp_path / "other.pd0"
    cap.write_bytes(b"".join(frames[:10]))
    ep = endpoint(free_port())
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "fault1",
        {"listen": [ep]},
        {
            "dvl": {
                "format": "pd0",
                "transport": {"kind": "serial", "url": str(dvl.link)},
                "backoff_initial_s": 0.05,
                "backoff_max_s": 0.3,
            },
            "other": {
                "format": "pd0",
                "transport": {"kind": "file", "path": str(cap), "loop": True, "byte_rate": 20000},
            },
        },
    )
    gw = procs.gateway(cfg)
    out = tmp_path / "sub.jsonl"
    sub = procs.subscriber(
        "sub",
        "--vehicle",
        "fault1",
        "--connect",
        ep,
        "--device",
        "dvl",
        "--count",
        str(len(frames)),
        "--out",
        str(out),
    )
    with GatewaySubscriber("fault1", BusConfig(connect=[ep])) as me:
        wait_until(lambda: (me.status("dvl") or {}).get("connected"), what="dvl connected")
        sub.wait_line("READY", 60)
        for f in before:
            dvl.write(f)
        wait_until(lambda: (me.status("dvl") or {}).get("frames") == len(before), what="frames")

        dvl.unplug()
        down = wait_until(
            lambda: (s := me.status("dvl")) and not s["connected"] and s, what="outage reported"
        )
        wait_until(lambda: "dvl" not in me.alive(), what="dvl token withdrawn")
        assert "gateway" in me.alive()
        assert down["outages"] == 1 and down["stale"] is True
        assert "disconnected" in down["last_error"] or "cannot open" in down["last_error"]
        # the other device keeps flowing during the outage
        n_other = me.status("other")["frames"]
        wait_until(lambda: me.status("other")["frames"] > n_other + 3, what="other device flowing")
        assert me.status("other")["connected"] is True

        dvl.plug()
        up = wait_until(lambda: (s := me.status("dvl")) and s["connected"] and s, what="replug")
        wait_until(lambda: "dvl" in me.alive(), what="dvl token back")
        assert up["connects"] == 2 and up["outages"] == 1
        for f in after:
            dvl.write(f)
        done = sub.wait_line("DONE", 60)
        final = wait_until(lambda: (s := me.status("dvl"))["frames"] == len(frames) and s, what="n")

    assert done.startswith(f"DONE {len(frames)} dropped=0"), done
    got = read_jsonl(out)
    # nothing written after the replug is lost: the sequence runs on without a gap
    assert frame_counters([g["seq"] for g in got]) == list(range(1, len(frames) + 1))
    assert [g["msg"] for g in got] == local_decoded(frames)
    assert final["bad_frames"] == 0
    assert "dvl: disconnected" in gw.stderr() and gw.stderr().count("dvl: connected on") == 2


STALLED = r"""
import sys, time
from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
s = open_session(BusConfig(connect=[sys.argv[1]]))
# a consumer that stops reading: its callback never returns, so its session stops draining
sub = s.declare_subscriber(sys.argv[2], lambda sample: time.sleep(3600))
while not any(r.ok for r in s.liveliness().get(sys.argv[3], timeout=1.0)):
    pass
print("READY", s.zid(), flush=True)
time.sleep(3600)
"""


def test_a_stalled_subscriber_does_not_stall_the_gateway(procs, tmp_path, dvl, shared_data):
    """Three passes over the real file (5163 ensembles, about 22 MB of raw + JSON): more than
    the loopback socket buffers and Zenoh queues toward the stalled process can hold, so the
    gateway must shed that link's samples (DROP) while the other subscriber gets everything, and
    the stalled process keeps its session (it is slow, not gone)."""
    frames = pd0_frames(shared_data)
    stream = frames * 3
    ep = endpoint(free_port())
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "stall1",
        {"listen": [ep]},
        {"dvl": {"format": "pd0", "transport": {"kind": "serial", "url": str(dvl.link)}}},
    )
    procs.gateway(cfg)
    stalled = procs.start(
        [PYTHON, "-c", STALLED, ep, "auv/stall1/**", "auv/stall1/alive/gateway"], "stalled"
    )
    out = tmp_path / "sub.jsonl"
    sub = procs.subscriber(
        "sub",
        "--vehicle",
        "stall1",
        "--connect",
        ep,
        "--count",
        str(len(stream)),
        "--out",
        str(out),
        "--raw",
    )
    with GatewaySubscriber("stall1", BusConfig(connect=[ep])) as me:
        wait_until(lambda: (me.status("dvl") or {}).get("connected"), what="dvl connected")
        stalled_zid = stalled.wait_line("READY", 60).split()[1]
        sub.wait_line("READY", 60)
        for i in range(0, len(stream), 50):
            dvl.write(b"".join(stream[i : i + 50]))
        done = sub.wait_line("DONE", 120)
        # framing counts are updated right after a chunk's frames are published
        st = wait_until(
            lambda: (s := me.status("dvl"))["frames"] == len(stream) and s, what="count"
        )
        gw = me.status()
    assert stalled.p.poll() is None  # still there, still not reading
    assert stalled_zid in gw["bus"]["peers"]  # and still connected: shed samples, not the peer
    assert done.startswith(f"DONE {len(stream)} dropped=0"), done
    got = read_jsonl(out)
    assert frame_counters([g["seq"] for g in got]) == list(range(1, len(stream) + 1))
    assert [bytes.fromhex(g["data"]) for g in got] == stream
    assert st["connected"] is True
