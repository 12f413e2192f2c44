"""DVL calibration (mounting yaw and scale factor from position fixes) and the CSV log import,
through the functions and through ``auvgw fusion [calibrate] --csv LOG --columns MAP``.

The run: 30 minutes of a survey with 800 m lines at 1.5 m/s (fusion.synthetic, HN-100 attitude
noise with its 0.3 deg correlated heading error, Pathfinder-grade DVL at 5 Hz) with a planted
26 deg mounting yaw and a 1 % scale factor, and GNSS fixes (1 m) every 30 s as if the vehicle
surfaced for them.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from auvgw.cli import main as cli_main
from auvgw.fusion import DvlMount
from auvgw.fusion.calibrate import CalibrationError, calibrate_dvl
from auvgw.fusion.csvlog import LogError, load_column_map, read_csv_log
from auvgw.fusion.synthetic import SensorNoise, lawnmower, simulate_sensors

PLANTED = DvlMount(rotation_deg=(0.0, 0.0, 26.0))
MAP = """angles = "deg"
[columns]
t = "time"
heading = "yaw"
roll = "roll"
pitch = "pitch"
dvl_x = "vx"
dvl_y = "vy"
dvl_z = "vz"
fix_north = "gps_n"
fix_east = "gps_e"
[options]
fix_sigma_m = 1.0
"""


def _run(scale: float, seed: int = 0):
    truth = lawnmower(duration_s=1800.0, rate_hz=10.0, leg_m=800.0, spacing_m=50.0)
    noise = SensorNoise(dvl_scale_factor=scale, fix_sigma_m=1.0)
    return simulate_sensors(truth, np.random.default_rng(seed), noise=noise, mount=PLANTED,
                            fix_times=np.arange(0.0, 1800.0, 30.0))


@pytest.fixture(scope="module")
def sim():
    return _run(1.01)


def test_calibration_recovers_planted_mounting_yaw_and_scale(sim):
    cal = calibrate_dvl(sim.ins, sim.dvl, sim.fixes, DvlMount())
    assert abs(cal.yaw_deg - 26.0) < 1.0
    assert abs(cal.scale_factor - 1.01) < 0.002
    assert 0 < cal.yaw_sigma_deg < 1.0 and 0 < cal.scale_sigma < 0.005
    assert cal.fixes == 59 and cal.distance_m > 2500  # the fix at t=0 precedes the DVL
    # not vacuous: no planted scale -> 1.000
    plain = calibrate_dvl(*_parts(_run(1.0)), DvlMount())
    assert abs(plain.scale_factor - 1.0) < 0.002 and abs(plain.scale_factor - 1.01) > 0.008


def _parts(s):
    return s.ins, s.dvl, s.fixes


def test_calibration_says_what_is_missing(sim):
    with pytest.raises(CalibrationError, match="at least 3 position fixes"):
        calibrate_dvl(sim.ins, sim.dvl, sim.fixes[:2])
    with pytest.raises(CalibrationError, match="attitude"):
        calibrate_dvl([], sim.dvl, sim.fixes)


def _write_log(sim, path) -> None:
    fixes = {round(f.t, 3): f for f in sim.fixes}
    dvl = {round(d.t, 1): d for d in sim.dvl}  # on the 10 Hz grid of the log
    lines = ["time,yaw,roll,pitch,vx,vy,vz,gps_n,gps_e"]
    for s in sim.ins:
        k = round(s.t, 3)
        d = dvl.get(round(s.t, 1)) if abs(s.t * 5 - round(s.t * 5)) < 1e-6 else None
        f = fixes.get(k)
        v = ("", "", "") if d is None else tuple(f"{c:.5f}" for c in d.velocity)
        fx = ("", "") if f is None else (f"{f.north:.3f}", f"{f.east:.3f}")
        lines.append(
            f"{s.t:.3f},{math.degrees(s.heading):.4f},{math.degrees(s.roll):.4f},"
            f"{math.degrees(s.pitch):.4f},{','.join(v)},{','.join(fx)}"
        )
    path.write_text("\n".join(lines) + "\n")


def test_cli_calibrate_and_run_over_a_csv_log(sim, tmp_path, capsys):
    log = tmp_path / "log.csv"
    _write_log(sim, log)
    cmap = tmp_path / "map.toml"
    cmap.write_text(MAP)
    parsed = read_csv_log(log, load_column_map(cmap))
    assert len(parsed.ins) == len(sim.ins) and len(parsed.fixes) == 60 and parsed.bad_cells == 0
    assert len(parsed.dvl) > 8000
    assert cli_main(["fusion", "calibrate", "--csv", str(log), "--columns", str(cmap)]) == 0
    out = capsys.readouterr().out
    yaw = float(re.search(r"mounting yaw\s+(-?[\d.]+) deg \+- ([\d.]+)", out).group(1))
    scale = float(re.search(r"scale factor\s+([\d.]+) \+- ([\d.]+)", out).group(1))
    assert abs(yaw - 26.0) < 1.0 and abs(scale - 1.01) < 0.003
    # the fusion over the same log, calibrated through the settings, with its diagnostics
    settings = tmp_path / "fusion.toml"
    settings.write_text(
        f"[filter]\nheading_error_tau_s = 0.0\n[filter.dvl]\nrotation_deg = [0.0, 0.0, {yaw}]\n"
        f"scale_factor = {scale}\n[filter.initial]\nposition_sigma_m = [5.0, 5.0, 1.0]\n"
    )
    assert cli_main(["fusion", "--csv", str(log), "--columns", str(cmap),
                     "--settings", str(settings)]) == 0
    out = capsys.readouterr().out
    assert "DVL fixes" in out and "accepted" in out and "coasting" in out and "NIS" in out
    err_m = float(re.search(r"final position\s+x (-?[\d.]+) m, y (-?[\d.]+)", out).group(1))
    assert abs(err_m - sim.truth.x[-1]) < 10.0  # GNSS fixes keep it near the truth


def test_log_errors_name_file_line_and_column(tmp_path):
    cmap = tmp_path / "map.toml"
    cmap.write_text(MAP.replace('yaw"', 'psi"'))
    log = tmp_path / "log.csv"
    log.write_text("time,yaw,roll,pitch,vx,vy,vz,gps_n,gps_e\n0.0,1,0,0,,,,,\n")
    with pytest.raises(LogError, match=r"log.csv: line 1: column 'psi' \(mapped to heading\)"):
        read_csv_log(log, load_column_map(cmap))
    cmap.write_text(MAP)
    log.write_text("time,yaw,roll,pitch,vx,vy,vz,gps_n,gps_e\n0.0,1,0,0,,,,,\n0.1,x,0,0,1,0,0,,\n")
    got = read_csv_log(log, load_column_map(cmap))
    assert got.bad_cells == 1 and "line 3: column 'yaw': 'x' is not a number" in got.first_error
    assert len(got.ins) == 1 and len(got.dvl) == 1  # the row's DVL fix is kept
    bad = tmp_path / "bad.toml"
    bad.write_text('[columns]\nheading = "yaw"\n')
    with pytest.raises(LogError, match=r"bad\.toml: columns\.t: "):
        load_column_map(bad)
