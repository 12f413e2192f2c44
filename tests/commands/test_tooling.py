"""What Python sees: the CLI's start-up cost, the folder-to-namespace mapping, the command table."""

from __future__ import annotations

import subprocess
import sys

import pytest

from auvgw.cli import COMMANDS, build_parser
from auvgw.ground.paths import REPO_ROOT

HEAVY = ("scipy", "numpy", "zenoh", "rerun", "matplotlib", "pydantic")


@pytest.mark.e2e
def test_help_imports_no_command_module_and_no_heavy_library():
    code = (
        "import sys\n"
        "from auvgw.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))\n"
        "print(sorted(m for m in sys.modules if m.startswith('auvgw.commands.')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout.splitlines()
    assert "demo" in "\n".join(out[:-2])  # the listing was printed
    assert out[-2:] == ["[]", "[]"]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_listed_command_is_registered_by_its_module(name):
    parser = build_parser(name)
    sub = next(a for a in parser._actions if a.dest == "command")
    assert name in sub.choices  # type: ignore[operator]


@pytest.mark.e2e
@pytest.mark.parametrize(
    "folder", ["ground", "drivers", "fusion", "slam", "sim_devices", "control", "config"]
)
def test_mapped_folders_refuse_their_folder_name(folder):
    proc = subprocess.run(
        [sys.executable, "-c", f"import {folder}"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode != 0
    assert f"import auvgw.{folder}, not {folder}" in proc.stderr
