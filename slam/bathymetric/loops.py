"""Loop closures: the correction ramp along the loop interval (eqs. 15-22) and the loop-closure
consistency determination, LCCD (eqs. 23-27, hierarchical clustering)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import squareform

__all__ = [
    "LCCD",
    "DriftModel",
    "LoopClosure",
    "consistent",
    "correction_ramp",
    "loop_valid",
    "max_clique",
]


@dataclass
class LoopClosure:
    """One resampling = one loop closure, eq. (14): jump ``m`` (m, NED) of the centroid,
    interval ``[t_loop, t_end]`` (pings), and what eq. (25) needs: DR and SLAM positions at
    both ends (SLAM at ``t_end`` after the resampling). ``accepted`` is the LCCD decision."""

    m: np.ndarray
    t_loop: int
    t_end: int
    dr_loop: np.ndarray
    dr_end: np.ndarray
    s_loop: np.ndarray
    s_end: np.ndarray
    s_end_before: np.ndarray
    accepted: bool = False
    overturned: bool = False
    pending: bool = False
    evidence: float = float("inf")  # the crossing's mode ratio (filters.mode_ratio)
    t_a: int = -1
    delta: np.ndarray | None = None

    def contribution(self, t: np.ndarray) -> np.ndarray:
        """What this accepted closure added to the mean trajectory at pings ``t`` (K,), (K, 2)
        m: its ramp ``delta`` on ``[t_a, t_end]`` (eqs. 15-22), the jump ``m`` after ``t_end``
        (the resampled particles carry it on), 0 before ``t_a``."""
        t = np.asarray(t)
        out = np.zeros((len(t), 2))
        if self.delta is None:
            return out
        ramp = (t >= self.t_a) & (t <= self.t_end)
        out[ramp] = self.delta[t[ramp] - self.t_a]
        out[t > self.t_end] = self.m
        return out

    @property
    def v_end(self) -> np.ndarray:
        """V_i at t_end, eq. (25): SLAM minus DR displacement over the loop."""
        return self.dr_loop - self.dr_end + self.s_end - self.s_loop

    def v(self, t: float) -> np.ndarray:
        """V_i(t), eq. (25): linear in time from 0 at t_loop to :attr:`v_end` at t_end."""
        span = max(self.t_end - self.t_loop, 1)
        return (t - self.t_loop) / span * self.v_end


@dataclass(frozen=True)
class DriftModel:
    """The dead-reckoning error a closure is judged against (ours; eq. 28 generalised): per
    ping and per axis the DR step errs by ``b(t) + w``, ``w ~ N(0, sigma_e^2)`` white, the
    bias ``b`` starting from ``N(0, spec^2)`` (the navigation spec) and random-walking by
    ``walk`` per sqrt(ping) (0 in eq. 28, a slowly varying current or bias in a real DVL /
    INS). A valid closure measures the DR drift over its interval up to its alignment error
    ``N(0, sigma_a^2)`` per axis. All in m (rates in m per ping)."""

    spec: float = 0.012
    walk: float = 3.3e-5
    sigma_e: float = 0.01
    sigma_a: float = 2.0
    gate_chi2: float = 9.21

    def rate(self, lc: LoopClosure) -> tuple[np.ndarray, float]:
        """The DR drift per ping (2,) that ``lc`` implies, ``-V_i(t_end) / (t_end - t_loop)``
        (eq. 25: DR displacement minus SLAM displacement over the loop, per ping), and its
        variance per axis from the white noise and the alignment error."""
        span = max(lc.t_end - lc.t_loop, 1)
        return -lc.v_end / span, (self.sigma_a**2 + self.sigma_e**2 * span) / span**2

    def mid(self, lc: LoopClosure) -> float:
        return 0.5 * (lc.t_loop + lc.t_end)

    def fits_spec(self, lc: LoopClosure) -> bool:
        """The closure's drift rate is within the gate of the spec's prior N(0, spec^2): a
        correction far beyond what the navigation can drift over the interval is implausible."""
        r, var = self.rate(lc)
        return float(r @ r) / (var + self.spec**2) <= self.gate_chi2

    def agree(self, a: LoopClosure, b: LoopClosure) -> bool:
        """Pairwise consistency (PCM-style, ours): the two closures' drift rates differ by no
        more than the gate allows given their own variances and the bias walk between their
        interval midpoints. Disjoint intervals are comparable too (unlike eqs. 26-27, A14)."""
        ra, va = self.rate(a)
        rb, vb = self.rate(b)
        var = va + vb + self.walk**2 * abs(self.mid(a) - self.mid(b))
        d = ra - rb
        return float(d @ d) / var <= self.gate_chi2

    def largest_agreeing(self, loops: list[LoopClosure]) -> list[LoopClosure]:
        """The largest subset of ``loops`` that fit the spec and agree pairwise
        (:func:`max_clique`; ties: the most evidence, the sum of log mode ratios, then the
        earliest)."""
        fits = [lp for lp in loops if self.fits_spec(lp)]
        k = len(fits)
        adj = np.zeros((k, k), dtype=bool)
        for a in range(k):
            for b in range(a + 1, k):
                adj[a, b] = adj[b, a] = self.agree(fits[a], fits[b])
        ev = np.array([math.log(min(lp.evidence, 1e6)) for lp in fits])
        return [fits[i] for i in max_clique(adj, ev)] if k else []

    def estimate(self, loops: list[LoopClosure], t: int) -> np.ndarray:
        """The bias now (2,) (m per ping) from ``loops``' drift rates: their weighted mean
        with the spec's zero-mean prior, each rate's variance grown by the walk since its
        interval's midpoint (an old rate says less about the bias at ping ``t``)."""
        num, den = np.zeros(2), 1.0 / self.spec**2 if self.spec > 0 else 0.0
        for lc in loops:
            r, var = self.rate(lc)
            var += self.walk**2 * max(t - self.mid(lc), 0.0)
            num += r / var
            den += 1.0 / var
        return num / den if den > 0 else num


