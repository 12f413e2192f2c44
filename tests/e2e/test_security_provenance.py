"""Provenance: a recording's configuration is data, error messages never echo file contents, and
the recorder stores only the configuration of the gateway it means."""

from __future__ import annotations

import json
import os
import subprocess
import threading

import zenoh

from auvgw.bus import Keys, open_session, pack_raw_attachment
from auvgw.config.bus import BusConfig
from auvgw.config.gateway import parse_gateway_config
from auvgw.decoding import make_decoders
from auvgw.recording import McapRecorder, read_info, recorded_paths
from auvgw.testing import AUVGW, endpoint, free_port, pd0_frames

SECRET = "root:$6$s3cr3tHash:19000:0:99999:7:::"


def _shadow(tmp_path):
    p = tmp_path / "shadow"
    p.write_text(SECRET + "\ndaemon:*:19000:0:99999:7:::\n")
    return p


def test_a_dbc_that_is_not_a_dbc_is_named_without_echoing_it(tmp_path):
    cfg = parse_gateway_config(
        {
            "vehicle": "v",
            "devices": {
                "mag": {
                    "format": "can",
                    "dbc": str(_shadow(tmp_path)),
                    "transport": {"kind": "can", "interface": "virtual", "channel": "x"},
                }
            },
        }
    )
    try:
        make_decoders(cfg)
    except ValueError as exc:
        text = str(exc)
    assert "devices.mag.dbc" in text and "line 1, column 6" in text
    assert "s3cr3t" not in text and "99999" not in text


def test_a_forged_recording_replays_raw_without_opening_its_paths(tmp_path, shared_data):
    """The recorded config points a table at a FIFO (opening it would block the replay forever)
    and a DBC at a 'shadow' file; replay republishes every raw frame, decodes the trusted device,
    opens neither file and says so in one line."""
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    frames = pd0_frames(shared_data, 3)
    cfg = parse_gateway_config(
        {
            "vehicle": "v",
            "devices": {  # one port each (never opened: a recording only names them)
                "dvl": {"format": "pd0", "transport": {"kind": "serial", "url": "/dev/rec-dvl"}},
                "ins": {"format": "hn100", "table": str(fifo),
                        "transport": {"kind": "serial", "url": "/dev/rec-ins"}},
                "mag": {
                    "format": "can",
                    "dbc": str(_shadow(tmp_path)),
                    "transport": {"kind": "can", "interface": "virtual", "channel": "x"},
                },
            },
        }
    )
    assert recorded_paths(cfg) == {"ins.table": str(fifo), "mag.dbc": str(tmp_path / "shadow")}
    mcap = tmp_path / "forged.mcap"
    rec = McapRecorder(mcap, "v")
    rec.set_gateway_config(cfg.model_dump_json())
    for i, f in enumerate(frames):
        for dev in ("dvl", "ins", "mag"):
            rec.add(f"auv/v/raw/{dev}", f, pack_raw_attachment(1000 + i, i + 1, 0))
    rec.close()
    r = subprocess.run(
        [AUVGW, "replay", str(mcap), "--speed", "0", "--listen", endpoint(free_port())],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "not opened" in ln]
    assert len(lines) == 1, r.stderr
    assert (
        "ins.table=" in lines[0] and "mag.dbc=" in lines[0] and "--trust-recorded-paths" in lines[0]
    )
    assert "s3cr3t" not in r.stderr + r.stdout
    summary = r.stderr.strip().splitlines()[-1]
    for dev in ("dvl", "ins", "mag"):
        assert f"auv/v/raw/{dev}: 3" in summary
    assert "auv/v/sensor/dvl/ensemble: 3" in summary and "sensor/ins" not in summary


def _fake_gateway(session: zenoh.Session, keys: Keys, text: bytes, stop: threading.Event):
    decls = [
        session.liveliness().declare_token(keys.alive("gateway")),
        session.declare_queryable(keys.config("gateway"), lambda q: q.reply(q.key_expr, text)),
    ]
    pub = session.declare_publisher(keys.status("gateway"))
    while not stop.wait(0.1):
        pub.put(b"{}")
    for d in (*decls, pub):
        d.undeclare()


def _record(tmp_path, ep: str, name: str, *extra: str) -> tuple[str | None, str]:
    out = tmp_path / f"{name}.mcap"
    r = subprocess.run(
        [
            AUVGW,
            "record",
            "--vehicle",
            "v",
            "-o",
            str(out),
            "--duration",
            "3",
            "--mode",
            "client",
            "--connect",
            ep,
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    return read_info(out).config_json, r.stderr


def test_the_recorder_stores_only_its_gateways_configuration(tmp_path):
    keys = Keys("v")
    real = parse_gateway_config(
        {
            "vehicle": "v",
            "devices": {
                "dvl": {"format": "pd0", "transport": {"kind": "serial", "url": "/dev/null"}}
            },
        }
    )
    real_json = real.model_dump_json().encode()
    forged = json.dumps({**json.loads(real_json), "vehicle": "forged"}).encode()
    ep = endpoint(free_port())
    stop = threading.Event()
    with (
        open_session(BusConfig(mode="router", listen=[ep])) as _router,
        open_session(BusConfig(mode="client", connect=[ep])) as gw,
        open_session(BusConfig(mode="client", connect=[ep])) as evil,
    ):
        threads = [
            threading.Thread(target=_fake_gateway, args=(gw, keys, real_json, stop)),
            threading.Thread(target=_fake_gateway, args=(evil, keys, forged, stop)),
        ]
        for t in threads:
            t.start()
        try:
            pinned, err = _record(tmp_path, ep, "pinned", "--gateway-zid", str(gw.zid()))
            unpinned, err2 = _record(tmp_path, ep, "unpinned")
        finally:
            stop.set()
            for t in threads:
                t.join()
    assert pinned is not None and json.loads(pinned)["vehicle"] == "v", err
    assert f"Zenoh id {evil.zid()} ignored" in err
    assert unpinned is None
    assert "different configurations" in err2 and "--gateway-zid" in err2
