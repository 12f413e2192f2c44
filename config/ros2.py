"""The ``[ros2]`` table of a gateway configuration: the vehicle on ROS 2 (rmw_zenoh), live.

    [ros2]
    enabled = true          # off by default
    domain_id = 0           # ROS_DOMAIN_ID
    namespace = "/fleet"    # ROS namespace of the node and every topic ("" for none)
    node = "auvgw_bridge"   # the node's name
    commands = ["actuators"]  # devices taking commands from ROS 2 (default none)
    batch_ms = 100          # the gateway's sensor messages gathered this long, sent together

    [ros2.mounts.dvl]       # one per sensor: /tf_static base_link -> dvl
    lever_arm_m = [0.5, 0.0, 0.2]   # body FRD (x forward, y starboard, z down), m
    rpy_deg = [0.0, 0.0, 45.0]      # roll, pitch, yaw of the sensor's axes in body FRD, deg

See docs/ros2.md; :class:`auvgw.stages.ros2.Ros2Bridge` is what runs.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["FoxgloveConfig", "Mount", "Ros2Config"]

_NAME = r"[A-Za-z][A-Za-z0-9_]*"
_Metres = Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)]
_Degrees = Annotated[float, Field(ge=-360.0, le=360.0, allow_inf_nan=False)]


class Mount(BaseModel):
    """A sensor's mount on the vehicle: ``lever_arm_m`` (body FRD, m, from the vehicle reference
    point) and ``rpy_deg`` (roll, pitch, yaw of the sensor's axes in body FRD, degrees)."""

    model_config = ConfigDict(extra="forbid")

    lever_arm_m: tuple[_Metres, _Metres, _Metres] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[_Degrees, _Degrees, _Degrees] = (0.0, 0.0, 0.0)


class Ros2Config(BaseModel):
    """``enabled``: run the ROS 2 bridge in the gateway; ``domain_id``: ``ROS_DOMAIN_ID``
    (0-232); ``namespace``: ``""`` or ``/name[/name...]``; ``node``: the node's name;
    ``mounts``: device -> :class:`Mount` (``/tf_static``); ``static_period_s``: s between
    ``/tf_static`` repeats; ``commands``: the gateway devices whose commands a ROS 2 node may
    send (a subscription on ``<namespace>/<vehicle>/cmd/<device>``, each message put on the bus
    command key, where the gateway's gate checks it; none by default: opt-in); ``batch_ms``:
    ms the bridge in the gateway gathers sensor messages before it converts and sends them
    together: a ROS 2 subscriber sees them up to this much later (about 60 ms at the median at
    100), and the bridge's worker runs once per window, each run paying for code and data gone
    cold since the last, which is most of its cost (at 10x, every topic watched, paired: the
    gateway's CPU 1.18-1.19x at 20 ms, 1.07-1.11x at 100: docs/ros2.md#cost); 0: each message on
    its own."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(False, strict=True)
    domain_id: int = Field(0, ge=0, le=232, strict=True)
    namespace: str = Field("", pattern=rf"^(/{_NAME})*$", max_length=200)
    node: str = Field("auvgw_bridge", pattern=rf"^{_NAME}$", max_length=100)
    mounts: dict[str, Mount] = Field(default_factory=dict, max_length=64)
    static_period_s: float = Field(1.0, ge=0.1, le=3600.0, allow_inf_nan=False)
    batch_ms: float = Field(100.0, ge=0.0, le=200.0, allow_inf_nan=False)
    commands: list[Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_-]*$", max_length=64)]] = (
        Field(default_factory=list, max_length=16))


class FoxgloveConfig(BaseModel):
    """The ``[foxglove]`` table: ``enabled``: serve the bus to the Foxglove app from the gateway
    over the Foxglove WebSocket protocol on ``host:port`` (the mounts of ``[ros2.mounts]`` give
    its ``/tf_static``). ``auvgw foxglove`` does the same as its own process."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(False, strict=True)
    host: str = Field("127.0.0.1", min_length=1, max_length=253)
    port: int = Field(8765, ge=0, le=65535, strict=True)
