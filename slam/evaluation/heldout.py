"""Held-out evaluation protocol (issue 28), shared by the magnetic and bathymetric studies.

**Seeds.** Base seeds below :data:`TEST_SEED_MIN` are *tuning* seeds (every result before
issue 28 used seed 0); base seeds from :data:`TEST_SEED_MIN` up are *test* seeds, run only
with parameters frozen before the run. **Scenarios.** A :class:`Split` names the tuning
scenarios (terrains, routes) and the test scenarios; the two never share a name.
:meth:`Split.check` refuses a tuning run on a test seed or test scenario, and a test run on a
tuning seed or tuning scenario. **Comparisons.** Every algorithm of run ``i`` sees the same
random numbers (common random numbers), so two algorithms are compared run by run:
:func:`paired_bootstrap_arrays` gives the mean difference and the ratio of the means with 95 %
percentile bootstrap intervals over the runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

__all__ = ["TEST_SEED_MIN", "Split", "paired_bootstrap_arrays", "seed_split"]

#: base seeds from here up are held-out test seeds; below: tuning seeds
TEST_SEED_MIN = 1000


def seed_split(seed: int) -> str:
    """``"test"`` for a held-out base seed (``>= TEST_SEED_MIN``), else ``"tuning"``."""
    return "test" if seed >= TEST_SEED_MIN else "tuning"


@dataclass(frozen=True)
class Split:
    """Named tuning and test scenarios of one study family (module docstring)."""

    tuning: tuple[str, ...]
    test: tuple[str, ...]

    def __post_init__(self) -> None:
        both = set(self.tuning) & set(self.test)
        if both:
            raise ValueError(f"scenarios in both tuning and test: {sorted(both)}")

    def check(self, seed: int, scenario: str, purpose: Literal["tuning", "test"]) -> None:
        """Raise ``ValueError`` unless base ``seed`` and ``scenario`` belong to ``purpose``."""
        if seed_split(seed) != purpose:
            raise ValueError(
                f"base seed {seed} is a {seed_split(seed)} seed, not a {purpose} seed "
                f"(test seeds are >= {TEST_SEED_MIN})"
            )
        names = self.tuning if purpose == "tuning" else self.test
        if scenario not in names:
            raise ValueError(
                f"scenario {scenario!r} is not a {purpose} scenario (those are {list(names)})"
            )


def paired_bootstrap_arrays(
    base: np.ndarray | list[float],
    other: np.ndarray | list[float],
    n_boot: int = 10000,
    seed: int = 0,
) -> dict[str, Any]:
    """Paired comparison of one measure (e.g. final error, m) of two algorithms over the same
    runs: the mean difference ``other - base`` and the ratio of the means ``other / base``,
    each with a 95 % percentile bootstrap interval over the runs (``n_boot`` resamples of the
    run indices, generator seeded ``seed``), and in how many runs ``other`` was lower."""
    a, b = np.asarray(base, float), np.asarray(other, float)
    if len(a) != len(b) or len(a) < 2:
        raise ValueError(f"a paired comparison needs the same runs (>= 2): {len(a)}, {len(b)}")
    idx = np.random.default_rng(seed).integers(0, len(a), (n_boot, len(a)))
    ma, mb = a[idx].mean(1), b[idx].mean(1)
    diff_ci = np.quantile(mb - ma, [0.025, 0.975])
    ratio_ci = np.quantile(mb / np.maximum(ma, 1e-12), [0.025, 0.975])
    return {
        "runs": len(a), "base_mean": float(a.mean()), "other_mean": float(b.mean()),
        "diff": float((b - a).mean()), "diff_ci": [float(x) for x in diff_ci],
        "ratio": float(b.mean() / a.mean()) if a.mean() > 0 else math.nan,
        "ratio_ci": [float(x) for x in ratio_ci], "other_better": int((b < a).sum()),
    }  # fmt: skip
