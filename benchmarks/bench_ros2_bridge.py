"""What the gateway's ROS 2 bridge costs when every topic is watched, and where; prints tables,
never fails on a time.

    .venv/bin/python benchmarks/bench_ros2_bridge.py [--rate 1650] [--seconds 6] [--rounds 2]
                                                      [--parts-only] [--cases CASE ...]
    .venv/bin/python benchmarks/bench_ros2_bridge.py --cold [--rate 1650] [--seconds 6]

The bridge (:class:`auvgw.stages.ros2.Ros2Bridge`) in this process, fed as the gateway feeds it
(:meth:`~auvgw.stages.ros2.RosStage.post` from a thread) with the all-devices bench's mix at 10x
(per 30 messages: 20 HN-100 solutions, 4 MS3A samples, 4 MSIS scan lines, 1 PD0 ensemble, 1
Kongsberg XYZ 88 ping: the sample frames of ``auvgw.testing.format_samples``, PD0's from the
real recording) at ``--rate`` messages/s, a subscriber on every ROS 2 key (``0/**``) in another
process. Per case, this process's CPU (all its threads: the feeding loop, the bridge's worker,
Zenoh's) over the fed seconds, in % of a core and in us per message, against "no bridge" (the
feeding loop alone) in the same round:

* ``no bridge``: the loop only;
* ``unwatched``: the bridge, no subscriber (it converts nothing: Zenoh's matching status);
* ``watched, rosbags``: rosbags objects and ``serialize_cdr`` for every message (the bridge
  before the compiled writers), 20 ms batches, puts held;
* ``watched, compiled, DATA priority``: the sensors' CDR from :mod:`auvgw.ros2_cdr`, the ROS 2
  publishers at the bus's own priority (the bridge before it put them at ``DATA_LOW``);
* ``watched, compiled``: the sensors' CDR from :mod:`auvgw.ros2_cdr`, publishers at
  ``DATA_LOW`` (now).

Rounds interleave the cases, in an order rotated per round, so the machine's drift hits them
all. First, the parts of one watched message, per ROS 2 form (single-thread timings, medians of
5 repeats): the conversion to rosbags objects, their CDR, the compiled writer (conversion and
CDR in one), the attachment, and a Zenoh put made alone and in a group of 40 (a subscriber in
another process).

``--cold`` prints instead what running once per batch window costs the bridge's worker (why
``[ros2] batch_ms`` defaults to 100, docs/ros2.md#cost): the mix in batches of a window's worth,
each after a sleep of the window, per message by window; and a writer's time by its place in a
20 ms batch and by whether a message of its form came before it in that batch.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
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
#: case -> (bridge on, watched, compiled CDR, ROS 2 publishers at the bus's DATA priority)
CASES: dict[str, tuple[bool, bool, bool, bool]] = {
    "no bridge": (False, False, True, False),
    "unwatched": (True, False, True, False),
    "watched, rosbags": (True, True, False, False),
    "watched, compiled, DATA priority": (True, True, True, True),
    "watched, compiled": (True, True, True, False),
}
#: the all-devices bench's mix: (device, format, messages per 30)
MIX = (("ins", "hn100", 20), ("mag", "ms3a", 4), ("msis", "seanet", 4), ("dvl", "pd0", 1),
       ("multibeam", "kongsberg", 1))  # fmt: skip


def mix() -> list[tuple[str, Any]]:
    """One cycle of the mix: (device, decoded message), 30 of them, sample messages with a
    standard ROS 2 form taken in turn."""
    from auvgw import ros2
    from auvgw.drivers.formats import get_format
    from auvgw.ground.paths import shared_dir
    from auvgw.testing.format_samples import stream_samples

    shared = shared_dir()
    tmp = Path(tempfile.mkdtemp(prefix="bench-ros2-"))
    out = []
    for device, fmt, n in MIX:
        _, frames = stream_samples(fmt, shared / "data" if shared else None, tmp)
        msgs = [m for f in frames for m in get_format(fmt).decode(f)
                if ros2.sensor_form(m) is not None]  # fmt: skip
        out += [(device, msgs[i % len(msgs)]) for i in range(n)]
    order = sorted(range(len(out)), key=lambda i: (i * 7) % len(out))  # the devices interleaved
    return [out[i] for i in order]


def _subscriber(ep: str) -> subprocess.Popen[str]:
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, ep], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert sub.stdout is not None and sub.stdout.readline().startswith("ready")
    return sub


def _count(sub: subprocess.Popen[str], settle: bool = False) -> int:
    """What the subscriber has received (``settle``: once the count stands still)."""
    assert sub.stdin is not None and sub.stdout is not None
    got, last = -1, -2
    while got != last:
        last = got
        sub.stdin.write("?\n")
        sub.stdin.flush()
        got = int(sub.stdout.readline())
        if not settle:
            break
        time.sleep(0.3)  # a loaded machine lags: poll until the count stands still
    return got


def run_case(case: str, rate: float, seconds: float,
             cycle: list[tuple[str, Any]]) -> tuple[float, float, int, int]:  # fmt: skip
    """(CPU % of a core, us per message, ROS 2 messages the subscriber got, ROS 2 messages the
    bridge put) of one case, over the fed window."""
    bridge_on, watched, compiled, data_priority = CASES[case]
    ep = endpoint(free_port())
    sub: Any = None
    with open_session(BusConfig(mode="peer", listen=[ep])) as session:
        if watched:
            sub = _subscriber(ep)
        bridge = None
        if bridge_on:
            bridge = Ros2Bridge(Ros2BridgeConfig(vehicle="v"), session, sections=())
            bridge.compiled = compiled
            if data_priority:
                bridge.priority = zenoh.Priority.DATA
            bridge.start()
            for d, m in cycle:  # each topic's first message declares its publisher
                bridge.post(d, time.time_ns(), m)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and (
                len(bridge._endpoints) < 6
                or (watched and not all(e.matching for e in bridge._endpoints.values()))
            ):
                time.sleep(0.05)  # a poll for the publishers and the match, not a measured wait
            time.sleep(bridge.batch_s + 0.2)
        put0 = bridge.stats.published if bridge is not None else 0
        got0 = _count(sub, settle=True) if sub is not None else 0
        n = int(rate * seconds)
        c0, t0 = time.process_time(), time.perf_counter()
        feeder = threading.Thread(target=_feed, args=(bridge, cycle, n, 1.0 / rate, t0))
        feeder.start()
        feeder.join()
        if bridge is not None:
            time.sleep(bridge.batch_s + 0.05)  # the last batch
        c1, t1 = time.process_time(), time.perf_counter()
        got = 0
        if sub is not None:
            got = _count(sub, settle=True) - got0
            sub.stdin.close()
            sub.wait(30)
        put = 0
        if bridge is not None:
            put = bridge.stats.published - put0
            bridge.stop()
    return 100 * (c1 - c0) / (t1 - t0), 1e6 * (c1 - c0) / n, got, put


def _feed(bridge: Ros2Bridge | None, cycle: list[tuple[str, Any]], n: int, period: float,
          t0: float) -> None:  # fmt: skip
    for i in range(n):
        if bridge is not None:
            d, m = cycle[i % len(cycle)]
            bridge.post(d, time.time_ns(), m)
        wait = t0 + (i + 1) * period - time.perf_counter()
        if wait > 0:
            time.sleep(wait)  # pacing at the gateway's rate


def _us(f: Any, n: int) -> float:
    """Median over 5 repeats of ``f()``'s CPU time (this thread), us per call (``n`` calls each)."""
    f()
    runs = []
    for _ in range(5):
        t = time.thread_time()
        for _ in range(n):
            f()
        runs.append((time.thread_time() - t) / n * 1e6)
    return statistics.median(runs)


