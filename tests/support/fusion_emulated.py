"""The fusion over the EMULATED survey, offline: the HN-100 and Pathfinder emulators' own
encoders called tick by tick (no ptys, no clock, as fast as possible), their byte streams framed
and decoded by the drivers, adapted and filtered by the same in-process fusion stage the bus
runs. Used by tests/service/test_fusion_emulated.py and benchmarks/bench_fusion_emulated.py.

Receive times model the serial lines: each tick's frame starts at the tick (or when the line is
free) and arrives when its last byte has crossed at 115200 baud (10 bits per byte); the host
clock reads ``HOST_EPOCH`` at vehicle time 0. The stage is told each device's fixed latency
(its frame's transmission time), so the odometry's host time minus ``HOST_EPOCH`` is the
vehicle time of the INS sample it belongs to.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from auvgw.config.scenario import Scenario
from auvgw.drivers import hn100, pd0
from auvgw.drivers.can_codec import CanDeviceCodec, hn100_can
from auvgw.drivers.framing import ErrorPolicy, Framer
from auvgw.fusion import FusionConfig, InitialState, Odometry
from auvgw.ground.paths import config_file
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.ins import InsEmulator
from auvgw.sim_devices.slcan import can_frame_bits
from auvgw.sim_devices.vehicle import Truth, simulate
from auvgw.sim_devices.world import World
from auvgw.stages.fusion import FusionStage, FusionStageConfig

BAUD = 115200
CAN_BITRATE = 500_000
#: host clock (POSIX s) at vehicle time 0; not the DVL's RTC epoch, so the clock mapping matters
HOST_EPOCH = 1_780_000_000.0
#: chi-square, 2 dof: Mahalanobis radius 2 (the 2-sigma ellipse, 86.5 % for a consistent
#: filter) and the 95 % ellipse (2.45 sigma)
NEES_2SIGMA = 4.0
NEES_95 = 5.991


def harbour_ins_dvl(duration_s: float) -> Scenario:
    """``config/scenarios/harbour.json`` cut at ``duration_s`` with only the INS and the DVL,
    their ports off (frames made offline, e.g. for :func:`write_recording`)."""
    data = json.loads(config_file("scenarios/harbour.json").read_text())
    data["duration_s"] = duration_s
    data["devices"] = {"ins": {"options": {"serial": False, "can": False}},
                       "dvl": {"options": {"serial": False}}}  # fmt: skip
    return Scenario.model_validate(data)


def survey_scenario(
    duration_s: float | None = None, bottom_lock_loss: tuple[tuple[float, float], ...] = ()
) -> Scenario:
    """``config/scenarios/survey.json`` (default noise figures: HN-100, Pathfinder) with the INS
    and DVL ports off, optionally cut at ``duration_s`` and with DVL bottom-lock-loss windows."""
    data = json.loads(config_file("scenarios/survey.json").read_text())
    if duration_s is not None:
        data["duration_s"] = duration_s
    data["devices"] = {
        "ins": {"options": {"serial": False, "can": False}},
        "dvl": {
            "options": {"serial": False},
            "faults": {"bottom_lock_loss": [list(w) for w in bottom_lock_loss]},
        },
    }
    return Scenario.model_validate(data)


@dataclass
class Emulated:
    """One offline emulated run: the scenario's context and emulators."""

    scenario: Scenario
    truth: Truth
    ctx: SimContext
    ins: InsEmulator
    dvl: DvlEmulator

    @property
    def duration(self) -> float:
        return float(self.truth.t[-1])


def emulate(scn: Scenario, port_dir: Path) -> Emulated:
    """World, truth and the two emulators (no ports opened)."""
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    ctx = SimContext(scn, world, truth, SimClock(0), port_dir)
    return Emulated(scn, truth, ctx, InsEmulator(ctx), DvlEmulator(ctx))


def tick_times(rate_hz: float, t0: float, t1: float) -> list[float]:
    """The emulator clock's tick times ``n / rate`` within ``[t0, t1]`` (vehicle s)."""
    first = math.ceil(t0 * rate_hz - 1e-9)
    return [k / rate_hz for k in range(first, int(t1 * rate_hz + 1e-9) + 1)]


