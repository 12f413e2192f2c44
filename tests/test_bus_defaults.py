"""Processes find each other with the shipped defaults (issue 16): sim, gateway, recorder, fusion
and SLAM each in its own process, started as the README says, with no bus option at all.

The one-machine default endpoint is this test session's free port (``$AUVGW_BUS_ENDPOINT``,
set by conftest.py) so parallel test runs never meet; the commands themselves get no option.
"""

from __future__ import annotations

import signal
import threading
from collections import Counter
from pathlib import Path

from gateway_support import AUVGW, REPO, wait_until

from auvgw.bus import Keys, open_session
from auvgw.config.bus import BusConfig, default_endpoint
from auvgw.recording import iter_samples, read_info

SCENARIO = str(REPO / "config" / "scenarios" / "harbour.json")


def _count_on_bus(stop: threading.Event, counts: Counter) -> threading.Thread:
    """Count samples per section of the default bus (a spoke, as every stage), until stop."""

    def run() -> None:
        with open_session(BusConfig().as_spoke()) as s:
            keys = Keys("auv1")

            def on_sample(smp) -> None:
                key = str(smp.key_expr)
                counts[key.split("/")[2]] += 1
                if "/slam/" in key and key.endswith("/pose"):
                    counts["slam_pose"] += 1

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
    stop = threading.Event()
    counter = _count_on_bus(stop, counts)
    try:
        rec.wait_line("recording", timeout=60)
        fusion.wait_line("fusion running", timeout=60)
        slam.wait_line("slam running", timeout=60)
        wait_until(lambda: counts["slam_pose"] >= 3 and counts["nav"] >= 50, timeout=120,
                   what=f"SLAM poses and odometry on the default bus (seen {counts})")  # fmt: skip
        rec.signal(signal.SIGTERM)
        assert rec.wait(60) == 0, rec.stderr()
    finally:
        stop.set()
        counter.join(10)
        for p in (slam, fusion, gw, sim):
            p.signal(signal.SIGINT)
    for p in (slam, fusion, gw):
        assert p.wait(60) == 0, p.stderr()
        assert "no publisher" not in p.stderr()

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


def test_a_stage_without_gateway_says_no_publisher_and_recorder_fails(procs, tmp_path: Path):
    rec = procs.start([AUVGW, "record", "--out", str(tmp_path / "empty.mcap")], "record")
    fusion = procs.start([AUVGW, "fusion"], "fusion")
    fusion.wait_line("fusion running", timeout=60)
    endpoint = default_endpoint()
    wait_until(lambda: "no publisher on auv/auv1/sensor/*/*" in fusion.stderr(), timeout=60,
               what="the fusion stage's 'no publisher' line")  # fmt: skip
    assert endpoint in fusion.stderr()
    wait_until(lambda: "no publisher on auv/auv1/raw/**" in rec.stderr(), timeout=60,
               what="the recorder's 'no publisher' line")  # fmt: skip
    rec.signal(signal.SIGTERM)
    assert rec.wait(60) == 1, rec.stderr()
    assert "nothing recorded" in rec.stderr()
    fusion.signal(signal.SIGTERM)
    assert fusion.wait(60) == 0
