"""A site's own device through the ``auvgw.devices`` entry point, without a fork.

The site's distribution is built here as it is installed: a ``.dist-info`` folder (``METADATA``,
``entry_points.txt``) beside its package, on the ``sys.path`` (``PYTHONPATH``) of a real ``auvgw``
process; no pip. Its device is a toy depth sensor with its own declarative line table
(``$TOYD,<counter>,<depth m>*HH``), the in-tree pattern of ``drivers/acoustic.py``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import typing
from functools import reduce
from importlib import metadata
from pathlib import Path

import pytest

from auvgw.drivers import registry, roles
from auvgw.drivers.can_codec import shipped_can_types
from auvgw.drivers.spec import resolve_type
from auvgw.fusion import adapters
from auvgw.fusion.samples import DvlSample
from auvgw.testing.format_samples import PD6_LINES

REPO = Path(__file__).resolve().parents[2]

TOY_TABLE = """\
[line]
start = "$"
header = "TOYD"
separator = ","
terminator = "\\r\\n"
max_length = 40

[line.checksum]
kind = "xor8"
delimiter = "*"
hex_case = "upper"

[[fields]]
name = "counter"
width = 4
sign = "never"

[[fields]]
name = "depth"
width = 7
decimals = 2
sign = "never"
units = "m"
"""

#: the record module: imports nothing but the registry (reading it costs nothing)
TOY_RECORD = """\
from pathlib import Path

from auvgw.drivers.registry import DeviceKind, MessageType

DEVICE = DeviceKind(
    "toy", "toy_device.codec:FORMAT",
    table=str(Path(__file__).with_name("toy.toml")), table_codec="toy_device.codec:ToyCodec",
    messages=(MessageType("ToyDepth"),),
)
"""

TOY_CODEC = """\
from auvgw.drivers.formats import Format
from auvgw.drivers.tablecodec import AsciiLineCodec, AsciiLineFramer, shipped_codec


class ToyCodec(AsciiLineCodec, device="toy"):
    DOC = "Toy depth sensor line. depth: m below the surface; counter: line count."
    REQUIRED_FIELDS = {"counter": "", "depth": "m"}


default_codec, __getattr__ = shipped_codec(ToyCodec.from_toml, ToyCodec.MESSAGE)


class ToyFramer(AsciiLineFramer, shipped=default_codec):
    pass


FORMAT = Format.of_codec("toy", "a toy depth sensor (a site's own device)", default_codec)
"""


def _line(counter: int, depth: float) -> bytes:
    body = f"TOYD,{counter:04d},{depth:07.2f}"
    xor = reduce(lambda a, b: a ^ b, body.encode(), 0)
    return f"${body}*{xor:02X}\r\n".encode()


def _dist(site: Path, name: str, entry_points: str, files: dict[str, str]) -> None:
    """An installed distribution ``name`` 0.1 in ``site``: its dist-info and its files."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[auvgw.devices]\n{entry_points}\n")
    for rel, text in files.items():
        (site / rel).parent.mkdir(parents=True, exist_ok=True)
        (site / rel).write_text(text)


def _toy(site: Path) -> None:
    _dist(site, "toy-device", "toy = toy_device:DEVICE", {
        "toy_device/__init__.py": TOY_RECORD,
        "toy_device/codec.py": TOY_CODEC,
        "toy_device/toy.toml": TOY_TABLE,
    })  # fmt: skip


def _broken(site: Path) -> None:
    """Two bad plugins: one that cannot import, one that takes the built-in name ``pd0``."""
    _dist(site, "broken-device", "broken = broken_device:DEVICE", {
        "broken_device/__init__.py": "import no_such_module_anywhere\n",
    })  # fmt: skip
    _dist(site, "clashing-device", "mypd0 = clashing_device:DEVICE", {
        "clashing_device/__init__.py": "from auvgw.drivers.registry import DeviceKind\n"
        "DEVICE = DeviceKind('pd0', 'clashing_device:FORMAT')\n",
    })  # fmt: skip


@pytest.fixture
def site(tmp_path: Path) -> Path:
    s = tmp_path / "site-packages"
    s.mkdir()
    return s


