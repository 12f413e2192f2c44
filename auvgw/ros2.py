"""ROS 2 message types of every auvgw stream, CDR-encoded with ``rosbags`` (docs/bus.md#ros-2).

Frames follow REP 103 / REP 105: ``map`` and ``odom`` are ENU (x east, y north, z up), ``base_link``
is FLU (x forward, y left, z up), a sensor's frame is named after its gateway device (``ins``,
``dvl``, ``multibeam``, ...) with FLU axes where the sensor's axes are the vehicle's (the static
transform ``base_link`` -> device is its lever arm). auvgw itself is NED / FRD throughout; this
module is the one place that converts:

* positions and velocities: NED (n, e, d) -> ENU (e, n, -d); body FRD (f, s, d) -> FLU (f, -s, -d)
* attitude (heading from north towards east, pitch nose up, roll starboard down; body -> NED)
  -> the quaternion of FLU -> ENU: ``R_enu_flu = S R_ned_frd(heading, pitch, roll) F`` with
  ``S`` the NED/ENU swap and ``F = diag(1, -1, -1)``, which is the ZYX Euler triple
  (yaw = pi/2 - heading, pitch = -pitch, roll = roll).

Mapping (decoded message type -> ROS 2 type, topic ``/<vehicle>/<section>/<device>/<name>``):

===============================  ==========================================  =================
auvgw                            ROS 2                                       topic name
===============================  ==========================================  =================
HN-100 solution (serial or CAN)  sensor_msgs/msg/Imu (frame ``<device>``)    ``imu``
MS3A sample (serial or CAN)      sensor_msgs/msg/MagneticField (T)           ``magnetic_field``
PD0 ensemble                     geometry_msgs/msg/TwistWithCovarianceStamped ``twist``
                                 sensor_msgs/msg/Range (altitude)            ``altitude``
XYZ 88 / Depth (multibeam)       sensor_msgs/msg/PointCloud2 (x y z intensity) ``points``
GeoSwath swath (XYZ 88 of the     sensor_msgs/msg/PointCloud2 (frame          ``points``
swath stage, ``<device>_swath``)  ``<device>_swath``: the reference point)
SeaNet mtHeadData (MSIS)         sensor_msgs/msg/PointCloud2 (one scan line)  ``returns``
fusion Odometry                  nav_msgs/msg/Odometry (``odom`` -> ``base_link``) ``odometry``
SLAM pose                        geometry_msgs/msg/PoseWithCovarianceStamped ``pose``
SLAM landmarks                   sensor_msgs/msg/PointCloud2 (``map``)       ``landmarks``
raw frame                        auvgw_msgs/msg/RawFrame (:data:`RAW_FRAME_MSG`)
anything else (status, truth,    auvgw_msgs/msg/Decoded (:data:`DECODED_MSG`: type name
PD6, SeaNet control, ...)        and the JSON body)
===============================  ==========================================  =================

A GeoSwath's swaths (:mod:`auvgw.stages.swath`, device ``<device>_swath``) are soundings re the
vehicle's reference point (the processing applied the transducer's lever arm), levelled and
heading-aligned like a Kongsberg XYZ 88 re its transducer: their frame ``<device>_swath`` sits at
``base_link`` with its axes (:func:`static_tf_for_config`); roll and pitch are left in, as for
the Kongsberg multibeam's frame.

The DVL twist is in the frame the DVL reports: RDI instrument axes in frame ``<device>`` (beam
and instrument coordinates), or ``base_link`` FLU (ship and earth coordinates, made body by
:func:`auvgw.fusion.adapters.dvl_from_pd0`). Covariances the devices do not give are zero
(ROS: unknown). Header stamps are the gateway's receive times (vehicle-paced under a ``[clock]``).
"""

from __future__ import annotations

import bisect
import dataclasses
import json
import math
import re
from collections.abc import Iterable, Mapping
from functools import cache, lru_cache
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, SupportsFloat, cast

import numpy as np

from auvgw.decoding import message_type
from auvgw.drivers import registry
from auvgw.drivers.roles import Field, Ins
from auvgw.ground.geometry import quaternion_zyx

if TYPE_CHECKING:  # rosbags' own message classes (the type store builds the same at run time)
    from rosbags.interfaces.typing import Typesdict
    from rosbags.typesys.store import Typestore
    from rosbags.typesys.stores.ros2_humble import (
        diagnostic_msgs__msg__DiagnosticArray as DiagnosticArray,
    )
    from rosbags.typesys.stores.ros2_humble import geometry_msgs__msg__Point as Point
    from rosbags.typesys.stores.ros2_humble import geometry_msgs__msg__Pose as Pose
    from rosbags.typesys.stores.ros2_humble import (
        geometry_msgs__msg__PoseWithCovarianceStamped as PoseWithCovarianceStamped,
    )
    from rosbags.typesys.stores.ros2_humble import geometry_msgs__msg__Quaternion as Quaternion
    from rosbags.typesys.stores.ros2_humble import (
        geometry_msgs__msg__TransformStamped as TransformStamped,
    )
    from rosbags.typesys.stores.ros2_humble import geometry_msgs__msg__Vector3 as Vector3
    from rosbags.typesys.stores.ros2_humble import nav_msgs__msg__Odometry as RosOdometry
    from rosbags.typesys.stores.ros2_humble import sensor_msgs__msg__Imu as Imu
    from rosbags.typesys.stores.ros2_humble import (
        sensor_msgs__msg__MagneticField as MagneticField,
    )
    from rosbags.typesys.stores.ros2_humble import sensor_msgs__msg__PointCloud2 as PointCloud2
    from rosbags.typesys.stores.ros2_humble import std_msgs__msg__Header as Header
    from rosbags.typesys.stores.ros2_humble import tf2_msgs__msg__TFMessage as TFMessage

    from auvgw.drivers import kongsberg, pd0
    from auvgw.drivers.seanet import HeadData
    from auvgw.fusion.odometry import Odometry