def max_clique(adj: np.ndarray, score: np.ndarray) -> list[int]:
    """The largest clique of the boolean adjacency ``adj`` (M, M) (Bron-Kerbosch with a
    pivot; M is a run's closures, a few dozen at most), ties broken by the largest sum of
    ``score`` (M,), then by the earliest members."""
    m = len(adj)
    nbr = [set(np.flatnonzero(adj[i]).tolist()) - {i} for i in range(m)]
    best: list[int] = []
    best_key = (0, -math.inf)

    def visit(r: list[int], p: set[int], x: set[int]) -> None:
        nonlocal best, best_key
        if not p and not x:
            key = (len(r), float(score[r].sum()))
            if key > best_key:
                best, best_key = sorted(r), key
            return
        if len(r) + len(p) < best_key[0]:
            return
        pivot = max(p | x, key=lambda u: len(nbr[u] & p))
        for v in sorted(p - nbr[pivot]):
            visit([*r, v], p & nbr[v], x & nbr[v])
            p = p - {v}
            x = x | {v}

    visit([], set(range(m)), set())
    return best


def loop_valid(lc: LoopClosure, truth: np.ndarray) -> bool:
    """Truth label of a loop closure (A22): valid when, after its jump, the loop-interval
    displacement error ``|(S_p^after(t_end) - S_p(t_loop)) - (x_true(t_end) - x_true(t_loop))|``
    is at most max(3 m, half of what it was before the jump). ``truth`` (T, 2) m, NED."""
    true_d = truth[lc.t_end] - truth[lc.t_loop]
    before = float(np.linalg.norm((lc.s_end_before - lc.s_loop) - true_d))
    after = float(np.linalg.norm((lc.s_end - lc.s_loop) - true_d))
    return after <= max(3.0, 0.5 * before)


