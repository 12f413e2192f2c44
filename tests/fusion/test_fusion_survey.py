"""Statistical check of the dead reckoning on a 30-minute survey with HN-100 / Pathfinder noise.

A lawnmower at 1.5 m/s (2.7 km), INS at 100 Hz with Gauss-Markov heading (0.3 deg RMS) and
roll/pitch (0.02 deg RMS) errors, DVL at 5 Hz (0.2 cm/s, lever arm and 45 deg mounting yaw),
pressure depth at 1 Hz. Fixed seeds. The two negative controls show the assertions can fail: a
filter that takes the INS heading error for white noise is inconsistent, and one that ignores the
DVL mounting rotation misses the accuracy bound.
"""

from __future__ import annotations

import numpy as np
import pytest

from auvgw.fusion import DvlMount, FusionConfig, InitialState, run_filter_arrays
from auvgw.fusion.offline import OdometryArrays
from auvgw.fusion.synthetic import SensorNoise, Trajectory, lawnmower, simulate_sensors

MOUNT = DvlMount(lever_arm_m=(-0.6, 0.1, 0.35), rotation_deg=(0.0, 0.0, 45.0))
NOISE = SensorNoise()  # HN-100 / Pathfinder figures
CHI2_2DOF_95 = 5.991
#: fixed seed; docs/fusion.md gives the Monte Carlo spread over seeds (a single 30-minute run
#: holds only a few correlation times of the heading error, so runs differ a lot)
SEED = 0


def config(**kw) -> FusionConfig:
    return FusionConfig(dvl=MOUNT, initial=InitialState(position_m=(0.0, 0.0, 20.0)), **kw)


def horizontal_nees(out: OdometryArrays, truth: Trajectory) -> np.ndarray:
    e = np.stack([out.x - truth.x, out.y - truth.y], axis=1)
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(out.cov_xy), e)


@pytest.fixture(scope="module")
def survey() -> tuple[Trajectory, OdometryArrays]:
    truth = lawnmower(duration_s=1800.0, speed_mps=1.5, leg_m=200.0, spacing_m=20.0)
    sim = simulate_sensors(truth, np.random.default_rng(SEED), noise=NOISE, mount=MOUNT)
    return truth, run_filter_arrays(sim.ins, sim.dvl, config(), sim.depth)


def test_survey_final_horizontal_error_under_1_percent_of_distance(survey):
    truth, out = survey
    distance = truth.distance()
    assert 2690.0 < distance < 2710.0 and len(out) == 180_001
    err = np.hypot(out.x - truth.x, out.y - truth.y)
    assert err[-1] < 0.01 * distance
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(truth.x), np.diff(truth.y)))])
    late = travelled > 500.0
    assert (err[late] < 0.01 * travelled[late]).all()  # and all along, once past 500 m


def test_survey_2_sigma_ellipse_contains_the_truth_90_percent_of_epochs(survey):
    truth, out = survey
    nees = horizontal_nees(out, truth)
    assert np.mean(nees <= CHI2_2DOF_95) >= 0.90
    # not vacuous: a covariance ten times too large (in sigma) would put the mean NEES near 0.02
    assert nees.mean() > 0.2


def test_survey_depth_velocity_and_flags(survey):
    truth, out = survey
    assert np.abs(out.z - truth.z)[out.t > 10.0].max() < 0.1
    v_err = out.velocity_body - np.stack([truth.u, truth.v, truth.w], axis=1)
    assert np.sqrt(np.mean(v_err[out.t > 1.0] ** 2)) < 0.005
    assert not out.coasting[out.t > 1.0].any() and out.stats.dvl_rejected < 5
    assert out.stats.dvl_updates >= 8990 and out.stats.depth_updates == 1800


def test_filter_treating_the_heading_error_as_white_fails_the_consistency_check():
    """The mistake the error-state design avoids: with a white heading error the filter believes
    it averages out, and its ellipse shrinks far below the real, correlated error."""
    truth = lawnmower(duration_s=400.0)
    sim = simulate_sensors(truth, np.random.default_rng(SEED), noise=NOISE, mount=MOUNT)
    out = run_filter_arrays(sim.ins, sim.dvl, config(heading_error_tau_s=0.0), sim.depth)
    nees = horizontal_nees(out, truth)
    assert np.mean(nees <= CHI2_2DOF_95) < 0.75 and nees.mean() > 5.0


def test_ignoring_the_dvl_mounting_fails_the_accuracy_check():
    truth = lawnmower(duration_s=120.0)
    sim = simulate_sensors(truth, np.random.default_rng(SEED), noise=NOISE, mount=MOUNT)
    wrong = FusionConfig(dvl=DvlMount(lever_arm_m=MOUNT.lever_arm_m))
    out = run_filter_arrays(sim.ins, sim.dvl, wrong, sim.depth)
    err = np.hypot(out.x[-1] - truth.x[-1], out.y[-1] - truth.y[-1])
    assert err > 0.01 * truth.distance()
