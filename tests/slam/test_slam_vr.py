"""Variance reduction (VR paper section 3): theorem 1 and the annealing schedule."""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from auvgw.slam.landmark.vrfastslam import neff_of, variance_reduction

weights = st.lists(st.floats(1e-12, 1.0), min_size=2, max_size=60)


@settings(max_examples=150, deadline=None)
@given(weights, st.lists(st.floats(0.01, 1.0), min_size=2, max_size=8, unique=True))
def test_theorem1_neff_rises_monotonically_as_alpha_falls(w, alphas):
    logw = np.log(np.asarray(w))
    alphas = sorted(alphas, reverse=True)  # alpha falls
    neffs = [neff_of(a * logw) for a in [1.0, *alphas]]
    for a, b in itertools.pairwise(neffs):
        assert b >= a - 1e-9 * len(w)
    assert neffs[-1] <= len(w) + 1e-9


def test_equal_weights_are_a_fixed_point():
    assert math.isclose(neff_of(np.zeros(10)), 10.0)
    assert math.isclose(neff_of(0.3 * np.zeros(10)), 10.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-60.0, 0.0), min_size=5, max_size=100), st.floats(0.2, 0.9))
def test_reduction_takes_the_first_step_of_the_schedule_that_reaches_the_threshold(lw, frac):
    logw = np.asarray(lw)
    m = len(lw)
    thr = frac * m
    out, alpha, k = variance_reduction(logw, thr, lam=0.8, k0=1.0)
    if neff_of(logw) >= thr:
        assert k == 0 and alpha == 1.0
        return
    assert neff_of(out) >= thr - 1e-9
    if k == -1:  # beyond the schedule: bisection on alpha
        assert 0 < alpha < 0.8 / 62
        return
    assert math.isclose(alpha, min(1.0, 0.8 / math.log2(k + 1)))
    if k > 1:  # the previous step of alpha = lambda / log2(k + k0) was not enough
        prev = min(1.0, 0.8 / math.log2(k))
        assert neff_of(prev * (logw - logw.max())) < thr + 1e-9  # equal up to rounding
    # ordering of the weights is kept (principle 3)
    order = np.argsort(logw, kind="stable")
    assert np.all(np.diff(out[order]) >= -1e-12)
    np.testing.assert_allclose(np.exp(out).sum(), 1.0)
