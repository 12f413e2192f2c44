"""The systemd units in deploy/ are complete (sections, user, restart policy) and their
``ExecStart`` lines are commands the installed ``auvgw`` accepts; the udev rules are well formed."""

from __future__ import annotations

import configparser
import re
import shlex
from pathlib import Path

import pytest

from auvgw.cli import build_parser
from auvgw.ground.paths import REPO_ROOT

UNITS = sorted((REPO_ROOT / "deploy" / "systemd").glob("*.service"))


def test_every_part_has_a_unit() -> None:
    names = {u.stem for u in UNITS}
    assert names == {"auvgw-router", "auvgw-gateway", "auvgw-fusion", "auvgw-slam", "auvgw-record"}


def _auvgw_argv(exec_start: str) -> list[str]:
    argv = shlex.split(exec_start)
    if argv[0] == "/bin/sh":  # sh -c 'exec .../auvgw ... $(date ...)'
        argv = shlex.split(re.sub(r"\$\([^)]*\)", "STAMP", argv[2]))[1:]
    assert argv[0] == "/opt/auvgw/venv/bin/auvgw", argv
    return argv[1:]


@pytest.mark.parametrize("unit", UNITS, ids=[u.stem for u in UNITS])
def test_unit_is_complete_and_its_command_parses(unit: Path) -> None:
    cp = configparser.ConfigParser(interpolation=None, strict=True)
    cp.optionxform = str  # keys are case sensitive
    cp.read_string(unit.read_text())
    assert set(cp.sections()) == {"Unit", "Service", "Install"}
    assert cp["Unit"]["Description"] and cp["Install"]["WantedBy"] == "multi-user.target"
    svc = cp["Service"]
    assert svc["User"] == "auvgw" and svc["Restart"] in ("always", "on-failure")
    assert float(svc["RestartSec"]) > 0 and svc["KillSignal"] in ("SIGTERM", "SIGINT")
    if unit.stem == "auvgw-gateway":
        assert "dialout" in svc["SupplementaryGroups"].split()
    if svc["Restart"] == "on-failure":
        assert svc["RestartPreventExitStatus"] == "2"  # a user error does not loop
    args = build_parser().parse_args(_auvgw_argv(svc["ExecStart"]))
    assert callable(args.func)
    if unit.stem == "auvgw-record":
        assert "STAMP" in str(args.out) and not args.force  # a new file per start


def test_udev_rules_are_well_formed() -> None:
    rules = (REPO_ROOT / "deploy" / "udev" / "99-auvgw.rules").read_text().splitlines()
    active = [r for r in rules if r.strip() and not r.startswith("#")]
    assert len(active) >= 5
    for r in active:
        keys = dict(re.findall(r'(\w+(?:\{\w+\})?)[+=]=?"([^"]*)"', r))
        assert keys["SUBSYSTEM"] == "tty" and keys["GROUP"] == "dialout"
        assert keys["SYMLINK"].startswith("auvgw/") and keys["MODE"] == "0660"