#: a 3-vector of anything ``float()`` takes (a tuple, a numpy row)
Vec3 = Iterable[SupportsFloat]


class PlanarPose(Protocol):
    """A pose on the map plane: ``x`` north, ``y`` east (m), ``heading`` (rad)."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def heading(self) -> float: ...


class MountLike(Protocol):
    """A sensor mount (:class:`auvgw.config.ros2.Mount`): lever arm (m, body FRD) and roll,
    pitch, yaw (deg)."""

    @property
    def lever_arm_m(self) -> tuple[float, float, float]: ...
    @property
    def rpy_deg(self) -> tuple[float, float, float]: ...

__all__ = [
    "ACTUATOR_COMMAND_MSG",
    "ACTUATOR_COMMAND_TYPE",
    "DECODED_MSG",
    "DECODED_TYPE",
    "DIAGNOSTICS_TYPE",
    "RAW_FRAME_MSG",
    "RAW_FRAME_TYPE",
    "TF_TYPE",
    "RosMessage",
    "TfTracker",
    "actuator_command",
    "auvgw_types",
    "decoded_msg",
    "diagnostics_msg",
    "enu_from_ned",
    "flu_from_frd",
    "map_odom_tf",
    "msgdef",
    "odom_tf",
    "quaternion_enu_flu",
    "raw_frame_msg",
    "ros_topic",
    "serialize",
    "static_tf",
    "static_tf_for_config",
    "tf_msg",
    "to_ros",
    "typestore",
]

#: ROS type of raw frames and its definition (ros2msg)
RAW_FRAME_TYPE = "auvgw_msgs/msg/RawFrame"
RAW_FRAME_MSG = """\
# One frame exactly as a device sent it (auvgw raw bus traffic).
std_msgs/Header header  # stamp: receive time; frame_id: the gateway device name
string device           # gateway device name (ins, dvl, ...)
string wire_format      # gateway format of the bytes (hn100, pd0, seanet, kongsberg, can...)
uint64 seq              # the device's frame sequence, from 1 since the gateway started
uint64 stream_offset    # byte offset of the frame's first byte since the connection opened
uint8[] data            # the frame's bytes (CAN: u32 LE id | u8 flags | data)
"""
#: ROS type of messages without a standard type, and its definition
DECODED_TYPE = "auvgw_msgs/msg/Decoded"
DECODED_MSG = """\
# A message with no standard ROS 2 type: its auvgw type name and fields as JSON (SI units).
std_msgs/Header header  # stamp: receive time of the frame it came from; frame_id: device/component
string source           # gateway device or stage component
string type             # auvgw message type (pd6.BS, mtAlive, GatewayStatus, ...)
uint64 seq              # sequence of the raw frame (sensors) or of the publisher
string json             # the message's fields, JSON (NaN as null)
"""

#: ROS type of an actuator command (a ROS 2 node's commands in, on
#: ``<namespace>/<vehicle>/cmd/<device>``: :meth:`auvgw.stages.ros2.Ros2Bridge.on_ros_command`)
#: and its definition: no standard ROS 2 type carries a shaft speed and two fin angles, so this
#: is ``config/actuators.dbc``'s ``ActuatorCommand`` field for field, in SI units
ACTUATOR_COMMAND_TYPE = "auvgw_msgs/msg/ActuatorCommand"
ACTUATOR_COMMAND_MSG = """\
# A command to the vehicle's actuators (config/actuators.dbc ActuatorCommand): the gateway checks
# it (DBC ranges, sequence) and sends it to the motor/fin controller on CAN (docs/ros2.md).
std_msgs/Header header  # stamp: when the command was made (0: when the bridge took it)
uint16 seq              # sequence number modulo 65536; one not newer than the last is refused
float64 shaft_rpm       # commanded shaft speed, rpm, positive ahead (DBC range +-1600)
float64 rudder          # rudder angle, rad; positive turns the vehicle to port (+-30 deg)
float64 stern           # stern-plane angle, rad; positive pitches the nose down (+-30 deg)
"""

#: the standard topics and types of transforms and diagnostics (absolute topic names: not
#: under ``/<vehicle>``, where tf2, Foxglove and rqt look for them)
TF_TYPE = "tf2_msgs/msg/TFMessage"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"

FRAME_MAP = "map"
FRAME_ODOM = "odom"
FRAME_BASE = "base_link"
#: sound speed (m/s) placing MSIS bins in range when the message does not say
DEFAULT_SOUND_SPEED = 1500.0

#: NED <-> ENU (its own inverse) and FRD <-> FLU
_S = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_F = np.diag([1.0, -1.0, -1.0])


class RosMessage(NamedTuple):
    """One ROS 2 message: topic name under ``/<vehicle>`` (or absolute, ``/`` first: ``/tf``,
    ``/tf_static``, ``/diagnostics``), ROS type and the message object."""

    topic: str
    type: str
    msg: Any


def auvgw_types() -> Typesdict:
    """The auvgw_msgs types (rosbags' parsed definitions), to register in a type store."""
    from rosbags.typesys import get_types_from_msg

    types: Typesdict = {}
    for text, name in ((RAW_FRAME_MSG, RAW_FRAME_TYPE), (DECODED_MSG, DECODED_TYPE),
                       (ACTUATOR_COMMAND_MSG, ACTUATOR_COMMAND_TYPE)):  # fmt: skip
        types.update(get_types_from_msg(text, name))
    return types


@cache
def typestore() -> Typestore:
    """The rosbags type store (ROS 2 Humble) with the auvgw_msgs types registered."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(auvgw_types())
    return ts


class RawFrameRos(Protocol):
    """``auvgw_msgs/msg/RawFrame`` as read back (the type store builds its class at run time)."""

    header: Header
    device: str
    wire_format: str
    seq: int
    stream_offset: int
    data: np.ndarray


class DecodedRos(Protocol):
    """``auvgw_msgs/msg/Decoded`` as read back."""

    header: Header
    source: str
    type: str
    seq: int
    json: str


def read_raw_frame(cdr: bytes) -> RawFrameRos:
    """A RawFrame message from its CDR bytes."""
    return cast("RawFrameRos", typestore().deserialize_cdr(cdr, RAW_FRAME_TYPE))


def read_decoded(cdr: bytes) -> DecodedRos:
    """A Decoded message from its CDR bytes."""
    return cast("DecodedRos", typestore().deserialize_cdr(cdr, DECODED_TYPE))


@cache
def msgdef(type_name: str) -> str:
    """The ros2msg schema text of a type (with its dependencies), as MCAP stores it."""
    text, _ = typestore().generate_msgdef(type_name, ros_version=2)
    return text


def serialize(m: RosMessage) -> bytes:
    """CDR (little endian) bytes of a message."""
    return bytes(typestore().serialize_cdr(m.msg, m.type))


def _t(name: str) -> Any:
    return typestore().types[name]


def actuator_command(cdr: bytes) -> tuple[Any, int]:
    """The actuators' DBC ``ActuatorCommand`` (:mod:`auvgw.drivers.actuators`; rad, rpm) of a
    CDR ``auvgw_msgs/msg/ActuatorCommand``, and its header stamp (ns, 0 when unset); a
    ``ValueError`` naming what is wrong for bytes that are not one. The ranges are not checked
    here: the gateway's :class:`~auvgw.drivers.actuators.CommandGate` does, and counts."""
    from auvgw.drivers.actuators import COMMAND_TYPE, actuators_can

    if len(cdr) < 4 or cdr[:2] not in (b"\x00\x00", b"\x00\x01"):
        raise ValueError(f"{len(cdr)} bytes without a CDR encapsulation header (00 00 or 00 01)")
    try:
        m: Any = typestore().deserialize_cdr(cdr, ACTUATOR_COMMAND_TYPE)
    except Exception as exc:  # rosbags raises what struct / its own checks raise
        raise ValueError(f"not a CDR {ACTUATOR_COMMAND_TYPE} ({len(cdr)} bytes): "
                         f"{type(exc).__name__}: {exc}") from None  # fmt: skip
    stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
    cmd = actuators_can().types[COMMAND_TYPE](
        seq=int(m.seq), shaft_rpm=float(m.shaft_rpm), rudder=float(m.rudder), stern=float(m.stern)
    )
    return cmd, stamp


# -- frames ----------------------------------------------------------------------------------------


def enu_from_ned(v: Vec3) -> tuple[float, float, float]:
    """A NED vector (north, east, down) as ENU (east, north, up)."""
    n, e, d = v
    return float(e), float(n), -float(d)


def flu_from_frd(v: Vec3) -> tuple[float, float, float]:
    """A body FRD vector (forward, starboard, down) as FLU (forward, left, up)."""
    f, s, d = v
    return float(f), -float(s), -float(d)


def quaternion_enu_flu(
    heading: float, pitch: float, roll: float
) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation FLU body -> ENU for an NED attitude (rad; heading from north
    towards east, pitch nose up, roll starboard down): ZYX Euler (pi/2 - heading, -pitch, roll)."""
    return quaternion_zyx(roll, -pitch, math.pi / 2 - heading)


def ros_topic(namespace: str, vehicle: str, topic: str) -> str:
    """The fully qualified ROS topic of a :class:`~auvgw.ros2.RosMessage` topic: absolute ones
    (``/tf``) as they are, the others under ``<namespace>/<vehicle>``; every character a ROS name
    may not hold (``-``, ``.``, ...) written ``_``."""
    full = topic if topic.startswith("/") else f"{namespace}/{vehicle}/{topic}"
    return re.sub(r"[^A-Za-z0-9_/]", "_", full)


# -- building blocks -------------------------------------------------------------------------------


def _header(t_ns: int, frame_id: str) -> Header:
    t = _t("builtin_interfaces/msg/Time")(
        sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
    )
    return _t("std_msgs/msg/Header")(stamp=t, frame_id=frame_id)


def _vec3(v: Vec3) -> Vector3:
    x, y, z = (float(a) for a in v)
    return _t("geometry_msgs/msg/Vector3")(x=x, y=y, z=z)


def _quat(q: tuple[float, float, float, float]) -> Quaternion:
    return _t("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3])


def _point(v: Vec3) -> Point:
    x, y, z = (float(a) for a in v)
    return _t("geometry_msgs/msg/Point")(x=x, y=y, z=z)


def cloud_points(xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
    """The (n, 4) little-endian float32 x, y, z, intensity rows of a :func:`_cloud`."""
    cols = np.empty((len(xyz), 4), dtype="<f4")
    cols[:, :3] = xyz
    cols[:, 3] = 0.0 if intensity is None else intensity
    return cols


def _cloud(t_ns: int, frame: str, rows: np.ndarray) -> PointCloud2:
    """PointCloud2 of :func:`cloud_points` rows (float32 x, y, z, intensity; NaN points kept:
    ``is_dense`` False)."""
    PF = _t("sensor_msgs/msg/PointField")
    n = len(rows)
    fields = [PF(name=c, offset=4 * i, datatype=PF.FLOAT32, count=1) for i, c in enumerate("xyz")]
    fields.append(PF(name="intensity", offset=12, datatype=PF.FLOAT32, count=1))
    return _t("sensor_msgs/msg/PointCloud2")(
        header=_header(t_ns, frame), height=1, width=n, fields=fields, is_bigendian=False,
        point_step=16, row_step=16 * n, data=rows.reshape(-1).view(np.uint8),
        is_dense=bool(np.isfinite(rows).all()),
    )  # fmt: skip


def _cov6(block: np.ndarray | None) -> np.ndarray:
    out = np.zeros(36)
    if block is not None:
        out[:] = np.nan_to_num(np.asarray(block, float)).reshape(36)
    return out


def raw_frame_msg(
    device: str, wire_format: str, t_ns: int, seq: int, offset: int, data: bytes
) -> RosMessage:
    """A raw frame as ``auvgw_msgs/msg/RawFrame`` on topic ``raw/<device>``."""
    m = _t(RAW_FRAME_TYPE)(
        header=_header(t_ns, device), device=device, wire_format=wire_format, seq=int(seq),
        stream_offset=int(offset), data=np.frombuffer(data, dtype=np.uint8),
    )  # fmt: skip
    return RosMessage(f"raw/{device}", RAW_FRAME_TYPE, m)


def decoded_msg(
    topic: str, source: str, type_name: str, t_ns: int, seq: int, body: object,
    frame: str | None = None,
) -> RosMessage:
    """Any message as ``auvgw_msgs/msg/Decoded`` (``body``: a JSON-ready mapping or JSON text;
    ``frame``: its header's frame, default ``source``)."""
    text = body if isinstance(body, str) else json.dumps(body, separators=(",", ":"))
    m = _t(DECODED_TYPE)(
        header=_header(t_ns, source if frame is None else frame), source=source,
        type=type_name, seq=int(seq), json=text,
    )  # fmt: skip
    return RosMessage(topic, DECODED_TYPE, m)


# -- per stream ------------------------------------------------------------------------------------


def imu_msg(msg: Ins, device: str, t_ns: int) -> Imu:
    """An HN-100 solution (serial or CAN) as sensor_msgs/Imu in frame ``device`` (FLU)."""
    q = quaternion_enu_flu(msg.heading, msg.pitch, msg.roll)
    zeros = np.zeros(9)
    return _t("sensor_msgs/msg/Imu")(
        header=_header(t_ns, device), orientation=_quat(q), orientation_covariance=zeros,
        angular_velocity=_vec3(flu_from_frd((msg.rate_x, msg.rate_y, msg.rate_z))),
        angular_velocity_covariance=zeros,
        linear_acceleration=_vec3(flu_from_frd((msg.accel_x, msg.accel_y, msg.accel_z))),
        linear_acceleration_covariance=zeros,
    )  # fmt: skip


def magnetic_field_msg(msg: Field, device: str, t_ns: int) -> MagneticField:
    """An MS3A sample (nT, sensor FRD axes) as sensor_msgs/MagneticField (T, FLU)."""
    b = flu_from_frd((msg.bx, msg.by, msg.bz))
    return _t("sensor_msgs/msg/MagneticField")(
        header=_header(t_ns, device), magnetic_field=_vec3(np.asarray(b) * 1e-9),
        magnetic_field_covariance=np.zeros(9),
    )  # fmt: skip


class DvlReading(NamedTuple):
    """What :func:`dvl_msgs` publishes of a PD0 ensemble."""

    frame: str  #: ``base_link`` (ship / earth coordinates) or the device (beam / instrument)
    velocity: tuple[float, float, float]  #: m/s in ``frame`` (FLU for ``base_link``)
    bottom_lock: bool
    altitude: float  #: m
    field_of_view: float  #: rad (twice the beam angle; 0 unknown)


def dvl_reading(msg: pd0.Ensemble, device: str) -> DvlReading | None:
    """The twist and altitude of a PD0 ensemble (see the module docstring), None for an
    ensemble the fusion's adapter refuses."""
    from auvgw.fusion.adapters import AdapterError, dvl_from_pd0

    try:
        s = dvl_from_pd0(msg, t=0.0)
    except AdapterError:
        return None
    if s.frame == "body":
        frame, v = FRAME_BASE, flu_from_frd(s.velocity)
    else:
        frame, v = device, (float(s.velocity[0]), float(s.velocity[1]), float(s.velocity[2]))
    beam = msg.fixed_leader.beam_angle if msg.fixed_leader is not None else None
    fov = float(2 * math.radians(beam)) if beam else 0.0
    return DvlReading(frame, v, bool(s.bottom_lock), float(s.altitude), fov)


def dvl_msgs(msg: pd0.Ensemble, device: str, t_ns: int) -> list[RosMessage]:
    """A PD0 ensemble as a twist (the DVL's frame, see the module docstring) and an altitude."""
    d = dvl_reading(msg, device)
    if d is None:
        return []
    twist = _t("geometry_msgs/msg/Twist")(linear=_vec3(d.velocity),
                                          angular=_vec3((0.0, 0.0, 0.0)))  # fmt: skip
    cov = np.zeros(36)
    if not d.bottom_lock:
        cov[0] = -1.0  # ROS convention: this field is not valid
    tw = _t("geometry_msgs/msg/TwistWithCovarianceStamped")(
        header=_header(t_ns, d.frame),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=cov),
    )
    R = _t("sensor_msgs/msg/Range")
    rng = R(
        header=_header(t_ns, device), radiation_type=R.ULTRASOUND, field_of_view=d.field_of_view,
        min_range=0.0, max_range=float("inf"), range=d.altitude,
    )  # fmt: skip
    return [
        RosMessage(f"sensor/{device}/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", tw),
        RosMessage(f"sensor/{device}/altitude", "sensor_msgs/msg/Range", rng),
    ]


def swath_points(msg: kongsberg.XYZ88 | kongsberg.Depth) -> np.ndarray:
    """The :func:`cloud_points` rows of a multibeam ping (:func:`swath_msg`): x, y, z FLU (m),
    intensity the reflectivity (dB; 0 without)."""
    b = msg.beams
    rows = np.empty((len(b.depth), 4), dtype="<f4")
    rows[:, 0] = b.along
    np.negative(b.across, out=rows[:, 1], casting="unsafe")
    np.negative(b.depth, out=rows[:, 2], casting="unsafe")
    refl = getattr(b, "reflectivity", None)
    rows[:, 3] = 0.0 if refl is None else refl
    valid = getattr(b, "valid", None)
    valid = np.asarray(b.depth) != 0 if valid is None else valid
    if not valid.all():
        rows[~valid, :3] = np.nan
    return rows


def swath_msg(msg: kongsberg.XYZ88 | kongsberg.Depth, device: str, t_ns: int) -> PointCloud2:
    """Multibeam beams (along x forward, across y starboard, depth z down, m from the transmit
    transducer) as a PointCloud2 in frame ``device`` (FLU), intensity = reflectivity (dB); a
    beam without a detection (XYZ 88 detection info bit 7; Depth: depth 0, which the sonar
    writes for one) is a NaN point, never a sounding at the transducer."""
    return _cloud(t_ns, device, swath_points(msg))


def scanline_points(msg: HeadData, sound_speed: float = DEFAULT_SOUND_SPEED) -> np.ndarray:
    """The :func:`cloud_points` rows of an MSIS scan line (:func:`scanline_msg`): x, y, z FLU
    (m), intensity the bin's amplitude."""
    n = len(msg.bins)
    rows = np.empty((n, 4), dtype="<f4")  # filled in place: the bridge does this 200 times a second
    r = _bin_centres(n) * msg.bin_length(sound_speed)
    np.multiply(r, math.cos(msg.bearing), out=rows[:, 0], casting="unsafe")
    np.multiply(r, -math.sin(msg.bearing), out=rows[:, 1], casting="unsafe")
    rows[:, 2] = 0.0
    rows[:, 3] = msg.bins
    return rows


@lru_cache(maxsize=16)
def _bin_centres(n: int) -> np.ndarray:
    """0.5, 1.5, ... n - 0.5: an MSIS line's bin centres in bin lengths (read only)."""
    out = np.arange(n) + 0.5
    out.flags.writeable = False
    return out


def scanline_msg(
    msg: HeadData, device: str, t_ns: int, sound_speed: float = DEFAULT_SOUND_SPEED
) -> PointCloud2:
    """One MSIS scan line: a point per bin at the bin's centre range along the transducer
    bearing (rad, clockwise from forward seen from above, i.e. towards starboard), FLU frame
    ``device``, intensity = the bin's amplitude."""
    return _cloud(t_ns, device, scanline_points(msg, sound_speed))


#: Odometry state (x, y, z, heading, pitch, u, v, w) -> ROS pose (x, y, z, roll, pitch, yaw) ENU
#: and twist (vx, vy, vz) FLU: linear, so covariances map as J C J^T
_J_POSE = np.zeros((6, 8))
_J_POSE[0, 1] = _J_POSE[1, 0] = 1.0
_J_POSE[2, 2] = _J_POSE[4, 4] = _J_POSE[5, 3] = -1.0
_J_TWIST = np.zeros((6, 8))
_J_TWIST[0, 5] = 1.0
_J_TWIST[1, 6] = _J_TWIST[2, 7] = -1.0


def odometry_msg(o: Odometry, t_ns: int) -> RosOdometry:
    """fusion Odometry (NED, body FRD) as nav_msgs/Odometry: pose of ``base_link`` in ``odom``
    (ENU), twist in ``base_link`` (FLU)."""
    cov = np.asarray(o.covariance, float)
    pose = _t("geometry_msgs/msg/Pose")(
        position=_point(enu_from_ned((o.x, o.y, o.z))),
        orientation=_quat(quaternion_enu_flu(o.heading, o.pitch, o.roll)),
    )
    twist = _t("geometry_msgs/msg/Twist")(
        linear=_vec3(flu_from_frd(o.velocity_body)), angular=_vec3(flu_from_frd(o.angular_rate))
    )
    pose_cov = _cov6(_J_POSE @ cov @ _J_POSE.T)
    twist_cov = _cov6(_J_TWIST @ cov @ _J_TWIST.T)
    return _t("nav_msgs/msg/Odometry")(
        header=_header(t_ns, FRAME_ODOM),
        child_frame_id=FRAME_BASE,
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=pose_cov),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=twist_cov),
    )


