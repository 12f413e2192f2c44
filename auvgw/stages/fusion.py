"""The fusion stage: the gateway's decoded attitude and DVL messages in, odometry out.

Online it subscribes to the kinds it reads, ``auv/<v>/sensor/*/<kind>`` for every kind of the
registry's ``attitude`` and ``velocity`` roles (``ins``: HN-100 on serial or CAN; a DVL's ``sa``
/ ``ensemble`` compass; ``ensemble`` PD0, ``bi`` / ``bs`` / ``be`` PD6), so a multibeam's pings
never reach its process; its callbacks run in Zenoh's receiving thread, so the samples of all
these subscriptions are queued in their arrival order. It keeps the attitude kinds of the
configured ``attitude`` device and the velocity kinds of the configured ``velocity`` device
(never "the first seen": :class:`~auvgw.fusion.adapters.MessageAdapter`), rebuilds the typed
messages from the envelopes (:func:`auvgw.drivers.spec.from_jsonable`, the values the gateway
decoded), maps each device's clock onto the host clock, feeds a
:class:`~auvgw.fusion.NavFilter`, and publishes one :class:`~auvgw.fusion.Odometry` envelope per
INS sample on ``auv/<v>/nav/odometry`` (``CongestionControl.DROP``: a slow subscriber never
stalls the stage). Its counters go to ``auv/<v>/status/fusion`` (published every
``status_period_s`` and answered as a query); the liveliness token ``auv/<v>/alive/fusion`` is
declared once its subscriptions are.

In-process (``auvgw demo``, tests, offline recordings) the same object is fed directly with
:meth:`FusionStage.feed` ``(device, t_recv_ns, message)`` (the gateway's ``on_message``
signature); with no session it publishes nothing and returns the odometry it produced.

Zenoh callbacks only queue the payloads; one worker thread decodes and filters them in arrival
order, so the callbacks stay short and the filter sees one sequence of messages.

Odometry times are the clock of the gateway's receive stamps (POSIX s: the host clock, or the
vehicle-paced clock of a gateway ``[clock]`` section, docs/gateway.md): INS time stamps mapped
through the INS clock's offset (:class:`~auvgw.fusion.adapters.DeviceClock`), so an odometry
sample's ``t`` is when the INS measured it, not when it was received. The stage never reads the
host clock for data: an odometry envelope's ``t_recv_ns`` is the receive stamp of the input
message that released it, so the stage runs the same at any emulation speed (status
publication and the counters' ``t_ns`` are host-clock health).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import cast

import zenoh
from pydantic import AliasChoices, ConfigDict, Field

from auvgw.bus import encode_envelope
from auvgw.fusion import FusionConfig, NavFilter, Odometry
from auvgw.fusion.adapters import ATTITUDE_TYPES, VELOCITY_TYPES, MessageAdapter
from auvgw.ground.errors import ConfigError, load_settings
from auvgw.stages.base import BusCounters, Stage, StageConfig

log = logging.getLogger(__name__)

__all__ = [
    "COMPONENT",
    "FusionStage",
    "FusionStageConfig",
    "SettingsError",
    "StageStats",
    "load_stage_config",
    "sensor_kinds",
]

#: the stage's component name (status, liveliness, envelope device)
COMPONENT = "fusion"


def sensor_kinds(type_names: frozenset[str]) -> list[str]:
    """The ``<kind>`` key segments of message type names, as the gateway builds them
    (:func:`auvgw.decoding.kind_of`: ``Hn100Nav`` -> ``ins``, ``pd0.Ensemble`` -> ``ensemble``)."""
    from auvgw.decoding import kind_of

    return sorted({kind_of(t) for t in type_names})


class SettingsError(ConfigError):
    """A fusion settings file that cannot be used (names the file and the field)."""


class FusionStageConfig(StageConfig):
    """Settings of the fusion stage (TOML: top-level keys, the filter under ``[filter]``).

    ``attitude`` / ``velocity`` (also spelled ``ins_device`` / ``dvl_device``): the gateway
    device names of the attitude source (an INS, or a DVL's compass) and of the velocity source
    (a PD0 or PD6 DVL), default ``"ins"`` and ``"dvl"``; never "the first seen", so live, replay
    and offline choose the same sources. ``latency_s``: per device, the fixed delay between the
    device's time stamp and the host's receive time (e.g. the frame's transmission time, bytes x
    10 / baud), subtracted when mapping its clock. ``clock_skew`` (s/s) and ``clock_jump_s``:
    see :class:`~auvgw.fusion.adapters.DeviceClock`. ``clock_warmup_s``: each device's samples
    are held for this long (s of receive time) while its clock offset is learnt, so the late
    first frames after a port opens do not cost motion (0: off; the demo uses 2 s; the held
    samples are processed and published in one burst at the window's end; see
    :meth:`~auvgw.fusion.adapters.MessageAdapter.adapt_all`). ``require_aligned``: drop INS
    solutions flagged not aligned or in error. ``high_res``: prefer the PD0 0x5803 velocity.
    """

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    ins_device: str = Field("ins", validation_alias=AliasChoices("attitude", "ins_device"))
    dvl_device: str = Field("dvl", validation_alias=AliasChoices("velocity", "dvl_device"))
    latency_s: dict[str, float] = Field(default_factory=dict)
    clock_skew: float = Field(1e-4, ge=0)
    clock_jump_s: float = Field(1.0, gt=0)
    clock_warmup_s: float = Field(0.0, ge=0, le=60)
    require_aligned: bool = True
    high_res: bool = True
    filter: FusionConfig = FusionConfig()


def load_stage_config(path: str | Path) -> FusionStageConfig:
    """Read a TOML (or JSON) settings file, its keys at the top level or under ``[fusion]`` (a
    larger vehicle file); :class:`SettingsError` names the file and field."""
    return load_settings(path, FusionStageConfig, SettingsError, table="fusion")


@dataclass
class StageStats(BusCounters):
    """Counters of the stage (``received``: messages fed, on the bus or in-process)."""

    published: int = 0  #: odometry samples produced (published when on the bus)
    #: samples the subscriptions delivered to this process (before the key filter, :meth:`wanted`)
    delivered: int = 0


class FusionStage(Stage):
    """INS + DVL messages -> :class:`Odometry` (see the module docstring).

    ``session``: publish odometry and status on it (None: in-process only). ``on_odometry``:
    called with every odometry sample produced (on the feeding thread).
    """

    name = COMPONENT
    status_schema = "FusionStatus"
    outputs = ("odometry",)
    stats: StageStats

    def __init__(
        self,
        config: FusionStageConfig | None = None,
        session: zenoh.Session | None = None,
        on_odometry: Callable[[Odometry], object] | None = None,
    ) -> None:
        self.config = cfg = config or FusionStageConfig()
        super().__init__(cfg, StageStats(), session)
        self.adapter = MessageAdapter(
            ins_device=cfg.ins_device,
            dvl_device=cfg.dvl_device,
            latency_s=cfg.latency_s,
            clock={"skew": cfg.clock_skew, "jump_s": cfg.clock_jump_s},
            require_aligned=cfg.require_aligned,
            high_res=cfg.high_res,
            warmup_s=cfg.clock_warmup_s,
        )
        self.nav = NavFilter(cfg.filter)
        self.on_odometry = on_odometry
        self.last: Odometry | None = None
        self._now_ns = 0  # latest input receive stamp, ns (the stage's "now")
        self._ins_kinds = frozenset(sensor_kinds(ATTITUDE_TYPES))
        self._dvl_kinds = frozenset(sensor_kinds(VELOCITY_TYPES))
        self._warned: set[str] = set()
        _register_can_types()

    def key(self, what: str) -> str:
        """``auv/<v>/nav/odometry`` (the one output)."""
        return self.keys.odometry()

    # -- in-process use -----------------------------------------------------------------------
    def feed(self, device: str, t_recv_ns: int, message: object) -> list[Odometry]:
        """One decoded message of ``device`` received at ``t_recv_ns`` (host ns since the Unix
        epoch); returns (and publishes, with a session) the odometry that became final."""
        with self._lock:
            self.stats.received += 1
            self._now_ns = max(self._now_ns, t_recv_ns)
            out = []
            for sample in self.adapter.adapt_all(device, t_recv_ns / 1e9, message):
                out += self.nav.push(sample)
            self._emit(out)
            return out

    def flush(self) -> list[Odometry]:
        """Release (and publish) everything the filter still holds (end of data, shutdown)."""
        with self._lock:
            out = []
            for sample in self.adapter.flush():
                out += self.nav.push(sample)
            out += self.nav.flush()
            self._emit(out)
            return out

    def _emit(self, out: list[Odometry]) -> None:
        for o in out:
            self.stats.published += 1
            self.last = o
            if self._pubs:
                t_ns = self._now_ns or time.time_ns()  # the stamp clock; host before any input
                payload, enc = encode_envelope(o, COMPONENT, t_ns, self.stats.published)
                self.publish("odometry", payload, enc, t_ns)
            if self.on_odometry is not None:
                self.on_odometry(o)

    def status_fields(self) -> dict[str, object]:
        """Adapter, device clocks, filter, reorder buffer, diagnostics and the last sample;
        ``t_stamp_ns``: the newest input's receive stamp (the stamp clock, vehicle-paced under a
        gateway ``[clock]``; None before any input), the time a viewer puts the status at, as
        a device's, rather than the host time of its sending (issue 33)."""
        a = self.adapter
        last = self.last
        return {
            "t_stamp_ns": self._now_ns or None,
            "adapter": asdict(a.stats),
            "ins_device": a.ins_device,
            "dvl_device": a.dvl_device,
            "clocks": {d: {"offset_s": c.offset, **asdict(c.stats)} for d, c in a.clocks.items()},
            "filter": asdict(self.nav.stats),
            "buffer": asdict(self.nav.buffer_stats),
            "diagnostics": self.nav.diagnostics.summary(),
            "last": None
            if last is None
            else {
                "t": last.t,
                "x": last.x,
                "y": last.y,
                "z": last.z,
                "heading": last.heading,
                "sigma_xy_m": float(last.cov_xy.trace()) ** 0.5,
                "bottom_lock": last.bottom_lock,
                "coasting": last.coasting,
            },
        }

    # -- on the bus ---------------------------------------------------------------------------
    def subscription_keys(self) -> list[str]:
        """The key expressions the stage subscribes to: ``auv/<v>/sensor/*/<kind>`` for each
        kind of the registry's attitude and velocity message types (by role, any device: a
        multibeam's or a sonar's messages never reach the stage's process).

        Several subscriptions keep one arrival order because :meth:`subscribe` runs their
        callbacks in Zenoh's receiving thread (the filter's fixed lag only absorbs so much
        reordering). The callback keeps the configured devices' ones (:meth:`wanted`) before
        anything is parsed.
        """
        return [self.keys.sensor("*", kind) for kind in sorted(self._ins_kinds | self._dvl_kinds)]

    def source_keys(self) -> list[str]:
        """``auv/<v>/sensor/<device>/*`` of the configured attitude and velocity devices (what
        ``auvgw fusion`` watches for "no publisher")."""
        a = self.adapter
        return list(dict.fromkeys(self.keys.sensor(d, "*") for d in (a.ins_device, a.dvl_device)))

    def wanted(self, key: str) -> bool:
        """Whether a sensor key carries an attitude or velocity message of a configured source
        device."""
        device, _, kind = key.rpartition("/")
        device = device.rpartition("/")[2]
        a = self.adapter
        return (kind in self._ins_kinds and device == a.ins_device) or (
            kind in self._dvl_kinds and device == a.dvl_device
        )

    def input_keys(self) -> list[str]:
        """:meth:`subscription_keys`."""
        return self.subscription_keys()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.stats.delivered += 1  # (only Zenoh's receiving thread writes it)
        super()._on_sample(sample)

    def on_start(self, subscribe: bool) -> None:
        """Log where the stage's input comes from: the bus, or in-process
        (``Gateway(..., on_message=stage.feed)`` in ``auvgw demo``, ``subscribe=False``: it still
        publishes odometry and status on the bus)."""
        keys = ", ".join(self.subscription_keys())
        how = f"subscribed to {keys}" if subscribe else "fed in-process"
        log.info("fusion stage for vehicle %r: %s", self.config.vehicle, how)

    def on_status(self) -> None:
        """With the status: each new kind of diagnostics warning logged once while it lasts."""
        if self._status_pub is None:
            return
        with self._lock:
            active = cast("list[str]", self.nav.diagnostics.summary()["warnings"])
            warnings = {w.split(":", 1)[0]: w for w in active}
        for kind in sorted(warnings.keys() - self._warned):
            log.warning("fusion: %s", warnings[kind])
        self._warned = set(warnings)


def _register_can_types() -> None:
    """Load the shipped HN-100 DBC once so ``HN100_Sample`` envelopes can be rebuilt (a site
    DBC with other signals arrives untyped and is counted as a bad payload)."""
    from auvgw.drivers.spec import MESSAGE_TYPES

    if "HN100_Sample" in MESSAGE_TYPES:
        return
    try:
        from auvgw.drivers.can_codec import hn100_can

        hn100_can()
    except Exception as exc:  # cantools missing or the DBC unreadable: CAN INS unavailable
        log.warning("fusion: HN-100 CAN types not available: %s", exc)
