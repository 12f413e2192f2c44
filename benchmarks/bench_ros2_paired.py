"""The ROS 2 bridge's cost inside one gateway: watched and unwatched windows alternating (issue 32).

``bench_gateway.py --ros2`` compares separate gateway processes, one phase each, and this
host moves a plain gateway's CPU by 18-23 % of a core between phases of one run: a 5 % change
needs many rounds to show. Here one ``auvgw run`` with ``[ros2] enabled`` (the bridge in the
gateway) reads all five emulated devices of ``--scenario`` (the harbour) at ``--speed`` for the
whole run while this process declares and undeclares a ROS 2 subscriber on every ROS 2 key
(``0/**``, ``ros2 bag record -a``) in alternating windows of ``--window-s`` (their order swapped
every cycle):

* **watched**: Zenoh's matching status tells the bridge somebody listens; it converts and puts
  every sensor message (the gateway's ``[ros2] batch_ms`` batches);
* **unwatched**: nobody listens; the gateway's listener checks the matching status and queues
  nothing (``auvgw run`` without ``[ros2]`` does not even call it: ``bench_gateway.py --ros2``
  measured the two the same, 0.99-1.02x).

Each window starts ``--settle-s`` after the switch (the matching status reaches the bridge and
the last batch goes out); the gateway's CPU is utime + stime of its process and per group of
threads (``/proc``, as in ``bench_gateway.py``), the ratio is each cycle's watched window over
its unwatched one, so the host's drift cancels within a cycle. Also per window: the raw frames'
latency (the gateway's receive stamp, its ``[clock]`` scaling undone, to arrival here) and, when
watched, the ROS 2 copies' (their attachment's source time to arrival): the batch window's
price. ``--batch-ms`` runs one gateway per value (a list: one after the other, in order).

    .venv/bin/python benchmarks/bench_ros2_paired.py --batch-ms 20 100 --cycles 20
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import zenoh
from tqdm import tqdm

from auvgw.bus import open_session, unpack_raw_attachment
from auvgw.config.bus import BusConfig
from auvgw.rmw_zenoh import unpack_attachment
from auvgw.sim_devices.runner import gateway_toml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_gateway import (  # the sibling bench's helpers (sys.path above)
    BIN,
    CLK_TCK,
    REPO_ROOT,
    all_devices_scenario,
    cpu_ticks,
    free_endpoint,
    host_latency_ms,
    pct,
    python_thread_names,
    start_sim,
    stop_process,
    thread_groups,
    thread_ticks,
)

VEHICLE = "benchall"  # start_sim's


@dataclass
class Window:
    """One measured window: ``watched`` or not, the gateway's CPU (% of a core) in all and per
    group of threads, ROS 2 messages received per second, latencies (ms)."""

    cycle: int
    watched: bool
    cpu: float
    threads: dict[str, float]
    ros2_per_s: float
    raw_ms: list[float] = field(default_factory=list)
    ros2_ms: list[float] = field(default_factory=list)


def run_gateway(batch_ms: float, speed: float, cycles: int, window_s: float, settle_s: float,
                tmp: Path, scenario: str = "harbour") -> list[Window]:  # fmt: skip
    """One sim + gateway run of ``cycles`` watched/unwatched pairs (module docstring)."""
    warm_s = 15.0
    wall = warm_s + cycles * 2 * (window_s + settle_s) + 10
    t_open, t_close = 5.0 * speed, wall * speed
    out = Path(tempfile.mkdtemp(prefix=f"paired-{batch_ms:g}ms-", dir=tmp))
    scn = all_devices_scenario(out / "scenario.json", t_open, t_close, name=scenario)
    sim, sim_log, _, vclock, _ = start_sim(scn, speed, t_close + 5 * speed, out)
    cfg = tomllib.loads((out / "gateway.toml").read_text())
    ep = free_endpoint()
    cfg["status_period_s"] = 1.0
    cfg["bus"] = {"listen": [ep]}
    cfg["ros2"] = {"enabled": True, "batch_ms": batch_ms}
    (out / "gw.toml").write_text(gateway_toml(cfg, "benchmark: the ROS 2 bridge, paired"))
    gw_log = open(out / "gateway.log", "wb")  # noqa: SIM115 - closed below
    gw = subprocess.Popen([str(BIN / "auvgw"), "run", "--config", str(out / "gw.toml")],
                          stderr=gw_log, cwd=REPO_ROOT)  # fmt: skip
    clock = cfg.get("clock", {})
    scale, epoch = float(clock.get("time_scale", 1.0)), int(clock.get("epoch_ns", 0))

    def host_ms(stamp_ns: int, arrived_ns: int) -> float:
        return host_latency_ms(stamp_ns, arrived_ns, scale, epoch)

    windows: list[Window] = []
    raw: list[float] = []
    ros: list[float] = []
    count = [0]
    measuring = threading.Event()

    def on_raw(s: zenoh.Sample) -> None:
        if measuring.is_set() and s.attachment is not None:
            raw.append(host_ms(unpack_raw_attachment(s.attachment.to_bytes())[0], time.time_ns()))

    def on_ros(s: zenoh.Sample) -> None:
        count[0] += 1
        if measuring.is_set() and s.attachment is not None:
            ros.append(host_ms(unpack_attachment(s.attachment.to_bytes())[1], time.time_ns()))

    try:
        with open_session(BusConfig(connect=[ep])) as session:
            raw_sub = session.declare_subscriber(f"auv/{VEHICLE}/raw/**", on_raw)
            vclock.wait(t_open + warm_s * speed)
            # every ROS 2 key declared (a key's first sample is always converted) before the
            # first window: one short watched spell
            ros_sub: zenoh.Subscriber[None] | None = session.declare_subscriber("0/**", on_ros)
            time.sleep(2.0)
            names = python_thread_names(gw.pid)
            for cycle in tqdm(range(cycles), desc=f"batch_ms {batch_ms:g}", unit="cycle"):
                for watched in (False, True) if cycle % 2 == 0 else (True, False):
                    if watched and ros_sub is None:
                        ros_sub = session.declare_subscriber("0/**", on_ros)
                    elif not watched and ros_sub is not None:
                        ros_sub.undeclare()
                        ros_sub = None
                    time.sleep(settle_s)
                    raw.clear()
                    ros.clear()
                    n0, c0, t0, m0 = (
                        count[0],
                        cpu_ticks(gw.pid),
                        thread_ticks(gw.pid),
                        time.monotonic(),
                    )
                    measuring.set()
                    time.sleep(window_s)
                    measuring.clear()
                    n1, c1, t1, m1 = (
                        count[0],
                        cpu_ticks(gw.pid),
                        thread_ticks(gw.pid),
                        time.monotonic(),
                    )
                    secs = m1 - m0
                    windows.append(Window(
                        cycle, watched, (c1 - c0) / CLK_TCK / secs * 100,
                        thread_groups(t0, t1, names, secs), (n1 - n0) / secs, list(raw), list(ros),
                    ))  # fmt: skip
                    if gw.poll() is not None:
                        raise SystemExit(f"the gateway exited; see {out / 'gateway.log'}")
            if ros_sub is not None:
                ros_sub.undeclare()
            raw_sub.undeclare()
    finally:
        stop_process(gw, signal.SIGTERM, 30.0)
        stop_process(sim, signal.SIGTERM, 30.0)
        gw_log.close()
        sim_log.close()
    return windows


def summary(batch_ms: float, windows: list[Window]) -> dict[str, object]:
    """The run's medians, paired ratios and latencies (:func:`print_table`)."""
    by = {(w.cycle, w.watched): w for w in windows}
    cycles = sorted({w.cycle for w in windows if (w.cycle, not w.watched) in by})
    ratios = [by[(c, True)].cpu / by[(c, False)].cpu for c in cycles if by[(c, False)].cpu > 0]
    plain = [by[(c, False)] for c in cycles]
    watched = [by[(c, True)] for c in cycles]

    def groups(ws: list[Window]) -> dict[str, float]:
        keys = {g for w in ws for g in w.threads}
        return {g: statistics.mean(w.threads.get(g, 0.0) for w in ws) for g in keys}

    def lat(ws: list[Window], attr: str) -> tuple[float, float]:
        vals = [v for w in ws for v in getattr(w, attr)]
        return pct(vals, 0.5), pct(vals, 0.99)

    q = statistics.quantiles(ratios, n=4) if len(ratios) >= 2 else [float("nan")] * 3
    return {
        "batch_ms": batch_ms, "cycles": len(cycles),
        "unwatched": statistics.median(w.cpu for w in plain),
        "watched": statistics.median(w.cpu for w in watched),
        "ratio": statistics.median(ratios), "q1": q[0], "q3": q[2],
        "mean": statistics.mean(ratios),
        "se": statistics.stdev(ratios) / len(ratios) ** 0.5 if len(ratios) > 1 else float("nan"),
        "ros2_per_s": statistics.median(w.ros2_per_s for w in watched),
        "raw_unwatched": lat(plain, "raw_ms"), "raw_watched": lat(watched, "raw_ms"),
        "ros2_latency": lat(watched, "ros2_ms"),
        "threads": (groups(plain), groups(watched)),
    }  # fmt: skip