def slam_pose_msg(body: Mapping[str, Any], t_ns: int) -> PoseWithCovarianceStamped:
    """A SLAM pose (map NED x, y, heading and its 3 x 3 covariance) as PoseWithCovarianceStamped
    in ``map`` (ENU; z 0: the pipelines are 2-D)."""
    cov6 = np.zeros((6, 6))
    c = body.get("cov")
    if c is not None:
        c = np.asarray(c, float)  # (x, y, heading) -> (y_enu, x_enu, -yaw)
        idx, sign = [1, 0, 5], np.array([1.0, 1.0, -1.0])
        cov6[np.ix_(idx, idx)] = c * np.outer(sign, sign)
    pose = _t("geometry_msgs/msg/Pose")(
        position=_point(enu_from_ned((body["x"], body["y"], 0.0))),
        orientation=_quat(quaternion_enu_flu(float(body["heading"]), 0.0, 0.0)),
    )
    return _t("geometry_msgs/msg/PoseWithCovarianceStamped")(
        header=_header(t_ns, FRAME_MAP),
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=_cov6(cov6)),
    )


def landmarks_msg(body: Mapping[str, object], t_ns: int) -> PointCloud2:
    """SLAM point landmarks (map NED x, y) as a PointCloud2 in ``map`` (ENU), intensity = id."""
    mean = np.asarray(body.get("mean") or np.zeros((0, 2)), float).reshape(-1, 2)
    xyz = np.column_stack([mean[:, 1], mean[:, 0], np.zeros(len(mean))])
    ids = np.asarray(body.get("ids") or np.zeros(len(mean)), float)
    return _cloud(t_ns, FRAME_MAP, cloud_points(xyz, ids))


