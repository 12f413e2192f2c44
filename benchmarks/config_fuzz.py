"""Thousands of mutated gateway configurations and scenarios through the real CLI entry.

Each file is a valid base (a gateway configuration using every transport kind; each shipped
scenario) with one field mutated (``auvgw.testing.config_fuzz``: type edges 0, -1, 2^63-1,
1e308, inf, nan, "", 100 kB strings, wrong types, 40-deep arrays, removed and unknown keys, two
devices on one port). Counted:

* ``auvgw run --check --config F`` and ``auvgw sim --check --scenario F`` in this process
  (``auvgw.cli.main``): accepted, refused with one line per problem naming the file (exit 2),
  or a traceback (anything else; must be 0);
* the same for ``--subprocess`` files of each kind through the installed ``auvgw`` command;
* every accepted gateway configuration (up to ``--run``) started for ``--run-s`` seconds on one
  shared Zenoh session: reader threads that died (an uncaught exception) or hit a reader error
  (the gateway's catch-all), both must be 0, and the highest CPU share of the process.

Writes the table to docs/reliability.md (``--out``) between its ``<!-- config-fuzz -->``
markers; exit code 1 if any traceback, dead thread or reader error. Regenerate with::

    .venv/bin/python benchmarks/config_fuzz.py --examples 3000
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections import Counter
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from auvgw.config.gateway import load_gateway_config
from auvgw.testing.config_fuzz import SCENARIOS, base_gateway, check_file, mutated, write_case

REPO = Path(__file__).resolve().parents[1]


class _ReaderErrors(logging.Handler):
    """Counts the gateway's "reader error" records (an exception caught in a reader thread)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.count = 0
        self.last = ""

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info:
            self.count += 1
            self.last = record.getMessage()


def sweep(
    kind: str, folder: Path, examples: int, keep: int
) -> tuple[Counter[str], list[Path], list[Path]]:
    """Outcome counts of ``examples`` mutated files of ``kind`` ("run" or "sim"), the accepted
    files (for the run phase) and the first ``keep`` files (for the subprocess sample)."""
    counts: Counter[str] = Counter()
    accepted: list[Path] = []
    kept: list[Path] = []
    gw = base_gateway(folder)
    bases = [gw] if kind == "run" else [json.loads(p.read_text()) for p in SCENARIOS]

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(data=st.data())
    def one(data: st.DataObject) -> None:
        doc = data.draw(mutated(data.draw(st.sampled_from(bases))))
        n = sum(counts.values())
        path = write_case(folder, f"{kind}{n}", kind, doc)
        outcome, text = check_file(kind, path)
        counts[outcome] += 1
        if outcome == "traceback":
            print(f"TRACEBACK {path}: {text}", file=sys.stderr)
        if outcome == "ok" and kind == "run":
            accepted.append(path)
        if n < keep:
            kept.append(path)
        elif outcome != "ok" or kind != "run":
            path.unlink()

    one()
    return counts, accepted, kept


def subprocess_sample(kind: str, files: list[Path]) -> Counter[str]:
    """``files`` of ``kind`` through the installed ``auvgw`` command, one process each."""
    counts: Counter[str] = Counter()
    exe = str(Path(sys.executable).with_name("auvgw"))
    for path in files:
        opt = "--config" if kind == "run" else "--scenario"
        proc = subprocess.run(
            [exe, kind, "--check", opt, str(path)], capture_output=True, text=True, timeout=120
        )
        lines = proc.stderr.splitlines()
        if proc.returncode == 0:
            counts["ok"] += 1
        elif proc.returncode == 2 and lines and all(path.name in ln for ln in lines):
            counts["error"] += 1
        else:
            counts["traceback"] += 1
            print(f"TRACEBACK {path}: {proc.stderr[-500:]}", file=sys.stderr)
    return counts


