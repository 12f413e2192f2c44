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
TESTED_BLOCK = re.compile(r"<!-- tested: tests/test_security_acl\.py.*?-->\s*```sh\n(.*?)```", re.S)
PUT_PROC = str(REPO / "tests" / "bus_put_proc.py")
SENSOR, NAV, SLAM = "auv/v/sensor/dvl/ensemble", "auv/v/nav/odometry", "auv/v/slam/ekf/pose"


def _doc_commands() -> list[str]:
    blocks = TESTED_BLOCK.findall(DOC.read_text())
    assert len(blocks) == 1, f"{DOC}: {len(blocks)} blocks marked for tests/test_security_acl.py"
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
        sub.undeclare()
    for plain in (f"tcp/127.0.0.1:{port}", f"tcp/localhost:{port}"):
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            open_session(BusConfig(mode="client", connect=[plain]))


def test_each_identity_publishes_on_its_own_keys_only(documented_router):
    """The gateway, fusion and a landmark SLAM stage, each with its own certificate in its own
    process, put on sensor/, nav/ and slam/ alike; a subscriber (the recorder's identity) gets
    each key from its owner only."""
    tmp, _port, procs = documented_router
    seen: dict[str, set[str]] = {SENSOR: set(), NAV: set(), SLAM: set()}
    count: dict[tuple[str, str], int] = {}
    lock = threading.Lock()

    def keep(s: zenoh.Sample) -> None:
        key, sender = str(s.key_expr), s.payload.to_bytes().decode().rsplit("-", 1)[0]
        with lock:
            seen[key].add(sender)
            count[key, sender] = count.get((key, sender), 0) + 1

    def owners_heard(n: int) -> bool:
        with lock:
            return all(
                count.get(k, 0) >= n
                for k in ((SENSOR, "gateway"), (NAV, "fusion"), (SLAM, "slam-landmark"))
            )

    with open_session(_bus(tmp, "recorder")) as rec:
        sub = rec.declare_subscriber("auv/v/**", keep)
        # each process puts first on the keys it does not own, last on its own: once its own
        # key's sample of a round arrives, the router has judged that round's forgeries
        for name, keys in (
            ("slam-landmark", (SENSOR, NAV, SLAM)),
            ("gateway", (NAV, SLAM, SENSOR)),
            ("fusion", (SENSOR, SLAM, NAV)),
        ):
            toml = tmp / "config" / "security" / f"{name}-bus.toml"
            proc = procs.start([PYTHON, PUT_PROC, str(toml), name, *keys], name)
            proc.wait_line("ready")
        wait_until(lambda: owners_heard(20), timeout=30, what="20 rounds from every owner")
        sub.undeclare()
    with lock:
        assert seen == {SENSOR: {"gateway"}, NAV: {"fusion"}, SLAM: {"slam-landmark"}}


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
    return {
        "gateway": {
            ("put", k.raw("dvl")),
            ("put", k.sensor("dvl", "ensemble")),
            *stage("gateway", []),
            *stage("dvl", []),
            ("declare_queryable", k.config("gateway")),
        },
        "fusion": stage("fusion", [k.odometry()]),
        "pilot": stage(
            "pilot", [k.cmd("actuators"), f"{k.base}/pilot/command", f"{k.base}/pilot/state"]
        ),
        "slam-landmark": landmark,
        **{
            f"slam-{s.name}": stage(f"slam-{s.name}", [k.slam(s.name, w) for w in s.outputs])
            for s in (MagneticStage, BathymetricStage)
        },
    }


def test_shipped_acl_gives_each_identity_its_own_keys_only():
    """Every key a component's code sends on is allowed to its identity and to no other but
    the gateway's status/alive (the landmark rule lists every algorithm's key segment, so a new
    one fails here); every vehicle
    identity and the shore receive everything; the router's identity may do nothing."""
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
        listens = _allowed(acl, identity, "ingress", "declare_subscriber", "auv/v/sensor/dvl/x")
        assert listens == (identity != "router")
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