def print_table(rows: list[dict[str, object]]) -> None:
    print()
    print(
        "| [ros2] batch_ms | cycles | gateway CPU unwatched / watched (% of a core, medians) "
        "| watched / unwatched, paired: median (quartiles); mean +- s.e. | ROS 2 msgs/s "
        "| ROS 2 copies p50 / p99 (ms) | raw frames p50 / p99 (ms): unwatched; watched |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ru, rw, rl = r["raw_unwatched"], r["raw_watched"], r["ros2_latency"]
        print(
            f"| {r['batch_ms']:g} | {r['cycles']} | {r['unwatched']:.1f} / {r['watched']:.1f} "
            f"| **{r['ratio']:.3f}x** ({r['q1']:.3f}-{r['q3']:.3f}); {r['mean']:.3f} +- "
            f"{r['se']:.3f} | {r['ros2_per_s']:,.0f} | {rl[0]:.1f} / {rl[1]:.1f} "
            f"| {ru[0]:.2f} / {ru[1]:.2f}; {rw[0]:.2f} / {rw[1]:.2f} |"
        )  # type: ignore[index]
    print()
    print("threads, % of a core (means of the windows), unwatched -> watched:")
    for r in rows:
        plain, watched = r["threads"]  # type: ignore[misc]
        keys = sorted(k for k in set(plain) | set(watched)
                      if max(plain.get(k, 0.0), watched.get(k, 0.0)) >= 0.2)  # fmt: skip
        print(
            f"  batch_ms {r['batch_ms']:g}: "
            + "; ".join(f"{k} {plain.get(k, 0.0):.2f} -> {watched.get(k, 0.0):.2f}" for k in keys)
        )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--batch-ms",
        type=float,
        nargs="+",
        default=[100.0],
        help="[ros2] batch_ms of each gateway run (default: 100, the default)",
    )
    ap.add_argument("--cycles", type=int, default=20, help="watched/unwatched pairs per run")
    ap.add_argument("--window-s", type=float, default=4.0, help="measured seconds per window")
    ap.add_argument("--settle-s", type=float, default=0.6, help="seconds after each switch")
    ap.add_argument("--speed", type=float, default=10.0, help="the sim's speed (x real time)")
    ap.add_argument("--scenario", default="harbour",
                    help="config/scenarios/<name>.json, all five devices on (default: harbour)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-ros2-paired-") as tmp:
        for ms in args.batch_ms:
            windows = run_gateway(ms, args.speed, args.cycles, args.window_s, args.settle_s,
                                  Path(tmp), args.scenario)  # fmt: skip
            rows.append(summary(ms, windows))
            print(f"batch_ms {ms:g}: load {os.getloadavg()[0]:.1f}", file=sys.stderr)
    print(
        f"{args.scenario} scenario, all five devices at {args.speed:g}x; one gateway per batch_ms; "
        f"{args.window_s:g} s windows after {args.settle_s:g} s to settle"
    )
    print_table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
