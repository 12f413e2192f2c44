"""The vehicle on ROS 2, live (issue 32): ``auvgw sim`` + ``auvgw run`` (its ``[ros2]`` bridge on)
+ ``auvgw fusion``, each its own process, seen by a ROS 2 graph reader written from rmw_zenoh's
design document alone (auvgw.ros2_graph): it lists every topic with its standard type and hash,
and echoes an Imu, an Odometry, a TFMessage and a DiagnosticArray; ``auvgw ros2 list`` prints the
same graph."""

from __future__ import annotations

import math
import signal
import subprocess
from pathlib import Path

import zenoh

from auvgw import ros2
from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
from auvgw.rmw_zenoh import type_hash
from auvgw.ros2 import ACTUATOR_COMMAND_TYPE as CMD_TYPE
from auvgw.ros2_graph import Ros2Graph
from auvgw.testing import AUVGW, PYTHON, REPO, wait_until

SCENARIO = str(REPO / "config" / "scenarios" / "harbour.json")

ROS2_TABLE = """
[ros2]
enabled = true
namespace = "/fleet"

[ros2.mounts.dvl]
lever_arm_m = [0.5, 0.0, 0.2]
rpy_deg = [0.0, 0.0, 45.0]

[ros2.mounts.ins]
"""

WANTED = {
    "/fleet/auv1/sensor/ins/imu": "sensor_msgs/msg/Imu",
    "/fleet/auv1/sensor/dvl/twist": "geometry_msgs/msg/TwistWithCovarianceStamped",
    "/fleet/auv1/sensor/magnetometer/magnetic_field": "sensor_msgs/msg/MagneticField",
    "/fleet/auv1/nav/odometry": "nav_msgs/msg/Odometry",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def test_a_ros2_graph_reader_sees_the_vehicle(procs, tmp_path: Path):
    sim = procs.start([AUVGW, "sim", "--scenario", SCENARIO, "--speed", "2", "--out",
                       str(tmp_path / "sim"), "--start-delay", "2"], "sim")
    cfg = sim.wait_line("gateway config:", timeout=60).split(":", 1)[1].strip()
    with open(cfg, "a") as f:  # the deployed way: the gateway's own [ros2] table
        f.write(ROS2_TABLE)
    gw = procs.start([AUVGW, "run", "--config", cfg], "gateway")
    fusion = procs.start([AUVGW, "fusion"], "fusion")
    mounts = tmp_path / "mounts.json"
    mounts.write_text('{"multibeam": {"lever_arm_m": [0.2, 0.0, 0.4]}}')
    fox = procs.start([AUVGW, "foxglove", "--port", "0", "--mounts", str(mounts)], "foxglove")
    try:
        fusion.wait_line("fusion running", timeout=60)
        url = fox.wait_line("foxglove running:", timeout=60).split(": ", 1)[1].strip()
        with open_session(BusConfig().as_spoke()) as s:
            graph = Ros2Graph(s, domain_id=0)
            seen: dict[str, tuple[str, str]] = {}

            def missing() -> list[str]:
                seen.update(graph.topics(1.0))
                return sorted(set(WANTED) - set(seen))

            try:
                wait_until(lambda: not missing(), timeout=120, what="the bridge's topics")
            except AssertionError:
                raise AssertionError(f"never published: {missing()}; seen {sorted(seen)}") from None
            topics = graph.topics(1.0)
            assert not graph.unparsed, graph.unparsed
            for topic, ros_type in WANTED.items():
                assert topics[topic] == (ros_type, type_hash(ros_type)), topic
            assert "/fleet/auvgw_bridge" in graph.nodes(1.0)
            # every topic a ROS name (no '-' from 'vb-aufastslam' and the like)
            assert all(all(c.isalnum() or c in "_/" for c in t) for t in topics), topics

            imu = graph.echo("/fleet/auv1/sensor/ins/imu", count=3, timeout_s=60)
            assert len(imu) == 3 and [m.seq for m in imu] == sorted(m.seq for m in imu)
            q = imu[-1].msg.orientation
            assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, rel_tol=1e-6)
            assert imu[-1].msg.header.frame_id == "ins"
            assert imu[-1].source_timestamp_ns > 0 and len(imu[-1].gid) == 16

            odo = graph.echo("/fleet/auv1/nav/odometry", count=2, timeout_s=60)
            o = odo[-1].msg
            assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_link")
            speed = math.hypot(o.twist.twist.linear.x, o.twist.twist.linear.y)
            assert 0.3 < speed < 5.0, speed  # the harbour vehicle's cruise, not zero or garbage

            tf = graph.echo("/tf", count=5, timeout_s=60)
            pairs = {(t.header.frame_id, t.child_frame_id) for m in tf for t in m.msg.transforms}
            assert ("odom", "base_link") in pairs, pairs
            static = graph.echo("/tf_static", count=1, timeout_s=30)[0].msg
            assert {(t.header.frame_id, t.child_frame_id) for t in static.transforms} == {
                ("base_link", "dvl"), ("base_link", "ins")}

            diag = graph.echo("/diagnostics", count=8, timeout_s=60)
            names = {st.name for m in diag for st in m.msg.status}
            assert {"auvgw/auv1/ins", "auvgw/auv1/dvl"} <= names, names
            ins = next(st for m in diag for st in m.msg.status if st.name == "auvgw/auv1/ins")
            assert ins.level == 0, (ins.level, ins.message)  # OK: connected, fresh
            assert "frames" in {kv.key for kv in ins.values}
        listed = subprocess.run([AUVGW, "ros2", "list"], capture_output=True, text=True,
                                timeout=60)  # fmt: skip
        assert listed.returncode == 0, listed.stderr
        assert "/fleet/auvgw_bridge\n" in listed.stdout
        assert (f"  publishes /fleet/auv1/sensor/ins/imu [sensor_msgs/msg/Imu] "
                f"{type_hash('sensor_msgs/msg/Imu')}") in listed.stdout
        _foxglove_client_decodes_a_cloud_and_transforms(url)
    finally:
        for p in (fox, fusion, gw, sim):
            p.signal(signal.SIGINT)
    for p in (fox, fusion, gw):
        assert p.wait(60) == 0, p.stderr()
    assert "Traceback" not in gw.stderr(), gw.stderr()


