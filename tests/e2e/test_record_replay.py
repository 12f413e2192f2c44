"""Record and replay: ``auvgw record`` writes the live raw traffic to MCAP; ``auvgw replay``
republishes it (raw + decoded); the replayed decoded stream equals the live one message by
message. Plus the MCAP layout itself (attachments, metadata, cut-short files) and the offline
iterator."""

from __future__ import annotations

import json
import signal
import time

import pytest

from auvgw.bus import RAW_ATTACHMENT, pack_raw_attachment, unpack_raw_attachment
from auvgw.config.bus import BusConfig
from auvgw.drivers.spec import to_jsonable
from auvgw.recording import (
    GATEWAY_METADATA,
    RAW_ENCODING,
    McapRecorder,
    RecordingError,
    iter_recording,
    iter_samples,
    read_info,
)
from auvgw.signing import check_signature, load_public_key, make_signing_key
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import (
    AUVGW,
    PtyDevice,
    endpoint,
    frame_counters,
    free_port,
    gateway_config_json,
    local_decoded,
    pd0_frames,
    read_jsonl,
    wait_until,
    write_gateway_toml,
)


def test_live_record_then_replay_gives_the_same_decoded_stream(procs, tmp_path, shared_data):
    frames = pd0_frames(shared_data, 50)
    corrupt = bytearray(frames[20])
    corrupt[40] ^= 0x55  # a bad checksum in the middle: never published, so never recorded
    wire = b"".join(frames[:20]) + bytes(corrupt) + b"".join(frames[20:])
    dvl = PtyDevice(tmp_path / "dvl")
    ep = endpoint(free_port())
    cfg = write_gateway_toml(
        tmp_path / "gw.toml",
        "rec1",
        {"listen": [ep]},
        {"dvl": {"format": "pd0", "transport": {"kind": "serial", "url": str(dvl.link)}}},
    )
    mcap = tmp_path / "rec1.mcap"
    sign_key, sign_pub = make_signing_key(tmp_path / "vehicle")  # the recorder signs at the end
    try:
        procs.gateway(cfg)
        live_out = tmp_path / "live.jsonl"
        live = procs.subscriber(
            "live",
            "--vehicle",
            "rec1",
            "--connect",
            ep,
            "--count",
            str(len(frames)),
            "--out",
            str(live_out),
        )
        recorder = procs.start(
            [
                AUVGW,
                "record",
                "--vehicle",
                "rec1",
                "--out",
                str(mcap),
                "--connect",
                ep,
                "--wait-gateway",
                "120",
                "--sign-key",
                str(sign_key),
            ],
            "recorder",
        )
        with GatewaySubscriber("rec1", BusConfig(connect=[ep])) as me:
            wait_until(lambda: (me.status("dvl") or {}).get("connected"), what="dvl connected")
            live.wait_line("READY", 60)
            recorder.wait_line("recording", 60)
            dvl.write(wire)
            assert live.wait_line("DONE", 60).startswith(f"DONE {len(frames)} dropped=0")
            wait_until(lambda: me.status("dvl")["frames"] == len(frames), what="frames counted")
            assert me.wait_ready(60)  # one more status round after the last frame
        recorder.signal(signal.SIGINT)
        assert recorder.wait(60) == 0, recorder.stderr()
    finally:
        dvl.close()
    assert f"/rec1/raw/dvl: {len(frames)}," in recorder.stderr()
    assert f"{mcap}: signed, {mcap}.sig" in recorder.stderr()
    signed = check_signature(mcap, (load_public_key(sign_pub),))
    assert signed.status == "valid" and signed.signer == "vehicle", signed.line

    # the file: the raw channel, the gateway configuration, every frame with its attachment
    info = read_info(mcap)
    assert info.vehicle == "rec1"
    assert info.config is not None and info.config.devices["dvl"].format == "pd0"
    assert info.counts["/rec1/raw/dvl"] == len(frames)
    assert info.counts["/rec1/sensor/dvl/twist"] == len(frames)
    samples = [s for s in iter_samples(mcap) if s.key == "auv/rec1/raw/dvl"]
    assert [s.payload for s in samples] == frames
    assert {s.message_encoding for s in samples} == {RAW_ENCODING}
    atts = [unpack_raw_attachment(s.attachment) for s in samples]
    assert frame_counters([a[1] for a in atts]) == list(range(1, len(frames) + 1))
    assert [s.log_time_ns for s in samples] == [a[0] for a in atts]  # log time = receive time
    assert atts[0][2] == 0 and atts[21][2] == sum(map(len, frames[:21])) + len(corrupt)

    live_got = read_jsonl(live_out)
    # offline: the same decode path gives the live messages
    offline = list(iter_recording(mcap))
    assert [r.raw for r in offline] == frames
    assert [r.t_recv_ns for r in offline] == [g["t_recv_ns"] for g in live_got]
    assert [json.loads(json.dumps(to_jsonable(r.messages[0]))) for r in offline] == [
        g["msg"] for g in live_got
    ]

    # replay on another bus, as fast as possible, once both listeners are declared
    ep2 = endpoint(free_port())
    replay_out = tmp_path / "replay.jsonl"
    replayed = procs.subscriber(
        "replayed",
        "--vehicle",
        "rec1",
        "--connect",
        ep2,
        "--count",
        str(len(frames)),
        "--out",
        str(replay_out),
        "--announce",
        "replaysub",
    )
    with GatewaySubscriber("rec1", BusConfig(connect=[ep2])) as me:
        raw = me.stream(device="dvl", raw=True)
        me.announce("rawsub")
        rp = procs.start(
            [
                AUVGW,
                "replay",
                str(mcap),
                "--speed",
                "0",
                "--listen",
                ep2,
                "--wait-for",
                "replaysub",
                "--wait-for",
                "rawsub",
            ],
            "replay",
        )
        replayed.wait_line("READY", 60)
        rp.wait_line("replaying", 60)
        assert replayed.wait_line("DONE", 60).startswith(f"DONE {len(frames)} dropped=0")
        raw_frames = [raw.get(30) for _ in frames]
        assert rp.wait(60) == 0, rp.stderr()
    assert f"{mcap}: signed by vehicle, valid" in rp.stderr()  # checked before replaying
    assert [f.data for f in raw_frames] == frames
    assert [(f.t_recv_ns, f.seq, f.offset) for f in raw_frames] == atts  # attachments kept
    replay_got = read_jsonl(replay_out)
    fields = ("key", "type", "device", "t_recv_ns", "seq", "typed", "msg")
    assert len(replay_got) == len(live_got)
    for i, (a, b) in enumerate(zip(live_got, replay_got, strict=True)):
        assert {k: a[k] for k in fields} == {k: b[k] for k in fields}, f"message #{i}"
    assert [g["msg"] for g in replay_got] == local_decoded(frames)


