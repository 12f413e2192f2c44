"""Line features from MSIS returns by Hough voting: Cui et al. 2020 ("VRFastSLAM"), sections
2.2.2 (the 180 deg data buffer) and 2.2.3 (voting with the beam-width arc and incidence rule).

**Buffer (2.2.2).** :class:`SectorBuffer` keeps the latest beams whose directions span at most
180 deg (the largest sector over which one line can be seen), each with its time, the vehicle
pose at its ping and its returns. The voting frame B is the sonar head's pose at the newest
ping, so a line comes out directly as an observation from the current pose.

**Voting (2.2.3).** Hough space is quantised in ``theta`` (``theta_res_rad``) and ``rho``
(``rho_res_m``). A return at range ``rho_S`` from a transducer at ``(x_S, y_S)`` in B, beam
direction ``theta_S``, is an arc of aperture ``alpha`` (the horizontal beam width); the lines
compatible with it are those through the arc whose incidence angle (between the beam and the
line's normal) is within ``+-beta/2``. For each Hough angle ``theta_k`` (steps 2-3: arc angles
``theta_S +- alpha/2``, normals within ``+-beta/2`` of them) the compatible distances are

    rho_k = x_S cos(theta_k) + y_S sin(theta_k) + rho_S cos(theta_k - theta_arc)   (step 4)

over the arc angles allowed; the return votes once for every ``(rho, theta)`` cell of that
interval. (The paper prints the last term of step 4 as ``rho_S cos(theta_S^B)``; the cosine of
the incidence angle ``theta_k - theta_arc`` is what the geometry of its Fig. 2 and the method it
cites, Ribas et al. 2008, use.) The cell with most votes is a line.

**Beyond the paper** (needed for a filter): every peak is refined by a weighted least-squares
line fit to the returns that agree with it (residual within 3 sigma, incidence within the
rule), which gives ``(rho, theta)`` between the cells and its 2 x 2 covariance. A line is
reported only once its whole visibility window (normal +- (alpha + beta)/2) has been scanned
(the "line seen over a full sector"), its returns are then removed from the buffer, and the
next peak is searched; duplicates (two peaks on one wall) are merged by refitting their union.

Frames: B is the transducer at the reference ping, x along the head's forward mark, y 90 deg
clockwise from it seen from above (also for an inverted head; angles clockwise from x, rad).
Lines are in normal form ``x cos(theta) + y sin(theta) = rho`` with ``rho >= 0`` (the normal
points from B to the line). :class:`LineObservation` also gives the line in the vehicle frame
at the reference ping, the form of ``auvgw.slam.models.LineFeature``, and in the pose (world /
odometry) frame.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .beams import SonarMount, wrap_angle

__all__ = [
    "BufferedReturns",
    "HoughSettings",
    "LineFit",
    "LineObservation",
    "SectorBuffer",
    "covers",
    "extract_lines",
    "fit_line",
    "hough_votes",
    "line_difference",
    "line_refitter",
    "line_to_world",
    "merge_lines",
]

FArray = np.ndarray
TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class HoughSettings:
    """Voting and acceptance of line features.

    ``beam_width_rad`` alpha, the horizontal beam width (Tritech Micron 3 deg);
    ``incidence_rad`` beta, the full aperture of incidence angles a return may vote for
    (normals within +-beta/2 of the beam); ``theta_res_rad`` / ``rho_res_m`` the Hough cells.
    ``min_votes`` returns, ``min_pings`` distinct pings and ``min_length_m`` extent along the
    line make a line. ``sigma_range_m``: one return's range noise (None: its bin length).
    ``gate_sigma``: returns within this many sigma of a fitted line support it. ``max_peaks``:
    peaks examined per vote. ``merge_chi2``: two lines closer than this (Mahalanobis, 2 dof)
    in one vote are one.
    """

    beam_width_rad: float = math.radians(3.0)
    incidence_rad: float = math.radians(60.0)
    theta_res_rad: float = math.radians(1.0)
    rho_res_m: float = 0.25
    min_votes: int = 10
    min_pings: int = 6
    min_length_m: float = 2.0
    sigma_range_m: float | None = None
    gate_sigma: float = 3.0
    max_peaks: int = 20
    merge_chi2: float = 13.8

    @property
    def window(self) -> float:
        """Half-width of the beam directions that can see a line, around its normal, rad."""
        return 0.5 * (self.beam_width_rad + self.incidence_rad)


# -- voting -------------------------------------------------------------------------------------


def hough_votes(
    sx: FArray, sy: FArray, ang: FArray, rng: FArray, settings: HoughSettings
) -> tuple[FArray, FArray, tuple[int, int]]:
    """The votes of returns (transducer ``sx, sy`` m and beam direction ``ang`` rad in B,
    range ``rng`` m) under the arc and incidence rule (sec. 2.2.3, steps 1-4).

    Returns ``(voter, cell, (K, P))``: for every vote the index of the return and the flat
    Hough cell ``k * P + p`` (``theta_k = k * theta_res`` in [0, 2 pi), ``rho_p = (p + 0.5) *
    rho_res``, rho >= 0). A return votes at most once per cell.
    """
    sx, sy, ang, rng = (np.asarray(a, float).ravel() for a in (sx, sy, ang, rng))
    dth, drho = settings.theta_res_rad, settings.rho_res_m
    half_a, half_b = 0.5 * settings.beam_width_rad, 0.5 * settings.incidence_rad
    n_theta = round(TWO_PI / dth)
    dth = TWO_PI / n_theta
    reach = np.hypot(sx, sy) + rng
    n_rho = max(1, math.ceil((float(reach.max(initial=0.0)) + drho) / drho))
    if sx.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), (n_theta, n_rho)
    # step 2-3: every Hough angle within the arc +- the incidence limit of each return
    w = half_a + half_b
    k_lo = np.ceil((ang - w) / dth).astype(np.int64)
    k_hi = np.floor((ang + w) / dth).astype(np.int64)
    cnt = np.maximum(k_hi - k_lo + 1, 0)
    ret = np.repeat(np.arange(sx.size), cnt)
    k = np.repeat(k_lo, cnt) + (np.arange(ret.size) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    theta = k * dth
    d = theta - ang[ret]  # normal minus beam axis
    # incidence e = theta_k - theta_arc over the arc angles allowed: [d - a/2, d + a/2] & +-b/2
    e_lo = np.maximum(d - half_a, -half_b)
    e_hi = np.minimum(d + half_a, half_b)
    e_min = np.where((e_lo <= 0) & (e_hi >= 0), 0.0, np.minimum(np.abs(e_lo), np.abs(e_hi)))
    e_max = np.maximum(np.abs(e_lo), np.abs(e_hi))
    # step 4: rho_k = x_S cos + y_S sin + rho_S cos(e), an interval over the allowed arc
    base = sx[ret] * np.cos(theta) + sy[ret] * np.sin(theta)
    r = rng[ret]
    p_lo = np.floor((base + r * np.cos(e_max)) / drho).astype(np.int64)
    p_hi = np.floor((base + r * np.cos(e_min)) / drho).astype(np.int64)
    p_lo = np.maximum(p_lo, 0)
    p_hi = np.minimum(p_hi, n_rho - 1)
    cnt2 = np.maximum(p_hi - p_lo + 1, 0)
    voter = np.repeat(ret, cnt2)
    start = np.repeat(p_lo, cnt2)
    p = start + (np.arange(voter.size) - np.repeat(np.cumsum(cnt2) - cnt2, cnt2))
    cell = np.repeat(k % n_theta, cnt2) * n_rho + p
    return voter, cell, (n_theta, n_rho)


# -- least-squares refinement -------------------------------------------------------------------


@dataclass(frozen=True)
class LineFit:
    """A line in B: ``x cos(theta) + y sin(theta) = rho`` (rho >= 0, m; theta rad in
    [-pi, pi)), ``covariance`` 2 x 2 over (rho, theta), Hough ``votes`` of its peak, the
    supporting returns ``support`` (indices into the voting input), their number of distinct
    pings, the extent ``t_min, t_max`` along the line (m, along ``(-sin, cos)`` from the
    foot of the normal) and the weighted squared residual ``chi2`` of the fit."""

    rho: float
    theta: float
    covariance: FArray
    votes: int
    support: FArray
    n_pings: int
    t_min: float
    t_max: float
    chi2: float

    @property
    def length(self) -> float:
        return self.t_max - self.t_min

    def endpoints(self) -> FArray:
        """(2, 2) ends of the supported segment in B, m."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        foot = np.array([self.rho * c, self.rho * s])
        d = np.array([-s, c])
        return np.stack([foot + self.t_min * d, foot + self.t_max * d])


