"""Emulated Tritech MSIS head (Micron / SeaKing): a byte-level SeaNet state machine and the
echo model that fills its bins from the world's horizontal ray casting.

:class:`MsisHead` speaks SeaNet through the project's codec (``auvgw.drivers.seanet``: framer,
decoder, builders). Like a real head it is silent unless polled:

* power-up (:meth:`MsisHead.power_up`) and every ``alive_period_s`` of silence
  (:meth:`MsisHead.tick`): mtAlive, HeadInf NO_PARAMS until configured;
* mtReBoot: reset (parameters forgotten, transducer re-centred), answered with mtAlive;
* mtSendVersion: mtVersionData;
* mtHeadCommand: takes range, gain, step, limits, continuous / sector, 4- / 8-bit bins, NBins
  and ADInterval; answers mtAlive (SENT_CFG, still NO_PARAMS) at once, then after
  ``config_delay_s`` (re-centring the motor) mtAlive with parameters: ready;
* mtSendData (once configured): exactly one mtHeadData at the current transducer bearing, then
  the transducer steps by the configured step (continuous rotation, or a sector between the
  limits with direction reversal at each limit, the limit itself pinged once);
* mtStopAlives: no more periodic mtAlive until reset.

Anything else (garbage, bad packets, other nodes' traffic, mtSendData before configuration,
messages a head does not answer) produces nothing and is counted in :attr:`MsisHead.stats`.

Bearings are the head's own transducer angle (0 at the forward mark, clockwise seen from above,
radians in the API, 1/16 gradian on the wire). The bin ranges of a ping are
``(k + 0.5) * ADInterval * c / 2`` for bin ``k`` (the centre of each sampling interval).

The bins come from a pluggable ``echo(bearing_rad, bin_ranges_m) -> intensity`` callable
(:data:`Echo`), intensities 0..1 being the echo level as a fraction of the receiver's 80 dB
range at the reference gain (0.4). The head adds its receiver gain (``gain`` x 80 dB relative to
the reference) and quantises: 8-bit bins 0..255 = 0..80 dB; 4-bit bins map ADLow..ADLow+ADSpan
onto 0..15. :func:`make_echo` builds the callable from the world's ray caster.

Measurement noise and the VB paper's noise bursts. The echo model places every target at its
exact ray-cast range; the sonar's own spread (pulse length, bin quantisation, speckle moving
the peak) is all the range noise it has. On top, each ping may carry a range error ``dr`` ~
``N(0, range_sigma_m^2)`` and a bearing error ``db`` ~ ``N(0, bearing_sigma_deg^2)`` (sound
speed and multipath errors, transducer position feedback): the bins are filled with
``echo(bearing + db, ranges - dr)``, so the head reports every target of that ping ``dr``
farther and ``db`` anticlockwise (in its own bearing sense) of where it is. A head given a
``noise_scale`` callable (the emulator's
:meth:`~auvgw.sim_devices.emulator.Emulator.sigma_scale`: ``sqrt(n)`` in a burst, else 1)
calls it once per ping and multiplies both sigmas by it, so a burst ping's range and bearing
error variances are ``n`` times the clean ones; burst pings are counted in
:attr:`MsisHeadStats.burst_pings` (and in the emulator's ``noise_samples`` /
``noise_bursts``). Both sigmas are 0 by default (no draw at all: the bins are as before);
inside the simulator they come from the scenario's ``devices.msis.noise`` (``range_m``,
``bearing_deg``) through :meth:`MsisHead.attach`, and bursts from
``devices.msis.faults.noise_burst_n`` / ``noise_burst_p``. With both sigmas 0 a burst changes
nothing (the emulator logs a warning when bursts are switched on so).

Times ``t`` are seconds on the simulation clock. The head returns its replies at once; a runner
that wants the real ping duration delays them by :meth:`MsisHead.ping_duration_s`, as
:func:`serve_on_port` does (the head on a :class:`~auvgw.sim_devices.ports.PtyPort`, driven by
the :class:`~auvgw.sim_devices.clock.SimClock`, optionally through a fault injector).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from auvgw.config.gateway import MsisPolling
from auvgw.config.scenario import DeviceSettings
from auvgw.drivers import seanet as sn
from auvgw.drivers.framing import DecodeError, ErrorPolicy
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.emulator import PolledEmulator, SimContext, device_option

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_NOISE",
    "REFERENCE_GAIN",
    "Caster",
    "Echo",
    "MsisHead",
    "MsisHeadStats",
    "make_echo",
    "make_emulator",
    "quantise",
    "serve_on_port",
    "silent_echo",
]

#: echo(bearing_rad, bin_ranges_m) -> intensities 0..1 (fraction of the 80 dB receiver range)
Echo = Callable[[float, np.ndarray], np.ndarray]

#: receiver gain (0..1) at which an echo intensity maps 1:1 onto the receiver range
REFERENCE_GAIN = 0.4
#: receiver dynamic range, dB (8-bit bins 0..255 = 0..80 dB; gain 0..1 = 0..80 dB)
RECEIVER_RANGE_DB = 80.0
#: the head's per-ping measurement noise (1 sigma), off by default: range m, bearing deg
DEFAULT_NOISE: dict[str, float] = {"range_m": 0.0, "bearing_deg": 0.0}
#: seconds per motor step (Tritech's MoTime default: 25 x 10 us), used for the ping duration
_STEP_TIME_S = 250e-6

_CENTRED = sn.HeadInf.CENTRED | sn.HeadInf.MOTOR_ON
_UNCONFIGURED = sn.HeadInf.NO_PARAMS | _CENTRED  # 0x4A, a head after power-up
_CFG_ACK = sn.HeadInf.SENT_CFG | sn.HeadInf.NO_PARAMS | _CENTRED  # 0xCA, command received
_READY = sn.HeadInf.SENT_CFG | sn.HeadInf.MOTOR_ON  # 0x88 + CENTRED or DIR


def silent_echo(bearing: float, ranges: np.ndarray) -> np.ndarray:
    """No echo anywhere: all bins 0 (a head in open water without noise)."""
    del bearing
    return np.zeros(len(ranges))


def quantise(intensity: np.ndarray, cmd: sn.HeadCommand) -> np.ndarray:
    """Echo intensities (0..1 of 80 dB at the reference gain) -> bins as ``cmd`` asks.

    The receiver gain adds ``(gain - REFERENCE_GAIN) x 80 dB``. 8-bit: 0..255 = 0..80 dB;
    4-bit: ADLow..ADLow+ADSpan dB -> 0..15. An odd bin count in 4-bit mode gets one zero bin
    appended (two bins per byte on the wire).
    """
    level_db = np.asarray(intensity, float) * RECEIVER_RANGE_DB
    level_db = level_db + (cmd.gain_ch1 - REFERENCE_GAIN) * RECEIVER_RANGE_DB
    if cmd.adc8on:
        return np.clip(np.rint(level_db * (255.0 / RECEIVER_RANGE_DB)), 0, 255).astype(np.uint8)
    span = max(cmd.ad_span, 1e-6)
    bins = np.clip(np.rint((level_db - cmd.ad_low) / span * 15.0), 0, 15).astype(np.uint8)
    if len(bins) % 2:
        bins = np.append(bins, np.uint8(0))
    return bins


@dataclass
class MsisHeadStats:
    """What the head received and sent since it was made."""

    polls: int = 0  # mtSendData received
    head_data: int = 0  # mtHeadData sent
    alives: int = 0  # mtAlive sent
    versions: int = 0  # mtVersionData sent
    commands: int = 0  # mtHeadCommand accepted
    reboots: int = 0  # mtReBoot received (power-ups not counted)
    ignored: int = 0  # valid packets not answered (other nodes, unsupported, not configured)
    decode_errors: int = 0  # packets that framed but did not decode
    bad_frames: int = 0  # framer: candidates that failed a check (garbage, corruption)
    skipped_bytes: int = 0  # framer: bytes outside valid packets
    burst_pings: int = 0  # mtHeadData whose range / bearing noise was a VB noise burst

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class MsisHead:
    """An emulated imaging head; every method returns the bytes the head puts on the line.

    ``echo`` fills the bins (default :func:`silent_echo`); ``sound_speed`` (m/s) converts
    ADInterval to bin ranges; ``node`` is the head's SeaNet node; ``alive_period_s`` the mtAlive
    period while idle; ``config_delay_s`` the re-centring time after mtHeadCommand. The head is
    thread-safe (host bytes and clock ticks may come from different threads). It starts
    powered off: call :meth:`power_up`.

    Per-ping noise (see the module docstring): ``range_sigma_m`` (m) and ``bearing_sigma_deg``
    (deg), drawn from ``rng`` (needed when either is > 0), times ``noise_scale()`` per ping when
    given (the noise-burst multiplier). :meth:`attach` sets all four from an emulator.
    """

    def __init__(
        self,
        echo: Echo | None = None,
        *,
        sound_speed: float = 1500.0,
        node: int = sn.HEAD_NODE,
        alive_period_s: float = 1.0,
        config_delay_s: float = 0.1,
        device_type: int = 11,
        serial_number: int = 1234,
        software_version: int = 17,
        range_sigma_m: float = 0.0,
        bearing_sigma_deg: float = 0.0,
        rng: np.random.Generator | None = None,
        noise_scale: Callable[[], float] | None = None,
    ) -> None:
        self.echo = echo if echo is not None else silent_echo
        self.set_noise(range_sigma_m, bearing_sigma_deg, rng, noise_scale)
        #: (range error m, bearing error rad, noise multiplier) of the latest ping
        self.last_ping_noise = (0.0, 0.0, 1.0)
        self.sound_speed = sound_speed
        self.node = node
        self.alive_period_s = alive_period_s
        self.config_delay_s = config_delay_s
        self.device_type = device_type
        self.serial_number = serial_number
        self.software_version = software_version
        self.stats = MsisHeadStats()
        self._lock = threading.Lock()
        self._framer = sn.SeaNetFramer(policy=ErrorPolicy.IGNORE, source="msis-head")
        self._framer_base = (0, 0)
        self.powered = False
        self._reset(0.0)

    def set_noise(
        self,
        range_sigma_m: float,
        bearing_sigma_deg: float,
        rng: np.random.Generator | None = None,
        noise_scale: Callable[[], float] | None = None,
    ) -> None:
        """Set the per-ping range / bearing noise (m, deg, 1 sigma), its generator and the
        noise-burst multiplier callable (None: always 1)."""
        if range_sigma_m < 0 or bearing_sigma_deg < 0:
            raise ValueError(
                f"MSIS noise sigmas must be >= 0, got range {range_sigma_m} m, bearing "
                f"{bearing_sigma_deg} deg"
            )
        if (range_sigma_m > 0 or bearing_sigma_deg > 0) and rng is None:
            raise ValueError("MSIS range / bearing noise needs a random generator (rng)")
        self.range_sigma_m = float(range_sigma_m)
        self.bearing_sigma = math.radians(bearing_sigma_deg)
        self.rng = rng
        self.noise_scale = noise_scale

    def attach(self, emulator: Any) -> None:
        """Take the noise settings from the
        :class:`~auvgw.sim_devices.emulator.PolledEmulator` wrapping this head:
        ``devices.msis.noise`` ``range_m`` / ``bearing_deg`` (unknown keys are an error), its
        generator and its :meth:`~auvgw.sim_devices.emulator.Emulator.sigma_scale`."""
        emulator.check_noise_keys(DEFAULT_NOISE)
        self.set_noise(
            emulator.noise("range_m", DEFAULT_NOISE["range_m"]),
            emulator.noise("bearing_deg", DEFAULT_NOISE["bearing_deg"]),
            emulator.rng,
            emulator.sigma_scale,
        )
        faults = emulator.settings.faults
        if faults.noise_burst_p > 0 and faults.noise_burst_n > 1 and not self._noisy():
            log.warning(
                "%s: noise bursts are on but devices.%s.noise.range_m and bearing_deg are 0: "
                "the bursts change nothing",
                getattr(emulator, "name", "msis"),
                getattr(emulator, "kind", "msis"),
            )

    def _noisy(self) -> bool:
        return self.range_sigma_m > 0 or self.bearing_sigma > 0

    def _ping_noise(self) -> tuple[float, float, float]:
        """(range error m, bearing error rad, multiplier) of one ping."""
        k = float(self.noise_scale()) if self.noise_scale is not None else 1.0
        if k > 1.0:
            self.stats.burst_pings += 1
        if not self._noisy() or self.rng is None:
            return 0.0, 0.0, k
        g = self.rng.standard_normal(2) * k
        return float(g[0] * self.range_sigma_m), float(g[1] * self.bearing_sigma), k

    # -- state --------------------------------------------------------------------------------
    def _reset(self, t: float) -> None:
        self.config: sn.HeadCommand | None = None
        self.ready = False
        self._ready_at = math.inf
        self.position = 0  # transducer angle, wire units (1/16 gradian), 0 = centre
        self.direction = 1  # +1 clockwise
        self.alives_on = True
        self._clock_ms = 0.0  # head clock at _clock_t
        self._clock_t = t
        self._last_tx = t

    def head_time(self, t: float) -> float:
        """Head clock at sim time ``t``: s since power-up, or of day as last set by mtSendData."""
        return (self._clock_ms / 1000.0 + (t - self._clock_t)) % 86_400.0

    @property
    def bearing(self) -> float:
        """Current transducer angle, rad (0..2pi, clockwise from the forward mark)."""
        return sn.angle_to_rad(self.position)

    def ping_duration_s(self) -> float:
        """How long one ping takes on a real head: the two-way travel time over the range
        plus one motor step (0 when unconfigured)."""
        cfg = self.config
        if cfg is None:
            return 0.0
        return cfg.ad_interval * cfg.n_bins + _STEP_TIME_S * max(1, sn.rad_to_angle(cfg.step))

    def bin_ranges(self) -> np.ndarray:
        """Range of each bin's centre, m, from ADInterval, NBins and the sound speed."""
        cfg = self.config
        if cfg is None:
            return np.zeros(0)
        n = cfg.n_bins + (1 if cfg.n_bins % 2 and not cfg.adc8on else 0)
        ad = cfg.ad_interval
        if ad <= 0:  # malformed command: derive it from the range scale
            ad = 2.0 * cfg.range_m / self.sound_speed / max(cfg.n_bins, 1)
        return (np.arange(n) + 0.5) * sn.bin_length(ad, self.sound_speed)

    # -- the line -----------------------------------------------------------------------------
    def power_up(self, t: float) -> bytes:
        """Switch on (or power-cycle) at sim time ``t``: the first mtAlive, NO_PARAMS."""
        with self._lock:
            self.powered = True
            self._framer_counts()  # a new line: a partial packet is lost, counts carry on
            self._framer_base = (self.stats.bad_frames, self.stats.skipped_bytes)
            self._framer = sn.SeaNetFramer(policy=ErrorPolicy.IGNORE, source="msis-head")
            self._reset(t)
            return self._alive(t, _UNCONFIGURED)

    def power_off(self) -> None:
        """Switch off: silent, host bytes are dropped, parameters are lost."""
        with self._lock:
            self.powered = False
            self.config = None
            self.ready = False

    def tick(self, t: float) -> bytes:
        """Time passes (call often, e.g. every 10-100 ms): the mtAlive announcing readiness
        after configuration, and the periodic mtAlive after ``alive_period_s`` of silence."""
        with self._lock:
            if not self.powered:
                return b""
            if t >= self._ready_at:
                self._ready_at = math.inf
                self.ready = True
                return self._alive(t, self._inf())
            if self.alives_on and t - self._last_tx >= self.alive_period_s:
                return self._alive(t, self._inf())
            return b""

    def feed(self, data: bytes, t: float) -> bytes:
        """Bytes from the host at sim time ``t`` -> the head's answer (may be empty)."""
        return b"".join(self.feed_packets(data, t))

    def feed_packets(self, data: bytes, t: float) -> list[bytes]:
        """As :meth:`feed`, one SeaNet packet per list item (for per-frame fault injection)."""
        with self._lock:
            if not self.powered:
                return []
            out: list[bytes] = []
            for frame in self._framer.feed(data):
                try:
                    msgs = sn.decode(frame.data)
                except DecodeError:
                    self.stats.decode_errors += 1
                    continue
                for msg in msgs:
                    reply = self._handle(msg, t)
                    if reply:
                        out.append(reply)
            self._framer_counts()
            return out

    def _framer_counts(self) -> None:
        s = self._framer.stats
        self.stats.bad_frames = self._framer_base[0] + s.bad_frames
        self.stats.skipped_bytes = self._framer_base[1] + s.skipped_bytes

    # -- messages -----------------------------------------------------------------------------
    def _inf(self) -> int:
        if self.config is None:
            return int(_UNCONFIGURED)
        if not self.ready:
            return int(_CFG_ACK)
        where = sn.HeadInf.CENTRED if self.position == 0 else sn.HeadInf.DIR
        return int(_READY | where)

    def _send(self, msg: Any, t: float) -> bytes:
        self._last_tx = t
        return sn.encode(msg)

    def _alive(self, t: float, head_inf: int) -> bytes:
        self.stats.alives += 1
        msg = sn.alive(
            self.head_time(t),
            head_inf=head_inf,
            transducer_bearing=self.bearing,
            tx=self.node,
        )
        return self._send(msg, t)

    def _handle(self, msg: Any, t: float) -> bytes:
        if msg.tx_node != sn.HOST_NODE or msg.rx_node != self.node:
            self.stats.ignored += 1
            return b""
        if isinstance(msg, sn.SendData):
            return self._on_send_data(msg, t)
        if isinstance(msg, sn.SendVersion):
            self.stats.versions += 1
            return self._send(
                sn.version_data(
                    software_version=self.software_version,
                    serial_number=self.serial_number,
                    tx=self.node,
                ),
                t,
            )
        if isinstance(msg, sn.HeadCommand):
            return self._on_head_command(msg, t)
        if isinstance(msg, sn.ReBoot):
            self.stats.reboots += 1
            self._reset(t)
            return self._alive(t, _UNCONFIGURED)
        if isinstance(msg, sn.SeaNetRaw) and msg.msg_type == sn.MessageType.mtStopAlives:
            self.alives_on = False
            return b""
        self.stats.ignored += 1
        return b""

    def _on_head_command(self, cmd: sn.HeadCommand, t: float) -> bytes:
        self.stats.commands += 1
        self.config = cmd
        self.ready = False
        self._ready_at = t + self.config_delay_s
        self.direction = 1 if cmd.scan_right else -1
        left, span = self._sector()
        if span:  # a sector scan starts at the limit it scans away from
            offset = (self.position - left) % sn.ANGLE_UNITS_PER_TURN
            if offset > span:
                self.position = left if self.direction > 0 else (left + span)
                self.position %= sn.ANGLE_UNITS_PER_TURN
            elif offset in (0, span):
                self.direction = 1 if offset == 0 else -1
        return self._alive(t, _CFG_ACK)

    def _sector(self) -> tuple[int, int]:
        """(left limit, clockwise span to the right limit) in wire units; span 0 = continuous
        (also for a sector whose limits coincide: the full circle)."""
        cfg = self.config
        if cfg is None or cfg.continuous:
            return 0, 0
        left = sn.rad_to_angle(cfg.left_limit)
        span = (sn.rad_to_angle(cfg.right_limit) - left) % sn.ANGLE_UNITS_PER_TURN
        return left, span

    def _on_send_data(self, msg: sn.SendData, t: float) -> bytes:
        self.stats.polls += 1
        cfg = self.config
        if cfg is None or not self.ready:
            self.stats.ignored += 1
            return b""
        self._clock_ms = round(msg.time * 1000.0)
        self._clock_t = t
        left, span = self._sector()
        offset = (self.position - left) % sn.ANGLE_UNITS_PER_TURN
        sweep = sn.SweepCode.NORMAL
        if span:
            if offset == 0:
                sweep = sn.SweepCode.AT_LEFT_LIMIT
            elif offset == span:
                sweep = sn.SweepCode.AT_RIGHT_LIMIT
        bearing = self.bearing
        dr, db, k = self._ping_noise()
        self.last_ping_noise = (dr, db, k)
        ranges = self.bin_ranges()
        if dr != 0.0 or db != 0.0:  # every target reported dr farther, db anticlockwise
            intensity = np.asarray(self.echo(bearing + db, ranges - dr), float)
        else:
            intensity = np.asarray(self.echo(bearing, ranges), float)
        bins = quantise(intensity, cfg)
        self.stats.head_data += 1
        reply = sn.head_data(
            bins,
            bearing,
            config=cfg,
            sweep_code=sweep,
            device_type=self.device_type,
            tx=self.node,
        )
        self._step(left, span, offset)
        return self._send(reply, t)

    def _step(self, left: int, span: int, offset: int) -> None:
        """Move the transducer by one step (reversing at a sector limit)."""
        step = max(1, sn.rad_to_angle(self.config.step)) if self.config else 1
        if not span:
            self.position = (self.position + self.direction * step) % sn.ANGLE_UNITS_PER_TURN
            return
        nxt = offset + self.direction * step
        if nxt >= span:
            nxt, self.direction = span, -1
        elif nxt <= 0:
            nxt, self.direction = 0, 1
        self.position = (left + nxt) % sn.ANGLE_UNITS_PER_TURN


