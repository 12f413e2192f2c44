"""PD0 framing + decode throughput on RDI_withBT.000 against dolfyn's reader, in the same run.

    .venv/bin/python benchmarks/bench_pd0.py [--runs 7] [--file PATH] [--baseline DIR]

Ours: the file's bytes (already in memory) fed to :class:`~auvgw.drivers.pd0.Pd0Framer` in
64 KiB chunks (every checksum verified) and every frame decoded to an
:class:`~auvgw.drivers.pd0.Ensemble` (SI values for every field of every data type), either one
by one with ``pd0.decode`` or per chunk with ``pd0.decode_many``.

dolfyn 1.3.0 needs numpy<2, scipy<1.14, pandas<2.2, xarray<2024.7, which this project's
environment does not have: the script creates (once) a separate venv at
``.bench/dolfyn-venv`` with ``python3 -m venv`` and pip-installs exactly those pins, then times
``dolfyn.io.rdi.read_rdi(path)`` in a subprocess (import time excluded). dolfyn's time includes
its own file reading, ensemble parsing and the construction of its xarray Dataset.

``--baseline DIR``: the same two readers of an older version of the code as well ("before"), in
the same interleaved rounds: ``DIR`` is a plain install of that version (``git worktree add
/tmp/base main && pip install --no-deps --target DIR /tmp/base``); each round runs this script
in a child process with ``DIR`` first on ``PYTHONPATH`` (a warm-up, then one timing of each).

The readers are timed in interleaved rounds (ours one by one, ours per chunk, dolfyn), the median
of the rounds is shown, so a change of machine load affects all of them alike; wall-clock time
is the headline, the process CPU time of the same runs is shown beside it (less sensitive to
other processes on a shared machine).

Beside the throughputs: the line rate of a Pathfinder on a 115200 baud 8N1 serial line
(11520 bytes/s) in ensembles/s for a bottom-track-only Pathfinder ensemble (fixed leader 58 B,
variable leader 77 B, bottom track 81 B) built by re-encoding the file's first ensemble.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from auvgw.drivers import pd0
from auvgw.ground.paths import REPO_ROOT, shared_dir

VENV = REPO_ROOT / ".bench" / "dolfyn-venv"
PINS = ["dolfyn==1.3.0", "numpy<2", "scipy<1.14", "pandas<2.2", "xarray<2024.7"]
BAUD_BYTES_PER_S = 115200 / 10  # 8N1: 10 bits per byte
CHUNK = 1 << 16

DOLFYN_SCRIPT = r"""
import contextlib, io, json, sys, time, warnings
warnings.simplefilter("ignore")
t0 = time.perf_counter()
import dolfyn
from dolfyn.io.rdi import read_rdi
t_import = time.perf_counter() - t0
path, runs = sys.argv[1], int(sys.argv[2])
wall, cpu = [], []
for _ in range(runs):
    with contextlib.redirect_stdout(io.StringIO()):
        t, c = time.perf_counter(), time.process_time()
        ds = read_rdi(path)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
print(json.dumps({"wall": wall, "cpu": cpu, "import_s": t_import, "n": int(ds.sizes["time"]),
                  "version": dolfyn.__version__}))