def _sigma_normal(rng: FArray, inc: FArray, sigma_r: FArray, alpha: float) -> FArray:
    """Std of a return's offset normal to a wall seen at incidence ``inc``: range noise along
    the beam, plus the spread of ranges over the beam footprint (the echo may peak anywhere
    in it: ``rho_S sin(inc) alpha / sqrt(12)``)."""
    s = np.sin(inc)
    return np.sqrt((sigma_r * np.cos(inc)) ** 2 + (rng * s * alpha) ** 2 / 12.0)


def fit_line(
    px: FArray,
    py: FArray,
    ang: FArray,
    rng: FArray,
    sigma_r: FArray,
    rho0: float,
    theta0: float,
    settings: HoughSettings,
    candidates: FArray | None = None,
    iterations: int = 5,
) -> tuple[float, float, FArray, FArray, float] | None:
    """Weighted least-squares line through the returns near ``(rho0, theta0)`` (B frame).

    Returns ``px, py`` (positions on the beam axis), beam direction ``ang``, range ``rng`` and
    range noise ``sigma_r``; ``candidates`` restricts which may support it. Each iteration
    takes the returns whose normal residual is within ``gate_sigma`` sigma (at least one Hough
    cell at the start) and whose beam is within the arc-and-incidence window of the normal,
    weights them by ``1 / sigma^2`` and solves the weighted total-least-squares line.
    Returns ``(rho, theta, covariance, support, chi2)`` or None when fewer than 3 support.

    Covariance: the inverse of ``sum w_i J_i^T J_i`` with ``J_i = (-1, t_i)`` (derivatives of
    the residual ``x cos + y sin - rho`` by ``rho`` and ``theta``; ``t_i`` the position along
    the line), scaled by the reduced chi-square when that exceeds 1.
    """
    idx = np.arange(px.size) if candidates is None else np.asarray(candidates)
    x, y, a, r, sr = px[idx], py[idx], ang[idx], rng[idx], sigma_r[idx]
    rho, theta = rho0, theta0
    support = np.zeros(0, np.int64)
    first = True
    alpha = settings.beam_width_rad
    for _ in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        res = x * c + y * s - rho
        inc = np.abs(wrap_angle(a - theta))
        sig = _sigma_normal(r, np.minimum(inc, 0.5 * math.pi), sr, alpha)
        gate = settings.gate_sigma * sig
        if first:
            t = -x * s + y * c
            gate = np.maximum(gate, settings.rho_res_m + 0.5 * settings.theta_res_rad * np.abs(t))
        ok = (np.abs(res) <= gate) & (inc <= settings.window)
        new = np.flatnonzero(ok)
        if new.size < 3:
            return None
        if not first and np.array_equal(new, support):
            break
        support, first = new, False
        w = 1.0 / sig[new] ** 2
        xs, ys = x[new], y[new]
        sw = w.sum()
        cx, cy = (w * xs).sum() / sw, (w * ys).sum() / sw
        dx, dy = xs - cx, ys - cy
        sxx, syy, sxy = (w * dx * dx).sum(), (w * dy * dy).sum(), (w * dx * dy).sum()
        # normal = direction of least weighted scatter
        phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # direction of most scatter
        theta_n = phi + 0.5 * math.pi
        rho_n = cx * math.cos(theta_n) + cy * math.sin(theta_n)
        if rho_n < 0:
            rho_n, theta_n = -rho_n, theta_n + math.pi
        rho, theta = rho_n, float(wrap_angle(theta_n))
    c, s = math.cos(theta), math.sin(theta)
    xs, ys = x[support], y[support]
    inc = np.abs(wrap_angle(a[support] - theta))
    sig = _sigma_normal(r[support], np.minimum(inc, 0.5 * math.pi), sr[support], alpha)
    w = 1.0 / sig**2
    res = xs * c + ys * s - rho
    t = -xs * s + ys * c
    info = np.array([[w.sum(), -(w * t).sum()], [-(w * t).sum(), (w * t * t).sum()]])
    chi2 = float((w * res * res).sum())
    dof = max(support.size - 2, 1)
    try:
        cov = np.linalg.inv(info) * max(1.0, chi2 / dof)
    except np.linalg.LinAlgError:
        return None
    return rho, theta, cov, idx[support], chi2