# -- on a virtual port ---------------------------------------------------------------------------


class _Port(Protocol):
    on_receive: Callable[[bytes], object] | None

    def write(self, data: bytes) -> bool: ...


class _Faults(Protocol):
    def process(self, frame: bytes, t: float) -> bytes: ...

    def sync_port(self, port: Any, t: float) -> bool: ...


def serve_on_port(
    head: MsisHead,
    port: _Port,
    clock: SimClock,
    *,
    faults: _Faults | None = None,
    tick_period_s: float = 0.05,
    power_up: bool = True,
) -> Any:
    """Run ``head`` on a virtual serial ``port`` (a :class:`~auvgw.sim_devices.ports.PtyPort`)
    with the simulation ``clock`` (:class:`~auvgw.sim_devices.clock.SimClock`).

    Host bytes go to :meth:`MsisHead.feed_packets` as they arrive (in the port's I/O thread);
    mtHeadData leaves :meth:`MsisHead.ping_duration_s` of vehicle time later (the ping), other
    replies at once; :meth:`MsisHead.tick` runs every ``tick_period_s``. With ``faults`` (a
    :class:`~auvgw.sim_devices.faults.FaultInjector` built with the SeaNet framer) every packet
    goes through ``faults.process`` and the port is unplugged / replugged in its windows.
    Powers the head up now unless ``power_up`` is false. Returns the clock's tick task (cancel
    it to stop the head's own messages).
    """

    def send(packets: list[bytes], t: float) -> None:
        for packet in packets:
            data = faults.process(packet, t) if faults is not None else packet
            if data:
                port.write(data)

    def on_receive(data: bytes) -> None:
        t = clock.now()
        packets = head.feed_packets(data, t)
        pings = [p for p in packets if p[10] == sn.MessageType.mtHeadData]
        send([p for p in packets if p[10] != sn.MessageType.mtHeadData], t)
        if pings:
            clock.at(t + head.ping_duration_s(), lambda t_done: send(pings, t_done), "msis-ping")

    def tick(t: float) -> None:
        if faults is not None:
            faults.sync_port(port, t)
        out = head.tick(t)
        if out:
            send([out], t)

    port.on_receive = on_receive
    task = clock.every(tick_period_s, tick, name="msis-tick")
    if power_up:
        t0 = clock.now()
        send([head.power_up(t0)], t0)
    return task