"""


def dolfyn_python() -> Path:
    """The dolfyn venv's python, creating the venv and installing the pins the first time."""
    py = VENV / "bin" / "python"
    if not py.exists():
        print(f"creating {VENV} (once) and installing {' '.join(PINS)} ...", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
        subprocess.run([str(py), "-m", "pip", "install", "-q", *PINS], check=True)
    return py


def time_ours(data: bytes, bulk: bool) -> tuple[float, float, int]:
    """(wall s, CPU s, ensembles) to frame ``data`` in 64 KiB chunks and decode every frame:
    one by one with :func:`pd0.decode`, or with :func:`pd0.decode_many` on each chunk's frames."""
    t, c = time.perf_counter(), time.process_time()
    framer = pd0.Pd0Framer(policy="ignore")
    n = 0
    for i in range(0, len(data), CHUNK):
        frames = framer.feed(data[i : i + CHUNK])
        if bulk:
            n += len(pd0.decode_many([f.data for f in frames]))
        else:
            for frame in frames:
                pd0.decode(frame.data)
                n += 1
    framer.finish()
    return time.perf_counter() - t, time.process_time() - c, n


def time_child(baseline: Path | None, path: Path) -> dict[str, list[float] | int]:
    """One round of both readers in a fresh child process: the code installed in ``baseline``
    (first on its PYTHONPATH), or this tree's (None)."""
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if baseline is not None:
        env["PYTHONPATH"] = str(baseline)
    out = subprocess.run(
        [sys.executable, __file__, "--round", "--file", str(path)],
        check=True, capture_output=True, text=True, env=env,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def one_round(data: bytes) -> dict[str, list[float] | int]:
    """``--round``: a warm-up, then one timing of each reader, as JSON (for ``--baseline``)."""
    time_ours(data, bulk=True)
    out: dict[str, list[float] | int] = {}
    for key, bulk in (("one", False), ("bulk", True)):
        wall, cpu, n = time_ours(data, bulk)
        out[key], out[f"{key}_n"] = [wall, cpu], n
    return out


def time_dolfyn(path: Path, runs: int) -> dict[str, object]:
    out = subprocess.run(
        [str(dolfyn_python()), "-c", DOLFYN_SCRIPT, str(path), str(runs)],
        check=True, capture_output=True, text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def pathfinder_bt_only_size(data: bytes) -> int:
    """Bytes of a bottom-track-only Pathfinder ensemble: the file's first ensemble re-encoded with
    only the fixed leader (58 B), variable leader (77 B) and bottom track (81 B)."""
    framer = pd0.Pd0Framer(policy="ignore")
    first = pd0.decode(framer.feed(data[:4096])[0].data)
    assert first.fixed_leader and first.variable_leader and first.bottom_track
    fl = dataclasses.replace(first.fixed_leader, beam_angle=None, extra=b"")
    vl = dataclasses.replace(
        first.variable_leader, spare_65=0, health_status=0, leak_a_count=0, leak_b_count=0,
        tx_voltage=float("nan"), tx_current=float("nan"), transducer_impedance=float("nan"),
    )
    bt = dataclasses.replace(first.bottom_track, reserved_81=None, extra=b"")
    ens = pd0.Ensemble(fixed_leader=fl, variable_leader=vl, bottom_track=bt)
    return len(pd0.encode(ens))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="timed rounds (>= 5; median shown)")
    ap.add_argument("--file", type=Path, default=None, help="PD0 file (default RDI_withBT.000)")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a plain install of the code before a change: timed as well")
    ap.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    path = args.file
    if path is None:
        shared = shared_dir()
        if shared is None:
            print("../shared/data not found (set AUVGW_SHARED)", file=sys.stderr)
            return 2
        path = shared / "data" / "pd0" / "RDI_withBT.000"
    data = path.read_bytes()
    if args.round:
        print(json.dumps(one_round(data)))
        return 0
    runs = max(args.runs, 5)
    before = ("one_before", "bulk_before") if args.baseline else ()

    dolfyn_python()  # create the venv before timing anything
    time_ours(data, bulk=True)  # warm-up: table plans and caches
    rows: dict[str, dict[str, list[float]]] = {
        k: {"wall": [], "cpu": []} for k in ("one", "bulk", *before, "dolfyn")
    }
    counts: dict[str, int] = {}
    theirs: dict[str, object] = {}
    for k in range(runs):  # interleaved rounds
        if not args.baseline:
            for key, bulk in (("one", False), ("bulk", True)):
                wall, cpu, counts[key] = time_ours(data, bulk)
                rows[key]["wall"].append(wall)
                rows[key]["cpu"].append(cpu)
        # with --baseline both sides run in fresh child processes, in alternating order (the
        # same code timed in this long-lived process and in a child differs by up to 10 %)
        sides = (("", None), ("_before", args.baseline)) if args.baseline else ()
        for suffix, where in sides[:: 1 if k % 2 == 0 else -1]:
            got = time_child(where, path)
            for key in ("one", "bulk"):
                wall, cpu = got[key]  # type: ignore[misc]
                rows[key + suffix]["wall"].append(wall)
                rows[key + suffix]["cpu"].append(cpu)
                counts[key + suffix] = int(got[f"{key}_n"])  # type: ignore[arg-type]
        theirs = time_dolfyn(path, 1)
        rows["dolfyn"]["wall"] += theirs["wall"]  # type: ignore[arg-type]
        rows["dolfyn"]["cpu"] += theirs["cpu"]  # type: ignore[arg-type]
        counts["dolfyn"] = int(theirs["n"])  # type: ignore[call-overload]
    med = {k: {m: statistics.median(v[m]) for m in v} for k, v in rows.items()}
    rate = {k: {m: counts[k] / med[k][m] for m in ("wall", "cpu")} for k in rows}
    mb = len(data) / 1e6
    pf_size = pathfinder_bt_only_size(data)
    line_ens = BAUD_BYTES_PER_S / pf_size

    print(f"file: {path} ({len(data)} bytes); median of {runs} interleaved rounds; checksums "
          "verified")
    print(f"{'reader':<40}{'ensembles':>10}{'wall s':>8}{'ens/s':>8}{'MB/s':>7}{'x dolfyn':>10}"
          f"{'cpu s':>8}{'x dolfyn':>10}")
    names = {
        "one": "auvgw Pd0Framer + decode (per frame)",
        "bulk": "auvgw Pd0Framer + decode_many (chunk)",
        **{k: f"  before: {k.split('_')[0]} (--baseline)" for k in before},
        "dolfyn": f"dolfyn {theirs['version']} read_rdi",
    }
    for k, name in names.items():
        print(f"{name:<40}{counts[k]:>10}{med[k]['wall']:>8.3f}{rate[k]['wall']:>8.0f}"
              f"{mb / med[k]['wall']:>7.2f}{rate[k]['wall'] / rate['dolfyn']['wall']:>9.1f}x"
              f"{med[k]['cpu']:>8.3f}{rate[k]['cpu'] / rate['dolfyn']['cpu']:>9.1f}x")
    print(f"{'Pathfinder line rate, 115200 baud 8N1':<40}{'':>10}{'':>8}{line_ens:>8.1f}"
          f"{BAUD_BYTES_PER_S / 1e6:>7.3f}{line_ens / rate['dolfyn']['wall']:>9.3f}x")
    for key in ("one", "bulk") if before else ():
        print(f"{key}: after / before = {rate[key]['wall'] / rate[key + '_before']['wall']:.3f} "
              f"(wall), {rate[key]['cpu'] / rate[key + '_before']['cpu']:.3f} (cpu)")
    print(f"bar: auvgw >= 10x dolfyn (ensembles/s). dolfyn import ({theirs['import_s']:.2f} s) "
          "excluded; its time includes reading the file and building its xarray Dataset.")
    print(f"line rate: {BAUD_BYTES_PER_S:.0f} B/s / {pf_size} B per bottom-track-only Pathfinder "
          "PD0 ensemble (fixed leader 58 B, variable leader 77 B, bottom track 81 B)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
