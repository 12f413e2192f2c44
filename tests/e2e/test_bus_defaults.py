"""Processes find each other with the shipped defaults (issue 16): sim, gateway, recorder, fusion
and SLAM each in its own process, started as the README says, with no bus option at all.

The one-machine default endpoint is this test session's free port (``$AUVGW_BUS_ENDPOINT``,
set by conftest.py) so parallel test runs never meet; the commands themselves get no option.
"""

from __future__ import annotations

import math
import signal
import threading
from collections import Counter
from pathlib import Path

from auvgw.bus import Keys, open_session
from auvgw.config.bus import BusConfig, default_endpoint
from auvgw.recording import iter_samples, read_info
from auvgw.testing import AUVGW, REPO, wait_until

SCENARIO = str(REPO / "config" / "scenarios" / "harbour.json")


def _count_on_bus(
    stop: threading.Event, counts: Counter, envelopes: list[tuple[str, bytes]]
) -> threading.Thread:
    """Count samples per section of the default bus (a spoke, as every stage) and keep the
    decoded envelopes (sensor/, nav/), until stop."""

    def run() -> None:
        with open_session(BusConfig().as_spoke()) as s:
            keys = Keys("auv1")

            def on_sample(smp) -> None:
                key = str(smp.key_expr)
                section = key.split("/")[2]
                counts[section] += 1
                if section in ("sensor", "nav"):
                    envelopes.append((key, smp.payload.to_bytes()))
                if "/slam/" in key and key.endswith("/pose"):
                    counts["slam_pose"] += 1
                if key.endswith("/msis/mtheaddata"):  # the polled head answers after its set-up
                    counts["msis_head"] += 1

            sub = s.declare_subscriber(keys.all("**"), on_sample)
            stop.wait()
            sub.undeclare()

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_default_endpoints_connect_sim_gateway_record_fusion_slam(procs, tmp_path: Path):
    sim_dir = tmp_path / "sim"
    sim = procs.start([AUVGW, "sim", "--scenario", SCENARIO, "--speed", "4", "--out",
                       str(sim_dir), "--start-delay", "3"], "sim")  # fmt: skip
    cfg = sim.wait_line("gateway config:", timeout=60).split(":", 1)[1].strip()
    assert default_endpoint() in Path(cfg).read_text()  # the sim wrote the rendezvous endpoint
    gw = procs.start([AUVGW, "run", "--config", cfg], "gateway")
    rec_path = tmp_path / "run.mcap"
    rec = procs.start([AUVGW, "record", "--out", str(rec_path)], "record")
    fusion = procs.start([AUVGW, "fusion"], "fusion")
    slam = procs.start([AUVGW, "slam", "run"], "slam")
    counts: Counter = Counter()
    envelopes: list[tuple[str, bytes]] = []
    stop = threading.Event()
    counter = _count_on_bus(stop, counts, envelopes)
    try:
        rec.wait_line("recording", timeout=60)
        fusion.wait_line("fusion running", timeout=60)
        slam.wait_line("slam running", timeout=60)
        wait_until(lambda: counts["slam_pose"] >= 3 and counts["nav"] >= 50
                   and counts["msis_head"] >= 3, timeout=120,
                   what=f"SLAM poses, odometry, sonar lines (seen {counts})")  # fmt: skip
        rec.signal(signal.SIGTERM)
        assert rec.wait(60) == 0, rec.stderr()
    finally:
        stop.set()
        counter.join(10)
        for p in (slam, fusion, gw, sim):
            p.signal(signal.SIGINT)
    for p in (slam, fusion, gw):
        assert p.wait(60) == 0, p.stderr()
        # a stage up before the data flows may say "no publisher", then must see it arrive
        for line in p.stderr().splitlines():
            if "no publisher on " in line:
                key = line.split("no publisher on ", 1)[1].split()[0]
                assert f"{key}: receiving now" in p.stderr(), p.stderr()

    info = read_info(rec_path)
    assert info.config is not None  # the recorder reached the gateway's config queryable
    sections = Counter()
    for s in iter_samples(rec_path):
        sections["/".join(s.key.split("/")[2:4])] += 1
    for want in ("sensor/ins", "sensor/dvl", "sensor/multibeam", "sensor/magnetometer",
                 "nav/odometry", "raw/ins", "raw/dvl", "raw/multibeam"):  # fmt: skip
        assert sections[want] > 0, (want, sections)
    assert any(k.startswith("slam/") and n > 0 for k, n in sections.items()), sections
    assert any(k.endswith("/pose") for k in info.counts if "/slam/" in k), info.counts
    _check_ros2_readers(rec_path, envelopes)


