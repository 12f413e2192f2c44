"""What mutual TLS and the per-component access control cost on the bus; prints a table, never
fails on a time.

    .venv/bin/python benchmarks/bench_security.py [--messages 20000] [--paced 1000] [--runs 3]

An ``auvgw router`` process in three set-ups: plain TCP (no security tables); the shipped
``config/security/router.toml`` without its ``access_control`` (mutual TLS only); the shipped file
as is (mutual TLS and the per-component ACL). Per run, a publisher process (the ``gateway``
identity, or a plain client) sends ``--messages`` 64-byte samples on a sensor key as fast as
``CongestionControl.BLOCK`` lets it, then ``--paced`` samples one per millisecond; the subscriber
in this process (the ``recorder`` identity) receives them through the router. Printed per set-up,
the median over ``--runs``: burst throughput (samples/s, and its ratio to plain TCP in the same
run) and the one-way latency of the paced samples (median and 99th percentile, us; the two
processes share the host clock).
"""

from __future__ import annotations

import argparse
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from auvgw.bus import load_bus_table, open_session
from auvgw.config.bus import BusConfig
from auvgw.ground.paths import config_file
from auvgw.ground.procs import free_port, stop_process
from auvgw.security import make_identity
from auvgw.testing import AUVGW, PYTHON

KEY = "auv/bench/sensor/dvl/ensemble"
#: burst flag (0) or paced (1), sequence, send time (ns, host clock), padding to 64 bytes
SAMPLE = struct.Struct("<BIq51x")


def _client(toml: Path | None, port: int) -> BusConfig:
    if toml is None:
        return BusConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])
    return BusConfig(**load_bus_table(toml)).rebased(toml.parent)


def publish(toml: str, port: int, burst: int, paced: int) -> int:
    """The publisher process: ``burst`` samples flat out, then ``paced`` at 1 kHz."""
    with open_session(_client(Path(toml) if toml != "-" else None, port)) as s:
        pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + 30
        while not pub.matching_status.matching:
            if time.monotonic() > deadline:
                print("no subscriber", flush=True)
                return 1
            time.sleep(0.01)
        for i in range(burst):
            pub.put(SAMPLE.pack(0, i, time.time_ns()))
        time.sleep(0.5)  # let the burst drain before the latency samples
        start = time.monotonic()
        for i in range(paced):
            wait = start + i * 1e-3 - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            pub.put(SAMPLE.pack(1, i, time.time_ns()))
        time.sleep(0.5)  # the session flushes before it closes
    print("done", flush=True)
    return 0


def one_run(setup: Path | None, tmp: Path, burst: int, paced: int) -> tuple[float, float, float]:
    """(burst samples/s, paced latency median us, p99 us) through a router with ``setup``."""
    port = free_port()
    args = [AUVGW, "router", "--listen", f"tcp/127.0.0.1:{port}"]
    folder = tmp / f"port-{port}"
    folder.mkdir()
    if setup is not None:
        for f in setup.parent.glob("*.toml"):
            (folder / f.name).write_text(f.read_text().replace(":7447", f":{port}"))
        (folder / "certs").symlink_to(tmp / "certs")
        args = [AUVGW, "router", "--bus-config", str(folder / setup.name)]
    router = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert router.stdout is not None
        if not router.stdout.readline().startswith("auvgw router"):
            raise SystemExit(f"{args}: the router did not start")
        times: list[tuple[int, int, int]] = []  # (flag, send ns, receive ns)
        lock = threading.Lock()

        def keep(sample: zenoh.Sample) -> None:
            now = time.time_ns()
            flag, _seq, sent = SAMPLE.unpack(sample.payload.to_bytes())
            with lock:
                times.append((flag, sent, now))

        sub_toml = None if setup is None else folder / "recorder-bus.toml"
        pub_toml = "-" if setup is None else str(folder / "gateway-bus.toml")
        with open_session(_client(sub_toml, port)) as s:
            sub = s.declare_subscriber(KEY, keep)
            pub = subprocess.run(
                [PYTHON, __file__, "--publish", pub_toml, str(port), str(burst), str(paced)],
                capture_output=True, text=True, timeout=600,
            )  # fmt: skip
            if pub.returncode != 0:
                raise SystemExit(f"publisher: {pub.stdout}{pub.stderr}")
            sub.undeclare()
    finally:
        stop_process(router)
    with lock:
        b = [r for f, _s, r in times if f == 0]
        lat = sorted((r - s) / 1e3 for f, s, r in times if f == 1)
    if len(b) < 2 or not lat:
        raise SystemExit(f"{args}: received {len(b)} burst and {len(lat)} paced samples")
    rate = (len(b) - 1) / ((b[-1] - b[0]) / 1e9)
    return rate, statistics.median(lat), lat[min(len(lat) - 1, int(0.99 * len(lat)))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=20000, help="burst samples per run")
    ap.add_argument("--paced", type=int, default=1000, help="1 kHz samples per run (latency)")
    ap.add_argument("--runs", type=int, default=3, help="runs per set-up (median printed)")
    ap.add_argument("--publish", nargs=4, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.publish is not None:
        toml, port, burst, paced = args.publish
        return publish(toml, int(port), int(burst), int(paced))
    shipped = config_file("security/router.toml")
    with tempfile.TemporaryDirectory(prefix="bench-security-") as tmpd:
        tmp = Path(tmpd)
        for name in ("router", "gateway", "recorder"):
            make_identity(tmp / "certs", name)
        no_acl = tmp / "tls-only" / "router.toml"
        no_acl.parent.mkdir()
        text = shipped.read_text()
        no_acl.write_text(text[: text.index("[bus.access_control]")])
        for f in shipped.parent.glob("*-bus.toml"):
            (no_acl.parent / f.name).write_text(f.read_text())
        setups: dict[str, Path | None] = {
            "plain TCP": None,
            "mutual TLS": no_acl,
            "mutual TLS + ACL": shipped,
        }
        results: dict[str, list[tuple[float, float, float]]] = {k: [] for k in setups}
        for _ in range(args.runs):  # interleaved, so load drifts hit every set-up alike
            for name, setup in setups.items():
                results[name].append(one_run(setup, tmp, args.messages, args.paced))
    print(f"\nBus security cost: gateway-identity publisher process -> auvgw router -> "
          f"subscriber, {SAMPLE.size}-byte samples; median of {args.runs} runs\n")  # fmt: skip
    print(f"  {'set-up':<18} {'burst samples/s':>16} {'runs min-max':>17} {'ratio':>6} "
          f"{'latency median us':>18} {'runs min-max':>13} {'p99 us':>8}")  # fmt: skip
    base = statistics.median(r[0] for r in results["plain TCP"])
    for name, rs in results.items():
        rates, meds = [r[0] for r in rs], [r[1] for r in rs]
        rate, med = statistics.median(rates), statistics.median(meds)
        p99 = statistics.median(r[2] for r in rs)
        print(f"  {name:<18} {rate:16.0f} {min(rates):8.0f}-{max(rates):<8.0f} "
              f"{rate / base:6.2f} {med:18.0f} {min(meds):6.0f}-{max(meds):<6.0f} "
              f"{p99:8.0f}")  # fmt: skip
    print(f"\n  burst: {args.messages} samples under BLOCK; latency: {args.paced} samples at 1 kHz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
