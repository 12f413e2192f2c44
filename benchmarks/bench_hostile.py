"""Hostile input against the stages, the bar of issue 27; prints tables, never fails on a time.

    .venv/bin/python benchmarks/bench_hostile.py [--inputs 2000] [--seconds 8]

1. **The forged message.** ``auvgw fusion`` runs as its own process on a Zenoh router of this
   one; 2 x ``--seconds`` of the emulated survey's INS and DVL envelopes are published at their
   real rate; halfway, the forged envelopes of issue 27 (an old JSON envelope with
   ``"t_recv_ns": 1e300`` that stopped the odometry for good, a century-ahead stamp, a boolean
   stamp) go on the DVL's key. Printed: odometry per second before and after, the stage's
   counters of refused samples (bar: the rate unchanged, every forged envelope counted).
2. **The sweep.** ``--inputs`` hostile payloads (:mod:`auvgw.testing.hostile`: envelopes of every
   version with fields at their type edges, wrong types, deep nesting, huge sizes, raw bytes)
   into every stage in-process, in the middle of good traffic, on sensor and odometry keys.
   Printed per stage: inputs tried, good outputs lost (bar: 0), refused and counted.
3. **SeaNet corruption.** Every single-byte corruption (each offset, XOR 0x01 and 0xFF) of
   realistic mtHeadData packets (300 bins of echo amplitudes, as the emulated head sends), through
   the SeaNet framer and decoder: how many corrupted packets are refused, per region of the
   packet (header and its length fields; the data bytes, which no checksum covers).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from auvgw.bus import Keys, encode_envelope, open_session
from auvgw.config.bus import BusConfig
from auvgw.ground.procs import free_endpoint
from auvgw.testing import AUVGW, REPO
from auvgw.testing.fusion_emulated import HOST_EPOCH
from auvgw.testing.hostile import fusion_traffic

T0 = 100.0
KEYS = Keys("auv1")
FORGED = [
    json.dumps({"v": 1, "type": "pd0.Ensemble", "device": "dvl", "t_recv_ns": 1e300, "seq": 1,
                "msg": {}}).encode(),
    json.dumps({"v": 1, "type": "pd0.Ensemble", "device": "dvl",
                "t_recv_ns": int(HOST_EPOCH * 1e9) + 100 * 365 * 86_400 * 10**9, "seq": 2,
                "msg": {}}).encode(),
    b'{"v": 1, "type": "pd0.Ensemble", "device": "dvl", "t_recv_ns": true, "seq": 3, "msg": {}}',
]


def forged_run(seconds: float) -> None:
    import subprocess

    import zenoh

    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as tmpd:
        tmp = Path(tmpd)
        good, cfg = fusion_traffic(tmp / "ports", 2 * seconds)
        settings = tmp / "fusion.json"
        settings.write_text(cfg.model_dump_json())  # type: ignore[attr-defined]
        ep = free_endpoint()
        stamps: list[float] = []
        session = open_session(BusConfig(mode="router", listen=[ep]))
        err = open(tmp / "fusion.err", "wb")  # noqa: SIM115 - closed below
        proc = subprocess.Popen([AUVGW, "fusion", "--vehicle", "auv1", "--mode", "client",
                                 "--connect", ep, "--settings", str(settings)],
                                stdout=subprocess.PIPE, stderr=err, text=True)  # fmt: skip
        try:
            assert proc.stdout is not None
            for line in proc.stdout:
                if line.startswith("fusion running"):
                    break
            sub = session.declare_subscriber(KEYS.odometry(),
                                             lambda _s: stamps.append(time.monotonic()))
            block = zenoh.CongestionControl.BLOCK
            pubs = {k: session.declare_publisher(k, congestion_control=block)
                    for k in {k for _, k, _ in good}}  # fmt: skip
            deadline = time.monotonic() + 30
            while not all(p.matching_status.matching for p in pubs.values()):
                if time.monotonic() > deadline:
                    raise SystemExit("the fusion stage never subscribed")
                time.sleep(0.05)
            t_first = good[0][0]
            start = time.monotonic()
            forged_at = None
            for t, key, payload in good:
                wait = start + (t - t_first) - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                if forged_at is None and t - t_first >= seconds:
                    forged_at = time.monotonic()
                    for bad in FORGED:
                        pubs[KEYS.sensor("dvl", "ensemble")].put(bad)
                pubs[key].put(payload)
            end = time.monotonic()
            time.sleep(1.0)  # the fixed-lag tail
            status = None
            for reply in session.get(KEYS.status("fusion"), timeout=5.0):
                if reply.ok is not None:
                    status = json.loads(reply.ok.payload.to_bytes())
            sub.undeclare()
        finally:
            proc.terminate()
            proc.wait(20)
            err.close()
            session.close()
    assert forged_at is not None
    before = [s for s in stamps if start + 1 <= s < forged_at]
    after = [s for s in stamps if forged_at <= s < end]
    rate_b = len(before) / max(1e-9, forged_at - start - 1)
    rate_a = len(after) / max(1e-9, end - forged_at)
    st = (status or {}).get("stage", {})
    print("\n1. The forged message against a running `auvgw fusion` (separate process)\n")
    print(f"  {'odometry before':>16} {'after':>8} {'ratio':>6} {'bad payloads':>13} "
          f"{'bad stamps':>11} {'forged sent':>12}")
    print(f"  {rate_b:13.1f} Hz {rate_a:5.1f} Hz {rate_a / rate_b:6.2f} "
          f"{st.get('bad_payloads', '?'):>13} {st.get('bad_stamps', '?'):>11} {len(FORGED):>12}")
    print("  bar: the rate after equals the rate before (ratio 1.00 +- the pacing's jitter), "
          "every forged envelope counted")


def sweep(n_inputs: int) -> None:
    from hypothesis.errors import NonInteractiveExampleWarning

    from auvgw.testing.hostile import hostile_payloads

    sys.path.insert(0, str(REPO / "tests" / "service"))
    import test_hostile_inputs as t  # the battery's own stage factories and traffic

    warnings.simplefilter("ignore", NonInteractiveExampleWarning)
    strategy = hostile_payloads()
    bad = [strategy.example() for _ in range(n_inputs)]
    keys = [KEYS.sensor("dvl", "ensemble"), KEYS.odometry(), KEYS.sensor("ins", "ins")]
    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as tmpd:
        tmp = Path(tmpd)
        good3, cfg = fusion_traffic(tmp / "ports", 4.0)
        good = [(k, p) for _, k, p in good3]
        rows = []
        expected, _ = t._odometry(cfg, good)
        half = len(good) // 2
        mixed = good[:half] + [(keys[i % 3], b) for i, b in enumerate(bad)] + good[half:]
        got, stage = t._odometry(cfg, mixed)
        c = stage.counters()["stage"]
        lost = _lost(expected, got)
        rows.append(("fusion", len(bad), len(expected), lost, c["bad_payloads"] + c["bad_stamps"]))
        odo = [(KEYS.odometry(), encode_envelope(o, "fusion", round(o.t * 1e9), i + 1)[0])
               for i, o in enumerate(expected)]  # fmt: skip
        down = sorted(good + odo, key=lambda kp: _stamp(kp[1]))
        half = len(down) // 2
        mixed = down[:half] + [(keys[i % 3], b) for i, b in enumerate(bad)] + down[half:]
        for name in ("slam", "bathymetric", "magnetic", "ros2", "viz"):
            clean, _ = t._run(name, tmp / f"{name}-clean", down)
            out, counters = t._run(name, tmp / f"{name}-mixed", mixed)
            s = counters["stage"]
            refused = (s.get("errors", 0) + sum(s.get("unknown", {}).values()) if name == "viz"
                       else s["bad_payloads"] + s["bad_stamps"])  # fmt: skip
            lost = _lost(clean, out)
            rows.append((name, len(bad), len(clean), lost, refused))
    print(f"\n2. {n_inputs} hostile payloads into every stage, in the middle of good traffic\n")
    print(f"  {'stage':12} {'inputs tried':>12} {'good outputs':>13} {'lost':>5} "
          f"{'refused, counted':>17}")
    for name, n, good_out, lost, refused in rows:
        print(f"  {name:12} {n:12d} {good_out:13d} {lost:5d} {refused:17d}")
    print("  bar: lost 0 in every stage (viz: its outputs are Rerun rows, counted as refused or "
          "unknown here; the recorder: tests/service/test_hostile_inputs.py)")


def _lost(clean: list, out: list) -> int:
    """Good outputs of the clean run missing from the mixed run (a bridge also republishes a
    well-formed hostile message, an extra output that is no loss)."""
    from collections import Counter

    return sum((Counter(map(repr, clean)) - Counter(map(repr, out))).values())


def _stamp(payload: bytes) -> int:
    from auvgw.envelope import decode_envelope

    return decode_envelope(payload).t_recv_ns


def seanet_flips(n_packets: int = 20, seed: int = 7) -> None:
    from auvgw.drivers.seanet import codec as sn
    from auvgw.testing import format_samples as fs

    rng = np.random.default_rng(seed)
    head = next(m for m in fs.sample_messages() if type(m).__name__ == "HeadData")
    regions = {"header (0-14)": [0, 0], "head data fields (15-43)": [0, 0],
               "bins (data bytes)": [0, 0], "terminator": [0, 0]}  # fmt: skip
    for _ in range(n_packets):
        bins = np.clip(rng.gamma(2.0, 20.0, 300), 0, 255).astype(np.uint8)  # speckle and echoes
        bins[rng.integers(0, 300, 6)] = rng.integers(120, 255, 6)
        msg = dataclasses.replace(head, bins=bins)
        packet = sn.encode(msg)
        for off in range(len(packet)):
            region = ("header (0-14)" if off < 15 else "head data fields (15-43)" if off < 44
                      else "terminator" if off == len(packet) - 1 else "bins (data bytes)")
            for mask in (0x01, 0xFF):
                bad = bytearray(packet)
                bad[off] ^= mask
                framer = sn.SeaNetFramer()
                frames = framer.feed(bytes(bad))
                passed = False
                for f in frames:
                    try:
                        sn.decode(f.data)
                        passed = True
                    except Exception:
                        pass
                regions[region][0] += 1
                regions[region][1] += passed
    print("\n3. SeaNet mtHeadData, every single-byte corruption (XOR 0x01 and 0xFF at each "
          f"offset) of {n_packets} packets of 300 bins\n")
    print(f"  {'region':28} {'corruptions':>11} {'accepted':>9} {'refused':>8}")
    tot = [0, 0]
    for name, (n, ok) in regions.items():
        tot[0] += n
        tot[1] += ok
        print(f"  {name:28} {n:11d} {ok:9d} {100 * (n - ok) / n:7.1f} %")
    print(f"  {'all':28} {tot[0]:11d} {tot[1]:9d} {100 * (tot[0] - tot[1]) / tot[0]:7.1f} %")
    print("  SeaNet carries no checksum: a corrupted data byte is a wrong echo amplitude that "
          "nothing on the wire can detect")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=2000, help="hostile payloads per stage")
    ap.add_argument("--seconds", type=float, default=8.0, help="s before and after the forgery")
    ap.add_argument("--skip-process", action="store_true", help="no separate-process run")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # the stages log the first refused payloads
    print(f"bench_hostile: machine load {os.getloadavg()[0]:.1f}")
    if not args.skip_process:
        forged_run(args.seconds)
    sweep(args.inputs)
    seanet_flips()
    threading.Event().wait(0.1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
