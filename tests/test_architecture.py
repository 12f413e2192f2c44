"""The layering of docs/architecture.md, checked from the import graph of the source files.

Layers, lowest first: ``ground/``; ``drivers/`` and ``config/``; ``fusion/``, ``slam/``,
``sim_devices/`` and ``control/``; the service (``auvgw/``); the commands (``auvgw/commands/``,
``auvgw/cli.py``).
A module imports only from its own layer or below, ``ground/`` from nothing of the project, and no
file imports itself back through a chain of others. Every import counts, the ones inside
functions too (a circle hidden in a function is still a circle); ``if TYPE_CHECKING:`` blocks do
not (they never run).
"""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]

#: import prefix -> (folder, layer)
FOLDERS: dict[str, tuple[str, int]] = {
    "auvgw.ground": ("ground", 0),
    "auvgw.drivers": ("drivers", 1),
    "auvgw.config": ("config", 1),
    "auvgw.fusion": ("fusion", 2),
    "auvgw.slam": ("slam", 2),
    "auvgw.sim_devices": ("sim_devices", 2),
    "auvgw.control": ("control", 2),
    "auvgw.commands": ("auvgw/commands", 4),
    "auvgw.cli": ("auvgw/cli.py", 4),
    "auvgw.__main__": ("auvgw/__main__.py", 4),
    "auvgw": ("auvgw", 3),
}
LAYER_NAMES = ["ground", "drivers/config", "fusion/slam/sim_devices/control", "service", "commands"]


def _modules() -> dict[str, Path]:
    """Every product module's import name -> its file (tests/support is the test house: not
    product, not checked)."""
    out: dict[str, Path] = {}
    for prefix, (folder, _) in FOLDERS.items():
        base = REPO_ROOT / folder
        files = [base] if base.suffix == ".py" else sorted(base.rglob("*.py"))
        for f in files:
            if base.suffix == ".py":
                out[prefix] = f
                continue
            parts = list(f.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out.setdefault(".".join([prefix, *parts]), f)
    return out


def _layer(module: str) -> int:
    prefix = max((p for p in FOLDERS if module == p or module.startswith(p + ".")), key=len)
    return FOLDERS[prefix][1]


def _imports(path: Path, known: dict[str, Path]) -> set[str]:
    """The project modules ``path`` imports (``from a.b import c`` counts ``a.b.c`` when that is a
    module, else ``a.b``); TYPE_CHECKING blocks skipped."""
    tree = ast.parse(path.read_text(), str(path))
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for b in node.body for n in ast.walk(b)}
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{a.name}" for a in node.names}
            found |= (subs & known.keys()) or {node.module}
    return {m for m in found if m in known}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(f, mods) - {m} for m, f in mods.items()}


def test_the_graph_sees_every_folder(graph):
    layers = {_layer(m) for m in graph}
    assert layers == {0, 1, 2, 3, 4}
    assert len(graph) > 100  # a broken walk would pass every check below vacuously
    assert "auvgw.ground.geometry" in graph["auvgw.fusion.ekf"]


def test_the_ground_imports_nothing_of_the_project(graph):
    bad = sorted((m, d) for m, ds in graph.items() if _layer(m) == 0 for d in ds if _layer(d) > 0)
    assert not bad, bad


