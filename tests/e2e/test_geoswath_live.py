"""End-to-end: emulated GeoSwath pings through ``auvgw run`` (another process) over its existing
transports, UDP datagrams and a TCP broadcast stream (``socket://``), read back from Zenoh in
this process: raw pings and decoded pings, compared with the local decoding of the same bytes; a
ping cut short in the TCP stream costs itself only."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from auvgw.config.bus import BusConfig
from auvgw.drivers.geoswath import GeoSwathPing, default_codec
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import endpoint, free_port, wait_until, write_gateway_toml
from auvgw.testing.geoswath import survey_context


def test_udp_and_tcp_pings_are_published_raw_and_decoded(procs, tmp_path: Path) -> None:
    em = survey_context(tmp_path, {"model_khz": 500})
    try:
        pings = [d for k in range(5) for d in em.prepare(60.0 + k / em.rate_hz)]
    finally:
        em.close()
    codec = default_codec()
    hsize = codec.layout.ping_header.itemsize
    tcp_sent = [pings[0], pings[1], pings[2][: hsize + 300], pings[3], pings[4]]
    tcp_want = [pings[0], pings[1], pings[3], pings[4]]

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(30.0)
    udp_port = free_port()
    ep = endpoint(free_port())
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "gs1",
        {"listen": [ep]},
        {
            "gsu": {"format": "geoswath",
                    "transport": {"kind": "udp", "host": "127.0.0.1", "port": udp_port}},
            "gst": {"format": "geoswath",
                    "transport": {"kind": "serial",
                                  "url": f"socket://127.0.0.1:{server.getsockname()[1]}"}},
        },
    )  # fmt: skip
    procs.gateway(cfg)
    with GatewaySubscriber("gs1", BusConfig(connect=[ep])) as me, server:
        decoded = me.stream(kind="geoswathping")
        raw = me.stream(raw=True)
        assert me.wait_ready(30.0)
        conn, _ = server.accept()
        with conn, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            for dev in ("gsu", "gst"):
                wait_until(lambda d=dev: (me.status(d) or {}).get("connected"), what=dev)
            stream = b"".join(tcp_sent)
            for i in range(0, len(stream), 1000):  # any chunking: a ping spans several reads
                conn.sendall(stream[i : i + 1000])
            for p in pings:
                udp.sendto(p, ("127.0.0.1", udp_port))
            got: dict[str, list] = {"gsu": [], "gst": []}
            frames: dict[str, list] = {"gsu": [], "gst": []}

            def drained() -> bool:
                while (env := decoded.get(0.05)) is not None:
                    got[env.device].append(env)
                while (fr := raw.get(0.0)) is not None:
                    frames[fr.key.rsplit("/", 1)[-1]].append(fr)
                return len(got["gsu"]) >= 5 and len(got["gst"]) >= 4

            try:
                wait_until(drained, timeout=30.0, what="9 decoded pings")
            except AssertionError as exc:  # which were lost: on the bus, or before the gateway
                counts = {d: (len(got[d]), len(frames[d]), (me.status(d) or {}).get("messages"))
                          for d in got}  # fmt: skip
                raise AssertionError(f"{exc}; (decoded, raw, gateway's count): {counts}") from None
            st = wait_until(lambda: (s := me.status("gst")) and s["bad_frames"] and s, what="st")
    for dev, want in (("gsu", pings), ("gst", tcp_want)):
        assert [fr.data for fr in frames[dev]] == want, dev  # raw first, byte for byte
        msgs = [env.message for env in got[dev]]
        assert all(isinstance(m, GeoSwathPing) for m in msgs), dev
        assert msgs == [codec.decode_ping(p) for p in want], dev
        assert {env.key for env in got[dev]} == {f"auv/gs1/sensor/{dev}/geoswathping"}
    assert st["bad_frames"] == 1 and st["bad_frame_reasons"] == {"inner_frame": 1}
    assert st["skipped_bytes"] == hsize + 300 and st["messages"] == {"GeoSwathPing": 4}


def test_demo_survey_with_the_geoswath_feeds_the_bathymetric_stage(tmp_path: Path) -> None:
    """``auvgw demo --scenario survey --multibeam geoswath`` (in-process stages): every ping the
    gateway decoded went through the swath stage, every swath reached the bathymetric stage,
    and its seabed map matches the true terrain."""
    import json
    import subprocess
    import sys

    out = tmp_path / "demo"
    res = subprocess.run(
        [sys.executable, "-m", "auvgw", "demo", "--scenario", "survey", "--multibeam",
         "geoswath", "--duration", "24", "--speed", "4", "--no-viz", "--out", str(out)],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert "multibeam" not in summary["devices"]
    gs = summary["devices"]["geoswath"]
    assert gs["bad_frames"] == 0 and gs["decode_errors"] == 0
    pings = gs["messages"]["GeoSwathPing"]
    assert pings >= 8  # 4 Hz over the part of the run the gateway saw (late on a loaded host)
    swath, slam = summary["swath"]["stage"], summary["slam"]["stage"]
    assert swath["received"] == pings and swath["bad_payloads"] == 0
    assert swath["swaths"] == pytest.approx(pings / 4, abs=2)  # 1 Hz swaths
    assert slam["swaths"] == swath["swaths"] and slam["bad_swaths"] == 0 and slam["pings"] >= 1
    m = summary["bathymetric_map"]
    assert m["cells"] > 100 and m["median_abs_error_m"] < 0.3 and m["share_under_2m"] > 0.99
