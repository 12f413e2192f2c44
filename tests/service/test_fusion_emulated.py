"""Dead reckoning over the EMULATED survey: the HN-100 and Pathfinder emulators' own byte streams
(serial binary frames, PD0 ensembles, CAN bursts), framed and decoded by the drivers, adapted and
filtered by the in-process fusion stage, against the ground truth.

The window is 120 s of ``config/scenarios/survey.json`` around the first two turns (the end of
line 1, the 80 m crossing, the start of line 2: the hardest part for dead reckoning), to keep
the suite fast; ``benchmarks/bench_fusion_emulated.py`` runs the whole 30 minutes and prints the
same figures (docs/fusion.md, "Emulated survey"). Filter settings follow the emulators' noise
model (``fusion_emulated.filter_config``: white attitude noise, so ``heading_error_tau_s=0``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.stages.fusion import FusionStageConfig
from auvgw.testing.fusion_emulated import (
    HOST_EPOCH,
    NEES_2SIGMA,
    NEES_95,
    decode_serial,
    dvl_stream,
    emulate,
    evaluate,
    filter_config,
    ins_output,
    run_stage,
    survey_scenario,
)

T0, T1 = 220.0, 340.0  # vehicle s: line 1 ends about 247 s, line 2 starts about 295 s
LOSS = (250.0, 310.0)  # 60 s without bottom lock, mid-run (through both turns)
CAN_T1 = T0 + 20.0


@pytest.fixture(scope="module")
def emulated(tmp_path_factory):
    """One emulated run: INS serial stream (and CAN for the first 20 s, same measurements),
    DVL streams without and with the 60 s bottom-lock loss (same noise draws otherwise)."""
    em = emulate(survey_scenario(T1 + 1.0), tmp_path_factory.mktemp("ports"))
    ins_can = ins_output(em, T0, CAN_T1, can=True)
    ins_rest = ins_output(em, CAN_T1 + 0.005, T1)
    dvl = dvl_stream(em, T0, T1)
    faulty = DvlEmulator(em.ctx)  # the same seeded noise as em.dvl
    faulty.set_faults(bottom_lock_loss=[LOSS])
    em_fault = type(em)(em.scenario, em.truth, em.ctx, em.ins, faulty)
    dvl_lost = dvl_stream(em_fault, T0, T1)
    return em, ins_can, ins_rest, dvl, dvl_lost


def decoded(emulated, lost: bool = False):
    _em, ins_can, ins_rest, dvl, dvl_lost = emulated
    msgs = decode_serial(ins_can.serial, "hn100", "ins")
    msgs += decode_serial(ins_rest.serial, "hn100", "ins")
    msgs += decode_serial(dvl_lost if lost else dvl, "pd0", "dvl")
    return msgs


def stage_config(emulated, **filter_changes) -> FusionStageConfig:
    em, ins_can, _ins_rest, dvl, _ = emulated
    return FusionStageConfig(
        ins_device="ins",
        latency_s={
            "ins": ins_can.serial.frame_latency_s,
            "ins_can": ins_can.can_latency_s,
            "dvl": dvl.frame_latency_s,
        },
        filter=filter_config(em, T0, **filter_changes),
    )


@pytest.fixture(scope="module")
def nominal(emulated):
    out, stage = run_stage(decoded(emulated), stage_config(emulated))
    return out, stage, evaluate(out, emulated[0].truth)


def test_every_frame_is_decoded_adapted_and_used(emulated, nominal):
    out, stage, ev = nominal
    n_ins = round((T1 - T0) * 100) + 1
    n_dvl = round((T1 - T0) * 5) + 1
    c = stage.counters()
    assert c["adapter"]["ins"] == n_ins and c["adapter"]["dvl"] == n_dvl
    assert c["adapter"]["errors"] == 0 and c["adapter"]["ignored"] == 0
    assert c["filter"]["dvl_updates"] == n_dvl and c["filter"]["depth_updates"] == n_dvl
    assert c["filter"]["dvl_rejected"] == 0 and c["filter"]["ins_gaps"] == 0
    assert all(v == 0 for v in c["buffer"].values())
    assert c["clocks"]["ins"]["resets"] == 0 and c["clocks"]["dvl"]["resets"] == 0
    assert len(out) == n_ins  # odometry at the INS rate
    # the device clocks are mapped onto the host clock: odometry times are the INS tick times
    assert np.allclose(ev.t, T0 + np.arange(n_ins) / 100.0, rtol=0, atol=1e-6)
    assert not ev.coasting[1:].any() and ev.bottom_lock.all()


def test_emulated_survey_error_under_1_percent_and_2_sigma_ellipse_holds_the_truth(nominal):
    _out, _stage, ev = nominal
    assert 200.0 < ev.distance < 210.0  # 120 s at 1.7 m/s
    assert ev.final_error < 0.01 * ev.distance
    # the reference track differs from the raw truth only by the truth's Euler step (< dt |v|)
    assert np.hypot(*(ev.err_raw - ev.err).T).max() < 0.02 * 2.0
    # consistency: the truth lies in the filter's 2-sigma ellipse (Mahalanobis radius 2) at
    # least 90 % of the time, and the covariance is not merely inflated (mean NEES near 2)
    assert ev.inside(NEES_2SIGMA) >= 0.90
    assert 0.3 < ev.nees.mean() < 4.0
    assert ev.sigma[-1] > ev.sigma[1]  # the horizontal uncertainty grows with distance


def test_an_overconfident_filter_fails_the_consistency_check(emulated):
    """Not vacuous: the same data through a filter that believes the INS heading is 10 times
    better and the DVL 10 times better than they are puts the truth outside its ellipse."""
    msgs = [m for m in decoded(emulated) if m[0] < HOST_EPOCH + T0 + 40.0]
    out, _ = run_stage(
        msgs,
        stage_config(
            emulated,
            heading_error_sigma_deg=0.03,
            dvl_velocity_sigma_mps=0.0002,
            velocity_random_walk=0.002,
        ),
    )
    ev = evaluate(out, emulated[0].truth)
    assert ev.inside(NEES_2SIGMA) < 0.75 and ev.nees.mean() > 6.0


def test_bottom_lock_lost_for_60_s_coasts_flags_and_grows_the_covariance(emulated, nominal):
    out, stage = run_stage(decoded(emulated, lost=True), stage_config(emulated))
    ev = evaluate(out, emulated[0].truth)
    c = stage.counters()
    n_lost = round((LOSS[1] - LOSS[0]) * 5)
    assert c["filter"]["dvl_no_lock"] == n_lost
    assert c["filter"]["dvl_updates"] == round((T1 - T0) * 5) + 1 - n_lost
    # the filter keeps running: odometry at every INS sample, through the gap
    assert len(out) == len(nominal[0]) and np.allclose(ev.t, nominal[2].t, rtol=0, atol=1e-6)
    assert c["filter"]["ins_gaps"] == 0
    gap = (ev.t > LOSS[0]) & (ev.t < LOSS[1])
    before = ev.t < LOSS[0]
    after = ev.t > LOSS[1] + 0.5
    # flagged: coasting and no bottom lock exactly over the gap
    assert ev.coasting[gap].all() and not ev.bottom_lock[gap].any()
    assert not ev.coasting[before][1:].any() and not ev.coasting[after].any()
    assert ev.bottom_lock[after].all()
    # the covariance grows over the gap (second by second; a depth fix may trim it a little, the
    # vertical velocity it observes couples with the forward one through pitch), far beyond
    # the bottom-locked one
    s_gap = ev.sigma[gap]
    assert (np.diff(s_gap[::100]) > 0).all()
    assert s_gap[-1] > 10.0 * s_gap[0] and s_gap[-1] > 10.0 * nominal[2].sigma[gap][-1]
    # ... and stays honest: the truth inside the 95 % ellipse while coasting
    assert ev.inside(NEES_95, gap) >= 0.95
    # coasting costs accuracy (held velocity through two turns) but not the run
    err = np.hypot(*ev.err.T)
    assert err[gap].max() > 5.0 * np.hypot(*nominal[2].err.T)[gap].max()
    assert err[-1] < 0.05 * ev.distance and math.isfinite(err[-1])
    # once lock is back, the velocity is re-acquired: the error stops growing
    assert err[after].max() - err[after][0] < 0.5


def test_ins_over_can_gives_the_same_odometry_as_over_serial(emulated):
    """The same INS measurements on CAN (HN100_Sample via the DBC, 8 frames per epoch) and on
    serial (Hn100Nav): the odometry agrees to the CAN resolution (1e-4 rad attitude)."""
    _em, ins_can, _ins_rest, dvl, _ = emulated
    dvl_msgs = [m for m in decode_serial(dvl, "pd0", "dvl") if m[0] <= ins_can.can[-1][0]]
    serial_msgs = decode_serial(ins_can.serial, "hn100", "ins")
    a, _ = run_stage(serial_msgs + dvl_msgs, stage_config(emulated))
    cfg = stage_config(emulated).model_copy(update={"ins_device": "ins_can"})
    b, stage_b = run_stage(ins_can.can + dvl_msgs, cfg)
    assert stage_b.counters()["adapter"]["ins"] == len(ins_can.can) == len(a) == len(b)
    ta, tb = np.array([o.t for o in a]), np.array([o.t for o in b])
    assert np.abs(ta - tb).max() < 1e-5  # both device clocks mapped to the same host times
    d = np.hypot([o.x - p.x for o, p in zip(a, b, strict=True)],
                 [o.y - p.y for o, p in zip(a, b, strict=True)])  # fmt: skip
    assert d.max() < 0.005
    dh = [abs(math.remainder(o.heading - p.heading, math.tau)) for o, p in zip(a, b, strict=True)]
    assert max(dh) < 2e-4
