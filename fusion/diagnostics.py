"""Health of the fusion's DVL (and position) updates, for the status, Rerun and summaries.

:class:`FusionDiagnostics` keeps the fixes of the last ``window_s`` seconds (sample time) and
the totals: accepted / rejected / forced shares, the coasting share of the outputs, the NIS
(normalised innovation squared) and its consistency, the normalised innovations per axis (mean
and standard deviation: 0 and 1 for a consistent filter) and the adapted DVL noise. Two
warnings:

* ``dvl_rejections``: more than ``max_reject_share`` (1/3) of the window's fixes were rejected;
* ``nis_inconsistent``: over a full window the summed NIS of the accepted fixes is above the
  two-sided ``nis_probability`` (99 %) chi-square interval of their degrees of freedom: the
  filter is overconfident (it assumes less noise than the data have), so it rejects good fixes
  and its sigma understates its error.

A NIS below the interval (``nis_consistent`` false, ``nis_side`` "low") is a conservative filter:
its process or measurement noise is larger than the data need (a Pathfinder with the default
cheap-DVL velocity random walk shows NIS ~0.05 per degree of freedom). It is reported in the
summary as the note ``nis_conservative``, not as a warning: its sigma overstates its error, it
does not lose fixes.

Pure computation (no transports): the bus stage publishes :meth:`FusionDiagnostics.summary`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from auvgw.fusion.deviation import CompassDeviationEstimator
from auvgw.ground.geometry import chi2_ppf

__all__ = ["FixRecord", "FusionDiagnostics"]


@dataclass(frozen=True)
class FixRecord:
    """One DVL fix as the filter judged it: time (s), accepted, forced, NIS, its degrees of
    freedom, and the normalised innovation per axis (NaN for a missing axis)."""

    t: float
    accepted: bool
    forced: bool
    nis: float
    dof: int
    norm: tuple[float, float, float]


class FusionDiagnostics:
    """Windowed and total statistics of the DVL fixes and of the outputs (see the module
    docstring). ``window_s``: length of the window, s of sample time."""

    def __init__(
        self,
        window_s: float = 60.0,
        max_reject_share: float = 1.0 / 3.0,
        nis_probability: float = 0.99,
    ) -> None:
        self.window_s = float(window_s)
        self.max_reject_share = float(max_reject_share)
        self.nis_probability = float(nis_probability)
        self.fixes: deque[FixRecord] = deque()
        self.outputs: deque[tuple[float, bool]] = deque()
        self.total_fixes = 0
        self.total_accepted = 0
        self.total_rejected = 0
        self.total_forced = 0
        self.total_outputs = 0
        self.total_coasting = 0
        self.noise_sigma: tuple[float, float, float] = (math.nan,) * 3
        #: the compass deviation estimate (None: ``compass_deviation = "off"``)
        self.compass_deviation: CompassDeviationEstimator | None = None
        self.last_t = -math.inf
        self.first_t = math.nan

    def add_fix(self, rec: FixRecord) -> None:
        """Record one DVL fix that had at least one valid component."""
        self.fixes.append(rec)
        self.total_fixes += 1
        self.total_accepted += rec.accepted
        self.total_rejected += not rec.accepted
        self.total_forced += rec.forced
        self._advance(rec.t)

    def add_output(self, t: float, coasting: bool) -> None:
        """Record one odometry output (coasting or not)."""
        self.outputs.append((t, coasting))
        self.total_outputs += 1
        self.total_coasting += coasting
        self._advance(t)

    def _advance(self, t: float) -> None:
        if math.isnan(self.first_t):
            self.first_t = t
        self.last_t = max(self.last_t, t)
        start = self.last_t - self.window_s
        while self.fixes and self.fixes[0].t < start:
            self.fixes.popleft()
        while self.outputs and self.outputs[0][0] < start:
            self.outputs.popleft()

    def summary(self) -> dict[str, object]:
        """JSON-ready statistics: ``window`` (the last ``window_s``) and ``total`` shares, NIS,
        innovations, adapted noise, and the active ``warnings``."""
        fixes = list(self.fixes)
        n = len(fixes)
        acc = [f for f in fixes if f.accepted]
        rejected = sum(not f.accepted for f in fixes)
        forced = sum(f.forced for f in fixes)
        n_out = len(self.outputs)
        coasting = sum(c for _, c in self.outputs)
        nis_sum = float(sum(f.nis for f in acc))
        dof = int(sum(f.dof for f in acc))
        norm = np.array([f.norm for f in acc], dtype=float).reshape(-1, 3)
        with np.errstate(all="ignore"):
            inn_mean = [_finite(np.nanmean(c)) if np.isfinite(c).any() else None for c in norm.T]
            inn_std = [_finite(np.nanstd(c)) if np.isfinite(c).sum() > 1 else None for c in norm.T]
        lo = hi = math.nan
        consistent: bool | None = None
        full = self.last_t - self.first_t >= self.window_s
        if dof > 0:
            q = 0.5 * (1.0 - self.nis_probability)
            lo, hi = float(chi2_ppf(q, dof)), float(chi2_ppf(1.0 - q, dof))
            consistent = lo <= nis_sum <= hi
        warnings = []
        if n and rejected / n > self.max_reject_share:
            warnings.append(
                f"dvl_rejections: {rejected} of {n} DVL fixes rejected in the last "
                f"{self.window_s:g} s (more than {100 * self.max_reject_share:.0f} %)"
            )
        notes = []
        side = None if consistent is not False else ("high" if nis_sum > hi else "low")
        if full and side is not None:
            text = (
                f"mean DVL NIS per degree of freedom {nis_sum / dof:.2f} over the last "
                f"{self.window_s:g} s (expected 1, {100 * self.nis_probability:g} % interval "
                f"{lo / dof:.2f}-{hi / dof:.2f})"
            )
            if side == "high":
                warnings.append(f"nis_inconsistent: {text}")
            else:
                notes.append(f"nis_conservative: {text}")
        tot = self.total_fixes
        return {
            "window_s": self.window_s,
            "window": {
                "fixes": n,
                "accepted_share": _share(n - rejected, n),
                "rejected_share": _share(rejected, n),
                "forced_share": _share(forced, n),
                "coasting_share": _share(coasting, n_out),
                "nis_mean_per_dof": nis_sum / dof if dof else None,
                "nis_interval_per_dof": [lo / dof, hi / dof] if dof else None,
                "nis_consistent": consistent,
                "nis_side": side,
                "innovation_mean": inn_mean,
                "innovation_std": inn_std,
            },
            "total": {
                "fixes": tot,
                "accepted_share": _share(self.total_accepted, tot),
                "rejected_share": _share(self.total_rejected, tot),
                "forced_share": _share(self.total_forced, tot),
                "coasting_share": _share(self.total_coasting, self.total_outputs),
            },
            "dvl_noise_sigma_mps": [_finite(s) for s in self.noise_sigma],
            "compass_deviation": (
                None if self.compass_deviation is None else self.compass_deviation.status()
            ),
            "warnings": warnings,
            "notes": notes,
        }


def _share(k: int, n: int) -> float | None:
    return k / n if n else None


def _finite(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None
