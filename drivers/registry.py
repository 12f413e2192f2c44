"""The device registry: one record per device kind, the one place a device is declared.

Every list of devices the rest of the project needs is derived from :data:`DEVICES`: the format
names (``auvgw decode --format``, the gateway's ``format`` key, :mod:`auvgw.drivers.formats`),
which formats take a replaceable table, a DBC or an options table, the decoder and host-driver
factories (:mod:`auvgw.decoding`, :mod:`auvgw.hostdrivers`), the emulators and their order
(:mod:`auvgw.sim_devices.runner`, the scenario's ``devices``), the bus ``<kind>`` of every message
type (``auv/<v>/sensor/<device>/<kind>``, docs/bus.md) and the role each type plays for fusion,
SLAM and the Rerun logger.

A site adds its own device without a fork: an installed distribution whose entry points in the
group :data:`ENTRY_POINT_GROUP` (``auvgw.devices``) name a :class:`DeviceKind` has it appended
after the built-ins (:func:`plugin_records`); one that fails to load or reuses a built-in name is
left out with a one-line error naming its distribution and entry point (:data:`PLUGIN_ERRORS`,
logged), and the built-ins keep working (docs/adding-a-device.md).

It lives in ``drivers/`` because a device kind is first a wire protocol; it names codecs,
emulators and host drivers by ``"module:attribute"`` strings and imports none of them, so reading
it costs nothing (``auvgw --help`` imports no numpy) and no table is read until a format is used.
"""

from __future__ import annotations

import importlib
import logging
import os
import re
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported when a distribution declares the group (some 50-100 ms)
    from importlib import metadata

__all__ = [
    "BUILTIN",
    "CAN_FORMAT",
    "DEVICES",
    "ENTRY_POINT_GROUP",
    "ONE_KIND_ROLES",
    "PLUGIN_ERRORS",
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
    "plugin_records",
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

#: the device kinds shipped with auvgw, in the order emulators are built and listed
BUILTIN: tuple[DeviceKind, ...] = (
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

#: the entry-point group a site's distribution names its own :class:`DeviceKind` records in
ENTRY_POINT_GROUP = "auvgw.devices"

log = logging.getLogger(__name__)


def _names(d: DeviceKind) -> list[tuple[str, str]]:
    """The names a record claims that no other record may: its format, its message types and
    its emulator's scenario key."""
    out = [("format", d.format), *(("message type", m.type) for m in d.messages)]
    if d.emulator is not None:
        out.append(("emulator key", d.emulator.key))
    return out


def _targets(d: DeviceKind) -> list[str]:
    """The ``"module:attribute"`` strings of a record (checked in form, not imported)."""
    named = [d.codec, d.table_codec, d.host_driver, d.emulator.factory if d.emulator else None]
    return [t for t in named if t is not None]


#: roles whose consumers subscribe to one bus kind (the landmark stage's ``sonar``, the magnetic
#: stage's ``field`` and ``range``): a plugin's type of such a role takes the built-ins' kind
ONE_KIND_ROLES = ("sonar", "field", "range")


def _kind_clash(record: DeviceKind, builtin: Iterable[DeviceKind]) -> str | None:
    """Why a record's message type of a :data:`ONE_KIND_ROLES` role cannot join (its kind is
    not the one its consumers read), or None."""
    for m in record.messages:
        for role in set(m.roles) & set(ONE_KIND_ROLES):
            kinds = sorted({b.kind for d in builtin for b in d.messages if role in b.roles})
            if kinds and m.kind not in kinds:
                return (f"its message type {m.type!r} of role {role!r} has kind {m.kind!r}: the "
                        f"consumers of {role!r} read kind {kinds[0]!r} only")  # fmt: skip
    return None


def _group_declared(group: str) -> bool:
    """Whether a distribution on ``sys.path`` declares entry points of ``group`` (its
    ``*.dist-info`` / ``*.egg-info`` ``entry_points.txt``): a few ms, where importing
    :mod:`importlib.metadata` to ask costs more than the rest of the registry. Zipped
    distributions are not looked in."""
    header = re.compile(rf"^\s*\[\s*{re.escape(group)}\s*\]", re.M)
    for entry in sys.path:
        try:
            with os.scandir(entry or ".") as it:
                infos = [e.path for e in it if e.name.endswith((".dist-info", ".egg-info"))]
        except OSError:  # a zip, a missing folder
            continue
        for info in infos:
            try:
                with open(os.path.join(info, "entry_points.txt"), encoding="utf-8") as f:
                    if header.search(f.read()):
                        return True
            except OSError:
                continue
    return False


def plugin_records(
    builtin: Iterable[DeviceKind], entry_points: Iterable[metadata.EntryPoint] | None = None
) -> tuple[tuple[DeviceKind, ...], tuple[str, ...]]:
    """The device kinds the ``auvgw.devices`` entry points name (default: those of the installed
    distributions), in entry-point order, and one line per entry point left out: one that fails
    to import, names something that is not a :class:`DeviceKind`, a malformed
    ``"module:attribute"``, a type of a :data:`ONE_KIND_ROLES` role under another kind, or a
    format, message type or emulator key that a built-in (or an earlier plugin) already has.
    Each line names the distribution and the entry point."""
    if entry_points is None:
        if not _group_declared(ENTRY_POINT_GROUP):
            return (), ()
        from importlib import metadata

        entry_points = metadata.entry_points(group=ENTRY_POINT_GROUP)
    builtin = tuple(builtin)
    taken = {n: "a built-in device" for d in builtin for n in _names(d)}
    records: list[DeviceKind] = []
    errors: list[str] = []
    for ep in entry_points:
        dist = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "unknown"
        where = f"device plugin {ep.name!r} ({ep.value}, distribution {dist})"
        try:
            record = ep.load()
        except Exception as exc:  # a plugin's import may raise anything: say it, run without it
            errors.append(f"{where}: not loaded: {type(exc).__name__}: {exc}")
            continue
        if not isinstance(record, DeviceKind):
            errors.append(f"{where}: not loaded: names a {type(record).__name__}, not a "
                          "registry.DeviceKind")  # fmt: skip
            continue
        bad = [t for t in _targets(record) if not all(t.partition(":")[::2])]
        clash = [(what, n, taken[(what, n)]) for what, n in _names(record) if (what, n) in taken]
        kind_clash = _kind_clash(record, builtin)
        if bad:
            errors.append(f"{where}: not loaded: {bad[0]!r} is not 'module:attribute'")
        elif kind_clash:
            errors.append(f"{where}: not loaded: {kind_clash}")
        elif clash:
            what, n, owner = clash[0]
            errors.append(f"{where}: not loaded: its {what} {n!r} collides with {owner}")
        else:
            records.append(record)
            taken.update(dict.fromkeys(_names(record), f"device plugin {ep.name!r}"))
    return tuple(records), tuple(errors)


_PLUGINS, PLUGIN_ERRORS = plugin_records(BUILTIN)
for _line in PLUGIN_ERRORS:
    log.error("auvgw: %s", _line)

#: every device kind: the built-ins, then the sites' own (entry points ``auvgw.devices``)
DEVICES: tuple[DeviceKind, ...] = BUILTIN + _PLUGINS

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
        failed = "".join(f"; {e}" for e in PLUGIN_ERRORS)
        raise KeyError(f"unknown format {fmt!r}; known: {', '.join(_BY_FORMAT)}{failed}") from None


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