def _transform(
    t_ns: int, parent: str, child: str, xyz: Vec3, q: tuple[float, float, float, float]
) -> TransformStamped:
    return _t("geometry_msgs/msg/TransformStamped")(
        header=_header(t_ns, parent),
        child_frame_id=child,
        transform=_t("geometry_msgs/msg/Transform")(
            translation=_vec3(xyz), rotation=_quat(q)
        ),
    )


def tf_msg(transforms: list[TransformStamped]) -> TFMessage:
    """tf2_msgs/TFMessage of ``TransformStamped`` messages (``/tf``, ``/tf_static``)."""
    return _t("tf2_msgs/msg/TFMessage")(transforms=transforms)


def odom_tf(o: Odometry, t_ns: int) -> TransformStamped:
    """The fusion's ``odom`` -> ``base_link`` transform (REP 105: the odometry's pose, ENU,
    FLU)."""
    return _transform(t_ns, FRAME_ODOM, FRAME_BASE, enu_from_ned((o.x, o.y, o.z)),
                      quaternion_enu_flu(o.heading, o.pitch, o.roll))  # fmt: skip


def map_odom_tf(slam: Mapping[str, float], odom: PlanarPose, t_ns: int) -> TransformStamped:
    """``map`` -> ``odom`` from a SLAM pose (map NED x, y, heading) and the odometry at the same
    time (NED x, y, heading): the 2-D correction ``T_map_base * T_odom_base^-1`` (REP 105), in ENU
    (z and the odometry's roll and pitch are the odometry's own: the pipelines are 2-D)."""
    dh = float(slam["heading"]) - float(odom.heading)
    c, s_ = math.cos(dh), math.sin(dh)
    # NED: p_map = R(dh) p_odom + t  =>  t = p_slam - R(dh) p_odom
    tn = float(slam["x"]) - (c * odom.x - s_ * odom.y)
    te = float(slam["y"]) - (s_ * odom.x + c * odom.y)
    # a turn of dh towards east (about NED down) is a yaw of -dh about ENU up
    return _transform(t_ns, FRAME_MAP, FRAME_ODOM, enu_from_ned((tn, te, 0.0)),
                      quaternion_zyx(0.0, 0.0, -dh))  # fmt: skip


