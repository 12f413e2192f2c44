"""What the gateway's ROS 2 bridge costs when every topic is watched; prints a table, never fails
on a time.

    .venv/bin/python benchmarks/bench_ros2_bridge.py [--rate 1650] [--seconds 6] [--rounds 2]

The bridge (:class:`auvgw.stages.ros2.Ros2Bridge`) in this process, fed as the gateway feeds it
(:meth:`~auvgw.stages.ros2.RosStage.post` from a thread, HN-100 solutions of 8 INS devices, so 8
``sensor_msgs/Imu`` topics, at ``--rate`` messages/s: the all-devices bench's ROS 2 rate at 10x),
a subscriber on every ROS 2 key (``0/**``) in another process. Per case, this process's CPU (all
its threads: the feeding loop, the bridge's worker, Zenoh's) over the fed seconds, in % of a core
and in us per message, against "no bridge" (the feeding loop alone) in the same round:

* ``no bridge``: the loop only;
* ``unwatched``: the bridge, no subscriber (it converts nothing: Zenoh's matching status);
* ``watched, 5 ms, each put``: the bridge before issue 32's cost work: 5 ms batches, each put
  as it is made, between the conversions;
* ``watched, 5 ms, held``: the worker's puts held and sent together;
* ``watched, 20 ms, held``: and 20 ms batches (``[ros2] batch_ms`` default).

Rounds interleave the cases so the machine's drift hits them all.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time
from typing import Any

from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
from auvgw.drivers.hn100 import Hn100Nav
from auvgw.stages.ros2 import Ros2Bridge, Ros2BridgeConfig
from auvgw.testing import endpoint, free_port

SUBSCRIBER = """
import sys
from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
n = [0]
with open_session(BusConfig(mode="peer", connect=[sys.argv[1]])) as s:
    sub = s.declare_subscriber("0/**", lambda _x: n.__setitem__(0, n[0] + 1))
    print("ready", flush=True)
    for _ in sys.stdin:
        print(n[0], flush=True)
"""
#: case -> (bridge on, watched, batch s, puts held)
CASES: dict[str, tuple[bool, bool, float, bool]] = {
    "no bridge": (False, False, 0.0, False),
    "unwatched": (True, False, 0.02, True),
    "watched, 5 ms, each put": (True, True, 0.005, False),
    "watched, 5 ms, held": (True, True, 0.005, True),
    "watched, 20 ms, held": (True, True, 0.02, True),
}


def _nav(i: int) -> Hn100Nav:
    return Hn100Nav(seq=i % 65536, status=0, time=10.0 + i / 100, roll=0.01, pitch=-0.02,
                    heading=(0.5 + i * 1e-3) % 6.28, rate_x=0.0, rate_y=0.0, rate_z=0.1,
                    accel_x=0.01, accel_y=0.0, accel_z=-9.81, vel_n=1.0, vel_e=0.1, vel_d=0.0,
                    latitude=0.7, longitude=0.1, depth=20.0, aligned=None, gnss_aided=None,
                    dvl_aided=None, error=None)  # fmt: skip


def run_case(case: str, rate: float, seconds: float) -> tuple[float, float, int, int]:
    """(CPU % of a core, us per message, messages the subscriber got, messages the bridge put)
    of one case."""
    bridge_on, watched, batch_s, held = CASES[case]
    ep = endpoint(free_port())
    msgs = [_nav(i) for i in range(1000)]
    devices = [f"ins{i}" for i in range(8)]
    sub: Any = None
    with open_session(BusConfig(mode="peer", listen=[ep])) as session:
        if watched:
            sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, ep], stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE, text=True)  # fmt: skip
            assert sub.stdout is not None and sub.stdout.readline().startswith("ready")
        bridge = None
        if bridge_on:
            bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="v", batch_ms=batch_s * 1000), session,
                                sections=())  # fmt: skip
            bridge.hold_puts = held
            bridge.start()
            for d in devices:  # each topic's first message declares its publisher
                bridge.post(d, time.time_ns(), msgs[0])
            deadline = time.monotonic() + 10
            while watched and time.monotonic() < deadline and not (
                len(bridge._endpoints) == 8 and all(e.matching for e in bridge._endpoints.values())
            ):
                time.sleep(0.05)  # a poll for the subscriber's match, not a measured wait
        n = int(rate * seconds)
        period = 1.0 / rate
        c0, t0 = time.process_time(), time.perf_counter()
        feeder = threading.Thread(target=_feed, args=(bridge, devices, msgs, n, period, t0))
        feeder.start()
        feeder.join()
        if bridge is not None:
            time.sleep(batch_s + 0.05)  # the last batch
        c1, t1 = time.process_time(), time.perf_counter()
        got = 0
        if sub is not None:
            assert sub.stdin is not None and sub.stdout is not None
            last = -1
            while got != last:  # until the count stands still (a loaded machine lags)
                last = got
                time.sleep(0.3)
                sub.stdin.write("?\n")
                sub.stdin.flush()
                got = int(sub.stdout.readline()) - len(devices)  # the 8 first: before the window
            sub.stdin.close()
            sub.wait(30)
        put = 0
        if bridge is not None:
            bridge.stop()
            put = bridge.stats.published - len(devices) - int(bridge.stats.tf)
    return 100 * (c1 - c0) / (t1 - t0), 1e6 * (c1 - c0) / n, got, put


def _feed(bridge: Ros2Bridge | None, devices: list[str], msgs: list[Hn100Nav], n: int,
          period: float, t0: float) -> None:  # fmt: skip
    for i in range(n):
        if bridge is not None:
            bridge.post(devices[i % 8], time.time_ns(), msgs[i % len(msgs)])
        wait = t0 + (i + 1) * period - time.perf_counter()
        if wait > 0:
            time.sleep(wait)  # pacing at the gateway's rate


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=1650.0, help="ROS 2 messages/s (default 1650)")
    ap.add_argument("--seconds", type=float, default=6.0, help="seconds per case (default 6)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (default 2)")
    args = ap.parse_args()
    res: dict[str, list[tuple[float, float, int, int]]] = {c: [] for c in CASES}
    for r in range(args.rounds):
        for case in CASES:
            res[case].append(run_case(case, args.rate, args.seconds))
            cpu, us, got, put = res[case][-1]
            print(f"round {r + 1} {case}: {cpu:.1f} % ({us:.1f} us/msg), put {put}, "
                  f"received {got}", file=sys.stderr, flush=True)  # fmt: skip
    n = int(args.rate * args.seconds)
    base = statistics.median(r[0] for r in res["no bridge"])
    print(f"\nROS 2 bridge, {args.rate:g} Imu messages/s on 8 topics, {args.seconds:g} s per case, "
          f"median of {args.rounds} interleaved rounds (load {os.getloadavg()[0]:.0f} at the end)")
    print("| case | process CPU (% of a core) | bridge's share | us per message | put, received |")
    print("|---|---|---|---|---|")
    for case, rows in res.items():
        cpu = statistics.median(r[0] for r in rows)
        put, got = min(r[3] for r in rows), min(r[2] for r in rows)
        share = (cpu - base) * 1e4 / args.rate
        print(f"| {case} | {cpu:.1f} | {cpu - base:+.1f} | {share:.0f} | "
              f"{f'{put}, {got} of {n}' if CASES[case][1] else '-'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