def parts(cycle: list[tuple[str, Any]]) -> None:
    """Print the parts of a watched message's cost, per ROS 2 form."""
    from auvgw import ros2, ros2_cdr
    from auvgw.rmw_zenoh import pack_attachment

    print("\nParts of one watched message (us per sensor message, CPU of this thread, "
          "medians of 5):")
    print("| form (device) | conversion (rosbags objects) | rosbags CDR | compiled writer |")
    print("|---|---|---|---|")
    seen: set[str] = set()
    for d, m in cycle:
        form = str(ros2.sensor_form(m))
        if form in seen:
            continue
        seen.add(form)
        msgs = ros2.to_ros("sensor", d, m, 10**18)
        conv = _us(lambda d=d, m=m: ros2.to_ros("sensor", d, m, 10**18), 2000)
        cdr = _us(lambda msgs=msgs: [ros2.serialize(x) for x in msgs], 2000)
        fast = _us(lambda d=d, m=m: ros2_cdr.sensor_cdr(d, m, 10**18), 2000)
        print(f"| {form} ({d}) | {conv:.1f} | {cdr:.1f} | {fast:.1f} |")
    att = _us(lambda: pack_attachment(7, 10**18, bytes(16)), 20000)
    print(f"\nattachment: {att:.2f} us")
    ep = endpoint(free_port())
    payload = bytes(324)  # an Imu's CDR
    with open_session(BusConfig(mode="peer", listen=[ep])) as session:
        sub = _subscriber(ep)
        pub = session.declare_publisher("0/bench/parts")
        deadline = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < deadline:  # type: ignore[attr-defined]
            time.sleep(0.05)
        for group in (1, 40):
            c0, n = time.process_time(), 0
            t_end = time.perf_counter() + 2.0
            while time.perf_counter() < t_end:  # 1,650 puts/s, in groups
                for _ in range(group):
                    pub.put(payload, attachment=bytes(32))
                n += group
                time.sleep(group / 1650)
            cpu = (time.process_time() - c0) / n * 1e6
            print(f"Zenoh put, groups of {group}: {cpu:.1f} us of this process's CPU per put "
                  f"(1,650 puts/s)")
        sub.stdin.close()  # type: ignore[union-attr]
        sub.wait(30)