@dataclass
class Stream:
    """A device's byte stream with the host receive time of each frame's last byte, by the
    frame's start offset (the framer reports start offsets)."""

    data: bytes
    recv_by_offset: dict[int, float]
    frame_latency_s: float  #: transmission time of one frame (latency told to the stage)


def serial_stream(frames: list[bytes], times: list[float], baud: int = BAUD) -> Stream:
    """Frames sent at ``times`` (vehicle s) on a line of ``baud``: start when the line is free,
    arrive when the last byte is in."""
    recv: dict[int, float] = {}
    offset, free = 0, -math.inf
    byte_s = 10.0 / baud
    for f, t in zip(frames, times, strict=True):
        start = max(t, free)
        free = start + len(f) * byte_s
        recv[offset] = HOST_EPOCH + free
        offset += len(f)
    return Stream(b"".join(frames), recv, len(frames[0]) * byte_s)


@dataclass
class InsOutput:
    """The INS emulator's output of one run: the serial byte stream and, when asked for, the CAN
    bursts of the same measurements decoded by the DBC driver (``(t_recv, device, sample)``)."""

    serial: Stream
    can: list[tuple[float, str, Any]]
    can_latency_s: float


def ins_output(em: Emulated, t0: float, t1: float, can: bool = False) -> InsOutput:
    """Every INS tick in ``[t0, t1]``: one measurement, encoded as the emulator sends it on
    serial (HN-100 binary frame) and, with ``can``, on CAN (a burst of 8 frames at 500 kbit/s,
    decoded with epoch assembly; the burst arrives after its frames' nominal bits)."""
    ins = em.ins
    times = tick_times(ins.rate_hz, t0, t1)
    frames: list[bytes] = []
    can_msgs: list[tuple[float, str, Any]] = []
    latency = 0.0
    if can:
        ins.can_codec = ins.can_codec or hn100_can()
        dec = CanDeviceCodec(hn100_can())
    for t in times:
        m = ins.measure(t)
        frames.append(ins.encode_serial(m))
        if can:
            burst = ins.encode_can(m)
            bits = sum(can_frame_bits(len(f.data), f.is_extended_id) for f in burst)
            latency = bits / CAN_BITRATE
            got = [dec.decode(f.arbitration_id, f.data, f.is_extended_id) for f in burst]
            assert got[:-1] == [None] * (len(burst) - 1) and got[-1] is not None
            can_msgs.append((HOST_EPOCH + t + latency, "ins_can", got[-1]))
    return InsOutput(serial_stream(frames, times), can_msgs, latency)


def dvl_stream(em: Emulated, t0: float, t1: float) -> Stream:
    """The PD0 ensembles of every DVL ping in ``[t0, t1]`` (the emulator's encoder)."""
    dvl = em.dvl
    times = tick_times(dvl.rate_hz, t0, t1)
    return serial_stream([dvl.frame_at(t) for t in times], times)


def decode_serial(stream: Stream, fmt: str, device: str) -> list[tuple[float, str, Any]]:
    """Frame and decode a byte stream with the drivers: ``(t_recv, device, message)``; every
    frame must be good."""
    framer: Framer
    if fmt == "hn100":
        framer, decode = hn100.Hn100Framer(policy=ErrorPolicy.RAISE), hn100.CODEC.decode
    else:
        framer, decode = pd0.Pd0Framer(policy=ErrorPolicy.RAISE), pd0.decode
    frames = [*framer.feed(stream.data), *framer.finish()]
    assert framer.stats.bad_frames == 0 and len(frames) == len(stream.recv_by_offset)
    return [(stream.recv_by_offset[f.offset], device, decode(f.data)) for f in frames]


def filter_config(
    em: Emulated,
    t0: float = 0.0,
    position_sigma_m: tuple[float, float, float] = (0.01, 0.01, 0.05),
    **changes: Any,
) -> FusionConfig:
    """Filter settings matching the emulators' noise model (see docs/fusion.md, "Emulated
    survey"): white INS attitude errors (the INS emulator draws independent noise every tick),
    the DVL's 0.2 cm/s plus its 1 mm/s wire rounding, the variable leader's depth (2 cm noise plus
    0.1 m rounding); the DVL sits at the reference point; start at the true position at ``t0``,
    known to ``position_sigma_m`` (1 cm: the DR uncertainty, not the start, dominates the
    ellipse)."""
    s = em.ctx.sampler.at(t0)
    base: dict[str, Any] = {
        "heading_error_sigma_deg": 0.3,
        "heading_error_tau_s": 0.0,
        "pitch_error_sigma_deg": 0.02,
        "pitch_error_tau_s": 0.0,
        "dvl_velocity_sigma_mps": math.hypot(0.002, 0.001 / math.sqrt(12.0)),
        "depth_sigma_m": math.hypot(0.02, 0.1 / math.sqrt(12.0)),
        "initial": InitialState(position_m=(s.x, s.y, s.z), position_sigma_m=position_sigma_m),
    }
    base.update(changes)
    return FusionConfig(**base)


