"""CDR bytes of the bridged sensor messages without building rosbags objects (docs/ros2.md#cost).

The ROS 2 bridge's conversion (:func:`auvgw.ros2.to_ros`: a rosbags message object, a dozen nested
dataclasses) and its CDR serialisation (``Typestore.serialize_cdr``: a size pass, then a write
pass) cost about 11 us per ``sensor_msgs/Imu`` and 40-60 us per PointCloud2 here, most of the
bridge's Python time when a ROS 2 node watches every topic. This module writes the same bytes with
one :class:`struct.Struct` per message type and string/sequence lengths, compiled once from the
type's definition in the rosbags type store (:func:`cdr_struct`: CDR's alignment of each primitive
to its size from the start of the payload, strings as ``uint32`` length with the NUL, sequences as
``uint32`` count and their elements), the way the project's codecs compile their tables. The
values are computed by the same helpers as :mod:`auvgw.ros2` (frames, quaternions, point rows),
so the two stay equal: ``tests/test_ros2.py`` checks the bytes against rosbags' for every sensor
form.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from auvgw import ros2
from auvgw.decoding import message_type
from auvgw.ground.geometry import quaternion_zyx

if TYPE_CHECKING:
    from auvgw.drivers import pd0
    from auvgw.drivers.roles import Field, Ins

__all__ = ["ENCAPSULATION", "cdr_struct", "sensor_cdr", "sensor_writer"]

#: CDR little endian (``CDR_LE``), no options: the 4 bytes before every payload
ENCAPSULATION = b"\x00\x01\x00\x00"

#: rosbags' primitive type -> struct code (little endian, no implicit alignment: ``<``)
_CODES = {"bool": "?", "byte": "B", "char": "B", "int8": "b", "uint8": "B", "int16": "h",
          "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
          "float32": "f", "float64": "d"}  # fmt: skip
# rosbags' node kinds (rosbags.interfaces.Nodetype)
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4


@lru_cache(maxsize=512)
def cdr_struct(ros_type: str, sizes: tuple[int, ...]) -> struct.Struct:
    """The :class:`struct.Struct` of a whole CDR message of ``ros_type`` (encapsulation header
    included, little endian): ``sizes`` gives, in field order, the byte length of each string
    (without its NUL) and the count of each sequence. Packing takes the encapsulation bytes,
    then every field in order: a primitive as itself, a fixed array as its elements, a string as
    its length + 1 and its bytes, a sequence as its count then its elements (a ``uint8``
    sequence: its count and its bytes). A ``ValueError`` when ``sizes`` does not fit the type."""
    fielddefs = ros2.typestore().fielddefs
    parts = ["<4s"]
    pos = 0  # offset from the start of the payload (CDR aligns against it)
    it: Iterator[int] = iter(sizes)

    def align(n: int) -> None:
        nonlocal pos
        pad = -pos % n
        if pad:
            parts.append(f"{pad}x")
            pos += pad

    def size(what: str) -> int:
        try:
            return next(it)
        except StopIteration:
            raise ValueError(f"{ros_type}: sizes {sizes} end before {what}") from None

    def prim(name: str, count: int = 1) -> None:
        nonlocal pos
        if name == "string":
            for _ in range(count):
                n = size("a string")
                align(4)
                parts.append(f"I{n + 1}s")
                pos += 5 + n
            return
        code = _CODES[name]
        width = struct.calcsize(code)
        align(width)
        parts.append(f"{count}{code}" if count != 1 else code)
        pos += width * count

    def node(kind: int, detail: Any) -> None:
        nonlocal pos
        if kind == _BASE:
            prim(detail[0])
        elif kind == _NAME:
            for _name, (k, d) in fielddefs[detail][1]:
                node(k, d)
        elif kind == _ARRAY:
            (sub_kind, sub), count = detail
            if sub_kind == _BASE:
                prim(sub[0], count)
            else:
                for _ in range(count):
                    node(sub_kind, sub)
        elif kind == _SEQUENCE:
            (sub_kind, sub), _bound = detail
            n = size("a sequence")
            align(4)
            parts.append("I")
            pos += 4
            if sub_kind == _BASE and sub[0] in ("uint8", "byte", "char"):
                parts.append(f"{n}s")
                pos += n
            elif sub_kind == _BASE and n:
                prim(sub[0], n)
            else:
                for _ in range(n):
                    node(sub_kind, sub)
        else:
            raise ValueError(f"{ros_type}: field kind {kind} unknown")

    node(_NAME, ros_type)
    if next(it, None) is not None:
        raise ValueError(f"{ros_type}: sizes {sizes} longer than its strings and sequences")
    return struct.Struct("".join(parts))


_Z9 = (0.0,) * 9
_Z36 = (0.0,) * 36
_BAD36 = (-1.0,) + (0.0,) * 35  # a twist covariance marked invalid (no bottom lock)
_INF = float("inf")
#: PointField names of :func:`auvgw.ros2.cloud_points`' rows and their CDR values
_CLOUD_FIELDS = tuple((4 * i, c.encode()) for i, c in enumerate(("x", "y", "z", "intensity")))
_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
#: the four PointFields as packed: (name length + 1, name, offset, datatype, count) each
_CLOUD_FIELD_VALUES = tuple(v for off, name in _CLOUD_FIELDS
                            for v in (len(name) + 1, name, off, _FLOAT32, 1))  # fmt: skip


def _seconds(t_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` (sec, nanosec) of a stamp; its ``sec`` is an int32: a stamp
    outside 1901-2038 raises ValueError."""
    if not -(2**31) * 1_000_000_000 <= t_ns < 2**31 * 1_000_000_000:
        raise ValueError(f"stamp {t_ns} ns is outside builtin_interfaces/Time's int32 seconds "
                         "(1901-12-13 to 2038-01-19 UTC)")
    return divmod(t_ns, 1_000_000_000)


