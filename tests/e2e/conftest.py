"""Every test in ``tests/e2e/`` is end-to-end (marked ``e2e`` by its folder): it runs the vehicle,
its processes, ports and bus, and ``make test-fast`` (``-m "not e2e"``) skips it."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).parent


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.is_relative_to(HERE):
            item.add_marker(pytest.mark.e2e)
