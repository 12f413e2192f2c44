"""The Rerun bus stage: bus messages in, :class:`~auvgw.viz.logger.RerunLogger` calls out.

Subscribes to ``auv/<v>/{sensor,nav,slam,truth,status}/**`` (raw frames are not needed: the
decoded envelopes carry everything shown) and maps each message to logger calls. Sensor
messages are shown by their device-registry role (:mod:`auvgw.drivers.registry`; the first of
a type's roles that has a view):

============================================  ==================================================
role ``swath`` (Kongsberg XYZ 88, Depth)      swath points + bathymetric grid, placed at the
                                               latest navigation pose (``nav``, else ``truth``)
role ``velocity`` (PD0 ``ensemble``)           DVL velocity (bottom track, vehicle over bottom),
                                               altitude, bottom lock
role ``sonar`` (SeaNet ``mtheaddata``)         MSIS scan line into the sonar fan
role ``samples`` (GeoSwath ``geoswathping``)   the latest raw ping per side (range against
                                               return angle, amplitude), every
                                               ``raw_ping_period_s`` device s
role ``attitude`` (``roll, pitch, heading``)   INS attitude (HN-100 binary or CAN, PD6 ``sa``)
role ``field`` (``bx, by, bz`` in nT)          magnetometer (MS3A ASCII or CAN sample)
role ``range`` (acoustic ``AcousticReply``)    a line from the navigation pose to the fix
``nav/odometry``                               ``dead_reckoning`` trajectory with its covariance
``slam/<p>/pose``                              ``slam/<p>`` trajectory (+ particles if carried)
``slam/<p>/landmarks``, ``slam/<p>/map``       landmarks with covariances, line features
``slam/<p>/cloud``, ``slam/<p>/map`` (DEM)     seabed points, DEM tile (bathymetric SLAM)
``truth/<what>``                               ``truth`` trajectory, true landmarks and lines
``status/<device>``                            per-device health series + connection events
``pilot/state``, ``pilot/command``             the autopilot's set-points and track errors,
                                               its fins and shaft (a control pipeline's
                                               outputs, by their registry views)
============================================  ==================================================

Messages of other types are skipped and counted per type (:attr:`StageStats.unknown`); a
message that fails to map is counted (:attr:`StageStats.errors`) and never stops the stage.
The JSON accepted on ``slam/``, ``truth/`` and ``nav/`` is documented in ``docs/viz.md``.

Time: each message goes on ``sensor_time`` at its device time where the wire carries a UTC
clock that agrees with the host (Kongsberg, PD0), else at the device time mapped onto the host
clock (:func:`host_clock`: INS time since power-up, simulation time, an emulator's epoch),
else at the gateway's receive time.

The Zenoh callback only copies the payload into a bounded queue (dropping with a counter when
full); a stage thread does the JSON decoding and mapping.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sized
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, SupportsFloat, TypeVar, cast

import numpy as np
import zenoh

from auvgw.bus import SCHEMA_VERSION, Keys, decode_envelope
from auvgw.drivers.roles import Attitude, Field, Range
from auvgw.drivers.spec import from_jsonable, resolve_type
from auvgw.ground.devicetime import DeviceClock
from auvgw.slam import pipelines
from auvgw.stages.base import BusCounters, Stage, StageConfig
from auvgw.subscribe import slam_output
from auvgw.viz.logger import RerunLogger, VizOptions

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from auvgw.drivers.geoswath import GeoSwathPing
    from auvgw.drivers.pd0 import Ensemble

__all__ = ["SECTIONS", "StageStats", "VizRunner", "VizStage", "host_clock", "open_viz"]

log = logging.getLogger(__name__)

#: bus sections the stage subscribes to: its own and each control pipeline's (``pilot``: the
#: pipeline registry's records that are not SLAM, :func:`auvgw.slam.pipelines.sections`)
SECTIONS: tuple[str, ...] = ("sensor", "nav", "slam", "truth", "status", *pipelines.sections())

#: sensor message types that carry nothing to show (replies, configuration, raw blocks)
IGNORED_TYPES = frozenset(
    {
        "mtAlive", "mtVersionData", "mtSendData", "mtHeadCommand", "mtReBoot", "mtSendVersion",
        "mtSendBBUser", "SeaNetRaw", "KongsbergDatagram", "pd0.RawBlock", "MotionIncrement",
    }
)  # fmt: skip

#: registry roles whose handlers need the typed message (rebuilt from JSON with the codec's
#: class, its module imported lazily so a missing or broken codec only loses its own messages);
#: the other roles' handlers read plain fields
_TYPED_ROLES = ("swath", "velocity", "sonar", "samples")


class _Obj:
    """Attribute access to a JSON object (for messages without a registered class)."""

    __slots__ = ("_d",)

    def __init__(self, d: Mapping[str, object]) -> None:
        self._d = d

    def __getattr__(self, name: str) -> object:
        try:
            return self._d[name]
        except KeyError:
            raise AttributeError(name) from None


class _Swath(Protocol):
    """Role ``swath`` (Kongsberg XYZ 88, Depth): per-beam ``xyz`` (along, across, depth m from
    the transducer) and the ``beams`` table (its ``valid`` flags, else non-zero ``depth``)."""

    @property
    def xyz(self) -> ArrayLike: ...
    @property
    def beams(self) -> object: ...


class _SonarPing(Protocol):
    """Role ``sonar`` (SeaNet ``mtHeadData``): one scan line: ``bearing`` (rad, clockwise from
    forward), ``bins`` (near to far), ``range_m``, head ``step`` (rad), 8-bit data or 4-bit."""

    @property
    def bearing(self) -> float: ...
    @property
    def bins(self) -> ArrayLike: ...
    @property
    def range_m(self) -> float: ...
    @property
    def step(self) -> float: ...
    @property
    def adc8on(self) -> bool: ...


_T = TypeVar("_T")


def _mapping(v: object, what: str) -> Mapping[str, object]:
    """``v`` as a JSON object (TypeError naming ``what`` otherwise)."""
    if not isinstance(v, Mapping):
        raise TypeError(f"{what}: a JSON object expected, not {type(v).__name__}")
    return v


def _array(v: object) -> np.ndarray | None:
    """A JSON array (or None) as a float64 array."""
    return None if v is None else np.asarray(v, dtype=np.float64)


def host_clock(jump_s: float = 1.0, sync_s: float = 60.0) -> DeviceClock:
    """One source's device clock (s) onto the host clock (POSIX s), for display.

    A UTC clock that agrees with the host within ``sync_s`` (a GPS-disciplined sonar, a DVL
    set at dive start) passes through. Any other clock (time since power-up, simulation time,
    an RTC set to another epoch) gets the smallest host-minus-device offset seen so far (the
    least delayed sample), re-anchored at once when the offset grows by more than ``jump_s``
    (clock reset or jump): the samples keep the device's own spacing on the host's time line.
    """
    return DeviceClock(
        skew=0.0, jump_s=jump_s, confirm=1, confirm_s=0.0, lag_confirm_s=0.0, sync_s=sync_s
    )


@dataclass
class StageStats(BusCounters):
    """Counters: samples received, dropped (``queue_dropped``: queue full), mapped to the
    logger, skipped as uninteresting (``ignored``), unknown types (per type) and mapping errors
    (``errors``: a payload that cannot be decoded is one; ``bad_payloads`` stays 0)."""

    logged: int = 0
    ignored: int = 0
    errors: int = 0
    unknown: Counter[str] = field(default_factory=Counter)
    last_error: str = ""

    @property
    def dropped(self) -> int:
        """Samples dropped because the queue was full."""
        return self.queue_dropped


def _float(v: object, default: float = math.nan) -> float:
    """``v`` as a float (a number or a numeric string), else ``default``."""
    if type(v) is float:  # most fields (this runs per field: no Protocol isinstance)
        return v
    if v is None:
        return default
    try:  # float() raises TypeError for what is neither
        return float(cast(SupportsFloat, v))
    except (TypeError, ValueError):
        return default


def _get(obj: object, *names: str) -> object:
    """First attribute or key of ``obj`` among ``names`` (None if none)."""
    for n in names:
        v = obj.get(n) if isinstance(obj, Mapping) else getattr(obj, n, None)
        if v is not None:
            return v
    return None


def _numeric_leaves(body: Mapping[str, object], limit: int = 16) -> dict[str, float]:
    """Numbers of a status object, nested objects flattened as ``a.b`` (two levels), at most
    ``limit``; the schema version and times in ns are left out."""
    out: dict[str, float] = {}

    def walk(obj: Mapping[str, object], prefix: str, depth: int) -> None:
        for k, v in obj.items():
            if len(out) >= limit:
                return
            name = f"{prefix}{k}"
            if isinstance(v, bool | int | float) and k != "v" and not k.endswith("_ns"):
                out[name] = float(v)
            elif isinstance(v, Mapping) and depth < 2:
                walk(v, f"{name}.", depth + 1)

    walk(body, "", 1)
    return out


def _items(value: object, what: str) -> list[object]:
    """A JSON array (None: empty) as a list (TypeError naming ``what`` otherwise)."""
    if not value:
        return []
    if not isinstance(value, Iterable):
        raise TypeError(f"{what}: an array expected, not {type(value).__name__}")
    return list(value)


def _points(value: object) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (L, 2) and ids from a list of [x, y] / {"x", "y", "id"} / an (L, 2) array."""
    if isinstance(value, Mapping):
        value = value.get("mean", value.get("points"))
    items = _items(value, "points")
    if items and isinstance(items[0], Mapping):
        objs = [_mapping(p, "point") for p in items]
        xy = np.array([[_float(p.get("x")), _float(p.get("y"))] for p in objs])
        ids = [p.get("id") for p in objs]
        return xy.reshape(-1, 2), (None if any(i is None for i in ids) else np.array(ids))
    return np.asarray(items, dtype=np.float64).reshape(-1, 2), None


