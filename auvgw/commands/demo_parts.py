"""Parts of ``auvgw demo`` shared by its modes (in one process,
:mod:`auvgw.commands.demo_inprocess`; one process per part, :mod:`auvgw.commands.demo_processes`;
the closed loop, :mod:`auvgw.commands.demo_closed_loop`): the sim's truth log followed, its
gateway configuration read and joined to the demo's bus, the fusion's settings, and what a SLAM
pipeline's record says it needs in the demo (:class:`InProcessPlan`, from its
``demo_inprocess`` entry; :class:`DemoPlan`, from its ``demo_processes`` entry)."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from auvgw.commands.common import UserError
from auvgw.config.gateway import ConfigError, load_gateway_config

if TYPE_CHECKING:
    import zenoh

    from auvgw.config.gateway import GatewayConfig
    from auvgw.config.scenario import Scenario
    from auvgw.stages.base import Stage
    from auvgw.stages.fusion import FusionStageConfig

__all__ = [
    "FREE_START_DELAY_S",
    "START_DELAY_S",
    "START_FILE",
    "START_LEAD_S",
    "VEHICLE",
    "DemoContext",
    "DemoPlan",
    "DemoProcess",
    "InProcessContext",
    "InProcessPlan",
    "OnPublish",
    "TruthSample",
    "_TruthTail",
    "_fusion_config",
    "_gateway_toml",
    "_load_sim_config",
    "_sim_argv",
    "_sim_done",
    "_sim_epoch_ns",
    "_start_vehicle",
    "_streamed_frames",
    "_true_beacons",
    "_wait_drained",
    "_wait_for",
]


#: one truth sample of the simulator's log (t s, x, y, z m, heading rad...)
TruthSample = dict[str, float]


@dataclass(frozen=True)
class DemoContext:
    """What a pipeline's demo processes are made from: the scenario (``scenario``: its file,
    ``scn``: loaded), the vehicle, the bus hub every child connects to (``hub``) and ``listen``,
    which gives each child an endpoint of its own (a free one per call)."""

    scenario: Path
    scn: Scenario
    vehicle: str
    hub: str
    listen: Callable[[], str]

    def bus_args(self) -> list[str]:
        """``--connect <hub> --listen <a free endpoint>``: a child on the demo's bus."""
        return ["--connect", self.hub, "--listen", self.listen()]


@dataclass(frozen=True)
class DemoProcess:
    """One child process of a pipeline in ``demo --processes``: its name (the demo's
    ``Children``), its ``auvgw`` arguments; ``after_clock``: started once the sim's gateway
    configuration gives vehicle time 0 (its ``[clock] epoch_ns``), which ``argv`` is then
    called with (else with None, before the sim starts: up before vehicle t = 0)."""

    name: str
    argv: Callable[[int | None], list[str]]
    after_clock: bool = False


@dataclass(frozen=True)
class DemoPlan:
    """What a SLAM pipeline needs in ``demo --processes`` (its record's ``demo_processes``
    entry, ``plan(ctx: DemoContext) -> DemoPlan``): its processes (in start order), the
    components the demo waits for on the bus before vehicle t = 0 (its devices and stages, by
    liveliness), its stage's status component and its name in the summary. The last process is
    its stage's, stopped once what the others (stopped with the gateway) put has reached it."""

    processes: tuple[DemoProcess, ...]
    alive: frozenset[str]
    component: str
    display: str


@dataclass(frozen=True)
class InProcessContext:
    """What a pipeline's stage in the in-process demo is made from: the scenario (``scenario``:
    its file, ``scn``: loaded), the gateway configuration the sim wrote (``gw_cfg``: its devices
    and vehicle), vehicle time 0 on the stamps' clock (``epoch_ns``, the sim's ``[clock]``), the
    demo's session and ``on_publish``, the hook every output of the stage goes to (the demo's
    SLAM track and Rerun recording)."""

    scenario: Path
    scn: Scenario
    gw_cfg: GatewayConfig
    epoch_ns: int
    session: zenoh.Session
    on_publish: OnPublish


@dataclass(frozen=True)
class InProcessPlan:
    """What a SLAM pipeline runs in the in-process demo (its record's ``demo_inprocess`` entry,
    ``plan(ctx: InProcessContext) -> InProcessPlan``): its stage (not started; the demo feeds it
    the gateway's messages and the fusion's odometry), its name in the summary and the stages
    in front of it by summary key (fed the gateway's messages, started before it and stopped,
    flushed, before it; their counters go into ``summary.json`` under their key)."""

    stage: Stage
    display: str
    before: dict[str, Stage] = field(default_factory=dict)


