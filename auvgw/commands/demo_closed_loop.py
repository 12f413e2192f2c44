"""``auvgw demo --closed-loop``: a mission flown through the whole chain, each part its own process.

:func:`fly_chain` starts ``auvgw fusion`` (dead reckoning from the scenario's start pose),
``auvgw pilot --mission M`` (its commands on ``auv/<v>/cmd/actuators``, the actuators'
feedback checked), optionally ``auvgw viz`` (Rerun file) and ``auvgw record`` (MCAP), then
``auvgw sim`` on the closed-loop scenario (REMUS 100 dynamics driven by the emulated actuators'
CAN controller; vehicle time 0 held back until every part is up and every port open,
``start_delay`` host seconds at the latest) and the gateway (``auvgw run``) on the sim's ports.
This process is the bus hub: it publishes the sim's ground truth (``truth.jsonl``) on
``auv/<v>/truth/pose`` and follows ``auv/<v>/pilot/state`` until the pilot reports ``done`` or
``aborted`` (or the time runs out), then stops everything in data-flow order. :func:`score`
compares the *truth* with the mission the pilot flew: per truth sample, the cross-track error
from the leg the pilot was on at that vehicle time and the depth error from that leg's depth
(m), over the samples flown (mode ``running``), as ``control.closed_loop`` does in-process.

Time: the gateway stamps vehicle-paced receive times (``[clock]`` of the sim's gateway.toml), so
the odometry, the pilot's steps and its state are on ``epoch + vehicle s``; the truth log is in
vehicle s.
"""

from __future__ import annotations

import argparse
import json
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from auvgw.commands.common import UserError
from auvgw.control.closed_loop import cross_track
from auvgw.control.mission import Mission, load_mission
from auvgw.ground.paths import config_file

if TYPE_CHECKING:
    import zenoh

    from auvgw.ground.procs import Children
    from auvgw.stages.fusion import FusionStageConfig
    from auvgw.subscribe import GatewaySubscriber

_T = TypeVar("_T")

__all__ = ["ChainResult", "ChainRun", "fly_chain", "lockstep_first_s", "run_closed_loop", "score"]

SCENARIO = config_file("scenarios/closed_loop.json")
VEHICLE = "auv1"
#: the fusion's fixed lag in the loop (``FusionConfig.max_latency_s``, s of sample time): its
#: default (0.2 s, for SLAM) delays every odometry sample that much, and the autopilot's loops
#: on this vehicle fail from 0.2 s of latency (docs/pilot.md)
FUSION_LAG_S = 0.03
#: the scenario's cruise speed at vehicle time 0 (m/s): the pilot's first leg is slower or
#: faster; a duration bound only
_MIN_SPEED = 0.8


@dataclass(frozen=True)
class ChainRun:
    """One closed-loop run through the chain: ``mission`` file at ``speed`` (x real time),
    output folder ``out``; ``rrd`` (a Rerun file via ``auvgw viz``) and ``mcap`` (``auvgw
    record``) optional; ``faults``: the sim's fault control file content (``{"dvl": {"unplug":
    [[t0, t1]]}}``, vehicle s) written before the start; ``max_vehicle_s``: stop after that
    much vehicle time (None: the mission's length at its slowest leg, plus turns)."""

    mission: Path
    speed: float
    out: Path
    scenario: Path = SCENARIO
    rrd: Path | None = None
    mcap: Path | None = None
    faults: dict[str, Any] | None = None
    start_delay: float = 60.0  # the latest: vehicle time 0 comes once every part is up
    feedback_timeout: float = 1.0
    max_vehicle_s: float | None = None
    fusion_lag_s: float = FUSION_LAG_S
    nav_timeout: float = 2.0
    #: the sim paced by the pilot (``auvgw sim --lockstep``); False: free-running on the host
    #: clock, where a stalled process delays the loop in vehicle time
    lockstep: bool = True
    lockstep_step: float = 0.15
    #: vehicle s the lock-step sim runs before the pilot's first answer, on top of the fusion's
    #: clock warm-up and lag (:func:`lockstep_first_s`)
    lockstep_first: float = 1.0
    #: start the vehicle on the mission (at its first waypoint and depth, heading along leg 0,
    #: as the in-process runs do) instead of at the scenario's start pose
    start_on_mission: bool = False


