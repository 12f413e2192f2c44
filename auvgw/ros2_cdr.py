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

import struct
from collections.abc import Iterator
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from auvgw import ros2

if TYPE_CHECKING:
    import numpy as np

    from auvgw.drivers import pd0
    from auvgw.drivers.roles import Field, Ins

__all__ = ["ENCAPSULATION", "cdr_struct", "sensor_cdr"]

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


def _stamp(t_ns: int, frame: str) -> tuple[int, bytes, tuple[int | bytes, ...]]:
    """(len(frame), its bytes, the header's packed values) of a ``std_msgs/Header``.

    ``builtin_interfaces/Time.sec`` is an int32: a stamp outside 1901-2038 raises ValueError."""
    if not -(2**31) * 1_000_000_000 <= t_ns < 2**31 * 1_000_000_000:
        raise ValueError(f"stamp {t_ns} ns is outside builtin_interfaces/Time's int32 seconds "
                         "(1901-12-13 to 2038-01-19 UTC)")
    f = frame.encode()
    return len(f), f, (ENCAPSULATION, t_ns // 1_000_000_000, t_ns % 1_000_000_000, len(f) + 1, f)


def _imu(msg: Ins, device: str, t_ns: int) -> bytes:
    n, _, head = _stamp(t_ns, device)
    q = ros2.quaternion_enu_flu(msg.heading, msg.pitch, msg.roll)
    return cdr_struct("sensor_msgs/msg/Imu", (n,)).pack(
        *head, *q, *_Z9,
        *ros2.flu_from_frd((msg.rate_x, msg.rate_y, msg.rate_z)), *_Z9,
        *ros2.flu_from_frd((msg.accel_x, msg.accel_y, msg.accel_z)), *_Z9,
    )  # fmt: skip


def _magnetic_field(msg: Field, device: str, t_ns: int) -> bytes:
    n, _, head = _stamp(t_ns, device)
    b = ros2.flu_from_frd((msg.bx, msg.by, msg.bz))
    return cdr_struct("sensor_msgs/msg/MagneticField", (n,)).pack(
        *head, b[0] * 1e-9, b[1] * 1e-9, b[2] * 1e-9, *_Z9
    )


def _cloud(t_ns: int, frame: str, xyz: np.ndarray, intensity: np.ndarray | None) -> bytes:
    import numpy as np

    rows = ros2.cloud_points(xyz, intensity)
    n, _, head = _stamp(t_ns, frame)
    count = len(rows)
    fields = [v for off, name in _CLOUD_FIELDS for v in (len(name) + 1, name, off, _FLOAT32, 1)]
    return cdr_struct("sensor_msgs/msg/PointCloud2", (n, 4, 1, 1, 1, 9, 16 * count)).pack(
        *head, 1, count, 4, *fields, False, 16, 16 * count, 16 * count, rows.tobytes(),
        bool(np.isfinite(rows).all()),
    )  # fmt: skip


def _dvl(msg: pd0.Ensemble, device: str, t_ns: int) -> list[tuple[str, str, bytes]]:
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


def sensor_cdr(source: str, msg: Any, t_ns: int) -> list[tuple[str, str, bytes]] | None:
    """(topic, ROS type, CDR bytes) of each ROS 2 message of a decoded sensor message, byte for
    byte what ``serialize`` of :func:`auvgw.ros2.to_ros`'s messages gives (same topics, same
    order); None for a message with no standard form (``auvgw_msgs/Decoded``: use ``to_ros``)."""
    form = ros2.sensor_form(msg)
    if form == "imu":
        return [(f"sensor/{source}/imu", "sensor_msgs/msg/Imu", _imu(msg, source, t_ns))]
    if form == "magnetic_field":
        return [(f"sensor/{source}/magnetic_field", "sensor_msgs/msg/MagneticField",
                 _magnetic_field(msg, source, t_ns))]  # fmt: skip
    if form == "dvl":
        return _dvl(msg, source, t_ns)
    if form == "points":
        return [(f"sensor/{source}/points", "sensor_msgs/msg/PointCloud2",
                 _cloud(t_ns, source, *ros2.swath_points(msg)))]  # fmt: skip
    if form == "returns":
        return [(f"sensor/{source}/returns", "sensor_msgs/msg/PointCloud2",
                 _cloud(t_ns, source, *ros2.scanline_points(msg)))]  # fmt: skip
    return None
