"""Shared fixtures (the real recordings in ../shared/data, required under CI=true), the unit and
real_data marks, and the check that a test starting processes, ptys or Zenoh sessions is marked
``e2e`` (tests/README.md)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from auvgw.ground.paths import shared_dir

#: a test not marked ``e2e`` that starts a process, a pty or a Zenoh session fails
pytest_plugins = ["auvgw.testing.e2e_marks"]


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; fails loudly (never skips) under CI when it is missing."""
    root = shared_dir()
    if root is None:
        msg = "../shared/data not found (set AUVGW_SHARED to the shared/ folder)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return root / "data"


@pytest.fixture(scope="session")
def papers_dir(shared_data: Path) -> Path:
    return shared_data.parent / "papers"


@pytest.fixture
def procs(tmp_path):
    """Child processes of a test (gateway, router, subscriber), all stopped at its end."""
    from auvgw.testing import Procs

    p = Procs(tmp_path)
    try:
        yield p
    finally:
        p.stop_all()


@pytest.fixture
def dvl(tmp_path):
    """A pty standing in for the DVL's serial port (stable symlink path)."""
    from auvgw.testing import PtyDevice

    d = PtyDevice(tmp_path / "dvl")
    try:
        yield d
    finally:
        d.close()


@pytest.fixture
def slcan_adapter(tmp_path):
    """An emulated USB-CAN adapter speaking SLCAN on a pty (stable symlink path), delivering
    frames as soon as written (``speed=0``: no bus-time pacing)."""
    from auvgw.sim_devices.slcan import SlcanAdapter

    a = SlcanAdapter("can", speed=0, link=tmp_path / "can0")
    try:
        yield a
    finally:
        a.close()


#: the folder whose tests run one after another on one worker under ``make test``'s two
#: workers (its demos start four to six processes each; two at once would starve each other)
SERIAL_FOLDER = "tests/e2e/"


@pytest.hookimpl(optionalhook=True)  # a pytest-xdist hook (tests/README.md, "Two workers")
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """Under ``--dist loadscope``: ``tests/e2e/`` as one unit of work, every other module as its
    own (its fixtures built once, on one worker). xdist's ``loadgroup`` marks would say the same
    but rename the node ids, which pytest 9 no longer lets a plugin do."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class FolderScope(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return SERIAL_FOLDER if path.startswith(SERIAL_FOLDER) else path

    return FolderScope(config, log)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test not marked ``e2e`` (``tests/e2e/`` by folder, elsewhere by its own mark)
    ``real_data`` (recordings from ../shared) or ``unit``, from the fixtures it uses."""
    for item in items:
        if item.get_closest_marker("e2e"):
            continue
        if set(getattr(item, "fixturenames", ())) & {"shared_data", "papers_dir"}:
            item.add_marker(pytest.mark.real_data)
        else:
            item.add_marker(pytest.mark.unit)


@pytest.fixture(scope="session", autouse=True)
def _bus_endpoint():
    """A free loopback port as the one-machine default bus endpoint of this test session (so
    parallel test runs on one machine never meet on tcp/127.0.0.1:7447)."""
    from auvgw.config.bus import ENDPOINT_ENV
    from auvgw.testing import endpoint, free_port

    old = os.environ.get(ENDPOINT_ENV)
    os.environ[ENDPOINT_ENV] = endpoint(free_port())
    yield os.environ[ENDPOINT_ENV]
    if old is None:
        os.environ.pop(ENDPOINT_ENV, None)
    else:
        os.environ[ENDPOINT_ENV] = old
