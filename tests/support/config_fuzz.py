"""Configuration and scenario fuzzing: one field of a valid file mutated, loaded through the real
CLI entry (``auvgw run --check --config F``, ``auvgw sim --check --scenario F``).

The outcome of a file is ``ok`` (exit 0), ``error`` (exit 2, every stderr line names the file)
or ``traceback`` (anything else: an exception out of ``main``, another exit code, an error line
without the file). ``tests/sim_devices/test_config_fuzz.py`` runs a few hundred examples;
``benchmarks/config_fuzz.py`` thousands, and starts the gateway on the accepted ones.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hypothesis import strategies as st

from auvgw.cli import main
from auvgw.testing import REPO

__all__ = [
    "EDGES",
    "SCENARIOS",
    "base_gateway",
    "check_file",
    "leaf_paths",
    "mutated",
    "to_toml",
    "write_case",
]

#: the shipped scenarios (valid bases for the scenario fuzz)
SCENARIOS = sorted((REPO / "config" / "scenarios").glob("*.json"))


def _deep(n: int) -> Any:
    v: Any = 1
    for _ in range(n):
        v = [v]
    return v


#: values put in place of a field: type edges, wrong types, huge and deep values (40 levels:
#: past the bound; 20,000 is a test of its own, the writers here recurse)
EDGES: list[Any] = [
    0, -1, 1, 2**31 - 1, 2**63 - 1, -(2**63), 1e308, -1e308, 1e-9, math.inf, -math.inf, math.nan,
    0.5, 3.0, "", "3", "yes", "x" * 100_000, "\u00e9\u0000", True, False, [], [1, 2], {},
    {"a": 1}, _deep(40),
]  # fmt: skip


def base_gateway(folder: Path) -> dict[str, Any]:
    """A valid gateway configuration using every transport kind, a DBC, a password file and a
    replayed file (written into ``folder``)."""
    (folder / "pw.txt").write_text("secret\n")
    (folder / "dvl.bin").write_bytes(bytes(range(256)) * 4)
    return {
        "vehicle": "auv1",
        "status_period_s": 1.0,
        "bus": {"listen": ["tcp/127.0.0.1:0"], "auth": {"user": "gw", "password_file": "pw.txt"}},
        "clock": {"time_scale": 1.0},
        "devices": {
            "dvl": {
                "format": "pd0",
                "stale_after_s": 2.0,
                "transport": {"kind": "file", "path": "dvl.bin", "byte_rate": 2000.0,
                              "chunk_size": 64, "loop": True},
            },
            "ins": {
                "format": "hn100",
                "transport": {"kind": "serial", "url": "/dev/null-fuzz-ins", "baud": 115200,
                              "max_chunk": 4096},
            },
            "mb": {
                "format": "kongsberg",
                "transport": {"kind": "udp", "host": "127.0.0.1", "port": 0,
                              "receive_buffer_bytes": 65536},
            },
            "mag": {
                "format": "can",
                "dbc": "ms3a.dbc",
                "transport": {"kind": "can", "interface": "virtual", "channel": "fuzz",
                              "bitrate": 500000},
            },
        },
    }  # fmt: skip


def leaf_paths(doc: Any, prefix: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """Every path to a value in ``doc`` (tables, arrays and their items included)."""
    if prefix:
        yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from leaf_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):  # a long waypoint list: its first items stand for all
            yield from leaf_paths(v, (*prefix, i))


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for p in path[:-1]:
        doc = doc[p]
    return doc


@st.composite
def mutated(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    """``base`` (not changed) with one field mutated: replaced by an edge value, removed, or
    given an unknown sibling; or (gateway) one device's transport copied to another."""
    doc = json.loads(json.dumps(base))
    paths = list(leaf_paths(doc))
    how = draw(st.sampled_from(["edge", "edge", "edge", "scale", "remove", "unknown", "share"]))
    path = draw(st.sampled_from(paths))
    parent, key = _parent(doc, path), path[-1]
    if how == "edge":
        parent[key] = draw(st.sampled_from(EDGES))
    elif (
        how == "scale"
        and isinstance(parent[key], int | float)
        and not isinstance(parent[key], bool)
    ):
        parent[key] = parent[key] * draw(st.sampled_from([-1, 1e-12, 1e12, 10**18]))
    elif how == "remove" and isinstance(parent, dict):
        del parent[key]
    elif how == "unknown" and isinstance(parent, dict):
        parent[f"{key}_typo"] = parent[key]
    elif how == "share" and isinstance(doc.get("devices"), dict) and len(doc["devices"]) > 1:
        names = sorted(doc["devices"])
        a, b = draw(st.permutations(names))[:2]
        if isinstance(doc["devices"][a], dict) and isinstance(doc["devices"][b], dict):
            doc["devices"][b]["transport"] = doc["devices"][a].get("transport")
            if "dbc" in doc["devices"][a]:
                doc["devices"][b].update(format="can", dbc=doc["devices"][a]["dbc"])
    return doc


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string (JSON escapes are TOML escapes)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return (
            "{ "
            + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items())
            + " }"
        )
    raise TypeError(f"no TOML for {type(v).__name__}")


def to_toml(doc: dict[str, Any]) -> str:
    """``doc`` as TOML: one ``key = value`` line per top-level key (inline tables below)."""
    return "".join(f"{json.dumps(str(k))} = {_toml_value(v)}\n" for k, v in doc.items())


def write_case(folder: Path, name: str, kind: str, doc: dict[str, Any]) -> Path:
    """``doc`` written as a gateway TOML (``kind`` "run") or a scenario JSON ("sim")."""
    if kind == "run":
        path = folder / f"{name}.toml"
        path.write_text(to_toml(doc), encoding="utf-8", errors="surrogatepass")
    else:
        path = folder / f"{name}.json"
        path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def check_file(kind: str, path: Path) -> tuple[str, str]:
    """``(outcome, stderr)`` of ``auvgw run --check --config path`` (``kind`` "run") or
    ``auvgw sim --check --scenario path`` ("sim"), run in this process."""
    argv = ["run", "--check", "--config", str(path)]
    if kind == "sim":
        argv = ["sim", "--check", "--scenario", str(path)]
    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main(argv)
    except BaseException as exc:
        return "traceback", f"{type(exc).__name__}: {exc}"[:500]
    text = err.getvalue()
    if rc == 0:
        return "ok", text
    lines = text.splitlines()
    if rc == 2 and lines and all(path.name in line for line in lines):
        return "error", text
    return "traceback", f"exit {rc}: {text[:500]}"
