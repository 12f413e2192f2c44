"""``auvgw ros2``: the vehicle on ROS 2 (rmw_zenoh_cpp), live.

    auvgw ros2 bridge [--vehicle auv1] [--domain-id 0] [--namespace /fleet] [--mounts M.json]
                      [--commands actuators]
    auvgw ros2 list [--domain-id 0]
    auvgw ros2 echo /auv1/sensor/ins/imu [--count 5]

``bridge`` republishes the vehicle's decoded sensors, odometry, SLAM outputs and status as a
ROS 2 node on rmw_zenoh would (data keys, CDR, attachments, liveliness tokens), with ``/tf``,
``/tf_static`` (``--mounts``: a JSON object device -> ``{"lever_arm_m": [x, y, z],
"rpy_deg": [r, p, y]}``, body FRD) and ``/diagnostics``; ``--commands DEVICE`` (repeatable)
takes that device's commands from ROS 2 (``<namespace>/<vehicle>/cmd/<device>``,
``auvgw_msgs/msg/ActuatorCommand``) onto the bus command key, where the gateway checks them;
``auvgw run`` does the same in the gateway with ``[ros2] enabled = true``. ``list`` prints the
ROS 2 graph of a domain as ``ros2 node list`` and ``ros2 topic list -t`` would; ``echo`` prints a
topic's messages. All three
join the bus with the usual options (``--connect``, default the local router's endpoint); a ROS 2
node on rmw_zenoh reaches them through the same router. See docs/ros2.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from auvgw.commands.common import SubParsers, UserError, add_command, add_duration

if TYPE_CHECKING:
    from auvgw.stages.ros2 import Ros2BridgeConfig


def register(sub: SubParsers) -> None:
    from auvgw.bus import add_bus_arguments

    p = add_command(sub, "ros2", __doc__)
    verbs = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    b = verbs.add_parser("bridge", help="republish the vehicle's bus as a ROS 2 node")
    b.add_argument("--vehicle", default="auv1", help="vehicle name (default auv1)")
    b.add_argument("--mounts", type=Path, default=None, metavar="JSON",
                   help="sensor mounts for /tf_static (device: lever_arm_m, rpy_deg)")  # fmt: skip
    b.add_argument("--node", default="auvgw_bridge", help="ROS node name")
    b.add_argument("--commands", action="append", default=[], metavar="DEVICE",
                   help="take DEVICE's commands from ROS 2 (repeatable; default none)")  # fmt: skip
    add_duration(b)
    lst = verbs.add_parser("list", help="the ROS 2 graph: nodes, topics and their types")
    e = verbs.add_parser("echo", help="print a topic's messages")
    e.add_argument("topic", help="fully qualified topic, e.g. /auv1/sensor/ins/imu")
    e.add_argument("--count", type=int, default=1, help="messages to print (default 1)")
    e.add_argument("--timeout", type=float, default=10.0, metavar="S", help="give up after S s")
    for q in (b, lst, e):
        q.add_argument("--domain-id", type=int, default=0, help="ROS_DOMAIN_ID (default 0)")
        if q is b:
            q.add_argument("--namespace", default="", help="ROS namespace (default none)")
        add_bus_arguments(q)
    p.set_defaults(func=run)


def bridge_config(args: argparse.Namespace) -> Ros2BridgeConfig:
    """The bridge's settings from the options (``--mounts`` read); a :class:`UserError` naming
    the file or option that is wrong."""
    from pydantic import ValidationError

    from auvgw.ground.errors import format_validation_error
    from auvgw.stages.ros2 import Ros2BridgeConfig

    mounts: Any = {}
    if args.mounts is not None:
        try:
            mounts = json.loads(args.mounts.read_text())
        except (OSError, ValueError) as exc:
            raise UserError(f"{args.mounts}: cannot read the mounts: {exc}") from None
    try:
        return Ros2BridgeConfig(
            vehicle=args.vehicle, domain_id=args.domain_id, namespace=args.namespace,
            node=args.node, mounts=mounts, enabled=True, commands=getattr(args, "commands", []),
        )  # fmt: skip
    except ValidationError as exc:
        raise UserError(format_validation_error(exc)) from None


def run(args: argparse.Namespace) -> int:
    from auvgw.bus import bus_from_args, open_cli_session

    if args.verb == "bridge":
        from auvgw.commands.run import serve_stage
        from auvgw.stages.ros2 import Ros2Bridge

        cfg = bridge_config(args)
        serve_stage(
            args,
            lambda session: Ros2Bridge(cfg, session),
            lambda st: (f"ros2 bridge running: vehicle {cfg.vehicle} as node "
                        f"{cfg.namespace}/{cfg.node} in ROS domain {cfg.domain_id}"),
            lambda st: st.input_keys(),
        )
        return 0
    if not 0 <= args.domain_id <= 232:
        raise UserError(f"--domain-id must be 0-232, got {args.domain_id}")
    try:
        bus = bus_from_args(args)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    session = open_cli_session(bus)
    try:
        from auvgw.ros2_graph import Ros2Graph

        graph = Ros2Graph(session, args.domain_id)
        if args.verb == "list":
            ents = graph.entities()
            for node in sorted({e.node_name for e in ents if e.kind == "NN"}):
                print(node)
                for e in ents:
                    if e.node_name == node and e.kind in ("MP", "MS"):
                        role = "publishes" if e.kind == "MP" else "subscribes"
                        print(f"  {role} {e.topic} [{e.type}] {e.type_hash}")
            return 0
        if args.count < 1:
            raise UserError("--count must be at least 1")
        try:
            got = graph.echo(args.topic, args.count, args.timeout)
        except LookupError as exc:
            raise UserError(str(exc)) from None
        for m in got:
            print(json.dumps({"seq": m.seq, "source_timestamp_ns": m.source_timestamp_ns,
                              "msg": _plain(m.msg)}))  # fmt: skip
        return 0 if len(got) == args.count else 1
    finally:
        session.close()


def _plain(msg: Any) -> Any:
    """A rosbags message as JSON-ready values."""
    import numpy as np

    if hasattr(msg, "__msgtype__"):
        return {k: _plain(getattr(msg, k)) for k in msg.__dataclass_fields__ if k != "__msgtype__"}
    if isinstance(msg, np.ndarray):
        return msg.tolist() if msg.size <= 64 else f"<{msg.size} values>"
    if isinstance(msg, list | tuple):
        return [_plain(v) for v in msg]
    return msg
