"""Bad gateway configurations: ``auvgw run --config`` answers each with its own message naming
the file, the field and what is expected, and exit code 2.

The cases of :data:`CASES` (and missing file, port in use, several problems at once) run the real
command in a subprocess; the variants of :data:`MORE_CASES` go through the same ``auvgw.cli.main``
in this process (every interpreter start costs over a second of CPU)."""

from __future__ import annotations

import socket
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from auvgw.testing import AUVGW, REPO

DVL = '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "serial", url = "/dev/null-dvl" }\n'

_ALL: dict[str, tuple[str, list[str]]] = {
    "not_toml": (
        'vehicle = "auv1"\n[devices.dvl\nformat = "pd0"\n',
        ["not valid TOML"],
    ),
    "missing_devices": (
        'vehicle = "auv1"\n',
        ["devices: no device configured: add a [devices.<name>] table"],
    ),
    "empty_devices": (
        "[devices]\n",
        ["devices: no device configured"],
    ),
    "unknown_format": (
        '[devices.dvl]\nformat = "pd9"\ntransport = { kind = "serial", url = "/dev/x" }\n',
        ["devices.dvl.format: Input should be 'hn100', 'pd0', 'pd6'", "(got 'pd9')"],
    ),
    "bad_transport_kind": (
        '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "serail", url = "/dev/x" }\n',
        ["devices.dvl.transport.kind: must be one of 'serial', 'can', 'udp', 'file', got 'serail'"],
    ),
    "transport_kind_missing": (
        '[devices.dvl]\nformat = "pd0"\ntransport = { url = "/dev/x" }\n',
        ["devices.dvl.transport.kind: missing; must be one of"],
    ),
    "transport_missing": (
        '[devices.dvl]\nformat = "pd0"\n',
        ["devices.dvl.transport: missing (required)"],
    ),
    "can_without_dbc": (
        '[devices.ins]\nformat = "can"\ntransport = { kind = "can", interface = "virtual" }\n',
        ["devices.ins: format 'can' needs 'dbc'"],
    ),
    "can_frames_with_stream_format": (
        '[devices.ins]\nformat = "hn100"\ntransport = { kind = "can", interface = "virtual" }\n',
        ["devices.ins: transport kind 'can' carries CAN frames: set format = \"can\""],
    ),
    "bad_baud_type": (
        '[devices.dvl]\nformat = "pd0"\n'
        'transport = { kind = "serial", url = "/dev/x", baud = "fast" }\n',
        ["devices.dvl.transport.baud: Input should be a valid integer", "(got 'fast')"],
    ),
    "unknown_transport_key": (
        '[devices.dvl]\nformat = "pd0"\n'
        'transport = { kind = "serial", url = "/dev/x", bauds = 9600 }\n',
        ["devices.dvl.transport.bauds: unknown key 'bauds'; expected one of: kind, url, baud"],
    ),
    "unknown_top_level_key": (
        'vehicel = "auv1"\n' + DVL,
        ["vehicel: unknown key 'vehicel'; expected one of: vehicle, bus, clock, status_period_s"],
    ),
    "scaled_clock_without_epoch": (
        "[clock]\ntime_scale = 4.0\n" + DVL,
        ["clock: time_scale != 1 needs 'epoch_ns'"],
    ),
    "zero_time_scale": (
        "[clock]\ntime_scale = 0\nepoch_ns = 0\n" + DVL,
        ["clock.time_scale: Input should be greater than 0"],
    ),
    "bad_vehicle_name": (
        'vehicle = "my auv"\n' + DVL,
        ["vehicle: vehicle name 'my auv': use letters, digits, '_' or '-'"],
    ),
    "bad_device_name": (
        '[devices."dvl/1"]\nformat = "pd0"\ntransport = { kind = "serial", url = "/dev/x" }\n',
        ["devices: device name 'dvl/1'"],
    ),
    "bad_endpoint": (
        '[bus]\nlisten = ["127.0.0.1:7447"]\n' + DVL,
        ["bus.listen: endpoint '127.0.0.1:7447' is not '<protocol>/<address>'"],
    ),
    "client_without_router": (
        '[bus]\nmode = "client"\n' + DVL,
        ["bus: mode 'client' needs the router's endpoint in 'connect'"],
    ),
    "bad_mode": (
        '[bus]\nmode = "server"\n' + DVL,
        ["bus.mode: Input should be 'peer', 'client' or 'router'", "(got 'server')"],
    ),
    "negative_period": (
        "status_period_s = -1\n" + DVL,
        ["status_period_s: Input should be greater than or equal to 0.05", "(got -1)"],
    ),
    "dbc_on_stream_format": (
        DVL + 'dbc = "hn100.dbc"\n',
        ["devices.dvl: 'dbc' only applies to format 'can', not 'pd0'"],
    ),
    "dbc_not_loadable": (
        '[devices.ins]\nformat = "can"\ndbc = "no-such.dbc"\n'
        'transport = { kind = "can", interface = "virtual", channel = "x" }\n',
        ["devices.ins.dbc:"],
    ),
}