# -- echo model ---------------------------------------------------------------------------------


class _Hits(Protocol):
    @property
    def range_m(self) -> np.ndarray: ...
    @property
    def incidence(self) -> np.ndarray: ...
    @property
    def kind(self) -> np.ndarray: ...
    @property
    def index(self) -> np.ndarray: ...


def _erf(x: np.ndarray) -> np.ndarray:
    """Error function, vectorised (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7)."""
    z = np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * z)
    poly = t * (
        0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    )
    return np.sign(x) * (1.0 - poly * np.exp(-z * z))


def _footprint(r: np.ndarray, obj: np.ndarray, hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range interval (lo, hi) each ray of a beam stands for, m: half-way to the ranges of its
    neighbouring rays on the same target (mirrored at the ends of a run of such rays), so a
    target seen obliquely fills the ranges between the sampled rays."""
    same = hit[:-1] & hit[1:] & (obj[:-1] == obj[1:])  # ray i and i + 1 see one target
    mid = np.where(same, (r[:-1] + r[1:]) / 2.0, np.nan)
    nxt = np.append(mid, np.nan)
    prv = np.insert(mid, 0, np.nan)
    nxt = np.where(np.isnan(nxt), 2.0 * r - prv, nxt)
    prv = np.where(np.isnan(prv), 2.0 * r - nxt, prv)
    return np.fmin(r, np.fmin(prv, nxt)), np.fmax(r, np.fmax(prv, nxt))


def _deposit(
    ranges: np.ndarray, r: np.ndarray, lo: np.ndarray, hi: np.ndarray, sigma: float
) -> np.ndarray:
    """(bins, rays) weights: each ray's power spread evenly over [lo, hi] and blurred by the
    pulse (a Gaussian of ``sigma`` m, peak 1); the integral over range is that of the peak-1
    Gaussian whatever the width, so an extended footprint lowers the peak."""
    d = ranges[:, None]
    width = (hi - lo)[None, :]
    point = np.exp(-0.5 * ((d - r[None, :]) / sigma) ** 2)
    wide = width > 1e-3 * sigma
    if not wide.any():
        return point
    k = 1.0 / (math.sqrt(2.0) * sigma)
    box = (
        math.sqrt(math.pi / 2.0)
        * sigma
        / np.where(wide, width, 1.0)
        * (_erf((hi[None, :] - d) * k) - _erf((lo[None, :] - d) * k))
    )
    return np.where(wide, box, point)


class Caster(Protocol):
    """What :func:`make_echo` needs of the world: horizontal rays from ``origin`` (x north,
    y east, m) in directions ``angles`` (rad from north towards east), first hit per ray within
    ``max_range`` (m): range (inf if none), incidence on the surface (rad), kind (0 nothing,
    1 line such as a wall, 2 point feature). :class:`auvgw.sim_devices.world.World` is one."""

    def cast(self, origin: tuple[float, float], angles: np.ndarray, max_range: float) -> _Hits: ...


def make_echo(
    world: Caster,
    pose_fn: Callable[[], tuple[float, float, float]],
    rng: np.random.Generator,
    beam_width_deg: float = 3.0,
    noise_floor: float = 0.1,
    speckle: float = 1.0,
    *,
    n_rays: int = 9,
    mount_offset: float = 0.0,
    inverted: bool = False,
    wall_db: float = 0.0,
    point_db: float = -6.0,
    spreading_db_per_decade: float = 20.0,
    absorption_db_per_m: float = 0.15,
    range_resolution_m: float = 0.075,
    reference_range_m: float = 1.0,
) -> Echo:
    """The MSIS echo callable for a head at ``pose_fn()`` = (x north, y east, heading rad) in
    ``world``, with a horizontal beam of ``beam_width_deg`` (-3 dB full width).

    Per ping, ``n_rays`` rays across +-1 beam width around the beam axis (heading +
    ``mount_offset`` + bearing; minus the bearing for an ``inverted`` head) are cast against the
    world's walls and point features. Each hit at range r and incidence i returns power

        beam(offset) * target * cos(i)^2 (Lambert) * spreading(r) * absorption(r)

    with the beam pattern -3 dB at +-width/2 (Gaussian), ``target`` ``wall_db`` / ``point_db``,
    spreading ``spreading_db_per_decade`` from ``reference_range_m`` (two-way 40 log r less the
    head's time-varied gain) and ``absorption_db_per_m`` each way. That power is spread over the
    bins around r with a Gaussian of half the larger of the bin length and
    ``range_resolution_m`` (the pulse), so an oblique wall, whose rays hit at different ranges,
    smears over the bins the beam footprint covers. Then speckle: the power is multiplied by
    ``(1 - speckle) + speckle * Exp(1)`` per bin (Rayleigh amplitude at ``speckle`` 1), and a
    noise floor adds noise power whose mean sits at intensity ``noise_floor`` (Rayleigh too).
    Intensity = 1 + 10 log10(power) / 80 dB, clipped to 0..1: 1 is a normal-incidence wall at
    the reference range.
    """
    if n_rays < 1:
        raise ValueError(f"n_rays must be >= 1, got {n_rays}")
    if not 0.0 <= speckle <= 1.0:
        raise ValueError(f"speckle must be within 0..1, got {speckle}")
    width = math.radians(beam_width_deg)
    offsets = np.linspace(-width, width, n_rays) if n_rays > 1 else np.zeros(1)
    beam = 10.0 ** (-0.3 * (2.0 * offsets / width) ** 2)  # power, -3 dB at +-width/2
    beam /= beam.sum()
    noise_power = (
        10.0 ** ((noise_floor - 1.0) * RECEIVER_RANGE_DB / 10.0) if noise_floor > 0 else 0.0
    )
    sense = -1.0 if inverted else 1.0
    target_db = {1: wall_db, 2: point_db}

    def echo(bearing: float, ranges: np.ndarray) -> np.ndarray:
        ranges = np.asarray(ranges, float)
        n = len(ranges)
        if n == 0:
            return np.zeros(0)
        bin_len = float(ranges[1] - ranges[0]) if n > 1 else 2.0 * float(ranges[0])
        sigma = max(bin_len, range_resolution_m) / 2.0
        x, y, heading = pose_fn()
        axis = heading + mount_offset + sense * bearing
        hits = world.cast((x, y), axis + offsets, float(ranges[-1]) + 3.0 * sigma)
        r = np.asarray(hits.range_m, float)
        kind = np.asarray(hits.kind)
        hit = (kind > 0) & np.isfinite(r)
        power = np.zeros(n)
        if hit.any():
            obj = np.where(hit, kind.astype(np.int64) * (1 << 32) + np.asarray(hits.index), -1)
            lo, hi = _footprint(np.where(hit, r, 0.0), obj, hit)
            rh, kh, lo, hi = r[hit], kind[hit], lo[hit], hi[hit]
            cos_i = np.cos(np.asarray(hits.incidence, float)[hit])
            ts = np.array([target_db.get(int(k), point_db) for k in kh])
            rr = np.maximum(rh, reference_range_m) / reference_range_m
            loss = spreading_db_per_decade * np.log10(rr) + 2.0 * absorption_db_per_m * rh
            p = beam[hit] * cos_i**2 * 10.0 ** ((ts - loss) / 10.0)
            power = _deposit(ranges, rh, lo, hi, sigma) @ p
        if speckle > 0:
            power = power * ((1.0 - speckle) + speckle * rng.exponential(1.0, n))
        if noise_power > 0:
            power = power + noise_power * rng.exponential(1.0, n)
        with np.errstate(divide="ignore"):
            level = 10.0 * np.log10(power)
        return np.clip(1.0 + level / RECEIVER_RANGE_DB, 0.0, 1.0)

    return echo


def make_emulator(ctx: SimContext, settings: DeviceSettings) -> PolledEmulator:
    """The simulator's Tritech head (the registry's emulator of ``seanet``): a :class:`MsisHead`
    with :func:`make_echo` on the world's ray caster, host-polled on a pty.

    Options: ``baud`` (115200), ``beam_width_deg`` (3), ``noise_floor`` (0.1), ``speckle``
    (1), ``mount_offset_deg`` (0), ``inverted`` (false), ``alive_period_s`` (1),
    ``tick_hz`` (20: how often the head's own clock is served), ``ping_delay`` (true: a
    HeadData reply leaves after the ping's duration); gateway polling keys (``range_m``,
    ``gain``, ``step_deg``, ``left_limit_deg``, ``right_limit_deg``, ``continuous``,
    ``n_bins``, ``adc8``, ``reply_timeout_s``) go to the gateway configuration's ``msis`` table.
    """

    def opt(key: str, default: Any) -> Any:
        return device_option(settings, "msis", key, default)

    pose_time = [0.0]

    def pose() -> tuple[float, float, float]:
        return ctx.truth.at(pose_time[0]).pose

    echo = make_echo(
        ctx.world,
        pose,
        ctx.rng("msis/echo"),
        beam_width_deg=opt("beam_width_deg", 3.0),
        noise_floor=opt("noise_floor", 0.1),
        speckle=opt("speckle", 1.0),
        mount_offset=math.radians(opt("mount_offset_deg", 0.0)),
        inverted=opt("inverted", False),
    )
    head = MsisHead(
        echo, sound_speed=ctx.world.sound_speed, alive_period_s=opt("alive_period_s", 1.0)
    )
    polling = {k: v for k, v in settings.options.items() if k in MsisPolling.model_fields}
    em = PolledEmulator(
        ctx,
        settings,
        head,
        kind="msis",
        fmt="seanet",
        framer=sn.SeaNetFramer,
        baud=opt("baud", 115200),
        rate_hz=opt("tick_hz", 20.0),
        extra={"msis": polling} if polling else None,
        reply_delay=head.ping_duration_s if opt("ping_delay", True) else None,
    )
    em.before_feed = lambda t: pose_time.__setitem__(0, t)
    return em