def run_stage(
    messages: list[tuple[float, str, Any]], config: FusionStageConfig
) -> tuple[list[Odometry], FusionStage]:
    """Feed ``(t_recv, device, message)`` in arrival order to an in-process fusion stage;
    returns every odometry sample (flushed at the end) and the stage."""
    out: list[Odometry] = []
    stage = FusionStage(config, on_odometry=out.append)
    for t_recv, device, msg in sorted(messages, key=lambda m: m[0]):
        stage.feed(device, round(t_recv * 1e9), msg)
    stage.flush()
    return out, stage


def reference_track(truth: Truth, t0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t, x, y)`` from ``t0``: the integral of the truth's NED velocity AS THE EMULATORS REPORT
    IT (linear between motion steps, so trapezoidal), from the true position at ``t0``.

    The truth's own positions come from an Euler step (velocity of step k applied over
    [t_k, t_k+1]) while every emulator samples velocity and attitude linearly between steps, so
    the two differ by ``dt/2 (v(t) - v(t0))`` (telescoping, never more than ``dt |v|``, 3.4 cm at
    1.7 m/s with the 0.02 s step) - bounded, but as large as the filter's own uncertainty in a
    short run. Consistency is judged against this reference; errors against the raw truth too.
    """
    t = np.concatenate([[t0], truth.t[truth.t > t0]])
    vn, ve = np.interp(t, truth.t, truth.vn), np.interp(t, truth.t, truth.ve)
    dt = np.diff(t)

    def integral(v: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(dt * (v[:-1] + v[1:]) / 2.0)])

    x0, y0 = np.interp(t0, truth.t, truth.x), np.interp(t0, truth.t, truth.y)
    return t, x0 + integral(vn), y0 + integral(ve)


@dataclass
class Evaluation:
    """Odometry against the truth at the INS sample times (vehicle s): ``err``/``nees`` against
    the :func:`reference_track`, ``err_raw``/``nees_raw`` against the raw truth positions."""

    t: np.ndarray
    err: np.ndarray  #: (n, 2) horizontal error against the reference track, m
    nees: np.ndarray  #: horizontal NEES against the reference track
    err_raw: np.ndarray  #: (n, 2) horizontal error against the raw truth, m
    nees_raw: np.ndarray
    sigma: np.ndarray  #: sqrt of the trace of the horizontal covariance, m
    travelled: np.ndarray  #: distance travelled since the start, m
    coasting: np.ndarray
    bottom_lock: np.ndarray

    @property
    def final_error(self) -> float:
        """Final horizontal error against the raw truth, m."""
        return float(np.hypot(*self.err_raw[-1]))

    @property
    def distance(self) -> float:
        return float(self.travelled[-1])

    def inside(self, nees_bound: float, mask: np.ndarray | None = None, raw: bool = False) -> float:
        """Fraction of epochs whose truth lies within the ellipse ``NEES <= nees_bound``."""
        n = self.nees_raw if raw else self.nees
        return float(np.mean((n if mask is None else n[mask]) <= nees_bound))


def evaluate(out: list[Odometry], truth: Truth) -> Evaluation:
    """Errors, NEES and distance of an odometry run against the truth (linear between steps)."""
    t = np.array([o.t for o in out]) - HOST_EPOCH
    xy = np.array([(o.x, o.y) for o in out])
    inv = np.linalg.inv(np.array([o.cov_xy for o in out]))
    tx = np.interp(t, truth.t, truth.x)
    ty = np.interp(t, truth.t, truth.y)
    rt, rx, ry = reference_track(truth, float(t[0]))
    err = xy - np.stack([np.interp(t, rt, rx), np.interp(t, rt, ry)], axis=1)
    err_raw = xy - np.stack([tx, ty], axis=1)
    seg = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(tx), np.diff(ty)))])
    return Evaluation(
        t=t,
        err=err,
        nees=np.einsum("ni,nij,nj->n", err, inv, err),
        err_raw=err_raw,
        nees_raw=np.einsum("ni,nij,nj->n", err_raw, inv, err_raw),
        sigma=np.sqrt(np.trace(np.linalg.inv(inv), axis1=1, axis2=2)),
        travelled=seg,
        coasting=np.array([o.coasting for o in out]),
        bottom_lock=np.array([o.bottom_lock for o in out]),
    )


def ins_dvl_frames(ins: InsOutput, dvl: Stream) -> list[tuple[float, str, bytes, Any]]:
    """The INS (HN-100 serial) and DVL (PD0) frames of an emulated run as a gateway reads them:
    ``(t_recv s, device "ins" | "dvl", raw frame, decoded message)``."""
    msgs = decode_serial(ins.serial, "hn100", "ins") + decode_serial(dvl, "pd0", "dvl")
    return [(t, d, hn100.CODEC.encode(m) if d == "ins" else pd0.encode(m), m) for t, d, m in msgs]


def write_recording(
    path: Path,
    vehicle: str,
    formats: dict[str, str],
    frames: list[tuple[float, str, bytes, Any]],
    truth: Truth,
) -> Path:
    """An MCAP as ``auvgw record`` writes it: the gateway configuration (``formats``: device ->
    format; serial devices on a /dev/recorded-<device> each, ``kongsberg`` on UDP), every raw
    frame in order with its attachment (receive time, sequence, stream offset per device) and
    every 10th truth pose on ``truth/pose``."""
    from auvgw.bus import Keys, pack_raw_attachment
    from auvgw.config.gateway import parse_gateway_config
    from auvgw.recording import McapRecorder

    # one port per device (the configuration's rule), never opened: a recording only names them
    devices = {d: {"format": f, "transport": {"kind": "udp", "port": 0} if f == "kongsberg"
                   else {"kind": "serial", "url": f"/dev/recorded-{d}"}}
               for d, f in formats.items()}  # fmt: skip
    gw = parse_gateway_config({"vehicle": vehicle, "devices": devices})
    keys = Keys(vehicle)
    rec = McapRecorder(path, vehicle)
    rec.set_gateway_config(gw.model_dump_json())
    offsets = dict.fromkeys(formats, 0)
    for seq, (t, dev, b, _) in enumerate(frames):
        rec.add(keys.raw(dev), b, pack_raw_attachment(round(t * 1e9), seq, offsets[dev]))
        offsets[dev] += len(b)
    for t, (x, y, h) in zip(truth.t[::10], truth.poses[::10], strict=True):
        body = json.dumps({"t": float(t), "x": float(x), "y": float(y), "heading": float(h)})
        rec.add(keys.truth("pose"), body.encode(), None, "application/json")
    rec.close()
    return path


def fusion_settings(
    path: Path, vehicle: str, em: Emulated, ins: InsOutput, dvl: Stream
) -> tuple[Path, FusionStageConfig]:
    """The fusion stage settings for an emulated INS + DVL run (their frame latencies, the
    emulators' noise model) written as JSON to ``path``: (path, the settings)."""
    cfg = FusionStageConfig(vehicle=vehicle, ins_device="ins", dvl_device="dvl",
                            latency_s={"ins": ins.serial.frame_latency_s,
                                       "dvl": dvl.frame_latency_s},
                            filter=filter_config(em, 0.0))  # fmt: skip
    path.write_text(cfg.model_dump_json())
    return path, cfg


def feed_through_fusion(
    config: FusionStageConfig, stage: Any, frames: list[tuple[float, str, bytes, Any]]
) -> None:
    """Feed decoded ``frames`` (``(t_recv s, device, raw, message)``, in order) to an in-process
    fusion stage and to ``stage`` (a SLAM stage: ``feed``, ``feed_odometry``, ``flush``), the
    fusion's odometry into ``stage``; flush both at the end."""
    fusion = FusionStage(config, on_odometry=stage.feed_odometry)
    for t, dev, _, m in frames:
        fusion.feed(dev, round(t * 1e9), m)
        stage.feed(dev, round(t * 1e9), m)
    fusion.flush()
    stage.flush()
