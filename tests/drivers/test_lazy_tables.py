"""No table is read at import time: importing every driver opens no ``.toml`` or ``.dbc``
file; the shipped tables are read on first use, once, also when a bus envelope names their
message type (``spec.message_class``)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROBE = r"""
import builtins, io, json
opened = []
_open = builtins.open

def _note(path):
    p = str(path)
    if p.endswith((".toml", ".dbc")):
        opened.append(p)

def open_(file, *a, **k):
    _note(file)
    return _open(file, *a, **k)

builtins.open = io.open = open_  # pathlib's reads go through io.open too
import importlib
for m in ("hn100", "ms3a", "acoustic", "pd0", "pd6", "kongsberg", "seanet", "can_codec",
          "formats"):
    importlib.import_module("auvgw.drivers." + m)
at_import = list(opened)
from auvgw.drivers import acoustic, hn100, ms3a
from auvgw.drivers.spec import message_class
lazy = message_class("Hn100Nav")  # a bus envelope's type name builds the class on demand
by_name = lazy is not None and lazy is hn100.Hn100Nav
names = [type(mod.CODEC).__name__ for mod in (hn100, ms3a, acoustic)]
same = ms3a.CODEC is ms3a.default_codec() and ms3a.Ms3aSample is ms3a.CODEC.message_type
msg = ms3a.Ms3aSample(counter=1, bx=1.0, by=2.0, bz=3.0)
line = ms3a.FORMAT.encode(msg)
back = ms3a.FORMAT.decode(line)[0]
print(json.dumps({"at_import": at_import, "after": opened[len(at_import):], "names": names,
                  "same": same, "round_trip": back == msg, "by_name": by_name}))
"""


@pytest.mark.e2e
def test_no_table_read_at_import_and_read_once_on_first_use():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         check=True, timeout=120)  # fmt: skip
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["at_import"] == []
    assert r["names"] == ["Hn100Codec", "Ms3aCodec", "AcousticCodec"]
    read = sorted(p.rsplit("/", 1)[-1] for p in r["after"])
    assert read == ["acoustic.toml", "hn100.toml", "ms3a.toml"]  # each once, on first use
    assert r["same"] and r["round_trip"] and r["by_name"]


def test_a_site_table_does_not_shadow_the_shipped_class_for_readers(tmp_path):
    """A site table builds its own class of the shipped type name (its codec's); a bus reader
    resolving the name still gets the shipped table's class (it would otherwise change every
    later reader's schema in the process)."""
    from auvgw.drivers import ms3a
    from auvgw.drivers.spec import resolve_type
    from auvgw.ground.paths import config_file

    shipped = ms3a.default_codec().message_type
    site_table = tmp_path / "site_ms3a.toml"
    site_table.write_text(config_file("ms3a.toml").read_text())
    site = ms3a.Ms3aCodec.from_toml(site_table).message_type
    assert site is not shipped and site.__name__ == shipped.__name__ == "Ms3aSample"
    assert resolve_type("Ms3aSample") is shipped
