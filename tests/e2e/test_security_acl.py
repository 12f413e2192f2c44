"""The vehicle's bus as docs/security.md documents it: the doc's commands run as written (one
makes the CA and every component's certificate, one starts the router on mutual TLS with the
shipped per-component access control), then real TLS sessions, each identity in its own process,
show that an identity can publish on its own keys only."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import threading
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from auvgw.bus import load_bus_table, open_session
from auvgw.config.bus import BusConfig
from auvgw.ground.paths import config_file
from auvgw.security import COMPONENTS
from auvgw.slam.landmark.registry import ALGORITHMS
from auvgw.testing import PYTHON, REPO, Procs, free_port, wait_until

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")

DOC = REPO / "docs" / "security.md"
SHIPPED = config_file("security/router.toml").parent
#: a fenced shell block the doc marks for this test
TESTED_BLOCK = re.compile(
    r"<!-- tested: tests/e2e/test_security_acl\.py.*?-->\s*```sh\n(.*?)```", re.S
)
PUT_PROC = str(REPO / "tests" / "bus_put_proc.py")
SENSOR, NAV, SLAM = "auv/v/sensor/dvl/ensemble", "auv/v/nav/odometry", "auv/v/slam/ekf/pose"
CMD, MARK = "auv/v/cmd/actuators", "auv/v/sensor/dvl/marker"


def _ros_key(topic: str, ros_type: str) -> str:
    from auvgw.rmw_zenoh import data_key

    return data_key(0, topic, ros_type)


def _doc_commands() -> list[str]:
    blocks = TESTED_BLOCK.findall(DOC.read_text())
    assert len(blocks) == 1, (
        f"{DOC}: {len(blocks)} blocks marked for tests/e2e/test_security_acl.py"
    )
    return [ln.strip() for ln in blocks[0].splitlines() if ln.strip() and not ln.startswith("#")]


def _bus(folder: Path, component: str) -> BusConfig:
    path = folder / "config" / "security" / f"{component}-bus.toml"
    return BusConfig(**load_bus_table(path)).rebased(path.parent)


@pytest.fixture(scope="module")
def documented_router(tmp_path_factory) -> Iterator[tuple[Path, int, Procs]]:
    """(scratch folder, port, its processes) after the doc's block ran in the scratch folder,
    which holds copies of config/security/*.toml with 7447 replaced by a free port."""
    tmp = tmp_path_factory.mktemp("documented")
    port = free_port()
    (tmp / "config" / "security").mkdir(parents=True)
    for f in SHIPPED.glob("*.toml"):
        text = f.read_text().replace(":7447", f":{port}")
        (tmp / "config" / "security" / f.name).write_text(text)
    env = {"PATH": f"{Path(PYTHON).parent}{os.pathsep}{os.environ['PATH']}"}
    procs = Procs(tmp)
    try:
        for i, line in enumerate(_doc_commands()):
            if line.endswith("&"):  # a server: started, then waited for its banner
                proc = procs.start(shlex.split(line[:-1]), f"doc-{i}", env=env, cwd=tmp)
                banner = proc.wait_line("auvgw router")
                assert banner.endswith(f"listening on tls/127.0.0.1:{port}"), banner
            else:
                r = subprocess.run(shlex.split(line), cwd=tmp, env={**os.environ, **env},
                                   capture_output=True, text=True, timeout=60)  # fmt: skip
                assert r.returncode == 0, f"{line}: {r.stderr}"
        yield tmp, port, procs
    finally:
        procs.stop_all()


def test_documented_router_speaks_tls_only(documented_router):
    tmp, port, _procs = documented_router
    names = {p.stem for p in (tmp / "config/security/certs").glob("*.pem")}
    assert names == {"ca", *COMPONENTS}  # one command made the CA and every component's pair
    with open_session(_bus(tmp, "gateway")) as gw, open_session(_bus(tmp, "fusion")) as fusion:
        got: list[bytes] = []
        sub = fusion.declare_subscriber(
            "auv/v/sensor/**", lambda s: got.append(s.payload.to_bytes())
        )

        def delivered() -> bool:  # re-put until the route is in place
            gw.put(SENSOR, b"over-tls")
            return b"over-tls" in got

        wait_until(delivered, what="a sample from the gateway's session at fusion's")
        # the gateway's ROS 2 bridge hands a ROS 2 command to the gateway's gate in its own
        # session: delivered there, while the router forwards it to nobody else (the gateway
        # identity may not send commands); the sensor sample put after it is the marker
        mine: list[bytes] = []
        heard: list[str] = []
        own = gw.declare_subscriber(CMD, lambda s: mine.append(s.payload.to_bytes()))
        # declared in order: once the marker's subscription works, the command's is in place
        cmd_sub = fusion.declare_subscriber(CMD, lambda s: heard.append("cmd"))
        mark_sub = fusion.declare_subscriber(MARK, lambda s: heard.append("marker"))

        def marked() -> bool:
            gw.put(CMD, b"from-the-bridge")
            gw.put(MARK, b"marker")
            return "marker" in heard

        wait_until(marked, what="the marker after a command at fusion's")
        assert mine and set(mine) == {b"from-the-bridge"} and "cmd" not in heard
        for d in (sub, own, cmd_sub, mark_sub):
            d.undeclare()
    for plain in (f"tcp/127.0.0.1:{port}", f"tcp/localhost:{port}"):
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            open_session(BusConfig(mode="client", connect=[plain]))


def test_each_identity_publishes_on_its_own_keys_only(documented_router):
    """The gateway, fusion, a landmark SLAM stage, the pilot and a ROS 2 node, each with its own
    certificate in its own process, put on sensor/, nav/, slam/, cmd/ and the ROS 2 keys alike;
    a subscriber (the recorder's identity) gets each key from its owner only: no stage's
    certificate sends an actuator command (only the pilot's), the ROS 2 sensor topic comes from
    the gateway (its bridge) only, the ROS 2 command topic from the pilot and the ROS 2 node."""
    from auvgw.ros2 import ACTUATOR_COMMAND_TYPE

    tmp, _port, procs = documented_router
    ros_imu = _ros_key("/v/sensor/ins/imu", "sensor_msgs/msg/Imu")
    ros_cmd = _ros_key("/v/cmd/actuators", ACTUATOR_COMMAND_TYPE)
    owners = {SENSOR: {"gateway"}, NAV: {"fusion"}, SLAM: {"slam-landmark"}, CMD: {"pilot"},
              ros_imu: {"gateway"}, ros_cmd: {"pilot", "ros2"}}  # fmt: skip
    seen: dict[str, set[str]] = {k: set() for k in owners}
    count: dict[tuple[str, str], int] = {}
    lock = threading.Lock()

    def keep(s: zenoh.Sample) -> None:
        key, sender = str(s.key_expr), s.payload.to_bytes().decode().rsplit("-", 1)[0]
        with lock:
            seen[key].add(sender)
            count[key, sender] = count.get((key, sender), 0) + 1

    def owners_heard(n: int) -> bool:
        with lock:
            return all(count.get((k, o), 0) >= n for k, who in owners.items() for o in who)

    with open_session(_bus(tmp, "recorder")) as rec:
        subs = [rec.declare_subscriber(k, keep) for k in ("auv/v/**", "0/**")]
        # each process puts first on the keys it does not own, last on its own: once its own
        # key's sample of a round arrives, the router has judged that round's forgeries
        for name, keys in (
            ("slam-landmark", (SENSOR, NAV, CMD, ros_imu, ros_cmd, SLAM)),
            ("gateway", (NAV, SLAM, CMD, ros_cmd, SENSOR, ros_imu)),
            ("fusion", (SENSOR, SLAM, CMD, ros_imu, ros_cmd, NAV)),
            ("pilot", (SENSOR, ros_imu, CMD, ros_cmd)),
            ("ros2", (CMD, SENSOR, ros_imu, ros_cmd)),
        ):
            toml = tmp / "config" / "security" / f"{name}-bus.toml"
            proc = procs.start([PYTHON, PUT_PROC, str(toml), name, *keys], name)
            proc.wait_line("ready")
        wait_until(lambda: owners_heard(20), timeout=30, what="20 rounds from every owner")
        for sub in subs:
            sub.undeclare()
    with lock:
        assert seen == owners


def _allowed(acl: dict, identity: str, flow: str, message: str, key: str) -> bool:
    """Whether the ACL lets the certificate CN ``identity`` send (``ingress``) or receive
    (``egress``) ``message`` on ``key``: some allow rule of one of its policies names all three
    (default deny; Zenoh's own verdict is what the process tests above see)."""
    subjects = {s["id"] for s in acl["subjects"] if identity in s.get("cert_common_names", [])}
    rules = {r["id"]: r for r in acl["rules"]}
    return any(
        r["permission"] == "allow"
        and flow in r["flows"]
        and message in r["messages"]
        and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"])
        for policy in acl["policies"]
        if subjects & set(policy["subjects"])
        for r in (rules[i] for i in policy["rules"])
    )


def _owned() -> dict[str, set[tuple[str, str]]]:
    """(message, key) each identity must be able to send: the keys the code publishes on."""
    from auvgw.bus import Keys
    from auvgw.rmw_zenoh import DEFAULT_QOS, node_token, topic_token
    from auvgw.ros2 import ACTUATOR_COMMAND_TYPE, TF_TYPE, ros_topic
    from auvgw.stages.bathymetric import BathymetricStage
    from auvgw.stages.magnetic import MagneticStage
    from auvgw.stages.slam import SlamStage, SlamStageConfig

    k = Keys("v")

    def stage(component: str, outputs: list[str]) -> set[tuple[str, str]]:
        return {
            *(("put", key) for key in outputs),
            ("put", k.status(component)),
            ("declare_queryable", k.status(component)),
            ("liveliness_token", k.alive(component)),
        }

    landmark: set[tuple[str, str]] = set()
    for algorithm in ALGORITHMS:
        pipe = SlamStageConfig(vehicle="v", algorithm=algorithm).pipeline_name
        landmark |= stage(f"slam-{pipe}", [k.slam(pipe, w) for w in SlamStage.outputs])
    # ROS 2 (domain 0): the bridge's topics, under a namespace and at the root, and the graph
    # tokens of a node, a publisher and a subscription
    zid = "8b2091e6f4a6c7d1" * 2
    ros_out = {("put", _ros_key(ros_topic("/fleet", "v", t), ros_type)) for t, ros_type in (
        ("sensor/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped"),
        ("nav/odometry", "nav_msgs/msg/Odometry"),
        ("slam/ekf/pose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
        ("status/fusion", "auvgw_msgs/msg/Decoded"), ("/tf", TF_TYPE), ("/tf_static", TF_TYPE),
        ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"))}  # fmt: skip
    cmd_topic = ros_topic("/fleet", "v", "cmd/actuators")
    graph = {("liveliness_token", node_token(0, zid, 0, "/fleet", "auvgw_bridge")),
             *(("liveliness_token", topic_token(0, zid, 0, 1, kind, "/fleet", "auvgw_bridge",
                                                cmd_topic, ACTUATOR_COMMAND_TYPE, DEFAULT_QOS))
               for kind in ("MP", "MS"))}  # fmt: skip
    ros_cmd = {("put", _ros_key(cmd_topic, ACTUATOR_COMMAND_TYPE))}
    return {
        "gateway": {
            ("put", k.raw("dvl")),
            ("put", k.sensor("dvl", "ensemble")),
            *stage("gateway", []),
            *stage("dvl", []),
            ("declare_queryable", k.config("gateway")),
            *ros_out,
            *graph,
        },
        "fusion": stage("fusion", [k.odometry()]),
        "pilot": stage(
            "pilot", [k.cmd("actuators"), f"{k.base}/pilot/command", f"{k.base}/pilot/state"]
        ) | graph | ros_cmd,
        "ros2": graph | ros_cmd,
        "slam-landmark": landmark,
        **{
            f"slam-{s.name}": stage(f"slam-{s.name}", [k.slam(s.name, w) for w in s.outputs])
            for s in (MagneticStage, BathymetricStage)
        },
    }


def test_shipped_acl_gives_each_identity_its_own_keys_only():
    """Every key a component's code sends on is allowed to its identity and to no other but
    the gateway's status/alive (the landmark rule lists every algorithm's key segment, so a new
    one fails here): the ROS 2 bridge's topics to the gateway only, the ROS 2 command topic and
    graph tokens to the pilot and the ROS 2 identity (and the tokens to the gateway); every
    vehicle identity and the shore receive everything, ROS 2 included; the router's identity may
    do nothing."""
    acl = tomllib.loads((SHIPPED / "router.toml").read_text())["bus"]["access_control"]
    owned = _owned()
    everything = set().union(*owned.values())
    for identity in COMPONENTS:
        for message, key in sorted(everything):
            mine = (message, key) in owned.get(identity, set()) or (
                # documented: the gateway's status/ and alive/ rights cover any device name
                identity == "gateway" and key.split("/")[2] in ("status", "alive")
            )
            assert _allowed(acl, identity, "ingress", message, key) == mine, (identity, key)
            receives = identity != "router"
            assert _allowed(acl, identity, "egress", "put", key) == receives, (identity, key)
        for key in ("auv/v/sensor/dvl/x", "0/v/sensor/dvl/twist/t/h"):
            listens = _allowed(acl, identity, "ingress", "declare_subscriber", key)
            assert listens == (identity != "router"), (identity, key)
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert subjects == {c: [c] for c in COMPONENTS if c != "router"}
    for component in subjects:
        assert (SHIPPED / f"{component}-bus.toml").is_file()


def test_viz_takes_its_own_bus_config():
    """``auvgw viz --bus-config viz-bus.toml``: the viewer's own certificate, paths resolved
    against the file's folder, ``--bus-connect`` still overriding the endpoints."""
    from auvgw.cli import build_parser
    from auvgw.commands.viz import _bus

    toml = SHIPPED / "viz-bus.toml"
    args = build_parser("viz").parse_args(["viz", "--bus-config", str(toml), "--vehicle", "v"])
    vehicle, bus = _bus(args)
    assert vehicle == "v" and bus.mode == "client" and bus.connect == ["tls/localhost:7447"]
    assert bus.tls is not None and bus.tls.connect_certificate == str(SHIPPED / "certs/viz.pem")
    args = build_parser("viz").parse_args(
        ["viz", "--bus-config", str(toml), "--bus-connect", "tls/10.0.0.2:7447"]
    )
    assert _bus(args)[1].connect == ["tls/10.0.0.2:7447"]


def test_certificate_command_user_errors(tmp_path, capsys):
    """A name that is no plain file name, or a folder that cannot be made: one line, exit 2,
    nothing written."""
    from auvgw.security import main

    assert main([str(tmp_path / "c"), "--name", "../ca"]) == 2
    assert (
        capsys.readouterr().err.strip().endswith("--name '../ca': letters, digits, '.', '_', '-'")
    )
    (tmp_path / "file").write_text("")
    assert main([str(tmp_path / "file" / "c"), "--name", "fusion"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m auvgw.security: fusion: ")
    assert not (tmp_path / "c").exists()
