"""GeoSwath Plus cost per ping: the codec (encode, decode, framer + decode) and the emulator and
swath processing, in one run.

    .venv/bin/python benchmarks/bench_geoswath.py [--rounds 7] [--pings 200]

Pings with 1000, 4000 and 16000 RAA samples (plus 2 MRU, 1 NAV, 1 MINISVS record and two short
raw strings), built with the shipped table (``config/geoswath.toml``). Each operation is timed
over ``--pings`` pings in interleaved rounds; the median round is shown in microseconds per ping,
with its ratio to the decode time of the same size (so machine load affects all alike), and the
RAA sample rate the framer + decode path sustains (samples/s, one core).

Second table: per ping of each model (125, 250, 500 kHz) over the flat 40 m seabed at 15 m
altitude, the emulator's samples (``side_samples``: the terrain fan and the defects), the encode,
and the swath processing (``ping_soundings``: range, angle, filters, geometry, across-track
median; then ``SwathProcessor.add``, the binning of a 1 Hz swath amortised), with the
processing's ratio to the decode of the same ping, and the share of one core the processing
(the swath stage's work) takes at 4 pings/s (1x) and 40 pings/s (10x).

Third table: the emulator on the terrain of ``config/scenarios/survey.json`` (four octaves of
relief, what the end-to-end survey runs; the flat seabed above is nearly free to cast): per
ping, ``side_samples`` with every terrain evaluation in double precision (before issue 31's
fix: the sim process fell behind at 10x) and as shipped (its 721-ray fan and amplitudes with
the terrain's single-precision depth), their ratio and the share of a core each takes at 10x
(40 pings/s).

Times are this process's CPU time (``time.process_time``) unless ``--wall``: on a shared machine
at a load of several times its cores, wall times mostly measure the wait for a core.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.drivers.geoswath import GeoSwathFramer, GeoSwathPing, default_codec
from auvgw.ground.paths import config_file
from auvgw.sim_devices.geoswath import MODELS, side_samples
from auvgw.sim_devices.world import FlatTerrain, TerrainModel, World
from auvgw.slam.bathymetric.swath_processing import SwathProcessing, SwathProcessor, ping_soundings

SIZES = (1000, 4000, 16000)
#: the timer (main: CPU time of this process unless --wall)
clock = time.process_time
#: pings per second of one GeoSwath (sides alternating) at nominal speed
PING_RATE_HZ = 4.0


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
    ap.add_argument("--wall", action="store_true",
                    help="time on the wall clock (default: this process's CPU time, which a "
                         "loaded machine's waits for a core leave out)")  # fmt: skip
    args = ap.parse_args()
    global clock
    clock = time.perf_counter if args.wall else time.process_time
    print(f"({'wall' if args.wall else 'CPU'} time; machine load {os.getloadavg()[0]:.1f})\n")
    codec = default_codec()
    rng = np.random.default_rng(0)
    print(
        "| samples | encode us | decode us | framer+decode us | encode/decode "
        "| framer+decode/decode | Msamples/s | without the end check us | with/without |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for n in SIZES:
        pings = [build(n, k, rng) for k in range(args.pings)]
        wire = [codec.encode(p) for p in pings]
        stream = b"".join(wire)
        times: dict[str, list[float]] = {"enc": [], "dec": [], "frm": [], "old": []}
        for _ in range(args.rounds):
            t = clock()
            for p in pings:
                codec.encode(p)
            times["enc"].append(clock() - t)
            t = clock()
            for w in wire:
                codec.decode(w)
            times["dec"].append(clock() - t)
            for key, check_end in (("frm", True), ("old", False)):
                t = clock()
                fr = GeoSwathFramer(codec)
                fr.check_end = check_end  # False: no end check (before issue 31)
                got = 0
                for i in range(0, len(stream), 1 << 16):
                    for rec in fr.feed(stream[i : i + (1 << 16)]):
                        codec.decode_ping(rec.data)
                        got += 1
                for rec in fr.finish():
                    codec.decode_ping(rec.data)
                    got += 1
                times[key].append(clock() - t)
                assert got == len(pings) and fr.stats.bad_frames == 0
        us = {k: statistics.median(v) / len(pings) * 1e6 for k, v in times.items()}
        print(
            f"| {n} | {us['enc']:.1f} | {us['dec']:.1f} | {us['frm']:.1f} | "
            f"{us['enc'] / us['dec']:.2f} | {us['frm'] / us['dec']:.2f} | "
            f"{n / us['frm']:.1f} | {us['old']:.1f} | {us['frm'] / us['old']:.2f} |"
        )
    print()
    print(
        "| model kHz | samples | emulate us | encode us | decode us | soundings us "
        "| processor us | processor/decode | processing % core 1x | 10x |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    world = World(terrain=FlatTerrain(40.0), sound_speed=1500.0)
    for freq, max_range in MODELS.items():
        k_pings = max(args.pings // 10, 8)
        cfg = SwathProcessing(frequency_hz=freq)
        t_em: dict[str, list[float]] = {"emu": [], "enc": [], "dec": [], "snd": [], "proc": []}
        for _ in range(args.rounds):
            t = clock()
            raws = [side_samples(world, np.array([0.25 * k, 0.0, 25.0]), 0.0, 0.01, 0.02,
                                 k % 2, freq, max_range, rng) for k in range(k_pings)]  # fmt: skip
            t_em["emu"].append(clock() - t)
            t = clock()
            wire = [
                codec.encode(codec.make_ping(
                    {"ping_time": 1000.0 + 0.25 * k, "side": k % 2},
                    {"raa": {"time": r.time, "sine": r.sine, "amplitude": r.amplitude},
                     "nav": {"x": [0.0], "y": [0.25 * k], "z": [-25.0]}},
                ))
                for k, r in enumerate(raws)
            ]  # fmt: skip
            t_em["enc"].append(clock() - t)
            t = clock()
            decoded = [codec.decode_ping(w) for w in wire]
            t_em["dec"].append(clock() - t)
            t = clock()
            for p in decoded:
                ping_soundings(p, cfg)
            t_em["snd"].append(clock() - t)
            proc = SwathProcessor(cfg)
            t = clock()
            for p in decoded:
                proc.add(p)
            proc.flush()
            t_em["proc"].append(clock() - t)
        us = {k: statistics.median(v) / k_pings * 1e6 for k, v in t_em.items()}
        print(
            f"| {freq // 1000} | {len(raws[0].time)} | {us['emu']:.0f} | {us['enc']:.0f} | "
            f"{us['dec']:.0f} | {us['snd']:.0f} | {us['proc']:.0f} | "
            f"{us['proc'] / us['dec']:.1f} | {us['proc'] * PING_RATE_HZ / 1e4:.1f} | "
            f"{us['proc'] * PING_RATE_HZ / 1e3:.1f} |"
        )
    survey_emulator(args.rounds, max(args.pings // 10, 8), rng)


class _Float64(TerrainModel):
    """A terrain without a coarse depth: every evaluation in double precision (the emulator
    before issue 31's fix)."""

    def __init__(self, inner: TerrainModel) -> None:
        self.inner = inner

    def depth(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        return self.inner.depth(x, y)

    def gradient(
        self, x: np.ndarray | float, y: np.ndarray | float
    ) -> tuple[np.ndarray, np.ndarray]:
        return self.inner.gradient(x, y)

    @property
    def bounds(self) -> tuple[float, float]:
        return self.inner.bounds


def survey_emulator(rounds: int, k_pings: int, rng: np.random.Generator) -> None:
    """The third table (see the module docstring): 250 kHz pings on the survey's terrain."""
    print()
    print("| survey.json terrain | side_samples us (float64) | shipped (float32 fan) | ratio "
          "| % of a core at 10x, float64 / shipped |")  # fmt: skip
    print("|---|---|---|---|---|")
    world = World.from_scenario(load_scenario(config_file("scenarios/survey.json")))
    worlds = {"f64": World(terrain=_Float64(world.terrain), sound_speed=world.sound_speed),
              "f32": world}  # fmt: skip
    t_s: dict[str, list[float]] = {k: [] for k in worlds}
    for _ in range(rounds):
        for key, w in worlds.items():
            t = clock()
            for k in range(k_pings):
                side_samples(w, np.array([100.0 + 0.5 * k, 50.0, 25.0]), 0.3 + 0.01 * k, 0.01,
                             0.02, k % 2, 250_000, 195.0, rng)  # fmt: skip
            t_s[key].append(clock() - t)
    us = {k: statistics.median(v) / k_pings * 1e6 for k, v in t_s.items()}
    print(f"| 250 kHz, 4062 samples | {us['f64']:.0f} | {us['f32']:.0f} | "
          f"{us['f64'] / us['f32']:.1f} | {us['f64'] * PING_RATE_HZ / 1e3:.1f} / "
          f"{us['f32'] * PING_RATE_HZ / 1e3:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
