"""``auvgw export --ros2``: a recording in the earlier auvgw layout (no profile, raw channels
``auvgw.raw.v1``, JSON truth) becomes a ROS 2 MCAP that rosbags reads and replay decodes alike."""

from __future__ import annotations

import json

import numpy as np
from mcap.writer import Writer
from rosbags.highlevel import AnyReader

from auvgw.bus import pack_raw_attachment
from auvgw.cli import main
from auvgw.drivers.spec import to_jsonable
from auvgw.recording import (
    GATEWAY_METADATA,
    RAW_ENCODING,
    iter_recording,
    pack_raw_record,
    read_info,
)
from auvgw.testing import gateway_config_json, local_decoded, pd0_frames


def _old_recording(path, frames):
    """What auvgw record wrote before the ROS 2 profile (the layout docs/gateway.md described)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="auvgw (schema 1)")
        raw = w.register_channel("auv/v1/raw/dvl", RAW_ENCODING, schema_id=0, metadata={
            "key": "auv/v1/raw/dvl", "zenoh_encoding": "application/octet-stream"})  # fmt: skip
        truth = w.register_channel("auv/v1/truth/pose", "json", schema_id=0, metadata={
            "key": "auv/v1/truth/pose", "zenoh_encoding": "application/json"})  # fmt: skip
        config = gateway_config_json("v1", "/dev/x")
        w.add_metadata(GATEWAY_METADATA, {"vehicle": "v1", "schema_version": "1", "config": config})
        for i, fr in enumerate(frames):
            att = pack_raw_attachment(1_000 + i, i + 1, 600 * i)
            w.add_message(raw, log_time=1_000 + i, data=pack_raw_record(att, fr),
                          publish_time=1_000 + i, sequence=i + 1)  # fmt: skip
        w.add_message(truth, log_time=5, data=b'{"t": 0.5, "x": 1.0}', publish_time=5)
        w.finish()


def test_export_converts_an_old_recording(tmp_path, shared_data, capsys):
    frames = pd0_frames(shared_data, 8)
    old = tmp_path / "old.mcap"
    _old_recording(old, frames)
    assert main(["export", "--ros2", str(old)]) == 0
    new = tmp_path / "old.ros2.mcap"
    assert "wrote" in capsys.readouterr().out
    assert main(["export", "--ros2", str(old)]) == 2  # never overwrites
    assert "exists" in capsys.readouterr().err

    with AnyReader([new]) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        msgs = [(c.topic, r.deserialize(raw, c.msgtype)) for c, _t, raw in r.messages()]
    assert types == {
        "/v1/raw/dvl": "auvgw_msgs/msg/RawFrame",
        "/v1/truth/pose": "auvgw_msgs/msg/Decoded",
        "/v1/sensor/dvl/twist": "geometry_msgs/msg/TwistWithCovarianceStamped",
        "/v1/sensor/dvl/altitude": "sensor_msgs/msg/Range",
    }
    raws = [m for t, m in msgs if t == "/v1/raw/dvl"]
    assert [bytes(m.data) for m in raws] == frames
    assert [(m.seq, m.stream_offset, m.wire_format) for m in raws] == [
        (i + 1, 600 * i, "pd0") for i in range(len(frames))
    ]
    twists = [m for t, m in msgs if t == "/v1/sensor/dvl/twist"]
    assert [m.header.stamp.nanosec for m in twists] == [1_000 + i for i in range(len(frames))]
    from auvgw.drivers.formats import get_format
    from auvgw.fusion.adapters import dvl_from_pd0

    pd0 = get_format("pd0")
    want = [dvl_from_pd0(m, t=0.0) for f in frames for m in pd0.decode(f)]
    got = [(t.twist.twist.linear.x, t.twist.twist.linear.y, t.twist.twist.linear.z) for t in twists]
    np.testing.assert_array_equal(np.array(got), np.array([w.velocity for w in want]))
    assert [t.twist.covariance[0] == -1 for t in twists] == [not w.bottom_lock for w in want]
    (truth,) = [m for t, m in msgs if t == "/v1/truth/pose"]
    assert json.loads(truth.json) == {"t": 0.5, "x": 1.0}

    # the converted file replays as the old one did: same frames, times, decoded messages
    info = read_info(new)
    assert info.config is not None and info.vehicle == "v1"
    a, b = list(iter_recording(old, truth=True)), list(iter_recording(new, truth=True))
    assert [(x.key, x.t_recv_ns, x.raw) for x in a] == [(x.key, x.t_recv_ns, x.raw) for x in b]
    decoded = [json.loads(json.dumps(to_jsonable(x.messages[0]))) for x in b if "/raw/" in x.key]
    assert decoded == local_decoded(frames)
