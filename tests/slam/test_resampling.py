"""The one systematic resampler (auvgw.slam.resampling) that the landmark and bathymetric
particle filters share."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.slam.resampling import systematic_resample


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40).filter(lambda w: sum(w) > 1e-6),
    st.integers(0, 2**32 - 1),
)
def test_each_particle_is_drawn_floor_or_ceil_of_n_times_its_weight(raw, seed) -> None:
    w = np.asarray(raw) / np.sum(raw)
    n = len(w)
    idx = systematic_resample(w, np.random.default_rng(seed))
    assert idx.shape == (n,) and idx.min() >= 0 and idx.max() <= n - 1
    assert np.all(np.diff(idx) >= 0)  # positions are increasing: so are the indices
    counts = np.bincount(idx, minlength=n)
    assert np.all(counts >= np.floor(n * w - 1e-9)) and np.all(counts <= np.ceil(n * w + 1e-9))


def test_one_uniform_draw_per_call_and_the_draw_decides() -> None:
    w = np.array([0.1, 0.2, 0.3, 0.4])
    rng = np.random.default_rng(7)
    u = np.random.default_rng(7).random()
    idx = systematic_resample(w, rng)
    positions = (u + np.arange(4)) / 4
    assert idx.tolist() == np.searchsorted(np.cumsum(w), positions).tolist()
    assert rng.random() == np.random.default_rng(7).random(2)[1]  # the next draw is the 2nd
    # weights whose sum rounds a hair over 1 still give indices inside the set
    assert systematic_resample(np.full(3, 1 / 3 + 1e-16), np.random.default_rng(0)).max() <= 2