def _foxglove_client_decodes_a_cloud_and_transforms(url: str) -> None:
    """A client of the Foxglove WebSocket protocol (foxglove/ws-protocol docs/spec.md; the SDK's
    server selects its current subprotocol name ``foxglove.sdk.v1``, the spec's first was
    ``foxglove.websocket.v1``: both are offered): serverInfo, advertise, subscribe, Message
    Data (opcode 1, u32 subscription id, u64 log time, payload), each payload decoded with
    Foxglove's ROS 2 decoder from the ``ros2msg`` schema the server advertised."""
    import json
    import struct
    import time

    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    from websockets.sync.client import connect

    wanted = {"/auv1/sensor/multibeam/points": "sensor_msgs/msg/PointCloud2",
              "/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage"}
    channels: dict[str, dict] = {}
    got: dict[str, object] = {}
    offered = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
    with connect(url, subprotocols=offered, open_timeout=30) as ws:  # type: ignore[arg-type]
        assert ws.subprotocol in offered
        info = json.loads(ws.recv(timeout=30))
        assert info["op"] == "serverInfo", info
        deadline = time.monotonic() + 60
        subscribed: dict[int, str] = {}
        decoders: dict[str, object] = {}
        while len(got) < len(wanted):
            assert time.monotonic() < deadline, f"decoded only {sorted(got)}"
            frame = ws.recv(timeout=30)
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] != "advertise":
                    continue
                for ch in op["channels"]:
                    channels[ch["topic"]] = ch
                    if ch["topic"] in wanted and ch["topic"] not in subscribed.values():
                        assert (ch["encoding"], ch["schemaEncoding"]) == ("cdr", "ros2msg")
                        assert ch["schemaName"] == wanted[ch["topic"]]
                        sid = len(subscribed) + 1
                        subscribed[sid] = ch["topic"]
                        schema = Schema(id=ch["id"], name=ch["schemaName"], encoding="ros2msg",
                                        data=ch["schema"].encode())
                        decoders[ch["topic"]] = DecoderFactory().decoder_for("cdr", schema)
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": sid, "channelId": ch["id"]}]}))
                continue
            assert frame[0] == 1, frame[:1]  # Message Data
            sid, _log_time = struct.unpack_from("<IQ", frame, 1)
            topic = subscribed[sid]
            got[topic] = decoders[topic](frame[13:])
    cloud = got["/auv1/sensor/multibeam/points"]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    assert cloud.width * cloud.point_step == len(cloud.data) and cloud.width > 10
    pairs = {(t.header.frame_id, t.child_frame_id) for t in got["/tf"].transforms}
    assert pairs == {("odom", "base_link")}
    (mount,) = got["/tf_static"].transforms
    assert (mount.child_frame_id, mount.transform.translation.z) == ("multibeam", -0.4)
    assert cloud.header.frame_id == "multibeam"  # placed by /tf_static in base_link


