"""Configuration and scenario files never end in a traceback (issue 27, item 6).

One field of a valid gateway configuration or shipped scenario mutated (type edges, wrong types,
huge and deep values, removed and unknown keys, two devices on one port), run through the real
CLI entry with ``--check``: a usable file or one line per problem naming the file, exit 2. The
sweep of thousands is ``benchmarks/config_fuzz.py`` (figures in docs/reliability.md). And the
largest values the models accept are safe where they reach a reader thread.
"""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.config.gateway import MAX_DEVICES
from auvgw.config.transport import MAX_CHUNK_BYTES, MAX_RECEIVE_BUFFER_BYTES
from auvgw.drivers.transports import EndOfStream, open_transport
from auvgw.ground.errors import MAX_DOCUMENT_BYTES
from auvgw.testing.config_fuzz import (
    SCENARIOS,
    _deep,
    base_gateway,
    check_file,
    mutated,
    to_toml,
    write_case,
)

_FUZZ = settings(
    max_examples=300,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def gateway_base(folder: Path) -> dict:
    return base_gateway(folder)


def test_the_bases_are_valid(folder: Path, gateway_base: dict) -> None:
    assert check_file("run", write_case(folder, "base", "run", gateway_base))[0] == "ok"
    for scn in SCENARIOS:
        path = write_case(folder, scn.stem, "sim", json.loads(scn.read_text()))
        assert check_file("sim", path) == ("ok", "")


@_FUZZ
@given(data=st.data())
def test_gateway_field_mutations(folder: Path, gateway_base: dict, data: st.DataObject) -> None:
    doc = data.draw(mutated(gateway_base))
    outcome, text = check_file("run", write_case(folder, "case", "run", doc))
    assert outcome in ("ok", "error"), text


@_FUZZ
@given(data=st.data())
def test_scenario_field_mutations(folder: Path, data: st.DataObject) -> None:
    scn = data.draw(st.sampled_from(SCENARIOS))
    doc = data.draw(mutated(json.loads(scn.read_text())))
    outcome, text = check_file("sim", write_case(folder, "case", "sim", doc))
    assert outcome in ("ok", "error"), text


def _devices(doc: dict) -> dict:
    return doc["devices"]


#: the defects of issue 27 (item 6): each the one line it now gets
NAMED = {
    "missing_password_file": (
        lambda d: d["bus"]["auth"].update(password_file="absent.txt"),
        "bus.auth.password_file: no such file",
    ),
    "deep_array": (
        lambda d: d.update(vehicle=_deep(40)),
        "arrays/tables nested too deep (40 levels at character",
    ),
    "byte_rate_inf": (
        lambda d: _devices(d)["dvl"]["transport"].update(byte_rate=float("inf")),
        "devices.dvl.transport.byte_rate: Input should be a finite number",
    ),
    "receive_buffer_huge": (
        lambda d: _devices(d)["mb"]["transport"].update(receive_buffer_bytes=2**63 - 1),
        f"devices.mb.transport.receive_buffer_bytes: Input should be less than or equal to "
        f"{MAX_RECEIVE_BUFFER_BYTES}",
    ),
    "chunk_size_huge": (
        lambda d: _devices(d)["dvl"]["transport"].update(chunk_size=2**63 - 1),
        f"devices.dvl.transport.chunk_size: Input should be less than or equal to "
        f"{MAX_CHUNK_BYTES}",
    ),
    "status_period_tiny": (
        lambda d: d.update(status_period_s=1e-9),
        "status_period_s: Input should be greater than or equal to 0.05",
    ),
    "enabled_yes": (
        lambda d: _devices(d)["ins"].update(enabled="yes"),
        "devices.ins.enabled: Input should be a valid boolean (got 'yes')",
    ),
    "baud_string": (
        lambda d: _devices(d)["ins"]["transport"].update(baud="115200"),
        "devices.ins.transport.baud: Input should be a valid integer",
    ),
    "baud_float": (
        lambda d: _devices(d)["ins"]["transport"].update(baud=115200.0),
        "devices.ins.transport.baud: Input should be a valid integer",
    ),
    "two_devices_one_port": (
        lambda d: _devices(d)["dvl"].update(transport=_devices(d)["ins"]["transport"]),
        "devices: devices 'dvl' and 'ins' both use serial /dev/null-fuzz-ins",
    ),
    "missing_dbc": (
        lambda d: _devices(d)["mag"].update(dbc="absent.dbc"),
        "devices.mag.dbc: cannot load 'absent.dbc'",
    ),
    # found by benchmarks/config_fuzz.py: accepted, then the reader thread died in open()
    "nul_in_a_path": (
        lambda d: _devices(d)["dvl"]["transport"].update(path="dvl\0.bin"),
        "devices.dvl.transport.path: contains a NUL character",
    ),
    "host_label_too_long": (
        lambda d: _devices(d)["mb"]["transport"].update(remote_host="h" * 64, remote_port=9),
        "devices.mb.transport.remote_host: 'hhhh",
    ),
    "unpaced_loop": (  # accepted before: a reader replaying at 100 % of a core for ever
        lambda d: _devices(d)["dvl"]["transport"].pop("byte_rate"),
        "devices.dvl.transport: 'loop' needs a pace: set 'byte_rate' or 'baud'",
    ),
    "too_many_devices": (
        lambda d: _devices(d).update(
            {
                f"u{i}": {"format": "pd0", "transport": {"kind": "udp", "port": 0}}
                for i in range(MAX_DEVICES)
            }
        ),
        f"devices: Dictionary should have at most {MAX_DEVICES} items",
    ),
}


@pytest.mark.parametrize("name", sorted(NAMED))
def test_named_defects_get_one_line(folder: Path, gateway_base: dict, name: str) -> None:
    change, expected = NAMED[name]
    doc = json.loads(json.dumps(gateway_base))
    change(doc)
    outcome, text = check_file("run", write_case(folder, name, "run", doc))
    assert outcome == "error", text
    assert len(text.splitlines()) == 1, text
    assert f"{name}.toml: {expected}" in text, text


def test_deep_nesting_is_refused_before_parsing(folder: Path) -> None:
    path = folder / "deep.toml"
    path.write_text("vehicle = " + "[" * 20_000 + "]" * 20_000 + "\n")
    outcome, text = check_file("run", path)
    assert outcome == "error", text
    assert "nested too deep (20000 levels at character 20009; at most 32)" in text
    scn = folder / "deep.json"
    scn.write_text('{"name": ' + "[" * 20_000 + "]" * 20_000 + "}")
    assert check_file("sim", scn)[0] == "error"


def test_a_huge_file_is_refused_unread(folder: Path, gateway_base: dict) -> None:
    path = folder / "huge.toml"
    path.write_text(to_toml(gateway_base) + "# " + "x" * MAX_DOCUMENT_BYTES + "\n")
    outcome, text = check_file("run", path)
    assert (outcome, text.strip()) == (
        "error",
        f"auvgw run: error: {path}: too large for a configuration file "
        f"(over {MAX_DOCUMENT_BYTES} bytes)",
    )


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("vehicle.loops", 10**9, "vehicle.loops: Input should be less than or equal to 1000"),
        ("seed", -1, "seed: Input should be greater than or equal to 0"),
        ("terrain.cell_m", 1e-9, "terrain.cell_m: Input should be greater than or equal to 0.01"),
        ("vehicle.speed_mps", "1.5", "vehicle.speed_mps: Input should be a valid number"),
        ("duration_s", 1e308, "duration_s: Input should be less than or equal to 86400"),
        # found by the fuzz: a reversed extent of a mixed terrain was a numpy traceback
        (
            "terrain",
            {"kind": "mixed", "extent_m": [100, -100, 0, 10]},
            "terrain: extent_m (100.0, -100.0, 0.0, 10.0): need x_min < x_max",
        ),
    ],
)
def test_scenario_bounds(folder: Path, field: str, value: object, expected: str) -> None:
    doc = json.loads((Path(SCENARIOS[0]).parent / "survey.json").read_text())
    parent = doc
    *head, last = field.split(".")
    for k in head:
        parent = parent[k]
    parent[last] = value
    outcome, text = check_file("sim", write_case(folder, "bounds", "sim", doc))
    assert outcome == "error", text
    assert f"bounds.json: {expected}" in text, text