def cold(cycle: list[tuple[str, Any]], rate: float, seconds: float) -> None:
    """Print what the bridge's worker pays for running once per batch window: the mix's
    messages (fresh copies, as the gateway decodes new ones) in batches of what ``rate`` fills in
    a window, each batch after a sleep of the window, written by the compiled writers and put
    (a subscriber in another process), this thread's CPU per message; then, for 20 ms windows,
    a message's writer alone by its place in the batch and by whether its form came before."""
    import copy

    from auvgw import ros2, ros2_cdr
    from auvgw.rmw_zenoh import pack_attachment

    ep = endpoint(free_port())
    gid = bytes(16)
    with open_session(BusConfig(mode="peer", listen=[ep])) as session:
        sub = _subscriber(ep)
        pubs: dict[str, Any] = {}
        for d, m in cycle:
            for topic, _, _ in ros2_cdr.sensor_cdr(d, m, 10**18) or []:
                pubs.setdefault(topic, session.declare_publisher(
                    "0/bench/" + topic.replace("/", "_"), priority=zenoh.Priority.DATA_LOW))
        time.sleep(1.0)  # the subscriber matched (a settle, not a measured wait)
        print("\nThe worker's batches, cold (compiled writers + attachment + put, this thread's "
              f"CPU; {rate:,.0f} messages/s):")
        print("| window (ms) | messages per batch | us per message | % of a core at this rate |")
        print("|---|---|---|---|")
        for window_ms in (0, 20, 50, 100, 200):
            size = max(1, round(rate * max(window_ms, 20) / 1000))
            batches = max(3, round(seconds * 1000 / max(window_ms, 20)))
            work = [[copy.deepcopy(cycle[(b * size + i) % len(cycle)]) for i in range(size)]
                    for b in range(batches)]  # fmt: skip
            cpu = 0.0
            for batch in work:
                time.sleep(window_ms / 1000)
                t = time.thread_time()
                for d, m in batch:
                    for topic, _, cdr in ros2_cdr.sensor_cdr(d, m, 10**18) or []:
                        pubs[topic].put(cdr, attachment=pack_attachment(1, 10**18, gid))
                cpu += time.thread_time() - t
            per = cpu / (batches * size) * 1e6
            label = f"{window_ms}" if window_ms else "0 (no sleep: warm)"
            print(f"| {label} | {size} | {per:.1f} | {per * rate / 1e4:.2f} |")
        sub.stdin.close()  # type: ignore[union-attr]
        sub.wait(30)
    size = max(1, round(rate * 0.02))
    place: dict[int, list[float]] = {}
    first: dict[str, list[float]] = {}
    later: dict[str, list[float]] = {}
    for b in range(max(50, round(seconds * 50))):
        batch = [copy.deepcopy(cycle[(b * size + i) % len(cycle)]) for i in range(size)]
        time.sleep(0.02)
        seen: set[str] = set()
        for i, (d, m) in enumerate(batch):
            t = time.thread_time()
            ros2_cdr.sensor_cdr(d, m, 10**18)
            us = (time.thread_time() - t) * 1e6
            place.setdefault(min(i, 3), []).append(us)
            form = str(ros2.sensor_form(m))
            (later if form in seen else first).setdefault(form, []).append(us)
            seen.add(form)
    print(f"\nOne writer in a 20 ms batch of {size} (us, medians): by its place in the batch: "
          + ", ".join(f"{'4th on' if k == 3 else f'#{k + 1}'} {statistics.median(v):.1f}"
                      for k, v in sorted(place.items())))  # fmt: skip
    print("by form, the first of its form in the batch / a later one: " + "; ".join(
        f"{f} {statistics.median(first[f]):.1f} / "
        + (f"{statistics.median(later[f]):.1f}" if later.get(f) else "-") for f in first))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=1650.0, help="ROS 2 messages/s (default 1650)")
    ap.add_argument("--seconds", type=float, default=6.0, help="seconds per case (default 6)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (default 2)")
    ap.add_argument("--parts-only", action="store_true", help="only the parts table")
    ap.add_argument("--cold", action="store_true",
                    help="only the batches' cold cost by window and by place (the worker's wakes)")
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES),
                    metavar="CASE", help="a subset of the cases ('no bridge' always runs)")
    args = ap.parse_args()
    cases = ["no bridge", *(c for c in args.cases if c != "no bridge")]
    cycle = mix()
    if args.cold:
        cold(cycle, args.rate, args.seconds)
        return 0
    parts(cycle)
    if args.parts_only:
        return 0
    res: dict[str, list[tuple[float, float, int, int]]] = {c: [] for c in cases}
    for r in range(args.rounds):
        for case in cases[r % len(cases):] + cases[:r % len(cases)]:  # rotated per round
            res[case].append(run_case(case, args.rate, args.seconds, cycle))
            cpu, us, got, put = res[case][-1]
            print(f"round {r + 1} {case}: {cpu:.1f} % ({us:.1f} us/msg), put {put}, "
                  f"received {got}", file=sys.stderr, flush=True)  # fmt: skip
    n = int(args.rate * args.seconds)
    base = statistics.median(r[0] for r in res["no bridge"])
    print(f"\nROS 2 bridge, {args.rate:g} sensor messages/s (the gateway's mix), "
          f"{args.seconds:g} s per case, median of {args.rounds} interleaved rounds (load "
          f"{os.getloadavg()[0]:.1f} at the end)")
    print("| case | process CPU (% of a core) | bridge's share | us per sensor message | "
          "ROS 2 messages put, received |")
    print("|---|---|---|---|---|")
    for case, rows in res.items():
        cpu = statistics.median(r[0] for r in rows)
        put, got = min(r[3] for r in rows), min(r[2] for r in rows)
        share = (cpu - base) * 1e4 / args.rate
        print(f"| {case} | {cpu:.1f} | {cpu - base:+.1f} | {share:.0f} | "
              f"{f'{put}, {got} (of {n} sensor messages)' if CASES[case][1] else '-'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
