"""``auvgw sim``: starts the emulated vehicle, prints its ports, writes a valid gateway
configuration, serves real clients, applies the fault control file and stops cleanly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
import serial

from auvgw.config.gateway import load_gateway_config
from auvgw.drivers import hn100, ms3a
from auvgw.drivers.can_codec import hn100_can
from auvgw.testing import wait_until

SCENARIO = {
    "name": "cli-mini",
    "seed": 3,
    "vehicle": {"waypoints": [[0, 0], [60, 0], [60, 40]], "speed_mps": 1.5, "depth_m": 5.0},
    "terrain": {"kind": "procedural", "depth_m": 20, "relief_m": 2, "wavelength_m": 50,
                "seed": 1},
    "magnetic_beacons": [{"x": 30, "y": 10, "z": 20, "moment_am2": 500}],
    "features": {"lines": [[-20, -20, 80, -20]]},
}


def _scenario(tmp_path: Path) -> Path:
    path = tmp_path / "mini.json"
    path.write_text(json.dumps(SCENARIO))
    return path


def _sim(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        # not `python -m auvgw.cli`: that runs cli.py twice (as __main__ and as auvgw.cli)
        [sys.executable, "-c", "import sys; from auvgw.cli import main; sys.exit(main())",
         "sim", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _read_until(proc: subprocess.Popen[str], marker: str, timeout: float = 60.0) -> list[str]:
    assert proc.stdout is not None
    lines: list[str] = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip("\n"))
        if marker in line:
            return lines
    pytest.fail(f"no {marker!r} from auvgw sim; got {lines}; stderr {proc.stderr.read()}")  # type: ignore[union-attr]


@pytest.mark.e2e
def test_sim_serves_its_ports_and_stops_cleanly_on_sigint(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _sim("--scenario", str(_scenario(tmp_path)), "--speed", "5", "--out", str(out))
    try:
        head = _read_until(proc, "running; Ctrl-C to stop")
        text = "\n".join(head)
        assert "scenario 'cli-mini'" in text and "5x real time" in text
        rows = [ln.split() for ln in head if ln.startswith("  ") and "not emulated" not in ln]
        ports = {row[0]: row for row in rows[1:]}  # after the column titles
        assert {"ins", "ins_can", "magnetometer", "magnetometer_can", "msis"} <= set(ports)
        assert ports["ins"][1:3] == ["hn100", "serial"]
        assert ports["multibeam"][1:3] == ["kongsberg", "udp"]
        cfg = load_gateway_config(out / "gateway.toml")
        for name in ("ins", "magnetometer", "msis"):
            url = cfg.devices[name].transport.url
            assert url == str(out / "ports" / name) and os.readlink(url) == ports[name][4]
        # a real client on the configured ports gets the real protocol
        with serial.Serial(cfg.devices["ins"].transport.url, 115200, timeout=0.1) as s:
            framer = hn100.Hn100Framer()
            frames: list = []
            end = time.monotonic() + 10
            while len(frames) < 20 and time.monotonic() < end:
                frames += framer.feed(s.read(max(1, s.in_waiting)))
        msgs = [hn100.CODEC.decode(f.data) for f in frames]
        assert len(msgs) >= 20 and all(m.depth == pytest.approx(5.0, abs=0.2) for m in msgs)
        assert [m.seq for m in msgs] == list(range(msgs[0].seq, msgs[0].seq + len(msgs)))
        assert msgs[-1].time - msgs[0].time == pytest.approx(0.01 * (len(msgs) - 1), abs=1e-3)
        with serial.Serial(cfg.devices["magnetometer"].transport.url, 38400, timeout=0.1) as s:
            framer2 = ms3a.Ms3aFramer()
            lines: list = []
            end = time.monotonic() + 10
            while len(lines) < 3 and time.monotonic() < end:
                lines += framer2.feed(s.read(max(1, s.in_waiting)))
        assert 40000 < abs(ms3a.CODEC.decode(lines[0].data).bz) < 50000  # Earth field, down
        tr = cfg.devices["ins_can"].transport
        bus = can.Bus(interface="slcan", channel=tr.channel, bitrate=tr.bitrate,
                      **tr.options)  # fmt: skip
        try:
            codec = hn100_can()
            asm = codec.assembler()
            sample = None
            end = time.monotonic() + 10
            while sample is None and time.monotonic() < end:
                m = bus.recv(timeout=0.5)
                if m is not None:
                    sample = asm.add(codec.decode_frame(m))
        finally:
            bus.shutdown()
        assert sample is not None and sample.depth == pytest.approx(5.0, abs=0.2)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "stopped at vehicle time" in stdout and "Traceback" not in stderr
    assert not any((out / "ports").iterdir()), "ports are gone after the sim stops"
    assert (out / "truth.jsonl").stat().st_size > 0


@pytest.mark.e2e
@pytest.mark.parametrize("processes", [False, True], ids=["one-process", "process-per-device"])
def test_sim_runs_for_a_duration_and_applies_the_fault_control_file(
    tmp_path: Path, processes: bool
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "faults.json").write_text(json.dumps({"magnetometer": {"dropout_p": 1.0}}))
    # vehicle time 0 when the go file says (an hour at the latest: the run would never end in
    # the test's time without it); a stale one is removed first (read, it would be exit 2)
    go = out / "go"
    go.write_text("stale")
    extra = ["--processes"] if processes else []
    proc = _sim("--scenario", str(_scenario(tmp_path)), "--speed", "2", "--duration", "3",
                "--out", str(out), "--devices", "ins,magnetometer", "--truth-rate", "5",
                "--start-delay", "3600", "--start-when", str(go), *extra)  # fmt: skip
    try:
        wait_until(lambda: (out / "gateway.toml").is_file() or proc.poll() is not None,
                   what="the sim's gateway.toml")  # fmt: skip
        (out / "go.new").write_text(f"{time.monotonic() + 0.2!r}\n")
        os.replace(out / "go.new", go)
        stdout, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "vehicle time 0: go's, " in stdout and "s before --start-delay's" in stdout
    assert "stopped at vehicle time 3.00 s" in stdout
    assert ("one process per device" in stdout) == processes
    stats = {ln.split()[0]: ln for ln in stdout.splitlines()[-4:] if ln.startswith("  ")}
    assert set(stats) == {"ins", "ins_can", "magnetometer", "magnetometer_can"}
    assert "samples     301" in stats["ins"] and "faults" not in stats["ins"]
    assert "'dropped':" in stats["magnetometer"] and "'dropped':" in stats["magnetometer_can"]
    rows = [json.loads(r) for r in (out / "truth.jsonl").read_text().splitlines()]
    assert [r["t"] for r in rows] == pytest.approx([k * 0.2 for k in range(16)])
    assert rows[-1]["x"] == pytest.approx(1.5 * 3.0, abs=0.05)
    cfg = load_gateway_config(out / "gateway.toml")
    assert set(cfg.devices) == {"ins", "ins_can", "magnetometer", "magnetometer_can"}
    # elastic pacing (the default): the gateway stamps the sim's own clock file, which ends
    # held within the lag of the run's end; every device process reported its dispatch there
    pacing = next(ln for ln in stdout.splitlines() if ln.startswith("pacing elastic: 3.0 "))
    assert "max lag" in pacing and "timeouts" in pacing
    assert cfg.clock.sim_clock == str(out / "clock")
    from auvgw.ground.simclock import ClockFileReader, DispatchBoard

    reader = ClockFileReader(out / "clock")
    assert 3.0 <= (reader.vehicle_s() or 0.0) <= 3.0 + 0.15 + 1e-9
    reader.close()
    if processes:
        board = DispatchBoard(out / "clock.dispatch")
        assert board.slots == 2 and board.least(range(2)) >= 3.0  # ins, magnetometer
        board.close()


def test_sim_bad_input_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    from auvgw.cli import main

    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**SCENARIO, "vehicle": {"waypoints": [[0, 0]]}}))
    assert main(["sim", "--scenario", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"auvgw sim: error: {bad}: vehicle: " in err
    assert main(["sim", "--scenario", str(tmp_path / "missing.json")]) == 2
    assert "missing.json: cannot read" in capsys.readouterr().err
    args = ["sim", "--scenario", str(_scenario(tmp_path)), "--out", str(tmp_path / "o")]
    assert main([*args, "--devices", "ins,sonar"]) == 2
    assert "unknown device(s) sonar" in capsys.readouterr().err
    assert main([*args, "--speed", "-1"]) == 2
    assert "--speed must be >= 0" in capsys.readouterr().err
    assert main([*args, "--lockstep", "--speed", "0"]) == 2
    assert "--lockstep needs one process" in capsys.readouterr().err
    assert main([*args, "--lockstep", "--lockstep-timeout", "0"]) == 2
    assert "--lockstep-timeout must be > 0" in capsys.readouterr().err
    assert main([*args, "--elastic-lag", "0"]) == 2
    assert "--elastic-lag must be > 0" in capsys.readouterr().err
    assert main([*args, "--pace", "free", "--start-when", str(tmp_path / "go")]) == 2
    assert "--start-when needs a real-time clock (--speed > 0) paced elastic or --lockstep" \
        in capsys.readouterr().err


@pytest.mark.e2e
def test_sim_holds_the_ports_of_its_device_processes(tmp_path: Path) -> None:
    """``--processes --hold`` (the GeoSwath survey demo's sim, issue 31: the GeoSwath's numpy
    work in its own process, never in the INS's interpreter): at the run's end every device
    process has sent every sample up to it, writes ``finished`` and keeps its ports open,
    silent, until SIGTERM; the gateway configuration names the GeoSwath's model."""
    scn = tmp_path / "gs.json"
    scn.write_text(json.dumps({**SCENARIO, "devices": {"geoswath": {"enabled": True}}}))
    out = tmp_path / "out"
    proc = _sim("--scenario", str(scn), "--speed", "2", "--duration", "3", "--out", str(out),
                "--devices", "ins,geoswath", "--processes", "--hold")  # fmt: skip
    try:
        head = "\n".join(_read_until(proc, "finished; ports held open", timeout=120.0))
        assert "one process per device" in head
        assert (out / "finished").read_text().strip() == "3.000"
        assert os.path.exists(os.readlink(out / "ports" / "ins"))  # the pty is still there
        cfg = load_gateway_config(out / "gateway.toml")
        assert set(cfg.devices) == {"ins", "ins_can", "geoswath"}
        gs = cfg.devices["geoswath"].geoswath
        assert gs is not None and gs.model_khz == 250
        assert proc.poll() is None  # held until told
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "stopped at vehicle time 3.00 s" in stdout and "Traceback" not in stderr
    stats = {ln.split()[0]: ln.split() for ln in stdout.splitlines() if ln.startswith("  ")}
    assert stats["ins"][1:3] == ["samples", "301"] and stats["geoswath"][1:3] == ["samples", "13"]
    assert not any((out / "ports").iterdir()), "ports are gone after the sim stops"
