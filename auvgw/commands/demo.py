"""``auvgw demo``: the whole vehicle on a desk, on embedded defaults.

Starts the emulated vehicle (``auvgw sim`` on a shipped scenario, in its own process, every device
on its own virtual port), then in this process the gateway (embedded Zenoh peer), the navigation
fusion, the SLAM stage where one is installed, and the Rerun recording; runs a few minutes of
vehicle time faster than real time; writes ``demo.rrd`` and ``summary.json`` and prints a summary:
messages per device, errors, and navigation error against ground truth.

``--processes``: the same chain as it runs on a vehicle, every part its own OS process joined by
Zenoh over loopback TCP: ``auvgw sim``, the gateway (``auvgw run``), the fusion stage (``auvgw
fusion``) and the SLAM stage (``auvgw slam-run``, live). This process only listens (the bus hub
the others connect to), publishes the ground truth on ``auv/<v>/truth/pose``, collects odometry
and SLAM poses and the components' status, stops the children (SIGINT, then kill) and reports
their exit codes. Vehicle time 0 is held back until every part is up (``auvgw sim
--start-delay``), so dead reckoning starts from the scenario's start pose.

``--scenario beacons`` (a scenario with magnetic beacons and a magnetometer): the SLAM stage is
the magnetic one (AMB-SLAM on the MS3A samples, the acoustic beacon's replies and the fusion
odometry; ``auvgw slam run --pipeline magnetic`` with ``--processes``, started once the sim's
``[clock]`` epoch, the beacons' phase reference, is known); the summary prints its counters and
its error against the truth beside dead reckoning's (RMSE / distance x 100), and the Rerun
recording gets the true and estimated beacons, their ellipses, the ranges and the acoustic beacon.

Time: the emulators run ``speed`` times faster than the host clock, so the device clocks advance
``speed`` vehicle seconds per host second. ``auvgw sim`` writes the gateway's ``[clock]`` section
(``time_scale = speed``, ``epoch_ns`` = host time of vehicle time 0), so the gateway stamps
*vehicle-paced* receive times (``epoch + (t_recv - epoch) * speed``) and every device clock keeps
a constant offset to them, exactly as on a real vehicle at speed 1; the stages take their time
from those stamps only, in this process or their own. Vehicle seconds = stamp - epoch.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
from pathlib import Path

from auvgw.commands.common import SubParsers, UserError, add_command
from auvgw.commands.demo_inprocess import _run_stages
from auvgw.commands.demo_parts import (
    FREE_START_DELAY_S,
    START_DELAY_S,
    _sim_argv,
    _wait_for,
)
from auvgw.commands.demo_processes import _run_processes
from auvgw.config.scenario import ScenarioError, load_scenario
from auvgw.ground.paths import config_file
from auvgw.ground.procs import stop_process
from auvgw.slam import pipelines

DEFAULT_SCENARIO = "harbour"
#: the demo's vehicle seconds and speed (x real time) unless told otherwise
DEFAULT_DURATION_S = 180.0
DEFAULT_SPEED = 2.0


def register(sub: SubParsers) -> None:
    p = add_command(sub, "demo", __doc__)
    p.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        help="shipped scenario name ("
        + ", ".join(f"{r.demo_scenario}: {r.name} SLAM" for r in pipelines.of_kind("slam"))
        + ") or a scenario JSON file",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help=f"vehicle seconds (default {DEFAULT_DURATION_S:.0f}; with --processes on the "
        "scenario of a pipeline with a route speed ("
        + ", ".join(r.demo_scenario for r in pipelines.of_kind("slam") if r.demo_route_speed)
        + "): its whole route; a survey's, about 30 min, whose tie line crosses every line: "
        "the loop closures)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help=f"x real time (default {DEFAULT_SPEED:g}; with --processes, its pipeline's route "
        "speed: "
        + ", ".join(f"{r.demo_scenario} {r.demo_route_speed:g}" for r in pipelines.of_kind("slam")
                    if r.demo_route_speed)
        + ")",
    )
    p.add_argument("--pace", choices=("elastic", "free"), default="elastic",
                   help="the sim's clock (auvgw sim --pace): elastic (default) waits for its "
                   "devices on a loaded host; free runs at --speed whatever happens")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--rrd", type=Path, default=None, help="Rerun file (default OUT/demo.rrd)")
    p.add_argument("--connect", default=None, help="also stream to a Rerun viewer at this URL")
    p.add_argument("--no-viz", action="store_true", help="no Rerun recording")
    p.add_argument("--no-slam", action="store_true", help="no SLAM stage")
    p.add_argument(
        "--multibeam",
        choices=("kongsberg", "geoswath"),
        default="kongsberg",
        help="a survey's multibeam: Kongsberg XYZ 88 swaths (default) or GeoSwath raw pings, "
        "processed into swaths by the swath stage (auvgw.stages.swath) for the bathymetric SLAM",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="the scenario's emulator seed (every device's noise draws; default: the "
        "scenario's). Tuning runs take seeds below 1000, reported runs 1000 and up "
        "(auvgw.slam.evaluation.heldout)",
    )
    p.add_argument(
        "--processes",
        action="store_true",
        help="sim, gateway, fusion and SLAM each in its own OS process (this one only collects)",
    )
    p.add_argument(
        "--start-delay",
        type=float,
        default=None,
        metavar="S",
        help="--processes, --closed-loop: host seconds from the sim's gateway.toml to vehicle "
        "time 0 at the latest; it comes as soon as every part is up and the gateway has opened "
        f"every port (default {START_DELAY_S:g}; --pace free: always this, default "
        f"{FREE_START_DELAY_S:g})",
    )
    for rec in pipelines.of_kind("control"):  # each control pipeline's own demo option
        p.add_argument(rec.demo_option, action="store_true", dest=f"run_{rec.name}",
                       help=f"run the {rec.name} pipeline on its scenario ({rec.demo_scenario}) "
                       "through the whole chain, each part a process, and print the errors "
                       f"against the truth: {rec.summary}")  # fmt: skip
    p.add_argument("--mission", type=Path, default=None,
                   help="--closed-loop: mission file (default config/missions/box.toml)")
    p.set_defaults(func=run)


def _scenario_path(name: str) -> Path:
    p = Path(name)
    if p.suffix == ".json" or p.exists():
        return p
    shipped = config_file(f"scenarios/{name}.json")
    if not shipped.is_file():
        raise UserError(f"--scenario {name}: not a file and not a shipped scenario")
    return shipped


def _demo_scenario(
    src: Path, out: Path, multibeam: str = "kongsberg", seed: int | None = None
) -> Path:
    """The scenario with the INS on serial only: python-can's slcan reader handles ~1400 CAN
    frames/s here, and the HN-100's 800 frames/s x speed would overrun it (the CAN form of the
    INS is exercised by the tests; the magnetometer keeps its CAN form). ``multibeam``
    "geoswath": the GeoSwath emulator replaces a multibeam the scenario has on. ``seed``: the
    emulators' seed instead of the scenario's. The devices the scenario's pipeline does not read
    (its record's ``demo_idle_devices``) are off unless its file turns them on: on a loaded host
    they only add lag, and the INS clock resets lag causes move dead reckoning's stamps off the
    vehicle's time."""
    try:
        scn = load_scenario(src)
    except ScenarioError as exc:
        raise UserError(str(exc)) from exc
    data = json.loads(src.read_text())
    devices = data.setdefault("devices", {})
    ins = devices.setdefault("ins", {})
    ins.setdefault("options", {})["can"] = False
    if seed is not None:
        data["seed"] = seed
    for name in pipelines.for_demo(scn).demo_idle_devices:
        devices.setdefault(name, {}).setdefault("enabled", False)
    if multibeam == "geoswath" and scn.devices.multibeam.enabled:
        devices["multibeam"] = {**devices.get("multibeam", {}), "enabled": False}
        devices["geoswath"] = {**devices.get("geoswath", {}), "enabled": True}
    # relative file references stay valid: resolve them against the original scenario
    for section, key in (("features", "points_file"), ("vehicle", "waypoints_file")):
        ref = data.get(section, {}).get(key)
        if ref and not str(ref).startswith("shared:") and not Path(ref).is_absolute():
            data[section][key] = str((src.parent / ref).resolve())
    path = out / f"{scn.name}-demo.json"
    path.write_text(json.dumps(data, indent=1))
    return path


def run(args: argparse.Namespace) -> int:
    if args.start_delay is None:  # only the latest, unless free pacing waits all of it
        args.start_delay = FREE_START_DELAY_S if args.pace == "free" else START_DELAY_S
    if not 0 <= args.start_delay <= 600:
        raise UserError(f"--start-delay must be 0 to 600 s, got {args.start_delay}")
    for rec in pipelines.of_kind("control"):
        if getattr(args, f"run_{rec.name}"):
            return int(rec.entry("demo_run")(args))
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    sim_dir = out / "sim"
    for stale in ("gateway.toml", "truth.jsonl", "finished", "clock"):
        (sim_dir / stale).unlink(missing_ok=True)
    scenario = _demo_scenario(_scenario_path(args.scenario), out, args.multibeam, args.seed)
    _scenario_defaults(args, scenario)
    rrd = None if args.no_viz else (args.rrd or out / "demo.rrd")
    speed = float(args.speed)
    if speed <= 0:
        raise UserError("--speed must be > 0 (the gateway reads the devices in real time)")

    print(f"auvgw demo: scenario {scenario.name}, {args.duration:.0f} s of vehicle time at "
          f"{speed:g}x real time" + (", one process per part" if args.processes else ""),
          flush=True)  # fmt: skip
    if args.processes:
        return _run_processes(args, sim_dir, scenario, rrd, speed)
    sim_log = open(out / "sim.log", "wb")  # noqa: SIM115 (closed in finally)
    sim = subprocess.Popen(
        [sys.executable, "-m", "auvgw",
         *_sim_argv(scenario, speed, args.duration, sim_dir, args.pace)],
        stdout=sim_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        _wait_for(sim_dir / "gateway.toml", sim, 60.0)
        return _run_stages(args, sim, sim_dir, scenario, rrd, speed)
    finally:
        stop_process(sim, signal.SIGINT, 20.0)
        sim_log.close()


def _scenario_defaults(args: argparse.Namespace, scenario: Path) -> None:
    """``--duration`` and ``--speed`` where not given: with ``--processes``, the whole route at
    the speed of the scenario's pipeline (its record's ``demo_route_speed``: the survey's loop
    closures, the bathymetric SLAM's gain over dead reckoning, come along the whole route); any
    other run :data:`DEFAULT_DURATION_S` at :data:`DEFAULT_SPEED` (one process does not keep up
    with the survey's devices at 10x: it lost 40 % of the INS frames and dead reckoning
    diverged, measured here)."""
    record = pipelines.for_demo(load_scenario(scenario))
    route_speed = record.demo_route_speed
    whole = route_speed is not None and args.processes
    if args.speed is None:
        args.speed = route_speed if whole else DEFAULT_SPEED
    if args.duration is None:
        args.duration = DEFAULT_DURATION_S
        if whole:
            from auvgw.sim_devices.vehicle import simulate
            from auvgw.sim_devices.world import World

            scn = load_scenario(scenario)
            args.duration = math.ceil(simulate(scn, World.from_scenario(scn)).duration)
        elif route_speed is not None:
            print(f"note: the {record.name} SLAM's gain comes along the whole route; `auvgw demo "
                  f"--scenario {args.scenario} --processes` runs it at {route_speed:g}x",
                  flush=True)  # fmt: skip