#: ROS 2 types the recording must hold (topic suffix -> type)
WANTED = {
    "/auv1/sensor/ins/imu": "sensor_msgs/msg/Imu",
    "/auv1/sensor/ins_can/imu": "sensor_msgs/msg/Imu",
    "/auv1/sensor/dvl/twist": "geometry_msgs/msg/TwistWithCovarianceStamped",
    "/auv1/sensor/dvl/altitude": "sensor_msgs/msg/Range",
    "/auv1/sensor/multibeam/points": "sensor_msgs/msg/PointCloud2",
    "/auv1/sensor/msis/returns": "sensor_msgs/msg/PointCloud2",
    "/auv1/sensor/magnetometer/magnetic_field": "sensor_msgs/msg/MagneticField",
    "/auv1/nav/odometry": "nav_msgs/msg/Odometry",
    "/auv1/slam/vb_aufastslam/pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/auv1/raw/dvl": "auvgw_msgs/msg/RawFrame",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def _stamp(h) -> int:
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def _check_ros2_readers(path: Path, envelopes: list[tuple[str, bytes]]) -> None:
    """rosbags' AnyReader lists the topics with their ROS 2 types and deserialises every
    message; the mcap ROS 2 decoder's values agree field for field with the gateway's."""
    import numpy as np
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    import auvgw.fusion.odometry  # noqa: F401 - the Odometry type
    from auvgw.bus import decode_envelope
    from auvgw.drivers.can_codec import hn100_can, ms3a_can
    from auvgw.fusion.adapters import dvl_from_pd0
    from auvgw.ros2 import DEFAULT_SOUND_SPEED, enu_from_ned, flu_from_frd, quaternion_enu_flu
    from auvgw.subscribe import typed_message

    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        n = sum(1 for c, _t, raw in reader.messages() if reader.deserialize(raw, c.msgtype))
    for topic, ros_type in WANTED.items():
        assert types.get(topic) == ros_type, (topic, types)
    assert n == sum(read_info(path).counts.values())

    # the gateway's values, by (device or section, receive time)
    hn100_can(), ms3a_can()  # the CAN devices' message types
    gw: dict[tuple[str, int], list] = {}  # several messages of one chunk share a time
    for key, payload in envelopes:
        env = decode_envelope(payload, key)
        gw.setdefault((key.split("/")[3], env.t_recv_ns), []).append(
            typed_message(env.type, env.body)
        )

    def expected(name: str, msg) -> tuple:
        if name == "imu":
            return (quaternion_enu_flu(msg.heading, msg.pitch, msg.roll),
                    flu_from_frd((msg.rate_x, msg.rate_y, msg.rate_z)),
                    flu_from_frd((msg.accel_x, msg.accel_y, msg.accel_z)))  # fmt: skip
        if name == "magnetic_field":
            return tuple(np.asarray(flu_from_frd((msg.bx, msg.by, msg.bz))) * 1e-9)
        if name == "points":
            b = msg.beams
            xyzi = np.column_stack([b.along, -b.across, -b.depth, b.reflectivity])
            xyzi[~b.valid, :3] = np.nan  # no detection: a NaN point
            return tuple(xyzi.astype("<f4").reshape(-1))
        if name in ("twist", "altitude"):
            # the DVL: bottom-track velocity in the frame it reports (ship here, levelled into
            # base_link FLU), -1 in covariance[0] without bottom lock; altitude in metres
            s = dvl_from_pd0(msg, t=0.0)
            if name == "altitude":  # sensor_msgs/Range carries float32
                return "dvl", float(np.float32(s.altitude))
            frame = "base_link" if s.frame == "body" else "dvl"
            v = flu_from_frd(s.velocity) if s.frame == "body" else s.velocity
            return frame, tuple(v), (0.0, 0.0, 0.0), 0.0 if s.bottom_lock else -1.0
        if name == "returns":
            # the MSIS scan line: a point per bin at its centre range along the bearing
            # (clockwise from forward, so starboard is -y in FLU), intensity = amplitude
            r = (np.arange(len(msg.bins)) + 0.5) * (msg.ad_interval * DEFAULT_SOUND_SPEED / 2)
            xyzi = np.column_stack([r * math.cos(msg.bearing), -r * math.sin(msg.bearing),
                                    np.zeros(len(r)), msg.bins])  # fmt: skip
            return "msis", tuple(xyzi.astype("<f4").reshape(-1))
        if name == "odometry":
            return (
                enu_from_ned((msg.x, msg.y, msg.z)),
                quaternion_enu_flu(msg.heading, msg.pitch, msg.roll),
                flu_from_frd(msg.velocity_body),
            )
        raise KeyError(name)

    def got(name: str, ros) -> tuple:
        if name == "imu":
            o, w, a = ros.orientation, ros.angular_velocity, ros.linear_acceleration
            return (o.x, o.y, o.z, o.w), (w.x, w.y, w.z), (a.x, a.y, a.z)
        if name == "magnetic_field":
            b = ros.magnetic_field
            return b.x, b.y, b.z
        if name == "points":
            assert [f.name for f in ros.fields] == ["x", "y", "z", "intensity"]
            return tuple(np.frombuffer(bytes(ros.data), dtype="<f4"))
        if name == "altitude":
            return ros.header.frame_id, ros.range
        if name == "twist":
            t, cov = ros.twist.twist, ros.twist.covariance
            assert not any(cov[1:])
            return (ros.header.frame_id, (t.linear.x, t.linear.y, t.linear.z),
                    (t.angular.x, t.angular.y, t.angular.z), cov[0])  # fmt: skip
        if name == "returns":
            assert [f.name for f in ros.fields] == ["x", "y", "z", "intensity"]
            assert (ros.height, ros.width, ros.point_step) == (1, len(ros.data) // 16, 16)
            return ros.header.frame_id, tuple(np.frombuffer(bytes(ros.data), dtype="<f4"))
        p, o, v = ros.pose.pose.position, ros.pose.pose.orientation, ros.twist.twist.linear
        return (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), (v.x, v.y, v.z)

    def same(a, b) -> bool:
        """Equal, bit for bit where numbers, NaN equal to NaN (a DVL without bottom lock)."""
        if isinstance(a, tuple | list) and isinstance(b, tuple | list):
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
        if isinstance(a, float | np.floating) and isinstance(b, float | np.floating):
            return (a != a and b != b) or a == b
        return a == b

    names = ("imu", "magnetic_field", "points", "odometry", "twist", "altitude", "returns")
    checked = Counter()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        recorded = [(ch.topic, ros) for _s, ch, _m, ros in reader.iter_decoded_messages()]
    # /tf and /diagnostics decode with Foxglove's ROS 2 decoder too (a TFMessage has no header)
    tf_pairs = {(t.header.frame_id, t.child_frame_id)
                for topic, r in recorded if topic == "/tf" for t in r.transforms}  # fmt: skip
    assert ("odom", "base_link") in tf_pairs, tf_pairs
    diag = {st.name for topic, r in recorded if topic == "/diagnostics" for st in r.status}
    assert {"auvgw/auv1/ins", "auvgw/auv1/dvl", "auvgw/auv1/fusion"} <= diag, diag
    # every frame a header names is reachable from map through /tf and /tf_static
    tf_pairs |= {(t.header.frame_id, t.child_frame_id)
                 for topic, r in recorded if topic == "/tf_static" for t in r.transforms}
    assert ("map", "odom") in tf_pairs, tf_pairs  # from the SLAM poses
    reach, grew = {"map"}, True
    while grew:
        new = {c for p, c in tf_pairs if p in reach} - reach
        reach |= new
        grew = bool(new)
    used = {r.header.frame_id for _t, r in recorded if hasattr(r, "header")} - {""}
    assert used <= reach, (used - reach, tf_pairs)
    assert {"ins", "dvl", "multibeam", "msis"} <= used
    # the shipped Foxglove layout names only topics the recording has
    topics = {t for t, _r in recorded} | {"/tf", "/tf_static", "/diagnostics"}
    assert _layout_topics() <= topics, _layout_topics() - topics
    recorded = [(t, r) for t, r in recorded if hasattr(r, "header") and t.count("/") >= 3]
    per_stamp = Counter((t, _stamp(r.header)) for t, r in recorded)
    for topic, ros in recorded:
        parts = topic.split("/")  # /auv1/<section>/<device or stream>/...
        name = parts[-1]
        candidates = gw.get((parts[3], _stamp(ros.header)))
        if candidates is None or name not in names:
            continue
        if len(candidates) > 1 or per_stamp[(topic, _stamp(ros.header))] > 1:
            continue  # several messages share this receive time: the pairing is ambiguous
        # field for field, bit for bit
        g, e = got(name, ros), expected(name, candidates[0])
        assert same(g, e), (topic, g, e)
        checked[name] += 1
    for name in names:
        assert checked[name] > 0, checked


def test_a_stage_without_gateway_says_no_publisher_and_recorder_fails(procs, tmp_path: Path):
    rec = procs.start([AUVGW, "record", "--out", str(tmp_path / "empty.mcap")], "record")
    fusion = procs.start([AUVGW, "fusion"], "fusion")
    fusion.wait_line("fusion running", timeout=60)
    endpoint = default_endpoint()
    wait_until(lambda: "no publisher on auv/auv1/sensor/ins/*" in fusion.stderr(), timeout=60,
               what="the fusion stage's 'no publisher' line")  # fmt: skip
    assert endpoint in fusion.stderr()
    wait_until(lambda: "no publisher on auv/auv1/raw/**" in rec.stderr(), timeout=60,
               what="the recorder's 'no publisher' line")  # fmt: skip
    rec.signal(signal.SIGTERM)
    assert rec.wait(60) == 1, rec.stderr()
    assert "nothing recorded" in rec.stderr()
    fusion.signal(signal.SIGTERM)
    assert fusion.wait(60) == 0


def test_run_listen_option_replaces_the_configuration_endpoints(procs, tmp_path: Path):
    from auvgw.subscribe import GatewaySubscriber
    from auvgw.testing import endpoint, free_port

    cfg = tmp_path / "gw.toml"
    cfg.write_text('vehicle = "lv"\nstatus_period_s = 0.2\n[bus]\nlisten = ["tcp/127.0.0.1:1"]\n'
                   '[devices.dvl]\nformat = "pd0"\n'
                   f'transport = {{ kind = "serial", url = "{tmp_path / "no"}" }}\n')  # fmt: skip
    ep = endpoint(free_port())
    gw = procs.start([AUVGW, "-v", "run", "--config", str(cfg), "--listen", ep], "gateway")
    with GatewaySubscriber("lv", BusConfig(connect=[ep])) as me:
        st = wait_until(lambda: me.status("dvl"), timeout=60, what="the gateway's status")
    assert st["connected"] is False  # the device is absent; the gateway answers on --listen
    assert f"listen {ep}" in gw.stderr()


def _layout_topics() -> set[str]:
    """Every topic config/foxglove-layout.json names (3D panel topics, plot paths, panels)."""
    import json

    layout = json.loads((REPO / "config" / "foxglove-layout.json").read_text())
    out: set[str] = set()
    for panel in layout["configById"].values():
        out |= set(panel.get("topics", {}))
        out |= {p["value"].split(".", 1)[0] for p in panel.get("paths", [])}
        out |= {panel[k].split(".", 1)[0] for k in ("topicPath", "topicToRender") if k in panel}
    assert len(out) >= 8, out
    return out
