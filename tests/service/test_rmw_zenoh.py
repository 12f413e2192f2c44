"""rmw_zenoh's names, hashes, tokens and attachments (auvgw.rmw_zenoh), checked against the
examples of rmw_zenoh's docs/design.md and against ROS 2's published type hashes."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from auvgw import ros2
from auvgw.rmw_zenoh import (
    DEFAULT_QOS,
    SENSOR_QOS,
    STATIC_QOS,
    Qos,
    data_key,
    dds_type_name,
    entity_gid,
    mangle,
    node_token,
    pack_attachment,
    parse_token,
    ros_type_name,
    topic_token,
    type_hash,
    unmangle,
    unpack_attachment,
)

#: published in rmw_zenoh's docs/design.md (std_msgs/msg/String, the `chatter` example)
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_rihs01_of_string_is_the_published_hash():
    assert type_hash("std_msgs/msg/String") == STRING_HASH


def test_the_hash_comes_from_the_type_description():
    # every standard type the bridge publishes has a hash, all different
    wanted = ["sensor_msgs/msg/Imu", "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage",
              "diagnostic_msgs/msg/DiagnosticArray", "sensor_msgs/msg/PointCloud2",
              "sensor_msgs/msg/MagneticField", ros2.RAW_FRAME_TYPE, ros2.DECODED_TYPE]
    hashes = {t: type_hash(t) for t in wanted}
    assert all(h.startswith("RIHS01_") and len(h) == 7 + 64 for h in hashes.values())
    assert len(set(hashes.values())) == len(wanted)
    # one field more in a definition gives another hash (computed, not looked up by name)
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    def hash_of(definition: str) -> str:
        ts = get_typestore(Stores.ROS2_JAZZY)
        ts.register(get_types_from_msg(definition, "test_msgs/msg/Probe"))
        return ts.hash_rihs01("test_msgs/msg/Probe")

    assert hash_of("string data") == hash_of("string data")
    assert hash_of("string data\nuint8 extra") != hash_of("string data")


def test_data_keys_are_the_design_documents_examples():
    assert (data_key(0, "/chatter", "std_msgs/msg/String")
            == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    assert (data_key(0, "/robot1/chatter", "std_msgs/msg/String")
            == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    with pytest.raises(ValueError, match="fully qualified"):
        data_key(0, "chatter", "std_msgs/msg/String")
    assert ros_type_name(dds_type_name("sensor_msgs/msg/Imu")) == "sensor_msgs/msg/Imu"
    with pytest.raises(ValueError):
        ros_type_name("sensor_msgs::msg::Imu")


def test_tokens_parse_the_design_documents_examples():
    pub = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
           f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    e = parse_token(pub)
    assert (e.domain_id, e.session_id, e.node_id, e.entity_id, e.kind) == (
        2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP")
    assert (e.node_name, e.topic, e.type, e.type_hash) == (
        "/talker", "/chatter", "std_msgs/msg/String", STRING_HASH)
    assert e.qos == Qos(depth=7)
    node = parse_token("@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    assert (node.kind, node.node_name, node.topic) == ("NN", "/listener", "")
    # and we write them back identically
    assert topic_token(2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "", "talker",
                       "/chatter", "std_msgs/msg/String", Qos(depth=7)) == pub
    assert node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "", "listener") == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    for bad in ("@ros2_lv/0/x/0/0/XX/%/%/n", "@ros2_lv/a/x/0/0/NN/%/%/n", "0/chatter/x/y",
                "@ros2_lv/0/x/0/1/MP/%/%/n/%t"):
        with pytest.raises(ValueError):
            parse_token(bad)


def test_namespaces_mangle_both_ways():
    assert mangle("/fleet/auv1") == "%fleet%auv1" and unmangle("%fleet%auv1") == "/fleet/auv1"
    assert mangle("") == "%" and unmangle("%") == ""
    e = parse_token(topic_token(0, "ab", 0, 3, "MP", "/fleet", "bridge", "/fleet/auv1/nav/odometry",
                                "nav_msgs/msg/Odometry", DEFAULT_QOS))
    assert (e.namespace, e.node_name, e.topic) == ("/fleet", "/fleet/bridge",
                                                   "/fleet/auv1/nav/odometry")


def test_qos_keyexpr_writes_only_what_differs_from_the_default():
    assert Qos().keyexpr() == "::,:,:,:,,"
    assert Qos(depth=10).keyexpr() == "::,10:,:,:,,"
    assert SENSOR_QOS.keyexpr() == "2::,5:,:,:,,"
    assert STATIC_QOS.keyexpr() == ":1:,1:,:,:,,"
    for q in (SENSOR_QOS, STATIC_QOS, DEFAULT_QOS, Qos(2, 1, 2, 1000)):
        assert Qos.parse(q.keyexpr()) == q


def test_attachment_is_two_int64_and_the_16_byte_gid():
    gid = entity_gid("@ros2_lv/0/x/0/1/MP/%/%/n/%t/a::msg::dds_::B_/h/::,:,:,:,,")
    att = pack_attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(att) == 32 and att[:8] == (7).to_bytes(8, "little")
    assert unpack_attachment(att) == (7, 1_700_000_000_123_456_789, gid)
    # zenoh-ext's own serializer writes the same bytes for (int64, int64, 16 x uint8)
    import zenoh.ext as ze

    ref = ze.z_serialize((ze.Int64(7), ze.Int64(1_700_000_000_123_456_789),
                          tuple(ze.UInt8(b) for b in gid))).to_bytes()
    assert ref == att
    with pytest.raises(ValueError):
        unpack_attachment(att[:-1])
    with pytest.raises(ValueError):
        pack_attachment(1, 2, b"short")


def _matrix(t) -> np.ndarray:
    q = t.transform.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r
    tr = t.transform.translation
    m[:3, 3] = (tr.x, tr.y, tr.z)
    return m


def test_map_to_odom_composes_with_odom_to_base_into_the_slam_pose():
    o = types.SimpleNamespace(x=10.0, y=5.0, z=2.0, heading=math.radians(30), pitch=0.0,
                              roll=0.0)
    slam = {"x": 12.0, "y": 4.0, "heading": math.radians(40)}
    m_map_odom = _matrix(ros2.map_odom_tf(slam, o, 0))
    m_odom_base = _matrix(ros2.odom_tf(o, 0))
    m_map_base = m_map_odom @ m_odom_base
    # the SLAM pose in ENU: east 4, north 12, yaw pi/2 - 40 deg (z: the odometry's, -2)
    assert m_map_base[:3, 3] == pytest.approx([4.0, 12.0, -2.0], abs=1e-9)
    assert math.atan2(m_map_base[1, 0], m_map_base[0, 0]) == pytest.approx(
        math.pi / 2 - math.radians(40))


def test_static_tf_places_each_mount_in_flu():
    mounts = {"dvl": types.SimpleNamespace(lever_arm_m=(1.0, 0.2, 0.3), rpy_deg=(0, 0, 45)),
              "ins": types.SimpleNamespace(lever_arm_m=(0.0, 0.0, 0.0), rpy_deg=(0, 0, 0))}
    msg = ros2.static_tf(mounts, 5)
    by = {t.child_frame_id: t for t in msg.transforms}
    assert set(by) == {"dvl", "ins"} and all(t.header.frame_id == "base_link"
                                             for t in msg.transforms)
    m = _matrix(by["dvl"])
    assert m[:3, 3] == pytest.approx([1.0, -0.2, -0.3])  # FRD (1, .2, .3) is FLU (1, -.2, -.3)
    # the DVL's forward axis, yawed 45 deg to starboard, points forward-right: FLU y < 0
    assert m[:3, 0] == pytest.approx([math.sqrt(0.5), -math.sqrt(0.5), 0.0])


def test_diagnostics_levels_follow_the_device_state():
    status = {"vehicle": "auv1", "devices": {
        "ins": {"connected": True, "stale": False, "rate_hz": 100.0, "port": "/dev/pts/3"},
        "dvl": {"connected": False, "last_error": "unplugged", "port": "/dev/pts/4"},
        "msis": {"connected": True, "stale": True, "silent_s": 7.5},
        "mag": {"connected": True, "stale": False, "bad_frames": 2, "decode_errors": 0}}}
    d = ros2.diagnostics_msg(status, 1)
    levels = {s.name: s.level for s in d.status}
    assert levels == {"auvgw/auv1/ins": ros2.DIAG_OK, "auvgw/auv1/dvl": ros2.DIAG_ERROR,
                      "auvgw/auv1/msis": ros2.DIAG_STALE, "auvgw/auv1/mag": ros2.DIAG_WARN}
    ins = next(s for s in d.status if s.name.endswith("/ins"))
    assert {kv.key: kv.value for kv in ins.values}["rate_hz"] == "100"
    stage = ros2.diagnostics_msg({"vehicle": "auv1", "component": "fusion", "stopped": False,
                                  "stage": {"received": 12}}, 1)
    assert stage.status[0].name == "auvgw/auv1/fusion"
    assert {kv.key: kv.value for kv in stage.status[0].values}["stage.received"] == "12"
