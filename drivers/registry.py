"""The device registry: one record per device kind, the one place a device is declared.

Every list of devices the rest of the project needs is derived from :data:`DEVICES`: the format
names (``auvgw decode --format``, the gateway's ``format`` key, :mod:`auvgw.drivers.formats`),
which formats take a replaceable table, a DBC or an options table, the decoder and host-driver
factories (:mod:`auvgw.decoding`, :mod:`auvgw.hostdrivers`), the emulators and their order
(:mod:`auvgw.sim_devices.runner`, the scenario's ``devices``), the bus ``<kind>`` of every message
type (``auv/<v>/sensor/<device>/<kind>``, docs/bus.md) and the role each type plays for fusion,
SLAM and the Rerun logger.

It lives in ``drivers/`` because a device kind is first a wire protocol; it names codecs,
emulators and host drivers by ``"module:attribute"`` strings and imports none of them, so reading
it costs nothing (``auvgw --help`` imports no numpy) and no table is read until a format is used.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

__all__ = [
    "CAN_FORMAT",
    "DEVICES",
    "ROLES",
    "DeviceKind",
    "Emulator",
    "MessageType",
    "default_kind",
    "device",
    "device_formats",
    "emulators",
    "kind_of",
    "kinds_with_role",
    "load",
    "message_types",
    "roles_of",
    "types_with_role",
]

#: the gateway format of a CAN bus device: frames decoded with the device's DBC
CAN_FORMAT = "can"

#: what a message type is used for by the consumers (fusion, SLAM, the Rerun logger)
ROLES: dict[str, str] = {
    "ins": "a full INS solution (attitude, rates, accelerations): fusion's attitude source",
    "attitude": "roll, pitch, heading (rad): fusion's attitude source, the Rerun attitude plot",
    "velocity": "bottom-track velocity and altitude: fusion's velocity source, Rerun DVL plot",
    "sonar": "one imaging-sonar ping (bearing, bins): landmark SLAM features, Rerun sonar view",
    "swath": "one multibeam swath (per-beam xyz): bathymetric SLAM, Rerun point cloud",
    "samples": "one side's raw interferometric samples (time, angle, amplitude): the swath "
    "stage's input, Rerun raw-ping view",
    "field": "a magnetic flux density vector (nT): magnetic SLAM, Rerun field plot",
    "range": "a range (and bearing) to an acoustic beacon: magnetic SLAM's anchor",
    "actuators": "measured shaft speed, fin angles, motor current and faults of the vehicle's "
    "actuators (a closed loop's feedback)",
}


def default_kind(type_name: str) -> str:
    """The bus ``<kind>`` of a type name the registry does not list: the name without its codec
    prefix, lower case (``pd0.RawBlock`` -> ``rawblock``)."""
    return type_name.rsplit(".", 1)[-1].lower()


@dataclass(frozen=True)
class MessageType:
    """A decoded message type: its ``TYPE`` name, its public bus ``<kind>`` and its roles.

    The kind is the type name without its codec prefix in lower case (``pd0.Ensemble`` ->
    ``ensemble``) unless several wires carry the same quantity: then every wire's type takes the
    quantity's name (``Hn100Nav`` on serial and ``HN100_Sample`` on CAN are both ``ins``).
    """

    type: str
    kind: str = ""
    roles: tuple[str, ...] = ()
    wire: str = "stream"  #: "stream" (the format's framer) or "can" (the device's DBC)

    def __post_init__(self) -> None:
        if not self.kind:
            object.__setattr__(self, "kind", default_kind(self.type))
        unknown = set(self.roles) - set(ROLES)
        if unknown:
            raise ValueError(f"message type {self.type}: unknown role(s) {sorted(unknown)}")


@dataclass(frozen=True)
class Emulator:
    """A device's emulator: its key in a scenario's ``devices``, the factory
    ``"module:callable"`` (``factory(ctx, settings) -> Emulator``) and whether a scenario runs it
    unless told otherwise."""

    key: str
    factory: str
    default_on: bool = True


@dataclass(frozen=True)
class DeviceKind:
    """One device kind (one wire format).

    ``format``: the format name (gateway ``format``, ``auvgw decode --format``); ``codec``:
    ``"module:attribute"`` of its :class:`~auvgw.drivers.formats.Format`, None for a device
    that only speaks CAN (its ``dbc``; the gateway opens it as format ``can``); ``live``: a gateway
    device may speak it (False for file containers such as ``.V4LOG``); ``table``: the shipped
    table in ``config/`` a site may replace, loaded by ``table_codec`` (``"module:Class"`` with
    ``from_toml(path)``); ``dbc``: the shipped CAN database of the same device; ``options``: the
    name of the device's own options table in the gateway configuration (``msis``,
    ``geoswath``);
    ``host_driver``: ``"module:callable"`` making the gateway's host driver from the device's
    configuration (a polled device); ``emulator``: see :class:`Emulator`; ``protocol_doc``: its
    page in ``docs/protocols/``; ``messages``: the message types it decodes (CAN ones included).
    """

    format: str
    codec: str | None
    messages: tuple[MessageType, ...] = ()
    live: bool = True
    table: str | None = None
    table_codec: str | None = None
    dbc: str | None = None
    options: str | None = None
    host_driver: str | None = None
    emulator: Emulator | None = None
    protocol_doc: str = ""


_D = "auvgw.drivers"
_S = "auvgw.sim_devices"

#: every device kind, in the order emulators are built and listed
DEVICES: tuple[DeviceKind, ...] = (
    DeviceKind(
        "hn100", f"{_D}.hn100:FORMAT", table="hn100.toml", table_codec=f"{_D}.hn100:Hn100Codec",
        dbc="hn100.dbc", emulator=Emulator("ins", f"{_S}.ins:InsEmulator"),
        protocol_doc="hn100.md",
        messages=(
            MessageType("Hn100Nav", "ins", ("ins", "attitude")),
            MessageType("HN100_Sample", "ins", ("ins", "attitude"), wire="can"),
        ),
    ),
    DeviceKind(
        "pd0", f"{_D}.pd0:FORMAT",
        emulator=Emulator("dvl", f"{_S}.dvl:DvlEmulator"), protocol_doc="pd0.md",
        messages=(MessageType("pd0.Ensemble", roles=("velocity", "attitude")),),
    ),
    DeviceKind(
        "pd6", f"{_D}.pd6:FORMAT", protocol_doc="pd6.md",
        messages=(
            MessageType("pd6.SA", roles=("attitude",)),
            MessageType("pd6.TS"),
            MessageType("pd6.WI"), MessageType("pd6.BI", roles=("velocity",)),
            MessageType("pd6.WS"), MessageType("pd6.BS", roles=("velocity",)),
            MessageType("pd6.WE"), MessageType("pd6.BE", roles=("velocity",)),
            MessageType("pd6.WD"), MessageType("pd6.BD"), MessageType("pd6.HM"),
        ),
    ),
    DeviceKind(
        "seanet", f"{_D}.seanet:FORMAT",
        options="msis", host_driver=f"{_D}.seanet.host:from_config",
        emulator=Emulator("msis", f"{_S}.msis:make_emulator"), protocol_doc="seanet.md",
        messages=(
            MessageType("mtHeadData", roles=("sonar",)),
            MessageType("mtAlive"), MessageType("mtVersionData"),
        ),
    ),
    DeviceKind(
        "v4log", f"{_D}.seanet.v4log:FORMAT", live=False,
        protocol_doc="v4log.md",
    ),
    DeviceKind(
        "kongsberg", f"{_D}.kongsberg:FORMAT",
        emulator=Emulator("multibeam", f"{_S}.multibeam:MultibeamEmulator"),
        protocol_doc="kongsberg.md",
        messages=(MessageType("XYZ88", roles=("swath",)), MessageType("Depth", roles=("swath",))),
    ),
    DeviceKind(
        "geoswath", f"{_D}.geoswath:FORMAT", table="geoswath.toml",
        table_codec=f"{_D}.geoswath:GeoSwathCodec", options="geoswath",
        emulator=Emulator("geoswath", f"{_S}.geoswath:GeoSwathEmulator", default_on=False),
        protocol_doc="geoswath.md",
        messages=(MessageType("GeoSwathPing", roles=("samples",)), MessageType("RdfFileHeader")),
    ),
    DeviceKind(
        "ms3a", f"{_D}.ms3a:FORMAT", table="ms3a.toml", table_codec=f"{_D}.ms3a:Ms3aCodec",
        dbc="ms3a.dbc",
        emulator=Emulator("magnetometer", f"{_S}.magnetometer:MagnetometerEmulator"),
        protocol_doc="ms3a.md",
        messages=(
            MessageType("Ms3aSample", "magnetometer", ("field",)),
            MessageType("MS3A_Sample", "magnetometer", ("field",), wire="can"),
        ),
    ),
    DeviceKind(
        "acoustic", f"{_D}.acoustic:FORMAT", table="acoustic.toml",
        table_codec=f"{_D}.acoustic:AcousticCodec",
        emulator=Emulator("acoustic", f"{_S}.acoustic:AcousticEmulator", default_on=False),
        protocol_doc="acoustic.md",
        messages=(MessageType("AcousticReply", roles=("range",)),),
    ),
    DeviceKind(
        "actuators", None, live=False, dbc="actuators.dbc",
        emulator=Emulator("actuators", f"{_S}.actuators:ActuatorEmulator", default_on=False),
        protocol_doc="actuators.md",
        messages=(
            MessageType("ActuatorState", roles=("actuators",), wire="can"),
            MessageType("ActuatorCommand", wire="can"),
        ),
    ),
)  # fmt: skip

_BY_FORMAT = {d.format: d for d in DEVICES}
_BY_TYPE = {m.type: m for d in DEVICES for m in d.messages}


def roles_of(type_name: str) -> tuple[str, ...]:
    """The roles of a message type, first the one it is shown by (empty: not registered)."""
    m = _BY_TYPE.get(type_name)
    return () if m is None else m.roles


def kind_of(type_name: str) -> str:
    """The public ``<kind>`` key segment of a message type name (see :class:`MessageType`)."""
    m = _BY_TYPE.get(type_name)
    return m.kind if m is not None else default_kind(type_name)


def device(fmt: str) -> DeviceKind:
    """The record of format ``fmt``; :class:`KeyError` names the known ones."""
    try:
        return _BY_FORMAT[fmt]
    except KeyError:
        raise KeyError(f"unknown format {fmt!r}; known: {', '.join(_BY_FORMAT)}") from None


def device_formats() -> tuple[str, ...]:
    """The formats a gateway device may speak: every live format, then ``can``."""
    return (*(d.format for d in DEVICES if d.live), CAN_FORMAT)


def message_types() -> Iterator[tuple[DeviceKind, MessageType]]:
    """Every registered message type with its device kind."""
    for d in DEVICES:
        for m in d.messages:
            yield d, m


def types_with_role(role: str) -> frozenset[str]:
    """Type names of the messages that play ``role`` (one of :data:`ROLES`)."""
    if role not in ROLES:
        raise KeyError(f"unknown role {role!r}; known: {', '.join(ROLES)}")
    return frozenset(m.type for _, m in message_types() if role in m.roles)


def kinds_with_role(role: str) -> tuple[str, ...]:
    """Bus ``<kind>`` segments of the messages that play ``role``, sorted."""
    return tuple(sorted({kind_of(t) for t in types_with_role(role)}))


def emulators() -> tuple[Emulator, ...]:
    """The emulators, in build order."""
    return tuple(d.emulator for d in DEVICES if d.emulator is not None)


def load(target: str) -> Any:
    """The object a ``"module:attribute"`` string names (imports the module)."""
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)
