"""Where one frame's time goes in the gateway: host timestamps at every stage, and reads per frame.

    .venv/bin/python benchmarks/diag_gateway_stages.py [--format pd0] [--rate 10] [--frames 80]

``auvgw run`` (its own process, as in ``bench_gateway.py``) reads a raw pty that this script
writes whole frames into at ``--rate``; a Zenoh subscriber here receives the decoded samples.
The gateway process runs with its stages wrapped (this file re-executed with ``--child``), each
taking ``time.time_ns()`` (one system clock for both processes):

    os.write returns -> select wakes (the chunk's receive stamp) -> os.read returns ->
    framer done -> decoded -> envelope built -> raw put -> decoded put -> subscriber callback

and, after the puts, the health accounting and listeners. Where the gateway reads a frame's
envelope straight from its bytes (PD0, HN-100), "framer -> envelope from the bytes" replaces the
decode and envelope steps and the decode runs after the puts. Prints the median of each step (us)
over the frames that came alone in their read, and the reads per frame (a frame split over
several reads would show here). The wrappers cost a few us each; compare runs of this script
with each other (main against a branch in one sitting), not with ``bench_gateway.py``.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import Any

#: (step, from, to, path): path "decode" only for frames decoded before their envelope, "bytes"
#: only for envelopes read from the frame's bytes (decoded after the puts), None for both
STEPS = (
    ("write -> select wake", "written", "t_recv", None),
    ("wake -> read done", "t_recv", "read", None),
    ("read -> framer done", "read", "framed", None),
    ("framer -> decoded", "framed", "decoded", "decode"),
    ("decoded -> envelope", "decoded", "env", "decode"),
    ("framer -> envelope from the bytes", "framed", "env", "bytes"),
    ("envelope -> raw put", "env", "rawput", None),
    ("raw put -> decoded put", "rawput", "decput", None),
    ("decoded put -> subscriber", "decput", "arrived", None),
    ("total: write -> subscriber", "written", "arrived", None),
    ("after the puts (decode, health, listeners)", "decput", "done", None),
)


def child(out_path: str, argv: list[str]) -> int:
    """``auvgw run`` with each stage stamped; the stamps are written to ``out_path`` at exit."""
    import auvgw.decoding as decoding
    import auvgw.gateway as gateway
    from auvgw.cli import main
    from auvgw.drivers import transports

    reads: list[tuple[int, int]] = []  # (receive stamp, bytes)
    frames: list[dict[str, Any]] = []
    cur: dict[str, Any] = {}

    real_read = transports.SerialTransport.read

    def read(self: Any, timeout_s: float | None) -> Any:
        chunk = real_read(self, timeout_s)
        if chunk is not None:
            reads.append((chunk.t_recv_ns, len(chunk.data)))
            cur["read"] = time.time_ns()
        return chunk

    real_feed = decoding.DeviceDecoder.frames

    def feed(self: Any, chunk: Any) -> Any:
        framer = self._framer
        framer_feed = framer.feed

        def timed(data: bytes, now: float | None = None) -> Any:
            out = framer_feed(data, now)
            cur["framed"] = time.time_ns()
            return out

        framer.feed = timed
        try:
            return real_feed(self, chunk)
        finally:
            del framer.feed

    real_item = decoding.DeviceDecoder.item

    def item(self: Any, *a: Any) -> Any:  # (any signature: main's and a branch's alike)
        out = real_item(self, *a)
        cur["decoded"] = time.time_ns()
        return out

    real_envelope = gateway.encode_envelope

    def envelope(*a: Any, **k: Any) -> Any:
        out = real_envelope(*a, **k)
        cur["env"] = time.time_ns()
        return out

    real_pack = gateway.pack_envelope  # an envelope read from the bytes

    def pack(*a: Any) -> Any:
        out = real_pack(*a)
        cur["env"] = time.time_ns()
        cur["path"] = "bytes"
        return out

    class Stamped:
        def __init__(self, pub: Any, tag: str) -> None:
            self.pub, self.tag = pub, tag

        def put(self, *a: Any, **k: Any) -> None:
            self.pub.put(*a, **k)
            cur[self.tag] = time.time_ns()

        def undeclare(self) -> None:
            self.pub.undeclare()

    real_handle = gateway.Gateway._handle_frames

    def handle(self: Any, dev: Any, items: Any, t_recv_ns: int, *a: Any) -> None:
        for k, pub in list(dev.pubs.items()):
            if not isinstance(pub, Stamped):
                dev.pubs[k] = Stamped(pub, "rawput" if k == "raw" else "decput")
        for t, (pub, enc) in list(dev.routes.items()):
            if not isinstance(pub, Stamped):
                dev.routes[t] = (Stamped(pub, "decput"), enc)
        real_handle(self, dev, items, t_recv_ns, *a)
        if items:
            frames.append({**cur, "t_recv": t_recv_ns, "n": len(items), "seq": dev.seq,
                           "done": time.time_ns()})  # fmt: skip
        cur.clear()

    transports.SerialTransport.read = read  # type: ignore[method-assign]
    decoding.DeviceDecoder.frames = feed  # type: ignore[method-assign]
    decoding.DeviceDecoder.item = item  # type: ignore[method-assign]
    gateway.encode_envelope = envelope
    gateway.pack_envelope = pack
    gateway.Gateway._handle_frames = handle  # type: ignore[method-assign]
    atexit.register(lambda: Path(out_path).write_text(json.dumps({"reads": reads,
                                                                  "frames": frames})))  # fmt: skip
    return main(argv)


def run(fmt_name: str, rate: float, n: int) -> dict[str, Any]:
    """One run: ``n`` frames at ``rate`` Hz through a stamped gateway; medians and reads/frame."""
    sys.path.insert(0, str(Path(__file__).parent))
    import bench_gateway as bench

    from auvgw.bus import decode_envelope, open_session
    from auvgw.config.bus import BusConfig
    from auvgw.decoding import message_kind
    from auvgw.drivers.formats import get_format
    from auvgw.ground.paths import REPO_ROOT, shared_dir
    from auvgw.ground.procs import free_endpoint, stop_process

    if fmt_name == "pd0":
        shared = shared_dir()
        if shared is None:
            raise SystemExit("../shared/data not found (set AUVGW_SHARED)")
        it, _ = get_format("pd0").frames_of_file(shared / "data" / "pd0" / "RDI_withBT.000")
        frames = [f.data for f in it]
    else:
        frames = bench.hn100_frames(200)
    kind = message_kind(get_format(fmt_name).decode(frames[0])[0])
    tmp = Path(tempfile.mkdtemp(prefix="diag-gw-"))
    gw_ep, my_ep = free_endpoint(), free_endpoint()
    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp / "dev"
    link.symlink_to(os.ttyname(slave))
    cfg = tmp / "gw.toml"
    cfg.write_text(
        f'vehicle = "diag"\n[bus]\nlisten = ["{gw_ep}"]\n[devices.dev]\nformat = "{fmt_name}"\n'
        f'transport = {{ kind = "serial", url = "{link}" }}\n'
    )
    stamps = tmp / "stamps.json"
    with open(tmp / "gateway.log", "wb") as log:
        gw = subprocess.Popen(
            [sys.executable, __file__, "--child", str(stamps), "run", "--config", str(cfg)],
            stderr=log, cwd=REPO_ROOT,
        )  # fmt: skip
    arrived: dict[int, int] = {}
    written: dict[int, int] = {}
    session = open_session(BusConfig(listen=[my_ep], connect=[gw_ep]))

    def on_sample(sample: Any) -> None:
        t = time.time_ns()
        arrived[decode_envelope(sample.payload.to_bytes(), typed=False).seq & 0xFFFFFFFF] = t

    sub = session.declare_subscriber(f"auv/diag/sensor/dev/{kind}", on_sample)
    try:
        deadline = time.monotonic() + 60
        while not any(
            r.ok is not None and json.loads(r.ok.payload.to_bytes())["connected"]
            for r in session.get("auv/diag/status/dev", timeout=1.0)
        ):
            if time.monotonic() > deadline:
                raise SystemExit(f"gateway did not connect; see {tmp / 'gateway.log'}")
            time.sleep(0.2)
        seq = 0
        for phase_n in (5, n):  # 5 frames to set every route up, then the measured ones
            first = seq
            t0 = time.perf_counter()
            for i in range(phase_n):
                while (d := t0 + i / rate - time.perf_counter()) > 0:
                    time.sleep(d)
                view = memoryview(frames[seq % len(frames)])
                while view:
                    view = view[os.write(master, view) :]
                seq += 1
                written[seq] = time.time_ns()
            time.sleep(1.5)
    finally:
        stop_process(gw, signal.SIGTERM, 10.0)
        sub.undeclare()
        session.close()
        os.close(master)
        os.close(slave)
    data = json.loads(stamps.read_text())
    measured = [f for f in data["frames"] if (f["seq"] & 0xFFFFFFFF) > first]
    t_first = written[first + 1] - 1_000_000
    reads = [r for r in data["reads"] if r[0] >= t_first]
    steps: dict[str, list[float]] = {name: [] for name, *_ in STEPS}
    for f in measured:
        k = f["seq"] & 0xFFFFFFFF
        if f["n"] != 1 or k not in arrived:
            continue
        f["written"], f["arrived"] = written[k], arrived[k]
        path = f.get("path", "decode")
        for name, a, b, only in STEPS:
            if only in (None, path):
                steps[name].append((f[b] - f[a]) / 1e3)
    return {
        "format": fmt_name,
        "rate_hz": rate,
        "frames": n,
        "reads_per_frame": len(reads) / n,
        "load": os.getloadavg()[0],
        "median_us": {k: statistics.median(v) for k, v in steps.items() if v},
    }


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        return child(sys.argv[2], sys.argv[3:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--format", default="pd0", choices=("pd0", "hn100"))
    ap.add_argument("--rate", type=float, default=10.0, help="frames per second")
    ap.add_argument("--frames", type=int, default=80, help="frames measured")
    ap.add_argument("--json", type=Path, help="also write the result here")
    args = ap.parse_args()
    res = run(args.format, args.rate, args.frames)
    print(
        f"{res['format']} at {res['rate_hz']:g} Hz, {res['frames']} frames, load "
        f"{res['load']:.1f}: {res['reads_per_frame']:.2f} reads per frame\n"
    )
    for name, v in res["median_us"].items():
        print(f"{name:36s} {v:7.0f} us")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