#: ``refit(rho0, theta0, votes, candidates)``: a line of ``votes`` near ``(rho0, theta0)`` from
#: the returns ``candidates``, or None when it fails the acceptance tests
Refit = Callable[[float, float, int, FArray], LineFit | None]


def line_refitter(
    px: FArray,
    py: FArray,
    ang: FArray,
    rng: FArray,
    sigma_r: FArray,
    ping: FArray,
    settings: HoughSettings,
) -> Refit:
    """:func:`fit_line` over these returns (``ping`` labels their pings) plus the acceptance
    tests (returns, pings, length), as a :data:`Refit`."""

    def refit(rho0: float, theta0: float, votes: int, candidates: FArray) -> LineFit | None:
        got = fit_line(px, py, ang, rng, sigma_r, rho0, theta0, settings, candidates)
        if got is None:
            return None
        rho, theta, cov, sup, chi2 = got
        c, s = math.cos(theta), math.sin(theta)
        t = -px[sup] * s + py[sup] * c
        n_pings = int(np.unique(ping[sup]).size)
        fit = LineFit(rho, theta, cov, votes, sup, n_pings, float(t.min()), float(t.max()), chi2)
        if (
            sup.size < settings.min_votes
            or n_pings < settings.min_pings
            or fit.length < settings.min_length_m
        ):
            return None
        return fit

    return refit


