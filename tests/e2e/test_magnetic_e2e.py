"""AMB-SLAM end to end in separate processes: ``auvgw demo --processes --scenario beacons`` runs
the emulated INS, DVL, MS3A magnetometer and acoustic beacon (``auvgw sim``), the gateway (``auvgw
run``), the fusion stage (``auvgw fusion``) and the magnetic stage (``auvgw slam run --pipeline
magnetic``), each its own OS process joined by Zenoh over loopback TCP, at 4x real time. The
demo process only collects; its summary is read back: every part exited cleanly, the magnetic
stage used every magnetometer sample the gateway decoded, demodulated and ranged beacons with the
MLP, mapped them, took the acoustic fixes, and its path is closer to the emulator's ground truth
than dead reckoning (RMSE / distance x 100). The demo waits on the processes' liveliness and the
gateway's frame counters, never on fixed sleeps."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from auvgw.testing import run_demo_processes
from auvgw.testing.processes import uart_overruns

DURATION_S = 120.0  # 600 m: the first leg and five beacons
SPEED = 4.0
MAG_RATE_HZ = 20.0


@pytest.fixture(scope="module")
def beacons_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("magnetic-e2e")
    _, stdout, summary = run_demo_processes(out, "beacons", DURATION_S, SPEED, 240, viz=True)
    return out, stdout, summary


def test_every_part_ran_in_its_own_process(beacons_run) -> None:
    out, _, summary = beacons_run
    procs = summary["processes"]
    assert set(procs) == {"sim", "gateway", "fusion", "slam"}
    assert len({p["pid"] for p in procs.values()}) == 4
    for name, p in procs.items():
        assert p["exit_code"] == 0 and not p["killed"], (name, p)
    # the SLAM process is the magnetic stage, with the scenario's channels and the sim's epoch
    gw = (out / "gateway.toml").read_text()
    assert "[clock]" in gw and "epoch_ns" in gw
    assert "slam running: vehicle auv1, AMB-SLAM" in (out / "slam.log").read_text()
    devices = summary["devices"]
    assert set(devices) == {"ins", "dvl", "magnetometer", "acoustic"}
    overruns = uart_overruns(out / "sim.log")  # a loaded host: frames cut by a full pty
    assert all(d["connected"] and (d["bad_frames"] == 0 or overruns.get(name, 0) > 0)
               for name, d in devices.items()), (devices, overruns)  # fmt: skip


def test_the_magnetic_stage_used_every_sample_and_mapped_beacons(beacons_run) -> None:
    _, _, summary = beacons_run
    counters = summary["slam"]
    assert counters["component"] == "slam-magnetic" and counters["algorithm"] == "amb-slam"
    st = counters["stage"]
    n_mag = summary["devices"]["magnetometer"]["messages"]["Ms3aSample"]
    assert n_mag == pytest.approx(DURATION_S * MAG_RATE_HZ, abs=2)
    # every decoded sample reached the demodulator, in order, timed by its counter; the last one
    # or two may still be on the bus when the run stops (seen on a loaded machine: 2400 of 2401)
    assert n_mag - 2 <= st["mag"] <= n_mag
    assert st["mag_before_odometry"] == 0 and st["mag_dropped"] == 0
    assert st["bad_payloads"] == 0 and st["queue_dropped"] == 0 and st["mag_other_device"] == 0
    # 1 Hz acoustic fixes, 5 % missed; every one the gateway decoded was used, those that came
    # before the first odometry (which lags the sensors by the fusion's hold-back, seconds on a
    # loaded machine) once it came
    n_ac = summary["devices"]["acoustic"]["messages"]["AcousticReply"]
    assert st["acoustic"] >= n_ac - 2 and n_ac >= 0.85 * DURATION_S
    assert st["acoustic_before_odometry"] <= 1
    # the first leg passes five beacons within the 25 m sensor range: each seen many times at 5 Hz
    assert st["observations"] >= 50
    assert 3 <= counters["landmarks"] <= 10


def test_amb_slam_beats_dead_reckoning(beacons_run) -> None:
    _, stdout, summary = beacons_run
    nav = summary["navigation"]
    dr, amb = nav["dead_reckoning"], nav["slam"]
    assert nav["slam_algorithm"] == "AMB-SLAM"
    assert amb["distance_m"] > 500 and amb["samples"] >= 0.8 * DURATION_S * 5  # 5 Hz poses
    # measured 1.55 m (0.26 %) against dead reckoning's 4.93 m (0.82 %) with a 2 deg heading bias
    assert amb["rmse_pct_distance"] < 0.6 * dr["rmse_pct_distance"], nav
    assert amb["rmse_m"] < 3.5, amb
    assert "AMB-SLAM vs truth over" in stdout and "RMSE/distance x 100" in stdout


def test_the_recording_holds_the_beacons_the_map_and_the_ranges(beacons_run) -> None:
    """The gateway's Rerun recording (``--viz-rrd``, the SLAM outputs from the magnetic stage's
    process over the bus) holds the 20 true beacons, the estimated ones with their ellipses, the
    ranges of each window and the acoustic beacon."""
    from auvgw.viz.readback import read_recording

    out, _, summary = beacons_run
    rec = read_recording(out / "demo.rrd")
    assert len(rec["map/truth/landmarks"].values("Points2D:positions")[-1]) == 20
    est = rec["map/slam/magnetic/landmarks"]
    n_est = len(est.values("Points2D:positions")[-1])
    assert n_est == summary["slam"]["landmarks"] and n_est >= 3
    assert len(est.values("LineStrips2D:strips")[-1]) == n_est
    ranges = rec["map/slam/magnetic/ranges"].values("LineStrips2D:strips")
    observations = summary["slam"]["stage"]["observations"]
    # one row per window; the last may still be on the bus when the run stops
    assert observations - 1 <= len(ranges) <= observations
    # the acoustic beacon at (250, 250) NED: map (east, -north)
    for name in ("truth", "slam/magnetic"):
        ab = rec[f"map/{name}/acoustic_beacon"].values("Points2D:positions")[-1]
        assert ab == [[250.0, -250.0]], (name, ab)


def test_in_process_demo_runs_amb_slam(tmp_path) -> None:
    """``auvgw demo --scenario beacons`` (gateway, fusion, magnetic stage and Rerun in one
    process, the emulators in another; the gateway opens the ports once the sim is up, a few
    vehicle seconds late at 4x), 60 s: the first two beacons. The summary names AMB-SLAM, and
    the recording holds the true beacons and the estimated ones (the recording's content is
    checked in full on the ``--processes`` run above)."""
    from auvgw.viz.readback import read_recording

    out = tmp_path
    res = subprocess.run(
        [sys.executable, "-m", "auvgw", "demo", "--scenario", "beacons", "--duration", "60",
         "--speed", str(SPEED), "--out", str(out)],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    summary = json.loads((out / "summary.json").read_text())
    nav = summary["navigation"]
    assert nav["slam_algorithm"] == "AMB-SLAM"
    assert summary["slam"]["component"] == "slam-magnetic"
    assert summary["slam"]["stage"]["observations"] >= 10 and summary["slam"]["landmarks"] >= 1
    # (the error against the truth is the --processes test's: in one process the fusion
    # starts at the first INS sample the late-opened gateway reads, from the truth logged by
    # then, and on a starved machine that falls back to the scenario's start pose)
    assert nav["slam"]["samples"] > 100 and nav["dead_reckoning"] is not None
    assert "AMB-SLAM vs truth over" in res.stdout
    rec = read_recording(out / "demo.rrd")
    assert len(rec["map/truth/landmarks"].values("Points2D:positions")[-1]) == 20
    est = rec["map/slam/magnetic/landmarks"].values("Points2D:positions")[-1]
    assert len(est) == summary["slam"]["landmarks"]