def test_no_folder_imports_a_higher_one(graph):
    bad = sorted(
        f"{m} ({LAYER_NAMES[_layer(m)]}) imports {d} ({LAYER_NAMES[_layer(d)]})"
        for m, ds in graph.items()
        for d in ds
        if _layer(d) > _layer(m)
    )
    assert not bad, "\n".join(bad)


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative); a package's
    import of its own submodules is not an edge back."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0

    def edges(v: str) -> list[str]:
        return sorted(w for w in graph[v] if not w.startswith(v + "."))

    for root in graph:
        if root in index:
            continue
        work = [(root, iter(edges(root)))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(edges(w))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_no_file_level_circles(graph):
    assert _circles(graph) == []


def test_the_circle_finder_finds_a_planted_circle(graph):
    planted = {k: set(v) for k, v in graph.items()}
    planted["auvgw.ground.geometry"].add("auvgw.fusion.ekf")  # ekf imports geometry
    assert any({"auvgw.fusion.ekf", "auvgw.ground.geometry"} <= set(c) for c in _circles(planted))


#: test folder -> the layer of the product it mirrors (tests/README.md); ``e2e`` runs everything
TEST_FOLDERS: dict[str, int] = {
    "ground": 0,
    "drivers": 1,
    "config": 1,
    "fusion": 2,
    "slam": 2,
    "sim_devices": 2,
    "control": 2,
    "service": 3,
    "commands": 4,
    "e2e": 4,
}
TESTS = REPO_ROOT / "tests"


def test_every_test_module_sits_in_a_folder_that_mirrors_the_product():
    modules = sorted(TESTS.rglob("test_*.py"))
    assert len(modules) > 100
    misplaced = [
        rel.as_posix()
        for rel in (m.relative_to(TESTS) for m in modules)
        if rel.parts != ("test_architecture.py",)
        and (len(rel.parts) != 2 or rel.parts[0] not in TEST_FOLDERS)
    ]
    assert misplaced == [], f"put each in one of tests/{{{','.join(TEST_FOLDERS)}}}/"


def test_no_test_imports_a_layer_above_its_folder():
    """A test lives with the highest layer it imports: ``tests/slam/`` runs without the service
    or the commands (``auvgw.testing``, the test house, is not counted)."""
    known = _modules()
    bad = sorted(
        f"tests/{folder}/{m.name} imports {d} ({LAYER_NAMES[_layer(d)]})"
        for folder, layer in TEST_FOLDERS.items()
        for m in sorted((TESTS / folder).glob("test_*.py"))
        for d in _imports(m, known)
        if _layer(d) > layer
    )
    assert bad == [], "\n".join(bad)


@pytest.mark.e2e  # it starts a pytest process, whose tests open a pty and start a process
def test_an_unmarked_test_that_starts_a_pty_fails_and_a_marked_one_runs(tmp_path):
    """The tripwires blame the test whose thread (or a thread it started) made the call."""
    from auvgw.testing import PYTHON

    (tmp_path / "test_planted.py").write_text(
        "import os, subprocess, sys\nimport pytest\n\n"
        "def test_unmarked():\n    a, b = os.openpty()\n    os.close(a)\n    os.close(b)\n\n"
        "@pytest.mark.e2e\ndef test_marked():\n"
        "    subprocess.run([sys.executable, '-c', ''], check=True)\n\n"
        "def test_pure():\n    assert sum([1, 1]) == 2\n\n"
        # a thread an earlier test left running starts a process while an unmarked test runs:
        # not that test's (the events order it; nothing sleeps)
        "import threading\ngo, done = threading.Event(), threading.Event()\n\n"
        "@pytest.mark.e2e\ndef test_marked_leaves_a_thread():\n"
        "    def later():\n        go.wait(60)\n"
        "        subprocess.run([sys.executable, '-c', ''], check=True)\n        done.set()\n"
        "    threading.Thread(target=later, daemon=True).start()\n\n"
        "def test_unmarked_while_an_earlier_thread_starts_a_process():\n"
        "    go.set()\n    assert done.wait(60)\n\n"
        # ... but a thread the unmarked test starts itself is the test's
        "def test_unmarked_thread():\n"
        "    t = threading.Thread(target=subprocess.run, args=([sys.executable, '-c', ''],))\n"
        "    t.start()\n    t.join()\n"
    )
    out = subprocess.run(
        [PYTHON, "-m", "pytest", "-q", "-p", "auvgw.testing.e2e_marks", "-p", "no:cacheprovider",
         "-o", "markers=e2e", "test_planted.py"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 1, out.stdout + out.stderr
    assert "test_planted.py::test_unmarked started a pty but is not marked e2e" in out.stdout
    assert "test_planted.py::test_unmarked_thread started a process but is not" in out.stdout
    assert "2 failed, 4 passed" in out.stdout, out.stdout
