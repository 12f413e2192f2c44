"""``auvgw foxglove``: serve the vehicle's bus to the Foxglove app, live.

    auvgw foxglove [--vehicle auv1] [--host 127.0.0.1] [--port 8765] [--mounts M.json]

A Foxglove WebSocket server (the ``foxglove-sdk`` package) on ``ws://HOST:PORT``: open it in the
Foxglove app ("Open connection", Foxglove WebSocket) and load ``config/foxglove-layout.json``. One
channel per ROS 2 topic with the recordings' schemas (``ros2msg``, ``cdr``): the vehicle's
sensors, odometry, SLAM outputs, ``/tf``, ``/tf_static`` (``--mounts``) and ``/diagnostics``.
``auvgw run`` serves the same with ``[foxglove] enabled = true``. Prints ``foxglove running:
ws://HOST:PORT`` once it takes clients (``--port 0``: a free port). See docs/ros2.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from auvgw.commands.common import SubParsers, add_command, add_duration


def register(sub: SubParsers) -> None:
    from auvgw.bus import add_bus_arguments

    p = add_command(sub, "foxglove", __doc__)
    p.add_argument("--vehicle", default="auv1", help="vehicle name (default auv1)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: any free)")
    p.add_argument("--mounts", type=Path, default=None, metavar="JSON",
                   help="sensor mounts for /tf_static (device: lever_arm_m, rpy_deg)")  # fmt: skip
    add_duration(p)
    add_bus_arguments(p)
    p.set_defaults(func=run, namespace="", domain_id=0, node="auvgw_bridge")


def run(args: argparse.Namespace) -> int:
    from auvgw.commands.ros2 import bridge_config
    from auvgw.commands.run import serve_stage
    from auvgw.stages.foxglove import FoxgloveStage

    cfg = bridge_config(args)
    serve_stage(
        args,
        lambda session: FoxgloveStage(cfg, session, host=args.host, port=args.port),
        lambda st: f"foxglove running: ws://{st.host}:{st.port}",
        lambda st: st.input_keys(),
    )
    return 0
