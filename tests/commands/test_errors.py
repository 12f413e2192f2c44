"""One exception tree: every family under AuvgwError, the old classes re-parented (still
ValueErrors where they were), decode errors carrying field and offset, and one settings
loader with one-line "file: field: message" errors."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import BaseModel, ConfigDict, Field

from auvgw.cli import main
from auvgw.config.gateway import ConfigError as GatewayConfigError
from auvgw.config.scenario import ScenarioError
from auvgw.config.transport import TransportConfigError
from auvgw.drivers.can_codec import CanCodecError
from auvgw.drivers.framing import DecodeError, FrameError
from auvgw.drivers.ms3a import default_codec
from auvgw.drivers.spec import WireError, decode_block, message, wire
from auvgw.drivers.tablecodec import LineError, TableError
from auvgw.drivers.transports import Disconnected, TransportError, TransportOpenError
from auvgw.fusion.adapters import AdapterError
from auvgw.fusion.calibrate import CalibrationError
from auvgw.fusion.csvlog import LogError
from auvgw.ground.errors import AuvgwError, ConfigError, DataError, UserError, load_settings
from auvgw.ground.errors import TransportError as RootTransportError
from auvgw.recording import RecordingError
from auvgw.stages.fusion import SettingsError


def test_families():
    for cls in (FrameError, DecodeError, WireError, LineError, CanCodecError, AdapterError,
                LogError, CalibrationError, RecordingError):  # fmt: skip
        assert issubclass(cls, DataError) and issubclass(cls, ValueError), cls
    for cls in (GatewayConfigError, TableError, TransportConfigError, ScenarioError,
                SettingsError):  # fmt: skip
        assert issubclass(cls, ConfigError) and issubclass(cls, ValueError), cls
    assert GatewayConfigError is ConfigError and TransportError is RootTransportError
    for cls in (TransportOpenError, Disconnected):
        assert issubclass(cls, TransportError)
    for cls in (DataError, ConfigError, TransportError, UserError):
        assert issubclass(cls, AuvgwError)


@message
class _T:
    a: int = wire("u16", 0)
    b: int = wire("u32", 2)


def test_decode_errors_carry_field_and_offset():
    with pytest.raises(WireError) as info:
        decode_block(_T, b"\x01\x00\x02", base=0)
    e = info.value
    assert (e.field, e.offset) == ("_T.b", 2) and str(e) == f"_T.b: {e.reason}"
    assert "needs bytes 2..5" in e.reason
    with pytest.raises(DecodeError) as dinfo:
        default_codec().decode(b"$MS3A,1,2\xff,3,4*00\r\n")
    d = dinfo.value
    assert d.source == "ms3a" and d.offset is not None and str(d).startswith("ms3a: ")
    frame = FrameError("dvl.pd0", 17, "bad checksum")
    assert str(frame) == "dvl.pd0: bad frame at byte offset 17: bad checksum"
    assert (frame.offset, frame.reason) == (17, "bad checksum")


class _Settings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rate_hz: float = Field(gt=0)
    name: str = "x"


def test_load_settings_one_line_per_problem(tmp_path: Path):
    good = tmp_path / "s.toml"
    good.write_text("[fusion]\nrate_hz = 2.5\n")
    assert load_settings(good, _Settings, table="fusion").rate_hz == 2.5
    bad = tmp_path / "bad.toml"
    bad.write_text("rate_hz = -1\nnmae = 'y'\n")
    with pytest.raises(ConfigError) as info:
        load_settings(bad, _Settings)
    assert str(info.value).splitlines() == [
        f"{bad}: rate_hz: Input should be greater than 0 (got -1)",
        f"{bad}: nmae: unknown key",
    ]
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    with pytest.raises(SettingsError, match=r"broken\.json: not valid JSON"):
        load_settings(broken, _Settings, SettingsError)
    with pytest.raises(ConfigError, match=r"missing\.toml: cannot read"):
        load_settings(tmp_path / "missing.toml", _Settings)


def test_cli_prints_config_and_data_errors_as_one_line(tmp_path: Path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert main(["sim", "--scenario", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("auvgw sim: error: ") and err.count("\n") == 1