def static_tf(mounts: Mapping[str, MountLike], t_ns: int) -> TFMessage:
    """``/tf_static``: ``base_link`` -> each sensor's frame (named after its device) from its
    mount: ``lever_arm_m`` (body FRD, m, from the vehicle reference point) and ``rpy_deg`` (roll,
    pitch, yaw of the sensor's axes in body FRD, degrees), both written FLU here (REP 103)."""
    out = []
    for device, m in sorted(mounts.items()):
        roll, pitch, yaw = (math.radians(float(a)) for a in m.rpy_deg)
        # Rz(y) Ry(p) Rx(r) between FRD axes is F Rz(y) Ry(p) Rx(r) F = Rz(-y) Ry(-p) Rx(r)
        # between FLU axes (F = diag(1, -1, -1))
        q = quaternion_zyx(roll, -pitch, -yaw)
        out.append(_transform(t_ns, FRAME_BASE, device, flu_from_frd(m.lever_arm_m), q))
    return tf_msg(out)


def static_tf_for_config(config: Mapping[str, Any], t_ns: int) -> TFMessage | None:
    """``/tf_static`` of a gateway configuration (its JSON form): every device's frame under
    ``base_link``, at its ``[ros2.mounts]`` mount, or at the reference point with the vehicle's
    axes for a device with none (so every sensor frame is placed), and the swath frame
    ``<device>_swath`` of each GeoSwath device (raw samples the swath stage turns into swaths re
    the reference point) at the reference point; None without devices."""
    from types import SimpleNamespace

    mounts = dict((config.get("ros2") or {}).get("mounts") or {})
    devices = dict(config.get("devices") or {})
    raw = {dev.format for dev, m in registry.message_types() if "samples" in m.roles}
    devices.update({f"{d}_swath": {} for d, c in list(devices.items())
                    if isinstance(c, Mapping) and c.get("format") in raw})  # fmt: skip
    placed = {
        d: SimpleNamespace(lever_arm_m=tuple(m.get("lever_arm_m", (0.0, 0.0, 0.0))),
                           rpy_deg=tuple(m.get("rpy_deg", (0.0, 0.0, 0.0))))
        for d, m in {**{d: {} for d in devices}, **mounts}.items()
    }  # fmt: skip
    return static_tf(placed, t_ns) if placed else None