@pytest.fixture
def auvgw(site: Path):
    """``auvgw ARGS`` in a process whose ``sys.path`` has the site's distributions."""

    def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, "PYTHONPATH": str(site)}
        return subprocess.run(
            [sys.executable, "-m", "auvgw", *map(str, args)],
            capture_output=True, text=True, env=env, timeout=60, cwd=site,
        )  # fmt: skip

    return run


@pytest.mark.e2e  # runs auvgw processes
def test_a_site_device_decodes_and_is_a_gateway_format(site, auvgw, tmp_path):
    _toy(site)
    capture = tmp_path / "toy.bin"
    capture.write_bytes(_line(1, 12.5) + b"noise$TOYD" + _line(2, 13.25) + _line(9999, 0.0))
    r = auvgw("decode", "--format", "toy", capture)
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in r.stdout.splitlines()]
    assert [(m["type"], m["counter"], m["depth"]) for m in rows] == [
        ("ToyDepth", 1, 12.5), ("ToyDepth", 2, 13.25), ("ToyDepth", 9999, 0.0),
    ]  # fmt: skip
    summary = json.loads(r.stderr.splitlines()[-1])
    assert summary["frames"] == 3 and summary["skipped_bytes"] == len(b"noise$TOYD")

    # the gateway takes it, with the site-table route of the registry's table_codec
    cfg = tmp_path / "gateway.toml"
    cfg.write_text(
        f'[devices.depth]\nformat = "toy"\ntable = "{site}/toy_device/toy.toml"\n'
        f'transport = {{ kind = "file", path = "{capture}" }}\n'
        '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "file", path = "dvl.bin" }\n'
    )
    r = auvgw("run", "--check", "--config", cfg)
    assert (r.returncode, r.stderr) == (0, ""), r.stderr
    assert r.stdout.startswith(f"{cfg}: ok (2 device(s)")


@pytest.mark.e2e  # runs auvgw processes
def test_bad_plugins_are_one_line_each_and_the_builtins_keep_working(site, auvgw, tmp_path):
    _toy(site)
    _broken(site)
    capture = tmp_path / "toy.bin"
    capture.write_bytes(_line(7, 1.0))
    r = auvgw("decode", "--format", "toy", capture)
    assert r.returncode == 0, r.stderr
    assert [json.loads(x)["counter"] for x in r.stdout.splitlines()] == [7]
    errors = sorted(r.stderr.splitlines()[:-1])  # the last line: the summary
    assert errors == [
        "auvgw: device plugin 'broken' (broken_device:DEVICE, distribution broken-device 0.1): "
        "not loaded: ModuleNotFoundError: No module named 'no_such_module_anywhere'",
        "auvgw: device plugin 'mypd0' (clashing_device:DEVICE, distribution clashing-device "
        "0.1): not loaded: its format 'pd0' collides with a built-in device",
    ]
    lines = tmp_path / "dvl.pd6"
    lines.write_bytes(b"".join(PD6_LINES))
    r = auvgw("decode", "--format", "pd6", "--quiet", lines)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stderr.splitlines()[-1])
    assert (summary["frames"], summary["bad_frames"]) == (len(PD6_LINES), 0)