def test_a_route_of_hours_is_refused(folder: Path) -> None:
    doc = json.loads((Path(SCENARIOS[0]).parent / "survey.json").read_text())
    doc["vehicle"]["waypoints"] = [[0, 0], [90000, 0]]
    doc["vehicle"]["waypoints_file"] = None
    doc["vehicle"]["loops"] = 1000
    outcome, text = check_file("sim", write_case(folder, "route", "sim", doc))
    assert outcome == "error" and "vehicle: the route takes about" in text, text


# -- the largest accepted values are safe where they reach a reader thread ---------------------


def test_largest_receive_buffer_and_chunk_read(tmp_path: Path) -> None:
    """``receive_buffer_bytes`` and ``chunk_size``/``max_chunk`` at their bounds open and read
    (2^63-1 overflowed setsockopt and asked read() for exabytes)."""
    with open_transport(
        {"kind": "udp", "host": "127.0.0.1", "port": 0,
         "receive_buffer_bytes": MAX_RECEIVE_BUFFER_BYTES}
    ) as udp:  # fmt: skip
        port = udp.local_address[1]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"ping", ("127.0.0.1", port))
        chunk = udp.read(5.0)
        assert chunk is not None and chunk.data == b"ping"
    data = bytes(range(256)) * 64
    (tmp_path / "f.bin").write_bytes(data)
    with open_transport(
        {"kind": "file", "path": str(tmp_path / "f.bin"), "chunk_size": MAX_CHUNK_BYTES}
    ) as f:
        chunk = f.read(1.0)
        assert chunk is not None and chunk.data == data
        with pytest.raises(EndOfStream):
            f.read(1.0)


def test_fastest_pace_replays_everything(tmp_path: Path) -> None:
    """``byte_rate`` at its bound (1e9 byte/s; inf was a traceback) with the largest chunk."""
    data = bytes(range(256)) * 16
    (tmp_path / "f.bin").write_bytes(data)
    cfg = {"kind": "file", "path": str(tmp_path / "f.bin"), "byte_rate": 1e9, "speed": 1000.0,
           "chunk_size": MAX_CHUNK_BYTES}  # fmt: skip
    got = b""
    with open_transport(cfg) as f, pytest.raises(EndOfStream):
        while True:
            chunk = f.read(1.0)
            got += chunk.data if chunk is not None else b""
    assert got == data


def test_a_huge_terrain_grid_is_refused_unread(folder: Path) -> None:
    from auvgw.sim_devices.world import MAX_GRID_BYTES

    grid = folder / "grid.json"
    with grid.open("w") as f:  # sparse: no disk is spent
        f.truncate(MAX_GRID_BYTES + 1)
    doc = json.loads((Path(SCENARIOS[0]).parent / "survey.json").read_text())
    doc["terrain"] = {"kind": "grid", "file": "grid.json"}
    outcome, text = check_file("sim", write_case(folder, "big_terrain", "sim", doc))
    assert outcome == "error", text
    assert f"big_terrain.json: terrain.file {grid}: too large for a depth grid" in text, text
