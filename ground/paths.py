"""Where things are: the project's shipped config files and the shared data beside the repo."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def config_file(name: str) -> Path:
    """Path of a file shipped in ``config/`` (tables, DBCs, scenarios), e.g. ``hn100.toml``."""
    return Path(str(resources.files("auvgw.config").joinpath(name)))


def shared_dir() -> Path | None:
    """The ``shared/`` folder beside the checkout (``$AUVGW_SHARED`` overrides), if present."""
    env = os.environ.get("AUVGW_SHARED")
    candidates = [Path(env)] if env else []
    candidates += [REPO_ROOT.parent / "shared", REPO_ROOT.parent.parent / "shared"]
    for c in candidates:
        if (c / "data").is_dir():
            return c
    return None
