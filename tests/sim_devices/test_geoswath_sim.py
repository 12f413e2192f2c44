"""GeoSwath emulator (raw samples from the terrain, the interferometer's defects, the wire) and
the swath processing (raw samples to binned XYZ 88 swaths) against the known geometry."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.drivers import kongsberg
from auvgw.drivers.formats import get_format
from auvgw.drivers.geoswath import GeoSwathPing, default_codec
from auvgw.sim_devices.geoswath import NOISE_FLOOR, SideSamples, side_samples
from auvgw.sim_devices.world import (
    FlatTerrain,
    ProceduralTerrain,
    TerrainModel,
    World,
    body_to_ned,
    first_crossing,
)
from auvgw.slam.bathymetric.swath_processing import (
    SwathProcessing,
    SwathProcessor,
    bin_swath,
    ping_soundings,
)
from auvgw.testing.geoswath import run_survey, survey_context, within

SEABED = 40.0
QUIET = {"angle_deg": 0.0, "nadir_k": 0.0, "range_k": 0.0}
WORLD = World(terrain=FlatTerrain(SEABED), sound_speed=1500.0)


def _samples(pos=(0.0, 0.0, 25.0), roll=0.05, pitch=-0.02, side=1, seed=0, **kw) -> SideSamples:
    return side_samples(WORLD, np.array(pos), 0.7, pitch, roll, side, 250_000, 195.0,
                        np.random.default_rng(seed), **kw)  # fmt: skip


def _level(s: SideSamples, roll: float, pitch: float, side: int) -> np.ndarray:
    """Each sample's (forward, starboard, down) offset, m, from its measured angle and range."""
    a = np.arcsin(s.sine / 32767.0)
    sgn = 1.0 if side == 1 else -1.0
    b = np.stack([np.zeros_like(a), sgn * np.sin(a), np.cos(a)]) * s.range_m
    return body_to_ned(0.0, pitch, roll) @ b


def test_samples_follow_the_seabed_geometry() -> None:
    """Noise off: every bottom sample's angle and range place it on the flat seabed 15 m
    below, from nadir (first return at the altitude) outward; the two sides mirror."""
    for side, roll in ((1, 0.05), (0, 0.05), (1, -0.1)):
        s = _samples(side=side, roll=roll, noise=QUIET, nadir_gap_deg=0.0, surface_fraction=0.0)
        assert s.time[0] == 16 and np.all(np.diff(s.time.astype(int)) == 16)  # wavelengths
        assert s.range_m[1] - s.range_m[0] == pytest.approx(1500 * 16 / 250_000 / 2)
        bottom = np.isfinite(s.true_angle)
        first = np.flatnonzero(bottom)[0]
        r0 = 15.0 / math.cos(roll) / math.cos(0.02)  # the body vertical's range: the fan's first
        assert 0 <= s.range_m[first] - r0 <= s.range_m[1] - s.range_m[0]
        p = _level(s, roll, -0.02, side)
        a = s.true_angle[bottom]
        quantum = s.range_m[bottom] * np.tan(np.abs(a)) * 0.5 / 32767  # sine rounding, as depth
        assert np.all(np.abs(p[2][bottom] - 15.0) < 1.2 * quantum + 0.005)
        assert np.all(np.sign(p[1][bottom][10:]) == (1 if side == 1 else -1))
        # Lambertian: the amplitude falls with grazing; the water column sits at the floor
        a = np.degrees(s.true_angle)
        assert np.median(s.amplitude[bottom & (a < 30)]) > 3 * np.median(
            s.amplitude[bottom & (a > 70)]
        )
        assert np.median(s.amplitude[:first]) < 2 * NOISE_FLOOR
        assert bottom.sum() > 1500 and not bottom[: first - 1].any()