def test_the_bridge_converts_only_what_a_subscriber_matches(tmp_path: Path):
    """Over real sessions: with no ROS 2 subscriber, a bus key's first sample declares its
    publishers (the graph lists them) and the rest are counted ``unwatched`` in the Zenoh
    callback, never queued nor converted; once a subscriber on the IMU's data key appears
    (Zenoh's matching status), the INS samples are converted and arrive while the DVL's stay
    unwatched: one sample per ROS 2 message, with rmw_zenoh's attachment (the publisher's
    sequence numbers in order, the envelope's stamp, its GID), at ``DATA_LOW`` (below the raw
    frames' priority)."""
    from auvgw.envelope import decode_envelope
    from auvgw.rmw_zenoh import data_key, unpack_attachment
    from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig
    from auvgw.testing import free_port, hostile

    good, _ = hostile.fusion_traffic(tmp_path, 1.0, 100.0)
    ins = [(k, p) for _, k, p in good if "/sensor/ins/" in k]
    dvl = [(k, p) for _, k, p in good if "/sensor/dvl/" in k]
    assert len(ins) > 50 and len(dvl) > 3 and len({k for k, _ in ins + dvl}) == 2
    ep = f"tcp/127.0.0.1:{free_port()}"
    with open_session(BusConfig(listen=[ep])) as hub, \
            open_session(BusConfig(connect=[ep])) as spoke:  # fmt: skip
        bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="auv1"), hub, sections=("sensor",))
        bridge.start()
        try:
            def counts() -> tuple[int, int]:
                c = bridge.counters()["stage"]
                return c["received"], c["unwatched"]

            pubs = {k: spoke.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                    for k, _ in (ins[0], dvl[0])}  # fmt: skip
            wait_until(lambda: all(p.matching_status.matching for p in pubs.values()),
                       timeout=30, what="the bridge's subscription reaching the publisher")

            def send(samples: list[tuple[str, bytes]], total: int) -> None:
                for k, p in samples:
                    pubs[k].put(p)
                wait_until(lambda: sum(counts()) == total, timeout=60, what="the samples taken")

            send([ins[0], dvl[0]], 2)  # the first of each key declares its publishers
            send(ins[1:] + dvl[1:], len(ins) + len(dvl))
            assert counts() == (2, len(ins) + len(dvl) - 2)
            imu_key = data_key(0, "/auv1/sensor/ins/imu", "sensor_msgs/msg/Imu")
            got: list[tuple[bytes, bytes, zenoh.Priority]] = []
            sub = spoke.declare_subscriber(imu_key, lambda s: got.append(
                (bytes(s.payload), bytes(s.attachment or b""), s.priority)))  # fmt: skip
            imu_ep = bridge._endpoints[imu_key]
            wait_until(lambda: imu_ep.matching, timeout=30, what="the subscriber matched")
            published = bridge.counters()["stage"]["published"]
            send(ins + dvl, 2 * (len(ins) + len(dvl)))
            wait_until(lambda: len(got) >= len(ins), timeout=30, what="the IMU messages")
            assert counts() == (2 + len(ins), 2 * (len(ins) + len(dvl)) - 2 - len(ins))
            assert bridge.counters()["stage"]["published"] == published + len(ins)
            # the IMU publisher's first put was the first INS sample's (sequence 1)
            assert [unpack_attachment(a) for _, a, _ in got] == [
                (seq, decode_envelope(p).t_recv_ns, imu_ep.gid)
                for seq, (_, p) in enumerate(ins, start=2)]  # fmt: skip
            assert [prio for _, _, prio in got] == [zenoh.Priority.DATA_LOW] * len(got)
            # the compiled writers' bytes (auvgw.ros2_cdr) are the recorder's (rosbags'), in order
            from auvgw.recording import sample_to_ros

            base = "auv/auv1/"
            want = [bytes(ros2.serialize(m)) for k, p in ins
                    for m in sample_to_ros("sensor", k[len(base) + 7:], p, 0)[0]]  # fmt: skip
            assert [cdr for cdr, _, _ in got] == want
            sub.undeclare()
        finally:
            bridge.stop(flush=False)


