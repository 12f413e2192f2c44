"""Acoustic beacon (the sixth device): codec round trip, corrupted lines, emulator on a pty,
gateway decoding."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from auvgw.config.gateway import load_gateway_config
from auvgw.config.scenario import Scenario
from auvgw.decoding import make_decoders
from auvgw.drivers.acoustic import CODEC, AcousticFramer, AcousticReply
from auvgw.drivers.formats import get_format
from auvgw.drivers.framing import ErrorPolicy, FrameError
from auvgw.sim_devices.runner import Runner, RunOptions
from auvgw.testing.emulators import SerialReader, endpoint, run_for
from auvgw.testing.format_samples import ACOUSTIC_LINE as LINE


def _line(counter: int, rng: float, brg: float, dep: float = 10.0) -> bytes:
    return CODEC.encode(AcousticReply(counter=counter, range=rng, bearing=math.radians(brg),
                                      depression=math.radians(dep), beacon=1))  # fmt: skip


def test_reference_line_decodes_and_reencodes() -> None:
    m = CODEC.decode(LINE)
    assert (m.counter, m.range, m.beacon) == (42, pytest.approx(123.45), 1)
    assert m.bearing == pytest.approx(math.radians(-45.3))
    assert m.depression == pytest.approx(math.radians(12.0))
    assert CODEC.encode(m) == LINE
    assert get_format("acoustic").decode(LINE)[0] == m


@pytest.mark.parametrize("chunk", [1, 7, 40, 10_000])
def test_any_line_roundtrips_and_corruption_loses_no_good_line(chunk: int) -> None:
    rng = np.random.default_rng(2)
    lines = [_line(i, float(rng.uniform(0, 5000)), float(rng.uniform(-180, 180)),
                   float(rng.uniform(-90, 90))) for i in range(30)]  # fmt: skip
    for ln in lines:
        assert CODEC.encode(CODEC.decode(ln)) == ln
    bad_sum = lines[3][:-4] + b"00\r\n"
    bad_num = lines[5].replace(b",", b",x", 1)
    cut = lines[8][:20]
    stream = b"".join(
        [*lines[:3], bad_sum, lines[4], bad_num, *lines[6:8], cut, *lines[9:], b"\xff\x00junk"]
    )
    f = AcousticFramer(policy=ErrorPolicy.IGNORE)
    frames = [
        fr.data for fr in f.frames([stream[i : i + chunk] for i in range(0, len(stream), chunk)])
    ]
    good = [ln for i, ln in enumerate(lines) if i not in (3, 5, 8)]
    assert frames == good
    assert f.stats.bad_frames >= 2
    with pytest.raises(FrameError, match=r"ac\.log: bad frame at byte offset 0: checksum: line"):
        AcousticFramer(policy=ErrorPolicy.RAISE, source="ac.log").feed(bad_sum)


@pytest.mark.e2e
def test_emulator_on_a_pty_reports_range_and_bearing_and_the_gateway_decodes(
    tmp_path: Path,
) -> None:
    scn = Scenario.model_validate({
        "name": "ac-test", "seed": 3,
        "vehicle": {"waypoints": [[0, 0], [60, 0], [60, 40]], "speed_mps": 2.0, "depth_m": 5.0},
        "terrain": {"kind": "flat", "depth_m": 30.0},
        "acoustic_beacon": {"x": 30.0, "y": 20.0, "z": 30.0, "sigma_range_m": 0.2},
        "devices": {"acoustic": {"enabled": True, "rate_hz": 2.0,
                                 "options": {"miss_p": 0.2, "delay": False}}},
    })  # fmt: skip
    with Runner(scn, RunOptions(out_dir=tmp_path, speed=20, devices=["acoustic"])) as r:
        em = r.emulators["acoustic"]
        cfg = load_gateway_config(r.write_gateway_config(tmp_path / "gw.toml"))
        dec = make_decoders(cfg)["acoustic"]
        line = SerialReader(endpoint(r, "acoustic").target, 9600)
        run_for(r, 30.0)
        data = line.finish()
    msgs = [CODEC.decode(f.data) for f in AcousticFramer(policy=ErrorPolicy.RAISE).frames([data])]
    assert em.ticks == 61 and len(msgs) == em.ticks - em.missed
    assert 0.05 < em.missed / em.ticks < 0.45  # miss_p 0.2, with a tolerance
    counters = [m.counter for m in msgs]
    assert counters == sorted(counters) and len(set(counters)) == len(counters)
    res_r, res_b = [], []
    for m in msgs:
        s = r.truth.at(m.counter / em.rate_hz)
        d = np.array([30.0 - s.x, 20.0 - s.y, 30.0 - s.z])
        res_r.append(m.range - np.linalg.norm(d))
        res_b.append(math.remainder(m.bearing - (math.atan2(d[1], d[0]) - s.heading), math.tau))
    assert np.std(res_r) == pytest.approx(0.2, rel=0.5)
    assert np.sqrt(np.mean(np.square(res_b))) < math.radians(3.0)
    items = [i for c in (data[:50], data[50:]) for i in dec.feed(SimpleNamespace(data=c))]
    assert [i.messages[0].counter for i in items] == counters