def _stamp(t_ns: int, frame: str) -> tuple[int, bytes, tuple[int | bytes, ...]]:
    """(len(frame), its bytes, the header's packed values) of a ``std_msgs/Header``."""
    f = frame.encode()
    return len(f), f, (ENCAPSULATION, *_seconds(t_ns), len(f) + 1, f)


#: what a writer gives for one decoded message: (topic, ROS type, CDR) per ROS 2 message
Out = list[tuple[str, str, bytes]]
Writer = Callable[[Any, int], Out]
_IMU, _FIELD = "sensor_msgs/msg/Imu", "sensor_msgs/msg/MagneticField"
_HALF_PI = math.pi / 2


def _imu_writer(source: str) -> Writer:
    """``sensor_msgs/Imu`` of an INS solution, frame ``source``: :func:`auvgw.ros2.imu_msg`'s
    values (:func:`auvgw.ros2.quaternion_enu_flu`, :func:`auvgw.ros2.flu_from_frd`) written out
    on the message's fields, with the topic, frame and struct bound once per device."""
    topic, frame = f"sensor/{source}/imu", source.encode()
    pack, n = cdr_struct(_IMU, (len(frame),)).pack, len(frame) + 1

    def write(msg: Ins, t_ns: int) -> Out:
        q = quaternion_zyx(msg.roll, -msg.pitch, _HALF_PI - msg.heading)  # ENU <- FLU
        return [(topic, _IMU, pack(
            ENCAPSULATION, *_seconds(t_ns), n, frame, *q, *_Z9,
            float(msg.rate_x), -float(msg.rate_y), -float(msg.rate_z), *_Z9,  # FLU <- FRD
            float(msg.accel_x), -float(msg.accel_y), -float(msg.accel_z), *_Z9,
        ))]  # fmt: skip

    return write


