"""Shared fixtures: the real recordings in ../shared/data (required under CI=true)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from auvgw.ground.paths import shared_dir


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


#: a test whose own code contains one of these runs real processes, ports or a bus: ``e2e``
_E2E_SIGNS = re.compile(r"subprocess\.|open_session\(|\bPty|SimRunner|zenoh\.|\bAUVGW\b")


def _source(func: object) -> str:
    import inspect

    try:
        return inspect.getsource(func)  # type: ignore[arg-type]
    except (OSError, TypeError):
        return ""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test ``e2e`` (processes, ptys, a Zenoh session), ``real_data`` (recordings
    from ../shared) or ``unit``, from what it uses, so ``make test-fast`` (``-m "not e2e"``)
    needs no marker in the test files and a new test is classified by what it does."""
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        funcs = [getattr(item, "function", None)]
        info = getattr(item, "_fixtureinfo", None)
        for defs in (info.name2fixturedefs.values() if info else ()):
            funcs += [d.func for d in defs if d.baseid]  # the project's fixtures, not pytest's
        source = "".join(_source(f) for f in funcs)
        if "procs" in fixtures or _E2E_SIGNS.search(source):
            item.add_marker(pytest.mark.e2e)
        elif fixtures & {"shared_data", "papers_dir"}:
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
