"""Closed-loop truth cost: the online truth (dynamics + actuator model + truth row) against the
bare RK4 step, and the emulated vehicle at a --speed with the INS and the actuators running.

    .venv/bin/python benchmarks/bench_closed_loop.py [--seconds 20] [--runs 3] [--speeds 1,4,8]
    nice -n 10 .venv/bin/python benchmarks/bench_closed_loop.py --latency [--seconds 60]
        [--speeds 1,4]

Part 1 (one thread, no ports): vehicle seconds integrated per host second, median of ``runs``,
``dynamics.step`` alone and ``ClosedLoopTruth.at`` stepping the same vehicle through the
actuator model (20 Hz commands of a heading hold), and their ratio in the same run. Part 2:
``Runner`` on the closed-loop scenario (INS at 100 Hz on a pty, actuators on SLCAN, nobody
reading: the ports drop what they cannot hold) for ``seconds / speed`` host seconds at each
speed: the clock's late ticks and largest lag, and the process CPU per host second.

``--latency``: the loop's latency through the whole chain, from a sensor frame's bytes to the
actuator command it causes. The emulated vehicle runs in this process (``Runner`` on the
closed-loop scenario, hooked), the gateway, the fusion and ``auvgw pilot`` (box mission) each
in its own process. Start: the host time an INS frame is handed to its pty (paced out at the
line's baud from then). End: the host time the ``ActuatorCommand`` CAN frame the gateway wrote
reaches the emulated controller's SLCAN adapter. A command is tied to its INS frame by its time:
the pilot stamps each command with the time of the odometry sample it stepped on, which is the
INS sample's (its device clock mapped onto the gateway's vehicle-paced stamps, within the
smallest transport delay: the frame's 10 ms tick is taken as the one at or before). INS frames
before vehicle t ``LOCKSTEP_FIRST_S`` are not counted: a lock-step sim runs that long before it
waits for the first answer, so their commands measure the start, not the loop. Printed:
p50 / p90 / p99 / max in host ms and in vehicle ms (the sim's clock when the CAN frame arrived
minus the INS frame's time), the number of commands, the machine's load average and core count;
``--sim free,ungated,lockstep`` (any of them; ``both`` = ``free,lockstep``): the sim on the
host clock, or paced by the pilot (``auvgw sim --lockstep``: its vehicle latency stays bounded
however the host stalls), its answers counted on arrival (``ungated``, as before the command
gate) or once the emulated actuators have the command they carry (``lockstep``).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.commands.sim import Lockstep
from auvgw.config.scenario import load_scenario
from auvgw.ground.paths import config_file
from auvgw.sim_devices import dynamics
from auvgw.sim_devices.actuators import ActuatorLimits, ActuatorModel
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.runner import Runner, RunOptions
from auvgw.sim_devices.world import World

SCENARIO = config_file("scenarios/closed_loop.json")
#: vehicle s the lock-step sim may run past the pilot's last answer (``auvgw sim`` default)
LOCKSTEP_STEP_S = 0.15
#: vehicle s the lock-step sim runs before the pilot's first answer (``auvgw sim`` default):
#: unanswered, so commands caused by INS frames before it are not counted (in every mode)
LOCKSTEP_FIRST_S = 1.0


def bare(seconds: float) -> float:
    p = dynamics.load_params()
    x = np.zeros(12)
    x[0], x[8] = 1.3, 5.0
    u = np.array([0.0, 0.0, 1000.0])
    n = int(seconds / 0.01)
    t0 = time.perf_counter()
    for _ in range(n):
        x = dynamics.step(p, x, u, 0.01)
    return seconds / (time.perf_counter() - t0)


def online(seconds: float) -> float:
    scn = load_scenario(SCENARIO)
    truth = ClosedLoopTruth(scn, World.from_scenario(scn))
    model = ActuatorModel(ActuatorLimits(command_timeout_s=1e9), rpm=1000.0)
    truth.set_inputs(model.inputs)
    t0 = time.perf_counter()
    for k in range(int(seconds * 20)):
        s = truth.at(k / 20)
        rud = float(np.clip(s.heading + 4 * s.yaw_rate, -0.35, 0.35))
        stern = float(np.clip(s.pitch + 4 * s.pitch_rate, -0.35, 0.35))
        model.command(k / 20, 1000.0, rud, stern, k)
    return seconds / (time.perf_counter() - t0)


def emulated(speed: float, seconds: float) -> tuple[int, float, float]:
    scn = load_scenario(SCENARIO)
    with tempfile.TemporaryDirectory() as out:
        r = Runner(scn, RunOptions(out_dir=out, speed=speed))
        try:
            t0 = time.monotonic()
            r.start(duration=seconds)
            while r.running:
                time.sleep(0.2)
            wall = time.monotonic() - t0
            st = r.stats()
        finally:
            r.close()
    return st["late_ticks"], st["max_lag_s"], st["process_cpu_s"] / wall


def loop_latency(speed: float, seconds: float, out: Path, lockstep: bool = False,
                 gate: bool = True) -> tuple[list[tuple[float, float]], dict[str, Any]]:
    """(host s, vehicle s) from each INS frame to the actuator command stepped on it (see the
    module docstring), for ``seconds`` of vehicle time at ``speed`` (``lockstep``: the sim
    paced by the pilot; ``gate`` False: its answers count before the emulated actuators have
    the command they carry); and the run's counters."""
    from auvgw.bus import Keys, decode_envelope, open_session
    from auvgw.commands.demo_parts import _fusion_config, _gateway_toml
    from auvgw.config.bus import BusConfig
    from auvgw.ground.procs import Children, free_endpoint
    from auvgw.subscribe import GatewaySubscriber

    scn = load_scenario(SCENARIO)
    r = Runner(scn, RunOptions(out_dir=out / "sim", speed=speed))
    ins, act = r.emulator("ins"), r.emulator("actuators")
    written: dict[int, float] = {}  # INS tick (10 ms of vehicle time) -> host s handed to pty
    # command seq -> (host s, vehicle s) its CAN frame reached the adapter
    arrived: dict[int, tuple[float, float]] = {}
    ins_send, on_frame = ins.serial.send, act.can.adapter.on_frame

    def hooked_send(frame: bytes, t: float, at: float | None = None) -> bool:
        written[math.floor(t * 100 + 1e-6)] = time.monotonic()
        return bool(ins_send(frame, t, at))

    def hooked_frame(frame: Any) -> None:
        h, v = time.monotonic(), r.clock.now()
        on_frame(frame)
        with contextlib.suppress(Exception):  # not a command: the emulator counted it
            arrived.setdefault(int(act.codec.decode_frame(frame).seq), (h, v))

    ins.serial.send = hooked_send
    act.can.adapter.on_frame = hooked_frame
    keys = Keys("auv1")
    hub = free_endpoint()
    session = open_session(BusConfig(listen=[hub]))
    sub = GatewaySubscriber("auv1", session=session)
    children = Children(out)
    cmds: list[tuple[int, int, float]] = []  # (seq, stamp ns, host s) of each command put

    def on_cmd(sample: Any) -> None:
        env = decode_envelope(sample.payload.to_bytes())
        cmds.append((int(env.seq), env.t_recv_ns, time.monotonic()))

    cmd_sub = session.declare_subscriber(keys.cmd("actuators"), on_cmd)
    clock_file = out / "sim" / "clock"
    step = None
    try:
        fusion = _fusion_config("auv1", (0.0, 0.0, scn.vehicle.depth_m), scn.devices.ins.noise)
        # a 0.03 s lag as in the closed-loop demo, and no clock warm-up: the demo's holds the
        # first 2 s of odometry back (its sim's first hold and captive start make room for it,
        # demo_closed_loop.lockstep_first_s), and the latency counts from vehicle t 1 s
        filt = fusion.filter.model_copy(update={"max_latency_s": 0.03})
        fusion = fusion.model_copy(update={"clock_warmup_s": 0.0, "filter": filt})
        (out / "fusion.json").write_text(fusion.model_dump_json())
        children.start("fusion", ["fusion", "--settings", str(out / "fusion.json"),
                                  "--connect", hub, "--listen", free_endpoint()])  # fmt: skip
        children.start("pilot", ["pilot", "--mission", str(config_file("missions/box.toml")),
                                 "--feedback-timeout", "0", "--nav-timeout", "2",
                                 *(["--lockstep", str(clock_file)] if lockstep else []),
                                 "--connect", hub, "--listen", free_endpoint()])  # fmt: skip
        start_at = time.monotonic() + 30.0
        if lockstep:
            step = Lockstep(r, "auv1", LOCKSTEP_STEP_S, 5.0, LOCKSTEP_FIRST_S, clock_file,
                            start_at, session, gate_commands=gate)  # fmt: skip
        cfg = r.write_gateway_config(out / "sim" / "gateway.toml", vehicle="auv1",
                                     start_at=start_at,
                                     sim_clock=clock_file if lockstep else None)  # fmt: skip
        epoch_ns = int(Path(cfg).read_text().split("epoch_ns = ")[1].split()[0])
        if step is not None:
            step.epoch_ns = epoch_ns
            step.begin()
        children.start("gateway", ["run", "--config", str(_gateway_toml(
            out / "sim", out, free_endpoint(), hub))])  # fmt: skip
        while sub.alive(timeout=0.5) < {"fusion", "pilot", "gateway", "ins", "actuators"}:
            if time.monotonic() > start_at - 0.5:
                raise SystemExit("the chain was not up before vehicle time 0")
            time.sleep(0.2)
        r.start(duration=seconds, start_at=start_at)
        load0 = os.getloadavg()
        while r.running:
            time.sleep(0.2)
        for name in ("pilot", "gateway", "fusion"):
            children.stop(name)
        stats = {"load": (load0, os.getloadavg()), "commands": len(cmds),
                 "applied": len(arrived), "ins_frames": len(written),
                 "lockstep": step.summary() if step is not None else ""}  # fmt: skip
    finally:
        r.close()  # first: a hold timeout while closing publishes to the lock-step's clock file
        if step is not None:
            step.__exit__()
        for name in list(children.procs):
            children.stop(name, grace_s=5.0)
        children.close()
        cmd_sub.undeclare()
        sub.close()
        session.close()
    lat = []
    for seq, stamp_ns, _ in cmds:
        tick = math.floor((stamp_ns - epoch_ns) / 1e7 + 1e-6)  # the INS tick at or before it
        if seq in arrived and tick in written and tick >= round(LOCKSTEP_FIRST_S * 100):
            lat.append((arrived[seq][0] - written[tick], arrived[seq][1] - tick / 100))
    return lat, stats