def line_difference(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """``(drho, dtheta)`` from line ``b`` to line ``a`` (normal form), ``b`` taken in whichever
    of its two forms ``(rho, theta)`` / ``(-rho, theta + pi)`` is closer in angle."""
    dth = float(wrap_angle(a[1] - b[1]))
    if abs(dth) <= 0.5 * math.pi:
        return a[0] - b[0], dth
    return a[0] + b[0], float(wrap_angle(dth - math.pi))


def extract_lines(
    sx: FArray,
    sy: FArray,
    ang: FArray,
    rng: FArray,
    ping: FArray,
    settings: HoughSettings,
    sigma_r: FArray | float | None = None,
) -> list[LineFit]:
    """All lines in a set of returns (B frame): vote (:func:`hough_votes`), then repeatedly
    take the strongest cell, refine it (:func:`fit_line`), accept it if it passes the
    acceptance tests and withdraw its supporting returns' votes; a peak that fails is
    suppressed with its neighbouring cells. Duplicates are merged (:func:`merge_lines`).

    ``ping`` labels the returns' pings; ``sigma_r`` their range noise (m; default
    ``settings.sigma_range_m``, required then).
    """
    sx, sy, ang, rng = (np.asarray(v, float).ravel() for v in (sx, sy, ang, rng))
    ping = np.asarray(ping).ravel()
    if sigma_r is None:
        if settings.sigma_range_m is None:
            raise ValueError("extract_lines: sigma_r or settings.sigma_range_m is needed")
        sigma_r = settings.sigma_range_m
    sr = np.broadcast_to(np.asarray(sigma_r, float), sx.shape).astype(float)
    if sx.size < settings.min_votes:
        return []
    px, py = sx + rng * np.cos(ang), sy + rng * np.sin(ang)
    refit = line_refitter(px, py, ang, rng, sr, ping, settings)
    voter, cell, (n_theta, n_rho) = hough_votes(sx, sy, ang, rng, settings)
    acc = np.bincount(cell, minlength=n_theta * n_rho).astype(np.int64)
    active = np.ones(sx.size, bool)
    dth = TWO_PI / n_theta
    fits: list[LineFit] = []
    for _ in range(settings.max_peaks):
        peak = int(np.argmax(acc))
        votes = int(acc[peak])
        if votes < settings.min_votes:
            break
        k, p = divmod(peak, n_rho)
        cand = np.flatnonzero(active)
        fit = refit((p + 0.5) * settings.rho_res_m, k * dth, votes, cand)
        if fit is None:
            # suppress the peak and its neighbours; its voters may still make another line
            kk = (k + np.arange(-1, 2)) % n_theta
            pp = np.clip(p + np.arange(-1, 2), 0, n_rho - 1)
            acc[(kk[:, None] * n_rho + pp[None, :]).ravel()] = -1
            continue
        fits.append(fit)
        gone = np.zeros(sx.size, bool)
        gone[fit.support] = True
        gone &= active
        active &= ~gone
        np.subtract.at(acc, cell[gone[voter]], 1)
    return merge_lines(fits, refit, settings)


def merge_lines(fits: list[LineFit], refit: Refit, settings: HoughSettings) -> list[LineFit]:
    """Merge lines of one vote that are the same line: Mahalanobis distance of their
    ``(rho, theta)`` difference (summed covariances) below ``merge_chi2``; the merged line is
    refitted (``refit``, see :func:`line_refitter`) on the union of their returns."""
    out = list(fits)
    merged = True
    while merged and len(out) > 1:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                d = np.array(line_difference((a.rho, a.theta), (b.rho, b.theta)))
                s = a.covariance + b.covariance
                if float(d @ np.linalg.solve(s, d)) > settings.merge_chi2:
                    continue
                cand = np.union1d(a.support, b.support)
                fit = refit(a.rho, a.theta, a.votes + b.votes, cand)
                if fit is None:
                    continue
                out[i] = fit
                del out[j]
                merged = True
                break
            if merged:
                break
    return out


# -- the sector buffer (2.2.2) ------------------------------------------------------------------


@dataclass
class _Beam:
    t: float
    pose: FArray  # vehicle pose at the ping (3,)
    sonar: FArray  # transducer position (2,)
    angle: float  # beam direction, pose frame, rad
    unwrapped: float  # the same, continuous over the buffer
    ranges: FArray
    intensity: FArray
    sigma_r: FArray
    ids: FArray


@dataclass(frozen=True)
class BufferedReturns:
    """The returns of a :class:`SectorBuffer` expressed in a frame B, flat (R,) each:
    ``ids`` (unique, to remove them), ``ping`` (a per-beam label), ``t``, transducer ``sx,
    sy`` and beam direction ``ang`` in B, ``rng``, ``intensity``, range noise ``sigma_r``,
    and the positions ``px, py`` in B; ``pose`` (R, 3) the vehicle pose (pose frame) of their
    ping. ``path`` (M,) the unwrapped beam directions in B of every buffered beam, oldest
    first (returns or not)."""

    ids: FArray
    ping: FArray
    t: FArray
    sx: FArray
    sy: FArray
    ang: FArray
    rng: FArray
    intensity: FArray
    sigma_r: FArray
    pose: FArray
    path: FArray

    @property
    def px(self) -> FArray:
        return self.sx + self.rng * np.cos(self.ang)

    @property
    def py(self) -> FArray:
        return self.sy + self.rng * np.sin(self.ang)

    def __len__(self) -> int:
        return self.ids.size


def covers(path: FArray, lo: float, hi: float) -> bool:
    """True when the unwrapped directions ``path`` (rad) sweep the whole interval
    ``[lo, hi]`` (rad, taken modulo 2 pi)."""
    if path.size == 0:
        return False
    pmin, pmax = float(path.min()), float(path.max())
    k_lo = math.ceil((pmin - lo) / TWO_PI)
    k_hi = math.floor((pmax - hi) / TWO_PI)
    return k_lo <= k_hi


@dataclass
class SectorBuffer:
    """Sec. 2.2.2: the latest beams whose directions (pose frame) span at most ``sector_rad``
    (180 deg), beams older than ``max_age_s`` dropped, each with its time, vehicle pose,
    transducer position and returns. Beams without returns are kept too (they tell which
    directions have been scanned)."""

    sector_rad: float = math.pi
    max_age_s: float = 120.0
    mount: SonarMount = field(default_factory=SonarMount)
    _beams: deque[_Beam] = field(default_factory=deque, init=False, repr=False)
    _next_id: int = field(default=0, init=False, repr=False)

    def __len__(self) -> int:
        return len(self._beams)

    @property
    def n_returns(self) -> int:
        return sum(b.ids.size for b in self._beams)

    @property
    def newest(self) -> _Beam | None:
        return self._beams[-1] if self._beams else None

    def clear(self) -> None:
        self._beams.clear()

    def push(
        self,
        t: float,
        bearing: float,
        pose: FArray,
        ranges: FArray,
        intensity: FArray,
        sigma_r: FArray | float,
    ) -> None:
        """Add one ping at time ``t`` (s), head ``bearing`` (rad), vehicle ``pose`` (x, y,
        heading) at that time, with its returns (ranges m, intensities, range noise m)."""
        pose = np.asarray(pose, float).reshape(3)
        sx, sy = self.mount.transducer(pose)
        angle = float(wrap_angle(pose[2] + self.mount.beam_angle(bearing)))
        last = self.newest
        unwrapped = (
            angle if last is None else last.unwrapped + float(wrap_angle(angle - last.angle))
        )
        ranges = np.asarray(ranges, float).ravel()
        n = ranges.size
        ids = np.arange(self._next_id, self._next_id + n)
        self._next_id += n
        self._beams.append(
            _Beam(
                float(t), pose, np.array([float(sx), float(sy)]), angle, unwrapped, ranges,
                np.asarray(intensity, float).ravel(),
                np.broadcast_to(np.asarray(sigma_r, float), (n,)).copy(), ids,
            )
        )  # fmt: skip
        self._trim()

    def _trim(self) -> None:
        beams = self._beams
        newest = beams[-1]
        while len(beams) > 1 and newest.t - beams[0].t > self.max_age_s:
            beams.popleft()
        u = np.fromiter((b.unwrapped for b in beams), float, len(beams))
        # longest suffix whose span is within the sector
        lo = np.minimum.accumulate(u[::-1])[::-1]
        hi = np.maximum.accumulate(u[::-1])[::-1]
        inside = np.flatnonzero(hi - lo <= self.sector_rad + 1e-9)
        for _ in range(int(inside[0]) if inside.size else len(beams) - 1):
            beams.popleft()

    def remove(self, ids: FArray) -> None:
        """Drop the returns ``ids`` (used by a feature)."""
        ids = np.asarray(ids)
        if ids.size == 0:
            return
        for b in self._beams:
            if b.ids.size and b.ids[-1] >= ids.min() and b.ids[0] <= ids.max():
                keep = ~np.isin(b.ids, ids)
                if not keep.all():
                    b.ranges, b.intensity = b.ranges[keep], b.intensity[keep]
                    b.sigma_r, b.ids = b.sigma_r[keep], b.ids[keep]

    def frame(self) -> tuple[FArray, FArray, float, float]:
        """Frame B: (vehicle pose at the newest ping, transducer position, heading of the head's
        forward mark in the pose frame, time)."""
        b = self.newest
        if b is None:
            raise ValueError("SectorBuffer.frame: the buffer is empty")
        return b.pose, b.sonar, float(b.pose[2] + self.mount.yaw_rad), b.t

    def returns(self) -> BufferedReturns:
        """All buffered returns in frame B (see :class:`BufferedReturns`)."""
        _, origin, psi, _ = self.frame()
        beams = self._beams
        m = len(beams)
        n = np.fromiter((b.ids.size for b in beams), np.int64, m)
        head = np.array([(b.t, b.sonar[0], b.sonar[1], b.unwrapped) for b in beams])
        c, s = math.cos(psi), math.sin(psi)
        ox, oy = head[:, 1] - origin[0], head[:, 2] - origin[1]
        newest = beams[-1]
        path = head[:, 3] - newest.unwrapped + float(wrap_angle(newest.angle - psi))
        with_returns = [b for b in beams if b.ids.size]
        cat = np.concatenate

        def per_return(v: FArray) -> FArray:
            return np.repeat(v, n, axis=0)

        if with_returns:
            ids = cat([b.ids for b in with_returns])
            rng = cat([b.ranges for b in with_returns])
            inten = cat([b.intensity for b in with_returns])
            sig = cat([b.sigma_r for b in with_returns])
        else:
            ids, rng, inten, sig = np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
        return BufferedReturns(
            ids=ids,
            ping=per_return(np.arange(m)),
            t=per_return(head[:, 0]),
            sx=per_return(c * ox + s * oy),
            sy=per_return(-s * ox + c * oy),
            ang=per_return(wrap_angle(path)),
            rng=rng,
            intensity=inten,
            sigma_r=sig,
            pose=per_return(np.array([b.pose for b in beams])),
            path=path,
        )


# -- observations -------------------------------------------------------------------------------


def line_to_world(
    rho: float, theta: float, cov: FArray, pose: FArray
) -> tuple[float, float, FArray]:
    """A line seen from the vehicle ``pose`` (x, y, heading) as ``(rho, theta)`` in the vehicle
    frame (``auvgw.slam.models.LineFeature`` form) -> ``(rho, theta, covariance)`` in the pose
    frame, ``rho >= 0``. Pose uncertainty is not included."""
    x, y, h = (float(v) for v in np.asarray(pose, float).reshape(3))
    th = theta + h
    c, s = math.cos(th), math.sin(th)
    rw = rho + x * c + y * s
    g = np.array([[1.0, -x * s + y * c], [0.0, 1.0]])
    cw = g @ cov @ g.T
    if rw < 0:
        rw, th = -rw, th + math.pi
        f = np.diag([-1.0, 1.0])
        cw = f @ cw @ f
    return rw, float(wrap_angle(th)), cw


@dataclass(frozen=True)
class LineObservation:
    """A line feature extracted from the sector buffer.

    ``t`` (s) and vehicle ``pose`` (x, y, heading; pose frame) of the reference ping;
    ``rho`` (m), ``theta`` (rad) the line in the vehicle frame at that ping (``x_v cos(theta)
    + y_v sin(theta) = rho``, x_v forward, y_v starboard; the measurement of
    ``auvgw.slam.models.LineFeature``), ``covariance`` 2 x 2 over (rho, theta);
    ``rho_b, theta_b, covariance_b`` the same in the head's frame B; ``votes`` of the Hough
    peak, ``n_returns`` and ``n_pings`` supporting it, ``t_first`` / ``t_last`` its oldest and
    newest return (s), ``endpoints`` (2, 2) the supported segment in the pose frame (m).
    """

    t: float
    pose: FArray
    rho: float
    theta: float
    covariance: FArray
    rho_b: float
    theta_b: float
    covariance_b: FArray
    votes: int
    n_returns: int
    n_pings: int
    t_first: float
    t_last: float
    endpoints: FArray

    @property
    def z(self) -> FArray:
        """The measurement ``(rho, theta)`` in the vehicle frame."""
        return np.array([self.rho, self.theta])

    def world(self, pose: FArray | None = None) -> tuple[float, float, FArray]:
        """``(rho, theta, covariance)`` in the pose frame, from ``pose`` (default: the pose of
        the reference ping)."""
        return line_to_world(
            self.rho, self.theta, self.covariance, self.pose if pose is None else pose
        )

    @classmethod
    def from_fit(
        cls,
        fit: LineFit,
        pose: FArray,
        psi: float,
        origin: FArray,
        t: float,
        t_support: FArray,
        mount: SonarMount,
    ) -> LineObservation:
        """From a fit in B (the head at ``origin`` with forward mark ``psi`` in the pose frame,
        vehicle ``pose``, time ``t``), with its returns' times ``t_support``."""
        # B -> vehicle frame: q_v = m + R(yaw) q_b, so theta_v = theta_b + yaw and
        # rho_v = rho_b + m . n_v
        th_v = fit.theta + mount.yaw_rad
        c, s = math.cos(th_v), math.sin(th_v)
        rho_v = fit.rho + mount.x_m * c + mount.y_m * s
        j = np.array([[1.0, -mount.x_m * s + mount.y_m * c], [0.0, 1.0]])
        cov_v = j @ fit.covariance @ j.T
        if rho_v < 0:  # the vehicle reference point is past the line: keep rho >= 0
            rho_v, th_v = -rho_v, th_v + math.pi
            f = np.diag([-1.0, 1.0])
            cov_v = f @ cov_v @ f
        cp, sp = math.cos(psi), math.sin(psi)
        ends = fit.endpoints()
        ends_w = np.stack(
            [origin[0] + cp * ends[:, 0] - sp * ends[:, 1],
             origin[1] + sp * ends[:, 0] + cp * ends[:, 1]], axis=1,
        )  # fmt: skip
        return cls(
            t=float(t),
            pose=np.asarray(pose, float).copy(),
            rho=float(rho_v),
            theta=float(wrap_angle(th_v)),
            covariance=cov_v,
            rho_b=fit.rho,
            theta_b=fit.theta,
            covariance_b=fit.covariance,
            votes=fit.votes,
            n_returns=int(fit.support.size),
            n_pings=fit.n_pings,
            t_first=float(np.min(t_support)),
            t_last=float(np.max(t_support)),
            endpoints=ends_w,
        )
