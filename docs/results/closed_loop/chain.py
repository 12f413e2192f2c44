"""Closed loop through the whole chain: missions flown by ``auvgw pilot`` with ``auvgw sim``,
``auvgw run`` and ``auvgw fusion`` each in its own process, scored against the sim's truth.

    nice -n 10 .venv/bin/python docs/results/closed_loop/chain.py [--cases box@1,box@4,...]
        [--out /tmp/chain] [--dvl-dropout T0,T1]

Each case is ``MISSION@SPEED`` (``config/missions/MISSION.toml``, ``--speed``); one line per
case: how the mission ended, legs, vehicle time to ``done``, cross-track and depth error RMS
(max) of the *truth* against the legs while running, the odometry's horizontal error against
the truth (RMS, final), commands forwarded / refused at the gateway, the pilot's timer steps
(steps made without odometry: stalls on the host), the wall time and the load average.
``--dvl-dropout T0,T1``: the DVL unplugged from vehicle T0 to T1 s (the sim's fault control
file), so the navigation drift shows in the flown path. The sim runs in lock-step with the pilot
(``auvgw sim --lockstep``: vehicle time waits for the pilot's answers, so host stalls stretch
wall time, not vehicle time; the ``lock-step`` line after each case says how often and how long
it held); ``--free-running``: on the host clock, as before. Output: chain.txt (verbatim).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from auvgw.commands.demo_closed_loop import ChainRun, fly_chain, score
from auvgw.commands.demo_parts import _load_sim_config
from auvgw.control.mission import load_mission
from auvgw.ground.paths import config_file


def windows(out: Path, mission: Path, spans: list[tuple[str, float, float]]) -> None:
    """Per vehicle-time window ``(label, t0, t1)`` of a finished run in ``out``: the truth's
    cross-track and depth error against the plan and the odometry's error against the truth
    (RMS, max or final), from the run's files (truth log, the pilot's states, the odometry)."""
    epoch = _load_sim_config(out / "sim").clock.epoch_ns / 1e9
    truth = np.array([(s["t"], s["x"], s["y"], s["z"]) for s in
                      map(json.loads, (out / "sim" / "truth.jsonl").read_text().splitlines())])
    states = sorted((s["t"] - epoch, int(s["leg"]), str(s["mode"])) for s in
                    map(json.loads, (out / "pilot_state.jsonl").read_text().splitlines()))
    odo = np.array(sorted((o["t"] - epoch, o["x"], o["y"]) for o in
                          map(json.loads, (out / "odometry.jsonl").read_text().splitlines())))
    m = load_mission(mission)
    for label, t0, t1 in spans:
        sel = truth[(truth[:, 0] >= t0) & (truth[:, 0] <= t1)]
        sc = score(m, sel, states, odo)
        print(f"  {label:26s} XTE RMS {sc['xte_rms']:5.2f} (max {sc['xte_max']:5.2f})  depth RMS "
              f"{sc['depth_rms']:6.3f}  nav error RMS {sc['nav_rms']:5.2f} (at the end "
              f"{sc['nav_final']:5.2f}) m", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="box@1,box@4,lawnmower@4,lawnmower@1")
    ap.add_argument("--out", type=Path, default=Path("/tmp/chain"))
    ap.add_argument("--dvl-dropout", default=None, metavar="T0,T1")
    ap.add_argument("--start-delay", type=float, default=25.0, metavar="S",
                    help="host s from the sim's gateway.toml to vehicle time 0 (the gateway's "
                    "start on a loaded machine)")
    ap.add_argument("--max-vehicle-s", type=float, default=None, metavar="S")
    ap.add_argument("--feedback-timeout", type=float, default=1.0, metavar="S",
                    help="auvgw pilot --feedback-timeout (0: no fin / thruster checks)")
    ap.add_argument("--scenario-start", action="store_true",
                    help="start at the scenario's pose (5 m, heading north) instead of on the "
                    "mission (its first waypoint and depth, heading along leg 0, as in-process)")
    ap.add_argument("--free-running", action="store_true",
                    help="the sim on the host clock (no lock-step)")
    ap.add_argument("--lockstep-step", type=float, default=0.15, metavar="S",
                    help="auvgw sim --lockstep-step (vehicle s past the pilot's last answer)")
    args = ap.parse_args()
    faults = None
    if args.dvl_dropout:
        t0, t1 = (float(v) for v in args.dvl_dropout.split(","))
        faults = {"dvl": {"unplug": [[t0, t1]]}}
        print(f"DVL unplugged from vehicle t = {t0:g} to {t1:g} s")
    print(("sim free-running on the host clock" if args.free_running else
           f"sim in lock-step with the pilot (step {args.lockstep_step:g} s)")
          + ("; start at the scenario's pose" if args.scenario_start else
             "; start on the mission (first waypoint and depth, heading along leg 0)"))
    print(f"auvgw pilot --feedback-timeout {args.feedback_timeout:g}"
          + (" (fin and thruster checks off)" if args.feedback_timeout == 0 else ""))
    print(f"{'case':14s} {'end':22s} {'legs':>5s} {'done s':>7s} {'XTE RMS (max)':>15s} "
          f"{'depth RMS (max)':>16s} {'nav RMS/final':>14s} {'fwd/refused':>12s} "
          f"{'timer':>6s} {'wall s':>7s} {'load':>5s}")  # fmt: skip
    for case in args.cases.split(","):
        name, speed = case.split("@")
        run = ChainRun(mission=config_file(f"missions/{name}.toml"), speed=float(speed),
                       out=args.out / case.replace("@", "_"), faults=faults,
                       feedback_timeout=args.feedback_timeout, start_delay=args.start_delay,
                       max_vehicle_s=args.max_vehicle_s, lockstep=not args.free_running,
                       lockstep_step=args.lockstep_step,
                       start_on_mission=not args.scenario_start)  # fmt: skip
        r = fly_chain(run)
        refused = sum(v for k, v in r.commands.items()
                      if isinstance(v, int) and k not in ("forwarded", "last_seq"))  # fmt: skip
        end = r.mode + (f" ({r.abort_reason})" if r.abort_reason else "")
        done = "-" if r.done_vehicle_s is None else f"{r.done_vehicle_s:.0f}"
        timer = r.pilot.get("stage", {}).get("timer_steps", "?")
        print(f"{case:14s} {end:22s} {r.legs_done:2d}/{r.n_legs:<2d} {done:>7s} "
              f"{r.xte_rms:6.2f} ({r.xte_max:5.2f}) {r.depth_rms:7.3f} ({r.depth_max:5.2f}) "
              f"{r.nav_rms:6.2f}/{r.nav_final:5.2f} "
              f"{r.commands.get('forwarded', 0):6d}/{refused:<5d} "
              f"{timer!s:>6s} {r.wall_s:7.0f} {os.getloadavg()[0]:5.1f}", flush=True)  # fmt: skip
        if r.lockstep:
            print(f"  lock-step: {r.lockstep}", flush=True)
        if faults:
            windows(run.out, run.mission, [
                ("before the dropout", 0.0, t0), (f"DVL out ({t0:g}-{t1:g} s)", t0, t1),
                (f"after ({t1:g}-{t1 + 120:g} s)", t1, t1 + 120),
                (f"the rest ({t1 + 120:g} s-)", t1 + 120, 1e9)])  # fmt: skip


if __name__ == "__main__":
    main()
