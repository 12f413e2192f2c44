"""Run a scenario's emulated vehicle: world, ground truth, one clock, every enabled device.

:class:`Runner` builds the :class:`~auvgw.sim_devices.world.World` and the ground-truth
trajectory of a :class:`~auvgw.config.scenario.Scenario`, one
:class:`~auvgw.sim_devices.clock.SimClock` (real time x ``speed``), and one emulator per enabled
device (:data:`FACTORIES`), each on its own virtual port with a stable symlink in
``<out_dir>/ports/``. It publishes nothing itself: ground truth goes to an ``on_truth`` callback
and/or a truth log (``.jsonl``: one JSON object per sample with the fields of
:data:`~auvgw.sim_devices.vehicle.TRUTH_FIELDS`; ``.npz``: one array per field), at
``truth_rate_hz`` on the vehicle clock; a ``.jsonl`` line is on disk as soon as its sample
is taken (line-buffered), so a reader can tail the log live.

Faults come from each device's ``faults`` in the scenario and can be switched at run time:

* :meth:`Runner.set_faults` (``runner.set_faults("ins", corrupt_p=0.1)``), :meth:`unplug_for`
  and :meth:`stall_for` (a window starting now);
* a control file (:meth:`Runner.watch_control`, ``auvgw sim`` watches ``<out>/faults.json``):
  a JSON object ``{"<device>": {<FaultSettings fields>}}``; whenever the file changes, each
  device's faults become the scenario's plus the file's entries for it (a device left out
  returns to the scenario's). Windows (``unplug``, ``stall``, ...) are in vehicle seconds.

Devices: every emulator of the device registry (:func:`auvgw.drivers.registry.emulators`, in
its order: ``ins``, ``dvl``, ``msis``, ``multibeam``, ``magnetometer``, ``acoustic``), each
made by its registered factory. A device whose module is not installed is listed in
:attr:`Runner.unavailable` with the reason.

One Python process runs its threads on about one core (the GIL). :class:`DeviceProcesses` runs
each device in its own process instead (each a :class:`Runner` of one device, built from the
same scenario file, so the same world and truth), all on one clock: vehicle time 0 is the same
host ``time.monotonic()`` instant everywhere (:meth:`Runner.start` ``start_at``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import resource
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Collection, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import DeviceSettings, FaultSettings, Scenario
from auvgw.drivers import registry
from auvgw.ground.closing import Closing
from auvgw.ground.errors import format_validation_error
from auvgw.ground.procs import stop_process
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.emulator import (
    DEFAULT_EPOCH,
    Emulator,
    Endpoint,
    SimContext,
)
from auvgw.sim_devices.vehicle import TRUTH_FIELDS, Truth, TruthSample, simulate
from auvgw.sim_devices.world import World

__all__ = [
    "DEVICE_ORDER",
    "FACTORIES",
    "DeviceProcesses",
    "DeviceUnavailable",
    "RunOptions",
    "Runner",
    "child_main",
    "gateway_clock",
    "gateway_config",
    "gateway_toml",
    "write_gateway_config",
]

log = logging.getLogger(__name__)

#: devices in the order they are built and listed (the scenario's ``devices`` keys, from the
#: device registry)
DEVICE_ORDER = tuple(em.key for em in registry.emulators())


class DeviceUnavailable(RuntimeError):
    """A device of the scenario whose emulator module is not installed."""


def _factory(em: registry.Emulator) -> Callable[[SimContext, DeviceSettings], Emulator]:
    """The registered factory of an emulator, imported when first called (a module that is not
    installed makes the device unavailable, not the simulator)."""

    def make(ctx: SimContext, settings: DeviceSettings) -> Emulator:
        module = em.factory.partition(":")[0]
        try:
            factory = registry.load(em.factory)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            raise DeviceUnavailable(f"no {em.key} emulator ({em.factory})") from exc
        except AttributeError as exc:
            raise DeviceUnavailable(f"no {em.key} emulator ({em.factory})") from exc
        emulator: Emulator = factory(ctx, settings)
        return emulator

    return make


#: device key -> factory(ctx, settings) -> emulator (raises DeviceUnavailable), from the registry
FACTORIES: dict[str, Callable[[SimContext, DeviceSettings], Emulator]] = {
    em.key: _factory(em) for em in registry.emulators()
}


# -- gateway configuration as TOML ---------------------------------------------------------------


def _toml_key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"TOML cannot hold {v}")
        return repr(v)
    if isinstance(v, str | Path):
        return json.dumps(str(v))
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def gateway_toml(data: dict[str, Any], header: str = "") -> str:
    """TOML text of a gateway configuration mapping: top-level keys, then one table per
    second-level mapping (``[bus]``, ``[devices.<name>]``), deeper mappings inline."""
    lines = [f"# {h}" if h else "#" for h in header.splitlines()]
    lines += [
        f"{_toml_key(k)} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)
    ]
    for k, v in data.items():
        if not isinstance(v, dict):
            continue
        if all(isinstance(x, dict) for x in v.values()) and v:
            for name, table in v.items():
                lines += ["", f"[{_toml_key(k)}.{_toml_key(name)}]"]
                lines += [f"{_toml_key(a)} = {_toml_value(b)}" for a, b in table.items()]
        else:
            lines += ["", f"[{_toml_key(k)}]"]
            lines += [f"{_toml_key(a)} = {_toml_value(b)}" for a, b in v.items()]
    return "\n".join(lines) + "\n"


def _process_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def gateway_clock(speed: float, start_at: float,
                  sim_clock: Path | None = None) -> dict[str, Any] | None:  # fmt: skip
    """The gateway's ``[clock]`` section for a run at ``speed`` x real time whose vehicle time 0
    is the host ``time.monotonic()`` instant ``start_at``: ``time_scale = speed`` and
    ``epoch_ns``, that instant on the Unix clock (ns), so the gateway stamps vehicle-paced
    receive times and ``(t_recv_ns - epoch_ns) / 1e9`` is vehicle seconds (docs/gateway.md).
    None at speed 0 (as fast as possible: no fixed mapping to host time). ``sim_clock``: a
    lock-step run's clock file (:mod:`auvgw.ground.simclock`), which the gateway then reads.
    """
    if not speed > 0:
        return None
    epoch_ns = time.time_ns() + round((start_at - time.monotonic()) * 1e9)
    clock: dict[str, Any] = {"time_scale": float(speed), "epoch_ns": epoch_ns}
    if sim_clock is not None:
        clock["sim_clock"] = str(sim_clock)
    return clock


def gateway_config(
    endpoints: Iterable[Endpoint], vehicle: str = "auv1", clock: dict[str, Any] | None = None
) -> dict[str, Any]:
    """A gateway configuration mapping (``config/gateway.py``'s model) for ``endpoints``, with
    the ``[clock]`` section ``clock`` (:func:`gateway_clock`) if given, and a ``[bus]`` section
    listening on the one-machine default endpoint, where every other command connects by
    default (docs/bus.md)."""
    from auvgw.config.bus import default_endpoint

    data: dict[str, Any] = {
        "vehicle": vehicle,
        "bus": {"mode": "peer", "listen": [default_endpoint()]},
        "devices": {ep.name: ep.gateway_device() for ep in endpoints},
    }
    if clock is not None:
        data["clock"] = clock
    return data


def write_gateway_config(
    path: str | Path,
    endpoints: Iterable[Endpoint],
    vehicle: str,
    scenario_name: str,
    port_dir: Path,
    clock: dict[str, Any] | None = None,
) -> Path:
    """Validate the configuration with the gateway's own model, then write it as TOML."""
    from auvgw.config.gateway import parse_gateway_config

    data = gateway_config(endpoints, vehicle, clock)
    parse_gateway_config(data, source=str(path))  # raises ConfigError naming the field
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = (
        f"auvgw gateway configuration for the emulated vehicle of scenario '{scenario_name}'\n"
        f"(written by auvgw sim; ports are stable symlinks in {port_dir})"
    )
    tmp = path.with_name(path.name + ".new")  # put in place whole: a reader never sees half
    tmp.write_text(gateway_toml(data, header))
    os.replace(tmp, path)
    return path


# -- the runner ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """How a scenario's emulated vehicle runs, for a :class:`Runner` or :class:`DeviceProcesses`.

    ``out_dir``: port symlinks go to ``out_dir/ports``. ``speed``: vehicle seconds per real
    second (0: as fast as possible). ``devices``: build only these (default: every enabled
    device). ``epoch``: UTC POSIX time of vehicle time 0 (device clocks that carry a date).
    ``udp_host``: the address UDP devices send from and to. ``on_truth(sample)``: called with
    the ground truth at ``truth_rate_hz`` (clock thread; keep it short). ``truth_log``: a
    ``.jsonl`` or ``.npz`` path. ``elastic_lag``: elastic pacing (vehicle s, speed > 0; 0:
    free-running): vehicle time runs at most that far past the earliest tick not dispatched yet
    (:meth:`SimClock.elastic`) and is shared through the clock file ``out_dir/clock``
    (:mod:`auvgw.ground.simclock`), which the gateway configuration then names. Checked when
    made (a ValueError names the bad value).
    """

    out_dir: Path
    speed: float = 1.0
    devices: Collection[str] | None = None
    epoch: float = DEFAULT_EPOCH
    udp_host: str = "127.0.0.1"
    truth_rate_hz: float = 10.0
    on_truth: Callable[[TruthSample], object] | None = None
    truth_log: Path | None = None
    elastic_lag: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "out_dir", Path(self.out_dir))
        if not (0 <= self.elastic_lag <= 60):
            raise ValueError(f"elastic_lag must be 0 to 60 vehicle s, got {self.elastic_lag}")
        if self.elastic_lag and not self.speed > 0:
            raise ValueError("elastic pacing needs a real-time clock: speed > 0")
        if self.devices is not None:
            object.__setattr__(self, "devices", tuple(self.devices))
        if self.truth_log is not None:
            object.__setattr__(self, "truth_log", Path(self.truth_log))
        unknown = sorted(set(self.devices or ()) - set(DEVICE_ORDER))
        if unknown:
            raise ValueError(
                f"unknown device(s) {', '.join(unknown)}; known: {', '.join(DEVICE_ORDER)}"
            )
        if self.truth_log is not None and self.truth_log.suffix not in (".jsonl", ".npz"):
            raise ValueError(f"truth log {self.truth_log}: use a .jsonl or .npz file name")
        if not self.truth_rate_hz > 0:
            raise ValueError(f"truth_rate_hz must be > 0, got {self.truth_rate_hz}")


class Runner(Closing):
    """World + truth + clock + emulators of one scenario (see the module docstring), run as
    ``options`` (:class:`RunOptions`) say."""

    def __init__(self, scenario: Scenario, options: RunOptions) -> None:
        self.options = options
        self.scenario = scenario
        self.world = World.from_scenario(scenario)
        self.truth: Truth | ClosedLoopTruth = (
            ClosedLoopTruth(scenario, self.world)
            if scenario.vehicle.mode == "dynamics"
            else simulate(scenario, self.world)
        )
        self.clock = SimClock(options.speed)
        self.ctx = SimContext(
            scenario, self.world, self.truth, self.clock, options.out_dir / "ports",
            options.epoch, options.udp_host,
        )  # fmt: skip
        self.emulators: dict[str, Emulator] = {}
        self.unavailable: dict[str, str] = {}
        self._base_faults: dict[str, FaultSettings] = {}
        self._truth_rows: list[list[float]] = []
        self._truth_file: Any = None
        self._truth_task: Any = None
        self._watch_stop = threading.Event()
        self._watch_thread: threading.Thread | None = None
        self._clock_thread: threading.Thread | None = None
        self._started = False
        self._closed = False
        self._stopped_at: float | None = None
        self._cpu0 = 0.0
        self._cpu_end: float | None = None
        self.until: float | None = None
        #: the gateway's [clock] epoch_ns (vehicle time 0 on the stamp clock) once known
        self.clock_epoch_ns: int | None = None
        self._clock_writer: Any = None
        try:
            for kind in DEVICE_ORDER:
                settings: DeviceSettings = getattr(scenario.devices, kind)
                if options.devices is not None and kind not in options.devices:
                    continue
                if not settings.enabled:
                    continue
                try:
                    em = FACTORIES[kind](self.ctx, settings)
                except DeviceUnavailable as exc:
                    self.unavailable[kind] = str(exc)
                    continue
                self.emulators[kind] = em
                self._base_faults[kind] = settings.faults
        except BaseException:
            self.close()
            raise

    # -- information ------------------------------------------------------------------------------
    @property
    def route_duration(self) -> float:
        """Vehicle seconds until the route ends."""
        return self.truth.duration

    def endpoints(self) -> list[Endpoint]:
        """Every port a host opens, device by device."""
        return [ep for em in self.emulators.values() for ep in em.endpoints()]

    def gateway_config(
        self, vehicle: str = "auv1", start_at: float | None = None
    ) -> dict[str, Any]:
        """A gateway configuration (``config/gateway.py``'s model as a mapping) pointing at
        every emulated port (stable symlinks, so the gateway finds replugged ports). With
        ``start_at`` (the host ``time.monotonic()`` instant that will be passed to
        :meth:`start`) it carries the ``[clock]`` section of vehicle-paced receive times
        (:func:`gateway_clock`)."""
        clock = None if start_at is None else gateway_clock(self.clock.speed, start_at)
        return gateway_config(self.endpoints(), vehicle, clock)

    def write_gateway_config(
        self, path: str | Path, vehicle: str = "auv1", start_at: float | None = None,
        sim_clock: Path | None = None,
    ) -> Path:
        """Validate :meth:`gateway_config` with the gateway's own model and write it as TOML
        (``sim_clock``: see :func:`gateway_clock`; an elastic run names its own clock file)."""
        if sim_clock is None and self.options.elastic_lag:
            sim_clock = self.clock_file
        clock = None if start_at is None else gateway_clock(self.clock.speed, start_at,
                                                            sim_clock)  # fmt: skip
        if clock is not None:
            self.clock_epoch_ns = clock["epoch_ns"]
        return write_gateway_config(
            path, self.endpoints(), vehicle, self.scenario.name, self.ctx.port_dir, clock
        )

    @property
    def clock_file(self) -> Path:
        """Where an elastic run shares its clock (:mod:`auvgw.ground.simclock`)."""
        return self.options.out_dir / "clock"

    def _start_elastic(self, start_at: float | None) -> None:
        """Elastic pacing on this runner's clock, its anchors published to :attr:`clock_file`
        (vehicle time 0 at ``start_at``, the gateway's ``epoch_ns`` on the stamp clock)."""
        from auvgw.ground.simclock import ClockFileWriter

        t0 = time.monotonic() if start_at is None else start_at
        if self.clock_epoch_ns is None:
            self.clock_epoch_ns = time.time_ns() + round((t0 - time.monotonic()) * 1e9)
        epoch = self.clock_epoch_ns
        writer = self._clock_writer = ClockFileWriter(self.clock_file)

        def publish(t: float, host: float, speed: float, limit: float) -> None:
            writer.publish(t, host, speed, limit, epoch)

        self.clock.elastic(self.options.elastic_lag, on_anchor=publish)
        writer.publish(0.0, t0, self.clock.speed, self.clock.limit, epoch)

    def emulator(self, name: str) -> Emulator:
        try:
            return self.emulators[name]
        except KeyError:
            raise ValueError(
                f"no running device {name!r}; running: {', '.join(self.emulators) or 'none'}"
            ) from None

    @property
    def vehicle_time(self) -> float:
        """Vehicle time now, or where the run ended (its duration, or where it was stopped)."""
        if self._stopped_at is not None:
            return self._stopped_at
        now = self.clock.now()
        return min(now, self.until) if self.until is not None else now

    def stats(self) -> dict[str, Any]:
        """Per-device counters, the clock's lag figures and the CPU seconds this process
        used since :meth:`start` (user + system, every thread)."""
        cpu = _process_cpu_s() - self._cpu0 if self._started else 0.0
        if self._cpu_end is not None:
            cpu = self._cpu_end - self._cpu0
        return {
            "vehicle_time": self.vehicle_time,
            "process_cpu_s": cpu,
            "clock_cpu_s": self.clock.thread_cpu_s,
            "late_ticks": self.clock.late_ticks,
            "max_lag_s": self.clock.max_lag,
            "elastic_lag_s": self.clock.elastic_lag,
            "holds": self.clock.holds,
            "held_s": self.clock.held_s,
            "hold_timeouts": self.clock.hold_timeouts,
            "devices": {k: em.stats() for k, em in self.emulators.items()},
        }

    # -- faults at run time -----------------------------------------------------------------------
    def set_faults(self, device: str, **changes: Any) -> FaultSettings:
        """Change fault knobs of one device now (validated like the scenario file)."""
        return self.emulator(device).set_faults(**changes)

    def _window_now(self, device: str, key: str, seconds: float) -> FaultSettings:
        em = self.emulator(device)
        now = self.clock.now()
        current = list(getattr(em.faults.settings, key))
        return em.set_faults(None, **{key: [*current, (now, now + float(seconds))]})

    def unplug_for(self, device: str, seconds: float) -> FaultSettings:
        """Unplug the device's ports from now for ``seconds`` vehicle seconds."""
        return self._window_now(device, "unplug", seconds)

    def stall_for(self, device: str, seconds: float) -> FaultSettings:
        """Silence the device from now for ``seconds`` vehicle seconds."""
        return self._window_now(device, "stall", seconds)

    def apply_control(
        self, control: dict[str, Any], only_mine: bool = False
    ) -> dict[str, FaultSettings]:
        """Each device's faults := the scenario's + ``control[device]`` (all validated first;
        a ValueError names the device and the field). ``only_mine``: entries for devices this
        runner does not run are skipped (one runner per process) if they name a device."""
        from pydantic import ValidationError

        if not isinstance(control, dict):
            raise ValueError("fault control: expected a JSON object {device: {field: value}}")
        new: dict[str, FaultSettings] = {}
        for name in control:
            if only_mine and name in DEVICE_ORDER:
                continue
            if name not in self.emulators:
                raise ValueError(
                    f"fault control: no running device {name!r}; running: "
                    f"{', '.join(self.emulators)}"
                )
        for name, base in self._base_faults.items():
            changes = control.get(name, {})
            if not isinstance(changes, dict):
                raise ValueError(f"fault control: {name}: expected an object of fault settings")
            try:
                new[name] = FaultSettings.model_validate({**base.model_dump(), **changes})
            except ValidationError as exc:
                lines = format_validation_error(exc, "fault control", rename=f"{name}.{{}}".format)
                raise ValueError(lines.split("\n")[0]) from None
        for name, fs in new.items():
            self.emulators[name].set_faults(fs)
        return new

    def watch_control(
        self, path: str | Path, interval_s: float = 0.5, only_mine: bool = False
    ) -> None:
        """Apply the control file at ``path`` whenever it changes (polled every ``interval_s``
        real seconds; a bad file is logged and ignored; ``only_mine``: see
        :meth:`apply_control`)."""
        path = Path(path)

        def loop() -> None:
            seen: tuple[int, int] | None = None
            while not self._watch_stop.wait(interval_s):
                try:
                    st = path.stat()
                except FileNotFoundError:
                    if seen is not None:
                        seen = None
                        self.apply_control({}, only_mine)
                        log.info("fault control %s removed: scenario faults restored", path)
                    continue
                key = (st.st_mtime_ns, st.st_size)
                if key == seen:
                    continue
                seen = key
                try:
                    self.apply_control(json.loads(path.read_text() or "{}"), only_mine)
                    log.warning("fault control %s applied", path)
                except (OSError, ValueError) as exc:
                    log.error("fault control %s ignored: %s", path, exc)

        self._watch_thread = threading.Thread(target=loop, name="sim-faults", daemon=True)
        self._watch_thread.start()

    # -- truth ------------------------------------------------------------------------------------
    def _truth_tick(self, t: float) -> None:
        s = self.truth.at(t)
        if self.options.on_truth is not None:
            try:
                self.options.on_truth(s)
            except Exception:
                log.exception("on_truth callback failed")
        if self.options.truth_log is None:
            return
        if self._truth_file is not None:
            rec = {f: getattr(s, f) for f in TRUTH_FIELDS}
            self._truth_file.write(json.dumps(rec, separators=(",", ":")) + "\n")
        else:
            self._truth_rows.append([getattr(s, f) for f in TRUTH_FIELDS])

    def _finish_truth_log(self) -> None:
        if self._truth_file is not None:
            self._truth_file.close()
            self._truth_file = None
            return
        path = self.options.truth_log
        if path is not None and path.suffix == ".npz" and self._started:
            rows = np.asarray(self._truth_rows, float).reshape(-1, len(TRUTH_FIELDS))
            columns = {f: rows[:, i] for i, f in enumerate(TRUTH_FIELDS)}
            np.savez(path, allow_pickle=False, **columns)

    # -- run --------------------------------------------------------------------------------------
    def start(self, duration: float | None = None, start_at: float | None = None) -> None:
        """Start every emulator at vehicle time 0 and run the clock in a thread until
        ``duration`` vehicle seconds (default: the end of the route). ``start_at``: the host
        ``time.monotonic()`` instant of vehicle time 0 (runners in several processes share
        one clock that way; default: now)."""
        if self._started:
            raise RuntimeError("the runner was already started")
        self._started = True
        self.until = float(duration) if duration is not None else self.route_duration
        o = self.options
        if o.truth_log is not None:
            o.truth_log.parent.mkdir(parents=True, exist_ok=True)
            if o.truth_log.suffix == ".jsonl":
                # a line on disk per sample: readers tail it live (the in-process demo starts
                # dead reckoning from it, in the INS reader; block-buffered, it trailed the
                # vehicle by up to 8 KiB of lines, 2.3 s at 10 Hz)
                self._truth_file = o.truth_log.open("w", encoding="utf-8", buffering=1)
        if o.on_truth is not None or o.truth_log is not None:
            self._truth_task = self.clock.every(
                1.0 / o.truth_rate_hz, self._truth_tick, start=0.0, name="truth"
            )
        self._cpu0 = _process_cpu_s()
        if o.elastic_lag and self.clock.elastic_lag == 0 and not self.clock.following:
            self._start_elastic(start_at)
        for em in self.emulators.values():
            em.start(0.0)
        self.clock.start(at=start_at)
        self._clock_thread = self.clock.start_thread(until=self.until)

    @property
    def running(self) -> bool:
        th = self._clock_thread
        return th is not None and th.is_alive()

    @property
    def ended(self) -> bool:
        """The clock reached the run's end (not stopped before it)."""
        return self._started and self._stopped_at is None and not self.running

    def wait(self, timeout: float | None = None) -> bool:
        """Wait (real seconds) for the run to reach its end; True if it did."""
        th = self._clock_thread
        if th is None:
            return False
        th.join(timeout)
        return not th.is_alive()

    def stop(self) -> None:
        """Stop the clock and every emulator (ports stay open, so readers can drain them)."""
        if self._started and self._stopped_at is None:
            self._stopped_at = self.vehicle_time
            self._cpu_end = _process_cpu_s()
        for em in self.emulators.values():
            em.stop()
        if self._truth_task is not None:
            self._truth_task.cancel()
        self.clock.close()
        if self._truth_file is not None:  # a reader of a held run sees its end (issue 33)
            self._truth_file.flush()

    def flush(self, drain_timeout: float = 5.0) -> None:
        """After :meth:`stop`: send the held-back bad frames and wait (real seconds) until the
        ports have delivered everything queued."""
        for em in self.emulators.values():
            em.flush()
        for em in self.emulators.values():
            for ch in em.channels:
                port = getattr(ch.port, "port", ch.port)  # an SLCAN adapter's pty
                if hasattr(port, "wait_drained"):
                    port.wait_drained(drain_timeout)

    def hold(self) -> float:
        """The run is over: :meth:`stop`, :meth:`flush`, and keep the ports open (the devices
        silent) until :meth:`close`; the vehicle time reached."""
        self.stop()
        self.flush()
        return self.vehicle_time

    def close(self) -> None:
        """Stop everything, release the ports and write the truth log."""
        if self._closed:
            return
        self._closed = True
        self._watch_stop.set()
        if self._watch_thread is not None:
            self._watch_thread.join(2.0)
        self.stop()
        for em in self.emulators.values():
            with contextlib.suppress(Exception):
                em.close()
        self._finish_truth_log()
        if self._clock_writer is not None:
            self._clock_writer.close()



# -- one process per device ----------------------------------------------------------------------

#: real seconds a device process may take to catch up with the run's end after "finish"
_FINISH_TIMEOUT_S = 60.0
_CHILD = "from auvgw.sim_devices.runner import child_main; child_main()"
#: an elastic run's dispatch board (:class:`auvgw.ground.simclock.DispatchBoard`), beside the
#: clock file
_BOARD = "clock.dispatch"
#: host s between the parent's reads of the dispatch board (elastic, one process per device)
_BOARD_POLL_S = 0.002


def _endpoint_dict(ep: Endpoint) -> dict[str, Any]:
    return dataclasses.asdict(ep)


def _follow_parent(runner: Runner, slot: int) -> None:
    """An elastic run's device process: vehicle time from the parent's clock file, this
    process's dispatch progress into its ``slot`` of the dispatch board beside it."""
    from auvgw.ground.simclock import ClockFileReader, DispatchBoard

    board = DispatchBoard(runner.clock_file.with_name(_BOARD))
    reader = ClockFileReader(runner.clock_file)
    runner.clock.follow(reader.state, lambda t: board.report(slot, t))


def child_main(argv: list[str] | None = None) -> None:
    """One device's process of :class:`DeviceProcesses` (stdin/stdout JSON lines protocol):
    build, print ``{"endpoints", "unavailable"}`` (or ``{"error"}``), wait for ``start T0
    UNTIL`` (T0 a host monotonic instant) or ``stop``, run until UNTIL (ports open until
    ``stop``/EOF) or ``stop``/EOF, print ``{"stats"}`` and exit. SIGINT is ignored (the
    parent stops its children)."""
    import signal

    from auvgw.config.scenario import ScenarioError, load_scenario

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    args = json.loads((argv or sys.argv[1:])[0])
    try:
        scn = load_scenario(args["scenario"])
        options = RunOptions(
            out_dir=args["out_dir"], speed=args["speed"], devices=[args["device"]],
            epoch=args["epoch"], udp_host=args["udp_host"],
        )  # fmt: skip
        runner = Runner(scn, options)
        if args.get("slot") is not None:  # elastic: the parent's clock, this device's slot
            _follow_parent(runner, int(args["slot"]))
    except (ScenarioError, ValueError, OSError) as exc:
        print(json.dumps({"error": str(exc)}), flush=True)
        return
    try:
        eps = [_endpoint_dict(ep) for ep in runner.endpoints()]
        print(json.dumps({"endpoints": eps, "unavailable": runner.unavailable}), flush=True)
        cmd = sys.stdin.readline().split()
        if cmd and cmd[0] == "start":
            runner.start(duration=float(cmd[2]), start_at=float(cmd[1]))
            if args.get("control"):
                runner.watch_control(args["control"], only_mine=True)
            # the ports stay open after the run's end until the parent says stop (or goes
            # away), so readers can drain them; "finish" / "hold": the run reached its end, so
            # this device's clock (behind the parent's on a busy machine) first sends every
            # sample up to it; "hold": then the device goes silent, its ports open, and says
            # so, until the next line
            word = sys.stdin.readline().strip()
            if word in ("finish", "hold"):
                runner.wait(_FINISH_TIMEOUT_S)
            if word == "hold":
                print(json.dumps({"held": runner.hold()}), flush=True)
                sys.stdin.readline()
        runner.stop()
        print(json.dumps({"stats": runner.stats()}), flush=True)
    finally:
        runner.close()


class DeviceProcesses(Closing):
    """Every device of a scenario in its own process, on one shared clock (vehicle time 0 at
    the same host instant in every process), so a run uses every core instead of one Python
    interpreter's. The same surface as :class:`Runner` for ``auvgw sim``: :meth:`endpoints`,
    :meth:`write_gateway_config`, :meth:`start`, :attr:`running`, :meth:`stop`,
    :meth:`stats`, :meth:`close`; ground truth (callback, log) stays in this process. The
    control file is watched by every device process (each applies its own entries)."""

    def __init__(
        self,
        scenario_path: str | Path,
        options: RunOptions,
        *,
        control: str | Path | None = None,
        startup_timeout_s: float = 120.0,
    ) -> None:
        from auvgw.config.scenario import load_scenario

        if options.speed <= 0:
            raise ValueError("one process per device needs a real-time clock: speed > 0")
        self.options = options
        self.scenario_path = Path(scenario_path)
        self.scenario = load_scenario(self.scenario_path)
        if self.scenario.vehicle.mode == "dynamics":
            raise ValueError(
                "vehicle.mode 'dynamics' runs every device in one process (the closed-loop "
                "truth is integrated where the actuators are): leave out --processes"
            )
        self.control = str(control) if control is not None else None
        # ground truth here (no device): the same world and trajectory as every child builds;
        # elastic, its clock is the one that holds (on the children's dispatch board)
        self.truth_runner = Runner(self.scenario, dataclasses.replace(options, devices=()))
        devices = options.devices
        wanted = DEVICE_ORDER if devices is None else [d for d in DEVICE_ORDER if d in devices]
        self.unavailable: dict[str, str] = {}
        self._endpoints: dict[str, list[Endpoint]] = {}
        self._stats: dict[str, Any] = {}
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self._slots: dict[str, int] = {}
        self._board: Any = None
        self._poll_stop = threading.Event()
        self._poller: threading.Thread | None = None
        try:
            kinds = [k for k in wanted if getattr(self.scenario.devices, k).enabled]
            if options.elastic_lag and kinds:
                from auvgw.ground.simclock import DispatchBoard

                options.out_dir.mkdir(parents=True, exist_ok=True)
                self._board = DispatchBoard(self.truth_runner.clock_file.with_name(_BOARD),
                                            len(kinds))  # fmt: skip
                self._slots = {k: i for i, k in enumerate(kinds)}
            for kind in kinds:
                args = {"scenario": str(self.scenario_path), "out_dir": str(options.out_dir),
                        "speed": options.speed, "device": kind, "epoch": options.epoch,
                        "udp_host": options.udp_host, "control": self.control,
                        "slot": self._slots.get(kind)}  # fmt: skip
                self.procs[kind] = subprocess.Popen(
                    [sys.executable, "-c", _CHILD, json.dumps(args)],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                )
            for kind, proc in list(self.procs.items()):
                msg = self._read(proc, startup_timeout_s)
                if msg is None or "error" in msg:
                    why = "exited" if msg is None else msg["error"]
                    raise ValueError(f"device process {kind}: {why}")
                self.unavailable.update(msg["unavailable"])
                self._endpoints[kind] = [Endpoint(**d) for d in msg["endpoints"]]
                if not msg["endpoints"]:
                    self._finish(kind)
        except BaseException:
            self.close()
            raise

    @staticmethod
    def _read(proc: subprocess.Popen[str], timeout: float) -> dict[str, Any] | None:
        assert proc.stdout is not None
        box: list[str] = []
        th = threading.Thread(target=lambda: box.append(proc.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        th.start()
        th.join(timeout)
        if not box or not box[0]:
            return None
        return json.loads(box[0])

    @staticmethod
    def _send(proc: subprocess.Popen[str], line: str, last: bool = False) -> None:
        if proc.stdin is None or proc.poll() is not None:
            return
        with contextlib.suppress(OSError, ValueError):
            proc.stdin.write(line + "\n")
            proc.stdin.flush()
            if last:
                proc.stdin.close()

    def _finish(self, kind: str, timeout: float = 30.0, word: str = "stop") -> None:
        proc = self.procs.pop(kind)
        self._send(proc, word, last=True)
        msg = self._read(proc, timeout)
        if msg is not None and "stats" in msg:
            self._stats[kind] = msg["stats"]
        stop_process(proc, None, timeout)  # asked on stdin; killed if it does not exit

    # -- the Runner surface -------------------------------------------------------------------
    @property
    def route_duration(self) -> float:
        return self.truth_runner.route_duration

    @property
    def emulators(self) -> dict[str, list[Endpoint]]:
        """Device -> its endpoints (the devices run in other processes)."""
        return dict(self._endpoints)

    def endpoints(self) -> list[Endpoint]:
        return [ep for eps in self._endpoints.values() for ep in eps]

    def write_gateway_config(
        self, path: str | Path, vehicle: str = "auv1", start_at: float | None = None
    ) -> Path:
        sim_clock = self.truth_runner.clock_file if self.options.elastic_lag else None
        clock = None if start_at is None else gateway_clock(self.options.speed, start_at,
                                                            sim_clock)  # fmt: skip
        if clock is not None:
            self.truth_runner.clock_epoch_ns = clock["epoch_ns"]
        return write_gateway_config(
            path, self.endpoints(), vehicle, self.scenario.name, self.options.out_dir / "ports",
            clock,
        )

    def watch_control(self, path: str | Path, interval_s: float = 0.5) -> None:
        """The device processes watch the control file given at construction."""
        if self.control is None or Path(path) != Path(self.control):
            raise ValueError("give the control file to DeviceProcesses(control=...)")

    def start(
        self, duration: float | None = None, lead_s: float = 0.5, start_at: float | None = None
    ) -> None:
        """Vehicle time 0 in ``lead_s`` real seconds (or at the host ``time.monotonic()``
        instant ``start_at``), in every process."""
        until = float(duration) if duration is not None else self.route_duration
        t0 = time.monotonic() + lead_s if start_at is None else float(start_at)
        for proc in self.procs.values():
            self._send(proc, f"start {t0!r} {until!r}")
        if self._board is not None:  # nothing dispatched yet: the holder waits for them
            self.truth_runner.clock.report(self._board.least(self._slots.values()))
        self.truth_runner.start(duration=until, start_at=t0)
        if self._board is not None:
            self._poller = threading.Thread(target=self._poll_board, name="sim-elastic",
                                            daemon=True)  # fmt: skip
            self._poller.start()

    def _poll_board(self) -> None:
        """Elastic: tell the holding clock the least pending tick of the device processes
        still running (one that exited holds nothing up), until :meth:`close`."""
        clock, board = self.truth_runner.clock, self._board
        while not self._poll_stop.wait(_BOARD_POLL_S):
            procs = dict(self.procs)  # (stop pops them from another thread)
            alive = [i for k, i in self._slots.items()
                     if k in procs and procs[k].poll() is None]  # fmt: skip
            try:
                clock.report(board.least(alive))
            except Exception:  # never leave the clock to its hold timeouts
                log.exception("elastic pacing: reading the dispatch board failed")

    @property
    def running(self) -> bool:
        """Until the shared clock reaches the end (the device processes keep their ports open
        until :meth:`stop`)."""
        return self.truth_runner.running and any(p.poll() is None for p in self.procs.values())

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while self.running:
            if end is not None and time.monotonic() > end:
                return False
            time.sleep(0.05)
        return True

    def hold(self) -> float:
        """The run reached its end: each device process catches up with it, goes silent and
        keeps its ports open (readers drain them) until :meth:`stop`; the vehicle time every
        device reached (the least)."""
        self.truth_runner.stop()
        for proc in self.procs.values():
            self._send(proc, "hold")
        reached = [self.truth_runner.vehicle_time]
        for proc in self.procs.values():
            msg = self._read(proc, _FINISH_TIMEOUT_S + 30.0)
            if msg is not None and "held" in msg:
                reached.append(float(msg["held"]))
        return min(reached)

    def stop(self) -> None:
        """Stop every device process (collecting its counters) and the truth clock. After the
        run's natural end each device first catches up to it (a busy machine delays a process's
        clock), so every device sends every sample of the run."""
        ended = self.truth_runner.ended
        self.truth_runner.stop()
        for kind in list(self.procs):
            self._finish(kind, timeout=_FINISH_TIMEOUT_S + 30.0, word="finish" if ended else "stop")

    def stats(self) -> dict[str, Any]:
        """Per-device counters as :meth:`Runner.stats` (after :meth:`stop`), merged; each
        device's entry also carries its process's CPU seconds (``process_cpu_s``)."""
        truth = self.truth_runner.stats()
        out: dict[str, Any] = {
            "vehicle_time": self.truth_runner.vehicle_time,
            "process_cpu_s": truth["process_cpu_s"],
            "clock_cpu_s": truth["clock_cpu_s"],
            "late_ticks": 0,
            "max_lag_s": 0.0,
            **{k: truth[k] for k in ("elastic_lag_s", "holds", "held_s", "hold_timeouts")},
            "devices": {},
        }
        for st in self._stats.values():
            out["process_cpu_s"] += st["process_cpu_s"]
            out["clock_cpu_s"] += st["clock_cpu_s"]
            out["late_ticks"] += st["late_ticks"]
            out["max_lag_s"] = max(out["max_lag_s"], st["max_lag_s"])
            for name, dev in st["devices"].items():
                out["devices"][name] = {**dev, "process_cpu_s": st["process_cpu_s"]}
        return out

    def close(self) -> None:
        for kind in list(self.procs):
            with contextlib.suppress(Exception):
                self._finish(kind, timeout=5.0)
        self._poll_stop.set()
        if self._poller is not None:
            self._poller.join(2.0)
        if self._board is not None:
            self._board.close()
        self.truth_runner.close()