class _TruthTail:
    """Follows the simulator's truth log (JSON lines), feeding each sample to ``on_sample`` once,
    in order, whichever thread polls (the in-process demo polls from its main loop and from the
    INS reader that starts dead reckoning)."""

    def __init__(self, path: Path, on_sample: Callable[[TruthSample], object]) -> None:
        self.path = path
        self.on_sample = on_sample
        self._lock = threading.Lock()
        self._pos = 0
        self._partial = ""
        self.t = 0.0  #: vehicle time of the newest sample, s (the sim's own clock)

    def poll(self) -> None:
        """Feed every complete line written since the last poll."""
        if not self.path.is_file():
            return
        with self._lock:  # two pollers must not read one stretch twice or feed it out of order
            with open(self.path) as fh:
                fh.seek(self._pos)
                data = fh.read()
                self._pos = fh.tell()
            text = self._partial + data
            lines = text.split("\n")
            self._partial = lines.pop()
            for line in lines:
                if line.strip():
                    sample = json.loads(line)
                    self.t = max(self.t, float(sample["t"]))
                    self.on_sample(sample)


def _load_sim_config(sim_dir: Path) -> GatewayConfig:
    """The gateway configuration ``auvgw sim`` wrote, with its vehicle-paced clock."""
    try:
        gw_cfg = load_gateway_config(sim_dir / "gateway.toml")
    except ConfigError as exc:
        raise UserError(str(exc)) from exc
    _sim_epoch_ns(gw_cfg)  # a UserError without one
    return gw_cfg


def _sim_epoch_ns(gw_cfg: GatewayConfig) -> int:
    """The gateway's vehicle time 0 (ns on the stamps' clock), from ``auvgw sim``."""
    if gw_cfg.clock.epoch_ns is None:
        raise UserError(f"{gw_cfg.source}: no [clock] epoch_ns (vehicle time 0) from auvgw sim")
    return gw_cfg.clock.epoch_ns


#: host seconds of delivery jitter between the sensors' paths that the demo's fusion absorbs:
#: its fixed lag (``FusionConfig.max_latency_s``, vehicle s) is this times the speed, at least the
#: filter's default 0.2 s. At 10x on a loaded host DVL ensembles reached the fusion more than the
#: default 0.2 vehicle s (20 host ms) after the INS sample of their time: 7 % of them were
#: dropped as late (``aiding_late``) in a survey run at load 10-20, 2-5 a run on a quiet host.
FUSION_JITTER_HOST_S = 0.1


def _fusion_config(
    vehicle: str, position_m: tuple[float, float, float], ins_noise: dict[str, float] | None = None,
    speed: float = 1.0,
) -> FusionStageConfig:
    """The demo's fusion stage: dead reckoning starts from the true position (what a GNSS fix at
    the surface gives a real vehicle). The INS heading error model follows the emulated INS
    (``ins_noise``: the scenario's ``devices.ins.noise``): with ``heading_bias_deg`` > 0 its
    heading error is Gauss-Markov (RMS ``heading_bias_deg``, correlation time
    ``heading_bias_tau_s``, default 300 s), and so is the filter's (``heading_error_sigma_deg``,
    ``heading_error_tau_s``); otherwise it is white (``heading_deg``, default 0.3 deg), tau = 0.
    ``speed``: the run's x real time, which scales the fixed lag (:data:`FUSION_JITTER_HOST_S`)."""

    from auvgw.fusion.config import FusionConfig, InitialState
    from auvgw.sim_devices.ins import DEFAULT_NOISE, HEADING_ERROR
    from auvgw.stages.fusion import FusionStageConfig

    noise = ins_noise or {}
    bias = float(noise.get("heading_bias_deg", 0.0))
    if bias > 0:
        sigma = bias
        tau = float(noise.get("heading_bias_tau_s", HEADING_ERROR["heading_bias_tau_s"]))
    else:
        sigma, tau = float(noise.get("heading_deg", DEFAULT_NOISE["heading_deg"])), 0.0
    filt = FusionConfig(
        initial=InitialState(position_m=position_m, position_sigma_m=(0.5, 0.5, 0.5)),
        heading_error_sigma_deg=sigma,
        heading_error_tau_s=tau,
        pitch_error_tau_s=0.0,
        max_latency_s=max(0.2, FUSION_JITTER_HOST_S * speed),
    )
    # the clocks warm up for 2 s: the first frames after the ports open arrive late (a backlog,
    # more on a loaded host) and cost motion otherwise (0.65 m in a 30 s harbour run)
    return FusionStageConfig(vehicle=vehicle, ins_device="ins", dvl_device="dvl", filter=filt,
                             clock_warmup_s=2.0)  # fmt: skip


def _gateway_toml(sim_dir: Path, out: Path, listen: str, hub: str) -> Path:
    """The sim's gateway.toml joined to this demo's bus (listen on its own port, connect to the
    hub); everything else, the [clock] included, as the sim wrote it."""
    import tomllib

    from auvgw.config.gateway import parse_gateway_config
    from auvgw.sim_devices.runner import gateway_toml

    data = tomllib.loads((sim_dir / "gateway.toml").read_text())
    data["bus"] = {"mode": "peer", "listen": [listen], "connect": [hub]}
    path = out / "gateway.toml"
    try:
        parse_gateway_config(data, source=str(path))
    except ConfigError as exc:
        raise UserError(str(exc)) from exc
    path.write_text(gateway_toml(data, f"auvgw demo --processes: {sim_dir / 'gateway.toml'} "
                                       "on the demo's bus"))  # fmt: skip
    return path


