"""One gateway per vehicle (issue 27): a second ``auvgw run`` for a vehicle whose gateway is
already on the bus refuses to start before it opens any port, with one line naming the first
(host, pid), and exits 2; the first loses nothing. Real processes: ``auvgw sim`` (the emulated
MS3A on a pty and on an emulated SLCAN adapter), the first gateway, a second joined to the
first's bus, a third started on the first's own listen endpoint, and this process watching the
first's status."""

from __future__ import annotations

import json
import socket

from auvgw.config.bus import BusConfig
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import AUVGW, Procs, endpoint, free_port, wait_until

SCENARIO = {
    "name": "single",
    "seed": 5,
    "vehicle": {"waypoints": [[0, 0], [200, 0]], "speed_mps": 1.5, "depth_m": 5.0},
    "magnetic_beacons": [{"x": 30, "y": 10, "z": 20, "moment_am2": 500}],
}
DEVICES = ("magnetometer", "magnetometer_can")


def _frames(me: GatewaySubscriber) -> dict[str, int]:
    st = me.status() or {"devices": {}}
    return {d: st["devices"].get(d, {}).get("frames", 0) for d in DEVICES}


def test_a_second_gateway_for_the_vehicle_refuses_and_the_first_loses_nothing(
    procs: Procs, tmp_path
) -> None:
    scenario = tmp_path / "single.json"
    scenario.write_text(json.dumps(SCENARIO))
    out = tmp_path / "sim"
    sim = procs.start(
        [AUVGW, "sim", "--scenario", str(scenario), "--speed", "1", "--out", str(out),
         "--devices", "magnetometer", "--vehicle", "solo", "--no-truth-log"],
        "sim",
    )  # fmt: skip
    sim.wait_line("running", 60)
    cfg = out / "gateway.toml"
    ep1, ep2 = endpoint(free_port()), endpoint(free_port())
    first = procs.gateway(cfg, "first", "--listen", ep1)
    with GatewaySubscriber("solo", BusConfig(connect=[ep1])) as me:
        wait_until(lambda: min(_frames(me).values()) > 0, 60, what="both devices flowing")

        # joined to the first's bus; then started again from the same file and endpoint (its
        # listener taken: it asks whoever holds it)
        second = procs.gateway(cfg, "second", "--listen", ep2, "--connect", ep1)
        third = procs.gateway(cfg, "third", "--listen", ep1)
        for other in (second, third):
            assert other.wait(60) == 2
            err = other.stderr()
            refusals = [ln for ln in err.splitlines() if "already has a gateway" in ln]
            assert len(refusals) == 1, err
            line = refusals[0]
            assert f"vehicle 'solo' already has a gateway on this bus: pid {first.p.pid} " in line
            assert f"on host {socket.gethostname()} " in line
            assert "connected on" not in err and "Traceback" not in err  # it opened no port

        # the first carries on: its counters keep increasing, its devices never dropped
        before = _frames(me)
        wait_until(
            lambda: all(n > before[d] + 10 for d, n in _frames(me).items()),
            30,
            what="frames after the refusal",
        )
        st = me.status()
        assert st is not None and st["pid"] == first.p.pid
        for d in DEVICES:
            dev = st["devices"][d]
            assert dev["connected"] is True and dev["stale"] is False, dev
            assert dev["connects"] == 1 and dev["outages"] == 0, dev
        assert {"gateway", *DEVICES} <= me.alive()
    assert first.p.poll() is None
