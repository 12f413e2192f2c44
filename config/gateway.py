"""Gateway configuration (``auvgw run --config vehicle.toml``), validated with pydantic.

Every error names the file, the field path and what was expected (see :func:`load_gateway_config`).
Relative paths in a configuration file (a file transport's ``path``, ``dbc``, ``table``) are
relative to the file's folder; a ``dbc``/``table`` name not found there is one shipped in
``config/``. Example (the full reference is docs/gateway.md)::

    vehicle = "auv1"

    [bus]
    mode = "peer"
    listen = ["tcp/127.0.0.1:7447"]

    [devices.dvl]
    format = "pd0"
    transport = { kind = "serial", url = "/dev/ttyUSB0", baud = 115200 }

    [devices.ins_can]
    format = "can"
    dbc = "hn100.dbc"
    transport = { kind = "can", interface = "slcan", channel = "/dev/ttyACM0", bitrate = 500000 }

    [clock]          # optional: vehicle-paced receive times (an emulated vehicle at k x real time)
    time_scale = 4.0
    epoch_ns = 1767225600000000000
"""

from __future__ import annotations

import time
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from auvgw.config.bus import BusConfig
from auvgw.config.ros2 import FoxgloveConfig, Ros2Config
from auvgw.config.transport import (
    KINDS,
    MAX_TEXT,
    CanTransportConfig,
    FileTransportConfig,
    SerialTransportConfig,
    TransportConfig,
    UdpTransportConfig,
)
from auvgw.drivers import registry
from auvgw.ground.errors import ConfigError, read_document
from auvgw.ground.errors import format_validation_error as format_errors

__all__ = [
    "DEVICE_FORMATS",
    "ClockConfig",
    "ConfigError",
    "DeviceConfig",
    "GatewayConfig",
    "MsisPolling",
    "format_validation_error",
    "load_gateway_config",
    "parse_gateway_config",
]

#: formats a device may speak (from the device registry); "can" decodes CAN frames with the
#: device's DBC
DEVICE_FORMATS = registry.device_formats()

_NAME_CHARS = "letters, digits, '_' or '-'"
#: most devices in one gateway (a thread each)
MAX_DEVICES = 64
#: the latest clock.epoch_ns accepted: 2100-01-01
MAX_EPOCH_NS = 4_102_444_800 * 10**9


class _Model(BaseModel):
    # every number finite (inf/nan rejected): an infinite period or delay kills a thread; strict:
    # no "yes" -> True, "3" -> 3 or 3.0 -> 3
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class MsisPolling(_Model):
    """How the gateway drives a Tritech head (SeaNet is host-polled). Angles in degrees."""

    range_m: float = Field(30.0, gt=0, le=300, description="range scale, m")
    gain: float = Field(0.4, ge=0, le=1, description="initial gain, 0..1")
    step_deg: float = Field(1.8, gt=0, le=7.2, description="angular step per ping, deg")
    left_limit_deg: float = Field(0.0, ge=0, lt=360)
    right_limit_deg: float = Field(360.0, gt=0, le=360)
    continuous: bool = True
    n_bins: int = Field(300, ge=8, le=1500)
    adc8: bool = True
    reply_timeout_s: float = Field(
        1.0, ge=0.01, le=60, description="resend mtSendData after this, s"
    )


class GeoSwathModel(_Model):
    """Which GeoSwath Plus the device is: its sonar frequency. The broadcast ping does not
    carry it, and its RAA sample times count wavelengths (slant range = c t / (2 f))."""

    model_khz: Literal[125, 250, 500] = Field(
        250, description="the GeoSwath Plus model: 125, 250 or 500 kHz"
    )

    @property
    def frequency_hz(self) -> float:
        """The sonar frequency, Hz."""
        return float(self.model_khz) * 1000.0


