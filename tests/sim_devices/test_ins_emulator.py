"""The HN-100 INS emulator's slowly varying heading error: a first-order Gauss-Markov bias
(statistics of the exact discretisation), a constant offset, the NED velocity resolved with the
erroneous heading, everything else unchanged, and clear errors for bad settings."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.ins import InsEmulator
from auvgw.sim_devices.vehicle import simulate
from auvgw.sim_devices.world import World

DEG = math.pi / 180.0

#: a long straight run with a turn (the truth lasts ~1400 s)
BASE: dict[str, Any] = {
    "name": "ins-test",
    "seed": 11,
    "vehicle": {"waypoints": [[0, 0], [1000, 0], [1000, 1000]], "speed_mps": 1.5},
    "terrain": {"kind": "flat", "depth_m": 30.0},
}


def context(tmp_path: Path, noise: dict[str, float]) -> SimContext:
    ins = {"noise": noise, "options": {"serial": False, "can": False}}
    scn = Scenario.model_validate({**BASE, "devices": {"ins": ins}})
    world = World.from_scenario(scn)
    return SimContext(scn, world, simulate(scn, world), SimClock(0), tmp_path / "ports")


def heading_error(em: InsEmulator, t: float) -> tuple[float, Any]:
    """Reported minus true heading (rad, wrapped) of one sample, and the sample."""
    m = em.measure(t)
    e = (m.heading - em.truth(t).heading + math.pi) % (2 * math.pi) - math.pi
    return e, m


def test_gauss_markov_heading_bias_has_its_correlation_and_steady_state_rms(tmp_path):
    sigma, tau, dt = 0.4, 50.0, 1.0
    ctx = context(tmp_path, {"heading_deg": 0.0, "heading_bias_deg": sigma,
                             "heading_bias_tau_s": tau})  # fmt: skip
    em = InsEmulator(ctx)
    times = np.arange(0.0, 1300.0, dt)
    samples = [heading_error(em, float(t)) for t in times]
    e = np.array([s[0] for s in samples]) / DEG
    # without white noise the reported error is exactly the slowly varying part
    np.testing.assert_allclose(e, [s[1].heading_error / DEG for s in samples], atol=1e-9)
    # AR(1) of the exact discretisation: e_k+1 = phi e_k + sqrt(1 - phi^2) sigma w
    phi = math.exp(-dt / tau)
    phi_hat = float(e[1:] @ e[:-1] / (e[:-1] @ e[:-1]))
    assert phi_hat == pytest.approx(phi, abs=0.012)
    resid = e[1:] - phi * e[:-1]
    assert resid.std() == pytest.approx(sigma * math.sqrt(1 - phi * phi), rel=0.06)
    # the stationary start: the first value over many independent devices is N(0, sigma^2)
    first = np.array([InsEmulator(ctx, name=f"ins{k}").heading_error(0.0) for k in range(400)])
    assert first.std() / DEG == pytest.approx(sigma, rel=0.1)
    assert abs(first.mean() / DEG) < 3 * sigma / math.sqrt(400)


def test_heading_offset_turns_heading_and_velocity_and_changes_no_other_draw(tmp_path):
    plain = InsEmulator(context(tmp_path / "a", {}))
    turned = InsEmulator(context(tmp_path / "b", {"heading_offset_deg": 1.0,
                                                  "heading_bias_deg": 0.3}))  # fmt: skip
    for t in (3.0, 400.0, 700.0, 1100.0):
        a, b = plain.measure(t), turned.measure(t)
        err = b.heading_error
        assert abs(err / DEG - 1.0) < 4 * 0.3  # the offset plus a bias of 0.3 deg RMS
        dh = (b.heading - a.heading + math.pi) % (2 * math.pi) - math.pi
        assert dh == pytest.approx(err, abs=1e-12)  # the same white noise on top
        # the true velocity turned by the error, plus the same white noise
        c, s = math.cos(err), math.sin(err)
        tr = plain.truth(t)
        turn = [(c - 1) * tr.vn - s * tr.ve, s * tr.vn + (c - 1) * tr.ve, 0.0]
        np.testing.assert_allclose(np.subtract(b.vel_ned, a.vel_ned), turn, atol=1e-12)
        # everything else is the very same draw
        assert (b.roll, b.pitch, b.rates, b.accel) == (a.roll, a.pitch, a.rates, a.accel)
        assert (b.latitude, b.longitude, b.depth) == (a.latitude, a.longitude, a.depth)
    assert plain.measure(1200.0).heading_error == 0.0  # off by default


@pytest.mark.parametrize(
    ("noise", "match"),
    [
        ({"heading_bias_deg": 0.3, "heading_bias_tau_s": 0.0}, "heading_bias_tau_s"),
        ({"heading_bias_deg": -0.1}, "heading_bias_deg"),
        ({"heading_bias_dg": 0.3}, r"devices\.ins\.noise\.heading_bias_dg.*heading_bias_deg"),
    ],
)
def test_bad_heading_error_settings_are_named(tmp_path, noise, match):
    with pytest.raises(ValueError, match=match):
        InsEmulator(context(tmp_path, noise))