COMMAND_PROC = str(REPO / "tests" / "ros2_command_proc.py")
CLOSED_LOOP = str(REPO / "config" / "scenarios" / "closed_loop.json")


def test_commands_from_a_ros2_node_reach_the_actuators(procs, tmp_path: Path):
    """``auvgw sim`` (the closed-loop scenario: an emulated motor/fin controller on an SLCAN pty)
    + ``auvgw run`` with ``[ros2] commands = ["actuators"]``; a ROS 2 publisher in its own
    process, written from rmw_zenoh's design document, finds the bridge's subscription in the
    graph and sends 30 commands: the gateway's gate forwards them to the controller, whose
    feedback echoes the last one and holds the commanded rudder; an out-of-range and a stale one
    are refused by the same gate and counted there, a sample that is no CDR by the bridge."""
    from auvgw.subscribe import GatewaySubscriber
    from auvgw.testing import endpoint, free_port

    n, rpm, rudder = 30, 600.0, 0.1
    sim = procs.start([AUVGW, "sim", "--scenario", CLOSED_LOOP, "--speed", "2", "--duration",
                       "200", "--out", str(tmp_path / "sim"), "--no-truth-log",
                       "--start-delay", "2"], "sim")  # fmt: skip
    cfg = sim.wait_line("gateway config:", timeout=60).split(":", 1)[1].strip()
    with open(cfg, "a") as f:
        f.write('\n[ros2]\nenabled = true\nnamespace = "/fleet"\ncommands = ["actuators"]\n')
    ep = endpoint(free_port())
    gw = procs.gateway(Path(cfg), "gateway", "--listen", ep)
    with GatewaySubscriber("auv1", BusConfig(connect=[ep])) as me:
        fb = me.stream("actuators", "actuatorstate")
        assert me.wait_ready(60)
        wait_until(lambda: (me.status("actuators") or {}).get("connected"), 60, what="CAN up")
        before = me.status("actuators")["commands"]
        assert before["forwarded"] == 0
        ros = procs.start([PYTHON, COMMAND_PROC, ep, "/fleet/auv1/cmd/actuators", str(n),
                           str(rpm), str(rudder), "0.0"], "ros2-commander")  # fmt: skip
        # the bridge's MS token carries the hash the ROS 2 side computes from the definition
        assert ros.wait_line("subscription", 60) == f"subscription {type_hash(CMD_TYPE)}"
        ros.wait_line("done", 60)

        def counted() -> dict | None:
            c = me.status("actuators")["commands"]
            return c if c["forwarded"] == n and c["stale_seq"] and c["out_of_range"] else None

        cmds = wait_until(counted, 30, what="30 forwarded, the bad ones refused")
        assert (cmds["out_of_range"], cmds["stale_seq"], cmds["malformed"]) == (1, 1, 0), cmds
        assert cmds["last_seq"] == n
        bridge = wait_until(lambda: (st := me.status("ros2")) and st["stage"]["bad_commands"]
                            and st["stage"], 20, what="the bad CDR counted")  # fmt: skip
        assert (bridge["commands"], bridge["bad_commands"]) == (n + 2, 1), bridge
        # the controller applied them: its feedback echoes the last sequence number, the rudder
        # where it was told (the fins hold their last command; only the thruster times out)
        states = wait_until(lambda: [m for e in fb.iter(0)
                                     if (m := e.message).cmd_seq == n] or None, 30,
                            what="feedback of the last command")  # fmt: skip
        assert abs(states[-1].rudder - rudder) < 0.02, states[-1]
        assert max(s.shaft_rpm for s in states) > 100, states
        ros.signal(signal.SIGINT)
        assert ros.wait(30) == 0, ros.stderr()
    gw.signal(signal.SIGINT)
    sim.signal(signal.SIGINT)
    assert gw.wait(60) == 0, gw.stderr()
    assert "Traceback" not in gw.stderr(), gw.stderr()