def test_replay_as_another_vehicle_paced(procs, tmp_path, shared_data):
    """--vehicle renames the keys; --speed paces by the recorded receive times; truth samples
    are republished as recorded; the recorded config is served for a recording of a replay."""
    frames = pd0_frames(shared_data, 6)
    mcap = tmp_path / "small.mcap"
    rec = McapRecorder(mcap, "orig")
    rec.set_gateway_config(gateway_config_json("orig", "/dev/null"))
    t0 = time.time_ns() - 1_000_000_000  # the truth sample gets the recorder's clock: now
    for i, f in enumerate(frames):
        rec.add("auv/orig/raw/dvl", f, pack_raw_attachment(t0 + i * 20_000_000, i + 1, i * 600))
    rec.add("auv/orig/truth/pose", b'{"x": 1.5}', None, "application/json")
    rec.close()

    ep = endpoint(free_port())
    with GatewaySubscriber("other", BusConfig(connect=[ep])) as me:
        decoded = me.stream(device="dvl")
        truth = me.session.declare_subscriber("auv/other/truth/**")
        me.announce("t")
        rp = procs.start(
            [
                AUVGW,
                "replay",
                str(mcap),
                "--speed",
                "4",
                "--vehicle",
                "other",
                "--listen",
                ep,
                "--wait-for",
                "t",
            ],
            "replay",
        )
        got = [decoded.get(60) for _ in frames]
        sample = wait_until(truth.try_recv, what="truth sample")
        assert bytes(sample.payload.to_bytes()) == b'{"x": 1.5}'
        assert str(sample.encoding).startswith("application/json")
        assert rp.wait(60) == 0, rp.stderr()
        truth.undeclare()
    assert {g.key for g in got} == {"auv/other/sensor/dvl/ensemble"}
    assert [g.t_recv_ns for g in got] == [t0 + i * 20_000_000 for i in range(len(frames))]
    assert [json.loads(json.dumps(to_jsonable(g.message))) for g in got] == local_decoded(frames)