class DeviceConfig(_Model):
    """One device: its wire format, its transport, and format-specific options."""

    format: str = Field(
        max_length=64, description="wire format: one of DEVICE_FORMATS (the device registry)"
    )
    transport: TransportConfig
    enabled: bool = True
    dbc: str | None = Field(
        None,
        max_length=MAX_TEXT,
        description="CAN database (format 'can'); file in config/ or path",
    )
    table: str | None = Field(
        None,
        max_length=MAX_TEXT,
        description="site table replacing the shipped one (formats with a registry table)",
    )
    msis: MsisPolling | None = None
    geoswath: GeoSwathModel | None = None
    stale_after_s: float = Field(
        2.0, ge=0.01, le=3600, description="report the device silent after this, s"
    )
    reopen_silent_periods: float = Field(
        20, ge=0, le=1e6,
        description="close and reopen a device that stays open but sends no frame for this "
        "many expected periods (at least stale_after_s), after it sent on that connection; "
        "0: never",
    )  # fmt: skip
    expected_period_s: float | None = Field(
        None, gt=0, le=3600,
        description="the device's frame period, s (for reopen_silent_periods); default: "
        "learned, the median interval between the reads that brought its frames",
    )  # fmt: skip
    backoff_initial_s: float = Field(0.2, ge=0.01, le=3600, description="first reconnect delay, s")
    backoff_max_s: float = Field(5.0, ge=0.01, le=3600, description="reconnect delay cap, s")
    partial_frame_max_age_s: float = Field(
        2.0, ge=0.001, le=600,
        description="drop a partial frame that waited this long for its bytes (host s); a "
        "few frame periods of the slowest message, longer than its transmission time",
    )  # fmt: skip
    read_interval_s: float = Field(
        0.005, ge=0, le=1,
        description="least time between two reads of a serial port while bytes keep coming "
        "(s): writes closer together are read together; 0: each as it arrives",
    )  # fmt: skip

    @field_validator("format")
    @classmethod
    def _known_format(cls, v: str) -> str:
        if v not in DEVICE_FORMATS:
            names = [repr(f) for f in DEVICE_FORMATS]
            raise ValueError(f"Input should be {', '.join(names[:-1])} or {names[-1]}")
        return v

    @model_validator(mode="after")
    def _format_options(self) -> DeviceConfig:
        kind = self.transport.kind
        dev = None if self.format == registry.CAN_FORMAT else registry.device(self.format)
        if self.format == "can" and not self.dbc:
            raise ValueError("format 'can' needs 'dbc' (e.g. dbc = \"hn100.dbc\")")
        if self.format == "can" and kind != "can":
            raise ValueError(f"format 'can' needs a transport of kind 'can', not {kind!r}")
        if self.format != "can" and kind == "can":
            raise ValueError(
                f"transport kind 'can' carries CAN frames: set format = \"can\" "
                f"(not {self.format!r}) and name the device's dbc"
            )
        if self.dbc and self.format != "can":
            raise ValueError(f"'dbc' only applies to format 'can', not {self.format!r}")
        if self.table and (dev is None or dev.table is None):
            tables = [repr(d.format) for d in registry.DEVICES if d.table and d.live]
            raise ValueError(
                f"'table' only applies to formats {', '.join(tables)}, not {self.format!r}"
            )
        for opt, model in _OPTIONS.items():
            takes = dev is not None and dev.options == opt
            if getattr(self, opt) is not None and not takes:
                owner = [repr(d.format) for d in registry.DEVICES if d.options == opt]
                raise ValueError(
                    f"{opt!r} only applies to format {' or '.join(owner)}, not {self.format!r}"
                )
            if takes and getattr(self, opt) is None:
                setattr(self, opt, model())
        if self.backoff_max_s < self.backoff_initial_s:
            raise ValueError("'backoff_max_s' must be >= 'backoff_initial_s'")
        return self


#: a device's own options table (the registry's ``options``) -> its model
_OPTIONS: dict[str, type[_Model]] = {"msis": MsisPolling, "geoswath": GeoSwathModel}


