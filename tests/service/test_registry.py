"""The device registry is the one list of devices: every other list is derived from it, and the
public kinds in docs/bus.md are the registry's."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from auvgw.drivers import registry

ROOT = Path(__file__).resolve().parents[2]


def test_derived_lists_are_the_registry() -> None:
    from auvgw.config.gateway import DEVICE_FORMATS
    from auvgw.config.scenario import Devices
    from auvgw.drivers.formats import FORMATS
    from auvgw.fusion.adapters import ATTITUDE_TYPES, INS_TYPES, VELOCITY_TYPES
    from auvgw.sim_devices.runner import DEVICE_ORDER, FACTORIES

    assert list(FORMATS) == ["hn100", "pd0", "pd6", "seanet", "v4log", "kongsberg", "geoswath",
                             "ms3a", "acoustic"]  # fmt: skip
    assert DEVICE_FORMATS == ("hn100", "pd0", "pd6", "seanet", "kongsberg", "geoswath", "ms3a",
                              "acoustic", "can")  # v4log is a file, not a device  # fmt: skip
    order = ("ins", "dvl", "msis", "multibeam", "geoswath", "magnetometer", "acoustic",
             "actuators")  # fmt: skip
    assert order == DEVICE_ORDER and tuple(FACTORIES) == order
    assert tuple(Devices.model_fields) == order
    assert not Devices().acoustic.enabled and Devices().ins.enabled
    assert not Devices().geoswath.enabled  # the Kongsberg multibeam is the default one
    assert not Devices().actuators.enabled  # a closed-loop scenario turns it on
    assert {"Hn100Nav", "HN100_Sample"} == INS_TYPES
    assert INS_TYPES | {"pd0.Ensemble", "pd6.SA"} == ATTITUDE_TYPES
    assert {"pd0.Ensemble", "pd6.BI", "pd6.BS", "pd6.BE"} == VELOCITY_TYPES


def test_every_record_resolves() -> None:
    from auvgw.drivers.formats import get_format
    from auvgw.ground.paths import config_file

    for d in registry.DEVICES:
        if d.codec is None:  # a device that only speaks CAN: its DBC, no byte-stream format
            assert d.dbc is not None and not d.live and all(m.wire == "can" for m in d.messages)
            with pytest.raises(KeyError, match="only speaks CAN"):
                get_format(d.format)
        else:
            assert get_format(d.format).name == d.format
        assert (ROOT / "docs" / "protocols" / d.protocol_doc).is_file(), d.format
        for name in (d.table, d.dbc):
            assert name is None or config_file(name).is_file(), (d.format, name)
        if d.table_codec is not None:
            assert hasattr(registry.load(d.table_codec), "from_toml")
        if d.host_driver is not None:
            assert callable(registry.load(d.host_driver))
        if d.emulator is not None:
            assert callable(registry.load(d.emulator.factory))


def test_kinds_follow_one_rule() -> None:
    assert registry.kind_of("pd0.Ensemble") == "ensemble"
    assert registry.kind_of("HN100_Sample") == registry.kind_of("Hn100Nav") == "ins"
    assert registry.kind_of("MS3A_Sample") == "magnetometer"
    assert registry.kind_of("mtSendData") == "mtsenddata"  # not listed: the first rule
    shared = {}
    for _, m in registry.message_types():
        if m.kind != registry.default_kind(m.type):  # a quantity name: two wires or more
            shared.setdefault(m.kind, []).append(m.type)
    assert all(len(types) >= 2 for types in shared.values()), shared
    assert registry.kinds_with_role("sonar") == ("mtheaddata",)
    with pytest.raises(ValueError, match="unknown role"):
        registry.MessageType("X", roles=("colour",))


def test_bus_doc_lists_the_public_kinds() -> None:
    text = (ROOT / "docs" / "bus.md").read_text()
    table = text[text.index("## Public kinds") :].split("\n\n")[2]
    documented = set()
    for row in table.splitlines()[2:]:
        documented |= set(re.findall(r"`([a-z0-9]+)`", row.split("|")[1]))
    assert documented == {m.kind for _, m in registry.message_types()}


@pytest.mark.e2e
def test_decode_help_lists_the_registered_formats() -> None:
    out = subprocess.run([sys.executable, "-m", "auvgw", "decode", "--help"],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    choices = re.search(r"\{([a-z0-9,]+)\}", out)
    assert choices is not None and choices.group(1).split(",") == sorted(
        d.format for d in registry.DEVICES if d.codec is not None
    )
    assert "hn100/geoswath/ms3a/acoustic" in out


@pytest.mark.e2e
def test_sim_help_lists_the_emulators() -> None:
    out = subprocess.run([sys.executable, "-m", "auvgw", "sim", "--help"],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    assert "ins,dvl,msis,multibeam,geoswath,magnetometer,acoustic,actuators" in "".join(out.split())


def test_gateway_checks_come_from_the_records(tmp_path: Path) -> None:
    from auvgw.config.gateway import ConfigError, parse_gateway_config
    from auvgw.decoding import make_decoders

    def cfg(**dev: object) -> dict[str, object]:
        return {"devices": {"d": {"transport": {"kind": "serial", "url": "/dev/null"}, **dev}}}

    site = tmp_path / "ac.toml"
    site.write_text((ROOT / "config" / "acoustic.toml").read_text())
    dec = make_decoders(parse_gateway_config(cfg(format="acoustic", table=str(site))))["d"]
    assert dec.format is not None and f"[table {site}]" in dec.format.summary
    with pytest.raises(ConfigError, match=r"'table' only applies to formats 'hn100', 'geoswath', "
                                          r"'ms3a', 'acoustic', not 'pd0'"):  # fmt: skip
        parse_gateway_config(cfg(format="pd0", table="x.toml"))
    with pytest.raises(ConfigError, match=r"'msis' only applies to format 'seanet', not 'ms3a'"):
        parse_gateway_config(cfg(format="ms3a", msis={}))
    assert parse_gateway_config(cfg(format="seanet")).devices["d"].msis is not None
