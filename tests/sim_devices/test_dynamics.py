"""Vehicle dynamics (sim_devices.dynamics): structure, energy and sanity checks."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from auvgw.sim_devices import dynamics as d

P = d.load_params()


def _run(p: d.VehicleParams, x: np.ndarray, inputs: list[float], seconds: float,
         dt: float = 0.02) -> np.ndarray:
    for _ in range(round(seconds / dt)):
        x = d.step(p, x, np.array(inputs), dt)
    return x


def test_every_parameter_cites_a_source(tmp_path: Path) -> None:
    text = d.REMUS100_FILE.read_text()
    bad = tmp_path / "v.toml"
    bad.write_text(text.replace('source = "[P01] Xudot = -9.30e-1 kg"', 'source = ""'))
    with pytest.raises(ValueError, match="Xudot has no source"):
        d.load_params(bad)


def test_mass_matrix_symmetric_positive_definite() -> None:
    m = d.mass_matrix(P)
    assert np.allclose(m, m.T)
    assert np.linalg.eigvalsh(m).min() > 0
    assert m[0, 0] == pytest.approx(30.48 + 0.93)


def test_coriolis_does_no_work() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        nu = rng.normal(size=6)
        c_rb, c_a = d.coriolis(P, nu)
        assert np.allclose(c_a, -c_a.T)
        assert nu @ (c_rb + c_a) @ nu == pytest.approx(0.0, abs=1e-9)


def test_energy_conserved_without_damping_and_propulsion() -> None:
    p = P.conservative()
    x = np.array([1.0, 0.2, -0.1, 0.3, 0.1, -0.2, 0, 0, 5.0, 0.2, 0.1, 0.5])
    e0 = d.energy(p, x)
    energies = []
    for _ in range(1000):  # 10 s at dt = 0.01
        x = d.step(p, x, np.array([0.3, 0.3, 1500.0]), 0.01)
        energies.append(d.energy(p, x))
    drift = max(abs(e - e0) for e in energies)
    assert drift < 1e-6 * max(1.0, abs(e0)) + 1e-6, drift
    # and with damping on, it is dissipated
    y = _run(P, np.array([1.0, 0.2, -0.1, 0.3, 0.1, -0.2, 0, 0, 5.0, 0.2, 0.1, 0.5]),
             [0, 0, 0], 5.0)
    assert d.energy(P, y) < e0


def test_passive_neutral_vehicle_settles_to_the_cg_cb_trim() -> None:
    # CG 2 mm ahead of and 19.6 mm below the CB: trim pitch where the CG hangs under the CB,
    # xg cos(theta) + zg sin(theta) = 0; roll trims to 0; neutral, so no depth change
    xg, zg = 0.002, P.r_g[2]
    p = replace(P, r_g=(xg, 0.0, zg), buoyancy=P.weight)
    x = np.zeros(12)
    x[9], x[10] = 0.3, 0.2  # released rolled and pitched
    x = _run(p, x, [0, 0, 0], 120.0, dt=0.05)
    assert x[10] == pytest.approx(math.atan2(-xg, zg), abs=2e-3)
    assert abs(x[9]) < 1e-3
    assert abs(x[8]) < 0.2  # only the transient of the released pitch oscillation
    assert np.abs(x[:6]).max() < 2e-3


def test_passive_buoyant_vehicle_rises_at_the_drag_balance() -> None:
    # net buoyancy B - W > 0 against the cross-flow drag: w = -sqrt((B - W) / |Zww|)
    x = _run(P, np.zeros(12), [0, 0, 0], 60.0, dt=0.05)
    w_ned = (d.rotation(*x[9:12]) @ x[:3])[2]
    assert w_ned == pytest.approx(-math.sqrt((P.buoyancy - P.weight) / -P.quad[2]), rel=0.05)
    assert x[8] < -5.0 and abs(x[9]) < 1e-3


def test_zero_rudder_goes_straight() -> None:
    p = replace(P, torque_per_thrust=0.0)
    x = _run(p, np.array([1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.7]), [0, 0, 800], 20.0)
    assert x[11] == pytest.approx(0.7, abs=1e-9)  # no yaw drift
    assert x[1] == pytest.approx(0.0, abs=1e-9) and x[5] == pytest.approx(0.0, abs=1e-9)
    assert x[6] > 5 and x[7] / x[6] == pytest.approx(math.tan(0.7), rel=1e-3)


def test_inputs_saturate_and_current_carries_the_vehicle() -> None:
    x = np.zeros(12)
    a = d.step(P, x, np.array([1.0, 0, 0]), 0.1)
    b = d.step(P, x, np.array([P.max_rudder, 0, 0]), 0.1)
    assert np.array_equal(a, b)
    # neutral, passive vehicle in a current: after a while it drifts with the water
    p = replace(P, buoyancy=P.weight)
    y = np.zeros(12)
    for _ in range(600):
        y = d.step(p, y, np.zeros(3), 0.05, current_ned=np.array([0.0, 0.3, 0.0]))
    v_ned = d.rotation(*y[9:12]) @ y[:3]
    assert v_ned[1] == pytest.approx(0.3, abs=0.03)
    with pytest.raises(ValueError, match="dt"):
        d.step(P, x, np.zeros(3), 0.0)


def test_step_refuses_to_cross_the_euler_singularity() -> None:
    x = np.zeros(12)
    x[10], x[4] = math.radians(84.9), 1.0  # pitching up through 85 deg
    with pytest.raises(d.PitchSingularityError, match="singular"):
        d.step(P, x, np.zeros(3), 0.01)


# --- Fossen's 2021 spheroid set (config/vehicles/remus100_fossen.toml), open-loop stable ---

PF = d.load_params(d.REMUS100_FOSSEN_FILE)


def test_fossen_set_derives_the_spheroid_and_cites_every_number(tmp_path: Path) -> None:
    # m = 4/3 pi rho a b^2 for the 1.6 m x 0.19 m spheroid; neutral (W = B); Lamb's k-factors
    assert PF.mass == pytest.approx(4 / 3 * math.pi * 1026 * 0.8 * 0.095**2)
    assert PF.weight == PF.buoyancy
    assert PF.spheroid is not None and PF.spheroid.strips[0] == pytest.approx(-0.8)
    assert len(PF.spheroid.strips) == 21 and PF.spheroid.strips[-1] == pytest.approx(0.8)
    assert -PF.added[0] / PF.mass == pytest.approx(0.027, abs=0.001)  # k1 of a 8.4:1 spheroid
    assert -PF.added[1] / PF.mass == pytest.approx(0.949, abs=0.002)  # k2
    m = d.mass_matrix(PF)
    assert np.allclose(m, m.T) and np.linalg.eigvalsh(m).min() > 0
    text = d.REMUS100_FOSSEN_FILE.read_text()
    bad = tmp_path / "f.toml"
    bad.write_text(text.replace('"[PVS] T_yaw = 5 s (the 2021 [MSS] file had 1 s)"', '" "'))
    with pytest.raises(ValueError, match="T_yaw has no source"):
        d.load_params(bad)


@pytest.mark.parametrize("p", [P, PF], ids=["prestero", "fossen"])
def test_fast_rhs_matches_the_matrix_form_of_each_set(p: d.VehicleParams) -> None:
    """rhs() works on floats; check it against M^-1 (tau - C nu - g) built from the matrices."""
    rng = np.random.default_rng(11)
    m_inv = np.linalg.inv(d.mass_matrix(p))
    for _ in range(5):
        x = rng.normal(scale=0.3, size=12)
        x[0] += 1.5
        inputs = np.array([0.1, -0.2, 1200.0])
        nu = x[:6]
        c_rb, c_a = d.coriolis(p, nu)
        assert np.allclose(d.coriolis_force(p, nu), (c_rb + c_a) @ nu)
        expected = m_inv @ (d.forces(p, nu, inputs) - (c_rb + c_a) @ nu - d.restoring(p, x[6:]))
        assert np.allclose(d.rhs(p, x, inputs)[:6], expected)
        assert np.allclose(d.rhs(p, x, inputs)[6:9], d.rotation(*x[9:12]) @ nu[:3])
    # the spheroid form has no Munk moment: a pure sideslip at speed gives no yaw moment
    c_rb, c_a = d.coriolis(PF, np.array([2.0, 0.3, 0.0, 0.0, 0.0, 0.0]))
    assert c_a[5, :2].tolist() == [0.0, 0.0]


def test_fossen_set_holds_a_straight_line_and_a_steady_turn() -> None:
    # without propeller torque the symmetric vehicle goes straight at zero rudder
    s = PF.spheroid
    assert s is not None
    no_torque = replace(PF, spheroid=replace(s, kq=(0.0, 0.0)))
    x = _run(no_torque, np.array([1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -0.4]), [0, 0, 1000], 20.0,
             dt=0.05)
    assert x[11] == pytest.approx(-0.4, abs=1e-9) and abs(x[1]) < 1e-9 and abs(x[9]) < 1e-9
    assert x[6] > 20 and x[7] / x[6] == pytest.approx(math.tan(-0.4), rel=1e-6)
    # open-loop stable: a fixed rudder settles into a circle (the Prestero set spirals in)
    start = np.zeros(12)
    start[0] = 1.67
    a = _run(no_torque, start, [math.radians(15), 0, 1000], 100.0, dt=0.05)
    b = _run(no_torque, a, [math.radians(15), 0, 1000], 10.0, dt=0.05)
    assert a[5] < 0  # positive rudder: bow to port (Prestero's convention for both sets)
    assert b[5] == pytest.approx(a[5], rel=1e-3) and b[0] == pytest.approx(a[0], rel=1e-3)
    diameter = 2 * b[0] / abs(b[5])
    assert 40 < diameter < 65  # manoeuvres.txt: 51.9 m at 15 deg, 1000 rpm


def test_fossen_set_speed_at_full_shaft_speed() -> None:
    # the header's 2.5 m/s at 1525 rpm (the propeller line's anchor, so a consistency check)
    x = _run(PF, np.zeros(12), [0, 0, 1525], 60.0, dt=0.05)
    assert float(np.linalg.norm(x[:3])) == pytest.approx(2.5, rel=0.10)
    # and the implementation: the surge balance solved by hand, (1 - t) rho D^4 (KT0 n^2 +
    # dKT/dJ (w U / D) n) = 1/2 rho U^2 S CD0 + M11 / T_surge exp(-3 U) U
    s = PF.spheroid
    assert s is not None
    n = 1525 / 60

    def surplus(u: float) -> float:
        thrust = (1 - s.t_prop) * s.rho * s.d_prop**4 * (
            s.kt[0] * n * n + s.kt[1] * s.wake * u / s.d_prop * n)
        return thrust - 0.5 * s.rho * u * u * s.area * s.cd0 - s.lin[0] * math.exp(-3 * u) * u

    lo, hi = 2.0, 3.0
    for _ in range(50):
        lo, hi = ((lo + hi) / 2, hi) if surplus((lo + hi) / 2) > 0 else (lo, (lo + hi) / 2)
    assert x[0] == pytest.approx(lo, rel=2e-3)


def test_fossen_passive_vehicle_rights_itself_and_dissipates() -> None:
    x = np.zeros(12)
    x[9], x[10], x[4] = 0.4, -0.3, 0.2  # released rolled, pitched and pitching
    e0 = d.energy(PF, x)
    energies = []
    for _ in range(int(60 / 0.05)):
        x = d.step(PF, x, np.zeros(3), 0.05)
        energies.append(d.energy(PF, x))
    assert abs(x[9]) < 2e-3 and abs(x[10]) < 2e-3  # CG under CB, neutral: trims level
    assert abs(x[8]) < 0.05  # W = B: no depth change
    assert energies[-1] < 1e-3 * e0
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(energies))


def test_fossen_crossflow_closed_form_equals_the_strip_sum() -> None:
    s = PF.spheroid
    assert s is not None
    for v, r in [(0.3, 0.1), (-0.3, 0.2), (0.05, 0.4), (0.0, -0.3), (-0.2, 0.0), (0.0, 0.0)]:
        nu = np.array([1.5, v, 0.0, 0.0, 0.0, r])
        tau = d.forces(PF, nu, np.zeros(3))
        lin = s.lin
        k = math.exp(-s.decay * math.hypot(1.5, v))
        y = -s.crossflow * sum((v + x * r) * abs(v + x * r) for x in s.strips) - lin[1] * k * v
        n = -s.crossflow * sum(x * (v + x * r) * abs(v + x * r) for x in s.strips) - lin[5] * k * r
        assert tau[1] == pytest.approx(y, rel=1e-9, abs=1e-12)
        assert tau[5] == pytest.approx(n, rel=1e-9, abs=1e-12)


def test_a_scenario_selects_the_fossen_set(tmp_path: Path) -> None:
    """vehicle.dynamics.params of a closed-loop scenario picks the file; the stable vehicle,
    with no controller at all (zero fins, the scenario's rpm), keeps its heading and depth."""
    from auvgw.config.scenario import load_scenario
    from auvgw.sim_devices.closedloop import ClosedLoopTruth
    from auvgw.sim_devices.world import World

    root = d.REMUS100_FILE.parent.parent
    data = json.loads((root / "scenarios" / "closed_loop.json").read_text())
    data["vehicle"]["dynamics"]["params"] = str(d.REMUS100_FOSSEN_FILE)
    path = tmp_path / "fossen.json"
    path.write_text(json.dumps(data))
    scn = load_scenario(path)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn))
    assert truth.params.spheroid is not None
    start = truth.state.copy()
    truth.at(10.0)
    assert truth.steps == round(10.0 / truth.dt)
    assert abs(truth.state[11] - start[11]) < math.radians(1.0)
    assert abs(truth.state[8] - start[8]) < 0.2
    assert truth.state[0] > 1.0