def test_recorder_file_layout_and_offline_iterator(tmp_path, shared_data):
    frames = pd0_frames(shared_data, 5)
    path = tmp_path / "x.mcap"
    rec = McapRecorder(path, "v1")
    for i, f in enumerate(frames[:2]):
        rec.add("auv/v1/raw/dvl", f, pack_raw_attachment(100 + i, i + 1, 7 * i))
    rec.set_gateway_config(gateway_config_json("v1", "/dev/x"))
    for i, f in enumerate(frames[2:], start=2):
        rec.add("auv/v1/raw/dvl", f, pack_raw_attachment(100 + i, i + 1, 7 * i))
    rec.add("auv/v1/truth/pose", b'{"n": 1}', None, "application/json")
    rec.close()

    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        metas = {m.name: m.metadata for m in reader.iter_metadata()}
    assert channels["/v1/raw/dvl"].message_encoding == "cdr"
    assert channels["/v1/raw/dvl"].metadata["key"] == "auv/v1/raw/dvl"
    assert channels["/v1/truth/pose"].message_encoding == "cdr"
    assert json.loads(metas[GATEWAY_METADATA]["config"])["devices"]["dvl"]["format"] == "pd0"
    assert metas["auvgw.recording"]["vehicle"] == "v1"

    samples = list(iter_samples(path))
    assert [s.attachment for s in samples[:5]] == [
        pack_raw_attachment(100 + i, i + 1, 7 * i) for i in range(5)
    ]
    assert len(samples[0].attachment) == RAW_ATTACHMENT.size
    items = list(iter_recording(path, truth=True))
    assert [i.t_recv_ns for i in items[:5]] == [100, 101, 102, 103, 104]
    assert [json.loads(json.dumps(to_jsonable(i.messages[0]))) for i in items[:5]] == local_decoded(
        frames
    )
    assert items[5] == ("auv/v1/truth/pose", items[5].t_recv_ns, b'{"n": 1}', ({"n": 1},))


def test_a_recording_cut_short_is_read_up_to_the_cut(tmp_path, shared_data):
    frames = pd0_frames(shared_data, 40)
    path = tmp_path / "cut.mcap"
    rec = McapRecorder(path, "v1", chunk_size=4096)  # small chunks: most of it reaches the disk
    rec.set_gateway_config(gateway_config_json("v1", "/dev/x"))
    for i, f in enumerate(frames):
        rec.add("auv/v1/raw/dvl", f, pack_raw_attachment(i, i + 1, 0))
    rec.close()
    whole = path.read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])  # what a killed recorder leaves behind
    info = read_info(cut)
    assert info.config is not None and info.vehicle == "v1"
    got = [r.raw for r in iter_recording(cut)]
    assert 0 < len(got) < len(frames)
    assert got == frames[: len(got)]


def test_unusable_recordings_are_named_errors(tmp_path, capsys):
    from auvgw.cli import main

    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_bytes(b"hello, not an mcap file")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        read_info(not_mcap)
    no_config = tmp_path / "noconf.mcap"
    rec = McapRecorder(no_config, "v1")
    rec.add("auv/v1/raw/dvl", b"\x7f\x7f", pack_raw_attachment(1, 1, 0))
    rec.close()
    with pytest.raises(RecordingError, match="no gateway configuration recorded"):
        list(iter_recording(no_config))
    for path, text in [
        (not_mcap, "not an MCAP file"),
        (no_config, "no gateway configuration recorded"),
        (tmp_path / "absent.mcap", "no such recording"),
    ]:
        assert main(["replay", str(path)]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and text in err
    assert main(["replay", str(no_config), "--speed", "-1"]) == 2
    assert "--speed must be >= 0" in capsys.readouterr().err
    assert main(["record", "--out", str(tmp_path / "no" / "dir.mcap")]) == 2
    assert "does not exist" in capsys.readouterr().err