def test_defects_nadir_range_gap_and_surface() -> None:
    pings = [_samples(roll=0.0, pitch=0.0, seed=k) for k in range(30)]  # few samples near nadir
    r = np.concatenate([s.range_m for s in pings])
    a_true = np.concatenate([s.true_angle for s in pings])
    sine = np.concatenate([s.sine for s in pings]) / 32767.0
    bottom = np.isfinite(a_true)
    err = np.arcsin(sine) - a_true
    deg = np.degrees(a_true)
    mirror = np.sqrt(np.clip(1 - (25 / r) ** 2, 0, 1))
    surface = (r > 25) & (np.abs(sine - mirror) < 1e-4)

    def sd(sel: np.ndarray) -> float:
        return float(np.std(err[sel & ~surface]))

    # angle noise: larger near nadir than at mid angles, larger at long range, as modelled
    mid = sd(bottom & (deg > 40) & (deg < 50))
    assert sd(bottom & (deg > 6) & (deg < 12)) > 1.3 * mid
    assert sd(bottom & (r > 150)) > 1.7 * mid
    a = np.radians(0.08) * (1 + 0.15 / np.maximum(np.sin(a_true), 0.05)) * (1 + 2 * (r / 195) ** 2)
    z = (err / a)[bottom & (deg > 5) & ~surface]
    assert abs(float(np.mean(z))) < 0.02 and float(np.std(z)) == pytest.approx(1.0, abs=0.03)
    # the nadir gap: random angles inside it
    gap = bottom & (deg < 5)
    assert gap.sum() > 10 and np.all(np.abs(np.degrees(np.arcsin(sine[gap]))) <= 5.01)
    # surface returns past the surface's range (25 m): about surface_fraction of the samples
    assert not surface[r <= 25].any()
    assert 0.015 < surface[r > 25].mean() < 0.025


@pytest.mark.parametrize("sides", ["alternate", "together"])
def test_emulator_pings_and_records(tmp_path: Path, sides: str) -> None:
    em = survey_context(tmp_path, {"sides": sides, "model_khz": 500})
    try:
        fmt = get_format("geoswath")
        got: list[GeoSwathPing] = []
        for k in range(4):
            for d in em.prepare(30.0 + k / em.rate_hz):
                (msg,) = fmt.decode(d)
                assert isinstance(msg, GeoSwathPing) and fmt.encode is not None
                assert fmt.encode(msg) == d
                got.append(msg)
    finally:
        em.close()
    want = [0, 1, 0, 1] if sides == "alternate" else [0, 1] * 4
    assert [int(p.header["side"]) for p in got] == want
    p = got[-1]
    t = 30.0 + 3 / em.rate_hz
    s = em.truth(t)
    assert p.header["ping_time"] == pytest.approx(em.ctx.epoch + t)
    assert p.count("raa") == int(2 * 95.0 / 1495.0 * 500_000) // 16  # the 500 kHz model
    assert p.arrays["nav"]["x"][0] == pytest.approx(s.y) and p.arrays["nav"]["z"][0] == -s.z
    assert p.arrays["mru"]["roll"][0] == pytest.approx(math.degrees(s.roll), abs=1e-4)
    assert p.arrays["gyro"]["heading"][0] == pytest.approx(math.degrees(s.heading) % 360, 1e-5)
    assert p.arrays["echo"]["depth1"][0] == pytest.approx(s.altitude, abs=1e-4)
    assert p.arrays["minisvs"]["velocity"][0] == pytest.approx(1495.0)


def _ping(s: SideSamples, side: int, pos: tuple[float, float, float], roll: float,
          pitch: float, t: float = 1000.0) -> GeoSwathPing:  # fmt: skip
    return default_codec().make_ping(
        {"ping_time": t, "side": side, "sample_interval": 16},
        {"raa": {"time": s.time, "sine": s.sine, "amplitude": s.amplitude},
         "nav": {"x": [pos[1]], "y": [pos[0]], "z": [-pos[2]]},
         "mru": {"roll": [math.degrees(roll)], "pitch": [math.degrees(pitch)]},
         "minisvs": {"velocity": [1500.0]}},
    )  # fmt: skip