#: run as subprocesses: the kinds of mistake a user makes most
CASES = {
    k: _ALL[k]
    for k in (
        "not_toml",
        "missing_devices",
        "unknown_format",
        "bad_transport_kind",
        "can_without_dbc",
        "bad_baud_type",
        "unknown_transport_key",
        "bad_vehicle_name",
        "bad_endpoint",
        "dbc_not_loadable",
    )
}
#: run in-process through auvgw.cli.main
MORE_CASES = {k: v for k, v in _ALL.items() if k not in CASES}


def run_config(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [AUVGW, "run", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )


def check(proc: subprocess.CompletedProcess[str], path: Path, expected: list[str]) -> list[str]:
    err = proc.stderr
    assert proc.returncode == 2, (proc.returncode, err)
    assert "Traceback" not in err, err
    for text in expected:
        assert text in err, f"expected {text!r} in:\n{err}"
    lines = [ln for ln in err.splitlines() if ln.strip()]
    for ln in lines:  # every problem line names the file
        assert str(path) in ln, ln
    return lines


@pytest.fixture(scope="module")
def case_results(tmp_path_factory):
    """Every case of CASES run once, a few at a time (each is a fresh interpreter)."""
    folder = tmp_path_factory.mktemp("configs")
    paths = {}
    for name, (text, _) in CASES.items():
        paths[name] = folder / f"{name}.toml"
        paths[name].write_text(text)
    with ThreadPoolExecutor(4) as pool:
        procs = dict(zip(paths, pool.map(run_config, paths.values()), strict=True))
    return {name: (paths[name], procs[name]) for name in CASES}


@pytest.mark.e2e
@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_config_gives_its_message_and_exit_code_2(case_results, name):
    path, proc = case_results[name]
    check(proc, path, CASES[name][1])


@pytest.mark.e2e
def test_every_problem_gets_its_own_line(tmp_path):
    path = tmp_path / "many.toml"
    path.write_text(
        'vehicle = "a b"\nstatus_period_s = 0\n'
        '[devices.dvl]\nformat = "pd9"\n'
        'transport = { kind = "serial", url = "/dev/x", baud = -3 }\n'
    )
    lines = check(run_config(path), path, [])
    fields = sorted(ln.split(f"{path}: ", 1)[1].split(": ")[0] for ln in lines)
    assert fields == sorted(
        ["vehicle", "status_period_s", "devices.dvl.format", "devices.dvl.transport.baud"]
    ), lines


@pytest.mark.e2e
def test_missing_file(tmp_path):
    path = tmp_path / "absent.toml"
    check(run_config(path), path, ["no such configuration file"])


@pytest.mark.parametrize("name", sorted(MORE_CASES))
def test_more_bad_configs_in_process(tmp_path, capsys, name):
    from auvgw.cli import main

    text, expected = MORE_CASES[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    rc = main(["run", "--config", str(path)])
    check(subprocess.CompletedProcess([], rc, "", capsys.readouterr().err), path, expected)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "is a directory, not a configuration file"),
        (b"\xff\xfe\x00garbage\x80", "not a text (UTF-8) file"),
    ],
)
def test_unreadable_files_in_process(tmp_path, capsys, content, expected):
    from auvgw.cli import main

    path = tmp_path
    if content is not None:
        path = tmp_path / "binary.toml"
        path.write_bytes(content)
    rc = main(["run", "--config", str(path)])
    check(subprocess.CompletedProcess([], rc, "", capsys.readouterr().err), path, [expected])


@pytest.mark.e2e
def test_listen_port_in_use(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        path = tmp_path / "busy.toml"
        path.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\n' + DVL)
        check(run_config(path), path, ["bus: cannot open the Zenoh session", "bus.listen"])