def lockstep_first_s(fusion: FusionStageConfig, first: float = 1.0) -> float:
    """Vehicle s a lock-step sim may run before the pilot's first answer: ``first`` plus the
    fusion's clock warm-up and fixed lag. The warm-up holds every sample of its first
    ``clock_warmup_s`` of receive time, and the gateway stamps receive time on the sim's clock:
    a first hold shorter than that stands the clock still before the warm-up ends, so no
    odometry, no answer, and only the hold timeouts move vehicle time on."""
    return first + fusion.clock_warmup_s + fusion.filter.max_latency_s


@dataclass
class ChainResult:
    """What a chain run did: the pilot's last ``mode`` / ``abort_reason``, the legs it
    completed (``legs_done`` of ``n_legs``), ``done_vehicle_s`` (None: not done), errors
    against the truth while running (m: ``xte_rms``, ``xte_max``, ``depth_rms``,
    ``depth_max``), ``nav_rms`` (odometry position against the truth, m, horizontal),
    ``flown_s`` (vehicle s running), the gateway's command counters, the exit codes and the
    lock-step summary."""

    mode: str = "waiting"
    abort_reason: str = ""
    legs_done: int = 0
    n_legs: int = 0
    done_vehicle_s: float | None = None
    xte_rms: float = math.nan
    xte_max: float = math.nan
    depth_rms: float = math.nan
    depth_max: float = math.nan
    nav_rms: float = math.nan
    nav_final: float = math.nan
    flown_s: float = 0.0
    commands: dict[str, Any] = field(default_factory=dict)
    pilot: dict[str, Any] = field(default_factory=dict)
    processes: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0
    #: the lock-step sim's closing line (answers, holds, host s held, hold timeouts); "" when
    #: free-running
    lockstep: str = ""

    def line(self) -> str:
        """One line: mode, legs, errors against the truth."""
        done = "" if self.done_vehicle_s is None else f" at vehicle t = {self.done_vehicle_s:.1f} s"
        why = f" ({self.abort_reason})" if self.abort_reason else ""
        return (f"{self.mode}{why}{done}, legs {self.legs_done}/{self.n_legs}; against the truth: "
                f"cross-track RMS {self.xte_rms:.2f} m (max {self.xte_max:.2f}), depth RMS "
                f"{self.depth_rms:.3f} m (max {self.depth_max:.2f}); navigation error RMS "
                f"{self.nav_rms:.2f} m (final {self.nav_final:.2f})")  # fmt: skip


