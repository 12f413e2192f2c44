"""What the fusion stage's subscriptions deliver to its process (issue 31); prints two tables.

    nice -n 10 .venv/bin/python benchmarks/fusion_subscription.py [--count 2000]
        [--duration 40] [--speed 2] [--out out/fusion_subscription]

1. **Order.** A publisher process sends ``--count`` samples alternating between an INS key and a
   DVL key as fast as it can; this process receives them (a) on one wildcard subscription
   ``sensor/*/*`` (the stage before issue 31), (b) on one subscription per kind with Zenoh's
   default callbacks (each subscription's callback in a thread of its own), (c) on one
   subscription per kind with ``indirect=False`` callbacks (run in Zenoh's receiving thread: the
   stage's :meth:`~auvgw.stages.fusion.FusionStage.subscribe`). Printed: samples received and
   inversions (a sample queued after one published later).
2. **Counts in a short run.** ``auvgw demo --scenario survey --multibeam geoswath --processes``
   (every part its own process) for ``--duration`` vehicle seconds; a session of this process
   joins the gateway's bus and counts, in the same run, the samples and bytes that ``sensor/*/*``
   (before) and the stage's keys (after) deliver; the fusion process's own ``delivered``
   counter (its status, in the demo's ``summary.json``) says what reached it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import zenoh

from auvgw.bus import Keys, open_session
from auvgw.config.bus import BusConfig
from auvgw.stages.fusion import FusionStage, FusionStageConfig
from auvgw.testing import endpoint, free_port

PUBLISHER = """
import sys, time, zenoh
from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
n, ep = int(sys.argv[1]), sys.argv[2]
with open_session(BusConfig(mode="peer", connect=[ep])) as s:
    pubs = [s.declare_publisher(k) for k in ("auv/o/sensor/ins/ins", "auv/o/sensor/dvl/ensemble")]
    time.sleep(2.0)  # the subscribers' declarations reach this session
    for i in range(n):
        pubs[i % 2].put(i.to_bytes(4, "big"))
    time.sleep(1.0)
"""


class Seq:
    """Sequence numbers received on some subscriptions, in the order they were queued."""

    def __init__(self) -> None:
        self.got: list[int] = []
        self.lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append(int.from_bytes(sample.payload.to_bytes(), "big"))

    def inversions(self) -> int:
        return sum(b < a for a, b in zip(self.got, self.got[1:], strict=False))


def order(count: int) -> None:
    ep = endpoint(free_port())
    stage = FusionStage(FusionStageConfig(vehicle="o"))
    kinds = stage.subscription_keys()
    modes = {"one wildcard sensor/*/* (before)": Seq(), "per kind, default callbacks": Seq(),
             "per kind, indirect=False (after)": Seq()}  # fmt: skip
    wild, default, direct = modes.values()
    with open_session(BusConfig(mode="peer", listen=[ep])) as s:
        decls = [s.declare_subscriber("auv/o/sensor/*/*", wild)]
        decls += [s.declare_subscriber(k, default) for k in kinds]
        decls += [s.declare_subscriber(k, zenoh.handlers.Callback(direct, indirect=False))
                  for k in kinds]  # fmt: skip
        subprocess.run([sys.executable, "-c", PUBLISHER, str(count), ep], check=True)
        for d in decls:
            d.undeclare()
    print(f"\n{count} samples alternating on two keys, one publisher process\n")
    print("| subscription | received | inversions |")
    print("|---|---|---|")
    for name, seq in modes.items():
        print(f"| {name} | {len(seq.got)} | {seq.inversions()} |")


def counts(duration: float, speed: float, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    gw_toml = out / "gateway.toml"
    gw_toml.unlink(missing_ok=True)
    argv = [sys.executable, "-m", "auvgw", "demo", "--scenario", "survey", "--multibeam",
            "geoswath", "--processes", "--duration", str(duration), "--speed", str(speed),
            "--no-viz", "--no-slam", "--out", str(out)]  # fmt: skip
    demo = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    while not gw_toml.is_file():
        if demo.poll() is not None:
            raise SystemExit(f"the demo stopped early: {demo.stderr.read().decode()[-2000:]}")
        time.sleep(0.2)
    cfg = tomllib.loads(gw_toml.read_text())
    keys = Keys(cfg["vehicle"])
    stage_keys = FusionStage(FusionStageConfig(vehicle=cfg["vehicle"])).subscription_keys()
    tally = {"before": [0, 0], "after": [0, 0]}

    def counter(which: str) -> zenoh.handlers.Callback:
        def on(sample: zenoh.Sample) -> None:
            tally[which][0] += 1
            tally[which][1] += len(sample.payload)

        return zenoh.handlers.Callback(on, indirect=False)

    with open_session(BusConfig(mode="peer", connect=cfg["bus"]["listen"])) as s:
        decls = [s.declare_subscriber(keys.sensor("*", "*"), counter("before"))]
        decls += [s.declare_subscriber(k, counter("after")) for k in stage_keys]
        _, err = demo.communicate()
        for d in decls:
            d.undeclare()
    if demo.returncode != 0:
        raise SystemExit(f"demo exit {demo.returncode}: {err.decode()[-2000:]}")
    summary = json.loads((out / "summary.json").read_text())
    fusion = summary.get("fusion") or {}
    stage = fusion.get("stage", fusion)
    pings = summary["devices"].get("geoswath", {}).get("frames")
    print(f"\n`{' '.join(argv[2:])}` (GeoSwath frames: {pings})\n")
    print("| fusion subscription | samples | MB | fusion process: delivered / used |")
    print("|---|---|---|---|")
    b, a = tally["before"], tally["after"]
    print(f"| `sensor/*/*` (before) | {b[0]} | {b[1] / 1e6:.1f} | |")
    print(f"| {len(stage_keys)} kinds (after) | {a[0]} | {a[1] / 1e6:.1f} | "
          f"{stage.get('delivered')} / {stage.get('received')} |")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=2000)
    p.add_argument("--duration", type=float, default=40.0, help="vehicle s of the demo")
    p.add_argument("--speed", type=float, default=2.0)
    p.add_argument("--out", type=Path, default=Path("out/fusion_subscription"))
    args = p.parse_args()
    order(args.count)
    counts(args.duration, args.speed, args.out)


if __name__ == "__main__":
    main()