def correction_ramp(
    covered: np.ndarray, t_loop: int, t_end: int, m: np.ndarray
) -> tuple[int, np.ndarray]:
    """The corrections of eqs. (15)-(22): ``(t_a, delta)`` with ``delta`` (t_end - t_a + 1, 2)
    to add to the mean trajectory from ``t_a`` to ``t_end``. ``covered`` (bool, >= t_end + 1)
    marks times already corrected by earlier valid loops (l^h, eq. 16); U = [t_loop, t_end]
    minus them (eq. 15). The ramp counts only U steps (eq. 21 with A12), so it rises from
    ``m / |U|`` at t_a to ``m`` at t_b = t_end, and a solidified gap moves rigidly with the last
    U step before it (eq. 22): continuous at both ends of every gap."""
    in_u = ~covered[t_loop : t_end + 1]
    if not in_u.any():
        return t_end, np.asarray(m, float)[None, :]
    first = int(np.argmax(in_u))
    t_a = t_loop + first
    in_u = in_u[first:]
    a = np.cumsum(in_u)  # eq. (19)/(21): a_t over U steps only
    return t_a, (a / a[-1])[:, None] * np.asarray(m, float)[None, :]  # eqs. (18), (21), (22)


def consistent(corrections: np.ndarray, tau_m: float, method: str = "single") -> bool:
    """True when the corrections (K, 2) (m, NED) form one cluster when the ``method`` linkage
    dendrogram is cut at ``tau_m``; False for fewer than two."""
    if len(corrections) < 2:
        return False
    z = linkage(np.asarray(corrections, float), method=method)
    return bool(len(set(fcluster(z, t=tau_m, criterion="distance"))) == 1)


