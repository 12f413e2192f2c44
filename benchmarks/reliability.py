"""How much random corruption each wire format lets through, and what it costs the good frames.

Per format and kind of corruption (1 bit flipped, 2 bits flipped, a burst of 2-16 random bytes
over a random stretch), ``--trials`` times: a stream of the format's good frames (as its codec
makes them; the real PD0 recording for PD0) with one frame corrupted is framed in random chunks
(1-200 bytes) and the frames decoded, as the gateway does. Reported:

* rejected: the share of corrupted frames the framer or the decoder refused (the rest came out
  as a valid message: corruption passed as good data);
* intact lost: good frames (not the corrupted one) that did not come out; must be 0.

Writes the table to docs/reliability.md (``--out``) between its ``<!-- table -->`` markers.
Regenerate with::

    .venv/bin/python benchmarks/reliability.py --trials 2000

(the sample frames come from the test house, ``auvgw.testing.format_samples``.)
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import ErrorPolicy
from auvgw.ground.paths import REPO_ROOT, shared_dir
from auvgw.testing.format_samples import STREAM_FORMATS, samples, v4log_records

Corrupt = Callable[[bytes, np.random.Generator], bytes]


def flip_bits(n: int) -> Corrupt:
    def corrupt(frame: bytes, rng: np.random.Generator) -> bytes:
        out = bytearray(frame)
        for bit in rng.choice(len(frame) * 8, n, replace=False):
            out[bit // 8] ^= 1 << (bit % 8)
        return bytes(out)

    return corrupt


def burst(frame: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(frame)
    n = int(rng.integers(2, min(16, len(frame)) + 1))
    at = int(rng.integers(0, len(frame) - n + 1))
    out[at : at + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return bytes(out)


KINDS: dict[str, Corrupt] = {"1 bit": flip_bits(1), "2 bits": flip_bits(2), "burst": burst}


def trial(fmt: str, good: list[bytes], head: bytes, corrupt: Corrupt, rng: np.random.Generator):
    """(rejected, intact frames lost) for one corrupted frame in the middle of the stream."""
    k = int(rng.integers(1, len(good) - 1))
    bad = corrupt(good[k], rng)
    while bad == good[k]:
        bad = corrupt(good[k], rng)
    wire = head + b"".join(good[:k]) + bad + b"".join(good[k + 1 :])
    f = get_format(fmt)
    framer = f.framer(policy=ErrorPolicy.IGNORE)
    out: list[bytes] = []
    i = 0
    while i < len(wire):
        n = int(rng.integers(1, 201))
        out += [fr.data for fr in framer.feed(wire[i : i + n])]
        i += n
    out += [fr.data for fr in framer.finish()]
    expected = good[:k] + good[k + 1 :]
    remaining = list(out)
    lost = 0
    for g in expected:
        if g in remaining:
            remaining.remove(g)
        else:
            lost += 1
    passed = 0
    for fr in remaining:  # frames that are not good ones: did they decode?
        try:
            f.decode(fr)
            passed += 1
        except Exception:  # any decode failure is a rejection
            pass
    return passed == 0, lost


def measure(trials: int, seed: int) -> list[tuple[str, str, float, int, int]]:
    rng = np.random.default_rng(seed)
    root = shared_dir()
    if root is None:
        raise SystemExit("../shared/data not found (set AUVGW_SHARED): PD0 needs the recording")
    streams: dict[str, tuple[list[bytes], bytes]] = {
        fmt: (samples(fmt, root / "data"), b"") for fmt in STREAM_FORMATS
    }
    with tempfile.TemporaryDirectory() as tmp:
        head, records = v4log_records(Path(tmp) / "r.V4LOG")
    streams["v4log"] = (records, head)
    rows = []
    jobs = [(fmt, kind) for fmt in streams for kind in KINDS]
    for fmt, kind in tqdm(jobs, desc="formats x corruptions"):
        good, head = streams[fmt]
        results = [trial(fmt, good, head, KINDS[kind], rng) for _ in range(trials)]
        rejected = sum(r for r, _ in results)
        lost = sum(n for _, n in results)
        rows.append((fmt, kind, rejected / trials, lost, trials))
    return rows


def table(rows: list[tuple[str, str, float, int, int]]) -> str:
    lines = ["| format | corruption | trials | rejected | passed as valid | intact frames lost |",
             "|---|---|---:|---:|---:|---:|"]  # fmt: skip
    for fmt, kind, rej, lost, n in rows:
        lines.append(f"| {fmt} | {kind} | {n} | {100 * rej:.1f} % | {100 * (1 - rej):.1f} % "
                     f"| {lost} |")  # fmt: skip
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=2000, help="per format and corruption")
    ap.add_argument("--seed", type=int, default=18)
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "reliability.md")
    args = ap.parse_args()
    rows = measure(args.trials, args.seed)
    text = table(rows)
    print(text)
    doc = args.out.read_text()
    new = re.sub(r"<!-- table -->.*<!-- /table -->",
                 f"<!-- table -->\n{text}\n<!-- /table -->", doc, flags=re.S)  # fmt: skip
    args.out.write_text(new)
    print(f"written to {args.out}")
    return 1 if any(lost for *_, lost, _ in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