class ClockConfig(_Model):
    """The receive time the gateway stamps on every envelope and raw attachment.

    Default (``time_scale = 1``): the host receive time, ns since the Unix epoch. An emulated
    vehicle running ``k`` times faster than real time (``auvgw sim --speed k``) sets
    ``time_scale = k`` and ``epoch_ns``, the host time (ns since the Unix epoch) of vehicle time
    0; the gateway then stamps ``epoch_ns + (t_recv_ns - epoch_ns) * time_scale``, a
    *vehicle-paced* time: it advances one second per vehicle second, every device clock keeps a
    constant offset to it, and ``(t - epoch_ns) / 1e9`` is the vehicle time in seconds.

    A lock-step sim (``auvgw sim --lockstep``) holds its vehicle time back while the controller
    has not answered, so host time no longer maps onto it: ``sim_clock`` names the sim's clock
    file (:mod:`auvgw.ground.simclock`) and the gateway stamps its vehicle time at receipt
    (``epoch_ns`` + vehicle ns; the scaled host time until the file is written).
    """

    time_scale: float = Field(1.0, gt=0, le=1000, description="stamped s per host s")
    epoch_ns: int | None = Field(
        None,
        ge=0,
        le=MAX_EPOCH_NS,
        description="host time of vehicle time 0, ns since the Unix epoch",
    )
    sim_clock: str | None = Field(
        None, min_length=1, max_length=4096,
        description="a lock-step sim's clock file: stamp its vehicle time at receipt",
    )
    _reader: Any = PrivateAttr(None)

    @model_validator(mode="after")
    def _epoch_when_scaled(self) -> ClockConfig:
        if self.time_scale != 1.0 and self.epoch_ns is None:
            raise ValueError(
                "time_scale != 1 needs 'epoch_ns' (host ns since the Unix epoch of vehicle "
                "time 0, the instant the scaled clock pivots on)"
            )
        return self

    def stamp(self, t_recv_ns: int) -> int:
        """The time the gateway publishes for a host receive time (both ns)."""
        if self.sim_clock is not None:
            if self._reader is None:
                from auvgw.ground.simclock import ClockFileReader

                self._reader = ClockFileReader(self.sim_clock)
            now = self._reader.stamp_ns(t_recv_ns)
            if now is not None:
                return int(now)
        if self.time_scale == 1.0 or self.epoch_ns is None:
            return t_recv_ns
        return self.epoch_ns + round((t_recv_ns - self.epoch_ns) * self.time_scale)

    def paced_monotonic(self) -> float:
        """Host monotonic seconds, or with ``sim_clock`` the sim's vehicle time over
        ``time_scale``: it runs like the host clock while the sim runs and stands still while
        a lock-step sim holds, so a device is not judged silent (and reopened) for a hold."""
        if self.sim_clock is not None:
            if self._reader is None:
                from auvgw.ground.simclock import ClockFileReader

                self._reader = ClockFileReader(self.sim_clock)
            v = self._reader.vehicle_s()
            if v is not None:
                return float(v) / self.time_scale
        return time.monotonic()

    def vehicle_s(self, t_ns: int) -> float:
        """Vehicle seconds of a stamped time (needs ``epoch_ns``)."""
        if self.epoch_ns is None:
            raise ValueError("clock.epoch_ns is not set: vehicle time 0 is unknown")
        return (t_ns - self.epoch_ns) / 1e9


class GatewayConfig(_Model):
    """The whole gateway: vehicle name (a Zenoh key segment), bus, status period, devices,
    and the receive-time clock."""

    vehicle: str = Field("auv1", max_length=64)
    bus: BusConfig = Field(default_factory=BusConfig)
    clock: ClockConfig = Field(default_factory=ClockConfig)
    status_period_s: float = Field(
        1.0, ge=0.05, le=3600, description="status publication period, s"
    )
    devices: dict[Annotated[str, Field(max_length=64)], DeviceConfig] = Field(
        min_length=1, max_length=MAX_DEVICES
    )
    ros2: Ros2Config = Field(default_factory=Ros2Config, description="the ROS 2 bridge")
    foxglove: FoxgloveConfig = Field(default_factory=FoxgloveConfig,
                                     description="the Foxglove WebSocket server")  # fmt: skip
    source: str | None = Field(None, exclude=True)

    @field_validator("vehicle")
    @classmethod
    def _vehicle_name(cls, v: str) -> str:
        if not _is_name(v):
            raise ValueError(f"vehicle name {v!r}: use {_NAME_CHARS} (it is a Zenoh key segment)")
        return v

    @field_validator("devices")
    @classmethod
    def _device_names(cls, v: dict[str, DeviceConfig]) -> dict[str, DeviceConfig]:
        for name in v:
            if not _is_name(name):
                raise ValueError(
                    f"device name {name!r}: use {_NAME_CHARS} (it is a Zenoh key segment)"
                )
            if name == "gateway":
                raise ValueError("'gateway' is reserved (the gateway's own status and liveliness)")
        return v

    @field_validator("devices")
    @classmethod
    def _one_device_per_port(
        cls, v: dict[str, DeviceConfig], info: ValidationInfo
    ) -> dict[str, DeviceConfig]:
        if isinstance(info.context, dict) and info.context.get("recorded"):
            return v  # a recording's configuration names its decoders; it opens no port
        seen: dict[tuple[str, ...], str] = {}
        for name, dev in v.items():
            key = _port_key(dev.transport)
            if key is None:
                continue
            if key in seen:
                raise ValueError(
                    f"devices {seen[key]!r} and {name!r} both use {dev.transport.describe()}: "
                    "one device per port (two would take turns failing to open it)"
                )
            seen[key] = name
        return v


def _port_key(t: TransportConfig) -> tuple[str, ...] | None:
    """What two devices may not share: a serial port, an exclusive CAN adapter's channel, a
    UDP port bound without SO_REUSEADDR (None: sharable, e.g. a replayed file, SocketCAN)."""
    if isinstance(t, SerialTransportConfig):
        return ("serial", t.url)
    if isinstance(t, CanTransportConfig):
        if t.interface in _SHARED_CAN:
            return None
        return ("can", t.interface, str(t.channel))
    if isinstance(t, UdpTransportConfig):
        reuse = t.reuse_address if t.reuse_address is not None else t.multicast_group is not None
        return None if t.port == 0 or reuse else ("udp", str(t.port))
    return None