def _records(site: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[tuple, tuple[str, ...]]:
    monkeypatch.syspath_prepend(str(site))
    eps = [ep for d in metadata.distributions(path=[str(site)]) for ep in d.entry_points]
    return registry.plugin_records(registry.BUILTIN, sorted(eps, key=lambda e: e.name))


def test_plugin_records_refuse_what_is_not_a_new_device(site, monkeypatch):
    rec = "from auvgw.drivers.registry import DeviceKind, Emulator, MessageType\n"
    _dist(site, "p-one", "a_notarecord = p_one:THING\nb_badtarget = p_one:BAD\n"
          "c_type = p_one:TYPE\nd_emu = p_one:EMU\ne_good = p_one:GOOD\nf_again = p_one:GOOD\n"
          "g_kind = p_one:MAG\nh_mag = p_one:MAG2",
          {"p_one.py": rec + "THING = 3\n"
           "BAD = DeviceKind('x1', 'no_colon_here')\n"
           "TYPE = DeviceKind('x2', 'm:F', messages=(MessageType('Hn100Nav'),))\n"
           "EMU = DeviceKind('x3', 'm:F', emulator=Emulator('dvl', 'm:E'))\n"
           "GOOD = DeviceKind('x4', 'm:F', messages=(MessageType('X4Msg'),))\n"
           "MAG = DeviceKind('x5', 'm:F', messages=(MessageType('X5Mag', roles=('field',)),))\n"
           "MAG2 = DeviceKind('x6', 'm:F', messages=(MessageType('X6Mag', 'magnetometer', "
           "('field',)),))\n"})  # fmt: skip
    records, errors = _records(site, monkeypatch)
    assert [r.format for r in records] == ["x4", "x6"]
    where = "(p_one:{}, distribution p-one 0.1): not loaded: "
    assert list(errors) == [
        f"device plugin 'a_notarecord' {where.format('THING')}names a int, not a "
        "registry.DeviceKind",
        f"device plugin 'b_badtarget' {where.format('BAD')}'no_colon_here' is not "
        "'module:attribute'",
        f"device plugin 'c_type' {where.format('TYPE')}its message type 'Hn100Nav' collides "
        "with a built-in device",
        f"device plugin 'd_emu' {where.format('EMU')}its emulator key 'dvl' collides with a "
        "built-in device",
        f"device plugin 'f_again' {where.format('GOOD')}its format 'x4' collides with device "
        "plugin 'e_good'",
        f"device plugin 'g_kind' {where.format('MAG')}its message type 'X5Mag' of role 'field' "
        "has kind 'x5mag': the consumers of 'field' read kind 'magnetometer' only",
    ]


def test_the_installed_registry_is_the_builtins_when_no_plugin_is_installed():
    installed = metadata.entry_points(group=registry.ENTRY_POINT_GROUP)
    assert registry.DEVICES[: len(registry.BUILTIN)] == registry.BUILTIN
    assert len(registry.DEVICES) == len(registry.BUILTIN) + len(installed) - len(
        registry.PLUGIN_ERRORS
    )


# -- roles as Protocols (drivers/roles.py) ---------------------------------------------------------


def _units(f: dataclasses.Field) -> str | None:
    """The decoded units a message class declares for a field (its table's wire row or its DBC
    signal), None when it declares none."""
    w = f.metadata.get("wire")
    return w.units if w is not None else f.metadata.get("units")


def _problems(cls: type, protocol: type) -> list[str]:
    """What ``cls`` lacks of ``protocol``: each member a field of the member's type and declared
    unit, or a property (of that return type when annotated)."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    out = []
    for name, (tp, unit) in roles.members(protocol).items():
        if name in fields:
            got, units = hints.get(name), _units(fields[name])
            if got != tp and not (tp is float and got in (float, int)):
                out.append(f"{name}: {got} is not {tp}")
            if units is not None and units != unit:
                out.append(f"{name}: declared in {units!r}, the role reads {unit!r}")
        elif isinstance(getattr(cls, name, None), property):
            got = typing.get_type_hints(getattr(cls, name).fget).get("return", tp)
            if got != tp:
                out.append(f"{name}: property of {got}, not {tp}")
        else:
            out.append(f"{name}: missing")
    return out


def _role_types() -> list[tuple[str, str]]:
    return [(m.type, r) for _, m in registry.message_types() for r in m.roles
            if r in roles.ROLE_PROTOCOLS]  # fmt: skip


@pytest.fixture(scope="module")
def message_classes() -> dict[str, type]:
    for d in registry.DEVICES:
        if d.codec is not None:
            registry.load(d.codec)
    shipped_can_types()
    classes = {t: resolve_type(t) for t, _ in _role_types()}
    assert None not in classes.values(), classes
    return classes  # type: ignore[return-value]


@pytest.mark.parametrize(("type_name", "role"), _role_types())
def test_every_message_type_with_a_role_has_what_its_consumers_read(
    message_classes, type_name, role
):
    """Structurally, over the declared fields and their units; a type read by an adapter of its
    own (PD0, PD6 bottom track) is named in fusion's OWN_ADAPTERS, and only while it lacks the
    role's members (so the list cannot go stale)."""
    problems = _problems(message_classes[type_name], roles.ROLE_PROTOCOLS[role])
    own = type_name in adapters.OWN_ADAPTERS.get(role, frozenset())
    assert bool(problems) == own, problems or f"{type_name} is {role} now: not in OWN_ADAPTERS"


def test_the_structural_check_refuses_a_wrong_unit_a_missing_member_and_a_wrong_type():
    @dataclasses.dataclass(frozen=True)
    class Compass:
        roll: float = dataclasses.field(default=0.0, metadata={"units": "deg"})
        pitch: int = 0

    assert _problems(Compass, roles.Attitude) == [
        "roll: declared in 'deg', the role reads 'rad'",
        "heading: missing",
    ]
    assert _problems(Compass, roles.Field)[:1] == ["counter: missing"]
    # pitch an int passes a float member (a DBC's unscaled signal); a str would not
    Bad = dataclasses.make_dataclass("Bad", [("range", str), ("bearing", float),
                                             ("depression", float)])  # fmt: skip
    assert _problems(Bad, roles.Range) == ["range: <class 'str'> is not <class 'float'>"]


def test_the_magnetic_stage_reads_a_can_magnetometer_sample_as_a_field(message_classes):
    """The CAN sample has bx, by, bz (the Field role) but not the serial class's ``b_nt``
    property, which the stage used to read: a CAN magnetometer as its source raised."""
    from auvgw.stages.magnetic import MagneticStage, config_from_scenario

    can = message_classes["MS3A_Sample"](counter=5, bx=1.5, by=-2.0, bz=40000.0, status=0)
    stage = MagneticStage(config_from_scenario(REPO / "config" / "scenarios" / "beacons_amb.json"))
    stage.feed("magnetometer_can", 2_000_000_000, can)
    held = list(stage._mags.release(math.inf))
    assert [(t, list(b)) for t, b in held] == [(2.0, [1.5, -2.0, 40000.0])]


@dataclasses.dataclass(frozen=True)
class SiteDvl:
    """A site's own DVL message, read by the velocity role's members."""

    TYPE: typing.ClassVar[str] = "site.Dvl"
    time: float
    velocity: tuple[float, float, float]
    frame: str = "body"
    bottom_lock: bool = True


def test_fusion_reads_a_velocity_type_without_an_adapter_of_its_own_by_its_role(monkeypatch):
    monkeypatch.setattr(adapters, "VELOCITY_TYPES", adapters.VELOCITY_TYPES | {"site.Dvl"})
    a = adapters.MessageAdapter(ins_device="ins", dvl_device="dvl")
    s1 = a.adapt("dvl", 100.0, SiteDvl(10.0, (1.0, 0.1, 0.0)))
    s2 = a.adapt("dvl", 100.6, SiteDvl(10.5, (1.2, 0.0, 0.0), bottom_lock=False))
    assert s1 == DvlSample(t=100.0, velocity=(1.0, 0.1, 0.0), bottom_lock=True, frame="body")
    assert s2 is not None and s2.t == pytest.approx(100.5) and not s2.bottom_lock
    assert all(math.isnan(c) for c in s2.velocity)
    assert a.adapt("dvl", 101.0, SiteDvl(11.0, (1.0, 0.0, 0.0), frame="ship")) is None
    assert (a.stats.dvl, a.stats.errors) == (2, 1)
    assert a.stats.last_error == (
        "dvl: SiteDvl: frame 'ship' is not one of instrument, body, earth"
    )
    assert adapters.dvl_from_velocity(SiteDvl(1.0, (0.0, 0.0, 0.0))).frame == "body"
    with pytest.raises(adapters.AdapterError, match=r"^SiteDvl: no field 'roll' .* role 'ins'"):
        adapters.ins_from_hn100(SiteDvl(1.0, (0.0, 0.0, 0.0)))  # type: ignore[arg-type]
    with pytest.raises(adapters.AdapterError, match=r"no field 'time' .* role 'velocity'"):
        adapters.dvl_from_velocity(DvlSample(t=1.0, velocity=(0.0, 0.0, 0.0)))  # type: ignore[arg-type]
