"""The host side of the SeaNet exchange: the gateway's polling driver for a Tritech MSIS head.

A Tritech imaging head is polled: it sends nothing but mtAlive until the host asks for a ping.
:class:`SeaNetHost` drives that exchange for the gateway (the ``HostDriver`` protocol of
:mod:`auvgw.hostdrivers`). It never touches a port or a clock: the gateway calls
:meth:`~SeaNetHost.on_connect`, :meth:`~SeaNetHost.on_message` for every decoded message and
:meth:`~SeaNetHost.on_idle` after every read, handing it ``write`` (bytes to the head) and
``now`` (``time.monotonic()`` seconds), so the whole state machine runs in tests by feeding
messages and times.

The sequence (states in capitals)::

    on_connect            [mtReBoot if reboot_on_connect]            -> WAIT_ALIVE
    WAIT_ALIVE   mtAlive, or alive_timeout_s without one: mtSendVersion -> WAIT_VERSION
    WAIT_VERSION mtVersionData: mtHeadCommand                      -> CONFIGURING
    CONFIGURING  mtAlive with parameters (not NO_PARAMS, motor on): mtSendData -> PINGING
    PINGING      mtHeadData: mtSendData (exactly one request outstanding)
                 mtHeadData with motor error / power loss: mtHeadCommand -> CONFIGURING
                 mtAlive saying NO_PARAMS (the head reset): mtSendVersion -> WAIT_VERSION

Timeouts: no answer within ``reply_timeout_s`` (mtVersionData, mtHeadData) or
``alive_timeout_s`` (the configured mtAlive, which a head sends after re-centring) re-sends the
request; ``max_timeouts`` in a row restart the sequence with mtReBoot (head rebooted, replugged
or wedged) -> WAIT_ALIVE. Messages from other nodes (the host's own echo on a 2-wire RS-485
line, other devices) are ignored.

A reply later than ``reply_timeout_s`` arriving after the re-send cannot be told from the
re-send's own reply (mtHeadData carries no sequence number); the head then holds one extra
mtSendData and answers it in turn, which changes nothing but the count of ``replies``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from enum import StrEnum
from typing import Any

from auvgw.config.gateway import DeviceConfig, MsisPolling
from auvgw.drivers.seanet import codec as sn

__all__ = [
    "HostState", "SeaNetHost", "SeaNetHostStats", "command_from_config", "from_config", "ms_of_day",
]  # fmt: skip

Write = Callable[[bytes], None]


class HostState(StrEnum):
    """Where the host is in the exchange."""

    IDLE = "idle"  # not connected
    WAIT_ALIVE = "wait_alive"  # waiting for the head's first mtAlive
    WAIT_VERSION = "wait_version"  # mtSendVersion sent
    CONFIGURING = "configuring"  # mtHeadCommand sent, waiting for mtAlive with parameters
    PINGING = "pinging"  # one mtSendData outstanding at a time


@dataclass
class SeaNetHostStats:
    """Counters since the host driver was made (all connections)."""

    pings_requested: int = 0  # mtSendData sent (re-sends included)
    replies: int = 0  # mtHeadData received while pinging
    timeouts: int = 0  # requests not answered in time
    resends: int = 0  # requests sent again after a timeout
    restarts: int = 0  # sequence restarted (max_timeouts, or the head lost its parameters)
    reconfigures: int = 0  # mtHeadCommand sent again after a head status error
    configured: int = 0  # times the head reported parameters and pinging started
    alives: int = 0  # mtAlive received
    versions: int = 0  # mtVersionData received
    unsolicited: int = 0  # mtHeadData received when none was asked for

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def ms_of_day(_now: float) -> int:
    """Wall-clock time of day, ms since UTC midnight (what mtSendData carries)."""
    return int(time.time() * 1000.0) % 86_400_000


def command_from_config(
    cfg: MsisPolling, *, sound_speed: float = 1500.0, node: int = sn.HEAD_NODE
) -> sn.HeadCommand:
    """The mtHeadCommand for a gateway's :class:`MsisPolling` settings (degrees -> wire units).

    ``range_m`` over ``n_bins`` at ``sound_speed`` (m/s) sets ADInterval; 4-bit bins need an
    even count, so ``n_bins`` is rounded up to even when ``adc8`` is off. Left and right limits
    are degrees clockwise from the head's forward mark (360 = 0); ``step_deg`` is rounded to
    the 1/16 gradian wire unit (0.05625 deg), at least one unit.
    """
    n_bins = cfg.n_bins if cfg.adc8 else cfg.n_bins + (cfg.n_bins & 1)
    step_units = min(255, max(1, round(cfg.step_deg / 360.0 * sn.ANGLE_UNITS_PER_TURN)))
    return sn.head_command(
        range_m=cfg.range_m,
        n_bins=n_bins,
        sound_speed=sound_speed,
        adc8on=cfg.adc8,
        continuous=cfg.continuous,
        scan_right=True,
        left_limit=math.radians(cfg.left_limit_deg),
        right_limit=math.radians(cfg.right_limit_deg),
        step=step_units * sn.RAD_PER_ANGLE_UNIT,
        gain=cfg.gain,
        rx=node,
    )


class SeaNetHost:
    """Polls one Tritech head over SeaNet (see the module doc for the sequence).

    ``cfg``: the device's :class:`MsisPolling` (range, gain, step, limits in degrees, bins,
    ``reply_timeout_s``). ``sound_speed`` (m/s) sets ADInterval. ``alive_timeout_s`` bounds the
    waits for an mtAlive (heads send one about every second). ``time_ms(now)`` gives the time
    of day in ms that mtSendData carries (default: the wall clock). ``node`` is the head's node.
    """

    def __init__(
        self,
        cfg: MsisPolling | None = None,
        *,
        sound_speed: float = 1500.0,
        alive_timeout_s: float = 3.0,
        max_timeouts: int = 3,
        reboot_on_connect: bool = False,
        time_ms: Callable[[float], int] = ms_of_day,
        node: int = sn.HEAD_NODE,
    ) -> None:
        self.cfg = cfg if cfg is not None else MsisPolling()
        if max_timeouts < 1:
            raise ValueError(f"max_timeouts must be >= 1, got {max_timeouts}")
        self.node = node
        self.reply_timeout_s = self.cfg.reply_timeout_s
        self.alive_timeout_s = alive_timeout_s
        self.max_timeouts = max_timeouts
        self.reboot_on_connect = reboot_on_connect
        self.time_ms = time_ms
        self.command = command_from_config(self.cfg, sound_speed=sound_speed, node=node)
        self._packets = {
            "reboot": sn.encode(sn.reboot(rx=node)),
            "send_version": sn.encode(sn.send_version(rx=node)),
            "head_command": sn.encode(self.command),
        }
        self.stats = SeaNetHostStats()
        self.state = HostState.IDLE
        self.version: sn.VersionData | None = None
        self.last_alive: sn.Alive | None = None
        self.last_reply_at: float | None = None
        self._deadline = math.inf
        self._misses = 0  # consecutive timeouts

    # -- HostDriver protocol ------------------------------------------------------------------
    def on_connect(self, write: Write, now: float) -> None:
        """The port has just been (re)opened: start from the beginning."""
        self._misses = 0
        if self.reboot_on_connect:
            write(self._packets["reboot"])
        self._enter(HostState.WAIT_ALIVE, now + self.alive_timeout_s)

    def on_message(self, msg: Any, write: Write, now: float) -> None:
        """A message decoded from the line; only the head's own messages count."""
        if getattr(msg, "tx_node", None) != self.node:
            return
        if isinstance(msg, sn.HeadData):
            self._on_head_data(msg, write, now)
        elif isinstance(msg, sn.Alive):
            self._on_alive(msg, write, now)
        elif isinstance(msg, sn.VersionData):
            self.stats.versions += 1
            self.version = msg
            if self.state is HostState.WAIT_VERSION:
                self._misses = 0
                self._configure(write, now)

    def on_idle(self, write: Write, now: float) -> None:
        """Called after every read: handle an expired wait."""
        if now < self._deadline:
            return
        st = self.state
        if st is HostState.WAIT_ALIVE:  # no mtAlive: the head may be up already; go on
            self._send_version(write, now)
            return
        if st is HostState.IDLE:
            return
        self.stats.timeouts += 1
        self._misses += 1
        if self._misses >= self.max_timeouts:
            self._restart(write, now)
            return
        self.stats.resends += 1
        if st is HostState.WAIT_VERSION:
            self._send_version(write, now)
        elif st is HostState.CONFIGURING:
            self._configure(write, now)
        else:
            self._ping(write, now)

    # -- status -------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """JSON-ready status: state, counters, head clock and parameters (SI units)."""
        out: dict[str, Any] = {"state": self.state.value, **self.stats.as_dict()}
        if self.last_alive is not None:
            out["head_time_s"] = self.last_alive.head_time
            out["head_inf"] = self.last_alive.head_inf
        if self.version is not None:
            out["serial_number"] = self.version.serial_number
            out["software_version"] = self.version.software_version
        cmd = self.command
        out["range_m"] = cmd.range_m
        out["n_bins"] = cmd.n_bins
        out["step_rad"] = cmd.step
        return out

    # -- transitions --------------------------------------------------------------------------
    def _enter(self, state: HostState, deadline: float) -> None:
        self.state = state
        self._deadline = deadline

    def _send_version(self, write: Write, now: float) -> None:
        write(self._packets["send_version"])
        self._enter(HostState.WAIT_VERSION, now + self.reply_timeout_s)

    def _configure(self, write: Write, now: float) -> None:
        write(self._packets["head_command"])
        self._enter(HostState.CONFIGURING, now + self.alive_timeout_s)

    def _ping(self, write: Write, now: float) -> None:
        write(sn.encode(sn.send_data(self.time_ms(now), rx=self.node)))
        self.stats.pings_requested += 1
        self._enter(HostState.PINGING, now + self.reply_timeout_s)

    def _restart(self, write: Write, now: float) -> None:
        """Too many timeouts: reset the head and wait for its mtAlive."""
        self.stats.restarts += 1
        self._misses = 0
        write(self._packets["reboot"])
        self._enter(HostState.WAIT_ALIVE, now + self.alive_timeout_s)

    def _on_alive(self, msg: sn.Alive, write: Write, now: float) -> None:
        self.stats.alives += 1
        self.last_alive = msg
        st = self.state
        if st is HostState.WAIT_ALIVE:
            self._misses = 0
            self._send_version(write, now)
        elif st is HostState.CONFIGURING and msg.ready:
            self._misses = 0
            self.stats.configured += 1
            self._ping(write, now)
        elif st is HostState.PINGING and msg.no_params:
            # the head has reset (power glitch, watchdog): configure it again
            self.stats.restarts += 1
            self._misses = 0
            self._send_version(write, now)

    def _on_head_data(self, msg: sn.HeadData, write: Write, now: float) -> None:
        if self.state is not HostState.PINGING:
            self.stats.unsolicited += 1
            return
        self.stats.replies += 1
        self.last_reply_at = now
        self._misses = 0
        if msg.head_status & (sn.HeadStatus.MOTOR_ERROR | sn.HeadStatus.HEAD_POWER_LOSS):
            self.stats.reconfigures += 1
            self._configure(write, now)
            return
        self._ping(write, now)


def from_config(cfg: DeviceConfig) -> SeaNetHost:
    """The gateway's host driver of a ``seanet`` device (the registry's ``host_driver``): polled
    with the device's ``msis`` table (defaults when absent)."""
    return SeaNetHost(cfg.msis or MsisPolling())
