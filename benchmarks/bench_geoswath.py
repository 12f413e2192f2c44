"""GeoSwath Plus ping codec cost per ping: encode, decode and framer + decode, in one run.

    .venv/bin/python benchmarks/bench_geoswath.py [--rounds 7] [--pings 200]

Pings with 1000, 4000 and 16000 RAA samples (plus 2 MRU, 1 NAV, 1 MINISVS record and two short
raw strings), built with the shipped table (``config/geoswath.toml``). Each operation is timed
over ``--pings`` pings in interleaved rounds; the median round is shown in microseconds per ping,
with its ratio to the decode time of the same size (so machine load affects all alike), and the
RAA sample rate the framer + decode path sustains (samples/s, one core).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from auvgw.drivers.geoswath import GeoSwathFramer, GeoSwathPing, default_codec

SIZES = (1000, 4000, 16000)


def build(n: int, k: int, rng: np.random.Generator) -> GeoSwathPing:
    codec = default_codec()
    dts = {name: dt for name, _, dt in codec.layout.arrays}
    raa = np.frombuffer(rng.bytes(6 * n), dts["raa"])
    return codec.make_ping(
        {"ping_number": k, "ping_time": 1.0 + k, "side": k % 2},
        {
            "raa": raa,
            "mru": np.zeros(2, dts["mru"]),
            "nav": np.zeros(1, dts["nav"]),
            "minisvs": np.zeros(1, dts["minisvs"]),
        },
        [b"$GPGGA,1*00\r\n", b"", b"$HEHDT,1*00\r\n", b"", b"", b"", b""],
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--pings", type=int, default=200)
    args = ap.parse_args()
    codec = default_codec()
    rng = np.random.default_rng(0)
    print(
        "| samples | encode us | decode us | framer+decode us | encode/decode "
        "| framer+decode/decode | Msamples/s |"
    )
    print("|---|---|---|---|---|---|---|")
    for n in SIZES:
        pings = [build(n, k, rng) for k in range(args.pings)]
        wire = [codec.encode(p) for p in pings]
        stream = b"".join(wire)
        times: dict[str, list[float]] = {"enc": [], "dec": [], "frm": []}
        for _ in range(args.rounds):
            t = time.perf_counter()
            for p in pings:
                codec.encode(p)
            times["enc"].append(time.perf_counter() - t)
            t = time.perf_counter()
            for w in wire:
                codec.decode(w)
            times["dec"].append(time.perf_counter() - t)
            t = time.perf_counter()
            fr = GeoSwathFramer(codec)
            got = 0
            for i in range(0, len(stream), 1 << 16):
                for _, rec in fr.feed(stream[i : i + (1 << 16)]):
                    codec.decode(rec)
                    got += 1
            times["frm"].append(time.perf_counter() - t)
            assert got == len(pings) and fr.stats.bad_frames == 0
        us = {k: statistics.median(v) / len(pings) * 1e6 for k, v in times.items()}
        print(
            f"| {n} | {us['enc']:.1f} | {us['dec']:.1f} | {us['frm']:.1f} | "
            f"{us['enc'] / us['dec']:.2f} | {us['frm'] / us['dec']:.2f} | "
            f"{n / us['frm']:.1f} |"
        )


if __name__ == "__main__":
    main()