def score(mission: Mission, truth: np.ndarray, states: list[tuple[float, int, str]],
          odometry: np.ndarray | None = None) -> dict[str, float]:  # fmt: skip
    """Errors of the flown path against the mission: ``truth`` rows ``(t, north, east, depth)``
    (vehicle s, m, NED), ``states`` the pilot's ``(t, leg, mode)`` in vehicle s (sorted). Each
    truth sample takes the leg and mode of the newest state at or before it; over the samples
    in mode ``running``: ``xte_rms`` / ``xte_max`` (m, from the leg's line), ``depth_rms`` /
    ``depth_max`` (m, from the leg's end depth), ``flown_s``. With ``odometry`` rows ``(t,
    north, east)``: ``nav_rms`` / ``nav_final``, its horizontal distance from the truth (m) at
    the truth's times while running."""
    out = {"xte_rms": math.nan, "xte_max": math.nan, "depth_rms": math.nan,
           "depth_max": math.nan, "flown_s": 0.0, "nav_rms": math.nan, "nav_final": math.nan}
    if not states or len(truth) == 0:
        return out
    st_t = np.array([s[0] for s in states])
    idx = np.searchsorted(st_t, truth[:, 0], side="right") - 1
    xte, dz, keep = [], [], []
    for k, i in enumerate(idx):
        if i < 0 or states[i][2] != "running":
            continue
        leg = states[i][1]
        _, n, e, d = truth[k]
        xte.append(cross_track(mission, leg, n, e))
        dz.append(d - mission.leg(leg)[1].depth)
        keep.append(k)
    if not keep:
        return out
    x, z = np.abs(np.array(xte)), np.abs(np.array(dz))
    tt = truth[keep, 0]
    out.update(xte_rms=float(np.sqrt(np.mean(x**2))), xte_max=float(x.max()),
               depth_rms=float(np.sqrt(np.mean(z**2))), depth_max=float(z.max()),
               flown_s=float(tt[-1] - tt[0]))  # fmt: skip
    if odometry is not None and len(odometry) > 1:
        on = np.interp(tt, odometry[:, 0], odometry[:, 1])
        oe = np.interp(tt, odometry[:, 0], odometry[:, 2])
        ok = (tt >= odometry[0, 0]) & (tt <= odometry[-1, 0])
        if ok.any():
            err = np.hypot(on - truth[keep, 1], oe - truth[keep, 2])[ok]
            out.update(nav_rms=float(np.sqrt(np.mean(err**2))), nav_final=float(err[-1]))
    return out