def _wait_for(path: Path, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.is_file():
        if proc.poll() is not None:
            raise UserError(f"the emulated vehicle stopped early (exit {proc.returncode})")
        if time.monotonic() > deadline:
            raise UserError(f"the emulated vehicle wrote no {path.name} in {timeout_s:.0f} s")
        time.sleep(0.1)


#: the sim's ``--start-when`` file in its folder: the demo writes it once every part is up
START_FILE = "go"
#: host s from the sim's gateway.toml to vehicle time 0 at the latest (it comes as soon as every
#: part is up: a quiet host waits 1-3 s; a loaded one took more than 10 s, its first magnetometer
#: samples lost)
START_DELAY_S = 60.0
#: the same with ``--pace free``, where it is a fixed wait (the gateway maps host time to it)
FREE_START_DELAY_S = 10.0
#: host s from every part's readiness to vehicle time 0 (the sim's device processes take it)
START_LEAD_S = 0.5


def _start_vehicle(sim_dir: Path, speed: float) -> float:
    """Every part that should see the whole run is up: vehicle time 0 :data:`START_LEAD_S` host
    s from now (written to the sim's ``--start-when`` file, ``sim_dir/go``), unless the sim's
    clock (``sim_dir/clock``, elastic or lock-step) has already started on its
    ``--start-delay``. Returns the vehicle time of the readiness, s (< 0: before time 0)."""
    from auvgw.ground.simclock import ClockFileReader

    now = time.monotonic()
    reader = ClockFileReader(sim_dir / "clock")
    try:
        st = reader.state()
    finally:
        reader.close()
    if st is not None and st[1] <= now:  # its anchor's host instant passed: the clock runs
        return st.vehicle_s(now)
    t0 = now + START_LEAD_S
    go = sim_dir / START_FILE
    tmp = go.with_name(go.name + ".new")
    tmp.write_text(f"{t0!r}\n")
    os.replace(tmp, go)  # whole: the sim reads it once it exists
    return (now - t0) * speed


#: the emulated vehicle's name (the <v> key segment)
VEHICLE = "auv1"
#: a stage's in-process publication hook: (key, payload, stamp ns)
OnPublish = Callable[[str, bytes, int], object]


def _sim_argv(scenario: Path, speed: float, duration: float, sim_dir: Path,
              pace: str = "elastic") -> list[str]:  # fmt: skip
    return ["sim", "--scenario", str(scenario), "--speed", str(speed), "--duration",
            str(duration), "--out", str(sim_dir), "--vehicle", VEHICLE, "--hold",
            "--pace", pace]  # fmt: skip


def _sim_done(sim: subprocess.Popen[bytes], sim_dir: Path) -> bool:
    """The emulated run is over: the sim wrote ``finished`` (ports still open) or exited."""
    return sim.poll() is not None or (sim_dir / "finished").exists()


def _streamed_frames(gw_cfg: GatewayConfig, devices: dict[str, dict[str, int]]) -> int:
    """Frames the gateway has read from the devices that speak on their own: a polled device
    (a host driver, the MSIS head) answers every poll for as long as its port stays open, so its
    frames never go quiet; counted, they held the drain at its limit while the gateway kept
    stamping rows past the end of the run (issue 33: 20 s of vehicle time at ``--speed 2``)."""
    from auvgw.drivers import registry

    polled = {k.format for k in registry.DEVICES if k.host_driver}
    return sum(
        int(d.get("frames", 0))
        for name, d in devices.items()
        if name not in gw_cfg.devices or gw_cfg.devices[name].format not in polled
    )


def _wait_drained(frames: Callable[[], int], quiet_s: float = 0.5, limit_s: float = 10.0) -> None:
    """Wait until a count has not moved for ``quiet_s``, at most ``limit_s``: the gateway's
    frames (the last read from the held-open ports) or a stage's received messages."""
    last, since, end = frames(), time.monotonic(), time.monotonic() + limit_s
    while time.monotonic() < end and time.monotonic() - since < quiet_s:
        time.sleep(0.05)
        n = frames()
        if n != last:
            last, since = n, time.monotonic()


class _Beacons(TypedDict, total=False):
    landmarks: list[list[float]]  # the magnetic beacons, [x, y] m
    acoustic_beacon: list[float]  # [x, y] m


def _true_beacons(scn: Scenario) -> _Beacons:
    """The scenario's magnetic beacons (``landmarks``, [x, y] m) and acoustic beacon
    (``acoustic_beacon``) for ``truth/map`` (nothing without beacons)."""
    out: _Beacons = {}
    if scn.magnetic_beacons:
        out["landmarks"] = [[b.x, b.y] for b in scn.magnetic_beacons]
    if scn.acoustic_beacon is not None:
        out["acoustic_beacon"] = [scn.acoustic_beacon.x, scn.acoustic_beacon.y]
    return out
