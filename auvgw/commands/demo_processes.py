"""``auvgw demo --processes``: every part its own OS process on the demo's bus; this process
only listens (the bus hub), publishes the truth, collects odometry, SLAM poses and status."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from auvgw.bus import Keys, decode_envelope, open_session
from auvgw.commands.common import UserError
from auvgw.commands.demo_parts import (
    START_FILE,
    VEHICLE,
    DemoContext,
    DemoPlan,
    TruthSample,
    _fusion_config,
    _gateway_toml,
    _load_sim_config,
    _sim_argv,
    _sim_done,
    _sim_epoch_ns,
    _start_vehicle,
    _streamed_frames,
    _true_beacons,
    _TruthTail,
    _wait_drained,
    _wait_for,
)
from auvgw.commands.demo_report import (
    Track,
    _map_summary,
    _Progress,
    _report,
    _smoothed_track,
)
from auvgw.config.bus import BusConfig
from auvgw.config.scenario import load_scenario
from auvgw.ground.procs import Children, free_endpoint
from auvgw.slam import pipelines
from auvgw.subscribe import slam_output

if TYPE_CHECKING:
    import zenoh

    from auvgw.subscribe import GatewaySubscriber


def _check_children(children: Children) -> None:
    """A :class:`UserError` if a child other than the sim has exited."""
    name = children.exited(but=("sim",))
    if name is not None:
        code = children.procs[name].returncode
        raise UserError(f"{name} stopped early (exit {code}): {children.tail(name)}")


class _Collector:
    """This process's subscriptions in ``--processes`` mode: odometry (stamped time, vehicle
    time, host arrival), SLAM poses and the latest status of every component."""

    def __init__(self, session: zenoh.Session, keys: Keys, epoch_s: float) -> None:
        self.epoch_s = epoch_s
        self.lock = threading.Lock()
        self.dead_reckoning, self.slam, self.truth = Track(), Track(), Track()
        self.odometry_stamps: list[tuple[float, float]] = []  # (envelope stamp s, host s)
        self.status: dict[str, dict[str, Any]] = {}
        self._subs = [
            session.declare_subscriber(keys.odometry(), self._on_odometry),
            session.declare_subscriber(keys.slam("*", "pose"), self._on_slam),
            session.declare_subscriber(keys.status("*"), self._on_status),
        ]

    def _on_odometry(self, sample: zenoh.Sample) -> None:
        env = decode_envelope(sample.payload.to_bytes())
        o = env.body
        with self.lock:
            self.dead_reckoning.add_odometry(
                o["t"] - self.epoch_s, o["x"], o["y"], bool(o["coasting"]), o["heading"]
            )
            self.odometry_stamps.append((env.t_recv_ns / 1e9, time.time()))

    def _on_slam(self, sample: zenoh.Sample) -> None:
        p = slam_output(sample.payload.to_bytes(), str(sample.key_expr))
        with self.lock:
            self.slam.add(p["t"] - self.epoch_s, p["x"], p["y"])

    def _on_status(self, sample: zenoh.Sample) -> None:
        component = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            self.status[component] = json.loads(sample.payload.to_bytes())

    def received(self, component: str) -> int:
        """Bus messages ``component`` (a stage) has counted as received, by its last status."""
        with self.lock:
            return int((self.status.get(component) or {}).get("stage", {}).get("received", 0))

    def close(self) -> None:
        from auvgw.bus import undeclare

        undeclare(self._subs)

    def wait_stopped(
        self, components: list[str], map_tap: _MapTap | None, limit_s: float = 10.0
    ) -> None:
        """Wait (at most ``limit_s``) for the last status of each stage in ``components`` (its
        ``stopped`` status, put after every pose and odometry sample it published) and, with
        ``map_tap``, for the whole map that went out before it (a lower-priority output, so it
        may arrive after the status)."""
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            with self.lock:
                last = [self.status.get(c) or {} for c in components]
            done = all(st.get("stopped") for st in last)
            if done and map_tap is not None:
                pings = last[-1].get("pings")
                done = (
                    bool(map_tap.last)
                    and bool(map_tap.track)
                    and slam_output(map_tap.last[-1]).get("pings") == pings
                )
            if done:
                return
            time.sleep(0.05)

    def timing(self) -> dict[str, Any]:
        """How the odometry envelopes' stamps advanced: the vehicle time of the first, their
        span (vehicle s) and their rate against the host clock of their arrival (stamped s per
        host s; the samples flushed at shutdown, all stamped with the last input's time, left
        out): ``speed`` when the stamps are vehicle-paced. The rate is the median slope over
        pairs half the run apart, so a burst delivered late by a stalled process (a busy
        machine) moves only the few pairs it is part of, where a least-squares fit would tilt."""
        with self.lock:
            st = np.asarray(self.odometry_stamps, float).reshape(-1, 2)
        if len(st) < 2:
            return {"samples": len(st)}
        live = st[st[:, 0] < st[:, 0].max()]
        half = len(live) // 2
        dt_host = live[half:, 1] - live[: len(live) - half, 1]
        ok = dt_host > 0
        d_stamp = live[half:, 0] - live[: len(live) - half, 0]
        rate = float(np.median(d_stamp[ok] / dt_host[ok])) if ok.any() else float("nan")
        return {
            "samples": len(st),
            "first_vehicle_s": float(st[0, 0] - self.epoch_s),
            "stamp_span_s": float(st[-1, 0] - st[0, 0]),
            "stamp_rate": rate if len(live) > 1 else None,
        }


def _wait_alive(
    sub: GatewaySubscriber, wanted: set[str], children: Children, timeout_s: float, what: str
) -> float:
    """Wait until every component in ``wanted`` holds its liveliness token; host time then."""
    deadline = time.monotonic() + timeout_s
    while True:
        _check_children(children)
        missing = wanted - sub.alive(timeout=0.5)
        if not missing:
            return time.time()
        if time.monotonic() > deadline:
            raise UserError(f"{what}: no {', '.join(sorted(missing))} on the bus after "
                            f"{timeout_s:.0f} s")  # fmt: skip
        time.sleep(0.1)


def _run_processes(
    args: argparse.Namespace, sim_dir: Path, scenario: Path, rrd: Path | None, speed: float
) -> int:
    from auvgw.subscribe import GatewaySubscriber

    out: Path = args.out
    scn = load_scenario(scenario)
    keys = Keys(VEHICLE)
    hub = free_endpoint()
    session = open_session(BusConfig(listen=[hub]))
    sub = GatewaySubscriber(VEHICLE, session=session)
    children = Children(out)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    t_start = time.monotonic()
    collector: _Collector | None = None
    map_tap: _MapTap | None = None
    slam_part: tuple[str, str] | None = None  # the SLAM stage's display name and component
    truth_pub = session.declare_publisher(keys.truth("pose"))
    try:
        # the stages first (they need nothing from the sim), so they are up before vehicle t = 0
        x0, y0, _ = scn.start_pose
        settings = out / "fusion.json"
        settings.write_text(_fusion_config(VEHICLE, (x0, y0, scn.vehicle.depth_m),
                                           scn.devices.ins.noise, speed)
                            .model_dump_json(indent=1))  # fmt: skip
        children.start("fusion", ["fusion", "--settings", str(settings),
                                  "--connect", hub, "--listen", free_endpoint()])  # fmt: skip
        wanted = {"fusion", "gateway", "ins", "dvl"}
        # the SLAM pipeline's processes, as its registry record says (demo_processes)
        record = None if args.no_slam else pipelines.for_demo(scn)
        ctx = DemoContext(scenario, scn, VEHICLE, hub, free_endpoint)
        plan: DemoPlan | None = None if record is None else pipelines.load(
            record.demo_processes)(ctx)  # fmt: skip
        if plan is not None:
            slam_part = (plan.display, plan.component)
            wanted |= plan.alive
            for proc in plan.processes:
                if not proc.after_clock:
                    children.start(proc.name, proc.argv(None))
        # the GeoSwath's emulator (numpy work on 4000-sample pings) in its own process, so it
        # never holds the INS emulator's interpreter (issue 31: in one sim process its pings
        # made the INS frames leave 40-58 vehicle s late at 10x): every device then has its own
        # process. Vehicle time 0 once every part is up (elastic pacing: the stamps follow the sim's
        # clock file), --start-delay at the latest (free pacing: always; host time maps to it)
        elastic = args.pace == "elastic"
        sim = children.start("sim", [*_sim_argv(scenario, speed, args.duration, sim_dir, args.pace),
                                     "--start-delay", str(args.start_delay),
                                     *(["--start-when", str(sim_dir / START_FILE)] if elastic
                                       else []),
                                     *(["--processes"] if scn.devices.geoswath.enabled
                                       else [])])  # fmt: skip
        _wait_for(sim_dir / "gateway.toml", sim, 120.0)
        gw_cfg = _load_sim_config(sim_dir)
        epoch_ns = _sim_epoch_ns(gw_cfg)
        collector = _Collector(session, keys, epoch_ns / 1e9)
        if record is not None and _MapTap.taps(record):
            map_tap = _MapTap(session, keys, record)
        gw_argv = ["run", "--config", str(_gateway_toml(sim_dir, out, free_endpoint(), hub))]
        if rrd is not None:
            gw_argv += ["--viz-rrd", str(rrd)]
        if args.connect:
            gw_argv += ["--viz-connect", args.connect]
        children.start("gateway", gw_argv)
        for proc in plan.processes if plan is not None else ():
            if proc.after_clock:  # after gateway.toml: its [clock] epoch (vehicle time 0)
                children.start(proc.name, proc.argv(epoch_ns))
        # every device's port open too (the fixed 10 s gave them all the time to): vehicle
        # time 0 follows
        wanted |= {name for name, d in gw_cfg.devices.items() if d.enabled}
        ready = _wait_alive(sub, wanted, children, 120.0, "--processes")
        if elastic:
            ready_vehicle_s = _start_vehicle(sim_dir, speed)
        else:
            ready_vehicle_s = (ready - epoch_ns / 1e9) * speed
        beacons = _true_beacons(scn)
        if beacons and rrd is not None:  # the true beacons, for the gateway's Rerun recording
            session.put(keys.truth("map"), json.dumps({"t": 0.0, **beacons}).encode())
        if ready_vehicle_s > 0:
            print(f"  warning: every part was up only at vehicle t = {ready_vehicle_s:.1f} s "
                  "(dead reckoning starts from the pose at t = 0)", flush=True)  # fmt: skip

        def on_truth(sample: TruthSample) -> None:
            assert collector is not None
            with collector.lock:
                collector.truth.add(sample["t"], sample["x"], sample["y"], sample["heading"])
            truth_pub.put(json.dumps(sample).encode())

        tail = _TruthTail(sim_dir / "truth.jsonl", on_truth)
        progress = _Progress(tail, args.duration)
        while not _sim_done(sim, sim_dir) and not stop.is_set():
            tail.poll()
            _check_children(children)
            stop.wait(0.2)
            progress.tick()
        tail.poll()
        # the devices are silent, their ports still open: the gateway drains them; then stop in
        # data-flow order: gateway, fusion (flushes its held-back odometry), SLAM once what they
        # put has reached it (its received count quiet for two status periods; a loaded machine
        # holds samples in flight for seconds), which drains its queue and publishes its last
        # pose, and the emulators last
        _wait_drained(lambda: _streamed_frames(
            gw_cfg, (sub.status(timeout=2.0) or {"devices": {}})["devices"]), quiet_s=1.5)
        status = sub.status(timeout=2.0) or collector.status.get("gateway") or {"devices": {}}
        # the plan's processes in front of its stage (the last) with them (a swath stage: flushes
        # its last swaths)
        parts = [p.name for p in plan.processes] if plan is not None else []
        for name in ("gateway", "fusion", *parts[:-1]):
            children.stop(name)
        if slam_part is not None:
            _wait_drained(partial(collector.received, slam_part[1]), quiet_s=2.5, limit_s=20.0)
        for name in (*parts[-1:], "sim"):
            children.stop(name)
        collector.wait_stopped(["fusion", *([slam_part[1]] if slam_part else [])], map_tap)
    finally:
        children.close()
        if collector is not None:
            collector.close()
        if map_tap is not None:
            map_tap.close()
        truth_pub.undeclare()
        sub.close()
        session.close()
    wall = time.monotonic() - t_start
    procs = children.report()
    print()
    print("processes: " + ", ".join(
        f"{n} pid {p['pid']} exit {p['exit_code']}" + (" (killed)" if p["killed"] else "")
        for n, p in procs.items()))  # fmt: skip
    c = collector
    assert c is not None
    slam = None if slam_part is None or record is None else (
        record, slam_part[0], c.status.get(slam_part[1]))  # fmt: skip
    _report(
        args, status, c.status.get("fusion"), slam, c.dead_reckoning, c.slam, c.truth, rrd, wall,
        speed, {"processes": procs, "odometry_timing": c.timing(),
                "ready_vehicle_s": ready_vehicle_s,
                **_map_summary(map_tap.last if map_tap else [], scn)},
        smoothed=_smoothed_track(map_tap.track if map_tap else [], epoch_ns / 1e9),
    )  # fmt: skip
    bad = [n for n, p in procs.items() if p["exit_code"] != 0]
    if bad:
        print(f"not every part exited cleanly: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


class _MapTap:
    """``--processes``: a pipeline's latest DEM payload (its output of view ``dem``: the whole map
    once the stage has flushed) and its smoothed trajectory (view ``path``, at flush)."""

    def __init__(self, session: zenoh.Session, keys: Keys, record: pipelines.Pipeline) -> None:
        self.last: list[bytes] = []
        self.track: list[bytes] = []
        what = {o.view: o.what for o in record.outputs}
        self._subs = [
            session.declare_subscriber(keys.slam(record.name, what["dem"]), self._on_map),
            session.declare_subscriber(keys.slam(record.name, what["path"]), self._on_track),
        ]

    @staticmethod
    def taps(record: pipelines.Pipeline) -> bool:
        """Whether ``record``'s stage publishes a DEM and a smoothed trajectory."""
        return {"dem", "path"} <= {o.view for o in record.outputs}

    def _on_map(self, sample: zenoh.Sample) -> None:
        self.last[:] = [sample.payload.to_bytes()]

    def _on_track(self, sample: zenoh.Sample) -> None:
        self.track[:] = [sample.payload.to_bytes()]

    def close(self) -> None:
        from auvgw.bus import undeclare

        undeclare(self._subs)