class TfTracker:
    """``map`` -> ``odom`` for each SLAM pose (REP 105), from the ROS messages of the bus as they
    pass: odometry remembered (the last ``keep``), a SLAM pose answered with the transform
    against the odometry at or before its stamp. Pure (no bus): the ROS 2 bridge, the Foxglove
    server and the recorder feed it the same messages."""

    def __init__(self, keep: int = 2048) -> None:
        self._t: list[int] = []
        self._odom: list[_Ned] = []
        self._keep = keep

    def feed(self, msgs: list[RosMessage], t_ns: int) -> list[RosMessage]:
        """The ``/tf`` messages ``msgs`` (one sample's) imply; [] for most."""
        out: list[RosMessage] = []
        for m in msgs:
            if m.type == "nav_msgs/msg/Odometry":
                self._t.append(t_ns)
                self._odom.append(_ned_of_pose(m.msg.pose.pose))
                if len(self._t) > self._keep:
                    del self._t[: len(self._t) - self._keep]
                    del self._odom[: len(self._odom) - self._keep]
            elif m.type == "geometry_msgs/msg/PoseWithCovarianceStamped" and self._t:
                i = max(0, bisect.bisect_right(self._t, t_ns) - 1)
                pose = _ned_of_pose(m.msg.pose.pose)
                slam = {"x": pose.x, "y": pose.y, "heading": pose.heading}
                tf = tf_msg([map_odom_tf(slam, self._odom[i], t_ns)])
                out.append(RosMessage("/tf", TF_TYPE, tf))
        return out