#: CAN interfaces several sockets may open at once (every other one is one adapter, one owner)
_SHARED_CAN = frozenset({"socketcan", "virtual", "udp_multicast"})


def _is_name(s: str) -> bool:
    return bool(s) and s.isascii() and s.replace("_", "").replace("-", "").isalnum()


# -- error messages ----------------------------------------------------------------------------


def _unwrap(ann: Any) -> list[Any]:
    """Members of a union annotation (without None), or the annotation alone."""
    if typing.get_origin(ann) is typing.Annotated:
        ann = typing.get_args(ann)[0]
    if typing.get_origin(ann) in (typing.Union, types.UnionType):
        return [a for a in typing.get_args(ann) if a is not type(None)]
    return [ann]


def _model_at(loc: tuple[str, ...]) -> type[BaseModel] | None:
    """The model whose fields live at ``loc`` (dict keys and union tags included), if any."""
    model: type[BaseModel] = GatewayConfig
    parts = list(loc)
    while parts:
        fld = model.model_fields.get(parts.pop(0))
        if fld is None:
            return None
        members = _unwrap(fld.annotation)
        if typing.get_origin(members[0]) is dict:
            if not parts:
                return None
            parts.pop(0)  # the dict key (a device name)
            members = _unwrap(typing.get_args(members[0])[1])
        models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
        if len(models) > 1:  # a union tagged by 'kind': pydantic puts the tag in the path
            tag = parts.pop(0) if parts else None
            models = [m for m in models if m.model_fields["kind"].default == tag]
        if len(models) != 1:
            return None
        model = models[0]
    return model


def _explain(loc: tuple[str, ...], err: Mapping[str, Any]) -> str | None:
    if loc == ("devices",) and err["type"] in ("missing", "too_short"):
        return "no device configured: add a [devices.<name>] table per device"
    if err["type"] == "extra_forbidden":
        model = _model_at(loc[:-1])
        known = ", ".join(k for k in model.model_fields if k != "source") if model else ""
        return f"unknown key {loc[-1]!r}" + (f"; expected one of: {known}" if known else "")
    return None


def format_validation_error(path: str, exc: ValidationError) -> str:
    """One line per problem: ``file: field.path: what is wrong / expected (got ...)``
    (:func:`auvgw.ground.errors.format_validation_error`; an unknown key lists the known ones)."""
    return format_errors(exc, path, tags=KINDS, tagged=("transport",), explain=_explain)


# -- loading -----------------------------------------------------------------------------------


def parse_gateway_config(
    data: Mapping[str, Any], source: str = "<config>", base_dir: Path | None = None
) -> GatewayConfig:
    """Validate a mapping; relative paths resolve against ``base_dir`` when given."""
    try:
        cfg = GatewayConfig.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(format_validation_error(source, exc)) from exc
    cfg.source = source
    if base_dir is not None:
        _resolve_paths(cfg, base_dir)
    return cfg


def _relative_port(path: str) -> bool:
    """A device path relative to the working directory (not a URL, not absolute)."""
    return bool(path) and "://" not in path and not Path(path).is_absolute()


def _resolve_paths(cfg: GatewayConfig, base: Path) -> None:
    """Relative file, device (serial url, slcan channel), DBC and table paths name files next
    to the configuration file, wherever the gateway is started from (systemd: ``/``)."""
    cfg.bus = cfg.bus.rebased(base)
    auth = cfg.bus.auth
    for attr in ("password_file", "dictionary_file"):
        name = getattr(auth, attr, None)
        if name is not None and not Path(name).is_file():
            raise ConfigError(f"{cfg.source}: bus.auth.{attr}: no such file ({name})")
    for dev in cfg.devices.values():
        t = dev.transport
        if isinstance(t, FileTransportConfig) and not t.path.is_absolute():
            dev.transport = t.model_copy(update={"path": base / t.path})
        elif isinstance(t, SerialTransportConfig) and _relative_port(t.url):
            dev.transport = t.model_copy(update={"url": str(base / t.url)})
        elif (
            isinstance(t, CanTransportConfig)
            and t.interface == "slcan"
            and isinstance(t.channel, str)
            and _relative_port(t.channel)
        ):
            dev.transport = t.model_copy(update={"channel": str(base / t.channel)})
        for attr in ("dbc", "table"):
            name = getattr(dev, attr)
            if name and not Path(name).is_absolute() and (base / name).is_file():
                setattr(dev, attr, str(base / name))


def load_gateway_config(path: str | Path) -> GatewayConfig:
    """Read and validate a gateway TOML file; :class:`ConfigError` names file and field."""
    path = Path(path)
    data = read_document(path, ConfigError, "configuration file")
    return parse_gateway_config(data, str(path), base_dir=path.resolve().parent)
