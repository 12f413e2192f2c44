"""The bus stage's queue and worker thread (``auvgw.ground.worker.Worker`` under ``Stage``):
the feeder's cost per item and the items handled per second, against an older version of the
code in the same interleaved rounds.

    .venv/bin/python benchmarks/bench_worker.py [--items 50000] [--rounds 5] [--baseline DIR]

A stage with a no-op ``feed`` is started (worker only, no bus) and given ``--items`` messages
with ``Stage.post`` (what the gateway's listeners and the Zenoh callbacks do); "post" is the
feeding loop's time per item (the cost a Zenoh callback pays; beside it the feeding thread's
own CPU time, which another thread holding the GIL does not inflate), "drain" the time from
the first post until ``stop()`` returned (every item handled) as items per second. The queue
holds them all (no drop). ``--baseline DIR``: a plain install of the older code (``pip install
--no-deps --target DIR <checkout>``); each round runs this script in a child process with
``DIR`` first on ``PYTHONPATH``. Medians of the rounds; wall clock and the process CPU time
beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time


def _one(items: int) -> dict[str, float]:
    from auvgw.stages.base import BusCounters, Stage, StageConfig

    class Sink(Stage):
        name = "bench"

        def feed(self, device: str, t_recv_ns: int, message: object) -> object:
            self.stats.received += 1
            return None

    stage = Sink(StageConfig(queue_size=items + 10), BusCounters())
    stage.start_worker()
    msg = object()
    c0, t0, th0 = time.process_time(), time.perf_counter(), time.thread_time()
    for i in range(items):
        stage.post("dev", i, msg)
    t_post, th_post = time.perf_counter() - t0, time.thread_time() - th0
    stage.stop(flush=False)
    t_all, c_all = time.perf_counter() - t0, time.process_time() - c0
    assert stage.stats.received == items and stage.stats.queue_dropped == 0, stage.stats
    return {"post_us": 1e6 * t_post / items, "post_cpu_us": 1e6 * th_post / items,
            "items_s": items / t_all, "cpu_items_s": items / c_all}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--items", type=int, default=50_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--baseline", default=None, help="a plain install of the older code")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_one(args.items)))
        return

    def child(path: str | None) -> dict[str, float]:
        env = dict(os.environ)
        if path is not None:
            env["PYTHONPATH"] = path + os.pathsep + env.get("PYTHONPATH", "")
        out = subprocess.run([sys.executable, __file__, "--child", "--items", str(args.items)],
                             env=env, capture_output=True, text=True, check=True, cwd="/")
        return dict(json.loads(out.stdout.strip().splitlines()[-1]))

    runs: dict[str, list[dict[str, float]]] = {"now": [], "before": []}
    for _ in range(args.rounds):
        runs["now"].append(child(None))
        if args.baseline:
            runs["before"].append(child(args.baseline))
    print(f"{args.items} items, {args.rounds} rounds (medians)")
    print(f"{'code':10s} {'post us/item':>13s} {'(its CPU)':>10s} {'drain items/s':>14s} "
          f"{'CPU items/s':>12s}")
    med = {}
    for name, rs in runs.items():
        if not rs:
            continue
        med[name] = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
        m = med[name]
        print(f"{name:10s} {m['post_us']:13.2f} {m['post_cpu_us']:10.2f} {m['items_s']:14,.0f} "
              f"{m['cpu_items_s']:12,.0f}")
    if "before" in med:
        a, b = med["now"], med["before"]
        print(f"{'now/before':10s} {a['post_us'] / b['post_us']:13.2f} "
              f"{a['post_cpu_us'] / b['post_cpu_us']:10.2f} {a['items_s'] / b['items_s']:14.2f} "
              f"{a['cpu_items_s'] / b['cpu_items_s']:12.2f}")


if __name__ == "__main__":
    main()
