"""Every emulator of a scenario at k x real time, with readers draining every port.

    .venv/bin/python benchmarks/bench_emulators.py [--scenario harbour] [--speed 10]
        [--duration 60] [--runs 3]

One :class:`~auvgw.sim_devices.runner.Runner` per run builds the world and every available
emulator of the scenario and runs them for ``--duration`` vehicle seconds at ``--speed`` x real
time. A reader process (this script with ``--reader``, so it has its own core and GIL, like a
gateway) opens every port with the real client library before the run starts: pyserial on the
serial ptys (framed and decoded with the drivers; the MSIS is polled by the gateway's own
:class:`~auvgw.drivers.seanet.host.SeaNetHost`), the USB-CAN adapters with python-can's
``slcan`` interface read in bulk as the gateway opens them
(:class:`~auvgw.drivers.slcanbus.BulkSlcanBus`; frames decoded with the DBC, counted in complete
epochs) and a UDP socket for the multibeam.

The table: per port, the nominal rate (vehicle Hz), the rate the emulator ticked at and the
rate the reader decoded at (messages per vehicle second, i.e. per real second / speed), the
reader/nominal ratio, bytes dropped by the port (a full pty or queue); then the clock's lag
(how far the dispatch of a tick ran behind its vehicle time, in vehicle seconds) and the real
time the run took against duration / speed. Then per device the CPU seconds it used: producing
samples (its ticks in the clock thread, delayed replies), its prefetch worker, its ports' I/O
threads (pacing, writes into the ptys, host requests such as the MSIS polls), and with one
process per device that whole process (imports and set-up excluded: from the start of the run);
and the clock thread's total (dispatch plus every device's ticks). Medians over ``--runs``
runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


# -- the reader process ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Events:
    """One reader thread's signals: ``opened`` (it set it: its port is open), ``draining`` (the
    run is over: no more SeaNet polls), ``stop`` (return)."""

    stop: threading.Event
    opened: threading.Event
    draining: threading.Event


def _read_serial(ep: dict[str, Any], counts: dict[str, int], ev: _Events) -> None:
    import serial

    from auvgw.drivers.formats import get_format

    fmt = get_format(ep["format"])
    framer = fmt.framer()
    s = serial.Serial(ep["target"], ep["transport"]["baud"], timeout=0.02)
    ev.opened.set()
    host = None
    write = s.write
    if ep["format"] == "seanet":
        from auvgw.config.gateway import MsisPolling
        from auvgw.drivers.seanet.host import SeaNetHost

        host = SeaNetHost(MsisPolling(**ep.get("msis", {})))
        host.on_connect(write, time.monotonic())
    try:
        while not ev.stop.is_set():
            data = s.read(max(1, s.in_waiting))
            for fr in framer.feed(data):
                for msg in fmt.decode(fr.data):
                    if host is None:
                        counts[ep["name"]] += 1
                        continue
                    counts[ep["name"] + (":pings" if type(msg).__name__ == "HeadData" else "")] += 1
                    if not ev.draining.is_set():  # the run is over: no more polls
                        host.on_message(msg, write, time.monotonic())
            if host is not None and not ev.draining.is_set():
                host.on_idle(write, time.monotonic())
    finally:
        s.close()
    counts[ep["name"] + ":bad"] = framer.stats.bad_frames


def _read_can(ep: dict[str, Any], counts: dict[str, int], ev: _Events) -> None:
    """The adapter opened as the gateway opens it: python-can's ``slcan`` interface read in bulk
    (:class:`~auvgw.drivers.slcanbus.BulkSlcanBus`), frames decoded with the DBC."""
    from auvgw.drivers.can_codec import load_can_codec
    from auvgw.drivers.slcanbus import BulkSlcanBus

    codec = load_can_codec(ep["dbc"])
    bus = BulkSlcanBus(channel=ep["target"], bitrate=ep["transport"]["bitrate"], sleep_after_open=0)
    ev.opened.set()
    try:
        while not ev.stop.is_set():
            msg = bus.recv(0.02)
            if msg is None:
                continue
            counts[ep["name"] + ":frames"] += 1
            if codec.decode(msg.arbitration_id, bytes(msg.data), msg.is_extended_id) is not None:
                counts[ep["name"]] += 1
    finally:
        counts[ep["name"] + ":bad"] = bus.malformed_lines
        bus.shutdown()


def _read_udp(ep: dict[str, Any], counts: dict[str, int], ev: _Events) -> None:
    import socket

    from auvgw.drivers.kongsberg import KongsbergFramer, decode

    framer = KongsbergFramer()
    tr = ep["transport"]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        sock.bind((tr["host"], tr["port"]))
        sock.settimeout(0.02)
        ev.opened.set()
        while not ev.stop.is_set():
            try:
                data = sock.recv(1 << 16)
            except TimeoutError:
                continue
            for fr in framer.feed(data):
                counts[ep["name"]] += len(decode(fr.data))


def reader_main(spec: str) -> int:
    """Open every endpoint, say 'ready', drain until 'stop' on stdin, print the counts."""
    from collections import Counter

    eps = json.loads(spec)
    counts: Counter[str] = Counter()
    stop = threading.Event()
    draining = threading.Event()
    kinds = {"serial": _read_serial, "can": _read_can, "udp": _read_udp}

    opened = [threading.Event() for _ in eps]

    def guarded(ep: dict[str, Any], ready: threading.Event) -> None:
        try:
            kinds[ep["kind"]](ep, counts, _Events(stop, ready, draining))
        except Exception as exc:
            counts[ep["name"] + ":error"] += 1
            print(f"reader {ep['name']}: {exc!r}", file=sys.stderr, flush=True)
            ready.set()

    threads = [
        threading.Thread(target=guarded, args=(ep, ev), daemon=True)
        for ep, ev in zip(eps, opened, strict=True)
    ]
    for th in threads:
        th.start()
    for ev in opened:
        ev.wait(30)
    time.sleep(0.2)  # the adapters have processed their open commands
    print("ready", flush=True)
    cpu0 = time.process_time()
    sys.stdin.readline()
    draining.set()
    end = time.monotonic() + 20.0
    while time.monotonic() < end:  # drain what is still on the way: until 0.5 s of quiet
        before = sum(counts.values())
        time.sleep(0.5)
        if sum(counts.values()) == before:
            break
    stop.set()
    for th in threads:
        th.join(5.0)
    cpu = time.process_time() - cpu0
    print(json.dumps({**counts, "reader_cpu_s": cpu}), flush=True)
    return 0


# -- the emulator side -------------------------------------------------------------------------


def one_run(scenario: Path, speed: float, duration: float, processes: bool) -> dict[str, Any]:
    from auvgw.config.scenario import load_scenario
    from auvgw.sim_devices.runner import DeviceProcesses, Runner, RunOptions

    with tempfile.TemporaryDirectory() as tmp:
        options = RunOptions(out_dir=Path(tmp), speed=speed)
        if processes:
            runner: Any = DeviceProcesses(scenario, options)
        else:
            runner = Runner(load_scenario(scenario), options)
        with runner:
            eps = []
            for ep in runner.endpoints():
                d = {"name": ep.name, "format": ep.format, "kind": ep.kind, "target": ep.target,
                     "transport": ep.transport, **ep.extra}  # fmt: skip
                eps.append(d)
            reader = subprocess.Popen(
                [sys.executable, __file__, "--reader", json.dumps(eps)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            assert reader.stdout is not None and reader.stdin is not None
            if reader.stdout.readline().strip() != "ready":
                raise RuntimeError("reader process failed to start")
            runner.start(duration=duration)
            runner.wait()
            # from vehicle time 0 (one process per device: a short lead after start())
            clock = runner.truth_runner.clock if processes else runner.clock
            real = time.monotonic() - clock.started_at
            if not processes:
                runner.flush(drain_timeout=2.0)
            reader.stdin.write("stop\n")  # the reader drains until its ports are quiet
            reader.stdin.flush()
            counts = json.loads(reader.stdout.readline())
            reader.wait(10)
            runner.stop()
            stats = runner.stats()
            unavailable = dict(runner.unavailable)
    bauds = {ep["name"]: ep["transport"].get("baud", 0) for ep in eps}
    ports: dict[str, dict[str, Any]] = {}
    cpu: dict[str, dict[str, float]] = {}
    for dev, st in stats["devices"].items():
        cpu[dev] = {**st["cpu_s"], "process": st.get("process_cpu_s", math.nan)}
        for ch, cs in st["channels"].items():
            ps = cs["port"]
            nominal, ticks, received = st["rate_hz"], st["ticks"], counts.get(ch, 0)
            if "ping_duration_s" in st:  # polled: one request and one ping at a time
                polls, replies = st["head"]["polls"], st["poll"]["replies"]
                line_b = ps["bytes_received"] / max(polls, 1)
                line_b += ps["bytes_written"] / max(replies, 1)
                cycle = st["ping_duration_s"] + line_b * 10 / bauds[ch]
                nominal = 1.0 / cycle if cycle > 0 else math.nan
                ticks = st["head"]["head_data"]
                received = counts.get(ch + ":pings", 0)
            ports[ch] = {
                "device": dev,
                "nominal": nominal,
                "ticks": ticks,
                "received": received,
                "dropped_bytes": ps.get("bytes_dropped", 0),
                "dropped_frames": ps.get("dropped_port", 0) + ps.get("dropped_closed", 0),
            }
    return {
        "real_s": real,
        "cpu_s": stats["process_cpu_s"],
        "clock_cpu_s": stats["clock_cpu_s"],
        "device_cpu": cpu,
        "load": os.getloadavg()[0],
        "max_lag_s": stats["max_lag_s"],
        "ports": ports,
        "unavailable": unavailable,
        "reader_errors": {k: v for k, v in counts.items() if k.endswith(":error")},
        "reader_cpu_s": counts["reader_cpu_s"],
    }


def report(label: str, runs: list[dict[str, Any]], dur: float, k: float) -> None:
    print(f"\n{label}")
    if runs[0]["unavailable"]:
        for name, why in runs[0]["unavailable"].items():
            print(f"  not run: {name}: {why}")
    head = f"{'port':18s} {'nominal Hz':>10s} {'ticked Hz':>10s} {'read Hz':>9s} {'read/nom':>9s}"
    print(head + f" {'dropped B':>10s} {'dropped fr':>10s}")
    for name in runs[0]["ports"]:
        rows = [r["ports"][name] for r in runs if name in r["ports"]]
        nominal = statistics.median(r["nominal"] for r in rows)
        ticked = statistics.median(r["ticks"] for r in rows) / dur
        read = statistics.median(r["received"] for r in rows) / dur
        drop_b = statistics.median(r["dropped_bytes"] for r in rows)
        drop_f = statistics.median(r["dropped_frames"] for r in rows)
        print(f"{name:18s} {nominal:10.2f} {ticked:10.2f} {read:9.2f} {read / nominal:9.3f} "
              f"{drop_b:10.0f} {drop_f:10.0f}")  # fmt: skip
    print(f"{'CPU s per device':18s} {'samples':>10s} {'worker':>10s} {'port I/O':>9s} "
          f"{'total':>9s} {'process':>10s} {'% core':>10s}")  # fmt: skip
    real = statistics.median(r["real_s"] for r in runs)
    for dev in runs[0]["device_cpu"]:
        rows = [r["device_cpu"][dev] for r in runs if dev in r["device_cpu"]]
        med = {k: statistics.median(c[k] for c in rows) for k in rows[0]}
        total = med["samples"] + med["worker"] + med["io"]
        proc = "-" if math.isnan(med["process"]) else f"{med['process']:.2f}"
        print(f"{dev:18s} {med['samples']:10.2f} {med['worker']:10.2f} {med['io']:9.2f} "
              f"{total:9.2f} {proc:>10s} {100 * total / real:10.1f}")  # fmt: skip
    clock_cpu = statistics.median(r["clock_cpu_s"] for r in runs)
    lag = statistics.median(r["max_lag_s"] for r in runs)
    cpu = statistics.median(r["cpu_s"] for r in runs)
    load = statistics.median(r["load"] for r in runs)
    print(f"real time {real:.2f} s for {dur / k:.2f} s expected (ratio {real * k / dur:.3f}); "
          f"clock max lag {lag * 1000:.0f} ms vehicle ({lag / k * 1000:.0f} ms real)")  # fmt: skip
    reader = statistics.median(r["reader_cpu_s"] for r in runs)
    print(f"emulator CPU {cpu:.2f} s ({cpu / real:.2f} cores; clock thread(s) {clock_cpu:.2f} s); "
          f"reader CPU {reader:.2f} s ({reader / real:.2f} cores); host load average {load:.1f} "
          f"on {os.cpu_count()} cores")  # fmt: skip
    errors = [e for r in runs for e in r["reader_errors"]]
    if errors:
        print(f"reader errors: {errors}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="harbour", help="name in config/scenarios or a path")
    ap.add_argument("--speed", type=float, default=10.0, help="k x real time")
    ap.add_argument("--duration", type=float, default=60.0, help="vehicle seconds per run")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--reader", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.reader is not None:
        return reader_main(args.reader)
    path = Path(args.scenario)
    if not path.exists():
        path = REPO / "config" / "scenarios" / f"{args.scenario}.json"
    dur, k = args.duration, args.speed
    print(f"scenario {path.name}: {dur:g} vehicle s at {k:g}x real time, {args.runs} runs per "
          f"mode (medians); readers in a second process")  # fmt: skip
    modes = {"one process": False, "one process per device (--processes)": True}
    results: dict[str, list[dict[str, Any]]] = {m: [] for m in modes}
    for _ in range(args.runs):  # interleaved, so a change of machine load hits both modes
        for label, processes in modes.items():
            results[label].append(one_run(path, k, dur, processes))
    for label, runs in results.items():
        report(label, runs, dur, k)
    print("\n(msis is polled, one request at a time: its nominal rate is one cycle of "
          "mtSendData on the line, the ping (two-way travel time over the range plus a motor "
          "step) and mtHeadData on the line; 'ticked' the HeadData it sent, 'read' those the "
          "host decoded. The host polls in real time, so each round trip also adds its real "
          "latency x speed, and a clock running behind real time lets more pings fit in a "
          "vehicle second)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
