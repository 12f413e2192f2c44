"""Dead reckoning over the whole EMULATED survey (30 minutes of vehicle time), offline.

The HN-100 and Pathfinder emulators' encoders are called for every tick (no ptys, as fast as
possible), their byte streams framed and decoded by the drivers, and the messages fed in arrival
order to the in-process fusion stage (the code the bus stage runs), with the filter settings of
the emulators' noise model (tests/support/fusion_emulated.py, docs/fusion.md "Emulated survey").

Prints two tables:

* accuracy and consistency: distance travelled, final horizontal error (against the raw truth and
  against the reference track, the integral of the truth's velocity as the emulators report it),
  its share of the distance (the issue's bound: 1 %), the fraction of INS epochs whose truth lies
  in the filter's 2-sigma ellipse (Mahalanobis radius 2; the issue's bound: 90 %) and in the 95 %
  ellipse, the mean NEES (2 when consistent); with ``--lock-loss`` the same run with 60 s
  without bottom lock mid-way (coasting share, sigma before / after the gap, largest error);
* time of each step (median of ``--repeat`` runs of the filter; the emulators once), as a
  multiple of real time (1800 s of vehicle time).

Usage: ``python benchmarks/bench_fusion_emulated.py [--duration 1800] [--lock-loss 900]
[--repeat 1]``. Takes a few minutes (the emulators dominate).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.stages.fusion import FusionStageConfig
from auvgw.testing.fusion_emulated import (
    NEES_2SIGMA,
    NEES_95,
    Emulated,
    Evaluation,
    decode_serial,
    dvl_stream,
    emulate,
    evaluate,
    filter_config,
    ins_output,
    run_stage,
    survey_scenario,
)


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def accuracy_row(name: str, ev: Evaluation) -> str:
    e_raw, e_ref = ev.final_error, float(np.hypot(*ev.err[-1]))
    return (
        f"{name:<22} {ev.distance:9.1f} {e_raw:9.3f} {e_ref:9.3f} "
        f"{100 * e_raw / ev.distance:8.4f} {100 * ev.inside(NEES_2SIGMA, raw=True):7.1f} "
        f"{100 * ev.inside(NEES_2SIGMA):7.1f} {100 * ev.inside(NEES_95):7.1f} "
        f"{ev.nees.mean():6.2f} {ev.sigma[-1]:8.3f}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=1800.0, help="vehicle seconds (1800)")
    ap.add_argument("--lock-loss", type=float, default=900.0, metavar="T",
                    help="start of a 60 s bottom-lock loss (negative: no such run)")
    ap.add_argument("--repeat", type=int, default=1, help="filter runs for the median time")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        em, t_setup = timed(emulate, survey_scenario(args.duration + 1.0), Path(tmp))
        end = min(args.duration, em.duration)
        ins, t_ins = timed(ins_output, em, 0.0, end)
        dvl, t_dvl = timed(dvl_stream, em, 0.0, end)
        msgs, t_dec = timed(
            lambda: decode_serial(ins.serial, "hn100", "ins") + decode_serial(dvl, "pd0", "dvl")
        )
        cfg = FusionStageConfig(
            latency_s={"ins": ins.serial.frame_latency_s, "dvl": dvl.frame_latency_s},
            filter=filter_config(em),
        )
        runs = [timed(run_stage, msgs, cfg) for _ in range(max(1, args.repeat))]
        (out, stage), _ = runs[0]
        t_filter = statistics.median(t for _, t in runs)
        ev = evaluate(out, em.truth)

        lost = None
        if args.lock_loss >= 0:
            window = (args.lock_loss, args.lock_loss + 60.0)
            faulty = DvlEmulator(em.ctx)
            faulty.set_faults(bottom_lock_loss=[window])
            em2 = Emulated(em.scenario, em.truth, em.ctx, em.ins, faulty)
            dvl2 = dvl_stream(em2, 0.0, end)
            msgs2 = decode_serial(ins.serial, "hn100", "ins") + decode_serial(dvl2, "pd0", "dvl")
            out2, stage2 = run_stage(msgs2, cfg)
            lost = (window, evaluate(out2, em.truth), stage2)

    c = stage.counters()
    print(f"emulated survey: {end:.0f} s of vehicle time, {c['adapter']['ins']} INS frames, "
          f"{c['adapter']['dvl']} PD0 ensembles, {c['filter']['dvl_updates']} DVL updates, "
          f"late samples {sum(c['buffer'].values())}")
    print()
    print(f"{'run':<22} {'dist m':>9} {'err m':>9} {'err ref':>9} {'% dist':>8} "
          f"{'in2s raw':>7} {'in2s %':>7} {'in95 %':>7} {'NEES':>6} {'sigma m':>8}")
    print(accuracy_row("bottom-locked", ev))
    if lost is not None:
        (a, b), ev2, st2 = lost
        print(accuracy_row(f"lock lost {a:.0f}-{b:.0f} s", ev2))
        gap = (ev2.t > a) & (ev2.t < b)
        err2 = np.hypot(*ev2.err.T)
        print(f"\nlock loss: coasting over {100 * ev2.coasting[gap].mean():.1f} % of the gap, "
              f"{st2.counters()['filter']['dvl_no_lock']} pings without lock; horizontal sigma "
              f"{ev2.sigma[gap][0]:.3f} m -> {ev2.sigma[gap][-1]:.3f} m; error at its end "
              f"{err2[gap][-1]:.3f} m; truth in the 95 % ellipse over the gap "
              f"{100 * ev2.inside(NEES_95, gap):.1f} %")
    print()
    print(f"{'step':<34} {'s':>8} {'x real time':>12}")
    for name, t in (
        ("truth + world", t_setup),
        ("INS emulator (measure + encode)", t_ins),
        ("DVL emulator (ping + encode)", t_dvl),
        ("framing + decoding (drivers)", t_dec),
        (f"adapt + filter (median of {len(runs)})", t_filter),
    ):
        print(f"{name:<34} {t:8.2f} {end / t:12.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
