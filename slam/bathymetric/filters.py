"""The bathymetric filters: MTM-PF (Zhang 2021), the paper's BPSLAM comparator and dead
reckoning. Each is fed one ping at a time, ``step(u, offsets, depth)``, with the DR displacement
``u`` (2,) since the previous ping, the ping's sounding offsets (B, 2) from the vehicle (NED, m)
and depths (B,) (m, down); ping 0 is given to ``start``. ``trajectory()`` is the final
(corrected) estimate at every ping, ``estimates`` the online estimate after each ping.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.loops import (
    LCCD,
    DriftModel,
    LoopClosure,
    consistent,
    correction_ramp,
    loop_valid,
)
from auvgw.slam.bathymetric.matching import idw, match_weights
from auvgw.slam.resampling import systematic_resample

__all__ = [
    "BPSLAM",
    "MTMPF",
    "BathyFilter",
    "BodyDrift",
    "DeadReckoning",
    "jitter_variance",
    "mode_ratio",
    "mode_weights",
    "no_match_weight",
    "own_nearest",
    "rotate",
]


def _tree(points: np.ndarray) -> cKDTree:
    """A KD-tree built each ping: sliding-midpoint splits, no node shrinking (half the build
    time of scipy's defaults here; same neighbours, the queries as fast)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def jitter_variance(t_r: int, cfg: BathyConfig) -> float:
    """sigma_m^2 of eq. (3): sigma_c^2 + A exp(-t_r / C), with A = 0 while t_r < B (A8)."""
    a = cfg.jitter_a if t_r >= cfg.jitter_b else 0.0
    return cfg.sigma_c2 + a * float(np.exp(-t_r / cfg.jitter_c))


def no_match_weight(n: int, cfg: BathyConfig) -> float:
    """Un-normalised weight of a particle that fails the gates, and what alpha flattens
    towards: 1/N as written (``unmatched_weight = 'uniform'``, A5), otherwise the expected
    eq. (7) weight of a match whose MSE equals the gate, ``1 / sqrt(2 pi (sigma_s^2 +
    mse_max))`` (independent of N)."""
    if cfg.unmatched_weight == "uniform":
        return 1.0 / n
    return 1.0 / float(np.sqrt(2 * np.pi * (cfg.sigma_s_m**2 + cfg.mse_max_m2)))


def fill_weights(
    n: int,
    idx: np.ndarray,
    w_m: np.ndarray,
    cfg: BathyConfig,
    w0: float | None = None,
    bad: np.ndarray | None = None,
) -> np.ndarray:
    """Normalised weights of ``n`` particles: ``w_m`` for those in ``idx`` (matched and gated
    in); the rest by ``unmatched_weight``: 1/N as written (A5), the gate's weight
    (:func:`no_match_weight`; ``w0`` overrides it), or 'neutral': the mean matched weight
    ("no evidence" neither favours nor penalises a particle) for those outside R, and at
    most the gate's weight for ``bad`` (inside R, failing the gates: a poor fit)."""
    if len(w_m) < cfg.min_matched_fraction * n:
        return np.full(n, 1.0 / n)
    w_gate = no_match_weight(n, cfg) if w0 is None else w0
    if cfg.unmatched_weight != "neutral" or len(w_m) == 0:
        w = np.full(n, w_gate)
    else:
        mean = float(w_m.mean())
        w = np.full(n, mean)
        if bad is not None:
            w[bad] = min(w_gate, mean)
    w[idx] = w_m
    s = w.sum()
    return w / s if s > 0 else np.full(n, 1.0 / n)


def _heaviest(
    x: np.ndarray, w: np.ndarray, radius_m: float, among: np.ndarray
) -> tuple[int, float]:
    """The particle of ``among`` whose ``radius_m`` neighbourhood (over every particle of ``x``
    (N, 2), m) holds the most of ``w`` (N,): its index and that weight."""
    cand = among[w[among] > 1e-12 * w.max()]  # particles that carry weight
    if len(cand) == 0:
        return -1, 0.0
    d2 = ((x[cand, None, :] - x[None, :, :]) ** 2).sum(-1)  # (C, N)
    mass = (d2 <= radius_m**2) @ w
    k = int(np.argmax(mass))
    return int(cand[k]), float(mass[k])


def mode_weights(x: np.ndarray, w: np.ndarray, radius_m: float) -> np.ndarray:
    """Normalised weights ``w`` (N,) of particles ``x`` (N, 2) (m) kept only within
    ``radius_m`` of the particle whose ``radius_m`` neighbourhood holds the most weight: the
    posterior's dominant mode."""
    centre, _ = _heaviest(x, w, radius_m, np.arange(len(w)))
    keep = ((x - x[centre]) ** 2).sum(-1) <= radius_m**2
    wk = np.where(keep, w, 0.0)
    return wk / wk.sum()


def mode_ratio(x: np.ndarray, w: np.ndarray, radius_m: float, apart_m: float) -> float:
    """Evidence of a closure (ours): the weight ``w`` (N,) within ``radius_m`` of the dominant
    mode's centre (:func:`mode_weights`) over the weight of the heaviest ``radius_m``
    neighbourhood centred more than ``apart_m`` from it (an alternative closure); inf when no
    particle lies that far. Both are Monte Carlo estimates of posterior masses, so the ratio
    does not depend on N. Positions ``x`` (N, 2) and distances in m."""
    n = len(w)
    centre, top = _heaviest(x, w, radius_m, np.arange(n))
    far = np.flatnonzero(((x - x[centre]) ** 2).sum(-1) > apart_m**2)
    _, second = _heaviest(x, w, radius_m, far)
    return top / second if second > 0 else float("inf")


def mode_odds(x: np.ndarray, w: np.ndarray, radius_m: float, apart_m: float) -> float:
    """Posterior odds that a closure lies where the dominant mode says (ours): the weight ``w``
    (N,) within ``apart_m`` of the dominant ``radius_m`` mode's centre (:func:`mode_weights`:
    the mode and its own peak's shoulder) over all the weight farther away (every other
    closure together); inf when no weight lies that far. Unlike :func:`mode_ratio` a mode
    holding a few per cent of the weight fails it however weak each rival is. Positions ``x``
    (N, 2) and distances in m."""
    centre, _ = _heaviest(x, w, radius_m, np.arange(len(w)))
    near = ((x - x[centre]) ** 2).sum(-1) <= apart_m**2
    rest = float(w[~near].sum())
    return float(w[near].sum()) / rest if rest > 0 else float("inf")


def rotate(v: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Vectors ``v`` (..., 2) (NED, m) turned by ``angle`` (rad, broadcast against ``v[..., 0]``;
    positive from north towards east, as a heading)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def own_nearest(
    trajs: np.ndarray, x: np.ndarray, ref: np.ndarray, dev: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """For each particle ``n``: the time of the point of its own history ``trajs[:, n]``
    ((h, N, 2), m) nearest to ``x[n]`` ((N, 2)), and the particles whose nearest point is
    within ``radius_m``. Exact, without the (h, N) distance matrix: ``dev[n]`` (m) bounds
    ``|trajs[t, n] - ref[t]|`` over every t for a reference track ``ref`` ((h, 2)), so a time
    within ``radius_m`` of particle ``n`` lies within ``radius_m + dev[n]`` of ``ref``; only
    the union of those times is searched (the history near the particles: a crossing). The
    time of a particle found beyond ``radius_m`` is meaningless (never used)."""
    n = len(x)
    balls = _tree(ref).query_ball_point(x, radius_m + dev + 1e-9)
    cand = np.unique(np.concatenate([np.asarray(b, dtype=np.intp) for b in balls]))
    if len(cand) == 0:
        return np.zeros(n, dtype=np.intp), np.zeros(0, dtype=np.intp)
    d2 = ((trajs[cand] - x[None]) ** 2).sum(-1)  # (C, N)
    k = d2.argmin(0)
    near = np.flatnonzero(d2[k, np.arange(n)] <= radius_m**2)
    return cand[k], near


class BodyDrift:
    """``drift_frame = 'body'`` (ours, issue 28): a DR error that turns with the vehicle. Each
    DR step is ``u_k = (1 + s) R(psi_k) d_k + w_k`` for the true step ``d_k`` (NED, m): a DVL
    scale factor ``s`` and a heading error ``psi_k`` (rad; DVL/INS misalignment + INS heading
    bias, constant, plus a Gauss-Markov drift), i.e. to first order an error ``e_k = (s I +
    psi_k J) u_k`` with ``J`` the +90 deg rotation. A closure over ``[a, b]`` measures the DR
    drift ``-V(t_end)`` of eq. (25), ``sum_{a<k<=b} e_k = s (DR_b - DR_a) + J sum psi_k u_k``:
    linear in ``(s, psi)``. ``psi`` is held constant over blocks of ``body_block_pings``
    pings and estimated with ``s`` as the posterior mean of a Gaussian prior from the spec
    (``s ~ N(0, body_scale_sigma^2)``; ``psi`` block covariance ``sigma_h^2 + sigma_gm^2
    exp(-|dt| / tau)``) given the closures, each with the alignment error ``closure_sigma_m``
    and the DR white noise ``omega_sigma_m`` per axis. While the worst closure's residual
    fails ``drift_gate_chi2`` it is dropped and the fit repeated. Over a closed loop the constant
    part nearly cancels (``DR_b - DR_a`` is within R), so the closures mostly see the heading
    drift; the prior carries the rest."""

    def __init__(self, cfg: BathyConfig) -> None:
        self.k = cfg.body_block_pings
        self.s2 = cfg.body_scale_sigma**2
        self.h2 = math.radians(cfg.body_heading_sigma_deg) ** 2
        self.g2 = math.radians(cfg.body_gm_sigma_deg) ** 2
        self.tau = cfg.body_gm_tau_pings
        self.a2, self.e2 = cfg.closure_sigma_m**2, cfg.omega_sigma_m**2
        self.gate = cfg.drift_gate_chi2

    def blocks(self, t: int) -> int:
        """Blocks of psi up to ping ``t`` and the next step's (step k lies in (k-1) // K)."""
        return t // self.k + 1

    def _rows(self, lc: LoopClosure, dr: np.ndarray, m: int) -> np.ndarray:
        """(2, 1 + m) design of one closure: the drift it measures = rows @ (s, psi)."""
        e = np.arange(m + 1) * self.k
        a, b = lc.t_loop, lc.t_end
        u = dr[np.clip(b, e[:-1], e[1:]).clip(max=len(dr) - 1)]
        u = u - dr[np.clip(a, e[:-1], e[1:]).clip(max=len(dr) - 1)]  # (m, 2) per block
        d = dr[b] - dr[a]
        return np.array([[d[0], *(-u[:, 1])], [d[1], *u[:, 0]]])

    def prior(self, m: int) -> np.ndarray:
        """Prior covariance (1 + m, 1 + m) of (s, psi_0 .. psi_{m-1})."""
        c = np.arange(m) * self.k
        p = np.zeros((m + 1, m + 1))
        p[0, 0] = self.s2
        p[1:, 1:] = self.h2 + self.g2 * np.exp(-np.abs(c[:, None] - c[None, :]) / self.tau)
        return p

    def fit(self, loops: list[LoopClosure], dr: np.ndarray) -> tuple[float, np.ndarray]:
        """``(s, psi)``: posterior means of the scale factor (1) and of each block's heading
        error (rad, (m,)) given ``loops`` and the DR track ``dr`` (t + 1, 2) m."""
        m = self.blocks(len(dr) - 1)
        p = self.prior(m)
        use = list(loops)
        z = np.zeros(m + 1)
        while use:
            h = np.vstack([self._rows(lc, dr, m) for lc in use])
            y = np.concatenate([-lc.v_end for lc in use])
            r = np.repeat([self.a2 + self.e2 * max(lc.t_end - lc.t_loop, 1) for lc in use], 2)
            z = p @ h.T @ np.linalg.solve(h @ p @ h.T + np.diag(r), y)
            res = ((y - h @ z) ** 2 / r).reshape(-1, 2).sum(1)
            worst = int(np.argmax(res))
            if res[worst] <= self.gate:
                return float(z[0]), z[1:]
            del use[worst]
        return 0.0, np.zeros(m)

    def step_error(self, s: float, psi: np.ndarray, u: np.ndarray, k: np.ndarray) -> np.ndarray:
        """First-order DR error ``(s I + psi J) u`` (K, 2) m of steps ``u`` (K, 2) numbered
        ``k`` (K,) (step k moves ping k-1 to k); blocks beyond ``psi`` use its last value."""
        if len(psi) == 0:
            return s * u
        ps = psi[np.minimum((k - 1) // self.k, len(psi) - 1)][:, None]
        return s * u + ps * np.column_stack([-u[:, 1], u[:, 0]])

    def cumulative(self, s: float, psi: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """Estimated DR error at every ping of ``dr`` (t + 1, 2) m, 0 at the start."""
        e = self.step_error(s, psi, np.diff(dr, axis=0), np.arange(1, len(dr)))
        return np.vstack([np.zeros((1, 2)), np.cumsum(e, axis=0)])


class BathyFilter:
    """Common storage: the swaths (offsets, depths) of every ping, preallocated for ``n_pings``."""

    name = "base"
    # arrays indexed by ping (first axis), grown by :meth:`reserve`
    _PER_PING = (
        "estimates",
        "dr",
        "offsets",
        "depths",
        "matched",
        "neff_log",
        "traj",
        "covered",
        "trajs",
        "ref",
        "pred_corr",
        "shift",
        "spread",
        "heading_log",
    )

    def __init__(self, cfg: BathyConfig, n_pings: int, rng: np.random.Generator) -> None:
        self.cfg, self.rng, self.T = cfg, rng, n_pings
        self.t = -1
        self.estimates = np.zeros((n_pings, 2))
        self.dr = np.zeros((n_pings, 2))
        self.offsets: np.ndarray | None = None
        self.depths: np.ndarray | None = None
        self.loops: list[LoopClosure] = []
        self.matched = np.zeros(n_pings, dtype=np.int32)
        self.neff_log = np.full(n_pings, np.nan)
        # the cloud's spread after each ping (m, :meth:`cloud_std`) and the pings at which the
        # particles were resampled (an accepted closure for MTM-PF): Fig. 11, claim C4
        self.spread = np.zeros(n_pings)
        self.resampled_at: list[int] = []
        # the true positions (T, 2), given only for the diagnostic lccd_mode = 'oracle'
        self.oracle_truth: np.ndarray | None = None
        # closure = "crossing": accumulated log weights, pings in / since the crossing
        self.logw = np.zeros(cfg.n_particles)
        self.crossing_len = 0
        self.since_match = 0

    def _store(self, offsets: np.ndarray, depth: np.ndarray) -> None:
        if self.offsets is None:
            self.offsets = np.zeros((self.T, len(depth), 2))
            self.depths = np.zeros((self.T, len(depth)))
        assert self.depths is not None
        self.offsets[self.t] = offsets
        self.depths[self.t] = depth

    def reserve(self, n_pings: int) -> None:
        """Grow every per-ping array to hold ``n_pings`` pings (online use: the mission length
        is not known up front). New rows are zero, ``False``, or NaN for ``neff_log``."""
        if n_pings <= self.T:
            return
        old = self.T
        for name in self._PER_PING:
            v = getattr(self, name, None)
            if isinstance(v, np.ndarray):
                fill = np.nan if name == "neff_log" else 0
                pad = np.full((n_pings - old, *v.shape[1:]), fill, dtype=v.dtype)
                setattr(self, name, np.concatenate([v, pad]))
        self.T = n_pings

    def start(self, x0: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        """Ping 0 at the known start position ``x0`` (Sec. 1.3: no initial spread)."""
        self.t = 0
        self.dr[0] = x0
        self._store(offsets, depth)
        self.estimates[0] = x0

    def step(self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        raise NotImplementedError

    def _advance(
        self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray, var: float
    ) -> np.ndarray:
        """Next ping: store DR and swath; return the particles' motion of eq. (2),
        u + omega + N(0, var), (N, 2)."""
        cfg, rng, n = self.cfg, self.rng, self.cfg.n_particles
        self.spread[self.t] = self.cloud_std()  # the previous ping's, after its resampling
        self.t += 1
        self.dr[self.t] = self.dr[self.t - 1] + u
        self._store(offsets, depth)
        return (
            u + rng.normal(0.0, cfg.omega_sigma_m, (n, 2)) + rng.normal(0.0, np.sqrt(var), (n, 2))
        )

    def trajectory(self) -> np.ndarray:
        """Final estimate of every ping so far, (t + 1, 2) m."""
        raise NotImplementedError

    def cloud_std(self) -> float:
        """Spread of the particles now, sqrt of the trace of their (weighted) covariance (m)."""
        return 0.0

    def _crossing_end(self, w: np.ndarray | None) -> tuple[np.ndarray, float] | None:
        """``closure = 'crossing'`` (ours): multiply this ping's normalised weights ``w`` (None:
        no overlap) into the crossing's (log-summed in ``logw``); when the crossing ends
        (``crossing_gap_pings`` pings without overlap, or ``crossing_max_pings``) return its
        normalised weights and their Neff (eq. 13) and start the next crossing, else None."""
        cfg = self.cfg
        if w is not None:
            self.logw += np.log(np.maximum(w, 1e-300))
            self.crossing_len += 1
            self.since_match = 0
        elif self.crossing_len:
            self.since_match += 1
        if not self.crossing_len:
            return None
        wa = np.exp(self.logw - self.logw.max())
        wa /= wa.sum()
        neff = 1.0 / float(np.sum(wa**2))
        self.neff_log[self.t] = neff
        if self.since_match < cfg.crossing_gap_pings and self.crossing_len < cfg.crossing_max_pings:
            return None
        self.logw[:] = 0.0
        self.crossing_len = self.since_match = 0
        return wa, neff

    def bytes_held(self) -> int:
        """Bytes of the filter's state arrays (map, trajectories, particles)."""
        return sum(
            v.nbytes
            for k, v in vars(self).items()
            if isinstance(v, np.ndarray) and k != "oracle_truth"
        )

    def map_points(self) -> np.ndarray:
        """Every sounding placed by :meth:`trajectory`: (P, 3) x, y, depth."""
        assert self.offsets is not None and self.depths is not None
        n = self.t + 1
        xy = self.trajectory()[:, None, :] + self.offsets[:n]
        return np.column_stack([xy.reshape(-1, 2), self.depths[:n].reshape(-1)])


class DeadReckoning(BathyFilter):
    """The DR track itself (the paper's eq. 28 input)."""

    name = "dr"

    def step(self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        self.t += 1
        self.dr[self.t] = self.dr[self.t - 1] + u
        self.estimates[self.t] = self.dr[self.t]
        self._store(offsets, depth)

    def trajectory(self) -> np.ndarray:
        return self.dr[: self.t + 1]


class MTMPF(BathyFilter):
    """The mean-trajectory-map particle filter (Zhang 2021, Secs. III-IV).

    Particles hold only their current position ``x`` (N, 2) (eq. 1); ``traj`` (T, 2) is the one
    mean trajectory of unweighted centroids (A7) along which every swath is placed."""

    name = "mtm-pf"

    def __init__(self, cfg: BathyConfig, n_pings: int, rng: np.random.Generator) -> None:
        super().__init__(cfg, n_pings, rng)
        self.x = np.zeros((cfg.n_particles, 2))
        self.traj = np.zeros((n_pings, 2))
        self.covered = np.zeros(n_pings, dtype=bool)  # l^h, eq. (16)
        self.t_r = 10**9  # "a large value" at mission start, eq. (3)
        self.drift = DriftModel(
            cfg.drift_spec_m,
            cfg.drift_walk_m,
            cfg.omega_sigma_m,
            cfg.closure_sigma_m,
            cfg.drift_gate_chi2,
        )
        self.lccd = LCCD(
            cfg.lccd_tau_m,
            cfg.lccd_linkage,
            cfg.lccd_disjoint_m,
            veto=cfg.lccd_mode == "veto",
            overturn=cfg.lccd_overturn and cfg.lccd_mode == "veto",
            pending=cfg.lccd_pending and cfg.lccd_mode == "veto",
            replace=cfg.lccd_replace and cfg.lccd_mode == "veto",
            drift=self.drift if cfg.lccd_mode == "drift" else None,
        )
        # drift_estimate (ours): the DR bias removed in prediction (m per ping, (2,)) and
        # the first ping of the accepted loop intervals it re-anchored the track at
        self.bias = np.zeros(2)
        self.anchor_t = -1
        # drift_frame = 'body': the error model, its estimate, the correction removed from
        # each DR step in prediction and the re-anchoring shift applied at each ping (m)
        self.body = BodyDrift(cfg) if cfg.drift_frame == "body" else None
        self.body_s, self.body_psi = 0.0, np.zeros(0)
        self.pred_corr = np.zeros((n_pings, 2))
        self.shift = np.zeros((n_pings, 2))
        self._tlp = np.zeros(cfg.n_particles, dtype=int)
        self._parts: list[np.ndarray] = []  # log weights of the crossing's pings with evidence
        self.weak_crossings = 0  # crossings below min_mode_ratio (no closure)
        # heading_bias (ours, issue 28; not the paper's, A30): each particle's navigation
        # heading offset b (rad), the mean b the current ping's swath was turned by, and per
        # ping the cloud's mean b and its std (rad) after that ping's update
        self.b = np.zeros(cfg.n_particles)
        self.b_swath = 0.0
        self.heading_log = np.zeros((n_pings, 2))

    def start(self, x0: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        super().start(x0, offsets, depth)
        self.x[:] = x0
        self.traj[0] = x0
        if self.cfg.heading_bias:  # the offset's prior: N(0, heading_sigma0^2)
            self.b = self.rng.normal(0.0, math.radians(self.cfg.heading_sigma0_deg), len(self.b))
            self.heading_log[0] = self.b.mean(), self.b.std()

    def _heading_walk(self, frozen: bool) -> None:
        """``heading_bias``: one step of b's random walk (or Gauss-Markov with
        ``heading_tau_pings``); ``frozen``: inside a crossing without jitter (each particle
        keeps one state through it, as its position offset)."""
        cfg = self.cfg
        if frozen:
            return
        if cfg.heading_tau_pings > 0:
            self.b *= math.exp(-1.0 / cfg.heading_tau_pings)
        self.b += self.rng.normal(0.0, math.radians(cfg.heading_walk_deg), len(self.b))

    def trajectory(self) -> np.ndarray:
        return self.traj[: self.t + 1]

    def cloud_std(self) -> float:
        return float(np.sqrt(((self.x - self.x.mean(0)) ** 2).sum(1).mean()))

    # -- one ping -----------------------------------------------------------------------------
    def step(self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        cfg, n = self.cfg, self.cfg.n_particles
        var = jitter_variance(self.t_r, cfg)
        if cfg.closure == "crossing" and self.crossing_len and not cfg.jitter_in_crossing:
            var = 0.0  # one offset per particle through a crossing (ours)
        b = self.bias
        if self.body is not None:  # the body-frame error of this step (ours)
            k = np.array([self.t + 1])
            b = self.body.step_error(self.body_s, self.body_psi, u[None], k)[0]
        turn = np.zeros((n, 2))
        if cfg.heading_bias:  # ours: the step and the swath turned back by the offset b
            self._heading_walk(frozen=var == 0.0 and self.crossing_len > 0)
            self.b_swath = float(self.b.mean())
            offsets = rotate(offsets, -self.b_swath)
            turn = rotate(u, -self.b) - u
        self.x += self._advance(u, offsets, depth, var) - b + turn  # eq. (2), R(-b) u - b (ours)
        t = self.t
        if self.body is not None:
            self.pred_corr[t] = b
            self.shift[t] = self.shift[t - 1]
        self.t_r += 1
        self.traj[t] = self.x.mean(0)  # S_p, unweighted centroid (A7)
        w, tlp = self.weights()
        if cfg.closure == "crossing":
            self._crossing(w, tlp)
        elif w is not None:
            neff = 1.0 / np.sum(w**2)  # eq. (13)
            self.neff_log[t] = neff
            if neff < cfg.neff_fraction * n:
                self._resample(w, tlp)
        self.estimates[t] = self.traj[t]
        self.heading_log[t] = self.b.mean(), self.b.std()

    def _submap(self) -> tuple[cKDTree, np.ndarray]:
        """Pmap as placed by the mean trajectory (eq. 4 with V_ec = 0): tree and depths."""
        assert self.offsets is not None and self.depths is not None
        cfg, t = self.cfg, self.t
        lo = max(t - cfg.t_p + 1, 0)
        sl = slice(None, None, cfg.pmap_beam_stride)
        pts = self.traj[lo : t + 1, None, :] + self.offsets[lo : t + 1, sl]
        return _tree(pts.reshape(-1, 2)), self.depths[lo : t + 1, sl].reshape(-1)

    def _mmap_index(self, tlp: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
        """Swath indices (K, W) of each Mmap around ``tlp`` and their mask, clipped to < h (A25)."""
        cfg = self.cfg
        rel = np.arange(-(cfg.t_m // 2), cfg.t_m // 2 + 1, cfg.mmap_ping_stride)
        idx = tlp[:, None] + rel[None, :]
        ok = (idx >= 0) & (idx < h)
        return np.clip(idx, 0, h - 1), ok

    def weights(self) -> tuple[np.ndarray | None, np.ndarray]:
        """Normalised weights (None: no particle overlaps the map) and each particle's t_lp."""
        cfg, n = self.cfg, self.cfg.n_particles
        m = self.match(self.x)
        if m is None:
            return None, np.zeros(n, dtype=int)
        tlp, near, w_m, gate = m
        self.matched[self.t] = len(near)
        if len(near) == 0:
            return None, tlp
        return fill_weights(n, near[gate], w_m[gate], cfg, bad=near[~gate]), tlp

    def match(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The submap match of this ping at positions ``x`` (G, 2) (m, NED; the particles, or
        any offsets a diagnosis probes): each position's t_lp, the indices of those within R of
        the old track (overlap test), their un-normalised weights (eqs. 4-12) and which of them
        pass the gates; None while there is no history (times < t - t_l) to match."""
        cfg, t = self.cfg, self.t
        h = t - cfg.t_l  # historical centroids: times < t - t_l (Sec. III-C)
        if h < 2:
            return None
        d, tlp = _tree(self.traj[:h]).query(x)
        near = np.flatnonzero(d <= cfg.radius_m)  # overlap test
        if len(near) == 0:
            return tlp, near, np.zeros(0), np.zeros(0, dtype=bool)
        tree, z_p = self._submap()
        v = x[near] - self.traj[t]  # V_ec, eq. (5)
        idx, ok = self._mmap_index(tlp[near], h)
        # heading_bias (ours): each particle's Pmap also turned by -(b - b_swath) about the
        # vehicle (the swath is stored turned by -b_swath); b belongs to the particles, so a
        # probe of other positions (len(x) != N) matches unturned
        turn = None
        if cfg.heading_bias and len(x) == len(self.b):
            turn = self.b[near] - self.b_swath
        z_pm, z_mm, valid, n_m = self._mmap_vs_pmap(tree, z_p, idx, ok, v, self.traj, turn)
        w0 = no_match_weight(cfg.n_particles, cfg)
        w_m, gate, _ = match_weights(z_pm, z_mm, valid, n_m, cfg, fallback=w0)
        return tlp, near, w_m, gate

    def _mmap_vs_pmap(
        self,
        tree: cKDTree,
        z_p: np.ndarray,
        idx: np.ndarray,
        ok: np.ndarray,
        shift: np.ndarray,
        traj: np.ndarray,
        turn: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """IDW of the Pmap at each row's Mmap points. Shifting the Pmap by ``shift`` (eq. 4) is
        querying the Mmap points shifted by ``-shift``: one tree serves every particle. ``turn``
        (K,) rad (ours, ``heading_bias``): the row's Pmap is also turned by ``-turn`` about the
        vehicle (``traj[t]``), i.e. the query points by ``+turn`` about it."""
        assert self.offsets is not None and self.depths is not None
        cfg = self.cfg
        bsl = slice(None, None, cfg.mmap_beam_stride)  # gather only the strided beams
        q = self.offsets[:, bsl][idx]  # (K, W, B', 2), in place below: no temporaries
        q += traj[idx][:, :, None, :]  # the Mmap points
        q -= shift[:, None, None, :]
        if turn is not None:
            c = self.traj[self.t]
            q[:] = rotate(q - c, turn[:, None, None]) + c
        z_mm = self.depths[:, bsl][idx]
        z_pm, valid = idw(
            tree, z_p, q, cfg.idw_k, cfg.idw_radius_m, cfg.idw_power, cfg.idw_min_neighbours
        )
        valid &= ok[:, :, None]
        n_m = ok.sum(1) * q.shape[2]
        k = len(idx)
        return z_pm.reshape(k, -1), z_mm.reshape(k, -1), valid.reshape(k, -1), n_m

    def _crossing(self, w: np.ndarray | None, tlp: np.ndarray) -> None:
        """closure = "crossing" (ours): one loop closure per crossing. The weights of the
        crossing's pings are multiplied (sequential importance sampling, the particles moving
        on by eq. (2) in between); the crossing ends after ``crossing_gap_pings`` pings without
        overlap or at ``crossing_max_pings``; then, if the accumulated Neff < f N (eq. 13),
        one resampling = one closure."""
        cfg, n = self.cfg, self.cfg.n_particles
        if w is not None:
            if np.ptp(w) > 0:  # a ping with evidence (not all 1/N)
                self._parts.append(np.log(np.maximum(w, 1e-300)))
            self._tlp = tlp
        ended = self._crossing_end(w)
        if ended is None:
            return
        wa, neff = ended
        parts, self._parts = self._parts, []
        if neff < cfg.neff_fraction * n and self.t - cfg.t_l >= 2:
            weak = cfg.closure_estimate == "mode" and cfg.min_mode_ratio > 1
            r = cfg.mode_radius_m
            ratio = mode_ratio(self.x, wa, r, cfg.mode_apart_m) if weak else math.inf
            if weak and (
                ratio < cfg.min_mode_ratio
                or (
                    cfg.min_mode_odds > 0
                    and mode_odds(self.x, wa, r, cfg.mode_apart_m) < cfg.min_mode_odds
                )
            ):
                self.weak_crossings += 1  # too little evidence: no resampling, no closure
                return
            agree = self._parts_agree(parts) if cfg.lccd and cfg.lccd_mode == "parts" else None
            self._resample(wa, self._tlp, agree, evidence=ratio)

    def _parts_agree(self, parts: list[np.ndarray]) -> bool:
        """LCCD inside one crossing (``lccd_mode = 'parts'``, ours): the crossing's pings with
        evidence are split in time into ``lccd_parts`` parts; each part's own multiplied
        weights give the correction it implies (weighted mean of the particles, which keep
        their offsets through the crossing, in the dominant mode with ``closure_estimate =
        'mode'``); the closure is consistent when those corrections
        form one cluster at ``lccd_tau_m`` (the same linkage as Sec. IV-B)."""
        cfg = self.cfg
        if len(parts) < cfg.lccd_parts:
            return False  # too few pings with evidence to confirm each other
        corr = []
        for chunk in np.array_split(np.arange(len(parts)), cfg.lccd_parts):
            lw = np.sum([parts[i] for i in chunk], axis=0)
            w = np.exp(lw - lw.max())
            w /= w.sum()
            if cfg.closure_estimate == "mode":
                w = mode_weights(self.x, w, cfg.mode_radius_m)
            corr.append(w @ self.x)
        return consistent(np.asarray(corr), cfg.lccd_tau_m, cfg.lccd_linkage)

    # -- resampling = loop closure ------------------------------------------------------------
    def _resample(
        self,
        w: np.ndarray,
        tlp: np.ndarray,
        agree: bool | None = None,
        evidence: float = math.inf,
    ) -> None:
        """Resample = one loop closure (14); ``agree``: the crossing's own LCCD decision
        (``lccd_mode = 'parts'``), None = the pool's (Sec. IV-B)."""
        cfg, t = self.cfg, self.t
        before, b_before = self.x.copy(), self.b.copy()
        s_before = self.traj[t].copy()
        if cfg.closure == "crossing" and cfg.closure_estimate == "mode":
            w = mode_weights(self.x, w, cfg.mode_radius_m)
        i = systematic_resample(w, self.rng)  # A20
        self.x, self.b = self.x[i], self.b[i]  # each particle keeps its heading offset (ours)
        s_after = self.x.mean(0)
        m = s_after - s_before  # eq. (14)
        h = t - cfg.t_l
        t_loop = int(cKDTree(self.traj[:h]).query(s_after)[1])  # A11
        loop = LoopClosure(
            m=m,
            t_loop=t_loop,
            t_end=t,
            dr_loop=self.dr[t_loop].copy(),
            dr_end=self.dr[t].copy(),
            s_loop=self.traj[t_loop].copy(),
            s_end=s_after,
            s_end_before=s_before,
            evidence=evidence,
        )
        self.loops.append(loop)
        if not cfg.lccd:
            valid = True
        elif cfg.lccd_mode == "oracle":  # diagnostic only: the truth label (A22) decides
            if self.oracle_truth is None:
                raise ValueError("lccd_mode = 'oracle' needs the truth (oracle_truth)")
            valid = loop_valid(loop, self.oracle_truth)
        elif agree is not None:
            valid = agree
        else:
            valid = self.lccd.judge(loop)
        loop.accepted = valid
        if not valid:  # A18 (and a pending closure): restore the particles, map unchanged
            self.x, self.b = before, b_before
            return
        covered = self.covered
        if cfg.min_ramp_pings > 0:  # ours: never a kink inside the recent pings
            covered = covered.copy()
            covered[max(t - cfg.min_ramp_pings + 1, 0) : t + 1] = False
        t_a, delta = correction_ramp(covered, t_loop, t, m)  # eqs. (15)-(22)
        self.traj[t_a : t + 1] += delta
        loop.t_a, loop.delta = t_a, delta
        self.resampled_at.append(t)
        self.covered[t_loop : t + 1] = True  # A19
        self.t_r = 1
        if cfg.lccd and self.lccd.overturned_now:
            self._overturn(loop, self.lccd.overturned_now)
        if cfg.drift_estimate:
            self._reanchor()

    def _reanchor_body(self) -> None:
        """``drift_estimate`` with ``drift_frame = 'body'`` (ours): :class:`BodyDrift` fitted
        to the accepted closures (once ``drift_min_agree`` of them exist) gives the DR error
        ``E(t)``; the stretch before ``t_f`` (the first accepted loop's start, which no closure
        corrects) must carry ``-E(t)`` in all, everything after it ``-E(t_f)`` rigidly (as
        :meth:`_reanchor`). Of that, the prediction already removed ``P(t)`` (the sum of
        ``pred_corr``); the rest is the re-anchoring ``shift``, applied as its change."""
        assert self.body is not None
        acc = [lc for lc in self.loops if lc.accepted]
        if not acc:
            return
        t = self.t
        dr = self.dr[: t + 1]
        if len(acc) >= self.cfg.drift_min_agree:
            self.body_s, self.body_psi = self.body.fit(acc, dr)
        else:
            self.body_s, self.body_psi = 0.0, np.zeros(0)
        e = self.body.cumulative(self.body_s, self.body_psi, dr)
        p = np.cumsum(self.pred_corr[: t + 1], axis=0)
        tt = np.minimum(np.arange(t + 1), min(lc.t_loop for lc in acc))
        target = e[tt] - p[tt]
        change = target - self.shift[: t + 1]
        self.traj[: t + 1] -= change
        self.x -= change[t]
        self.shift[: t + 1] = target

    def _reanchor(self) -> None:
        """``drift_estimate`` (ours): the DR bias from the accepted closures
        (:meth:`DriftModel.estimate`), removed from the DR steps from now on, and the track
        re-anchored: before ``t_f``, the first ping of any accepted loop interval, no closure
        corrects the track (eqs. 15-22 move only ``[t_loop, t]``), so it carries the DR drift
        since the known start; it moves by ``-b t`` (0 at the start) and everything from
        ``t_f`` on, loops and particles, rigidly by ``-b t_f`` (each loop's alignment kept).
        Applied as the change from what was applied before; when ``t_f`` moved later (the
        earliest loop was overturned) the stretch it freed gets the applied bias's ramp. With
        ``drift_min_agree`` > 1 the bias comes from the largest agreeing set of the accepted
        closures (:meth:`DriftModel.largest_agreeing`), and is 0 while that set is smaller."""
        if self.body is not None:
            self._reanchor_body()
            return
        acc = [lc for lc in self.loops if lc.accepted]
        if not acc:
            return
        t = self.t
        times = np.arange(t + 1)
        t_f = min(lc.t_loop for lc in acc)
        if 0 <= self.anchor_t < t_f:
            freed = (np.clip(times, self.anchor_t, t_f) - self.anchor_t)[:, None]
            self.traj[: t + 1] -= freed * self.bias
            self.x -= (t_f - self.anchor_t) * self.bias
        self.anchor_t = t_f
        if self.cfg.drift_min_agree > 1:
            acc = self.drift.largest_agreeing(acc)
        new = self.drift.estimate(acc, t) if len(acc) >= self.cfg.drift_min_agree else np.zeros(2)
        step = new - self.bias
        self.traj[: t + 1] -= np.minimum(times, t_f)[:, None] * step
        self.x -= t_f * step
        self.bias = new

    def _overturn(self, keep: LoopClosure, wrong: list[LoopClosure]) -> None:
        """Undo the ``wrong`` closures' corrections (``lccd_overturn``, ours): the ramp of eqs.
        (15)-(22) and the jump the particles carried on are additive, so each one's
        :meth:`LoopClosure.contribution` is subtracted from the mean trajectory and the jump
        from the particles. ``keep`` (the closure that overturned them, at ``t``) aligned the
        ping ``t`` with the map at its ``t_loop``; that map moved by ``-c(t_loop)``, so the
        end must move with it: a linear ramp over ``[t_loop, t]`` restores that alignment.
        ``covered`` (eq. 16) is rebuilt from the closures still accepted."""
        t = self.t
        times = np.arange(t + 1)
        for lc in wrong:
            c = lc.contribution(times)
            fix = c[t] - c[keep.t_loop]
            self.traj[: t + 1] -= c
            span = max(t - keep.t_loop, 1)
            self.traj[keep.t_loop : t + 1] += (
                (times[keep.t_loop :] - keep.t_loop)[:, None] / span * fix
            )
            self.x += fix - c[t]
        self.covered[:] = False
        for lc in self.loops:
            if lc.accepted:
                self.covered[lc.t_loop : lc.t_end + 1] = True


class BPSLAM(BathyFilter):
    """The paper's BPSLAM comparator (Sec. V-A, A24) as Barkby's filter runs it: every particle
    stores its own trajectory (``trajs`` (T, N, 2): the m_j N of Table 1), Pmap and Mmap from
    its own trajectory, the same IDW / MSE gate / eqs. (7)-(8) likelihood, no alpha, no LCCD.

    Weights (issue 28): with ``closure = 'resampling'`` a sequential importance resampling
    filter: each ping's likelihood multiplies the weight (``bpslam_weights = 'accumulate'``;
    ``'replace'`` = the latest ping's only, as before issue 28) and the particles are resampled
    when ``Neff < f N`` (eq. 13), weights reset to 1/N. Jitter: ``bpslam_sigma_c2`` per ping
    (its own, tuned on the tuning seeds). With ``closure = 'crossing'`` it gets the same
    method-agnostic additions as MTM-PF (all options of :class:`BathyConfig`): one resampling
    per crossing of the accumulated weights, no jitter within a crossing
    (``jitter_in_crossing``), the dominant mode only (``closure_estimate = 'mode'``) and the
    evidence test (``min_mode_ratio``). Estimate: the weighted mean of the particle
    trajectories."""

    name = "bpslam"

    def __init__(self, cfg: BathyConfig, n_pings: int, rng: np.random.Generator) -> None:
        super().__init__(cfg, n_pings, rng)
        n = cfg.n_particles
        self.trajs = np.zeros((n_pings, n, 2))
        # the particles' mean track and each particle's largest distance from it (m): the
        # bound that lets own_nearest search only the history near the particles
        self.ref = np.zeros((n_pings, 2))
        self.dev = np.zeros(n)
        self.w = np.full(n, 1.0 / n)
        self.weak_crossings = 0
        self.resamplings = 0

    def start(self, x0: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        super().start(x0, offsets, depth)
        self.trajs[0] = x0
        self.ref[0] = x0

    def trajectory(self) -> np.ndarray:
        return np.einsum("tnk,n->tk", self.trajs[: self.t + 1], self.w)

    def cloud_std(self) -> float:
        x = self.trajs[self.t]
        return float(np.sqrt(self.w @ ((x - self.w @ x) ** 2).sum(1)))

    def step(self, u: np.ndarray, offsets: np.ndarray, depth: np.ndarray) -> None:
        cfg = self.cfg
        var = cfg.bpslam_sigma_c2  # eq. (2) with its own sigma_m^2
        if cfg.closure == "crossing" and self.crossing_len and not cfg.jitter_in_crossing:
            var = 0.0  # one offset per particle through a crossing (ours, as MTM-PF)
        step = self._advance(u, offsets, depth, var)
        t = self.t
        self.trajs[t] = self.trajs[t - 1] + step
        self.ref[t] = self.trajs[t].mean(0)
        self.dev = np.maximum(self.dev, np.linalg.norm(self.trajs[t] - self.ref[t], axis=1))
        lik = self.weights()
        if cfg.closure == "crossing":
            self._crossing(lik)
        elif lik is not None:
            w = lik if cfg.bpslam_weights == "replace" else self.w * lik
            self.w = w / w.sum()
            neff = 1.0 / np.sum(self.w**2)  # eq. (13)
            self.neff_log[t] = neff
            if neff < cfg.neff_fraction * cfg.n_particles:
                self._resample(self.w)
        self.estimates[t] = self.w @ self.trajs[t]

    def _crossing(self, lik: np.ndarray | None) -> None:
        """``closure = 'crossing'``: the crossing's per-ping likelihoods multiplied, one
        resampling when it ends (as :meth:`MTMPF._crossing`), if Neff < f N and the dominant
        mode passes ``min_mode_ratio``; otherwise the crossing's weights are dropped."""
        cfg, n = self.cfg, self.cfg.n_particles
        ended = self._crossing_end(lik)
        if ended is None:
            return
        wa, neff = ended
        if neff >= cfg.neff_fraction * n:
            return
        x = self.trajs[self.t]
        r = cfg.mode_radius_m
        evidence = cfg.closure_estimate == "mode" and cfg.min_mode_ratio > 1
        if evidence and mode_ratio(x, wa, r, cfg.mode_apart_m) < cfg.min_mode_ratio:
            self.weak_crossings += 1  # too little evidence: no resampling
            return
        if cfg.closure_estimate == "mode":
            wa = mode_weights(x, wa, cfg.mode_radius_m)
        self._resample(wa)

    def _resample(self, w: np.ndarray) -> None:
        """Systematic resampling (A20) of whole trajectories; weights back to 1/N."""
        n, t = self.cfg.n_particles, self.t
        i = systematic_resample(w, self.rng)  # A20
        self.trajs[: t + 1] = self.trajs[: t + 1, i]
        self.ref[: t + 1] = self.trajs[: t + 1].mean(1)
        self.dev = np.linalg.norm(self.trajs[: t + 1] - self.ref[: t + 1, None], axis=2).max(0)
        self.w = np.full(n, 1.0 / n)
        self.resamplings += 1
        self.resampled_at.append(t)

    def weights(self) -> np.ndarray | None:
        """Weights from each particle's own Pmap / Mmap; None when no particle overlaps."""
        assert self.offsets is not None and self.depths is not None
        cfg, t, n = self.cfg, self.t, self.cfg.n_particles
        h = t - cfg.t_l
        if h < 2:
            return None
        x = self.trajs[t]
        tlp, near = own_nearest(self.trajs[:h], x, self.ref[:h], self.dev, cfg.radius_m)
        self.matched[t] = len(near)
        if len(near) == 0:
            return None
        k = len(near)
        lo = max(t - cfg.t_p + 1, 0)
        bsl = slice(None, None, cfg.pmap_beam_stride)
        own = self.trajs[lo : t + 1][:, near]  # (Tp, K, 2)
        pm = own[:, :, None, :] + self.offsets[lo : t + 1, None, bsl]  # (Tp, K, B', 2)
        # one tree over every particle's Pmap: the particle index is a third coordinate far
        # beyond any search radius, so a query only finds its own particle's points
        sep = 1e7
        lab = np.broadcast_to(np.arange(k)[None, :, None, None] * sep, (*pm.shape[:3], 1))
        tree = cKDTree(np.concatenate([pm, lab], -1).reshape(-1, 3))
        z_p = np.broadcast_to(self.depths[lo : t + 1, None, bsl], pm.shape[:3]).reshape(-1)
        rel = np.arange(-(cfg.t_m // 2), cfg.t_m // 2 + 1, cfg.mmap_ping_stride)
        idx = tlp[near][:, None] + rel[None, :]
        ok = (idx >= 0) & (idx < h)
        idx = np.clip(idx, 0, h - 1)
        msl = slice(None, None, cfg.mmap_beam_stride)
        own_h = self.trajs[idx, near[:, None]]  # (K, W, 2)
        pts = own_h[:, :, None, :] + self.offsets[idx][:, :, msl]
        q = np.concatenate(
            [pts, np.broadcast_to(np.arange(k)[:, None, None, None] * sep, (*pts.shape[:3], 1))],
            -1,
        )
        z_pm, valid = idw(
            tree, z_p, q, cfg.idw_k, cfg.idw_radius_m, cfg.idw_power, cfg.idw_min_neighbours
        )
        mask = np.broadcast_to(ok[:, :, None], valid.shape)
        valid = (valid & mask).reshape(k, -1)
        z_mm = self.depths[idx][:, :, msl].reshape(k, -1)
        w_m, gate, _ = match_weights(
            z_pm.reshape(k, -1), z_mm, valid, mask.reshape(k, -1).sum(1), cfg, use_alpha=False
        )
        # unmatched particles as cfg.unmatched_weight says ('uniform' = 1/N as written, A5)
        return fill_weights(n, near[gate], w_m[gate], cfg, bad=near[~gate])


FILTERS: dict[str, type[BathyFilter]] = {"mtm-pf": MTMPF, "bpslam": BPSLAM, "dr": DeadReckoning}
