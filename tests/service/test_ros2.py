"""ROS 2 conversion (auvgw/ros2.py): REP 103/105 frames from the project's NED/FRD, CDR round
trips through rosbags, and the mapping of every stream to its ROS 2 type."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from auvgw import ros2
from auvgw.drivers.hn100 import Hn100Nav
from auvgw.fusion.odometry import Odometry

S = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED <-> ENU
F = np.diag([1.0, -1.0, -1.0])  # FRD <-> FLU


def _odometry(heading: float, v_body=(1.0, 0.0, 0.0), xyz=(10.0, 20.0, 5.0)) -> Odometry:
    c, s = math.cos(heading), math.sin(heading)
    v_ned = (c * v_body[0] - s * v_body[1], s * v_body[0] + c * v_body[1], v_body[2])
    cov = np.diag([1.0, 4.0, 0.25, 0.01, 0.02, 0.1, 0.2, 0.3])
    cov[0, 1] = cov[1, 0] = 0.5
    return Odometry(t=1.0, x=xyz[0], y=xyz[1], z=xyz[2], roll=0.0, pitch=0.0, heading=heading,
                    velocity_ned=v_ned, velocity_body=tuple(v_body), angular_rate=(0.0, 0.0, 0.1),
                    covariance=cov, bottom_lock=True, coasting=False, dvl_age_s=0.1,
                    depth_age_s=0.1, ins_gap=False, increment=None)  # fmt: skip


def _rot(q) -> np.ndarray:
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()


def _roundtrip(m: ros2.RosMessage):
    return ros2.typestore().deserialize_cdr(ros2.serialize(m), m.type)


def test_heading_east_at_one_metre_per_second_is_plus_x_in_enu():
    m, tf = ros2.to_ros("nav", "odometry", _odometry(math.pi / 2), t_ns=1_500_000_000)
    assert (m.topic, m.type) == ("nav/odometry", "nav_msgs/msg/Odometry")
    assert (tf.topic, tf.type) == ("/tf", ros2.TF_TYPE)  # and odom -> base_link, the same pose
    (t,) = _roundtrip(tf).transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
    assert (t.transform.translation.x, t.transform.translation.y) == pytest.approx((20.0, 10.0))
    o = _roundtrip(m)
    assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_link")
    assert (o.header.stamp.sec, o.header.stamp.nanosec) == (1, 500_000_000)
    # position NED (10 north, 20 east, 5 down) -> ENU (20, 10, -5)
    p = o.pose.pose.position
    assert (p.x, p.y, p.z) == (20.0, 10.0, -5.0)
    # twist in base_link (FLU): forward; in odom (ENU) that is +x (east)
    lin = o.twist.twist.linear
    assert (lin.x, lin.y, lin.z) == (1.0, -0.0, -0.0)
    v_enu = _rot(o.pose.pose.orientation) @ [lin.x, lin.y, lin.z]
    np.testing.assert_allclose(v_enu, [1.0, 0.0, 0.0], atol=1e-12)
    # yaw rate: NED r = +0.1 (turning to starboard) is FLU z = -0.1
    assert o.twist.twist.angular.z == pytest.approx(-0.1)
    # covariance: x_enu = y_ned, y_enu = x_ned, yaw = -heading
    cov = np.asarray(o.pose.covariance).reshape(6, 6)
    assert (cov[0, 0], cov[1, 1], cov[2, 2], cov[0, 1]) == (4.0, 1.0, 0.25, 0.5)
    assert (cov[5, 5], cov[4, 4]) == (0.01, 0.02)
    tw = np.asarray(o.twist.covariance).reshape(6, 6)
    assert (tw[0, 0], tw[1, 1], tw[2, 2]) == (0.1, 0.2, 0.3)


@pytest.mark.parametrize(
    ("heading", "pitch", "roll"),
    [
        (0.0, 0.0, 0.0),
        (math.pi / 2, 0.0, 0.0),
        (0.3, 0.2, -0.1),
        (-2.5, -0.4, 0.7),
        (math.pi, 0.1, 0.3),
    ],
)
def test_quaternion_is_ned_attitude_seen_in_enu_flu(heading, pitch, roll):
    q = ros2.quaternion_enu_flu(heading, pitch, roll)
    r_ned_frd = Rotation.from_euler("ZYX", [heading, pitch, roll]).as_matrix()
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), S @ r_ned_frd @ F, atol=1e-12)
    assert math.isclose(float(np.dot(q, q)), 1.0)


def test_quaternion_named_cases():
    def fwd(q):
        return Rotation.from_quat(q).apply([1.0, 0.0, 0.0])

    np.testing.assert_allclose(fwd(ros2.quaternion_enu_flu(0.0, 0.0, 0.0)), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(
        fwd(ros2.quaternion_enu_flu(math.pi / 2, 0, 0)), [1, 0, 0], atol=1e-12
    )
    # nose up 0.3 rad: forward points up in ENU
    assert fwd(ros2.quaternion_enu_flu(0.0, 0.3, 0.0))[2] == pytest.approx(math.sin(0.3))
    # roll starboard down: the left (FLU +y) axis points up
    left = Rotation.from_quat(ros2.quaternion_enu_flu(0.0, 0.0, 0.2)).apply([0.0, 1.0, 0.0])
    assert left[2] == pytest.approx(math.sin(0.2))


def test_ins_imu_message():
    nav = Hn100Nav(seq=1, status=0, time=12.5, roll=0.1, pitch=-0.05, heading=1.2,
                   rate_x=0.01, rate_y=0.02, rate_z=0.03, accel_x=0.1, accel_y=0.2, accel_z=-9.81,
                   vel_n=1.0, vel_e=0.0, vel_d=0.0, latitude=0.7, longitude=0.1, depth=5.0,
                   aligned=None, gnss_aided=None, dvl_aided=None, error=None)  # fmt: skip
    (m,) = ros2.to_ros("sensor", "ins", nav, t_ns=5)
    assert (m.topic, m.type) == ("sensor/ins/imu", "sensor_msgs/msg/Imu")
    imu = _roundtrip(m)
    assert imu.header.frame_id == "ins"
    a, w = imu.linear_acceleration, imu.angular_velocity
    assert (a.x, a.y, a.z) == (0.1, -0.2, 9.81)  # FRD specific force -> FLU: +g up at rest
    assert (w.x, w.y, w.z) == (0.01, -0.02, -0.03)
    np.testing.assert_allclose(
        _rot(imu.orientation),
        S @ Rotation.from_euler("ZYX", [1.2, -0.05, 0.1]).as_matrix() @ F,
        atol=1e-12,
    )


def test_slam_pose_raw_and_fallback_messages():
    body = {"t": 3.0, "x": 5.0, "y": -2.0, "heading": 0.0, "cov": [[1, 0, 0], [0, 2, 0], [0, 0, 3]]}
    (m,) = ros2.to_ros("slam", "vb-aufastslam/pose", body, t_ns=3_000_000_000)
    assert m.type == "geometry_msgs/msg/PoseWithCovarianceStamped"
    p = _roundtrip(m)
    assert p.header.frame_id == "map"
    assert (p.pose.pose.position.x, p.pose.pose.position.y) == (-2.0, 5.0)
    cov = np.asarray(p.pose.covariance).reshape(6, 6)
    assert (cov[0, 0], cov[1, 1], cov[5, 5]) == (2.0, 1.0, 3.0)

    raw = ros2.raw_frame_msg("dvl", "pd0", 7, 42, 1000, b"\x7f\x7f\x00\x01")
    r = _roundtrip(raw)
    assert (r.device, r.wire_format, r.seq, r.stream_offset) == ("dvl", "pd0", 42, 1000)
    assert bytes(r.data) == b"\x7f\x7f\x00\x01"
    assert "uint8[] data" in ros2.msgdef(ros2.RAW_FRAME_TYPE)

    (st,) = ros2.to_ros("status", "gateway", {"v": 1, "vehicle": "auv1"}, t_ns=1)
    d = _roundtrip(st)
    assert (st.topic, st.type, d.source) == ("status/gateway", ros2.DECODED_TYPE, "gateway")
    assert d.json == '{"v":1,"vehicle":"auv1"}'


def _command_cdr(seq: int, rpm: float, rudder: float, stern: float, stamp_ns: int = 0) -> bytes:
    t = ros2._t("builtin_interfaces/msg/Time")(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    m = ros2._t(ros2.ACTUATOR_COMMAND_TYPE)(
        header=ros2._t("std_msgs/msg/Header")(stamp=t, frame_id="base_link"), seq=seq,
        shaft_rpm=rpm, rudder=rudder, stern=stern)  # fmt: skip
    return ros2.serialize(ros2.RosMessage("cmd/actuators", ros2.ACTUATOR_COMMAND_TYPE, m))


def test_a_ros2_command_becomes_the_gates_command_envelope():
    """The bridge's command side in-process: a CDR ActuatorCommand becomes the bus envelope of
    the DBC's ActuatorCommand (same fields, source ros2, its stamp), which the gateway's gate
    forwards; one out of the DBC's range is the gate's to refuse; bytes that are no command are
    counted and give None."""
    from auvgw.bus import decode_envelope
    from auvgw.drivers.actuators import CommandGate, CommandRefused
    from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig

    bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="v", namespace="/fleet", commands=["actuators"]))
    assert bridge.command_topic("actuators") == "/fleet/v/cmd/actuators"
    payload = bridge.on_ros_command("actuators", _command_cdr(7, 500.0, 0.1, -0.05, 123))
    env = decode_envelope(payload, "auv/v/cmd/x")
    assert (env.type, env.device, env.t_recv_ns, env.seq) == ("ActuatorCommand", "ros2", 123, 7)
    m = env.message
    assert (m.seq, m.shaft_rpm, m.rudder, m.stern) == (7, 500.0, 0.1, -0.05)
    gate = CommandGate()
    gate.sent(gate.check(m))
    wild = decode_envelope(bridge.on_ros_command("actuators", _command_cdr(8, 9999.0, 0, 0)), "k")
    with pytest.raises(CommandRefused, match="out_of_range"):
        gate.check(wild.message)
    good = _command_cdr(9, 0.0, 0.0, 0.0)
    for bad in (b"", b"\x00\x01\x00\x00\x07", good[:-3], b"\x00\x01\x00\x00" + b"\xff" * 60,
                b"\x13\x37" + good[2:]):  # fmt: skip
        assert bridge.on_ros_command("actuators", bad) is None
    assert (bridge.stats.commands, bridge.stats.bad_commands) == (2, 5)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=80))
def test_no_bytes_on_a_command_topic_raise(data: bytes):
    from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig

    bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="v", commands=["actuators"]))
    out = bridge.on_ros_command("actuators", data)
    assert (out is None) == (bridge.stats.bad_commands == 1)


# -- compiled CDR writers (auvgw/ros2_cdr.py): the bridge's bytes are rosbags' ---------------------


def _reference(source: str, msg, t_ns: int) -> list[tuple[str, str, bytes]]:
    return [(m.topic, m.type, bytes(ros2.serialize(m)))
            for m in ros2.to_ros("sensor", source, msg, t_ns)]  # fmt: skip


@pytest.fixture(scope="module")
def sensor_samples(shared_data, tmp_path_factory) -> list[tuple[str, object]]:
    """(format, decoded message) of every format's sample frames with a standard ROS 2 form
    (PD0's from the real recording)."""
    from auvgw.drivers.formats import FORMATS, get_format
    from auvgw.testing.format_samples import stream_samples

    out = []
    for fmt in FORMATS:
        _, frames = stream_samples(fmt, shared_data, tmp_path_factory.mktemp(fmt))
        out += [(fmt, m) for f in frames for m in get_format(fmt).decode(f)
                if ros2.sensor_form(m) is not None]  # fmt: skip
    return out


@pytest.mark.parametrize("device", ["i", "ins", "dvl_1", "multibeam"])  # every frame_id padding
def test_compiled_cdr_is_rosbags_cdr_for_every_sensor_form(sensor_samples, device):
    from auvgw.ros2_cdr import sensor_cdr

    assert {ros2.sensor_form(m) for _, m in sensor_samples} == {
        "imu", "magnetic_field", "dvl", "points", "returns"}  # fmt: skip
    for i, (fmt, msg) in enumerate(sensor_samples):
        t_ns = 1_700_000_000_000_000_000 + 123_456_789 * i
        assert sensor_cdr(device, msg, t_ns) == _reference(device, msg, t_ns), (fmt, msg)
    status = {"v": 1}
    assert sensor_cdr(device, status, 0) is None  # no standard form: to_ros's Decoded


_floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=40, deadline=None)
@given(device=st.text("abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=12),
       t_ns=st.integers(0, 2**31 * 10**9 - 1),
       angles=st.lists(st.floats(allow_infinity=False), min_size=3, max_size=3),
       v=st.lists(_floats, min_size=12, max_size=12))  # fmt: skip
def test_compiled_imu_and_field_cdr_equal_rosbags_for_any_values(device, t_ns, angles, v):
    """Any values (NaN and infinities too; the angles finite, as ``math.cos`` needs)."""
    from auvgw.drivers.ms3a import Ms3aSample
    from auvgw.ros2_cdr import sensor_cdr

    roll, pitch, heading = angles
    nav = Hn100Nav(seq=1, status=0, time=1.0, roll=roll, pitch=pitch, heading=heading,
                   rate_x=v[3], rate_y=v[4], rate_z=v[5], accel_x=v[6], accel_y=v[7], accel_z=v[8],
                   vel_n=0.0, vel_e=0.0, vel_d=0.0, latitude=0.0, longitude=0.0, depth=0.0,
                   aligned=None, gnss_aided=None, dvl_aided=None, error=None)  # fmt: skip
    assert sensor_cdr(device, nav, t_ns) == _reference(device, nav, t_ns)
    mag = Ms3aSample(counter=1, bx=v[9], by=v[10], bz=v[11])
    assert sensor_cdr(device, mag, t_ns) == _reference(device, mag, t_ns)


def test_a_stamp_past_2038_is_refused_by_name():
    """ROS 2's ``Time.sec`` is an int32: the writer says so instead of a bare struct.error."""
    from auvgw.drivers.ms3a import Ms3aSample
    from auvgw.ros2_cdr import sensor_cdr

    mag = Ms3aSample(counter=1, bx=1.0, by=2.0, bz=3.0)
    assert sensor_cdr("mag", mag, 2**31 * 10**9 - 1) is not None
    with pytest.raises(ValueError, match="int32 seconds"):
        sensor_cdr("mag", mag, 2**31 * 10**9)


def test_cdr_struct_refuses_sizes_that_do_not_fit_the_type():
    from auvgw.ros2_cdr import cdr_struct

    # encapsulation, stamp (2 x 4), frame_id "ab" (4 + 3), 1 byte to align the doubles to 8
    assert cdr_struct("sensor_msgs/msg/Imu", (2,)).size == 4 + 8 + 7 + 1 + 37 * 8
    with pytest.raises(ValueError, match="end before a string"):
        cdr_struct("sensor_msgs/msg/Imu", ())
    with pytest.raises(ValueError, match="longer than"):
        cdr_struct("sensor_msgs/msg/Imu", (3, 1))


def test_a_batch_puts_every_good_message_in_order_around_one_that_fails(sensor_samples):
    """The gateway's batch (``Ros2Bridge.feed_batch``): each message's CDR in the posted order,
    the compiled writers' bytes; a message whose conversion raises (a stamp ROS 2 cannot hold)
    is counted and the rest of the batch still goes out."""
    from collections import deque

    from auvgw.ros2_cdr import sensor_cdr
    from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig

    got: list[tuple[str, bytes, int]] = []
    bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="v"),
                        on_publish=lambda key, cdr, t_ns: got.append((key, cdr, t_ns)))  # fmt: skip
    forms = {}
    for _, m in sensor_samples:
        forms.setdefault(ros2.sensor_form(m), m)
    t0, bad = 1_700_000_000_000_000_000, 2**31 * 10**9  # past 2038: Time.sec overflows
    posted = [("ins", t0 + i, m) for i, m in enumerate(forms.values())]
    posted.insert(2, ("mag", bad, forms["magnetic_field"]))
    bridge.feed_batch(deque(posted))
    expect = [(cdr, t) for d, t, m in posted if t != bad for _, _, cdr in sensor_cdr(d, m, t)]
    assert [(cdr, t) for _, cdr, t in got] == expect and len(expect) == 6  # the DVL's two
    stats = bridge.counters()["stage"]
    assert (stats["received"], stats["published"], stats["bad_payloads"]) == (6, 6, 1)


@pytest.mark.parametrize(("value", "dense"),
                         [(1.0, True), (np.nan, False), (np.inf, False), (-np.inf, False),
                          (3e38, True), (-3e38, True)])  # fmt: skip
def test_a_clouds_is_dense_says_whether_every_value_is_finite(value, dense):
    """``is_dense`` (the compiled writer: a float64 sum) is rosbags' ``isfinite().all()``:
    NaN and either infinity make it False, float32's largest values do not overflow it."""
    from auvgw.ros2_cdr import _cloud

    rows = np.full((8, 4), 3e38, dtype="<f4")
    rows[5, 2] = value
    cdr = _cloud(1_700_000_000_000_000_000, "mb", rows)
    msg = ros2.typestore().deserialize_cdr(cdr, "sensor_msgs/msg/PointCloud2")
    assert msg.is_dense is bool(np.isfinite(rows).all()) is dense