def run_accepted(paths: list[Path], run_s: float) -> dict[str, Any]:
    """Start each accepted configuration's gateway for ``run_s`` s on one Zenoh session."""
    import zenoh

    from auvgw.gateway import Gateway

    died: list[str] = []
    old_hook = threading.excepthook

    current = [Path()]

    def hook(args: threading.ExceptHookArgs) -> None:
        name = args.thread.name if args.thread else "?"
        died.append(f"{current[0].name} {name}: {args.exc_type.__name__}: {args.exc_value}")
        print(f"DIED {current[0]}:", file=sys.stderr)
        traceback.print_exception(args.exc_type, args.exc_value, args.exc_traceback)

    threading.excepthook = hook
    errors = _ReaderErrors()
    logging.getLogger("auvgw.gateway").addHandler(errors)
    logging.getLogger("auvgw.gateway").propagate = False
    session = zenoh.open(zenoh.Config())
    worst_cpu = 0.0
    try:
        for path in paths:
            current[0] = path
            cfg = load_gateway_config(path)
            gw = Gateway(cfg, session=session)
            gw.start()
            time.sleep(0.1)  # past the start-up (declarations, first opens)
            cpu0, t0 = time.process_time(), time.monotonic()
            time.sleep(run_s)
            cpu = (time.process_time() - cpu0) / (time.monotonic() - t0)
            gw.stop()
            if cpu > 0.5:
                devices = {n: d.transport.describe() for n, d in cfg.devices.items()}
                print(f"BUSY {100 * cpu:.0f} % {path}: {devices}", file=sys.stderr)
            worst_cpu = max(worst_cpu, cpu)
    finally:
        session.close()
        threading.excepthook = old_hook
    return {"configs": len(paths), "died": died, "reader_errors": errors.count,
            "last_error": errors.last, "worst_cpu": worst_cpu}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=3000, help="mutated files per kind")
    ap.add_argument("--subprocess", type=int, default=100, help="files per kind via `auvgw`")
    ap.add_argument("--run", type=int, default=300, help="accepted configurations started")
    ap.add_argument("--run-s", type=float, default=0.3, help="seconds each runs")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "reliability.md")
    ap.add_argument("--no-out", action="store_true", help="print the table only")
    args = ap.parse_args()
    logging.basicConfig(level=logging.CRITICAL)
    rows = []
    bad = 0
    with tempfile.TemporaryDirectory(prefix="cfgfuzz-") as tmp:
        folder = Path(tmp)
        accepted: list[Path] = []
        for kind, what in (("run", "auvgw run --check --config"),
                           ("sim", "auvgw sim --check --scenario")):  # fmt: skip
            t0 = time.monotonic()
            counts, acc, kept = sweep(kind, folder, args.examples, args.subprocess)
            accepted += acc
            dt = time.monotonic() - t0
            n = sum(counts.values())
            rows.append(f"| `{what}` (in process) | {n} | {counts['ok']} | {counts['error']} | "
                        f"{counts['traceback']} | {1000 * dt / max(n, 1):.1f} ms |")  # fmt: skip
            bad += counts["traceback"]
            t0 = time.monotonic()
            sub = subprocess_sample(kind, kept)
            dt = time.monotonic() - t0
            n = sum(sub.values())
            rows.append(f"| `{what}` (subprocess) | {n} | {sub['ok']} | {sub['error']} | "
                        f"{sub['traceback']} | {1000 * dt / max(n, 1):.0f} ms |")  # fmt: skip
            bad += sub["traceback"]
        ran = run_accepted(accepted[: args.run], args.run_s)
    bad += len(ran["died"]) + ran["reader_errors"]
    table = "\n".join([
        "| files | checked | accepted | refused, one line per problem | traceback | per file |",
        "|---|---:|---:|---:|---:|---:|",
        *rows,
        "",
        f"Accepted configurations started ({args.run_s:g} s each, one Zenoh session): "
        f"{ran['configs']}; reader threads that died: {len(ran['died'])}; reader errors: "
        f"{ran['reader_errors']}; highest CPU of the process while they ran (after a 0.1 s start): "
        f"{100 * ran['worst_cpu']:.0f} % of a core.",
    ])  # fmt: skip
    print(table)
    if ran["died"] or ran["reader_errors"]:
        print(f"died: {ran['died'][:5]}; last reader error: {ran['last_error']}", file=sys.stderr)
    if not args.no_out:
        text = args.out.read_text()
        block = f"<!-- config-fuzz -->\n{table}\n<!-- /config-fuzz -->"
        pat = re.compile(r"<!-- config-fuzz -->.*?<!-- /config-fuzz -->", re.S)
        args.out.write_text(pat.sub(block, text) if pat.search(text) else text + "\n" + block)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
