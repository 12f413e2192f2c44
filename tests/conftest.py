"""Shared fixtures: the real recordings in ../shared/data (required under CI=true)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from auvgw.paths import shared_dir


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