class _Ned(NamedTuple):
    x: float  #: north, m
    y: float  #: east, m
    heading: float  #: rad from north towards east


def _ned_of_pose(pose: Pose) -> _Ned:
    """x, y (NED) and heading of a ROS pose (ENU position, FLU -> ENU orientation)."""
    q = pose.orientation
    yaw_enu = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    return _Ned(pose.position.y, pose.position.x, math.pi / 2 - yaw_enu)


#: diagnostic_msgs/DiagnosticStatus levels
DIAG_OK, DIAG_WARN, DIAG_ERROR, DIAG_STALE = 0, 1, 2, 3


def _diag_value(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def diagnostics_msg(status: Mapping[str, object], t_ns: int) -> DiagnosticArray:
    """A component's status JSON as diagnostic_msgs/DiagnosticArray: one DiagnosticStatus per
    gateway device, of the gateway's status or a device's own (name
    ``auvgw/<vehicle>/<device>``, hardware_id its port; OK, WARN when it has bad frames or decode
    errors, ERROR when disconnected, STALE when
    silent past its ``stale_after_s``) or one for a stage (``auvgw/<vehicle>/<component>``, OK;
    STALE once stopped), with every scalar counter as a key-value."""
    kv = _t("diagnostic_msgs/msg/KeyValue")
    ds = _t("diagnostic_msgs/msg/DiagnosticStatus")
    vehicle = str(status.get("vehicle", ""))
    out = []
    devices = status.get("devices")
    if devices is None and "device" in status:  # one device's own status key
        devices = {str(status["device"]): status}
    if isinstance(devices, Mapping):
        for name, d in sorted(devices.items()):
            if not isinstance(d, Mapping):
                continue
            if not d.get("connected", False) and not d.get("ended", False):
                level, text = DIAG_ERROR, f"disconnected: {d.get('last_error') or 'no data'}"
            elif d.get("stale", False):
                level, text = DIAG_STALE, f"silent for {d.get('silent_s')} s"
            elif d.get("bad_frames", 0) or d.get("decode_errors", 0):
                level, text = DIAG_WARN, (f"{d.get('bad_frames', 0)} bad frames, "
                                          f"{d.get('decode_errors', 0)} decode errors")  # fmt: skip
            else:
                rate = d.get("rate_hz")  # None: not known yet (auvgw.health)
                level, text = DIAG_OK, "rate not known yet" if rate is None else f"{rate} Hz"
            values = [kv(key=k, value=_diag_value(v)) for k, v in d.items()
                      if isinstance(v, int | float | str | bool) and v is not None]  # fmt: skip
            out.append(ds(level=level, name=f"auvgw/{vehicle}/{name}", message=text,
                          hardware_id=str(d.get("port", name)), values=values))  # fmt: skip
    else:
        comp = str(status.get("component", "stage"))
        stopped = bool(status.get("stopped", False))
        flat: dict[str, object] = {}
        for k, v in status.items():
            if isinstance(v, Mapping):
                flat.update({f"{k}.{kk}": vv for kk, vv in v.items()})
            else:
                flat[k] = v
        values = [kv(key=k, value=_diag_value(v)) for k, v in flat.items()
                  if isinstance(v, int | float | str | bool)]  # fmt: skip
        out.append(ds(level=DIAG_STALE if stopped else DIAG_OK,
                      name=f"auvgw/{vehicle}/{comp}", message="stopped" if stopped else "running",
                      hardware_id=comp, values=values))  # fmt: skip
    return _t("diagnostic_msgs/msg/DiagnosticArray")(header=_header(t_ns, ""), status=out)


# -- dispatch --------------------------------------------------------------------------------------

# message types by the device registry's roles (auvgw.drivers.registry)
_INS = registry.types_with_role("ins")
_MAG = registry.types_with_role("field")
_SWATH = registry.types_with_role("swath")


def sensor_form(msg: object) -> str | None:
    """The standard ROS 2 form of a decoded sensor message: ``imu`` (sensor_msgs/Imu),
    ``magnetic_field``, ``dvl`` (a twist and a Range), ``points`` (a multibeam PointCloud2),
    ``returns`` (an MSIS scan line's PointCloud2), or None (``auvgw_msgs/Decoded``)."""
    return form_of_type(message_type(msg))


def form_of_type(name: str) -> str | None:
    """:func:`sensor_form` of a decoded type's name (``TYPE``, else the class name)."""
    if name in _INS:
        return "imu"
    if name in _MAG:
        return "magnetic_field"
    if name == "pd0.Ensemble":
        return "dvl"
    if name in _SWATH:
        return "points"
    return "returns" if name == "mtHeadData" else None


def _jsonable(msg: object) -> object:
    from auvgw.drivers.spec import to_jsonable

    if dataclasses.is_dataclass(msg) and not isinstance(msg, type):
        return to_jsonable(msg)
    return msg


def to_ros(
    section: str, source: str, msg: Any, t_ns: int, seq: int = 0, kind: str = ""
) -> list[RosMessage]:
    """The ROS 2 messages of one auvgw message on the bus.

    ``section``: the key section (``sensor``, ``nav``, ``slam``, ``status``, ``truth``);
    ``source``: the device (sensor) or what follows the section in the key (``odometry``,
    ``<pipeline>/pose``, ``gateway``...); ``msg``: the typed message (sensor, Odometry) or the
    parsed JSON body (SLAM, status, truth); ``kind``: the key's last part, naming the topic of a
    message without a standard type.
    """
    if section == "sensor":
        name = message_type(msg)
        form = sensor_form(msg)
        if form == "imu":
            return [
                RosMessage(
                    f"sensor/{source}/imu", "sensor_msgs/msg/Imu", imu_msg(msg, source, t_ns)
                )
            ]
        if form == "magnetic_field":
            return [RosMessage(f"sensor/{source}/magnetic_field", "sensor_msgs/msg/MagneticField",
                               magnetic_field_msg(msg, source, t_ns))]  # fmt: skip
        if form == "dvl":
            return dvl_msgs(msg, source, t_ns)
        if form == "points":
            return [
                RosMessage(
                    f"sensor/{source}/points",
                    "sensor_msgs/msg/PointCloud2",
                    swath_msg(msg, source, t_ns),
                )
            ]
        if form == "returns":
            return [RosMessage(f"sensor/{source}/returns", "sensor_msgs/msg/PointCloud2",
                               scanline_msg(msg, source, t_ns))]  # fmt: skip
        return [
            decoded_msg(
                f"sensor/{source}/{kind or name.lower()}", source, name, t_ns, seq, _jsonable(msg)
            )
        ]
    if section == "nav" and message_type(msg) == "Odometry":
        return [RosMessage(f"nav/{source}", "nav_msgs/msg/Odometry", odometry_msg(msg, t_ns)),
                RosMessage("/tf", TF_TYPE, tf_msg([odom_tf(msg, t_ns)]))]  # fmt: skip
    if section == "slam" and isinstance(msg, Mapping):
        if source.endswith("/pose") and "x" in msg:
            return [RosMessage(f"slam/{source}", "geometry_msgs/msg/PoseWithCovarianceStamped",
                               slam_pose_msg(msg, t_ns))]  # fmt: skip
        if source.endswith("/landmarks") and "mean" in msg:
            return [
                RosMessage(
                    f"slam/{source}", "sensor_msgs/msg/PointCloud2", landmarks_msg(msg, t_ns)
                )
            ]
    body = _jsonable(msg)
    type_name = body.get("type", section) if isinstance(body, Mapping) else section
    return [decoded_msg(f"{section}/{source}", source, str(type_name), t_ns, seq, body)]