def test_processing_applies_attitude_lever_arm_and_filters() -> None:
    """A transducer 0.5 m forward, 0.3 m to starboard and 0.8 m below the vehicle's reference
    point (at 25 m): with that lever arm every kept sounding is on the seabed at 40 m; without
    it, off by the lever arm's depth; the filters take the water column, the nadir gap and the
    surface returns."""
    roll, pitch = 0.08, -0.03
    lever = np.array([0.5, 0.3, 0.8])
    ref = np.array([0.0, 0.0, 25.0])
    xdcr = ref + body_to_ned(0.7, pitch, roll) @ lever
    cfg = SwathProcessing(lever_arm_m=(0.5, 0.3, 0.8), across_window=1)
    for side in (0, 1):
        s = _samples(tuple(xdcr), roll, pitch, side, noise=QUIET, surface_fraction=0.0)
        ps = ping_soundings(_ping(s, side, tuple(ref), roll, pitch), cfg)
        assert ps.depth_ref == 25.0 and len(ps.depth) > 1000
        assert np.all(np.abs(ps.depth + ps.depth_ref - SEABED) < 0.03)
        assert np.all(np.sign(ps.across) == (1 if side == 1 else -1))
        off = ping_soundings(_ping(s, side, tuple(ref), roll, pitch), SwathProcessing(
            across_window=1))  # fmt: skip
        level_lever = (body_to_ned(0.0, pitch, roll) @ lever)[2]
        assert np.median(off.depth + 25.0 - SEABED) == pytest.approx(-level_lever, abs=0.03)
        assert ps.dropped["amplitude"] >= int(np.sum(s.range_m < 15.0)) - 5  # water column
        # the nadir gap: rolled starboard down, the body vertical points to port; the starboard
        # fan's first returns are already 9 deg out
        assert (ps.dropped["angle"] > 0) == (side == 0)
    # surface returns and noise: the across-track median takes what the other filters leave
    s = _samples(tuple(xdcr), roll, pitch, 1, surface_fraction=0.05, seed=4)
    raw = ping_soundings(_ping(s, 1, tuple(ref), roll, pitch), SwathProcessing(
        lever_arm_m=(0.5, 0.3, 0.8), across_window=1))  # fmt: skip
    med = ping_soundings(_ping(s, 1, tuple(ref), roll, pitch), SwathProcessing(
        lever_arm_m=(0.5, 0.3, 0.8)))  # fmt: skip
    wild = np.abs(raw.depth + 25 - SEABED) > 1.0
    assert wild.sum() > 20 and med.dropped["median"] >= wild.sum()
    assert np.max(np.abs(med.depth + 25 - SEABED)) < 1.0


@pytest.mark.e2e
def test_binning_and_the_along_track_window() -> None:
    cfg = SwathProcessing(n_bins=41, along_window=3)
    procs = SwathProcessor(cfg)
    out: list[kongsberg.XYZ88] = []
    for k in range(12):  # 3 s of pings at 4 Hz, sides alternating
        side = k % 2
        s = _samples((1.0 * k, 0.0, 25.0), 0.0, 0.0, side, seed=k)
        out += procs.add(_ping(s, side, (1.0 * k, 0.0, 25.0), 0.0, 0.0, 1000.0 + k / 4))
        if k in (4, 8):  # the 5th ping closes swath 0, which waits for its successor (9th)
            assert len(out) == k // 8
    out += procs.flush()
    assert len(out) == 3 and procs.swaths == 3 and procs.pings == 12
    for i, m in enumerate(out):
        assert isinstance(m, kongsberg.XYZ88) and m.n_beams == 41
        assert m.device_time == pytest.approx(1000.0 + i)
        assert kongsberg.decode(kongsberg.encode(m))[0] == m  # the stage's message, on the wire
        b = m.beams
        ok = np.asarray(b.valid)
        assert ok.sum() >= 39  # (the nadir gap, 1.3 m each side, is inside the centre bin)
        assert np.all(np.abs(np.asarray(b.depth)[ok] + m.transducer_depth - SEABED) < 0.15)
        across = np.asarray(b.across)[ok]
        assert np.all(np.diff(across) > 0) and across[0] < -60 and across[-1] > 60
        # along: soundings of the swath's pings moved to its first ping (1 m per ping forward)
        assert 0.5 < float(np.median(np.asarray(b.along)[ok])) < 3.5
    # a swath of one ping: its bins' counts add up to the soundings inside the swath width
    s = _samples((0.0, 0.0, 25.0), 0.0, 0.0, 1, seed=9)
    ps = ping_soundings(_ping(s, 1, (0.0, 0.0, 25.0), 0.0, 0.0), cfg)
    across, _, depth, count = bin_swath([ps], cfg)
    assert count.sum() == np.sum(np.abs(ps.across) < 5 * 15.0)  # altitude: the median depth
    edges = np.linspace(-75.0, 75.0, 42)
    full = count >= 2
    lo, hi = edges[:-1][full] - 0.1, edges[1:][full] + 0.1
    assert np.all((across[full] >= lo) & (across[full] <= hi))
    assert np.all(np.isnan(depth[count < 2])) and not np.isnan(depth[count >= 2]).any()


