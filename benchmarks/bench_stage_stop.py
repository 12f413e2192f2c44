"""How long a stage's command takes to stop after SIGINT: its own stop, then the process's exit.

    nice -n 10 .venv/bin/python benchmarks/bench_stage_stop.py [--runs 4] [--burners 0]

``auvgw fusion`` listens on a free port (no gateway: the stop path alone), prints ``fusion
running``, gets SIGINT a second later; timed: SIGINT to its ``fusion counters`` line (the stage
stopped, its session closed) and SIGINT to the process's exit. Two ways in one run: ``entry``
(``python -m auvgw``: ends with ``os._exit`` once stopped) and ``finalise`` (the same ``main``
under ``sys.exit``: the interpreter's finalisation, a garbage collection of the whole heap and the
modules' teardown, as every stage's command did before issue stop40); the ratio of their median
exits. ``--burners N`` starts N ``while True: pass`` processes beside it (a loaded host).

Measured (2 cores, 6 burners and other engineers' tests, load 10-12): at nice 0, finalise exit
0.83-1.22 s, entry 0.04-0.06 s; at nice 10, finalise 3.42-6.67 s (median 4.47), entry 0.23-0.68 s
(0.40), ratio 11.2x; 0.06-0.33 s to the counters line either way: the finalisation was most of
the stop, and it stretches with the CPU share the process gets.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import subprocess
import sys
import time

from auvgw.ground.procs import free_endpoint, stop_process

WAYS = {
    "entry": [sys.executable, "-m", "auvgw"],
    "finalise": [sys.executable, "-c", "import sys; from auvgw.cli import main; sys.exit(main())"],
}


def _one(argv: list[str]) -> tuple[float, float]:
    """(SIGINT to the counters line, SIGINT to the exit), s."""
    p = subprocess.Popen([*argv, "fusion", "--listen", free_endpoint()], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert p.stdout is not None and p.stderr is not None
        if not p.stdout.readline().startswith("fusion running"):
            raise SystemExit(f"fusion did not start: {p.stderr.read()}")
        time.sleep(1.0)  # a running stage, not one stopped while starting
        t0 = time.monotonic()
        p.send_signal(signal.SIGINT)
        t_counters = next((time.monotonic() for ln in p.stderr
                           if ln.startswith("fusion counters")), None)  # fmt: skip
        p.wait(60)
        if t_counters is None or p.returncode != 0:
            raise SystemExit(f"fusion exit {p.returncode} without its counters")
        return t_counters - t0, time.monotonic() - t0
    finally:
        stop_process(p, None, 5.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--burners", type=int, default=0)
    args = ap.parse_args()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
               for _ in range(args.burners)]  # fmt: skip
    try:
        exits = {}
        print(f"{'way':<10} {'run':>3} {'to counters s':>14} {'to exit s':>10}")
        for way, argv in WAYS.items():
            exits[way] = []
            for i in range(args.runs):
                counters, exit_ = _one(argv)
                exits[way].append(exit_)
                print(f"{way:<10} {i:>3} {counters:>14.2f} {exit_:>10.2f}", flush=True)
        med = {w: statistics.median(v) for w, v in exits.items()}
        print(
            f"median exit: finalise {med['finalise']:.2f} s, entry {med['entry']:.2f} s, "
            f"ratio {med['finalise'] / med['entry']:.1f}x"
        )
    finally:
        for b in burners:
            stop_process(b, signal.SIGKILL, 5.0)


if __name__ == "__main__":
    main()
