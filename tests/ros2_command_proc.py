"""A ROS 2 publisher of actuator commands on rmw_zenoh, written from rmw_zenoh's docs/design.md
alone (no auvgw key or token helper): what a ROS 2 node with ``rmw_zenoh_cpp`` puts on Zenoh.

``python ros2_command_proc.py ENDPOINT TOPIC N RPM RUDDER STERN`` joins the bus at ENDPOINT as
node ``/commander`` of ROS domain 0 (its ``NN`` token and the ``MP`` token of TOPIC), waits for a
subscription of TOPIC in the graph (an ``MS`` token; it prints ``subscription <type hash>``) and
for Zenoh to match its publisher, then publishes commands ``seq`` 1..N (RPM rpm, RUDDER and STERN
rad) at 20 Hz, CDR with the attachment (sequence number, source time, GID), and prints
``sent N``. Then one out of the DBC's range (seq N+1, 9999 rpm), one stale (seq N again) and one
sample that is no CDR at all, ``done``, and it stays on the bus until SIGTERM/SIGINT.

The message definition is the one a ROS 2 user builds in the ``auvgw_msgs`` package
(:data:`auvgw.ros2.ACTUATOR_COMMAND_MSG`); its RIHS01 hash is computed here with rosbags.
"""

from __future__ import annotations

import hashlib
import struct
import sys
import threading
import time

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from auvgw.bus import open_session
from auvgw.commands.common import handle_stop_signals
from auvgw.config.bus import BusConfig
from auvgw.ros2 import ACTUATOR_COMMAND_MSG

ROS_TYPE = "auvgw_msgs/msg/ActuatorCommand"
DDS_TYPE = "auvgw_msgs::msg::dds_::ActuatorCommand_"  # "<pkg>::msg::dds_::<Name>_"


def main() -> int:
    endpoint, topic, n, rpm, rudder, stern = sys.argv[1:]
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(ACTUATOR_COMMAND_MSG, ROS_TYPE))
    type_hash = store.hash_rihs01(ROS_TYPE)
    Cmd = store.types[ROS_TYPE]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    mangled = topic.replace("/", "%")  # names in tokens: '/' -> '%'
    key = f"0/{topic.strip('/')}/{DDS_TYPE}/{type_hash}"  # <domain>/<topic>/<type>/<hash>
    stop = threading.Event()
    with open_session(BusConfig(mode="peer", connect=[endpoint])) as s, handle_stop_signals(stop):
        zid = str(s.zid())
        lv = s.liveliness()
        node = lv.declare_token(f"@ros2_lv/0/{zid}/0/0/NN/%/%/commander")
        # reliable, volatile, keep last 10: '' for rmw_zenoh's defaults, depth 10
        mp_token = (f"@ros2_lv/0/{zid}/0/1/MP/%/%/commander/{mangled}/{DDS_TYPE}/{type_hash}/"
                    "::,10:,:,:,,")  # fmt: skip
        mp = lv.declare_token(mp_token)
        gid = hashlib.sha256(mp_token.encode()).digest()[:16]
        found = ""
        while not found and not stop.is_set():
            for r in lv.get("@ros2_lv/0/**", timeout=1.0):
                parts = str(r.ok.key_expr).split("/") if r.ok is not None else []
                if len(parts) == 13 and parts[5] == "MS" and parts[9] == mangled:
                    found = parts[11]
        print(f"subscription {found}", flush=True)
        pub = s.declare_publisher(key)
        while not pub.matching_status.matching and not stop.wait(0.01):
            pass
        seq = 0

        def put(data: bytes) -> None:
            nonlocal seq
            seq += 1  # the attachment's sequence number: every message of this publisher
            now = time.time_ns()
            pub.put(data, attachment=struct.pack("<qq16s", seq, now, gid))

        def cmd(s_: int, rpm_: float) -> bytes:
            now = time.time_ns()
            stamp = Time(sec=now // 1_000_000_000, nanosec=now % 1_000_000_000)
            m = Cmd(header=Header(stamp=stamp, frame_id="base_link"), seq=s_,
                    shaft_rpm=rpm_, rudder=float(rudder), stern=float(stern))  # fmt: skip
            return bytes(store.serialize_cdr(m, ROS_TYPE))

        for i in range(1, int(n) + 1):
            put(cmd(i, float(rpm)))
            if stop.wait(0.05):  # 20 Hz: the pace of a controller, not a wait for a condition
                break
        print(f"sent {n}", flush=True)
        put(cmd(int(n) + 1, 9999.0))  # out of the DBC's +-1600 rpm
        put(cmd(int(n), float(rpm)))  # stale: not after the last one forwarded
        put(b"\x00\x01\x00\x00\x07")  # a CDR header and one byte: no command
        print("done", flush=True)
        stop.wait()
        for d in (pub, mp, node):
            d.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
