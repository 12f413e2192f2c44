"""The GeoSwath's swaths in a recording: the swath stage's XYZ 88 envelopes written by the MCAP
recorder become sensor_msgs/PointCloud2 (decoded back with mcap-ros2-support) in the frame
``<device>_swath``, which /tf_static places at base_link, reachable from map through /tf."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from auvgw.config.gateway import parse_gateway_config
from auvgw.drivers.geoswath import default_codec
from auvgw.envelope import decode_envelope, encode_envelope
from auvgw.fusion.odometry import Odometry
from auvgw.recording import McapRecorder
from auvgw.stages.swath import SwathStage, SwathStageConfig
from auvgw.subscribe import envelope_message
from auvgw.testing.geoswath import survey_context


def _odometry(t: float) -> Odometry:
    return Odometry(
        t=t, x=10.0, y=20.0, z=25.0, roll=0.0, pitch=0.0, heading=0.3,
        velocity_ned=(0.0, 0.0, 0.0), velocity_body=(0.0, 0.0, 0.0),
        angular_rate=(0.0, 0.0, 0.0), covariance=np.eye(8), bottom_lock=True, coasting=False,
        dvl_age_s=0.0, depth_age_s=0.0, ins_gap=False, increment=None,
    )  # fmt: skip


def test_swaths_are_point_clouds_in_a_placed_frame(tmp_path: Path) -> None:
    em = survey_context(tmp_path, {"model_khz": 500})
    codec = default_codec()
    path = tmp_path / "gs.mcap"
    rec = McapRecorder(path, "auv1")
    gs = {"format": "geoswath", "transport": {"kind": "udp", "host": "127.0.0.1", "port": 9}}
    rec.set_gateway_config(
        parse_gateway_config({"vehicle": "auv1", "devices": {"gs": gs}}).model_dump_json()
    )
    sent: list[tuple[str, bytes]] = []

    def publish(key: str, payload: bytes, t_ns: int) -> None:
        sent.append((key, payload))
        rec.add(key, payload, None)
        o = _odometry(t_ns / 1e9)  # the vehicle's pose then (odom -> base_link) and a SLAM
        odo, _ = encode_envelope(o, "fusion", t_ns, len(sent))  # pose (map -> odom)
        rec.add("auv/auv1/nav/odometry", odo, None)
        pose = {"t": t_ns / 1e9, "x": 11.0, "y": 19.0, "heading": 0.32}
        rec.add("auv/auv1/slam/bathymetric/pose", json.dumps(pose).encode(), None)

    stage = SwathStage(
        SwathStageConfig(device="gs", processing={"frequency_hz": em.frequency}),
        on_publish=publish,
    )
    try:
        for k in range(14):
            for d in em.prepare(50.0 + k / em.rate_hz):
                ping = codec.decode_ping(d)
                stage.feed("gs", int((float(ping.header["ping_time"]) + 0.1) * 1e9), ping)
        stage.flush()
    finally:
        em.close()
        rec.close()
    assert len(sent) >= 3 and rec.skipped == 0
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        recorded = [(ch.topic, sc.name, ros) for sc, ch, _m, ros in reader.iter_decoded_messages()]
    clouds = [r for topic, _, r in recorded if topic == "/auv1/sensor/gs_swath/points"]
    assert {n for t, n, _ in recorded if t == "/auv1/sensor/gs_swath/points"} == {
        "sensor_msgs/msg/PointCloud2"
    }
    assert len(clouds) == len(sent)
    for (key, payload), cloud in zip(sent, clouds, strict=True):
        msg = envelope_message(decode_envelope(payload, key))
        assert cloud.header.frame_id == "gs_swath"
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
        assert (cloud.height, cloud.width) == (1, msg.n_beams)
        pts = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 4)
        b = msg.beams
        # FLU from the swath's forward, starboard, down: the seabed below (15 m altitude)
        # (an empty bin a NaN point, not a sounding at the reference point)
        want = np.column_stack([b.along, -b.across, -b.depth]).astype("<f4")
        want[~b.valid] = np.nan
        assert np.array_equal(pts[:, :3], want, equal_nan=True)
        ok = np.isfinite(pts[:, 2])
        assert ok.sum() > 120 and np.all((pts[ok, 2] < -5.0) & (pts[ok, 2] > -40.0))
    # every frame a header names is reachable from map through /tf and /tf_static
    pairs = {(t.header.frame_id, t.child_frame_id)
             for topic, _, r in recorded if topic in ("/tf", "/tf_static")
             for t in r.transforms}  # fmt: skip
    assert ("base_link", "gs_swath") in pairs and ("base_link", "gs") in pairs
    reach, grew = {"map"}, True
    while grew:
        new = {c for p, c in pairs if p in reach} - reach
        reach |= new
        grew = bool(new)
    used = {r.header.frame_id for _t, _n, r in recorded if hasattr(r, "header")} - {""}
    assert "gs_swath" in used and used <= reach, (used - reach, pairs)