def _pct(v: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(v), q)) if v else math.nan


def main_latency(args: argparse.Namespace) -> None:
    print(f"loop latency: INS frame to the pty -> the ActuatorCommand it causes at the CAN "
          f"adapter ({args.seconds:g} vehicle s per speed, INS frames from vehicle t "
          f"{LOCKSTEP_FIRST_S:g} s on; {os.cpu_count()} cores)")  # fmt: skip
    print(f"{'sim':>11s} {'speed':>5s} {'n':>5s} {'p50 ms':>7s} {'p90':>7s} {'p99':>7s} "
          f"{'max':>7s}  {'vehicle p50':>11s} {'p99':>7s} {'max':>7s}  "
          "load avg (start -> end)")  # fmt: skip
    names = {"free": "free", "ungated": "ungated", "lockstep": "lock-step"}
    modes = args.sim.replace("both", "free,lockstep").split(",")
    if not set(modes) <= set(names):
        raise SystemExit(f"--sim: one or more of {', '.join(names)}, both; got {args.sim!r}")
    for sp in (float(v) for v in args.speeds.split(",")):
        for mode in modes:
            with tempfile.TemporaryDirectory() as tmp:
                lat, st = loop_latency(sp, args.seconds, Path(tmp), lockstep=mode != "free",
                                       gate=mode == "lockstep")  # fmt: skip
            ms = [1e3 * h for h, _ in lat]
            vms = [1e3 * v for _, v in lat]
            (l0, l1) = st["load"]
            print(f"{names[mode]:>11s} {sp:5g} {len(ms):5d} "
                  f"{_pct(ms, 50):7.1f} {_pct(ms, 90):7.1f} {_pct(ms, 99):7.1f} "
                  f"{max(ms, default=math.nan):7.1f}  {_pct(vms, 50):11.1f} {_pct(vms, 99):7.1f} "
                  f"{max(vms, default=math.nan):7.1f}  {l0[0]:.1f} -> {l1[0]:.1f} (1 min), "
                  f"{l1[1]:.1f} (5 min)", flush=True)  # fmt: skip
            if st["lockstep"]:
                print(f"{'':11s} lock-step: {st['lockstep']}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="vehicle seconds per case")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--speeds", default="1,4,8")
    ap.add_argument("--latency", action="store_true", help="the loop latency through the chain")
    ap.add_argument("--sim", default="both",
                    help="--latency: comma list of free (the sim on the host clock), ungated "
                    "(lock-step, answers counted on arrival), lockstep (answers counted once "
                    "the emulated actuators have their command); both = free,lockstep")
    args = ap.parse_args()
    if args.latency:
        main_latency(args)
        return
    b = [bare(args.seconds) for _ in range(args.runs)]
    o = [online(args.seconds) for _ in range(args.runs)]
    mb, mo = statistics.median(b), statistics.median(o)
    print(f"{'integration (dt 0.01 s)':34s} {'x real time':>12s}  (median of {args.runs})")
    print(f"{'dynamics.step alone':34s} {mb:12.1f}")
    print(f"{'ClosedLoopTruth + actuator model':34s} {mo:12.1f}   ratio {mo / mb:.2f}")
    print()
    print(f"{'speed':>6s} {'late ticks':>11s} {'max lag s':>10s} {'CPU s per s':>12s}"
          f"  (INS 100 Hz + actuators 20 Hz, {args.seconds:g} vehicle s)")  # fmt: skip
    for sp in (float(v) for v in args.speeds.split(",")):
        late, lag, cpu = emulated(sp, args.seconds)
        print(f"{sp:6g} {late:11d} {lag:10.3f} {cpu:12.2f}")


if __name__ == "__main__":
    main()