def _field_writer(source: str) -> Writer:
    """``sensor_msgs/MagneticField`` (tesla, FLU) of a field sample (nT, FRD), frame
    ``source`` (:func:`auvgw.ros2.magnetic_field_msg`'s values)."""
    topic, frame = f"sensor/{source}/magnetic_field", source.encode()
    pack, n = cdr_struct(_FIELD, (len(frame),)).pack, len(frame) + 1

    def write(msg: Field, t_ns: int) -> Out:
        return [(topic, _FIELD, pack(
            ENCAPSULATION, *_seconds(t_ns), n, frame,
            float(msg.bx) * 1e-9, -float(msg.by) * 1e-9, -float(msg.bz) * 1e-9, *_Z9,
        ))]  # fmt: skip

    return write


def _cloud(t_ns: int, frame: str, rows: np.ndarray) -> bytes:
    """A PointCloud2 of :func:`auvgw.ros2.cloud_points` rows."""
    n, _, head = _stamp(t_ns, frame)
    count = len(rows)
    # is_dense: every value finite, i.e. their float64 sum is (float32 values cannot overflow it)
    return cdr_struct("sensor_msgs/msg/PointCloud2", (n, 4, 1, 1, 1, 9, 16 * count)).pack(
        *head, 1, count, 4, *_CLOUD_FIELD_VALUES, False, 16, 16 * count, 16 * count,
        rows.tobytes(), math.isfinite(rows.sum(dtype=np.float64)),
    )  # fmt: skip


def _dvl(msg: pd0.Ensemble, device: str, t_ns: int) -> Out:
    d = ros2.dvl_reading(msg, device)
    if d is None:
        return []
    n, _, head = _stamp(t_ns, d.frame)
    twist = cdr_struct("geometry_msgs/msg/TwistWithCovarianceStamped", (n,)).pack(
        *head, *d.velocity, 0.0, 0.0, 0.0, *(_Z36 if d.bottom_lock else _BAD36)
    )
    n, _, head = _stamp(t_ns, device)
    rng = cdr_struct("sensor_msgs/msg/Range", (n,)).pack(
        *head, 0, d.field_of_view, 0.0, _INF, d.altitude  # radiation_type ULTRASOUND
    )
    return [(f"sensor/{device}/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", twist),
            (f"sensor/{device}/altitude", "sensor_msgs/msg/Range", rng)]  # fmt: skip


def _cloud_writer(source: str, form: str) -> Writer:
    """A ``PointCloud2`` (topic ``sensor/<source>/<form>``) of a multibeam ping (``points``)
    or an MSIS scan line (``returns``)."""
    topic = f"sensor/{source}/{form}"
    points = ros2.swath_points if form == "points" else ros2.scanline_points
    return lambda msg, t_ns: [(topic, "sensor_msgs/msg/PointCloud2",
                               _cloud(t_ns, source, points(msg)))]  # fmt: skip


@lru_cache(maxsize=1024)
def sensor_writer(source: str, type_name: str) -> Writer | None:
    """The writer of decoded messages of type ``type_name`` from device ``source`` (None for a
    type with no standard form), made once per pair: :func:`sensor_cdr` calls it."""
    form = ros2.form_of_type(type_name)
    if form == "imu":
        return _imu_writer(source)
    if form == "magnetic_field":
        return _field_writer(source)
    if form == "dvl":
        return lambda msg, t_ns: _dvl(msg, source, t_ns)
    if form in ("points", "returns"):
        return _cloud_writer(source, form)
    return None


def sensor_cdr(source: str, msg: Any, t_ns: int) -> Out | None:
    """(topic, ROS type, CDR bytes) of each ROS 2 message of a decoded sensor message, byte for
    byte what ``serialize`` of :func:`auvgw.ros2.to_ros`'s messages gives (same topics, same
    order); None for a message with no standard form (``auvgw_msgs/Decoded``: use ``to_ros``)."""
    write = sensor_writer(source, message_type(msg))
    return None if write is None else write(msg, t_ns)