def _lines(value: object) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(rho, theta, cov, endpoints) from a list of {"rho", "theta", "cov"?, "p0"?, "p1"?} or
    [rho, theta] pairs, or {"rho": [...], "theta": [...], "cov": [...], "p0"?: [...], "p1"?:
    [...]} (a :class:`~auvgw.slam.outputs.LineSet`)."""
    if isinstance(value, Mapping):
        rho = np.asarray(value.get("rho", []), dtype=np.float64).reshape(-1)
        theta = np.asarray(value.get("theta", []), dtype=np.float64).reshape(-1)
        cov = value.get("cov")
        c = None if cov is None else np.asarray(cov, dtype=np.float64).reshape(-1, 2, 2)
        p0, p1 = value.get("p0"), value.get("p1")
        e = None
        if isinstance(p0, Sized) and isinstance(p1, Sized) and len(p0) == len(p1) == len(rho):
            e = np.stack([np.asarray(p0, np.float64).reshape(-1, 2),
                          np.asarray(p1, np.float64).reshape(-1, 2)], axis=1)  # fmt: skip
        return rho, theta, c, e
    items = _items(value, "lines")
    if items and isinstance(items[0], Mapping):
        objs = [_mapping(v, "line") for v in items]
        rho = np.array([_float(v.get("rho")) for v in objs])
        theta = np.array([_float(v.get("theta")) for v in objs])
        covs = [v.get("cov") for v in objs]
        c = None if any(x is None for x in covs) else np.asarray(covs, dtype=np.float64)
        ends = [(v.get("p0"), v.get("p1")) for v in objs]
        e = None
        if all(a is not None and b is not None for a, b in ends):
            e = np.asarray(ends, dtype=np.float64).reshape(-1, 2, 2)
        return rho, theta, None if c is None else c.reshape(-1, 2, 2), e
    arr = np.asarray(items, dtype=np.float64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1], None, None


class VizStage(Stage):
    """Maps the bus of one vehicle to a :class:`RerunLogger` (see the module docstring).

    :meth:`attach` subscribes on a Zenoh session and :meth:`Stage.start` ``(subscribe=False)``
    runs the mapping thread (the stage declares nothing else: no outputs, no status on the bus);
    :meth:`Stage.stop` maps what is queued (the logger stays open: close it afterwards);
    :meth:`handle_sample` maps one payload synchronously (tests, replay) and
    :meth:`on_message` one typed message (in-process, e.g. ``Gateway(on_message=...)``). Its
    own health (every ``health_period_s`` and at :meth:`stop`) goes to the logger, not the bus.
    """

    name = "viz"
    stats: StageStats

    def __init__(
        self,
        logger: RerunLogger,
        vehicle: str = "auv1",
        *,
        root: str = "auv",
        queue_size: int = 20_000,
        health_period_s: float = 1.0,
    ) -> None:
        cfg = StageConfig(vehicle=vehicle, status_period_s=health_period_s, queue_size=queue_size)
        super().__init__(cfg, StageStats(), keys=Keys(vehicle, root))
        self.logger = logger
        self.sections: tuple[str, ...] = SECTIONS
        self._map_lock = threading.Lock()  # mapping state (clocks, poses): bus and in-process
        self._clocks: dict[str, DeviceClock] = {}
        self._nav: tuple[float, float, float, float] | None = None
        self._truth: tuple[float, float, float, float] | None = None
        self._acoustic: dict[str, tuple[float, float]] = {}  # acoustic beacon logged, per map
        #: magnetic-beacon ranges of the latest window, per map: (t, beacon positions)
        self._ranges: dict[str, tuple[float, list[tuple[float, float]]]] = {}
        self._status: dict[str, tuple[object, object]] = {}  # (connected, last error)
        self._warnings: dict[str, tuple[str, ...]] = {}  # a fusion's diagnostics warnings
        self._modes: dict[str, str] = {}  # each control pipeline's mode last shown
        self._losses: dict[str, dict[str, float]] = {}  # the loss counters seen, per device
        self._t_last = 0.0  # the newest data time (sensor, odometry stamps), s; never goes back
        self._raw_ping_t: dict[tuple[str, int], float] = {}  # raw ping shown last, per side
        #: device registry role -> handler; a message type is shown by the first of its roles
        #: that has one (registry.MessageType.roles)
        self._role_handlers: dict[str, Callable[[str, object, float], bool]] = {
            "swath": self._swath,
            "samples": self._raw_ping,
            "velocity": self._dvl,
            "sonar": self._msis,
            "attitude": self._attitude,
            "field": self._field,
            "range": self._acoustic_fix,
        }
        self._classes: dict[str, type] = {}
        self._load_codecs()

    def _load_codecs(self) -> None:
        import importlib

        from auvgw.drivers import registry

        for dev, m in registry.message_types():
            if m.wire != "stream" or not set(m.roles) & set(_TYPED_ROLES) or dev.codec is None:
                continue
            name = dev.codec.partition(":")[0]
            try:
                importlib.import_module(name)
            except Exception as exc:  # a codec being written must not stop the stage
                log.warning("viz stage: %s unavailable (%s); its messages are skipped", name, exc)
            if (cls := resolve_type(m.type)) is not None:
                self._classes[m.type] = cls

    # -- bus side --------------------------------------------------------------------------
    def input_keys(self) -> list[str]:
        """``auv/<v>/<section>/**`` of each attached section."""
        return [self.keys.all(f"{section}/**") for section in self.sections]

    def attach(self, session: zenoh.Session, sections: Iterable[str] = SECTIONS) -> None:
        """Subscribe to this vehicle's ``sections`` on ``session`` (the mapping thread is the
        base's worker: :meth:`Stage.start` ``(subscribe=False)`` starts it; not started,
        :meth:`Stage.stop` maps what is queued on the calling thread)."""
        self.session = session
        self.sections = tuple(sections)
        self.subscribe()

    def on_status(self) -> None:
        """The stage's own health into the logger (once something was mapped), not the bus."""
        if not self._t_last:
            return
        s = self.stats
        self.logger.health(
            "viz",
            self._t_last,
            {
                "stage_dropped": float(s.queue_dropped),
                "unknown": float(sum(s.unknown.values())),
                "errors": float(s.errors),
            },
        )

    # -- mapping ---------------------------------------------------------------------------
    def _clock(self, source: str) -> DeviceClock:
        c = self._clocks.get(source)
        if c is None:
            c = self._clocks[source] = host_clock()
        return c

    def read_payload(self, key: str, payload: bytes, t_arrival_ns: int | None) -> str:
        """Map one bus sample (:meth:`Stage.handle_sample`: envelopes and the JSON sections);
        returns ``logged``, ``ignored``, ``unknown`` or ``error``."""
        with self._lock:
            self.stats.received += 1
        t_host = (t_arrival_ns if t_arrival_ns is not None else time.time_ns()) / 1e9
        try:
            with self._map_lock:
                outcome = self._handle(key, payload, t_host)
        except Exception as exc:
            return self._error(key, exc)
        return self._count(outcome)

    def _error(self, what: str, exc: Exception) -> str:
        with self._lock:
            self.stats.errors += 1
            self.stats.last_error = f"{what}: {type(exc).__name__}: {exc}"
            n = self.stats.errors
        if n <= 5:
            log.warning("viz stage: %s", self.stats.last_error)
        return "error"

    def _count(self, outcome: str) -> str:
        """Count a handler's outcome: ``logged``, ``ignored`` or the reason it is unknown."""
        with self._lock:
            if outcome == "logged":
                self.stats.logged += 1
                return outcome
            if outcome == "ignored":
                self.stats.ignored += 1
                return outcome
            self.stats.unknown[outcome] += 1
        return "unknown"

    def _handle(self, key: str, payload: bytes, t_host: float) -> str:
        split = self.keys.split(key)
        if split is None:
            return "unknown:key"
        section = split[0]
        parts = [section, *split[1].split("/")] if split[1] else [section]
        if section in ("sensor", "nav"):  # envelopes (MessagePack; JSON of the previous release)
            env = decode_envelope(payload, key)
            if not self._stamps.accept(env.t_recv_ns):  # a forged time never moves the clock
                return "unknown:stamp"
            if section == "sensor" and env.message is not None:
                t_stamp = env.t_recv_ns / 1e9
                self._t_last = max(self._t_last, t_stamp)
                return self._sensor(env.device, env.type, env.message, t_stamp)
            data: object = {"v": SCHEMA_VERSION, "type": env.type, "device": env.device,
                         "msg": env.body, "t_recv_ns": env.t_recv_ns}  # fmt: skip
        elif section == "slam":  # a declared SLAM output (auvgw.slam.outputs), or JSON
            data = slam_output(payload, key)
        else:
            data = json.loads(payload)
        type_name, device, body = "", parts[1] if len(parts) > 1 else "", data
        if isinstance(data, Mapping) and "msg" in data and "v" in data:
            if data["v"] != SCHEMA_VERSION:
                raise ValueError(f"schema version {data['v']!r}, expected {SCHEMA_VERSION}")
            type_name = str(data.get("type", ""))
            device = str(data.get("device", device))
            body = data["msg"]
            t_host = _float(data.get("t_recv_ns"), t_host * 1e9) / 1e9
        elif isinstance(data, Mapping):
            type_name = str(data.get("type", ""))
        if not isinstance(body, Mapping):
            return f"unknown:{section}"
        if section in ("sensor", "nav"):  # data times only: status and SLAM rows follow them
            self._t_last = max(self._t_last, t_host)
        if section == "sensor":
            return self._sensor_json(device, type_name, body, t_host)
        if section == "nav":
            return self._odometry(body, t_host)
        if section == "slam" and len(parts) >= 3:
            return self._slam(parts[1], parts[2], body, t_host)
        if section == "truth":
            return self._truth_msg(body, t_host)
        if section == "status" and len(parts) >= 2:
            return self._health(parts[1], body, t_host)
        record = pipelines.for_section(section)
        if record is not None and len(parts) >= 2:
            return self._control(record, parts[1], body, t_host)
        return f"unknown:{section}"

    def _control(self, record: pipelines.Pipeline, what: str, body: Mapping[str, object],
                 t_host: float) -> str:  # fmt: skip
        """An output of a control pipeline (``auv/<v>/<name>/<what>``), shown by its view in
        the pipeline registry (``setpoints``, ``commands``), on the odometry's clock."""
        t = _float(body.get("t"), t_host)
        view = record.view_of(what)
        if view == "setpoints":
            self._setpoints(record.name, body, t)
        elif view == "commands":
            self._commands(record.name, body, t)
        else:
            return f"{record.name}:{what}"
        return "logged"

    def _commands(self, name: str, body: Mapping[str, object], t: float) -> None:
        """An actuator command (the pilot's ``command``: ``rpm``, ``rudder``, ``stern`` rad) as
        ``<name>/fins`` (rudder and stern plane, deg) and ``<name>/shaft`` (rpm)
        (:data:`auvgw.viz.entities.PILOT_VIEWS`)."""
        deg = math.degrees
        self.logger.series(f"{name}/fins", t, {
            "rudder_deg": deg(_float(body.get("rudder"))),
            "stern_deg": deg(_float(body.get("stern")))})  # fmt: skip
        self.logger.series(f"{name}/shaft", t, {"rpm": _float(body.get("rpm"))})

    def _setpoints(self, name: str, body: Mapping[str, object], t: float) -> None:
        """An autopilot's state (auvgw.stages.pilot, docs/pilot.md; the pilot's ``state``), one
        unit per view (:data:`auvgw.viz.entities.PILOT_VIEWS`): ``<name>/track`` (cross- and
        along-track error, depth set-point, m), ``<name>/setpoints`` (heading and pitch, deg),
        ``<name>/speed`` (set-point, m/s) and ``<name>/leg``, with a
        ``health/<name>-state/events`` line at each change of mode (an abort with its reason,
        as an error)."""
        deg = math.degrees
        self.logger.series(f"{name}/track", t, {
            "cross_track_m": _float(body.get("cross_track")),
            "along_track_m": _float(body.get("along_track")),
            "depth_d_m": _float(body.get("depth_d"))})  # fmt: skip
        self.logger.series(f"{name}/setpoints", t, {
            "heading_d_deg": deg(_float(body.get("heading_d"))),
            "pitch_d_deg": deg(_float(body.get("pitch_d")))})  # fmt: skip
        self.logger.series(f"{name}/speed", t, {"speed_d_mps": _float(body.get("speed_d"))})
        self.logger.series(f"{name}/leg", t, {"leg": _float(body.get("leg"))})
        mode = str(body.get("mode", ""))
        if self._modes.get(name) != mode:
            self._modes[name] = mode
            reason = body.get("abort_reason") or ""
            why = f": {reason} ({body.get('abort_detail', '')})" if reason else ""
            self.logger.event(f"{name}-state", t, f"mode {mode}{why}",
                              "ERROR" if mode == "aborted" else "INFO")  # fmt: skip

    def _sensor_json(
        self, device: str, type_name: str, body: Mapping[str, object], t: float
    ) -> str:
        cls = self._classes.get(type_name)
        msg: object
        if type_name == "pd0.Ensemble" and cls is not None:
            msg = self._ensemble(body)
        elif cls is not None:
            msg = from_jsonable(body, cls)
        else:
            msg = _Obj(body)
        return self._sensor(device, type_name, msg, t)

    def _ensemble(self, body: Mapping[str, object]) -> Ensemble:
        """A PD0 ensemble with only the blocks shown (the profiles are not rebuilt)."""
        from auvgw.drivers import pd0

        def block(name: str, cls: type[_T]) -> _T | None:
            v = body.get(name)
            return None if v is None else from_jsonable(_mapping(v, name), cls)

        return pd0.Ensemble(
            fixed_leader=block("fixed_leader", pd0.FixedLeader),
            variable_leader=block("variable_leader", pd0.VariableLeader),
            bottom_track=block("bottom_track", pd0.BottomTrack),
            bt_high_res=block("bt_high_res", pd0.BottomTrackHighRes),
            bt_range=block("bt_range", pd0.BottomTrackRange),
        )

    def on_message(self, device: str, t_recv_ns: int, msg: object) -> str:
        """Map one typed message (in-process: ``Gateway(on_message=stage.on_message)``)."""
        with self._lock:
            self.stats.received += 1
        type_name = getattr(msg, "TYPE", type(msg).__name__)
        t_host = t_recv_ns / 1e9
        self._t_last = max(self._t_last, t_host)
        try:
            with self._map_lock:
                outcome = self._sensor(device, type_name, msg, t_host)
        except Exception as exc:
            return self._error(f"{device}/{type_name}", exc)
        return self._count(outcome)

    def _sensor(self, device: str, type_name: str, msg: object, t_host: float) -> str:
        from auvgw.drivers import registry

        if type_name in IGNORED_TYPES:
            return "ignored"
        for role in registry.roles_of(type_name):
            handler = self._role_handlers.get(role)
            if handler is not None and handler(device, msg, t_host):
                return "logged"
        return f"sensor:{type_name or '?'}"

    def _attitude(self, device: str, message: object, t_host: float) -> bool:
        if not all(hasattr(message, n) for n in ("roll", "pitch", "heading")):
            return False
        msg = cast(Attitude, message)
        t = self._clock(device)(_float(getattr(msg, "time", None)), t_host)
        self.logger.attitude(t, _float(msg.roll), _float(msg.pitch), _float(msg.heading))
        return True

    def _field(self, device: str, message: object, t_host: float) -> bool:
        if not all(hasattr(message, n) for n in ("bx", "by", "bz")):
            return False
        msg = cast(Field, message)
        b = (_float(msg.bx), _float(msg.by), _float(msg.bz))
        self.logger.magnetometer(self._clock(device)(None, t_host), b)
        return True

    def _acoustic_fix(self, device: str, message: object, t_host: float) -> bool:
        """An acoustic beacon reply (slant ``range`` m, ``bearing`` rad from the bow,
        ``depression`` rad): a line from the navigation pose to where the fix places the beacon
        (``map/acoustic/ranges``; it ends on the beacon while the navigation is right)."""
        if not all(hasattr(message, n) for n in ("range", "bearing")):
            return False
        msg = cast(Range, message)
        pose = self._nav or self._truth
        if pose is None:
            return True  # nothing to draw it from yet
        x, y, _, h = pose
        r = _float(msg.range) * math.cos(_float(getattr(msg, "depression", 0.0), 0.0))
        b = h + _float(msg.bearing)
        end = (x + r * math.cos(b), y + r * math.sin(b))
        self.logger.ranges("acoustic", self._clock(device)(None, t_host), (x, y), [end])
        return True

    # sensor handlers (typed messages) -------------------------------------------------------
    def _pose_for_swath(self, heading: float) -> tuple[float, float, float, float]:
        pose = self._nav or self._truth
        if pose is None:
            return (0.0, 0.0, 0.0, heading)
        return pose

    def _swath(self, device: str, message: object, t_host: float) -> bool:
        msg = cast(_Swath, message)
        t = self._clock(device)(_float(getattr(msg, "device_time", None)), t_host)
        xyz = np.asarray(msg.xyz, dtype=np.float64)
        beams = msg.beams
        valid = getattr(beams, "valid", None)
        if valid is None:
            valid = np.asarray(getattr(beams, "depth", ())) != 0
        x, y, z, h = self._pose_for_swath(_float(getattr(msg, "heading", 0.0), 0.0))
        draft = _float(getattr(msg, "transducer_depth_total", None))
        if math.isnan(draft):
            draft = _float(getattr(msg, "transducer_depth", None), 0.0)
        z0 = draft if draft != 0.0 else z
        self.logger.swath(
            t, xyz[:, 0], xyz[:, 1], xyz[:, 2], x=x, y=y, z=z0, heading=h, valid=valid
        )
        return True

    def _raw_ping(self, device: str, message: object, t_host: float) -> bool:
        """A GeoSwath ping: its samples' return angle (deg) and slant range (m, at the ping's
        MINISVS sound speed and the device's frequency: ``geoswath_frequencies_hz``, else
        ``geoswath_frequency_hz``) with their amplitude, every ``raw_ping_period_s`` device
        seconds per side."""
        arrays = getattr(message, "arrays", None)
        if not isinstance(arrays, Mapping) or "raa" not in arrays:
            return False
        ping = cast("GeoSwathPing", message)
        from auvgw.slam.bathymetric.swath_processing import SwathProcessing, ping_samples

        opts = self.logger.options
        side = int(ping.header["side"])
        t = self._clock(device)(_float(ping.header.get("ping_time")), t_host)
        if 0.0 <= t - self._raw_ping_t.get((device, side), -math.inf) < opts.raw_ping_period_s:
            return True  # shown less often (a clock that went back shows the ping at once)
        self._raw_ping_t[(device, side)] = t
        f_hz = opts.geoswath_frequencies_hz.get(device, opts.geoswath_frequency_hz)
        a, r, amp, _ = ping_samples(ping, SwathProcessing(frequency_hz=f_hz))
        self.logger.raw_ping(device, t, side, np.degrees(a), r, amp)
        return True

    _FRAME_AXES: Mapping[int, tuple[str, str, str]] = {
        0: ("beam 1", "beam 2", "beam 3"),
        1: ("x", "y", "z"),
        2: ("starboard", "forward", "up"),
        3: ("east", "north", "up"),
    }

    def _dvl(self, device: str, message: object, t_host: float) -> bool:
        if not hasattr(message, "bottom_track"):  # a PD0 ensemble; PD6 velocities are not shown
            return False
        ens = cast("Ensemble", message)
        vl = ens.variable_leader
        t = self._clock(device)(None if vl is None else vl.device_time_s, t_host)
        bt, hr, rng = ens.bottom_track, ens.bt_high_res, ens.bt_range
        v = np.full(3, np.nan)
        if hr is not None:
            v = np.asarray(hr.vehicle_velocity, dtype=np.float64)[:3]
        if not np.all(np.isfinite(v)) and bt is not None:
            v = np.asarray(bt.vehicle_velocity, dtype=np.float64)[:3]
        altitude = math.nan
        if rng is not None and math.isfinite(_float(rng.vertical_range)):
            altitude = float(rng.vertical_range)
        elif bt is not None and np.any(np.isfinite(bt.range)):
            altitude = float(np.nanmean(bt.range))
        lock = bt is not None and bool(np.all(np.isfinite(np.asarray(bt.velocity, dtype=float))))
        frame = ens.coordinate_frame
        names = self._FRAME_AXES.get(int(frame) if frame is not None else 1, ("x", "y", "z"))
        self.logger.dvl(t, v, altitude, names, lock)
        return True

    def _msis(self, device: str, message: object, t_host: float) -> bool:
        msg = cast(_SonarPing, message)
        t = self._clock(device)(None, t_host)
        max_value = 255 if msg.adc8on else 15
        self.logger.msis_ping(t, msg.bearing, msg.bins, msg.range_m, msg.step, max_value)
        return True

    # nav, slam, truth, status (JSON objects) ------------------------------------------------
    def _odometry(self, body: Mapping[str, object], t_host: float) -> str:
        if "x" not in body or "y" not in body:
            return "nav:?"
        t = self._clock("nav")(_float(body.get("t")), t_host)
        x, y = _float(body["x"]), _float(body["y"])
        z, h = _float(body.get("z"), 0.0), _float(body.get("heading"))
        cov = body.get("covariance")
        cxy = None if cov is None else np.asarray(cov, dtype=np.float64)[:2, :2]
        self._nav = (x, y, z, h)
        self.logger.trajectory("dead_reckoning", t, x, y, z, h, cxy)
        return "logged"

    def _pose_of(self, body: Mapping[str, object]) -> tuple[float, float, float, float] | None:
        pose = body.get("pose")
        if isinstance(pose, list | tuple) and len(pose) >= 2:
            h = _float(pose[2]) if len(pose) > 2 else math.nan
            return _float(pose[0]), _float(pose[1]), _float(body.get("z"), 0.0), h
        if "x" in body and "y" in body:
            return (
                _float(body["x"]), _float(body["y"]), _float(body.get("z"), 0.0),
                _float(body.get("heading")),
            )  # fmt: skip
        return None

    def _map_features(self, name: str, body: Mapping[str, object], t: float) -> bool:
        shown = False
        pts = _get(body, "mean", "landmarks", "points", "features")
        if pts is not None:
            mean, ids = _points(pts)
            cov = body.get("cov")
            c = None if cov is None else np.asarray(cov, dtype=np.float64).reshape(-1, 2, 2)
            raw_ids = body.get("ids")
            if raw_ids is not None:
                ids = np.asarray(raw_ids)
            if ids is None or len(ids) != len(mean):  # the map's order is the features' id
                ids = np.arange(len(mean))
            elif np.issubdtype(np.asarray(ids).dtype, np.number) and (np.asarray(ids) < 0).any():
                # a filter's "no id yet" (-1): the landmark's place in the map names it instead
                ids = np.where(np.asarray(ids) < 0, np.arange(len(mean)), ids)
            if c is not None and len(c) != len(mean):
                c = None
            self.logger.landmarks(name, t, mean, c, ids)
            shown = True
        ab = body.get("acoustic_beacon")
        if isinstance(ab, list | tuple) and len(ab) >= 2:
            xy = (_float(ab[0]), _float(ab[1]))
            if self._acoustic.get(name) != xy:  # a fixed position: logged when it changes
                self._acoustic[name] = xy
                self.logger.acoustic_beacon(name, t, *xy)
            shown = True
        lines = body.get("lines")
        if lines is not None:
            rho, theta, lcov, ends = _lines(lines)
            self.logger.lines(name, t, rho, theta, lcov, ends)
            shown = True
        return shown

    def _slam(self, pipeline: str, what: str, body: Mapping[str, object], t_host: float) -> str:
        """A SLAM output, shown by its view in the pipeline registry
        (:data:`auvgw.slam.pipelines.OUTPUT_VIEWS`): the pipeline publishing under ``pipeline``
        names the view of each of its outputs ``what``."""
        name = f"slam/{pipeline}"
        # a SLAM output's t is on the odometry's clock, the stamps' (vehicle-paced under a
        # [clock]): its own row time as it is; mapping it against the host's arrival time made
        # rows at --speed 2 land at about half their vehicle time (issue 33)
        t = _float(body.get("t"), t_host)
        record = pipelines.for_segment(pipeline)
        view = record.view_of(what) if record is not None else None
        shown = False
        pose = self._pose_of(body)
        if view == "pose" and pose is not None:
            cov = body.get("cov", body.get("covariance"))
            cxy = None if cov is None else np.asarray(cov, dtype=np.float64)[:2, :2]
            self.logger.trajectory(name, t, *pose, cxy)
            shown = True
        particles = body.get("particles")
        if particles is not None:
            self.logger.particles(name, t, np.asarray(particles, dtype=np.float64),
                                  _array(body.get("weights")))  # fmt: skip
            shown = True
        if view == "dem":
            shown |= self._dem(name, body, t)
        elif view == "cloud":
            shown |= self._seabed(name, body, t)
        elif view == "landmarks":
            shown |= self._map_features(name, body, t)
        elif view == "ranges":
            shown |= self._beacon_ranges(name, body, t)
        elif view == "path":
            shown |= self._path(name, body)
        return "logged" if shown else f"slam:{what}"

    def _path(self, name: str, body: Mapping[str, object]) -> bool:
        """A smoothed trajectory (bathymetric SLAM's ``track``: ``t``, ``x``, ``y`` per pose,
        sent once at the end): its own track ``<name>-smoothed``, each pose at its time."""
        t, x, y = body.get("t"), body.get("x"), body.get("y")
        if not isinstance(t, list) or not isinstance(x, list) or not isinstance(y, list):
            return False
        for ti, xi, yi in zip(t, x, y, strict=False):
            if ti is not None and xi is not None and yi is not None:
                self.logger.trajectory(f"{name}-smoothed", float(ti), float(xi), float(yi))
        return bool(t)

    def _dem(self, name: str, body: Mapping[str, object], t: float) -> bool:
        """A DEM tile (bathymetric SLAM's ``map``: ``depth`` grid, ``cell_m``, ``x0``, ``y0``)."""
        if "cell_m" not in body or "depth" not in body:
            return False
        rows = [[math.nan if v is None else v for v in _items(row, "depth")]
                for row in _items(body["depth"], "depth")]  # fmt: skip
        grid = np.asarray(rows, dtype=np.float64)
        self.logger.dem(name, t, _float(body["x0"]), _float(body["y0"]), _float(body["cell_m"]),
                        grid)  # fmt: skip
        return True

    def _seabed(self, name: str, body: Mapping[str, object], t: float) -> bool:
        """Seabed points (bathymetric SLAM's ``cloud``: ``points`` [[x, y, depth]])."""
        pts = body.get("points")
        if isinstance(pts, list) and len(pts) and len(pts[0]) == 3:
            self.logger.seabed(name, t, pts)
            return True
        return False

    def _beacon_ranges(self, name: str, body: Mapping[str, object], t: float) -> bool:
        """One magnetic-beacon observation (``slam/magnetic/observations``: ``z`` = [range m,
        bearing rad from the heading] seen from ``x``, ``y``, ``heading``): a line from the
        vehicle to where it places the beacon."""
        z = body.get("z")
        pose = self._pose_of(body)
        if not isinstance(z, list | tuple) or len(z) < 2 or pose is None:
            return False
        x, y, _, h = pose
        r, b = _float(z[0]), _float(z[1])
        end = (x + r * math.cos(h + b), y + r * math.sin(h + b))
        # the observations of one demodulated window share its time and are drawn together; an
        # older window's (or one received twice, from the bus and in process) is not redrawn
        t_last, ends = self._ranges.get(name, (-math.inf, []))
        if t < t_last or end in ends:
            return True
        if t > t_last:
            ends = []
        ends.append(end)
        self._ranges[name] = (t, ends)
        self.logger.ranges(name, t, (x, y), ends)
        return True

    def _truth_msg(self, body: Mapping[str, object], t_host: float) -> str:
        t = self._clock("truth")(_float(body.get("t")), t_host)
        shown = False
        pose = self._pose_of(body)
        if pose is not None:
            self._truth = pose
            self.logger.trajectory("truth", t, *pose)
            shown = True
        shown |= self._map_features("truth", body, t)
        return "logged" if shown else "truth:?"

    #: fusion diagnostics shown as one series each (``<device>_diagnostics``), window shares
    _DIAG_KEYS = ("accepted_share", "rejected_share", "coasting_share", "nis_mean_per_dof")

    def _diagnostics(self, device: str, diag: Mapping[str, object], t: float) -> None:
        """A fusion status's diagnostics: the window's shares, NIS and the adapted DVL noise as
        series, and each new warning as a WARN event (docs/fusion.md, Diagnostics)."""
        win = diag.get("window")
        win = win if isinstance(win, Mapping) else {}
        metrics = {k: _float(win.get(k)) for k in self._DIAG_KEYS}
        sig = diag.get("dvl_noise_sigma_mps")
        sig = list(sig) if isinstance(sig, list | tuple) and len(sig) == 3 else [None] * 3
        for axis, v in zip("xyz", sig, strict=True):
            metrics[f"dvl_noise_{axis}_mps"] = _float(v)
        self.logger.health(f"{device}_diagnostics", t, metrics)
        warnings = tuple(str(w) for w in _items(diag.get("warnings"), "warnings"))
        prev = self._warnings.get(device)
        if prev != warnings:
            self._warnings[device] = warnings
            for w in warnings:
                if prev is None or w.split(":", 1)[0] not in {p.split(":", 1)[0] for p in prev}:
                    self.logger.event(device, t, f"{device}: {w}", "WARN")

    _HEALTH_KEYS = (
        "rate_hz", "bad_frames", "decode_errors", "skipped_bytes", "silent_s",
        "age_s", "lag_s", "transport_lost",
    )  # fmt: skip
    _HEALTH_FLAGS = ("connected", "stale")
    #: a device's loss counters: each increase is a WARN event
    _LOSS_KEYS = ("bad_frames", "decode_errors", "skipped_bytes", "transport_lost")

    def _health(self, device: str, body: Mapping[str, object], t_host: float) -> str:
        if device == "gateway" or "devices" in body:
            return "ignored"  # the gateway summary repeats the per-device status
        # on the data's timeline (the gateway's stamp clock, vehicle-paced in emulation), not
        # the host clock of arrival, which falls behind it at speed != 1: a device's status and
        # a stage's (its own clock: the newest input stamp it took) carry their stamp
        t = _float(body.get("t_stamp_ns"), math.nan) / 1e9
        if t != t:
            if "t_stamp_ns" in body:  # a stage before its first input: no vehicle time yet
                return "ignored"
            t = self._t_last or t_host  # no stamp at all: the newest data time seen here
        if not any(k in body for k in (*self._HEALTH_KEYS, *self._HEALTH_FLAGS)):
            # another component's status (fusion, SLAM, ...): its numbers, one series each
            leaves = _numeric_leaves(body)
            diag = body.get("diagnostics")
            if isinstance(diag, Mapping):
                self._diagnostics(device, diag, t)
            if not leaves:
                return f"status:{device}"
            self.logger.health(device, t, leaves)
            return "logged"
        # always the same metrics (NaN when absent), so the series stay the same
        metrics = {k: _float(body.get(k)) for k in self._HEALTH_KEYS}
        for flag in self._HEALTH_FLAGS:
            metrics[flag] = math.nan if body.get(flag) is None else float(bool(body[flag]))
        self.logger.health(device, t, metrics)
        # a loss counter that grew is an event (the counters themselves are a table, not lines)
        counts = self._losses.setdefault(device, {})
        for k in self._LOSS_KEYS:
            v, before = metrics[k], counts.get(k, 0.0)
            if v == v and v > before:
                self.logger.event(device, t, f"{device}: {k} {v:.0f} (+{v - before:.0f})", "WARN")
                counts[k] = v
        state = (body.get("connected"), body.get("last_error"))
        prev = self._status.get(device)
        if prev != state:
            self._status[device] = state
            if prev is None or prev[0] != state[0]:
                word = "connected" if state[0] else "disconnected"
                text = f"{device} {word}" + (f": {state[1]}" if state[1] and not state[0] else "")
                self.logger.event(device, t, text, "INFO" if state[0] else "WARN")
            elif state[1]:
                self.logger.event(device, t, f"{device}: {state[1]}", "WARN")
        return "logged"


@dataclass
class VizRunner:
    """A logger and the stage feeding it, as a command runs them (see :func:`open_viz`)."""

    logger: RerunLogger
    stage: VizStage

    @property
    def on_message(self) -> Callable[[str, int, object], str]:
        """In-process hook for ``Gateway(on_message=...)`` (then attach without ``sensor``)."""
        return self.stage.on_message

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop the stage (mapping what is queued), then close the logger (writes the footer)."""
        try:
            self.stage.stop(timeout_s=timeout_s)
        finally:
            self.logger.close(timeout_s)


def open_viz(
    session: zenoh.Session,
    vehicle: str,
    *,
    rrd: str | Path | None = None,
    connect: str | None = None,
    options: VizOptions | None = None,
    sections: Iterable[str] = SECTIONS,
) -> VizRunner:
    """Start Rerun logging of ``vehicle``'s bus on ``session`` to ``rrd`` and/or a viewer at
    ``connect``; ``close()`` the result before closing the session.

    For a gateway in the same process, pass ``sections`` without ``"sensor"`` and give the
    gateway ``on_message=runner.on_message`` (no JSON round trip for sensor data).
    """
    logger = RerunLogger(rrd=rrd, connect=connect, options=options)
    stage = VizStage(logger, vehicle)
    try:
        stage.attach(session, sections)
    except Exception:
        logger.close()
        raise
    stage.start(subscribe=False)  # attached above; nothing of its own to declare on the bus
    return VizRunner(logger, stage)