class _Follow:
    """This process's subscriptions: the pilot's state, the odometry and the status keys."""

    def __init__(self, session: zenoh.Session, vehicle: str, epoch_s: float, out: Path) -> None:
        from auvgw.bus import Keys, decode_envelope

        self._decode = decode_envelope
        self.epoch_s = epoch_s
        self.lock = threading.Lock()
        self.states: list[tuple[float, int, str]] = []
        self.last_state: dict[str, Any] = {}
        self.odometry: list[tuple[float, float, float]] = []
        self.status: dict[str, dict[str, Any]] = {}
        # what the pilot saw and did, one JSON object per line (for the results' plots)
        self._files = {w: open(out / f"{w}.jsonl", "w")  # noqa: SIM115 (closed in close)
                       for w in ("odometry", "pilot_state", "pilot_command")}  # fmt: skip
        keys = Keys(vehicle)
        self._subs = [
            session.declare_subscriber(f"{keys.base}/pilot/state", self._on_state),
            session.declare_subscriber(keys.odometry(), self._on_odometry),
            session.declare_subscriber(keys.status("*"), self._on_status),
            session.declare_subscriber(f"{keys.base}/pilot/command", self._on_command),
        ]

    def _on_state(self, sample: zenoh.Sample) -> None:
        s = json.loads(sample.payload.to_bytes())
        with self.lock:
            self.states.append((float(s["t"]) - self.epoch_s, int(s["leg"]), str(s["mode"])))
            self.last_state = s
            self._files["pilot_state"].write(json.dumps(s) + "\n")

    def _on_command(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self._files["pilot_command"].write(sample.payload.to_bytes().decode() + "\n")

    def _on_odometry(self, sample: zenoh.Sample) -> None:
        o = self._decode(sample.payload.to_bytes()).body
        with self.lock:
            self.odometry.append((float(o["t"]) - self.epoch_s, float(o["x"]), float(o["y"])))
            self._files["odometry"].write(json.dumps(o, default=_jsonable) + "\n")

    def _on_status(self, sample: zenoh.Sample) -> None:
        component = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            self.status[component] = json.loads(sample.payload.to_bytes())

    def mode(self) -> str:
        with self.lock:
            return str(self.last_state.get("mode", "waiting"))

    def close(self) -> None:
        from auvgw.bus import undeclare

        undeclare(self._subs)
        with self.lock:
            for f in self._files.values():
                f.close()


def _jsonable(v: object) -> object:
    return v.tolist() if hasattr(v, "tolist") else str(v)


def _duration(mission: Mission, run: ChainRun) -> float:
    if run.max_vehicle_s is not None:
        return run.max_vehicle_s
    slowest = max(_MIN_SPEED, min(w.speed for w in mission.waypoints))
    return 1.5 * mission.length / slowest + 60.0


def fly_chain(run: ChainRun, progress: bool = False) -> ChainResult:
    """Fly ``run`` through the chain (see the module docstring) and score it against the truth."""
    from auvgw.bus import Keys, open_session
    from auvgw.commands.demo_parts import (
        START_FILE,
        TruthSample,
        _fusion_config,
        _gateway_toml,
        _load_sim_config,
        _sim_epoch_ns,
        _start_vehicle,
        _TruthTail,
        _wait_for,
    )
    from auvgw.config.bus import BusConfig
    from auvgw.config.scenario import load_scenario
    from auvgw.ground.procs import Children, free_endpoint
    from auvgw.subscribe import GatewaySubscriber

    mission = load_mission(run.mission)
    out = run.out
    out.mkdir(parents=True, exist_ok=True)
    scenario = _scenario_on_mission(run.scenario, mission, out) if run.start_on_mission \
        else run.scenario  # fmt: skip
    scn = load_scenario(scenario)
    sim_dir = out / "sim"
    sim_dir.mkdir(exist_ok=True)
    for stale in ("gateway.toml", "truth.jsonl", "finished", "faults.json", "clock"):
        (sim_dir / stale).unlink(missing_ok=True)
    if run.faults:
        (sim_dir / "faults.json").write_text(json.dumps(run.faults))
    duration = _duration(mission, run)
    keys = Keys(VEHICLE)
    hub = free_endpoint()
    session = open_session(BusConfig(listen=[hub]))
    sub = GatewaySubscriber(VEHICLE, session=session)
    children = Children(out)
    truth_pub = session.declare_publisher(keys.truth("pose"))
    follow: _Follow | None = None
    res = ChainResult(n_legs=mission.n_legs)
    t0 = time.monotonic()
    truth_rows: list[tuple[float, float, float, float]] = []
    try:
        x0, y0, _ = scn.start_pose
        settings = out / "fusion.json"
        fusion = _fusion_config(VEHICLE, (x0, y0, scn.vehicle.depth_m), scn.devices.ins.noise)
        # the demo's fusion (its clock warm-up included) with the loop's short lag; the
        # lock-step sim's first hold leaves room for the warm-up (lockstep_first_s)
        filt = fusion.filter.model_copy(update={"max_latency_s": run.fusion_lag_s})
        fusion = fusion.model_copy(update={"filter": filt})
        settings.write_text(fusion.model_dump_json(indent=1))
        children.start("fusion", ["fusion", "--settings", str(settings), "--connect", hub,
                                  "--listen", free_endpoint()])  # fmt: skip
        lockstep = ["--lockstep", str(sim_dir / "clock")] if run.lockstep else []
        children.start("pilot", ["pilot", "--mission", str(run.mission), "--vehicle", VEHICLE,
                                 "--feedback-timeout", str(run.feedback_timeout),
                                 "--nav-timeout", str(run.nav_timeout), *lockstep,
                                 "--connect", hub, "--listen", free_endpoint()])  # fmt: skip
        wanted = {"fusion", "pilot", "gateway", "ins", "dvl", "actuators"}
        if run.rrd is not None:
            children.start("viz", ["viz", "--rrd", str(run.rrd), "--vehicle", VEHICLE,
                                   "--bus-connect", hub, "--bus-listen", free_endpoint()])
        if run.mcap is not None:
            children.start("record", ["record", "--vehicle", VEHICLE, "--out", str(run.mcap),
                                      "--force", "--connect", hub, "--listen", free_endpoint()])
        # the stages first, up before the sim starts its clock: vehicle time 0 then waits
        # only for the gateway (start_delay after the sim's gateway.toml at the latest)
        _wait_alive(sub, {"fusion", "pilot"}, children, 120.0)
        sim = children.start("sim", [
            "sim", "--scenario", str(scenario), "--speed", str(run.speed), "--duration",
            str(duration), "--out", str(sim_dir), "--vehicle", VEHICLE, "--hold",
            "--start-delay", str(run.start_delay), "--start-when", str(sim_dir / START_FILE),
            *(["--lockstep", "--lockstep-step", str(run.lockstep_step), "--lockstep-first",
               str(lockstep_first_s(fusion, run.lockstep_first)), "--connect", hub,
               "--listen", free_endpoint()] if run.lockstep else [])])  # fmt: skip
        _wait_for(sim_dir / "gateway.toml", sim, 120.0)
        gw_cfg = _read_when_written(lambda: _load_sim_config(sim_dir))
        epoch_s = _sim_epoch_ns(gw_cfg) / 1e9
        follow = _Follow(session, VEHICLE, epoch_s, out)
        children.start("gateway", ["run", "--config",
                                   str(_gateway_toml(sim_dir, out, free_endpoint(), hub))])
        # vehicle time 0 once every part is up and every port open (start_delay at the latest)
        wanted |= {name for name, d in gw_cfg.devices.items() if d.enabled}
        _wait_alive(sub, wanted, children, 120.0)
        ready_vehicle_s = _start_vehicle(sim_dir, run.speed)
        if ready_vehicle_s > 0:
            raise UserError(f"every part was up only at vehicle t = {ready_vehicle_s:.1f} s: "
                            "raise --start-delay")  # fmt: skip

        def on_truth(s: TruthSample) -> None:
            truth_rows.append((s["t"], s["x"], s["y"], s["z"]))
            truth_pub.put(json.dumps(s).encode())

        tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
        next_print = 0.0
        while follow.mode() not in ("done", "aborted"):
            tail.poll()
            name = children.exited()
            if name is not None:
                if name == "sim" or (sim_dir / "finished").exists():
                    break
                raise UserError(f"{name} stopped early: {children.tail(name)}")
            if (sim_dir / "finished").exists():
                break
            if progress and time.monotonic() > next_print:
                next_print = time.monotonic() + 10.0
                with follow.lock:
                    st = dict(follow.last_state)
                if st:
                    print(f"  vehicle t {st['t'] - epoch_s:7.1f} s  {st['mode']:8s} leg "
                          f"{st['leg']}/{st['n_legs']}  pilot's cross-track "
                          f"{st['cross_track']:6.2f} m", flush=True)  # fmt: skip
            time.sleep(0.2)
        # a few vehicle seconds more of truth after the end (the score stops at "done")
        end = time.monotonic() + 2.0 / run.speed + 0.5
        while time.monotonic() < end:
            tail.poll()
            time.sleep(0.1)
        gw = sub.status(timeout=2.0) or {}
        res.commands = dict((gw.get("devices", {}).get("actuators") or {}).get("commands") or {})
        _stop_all(children, ("pilot", "gateway", "fusion", "viz", "record", "sim"))
        tail.poll()
    finally:
        children.close()
        if follow is not None:
            follow.close()
        truth_pub.undeclare()
        sub.close()
        session.close()
    assert follow is not None
    res.processes = children.report()
    res.wall_s = time.monotonic() - t0
    res.pilot = dict(follow.status.get("pilot") or {})
    sim_log = out / "sim.log"
    if run.lockstep and sim_log.exists():
        lines = [ln for ln in sim_log.read_text(errors="replace").splitlines()
                 if ln.startswith("lock-step: ") and "answers" in ln]  # fmt: skip
        res.lockstep = lines[-1][len("lock-step: "):] if lines else "no summary (sim killed?)"
    last = follow.last_state
    res.mode = str(last.get("mode", "waiting"))
    res.abort_reason = str(last.get("abort_reason", ""))
    leg = int(last.get("leg", 0))
    res.legs_done = mission.n_legs if res.mode == "done" else leg
    done = [t for t, _, m in follow.states if m == "done"]
    res.done_vehicle_s = done[0] if done else None
    odo = np.array(follow.odometry, float).reshape(-1, 3)
    odo = odo[np.argsort(odo[:, 0], kind="stable")]
    sc = score(mission, np.array(truth_rows, float).reshape(-1, 4), sorted(follow.states), odo)
    for k, v in sc.items():
        setattr(res, k, v)
    return res


def _scenario_on_mission(scenario: Path, mission: Mission, out: Path) -> Path:
    """``OUT/scenario.json``: ``scenario`` with the vehicle starting at the mission's first
    waypoint and depth, heading along leg 0 (its route's two points set the start heading)."""
    data = json.loads(scenario.read_text())
    a, b = mission.leg(0)
    data["vehicle"]["waypoints"] = [[a.north, a.east], [b.north, b.east]]
    data["vehicle"]["depth_m"] = a.depth
    data["name"] = f"{data.get('name', 'scenario')}-on-{mission.name}"
    path = out / "scenario.json"
    path.write_text(json.dumps(data, indent=1))
    return path


def _read_when_written(read: Callable[[], _T], timeout_s: float = 10.0) -> _T:
    """``read()``, again while it fails for at most ``timeout_s``: the sim may still be
    writing the file that has just appeared."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return read()
        except UserError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def _stop_all(children: Children, names: tuple[str, ...], grace_s: float = 15.0) -> None:
    """SIGINT to every child in ``names`` at once (in that order), then wait for each (killed
    after ``grace_s``): their clean stops overlap."""
    import signal

    from auvgw.ground.procs import stop_process

    procs = [(n, children.procs[n]) for n in names if n in children.procs]
    for _, p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for n, p in procs:
        code, killed = stop_process(p, None, grace_s)
        children.exit_codes[n] = code
        if killed:
            children.killed.append(n)


def _wait_alive(
    sub: GatewaySubscriber, wanted: set[str], children: Children, timeout_s: float
) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        name = children.exited()
        if name is not None:
            raise UserError(f"{name} stopped early: {children.tail(name)}")
        missing = wanted - sub.alive(timeout=0.5)
        if not missing:
            return
        if time.monotonic() > deadline:
            raise UserError(f"no {', '.join(sorted(missing))} on the bus after {timeout_s:.0f} s")
        time.sleep(0.1)


def run_closed_loop(args: argparse.Namespace) -> int:
    """``auvgw demo --closed-loop``: fly ``--mission`` at ``--speed``; print and save the
    result (``OUT/closed_loop.json``)."""
    out: Path = args.out
    speed = float(args.speed if args.speed is not None else 1.0)
    if speed <= 0:
        raise UserError("--speed must be > 0 (the gateway reads the devices in real time)")
    mission = Path(args.mission) if args.mission else config_file("missions/box.toml")
    run = ChainRun(mission=mission, speed=speed, out=out,
                   rrd=None if args.no_viz else (args.rrd or out / "demo.rrd"),
                   mcap=out / "demo.mcap", start_delay=float(args.start_delay),
                   max_vehicle_s=args.duration)  # fmt: skip
    print(f"auvgw demo --closed-loop: mission {mission}, {speed:g}x real time; sim, gateway, "
          "fusion, pilot, viz and record each in its own process", flush=True)
    res = fly_chain(run, progress=True)
    print()
    print("pilot: " + res.line())
    print(f"commands at the gateway: {json.dumps(res.commands)}")
    if res.lockstep:
        print(f"lock-step: {res.lockstep}")
    print("processes: " + ", ".join(f"{n} exit {p['exit_code']}" + (" (killed)" if p["killed"]
                                    else "") for n, p in res.processes.items()))  # fmt: skip
    if run.rrd is not None:
        print(f"Rerun recording: {run.rrd}   recording: {run.mcap}")
    (out / "closed_loop.json").write_text(json.dumps(asdict(res), indent=1, default=str))
    return 0 if res.mode == "done" else 1