def test_survey_sample_meets_the_accuracy_bar(tmp_path: Path) -> None:
    """A short stretch of the emulated survey (the full run: benchmarks/geoswath_accuracy.py,
    docs/results/geoswath/): at least 95 % of the binned soundings in the swath's centre 80 %
    within 1 % of the water depth, per bin no bias beyond 5 cm."""
    res = run_survey(survey_context(tmp_path), 40.0, 6.0)
    assert len(res.swaths) == 6 and res.pings == 24
    share, n = within(res)
    assert n > 500 and share >= 0.95
    assert abs(float(np.nanmean(res.error))) < 0.05


class _Counting(ProceduralTerrain):
    """The survey's kind of terrain, counting its exact and coarse evaluations (points)."""

    def __init__(self) -> None:
        super().__init__(40.0, 8.0, 150.0, seed=42, octaves=4)
        self.exact = self.coarse = 0

    def depth(self, x, y):  # type: ignore[no-untyped-def]
        self.exact += np.size(np.broadcast(np.asarray(x), np.asarray(y)))
        return super().depth(x, y)

    def gradient(self, x, y):  # type: ignore[no-untyped-def]
        self.exact += np.size(np.broadcast(np.asarray(x), np.asarray(y)))
        return super().gradient(x, y)

    def depth_coarse(self, x, y):  # type: ignore[no-untyped-def]
        self.coarse += np.size(np.broadcast(np.asarray(x), np.asarray(y)))
        return super().depth_coarse(x, y)


def test_the_emulator_casts_its_fan_in_single_precision() -> None:
    """Issue 31's end-to-end break: at 10x the survey's GeoSwath pings cost the emulator 11 ms of
    CPU each in double precision (45 % of a core beside the INS's 1000 ticks/s in the sim
    process, whose clock then fell 40-58 vehicle s behind). Its rays and amplitudes use the
    terrain's coarse (float32) depth, never the exact one; the fan's ranges stay within the
    terrain's ``coarse_tol_m`` of the exact cast, and the exact cast is unchanged by its coarse
    bracket."""
    terrain = _Counting()
    world = World(terrain=terrain, sound_speed=1500.0)
    pos = np.array([120.0, -60.0, 25.0])
    s = side_samples(world, pos, 0.4, 0.01, 0.03, 1, 250_000, 195.0, np.random.default_rng(1))
    assert terrain.exact == 0 and terrain.coarse > 10_000
    assert np.isfinite(s.true_angle).sum() > 0.3 * len(s.time)  # past the water column
    theta = np.radians(np.linspace(0.0, 85.0, 721))
    d = (body_to_ned(0.4, 0.01, 0.03) @ np.stack([0 * theta, np.sin(theta), np.cos(theta)])).T
    coarse = first_crossing(terrain, pos, d, 205.0, samples=24, exact=False)
    exact = first_crossing(terrain, pos, d, 205.0, samples=24)
    reference = first_crossing(_Exact(terrain), pos, d, 205.0, samples=24)
    hit = np.isfinite(reference)
    assert hit.sum() > 600 and np.array_equal(hit, np.isfinite(exact))
    assert np.array_equal(hit, np.isfinite(coarse))
    assert np.max(np.abs(exact[hit] - reference[hit])) < 1e-9
    assert 0 < np.max(np.abs(coarse[hit] - reference[hit])) < terrain.coarse_tol_m


class _Exact(TerrainModel):
    """A terrain with no coarse depth: :func:`first_crossing` as it was, all in float64."""

    def __init__(self, inner: TerrainModel) -> None:
        self.inner = inner

    def depth(self, x, y):  # type: ignore[no-untyped-def]
        return self.inner.depth(x, y)

    @property
    def bounds(self) -> tuple[float, float]:
        return self.inner.bounds