class LCCD:
    """Loop-closure consistency determination (Sec. IV-B): the pool holds every loop closure so
    far (A17); a new one is valid unless it ends up alone in its cluster when the single-linkage
    (A15) dendrogram of D (eqs. 23-27) is cut at ``tau_m``."""

    def __init__(
        self,
        tau_m: float = 3.0,
        method: str = "single",
        disjoint_m: float = 1e6,
        veto: bool = False,
        overturn: bool = False,
        pending: bool = False,
        replace: bool = False,
        drift: DriftModel | None = None,
    ) -> None:
        self.tau_m, self.method, self.disjoint_m = tau_m, method, disjoint_m
        self.drift = drift
        self.veto, self.overturn, self.hold = veto, overturn, pending
        self.replace = replace
        self.pool: list[LoopClosure] = []
        self.overturned_now: list[LoopClosure] = []  # by the last :meth:`judge`

    @staticmethod
    def distance(a: LoopClosure, b: LoopClosure, disjoint_m: float = 1e6) -> float:
        """d(i, j) of Fig. 7 for ``a`` earlier than ``b`` (t_end order)."""
        i, j = a, b
        if j.t_loop < i.t_loop:  # relation 1: l_i nested in l_j, eq. (26)
            d = (j.v(i.t_end) - j.v(i.t_loop)) - i.v(i.t_end)
        elif j.t_loop <= i.t_end:  # relation 2: partial overlap, eq. (27) over the overlap (A16)
            d = (i.v(i.t_end) - i.v(j.t_loop)) - j.v(i.t_end)
        else:  # relation 3: disjoint, not comparable (A14)
            return disjoint_m
        return float(np.linalg.norm(d))

    def matrix(self) -> np.ndarray:
        """D (M x M) over the pool, eqs. (23)-(24)."""
        m = len(self.pool)
        d = np.zeros((m, m))
        for b in range(m):
            for a in range(b):
                d[a, b] = d[b, a] = self.distance(self.pool[a], self.pool[b], self.disjoint_m)
        return d

    def judge(self, loop: LoopClosure) -> bool:
        """Add ``loop`` to the pool and set ``loop.accepted``: True if it is consistent with at
        least one other. With ``veto`` (ours) a loop alone in its cluster is rejected only
        when some accepted loop is comparable with it (not disjoint, A14): the first loop, and
        a loop disjoint from every accepted one, have nothing to contradict them and are
        accepted; with ``pending`` (ours, A17's "singleton => invalid" made revisable) they are
        held ``pending`` instead (not accepted: the filter applies nothing), until a later loop
        falls in their cluster (both accepted; the pending one is not applied again) or an
        accepted loop comparable with it falls outside its cluster (it stays rejected).
        With ``replace`` (ours) a loop vetoed only by accepted loops that no other accepted
        loop agrees with (unconfirmed) replaces them when its ``evidence`` is larger: they are
        overturned as below. With ``overturn`` (ours) an accepted loop with partners overturns every
        earlier accepted loop comparable with it, outside its cluster, whose own cluster is
        smaller: those are marked ``overturned`` (no longer accepted), left out of the pool,
        and listed in :attr:`overturned_now` so the filter can undo their corrections."""
        self.pool.append(loop)
        self.overturned_now = []
        if self.drift is not None:
            return self._judge_drift(loop, self.drift)
        if len(self.pool) < 2:
            loop.accepted = self.veto and not self.hold
            loop.pending = self.veto and self.hold
            return loop.accepted
        d = self.matrix()
        z = linkage(squareform(d, checks=False), method=self.method)
        labels = fcluster(z, t=self.tau_m, criterion="distance")
        size = np.bincount(labels)
        loop.accepted = bool(size[labels[-1]] > 1)
        if not loop.accepted and self.veto:
            judges = [i for i, lp in enumerate(self.pool[:-1]) if lp.accepted]
            against = [i for i in judges if d[i, -1] < self.disjoint_m]
            loop.accepted = not against
            lone = all(not any(j != i and labels[j] == labels[i] for j in judges) for i in against)
            if (
                against
                and self.replace
                and lone
                and loop.evidence > max(self.pool[i].evidence for i in against)
            ):
                self._overturn([self.pool[i] for i in against])
                loop.accepted = True
                return True
            if loop.accepted and self.hold:
                loop.accepted, loop.pending = False, True
        if self.hold and loop.accepted:
            for i, lp in enumerate(self.pool[:-1]):
                if lp.pending and labels[i] == labels[-1]:
                    lp.accepted, lp.pending = True, False  # confirmed
                elif lp.pending and d[i, -1] < self.disjoint_m:
                    lp.pending = False  # contradicted: stays rejected
        if not (loop.accepted and self.overturn and size[labels[-1]] > 1):
            return loop.accepted
        self._overturn(
            [
                lp
                for i, lp in enumerate(self.pool[:-1])
                if lp.accepted
                and labels[i] != labels[-1]
                and d[i, -1] < self.disjoint_m
                and size[labels[i]] < size[labels[-1]]
            ]
        )
        return loop.accepted

    def _judge_drift(self, loop: LoopClosure, dm: DriftModel) -> bool:
        """``lccd_mode = 'drift'`` (ours, PCM-style: Mangelson et al. 2018's pairwise
        consistency maximisation over the drift rates of eq. 25): the closures of the pool
        that fit the spec (:meth:`DriftModel.fits_spec`) are nodes, pairs whose drift rates
        agree (:meth:`DriftModel.agree`) edges; the largest clique (ties: the most evidence,
        the crossing's log mode ratio) is the consistent set. ``loop`` is accepted iff it is
        in it; accepted closures outside it are overturned (listed in :attr:`overturned_now`
        to be undone). Rejected closures stay in the pool and count (A17), but are never
        applied later."""
        keep = {id(lp) for lp in dm.largest_agreeing(self.pool)}
        loop.accepted = id(loop) in keep
        if loop.accepted:
            self._overturn([lp for lp in self.pool[:-1] if lp.accepted and id(lp) not in keep])
        return loop.accepted

    def _overturn(self, out: list[LoopClosure]) -> None:
        """Mark ``out`` overturned (no longer accepted), leave them out of the pool and list
        them in :attr:`overturned_now` for the filter to undo."""
        for lp in out:
            lp.accepted, lp.overturned = False, True
        self.pool = [lp for lp in self.pool if not lp.overturned]
        self.overturned_now = out
