"""Point features from MSIS returns: compact clusters of returns (piles, dolphins, moorings)
turned into range-bearing observations with covariance, the measurement of the VB filters
(Mu et al. 2022, eq. 4; ``auvgw.slam.models.RangeBearing``).

The returns come from the sector buffer of :mod:`.lines` (Cui 2020 sec. 2.2.2), already placed
with the sonar pose of their own ping, in the head's frame B at the newest ping. Returns that
support a line, or lie near one, are left out; the rest are clustered by single linkage
(returns closer than ``link_m`` join). A cluster is a point feature when it is small (extent
<= ``max_extent_m`` along the line of sight, and across it ``max_extent_m`` plus
``(alpha + s) r``: every return sits on its beam's axis, so even a thin target smears over the
beam width alpha and a scan step s at its range r), seen by at least ``min_pings`` pings with
``min_returns`` returns,
isolated (no other return, on a line or not, within ``isolation_m`` of its centre: a stretch
of wall seen at a steep angle breaks into small clusters, but its neighbours along the wall
give it away) and complete: the scan has swept past both its sides by a beam width, a step and
the angle of the isolation radius, so no later ping can still add to it.

Each return lies on the near face of the target, on its beam axis; ``target_radius_m`` moves
it back along the beam to the target's centre (the harbour's piles: 0.6 m). The centre is the
mean of those points. Its covariance, along and across the mean line of sight:

* along (range): ``sigma_r^2 / n`` (one return's range noise, by default its bin length, over
  ``n`` returns) plus ``(target_radius_m / 2)^2 / n`` for where on the face the echo peaks;
* across (bearing): the pings that see the target sample the beam at the scan step ``s``, so
  their mean direction is off by up to a step: ``s^2 / 12``, plus the beam's own spread
  ``alpha^2 / (12 n)``; times the squared range.

Frames: B as in :mod:`.lines` (x along the head's forward mark, y starboard, rad clockwise);
:class:`PointObservation` gives range and bearing from the vehicle reference point at the
reference ping (bearing from the bow, positive to starboard) and the centre in the pose frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .beams import SonarMount, wrap_angle

__all__ = [
    "PointFit",
    "PointObservation",
    "PointSettings",
    "cluster_returns",
    "extract_points",
    "segment_distance",
]

FArray = np.ndarray


@dataclass(frozen=True)
class PointSettings:
    """Clustering and acceptance of point features (see the module docstring).

    ``link_m`` single-linkage distance; ``max_extent_m`` largest cluster extent along the line
    of sight (across it, plus ``(beam_width_rad + step) r``; larger ones are walls);
    ``min_returns`` / ``min_pings``; ``target_radius_m`` radius of the targets
    (added along the beam); ``beam_width_rad`` alpha; ``sigma_range_m`` range noise of one
    return (None: its bin length); ``line_clearance_m`` returns nearer than this to an
    extracted line segment are not point targets; ``isolation_m``: a target has no other
    return within this distance of its centre (a stretch of wall seen at a steep angle has;
    0: no isolation test).
    """

    link_m: float = 1.0
    max_extent_m: float = 2.0
    min_returns: int = 2
    min_pings: int = 2
    target_radius_m: float = 0.0
    beam_width_rad: float = math.radians(3.0)
    sigma_range_m: float | None = None
    line_clearance_m: float = 1.5
    isolation_m: float = 3.0


def cluster_returns(x: FArray, y: FArray, link_m: float) -> FArray:
    """Single-linkage cluster label of each point (x, y m): points closer than ``link_m``
    share a label (the smallest index in the cluster)."""
    pts = np.stack([np.asarray(x, float).ravel(), np.asarray(y, float).ravel()], axis=1)
    labels = np.arange(len(pts))
    if len(pts) < 2:
        return labels
    pairs = cKDTree(pts).query_pairs(link_m, output_type="ndarray")
    if len(pairs) == 0:
        return labels
    i, j = pairs[:, 0], pairs[:, 1]
    while True:  # propagate the smallest label along the links, then jump pointers
        m = np.minimum(labels[i], labels[j])
        new = labels.copy()
        np.minimum.at(new, i, m)
        np.minimum.at(new, j, m)
        new = new[new]
        if np.array_equal(new, labels):
            return labels
        labels = new


def segment_distance(px: FArray, py: FArray, segments: FArray) -> FArray:
    """Distance (m) from each point to the nearest of ``segments`` (S, 2, 2) ends; inf if
    there are none."""
    px, py = np.asarray(px, float).ravel(), np.asarray(py, float).ravel()
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    if len(seg) == 0:
        return np.full(px.size, math.inf)
    a, b = seg[:, 0], seg[:, 1]
    d = b - a
    dd = np.maximum((d * d).sum(axis=1), 1e-12)
    wx = px[:, None] - a[None, :, 0]
    wy = py[:, None] - a[None, :, 1]
    u = np.clip((wx * d[None, :, 0] + wy * d[None, :, 1]) / dd[None, :], 0.0, 1.0)
    ex = wx - u * d[None, :, 0]
    ey = wy - u * d[None, :, 1]
    return np.sqrt(ex * ex + ey * ey).min(axis=1)


@dataclass(frozen=True)
class PointFit:
    """A point target in B: ``centre`` (2,) m, ``covariance`` 2 x 2, its returns ``support``
    (indices into the input), ``n_pings``, the unwrapped directions ``a_min, a_max`` (rad) of
    the pings that saw it and its ``distance`` from their mean transducer position (m)."""

    centre: FArray
    covariance: FArray
    support: FArray
    n_pings: int
    a_min: float
    a_max: float
    distance: float


def extract_points(
    sx: FArray,
    sy: FArray,
    ang: FArray,
    rng: FArray,
    ping: FArray,
    ping_dir: FArray,
    settings: PointSettings,
    sigma_r: FArray | float | None = None,
    step_rad: float | None = None,
    eligible: FArray | None = None,
) -> list[PointFit]:
    """Point targets among returns (B frame: transducer ``sx, sy``, beam direction ``ang``,
    range ``rng``) labelled by ``ping``, whose unwrapped beam direction is
    ``ping_dir[ping]``. ``sigma_r`` range noise (m; default ``settings.sigma_range_m``);
    ``step_rad`` the scan step (default: median step of ``ping_dir``); ``eligible`` which
    returns may form targets (default all; the others, e.g. returns on a line, still count as
    neighbours for the isolation test). Completeness is not judged here (see
    :class:`~auvgw.slam.features.pipeline.SonarFeatureExtractor`)."""
    sx, sy, ang, rng = (np.asarray(v, float).ravel() for v in (sx, sy, ang, rng))
    ping = np.asarray(ping, int).ravel()
    ping_dir = np.asarray(ping_dir, float).ravel()
    if sigma_r is None:
        if settings.sigma_range_m is None:
            raise ValueError("extract_points: sigma_r or settings.sigma_range_m is needed")
        sigma_r = settings.sigma_range_m
    sr = np.broadcast_to(np.asarray(sigma_r, float), sx.shape)
    if step_rad is None:
        steps = np.abs(np.diff(ping_dir))
        steps = steps[steps > 0]
        step_rad = float(np.median(steps)) if steps.size else settings.beam_width_rad
    idx = np.arange(sx.size) if eligible is None else np.flatnonzero(eligible)
    if idx.size < settings.min_returns:
        return []
    px, py = sx + rng * np.cos(ang), sy + rng * np.sin(ang)
    labels = cluster_returns(px[idx], py[idx], settings.link_m)
    big = np.bincount(labels) >= settings.min_returns
    keep = big[labels]
    idx, labels = idx[keep], labels[keep]
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(labels[order])) + 1
    fits = []
    for members in np.split(idx[order], bounds) if idx.size else []:
        pings = np.unique(ping[members])
        if pings.size < settings.min_pings:
            continue
        mx, my = px[members], py[members]
        if not _compact(mx, my, ang[members], rng[members], settings, step_rad):
            continue
        # isolation: no other return (eligible or not) near the cluster
        if settings.isolation_m > 0:
            near = np.hypot(px - mx.mean(), py - my.mean()) <= settings.isolation_m
            near[members] = False
            if near.any():
                continue
        fits.append(_point_fit(members, sx, sy, ang, rng, sr, ping_dir[pings], step_rad,
                               settings))  # fmt: skip
    return fits


def _compact(
    mx: FArray, my: FArray, a: FArray, r: FArray, settings: PointSettings, step: float
) -> bool:
    """Whether returns at ``(mx, my)`` (beam directions ``a``, ranges ``r``) can be one point
    target: at most ``max_extent_m`` along the mean line of sight, and across it at most
    ``max_extent_m`` plus ``(alpha + step) r``. Each return is placed on its beam's axis and a
    target is detected while the beam still covers it, so even a thin pile smears into an arc
    about a beam width (plus a scan step of quantisation) wide: 2.2 m for the harbour's 3 deg
    beam and 1.8 deg step at 26 m, more than the target itself. A wall seen square on, whose
    arc is as wide as the beam pattern and the Lambert fall-off allow, is wider."""
    los = math.atan2(float(np.mean(np.sin(a))), float(np.mean(np.cos(a))))
    c, s = math.cos(los), math.sin(los)
    along = c * mx + s * my
    across = -s * mx + c * my
    footprint = (settings.beam_width_rad + step) * float(np.mean(r))
    return bool(
        np.ptp(along) <= settings.max_extent_m
        and np.ptp(across) <= settings.max_extent_m + footprint
    )


def _point_fit(
    members: FArray,
    sx: FArray,
    sy: FArray,
    ang: FArray,
    rng: FArray,
    sr: FArray,
    dirs: FArray,
    step: float,
    settings: PointSettings,
) -> PointFit:
    n = members.size
    a, r = ang[members], rng[members] + settings.target_radius_m
    cx = float(np.mean(sx[members] + r * np.cos(a)))
    cy = float(np.mean(sy[members] + r * np.sin(a)))
    # mean line of sight from the transducers to the centre
    los = math.atan2(cy - float(np.mean(sy[members])), cx - float(np.mean(sx[members])))
    dist = math.hypot(cx - float(np.mean(sx[members])), cy - float(np.mean(sy[members])))
    var_along = (float(np.mean(sr[members] ** 2)) + (0.5 * settings.target_radius_m) ** 2) / n
    var_bearing = step**2 / 12.0 + settings.beam_width_rad**2 / (12.0 * n)
    var_across = dist**2 * var_bearing
    c, s = math.cos(los), math.sin(los)
    rot = np.array([[c, -s], [s, c]])
    cov = rot @ np.diag([var_along, var_across]) @ rot.T
    return PointFit(
        centre=np.array([cx, cy]),
        covariance=cov,
        support=members,
        n_pings=int(dirs.size),
        a_min=float(dirs.min()),
        a_max=float(dirs.max()),
        distance=dist,
    )


@dataclass(frozen=True)
class PointObservation:
    """A point feature seen from the vehicle at the reference ping.

    ``t`` (s) and vehicle ``pose`` (x, y, heading; pose frame) of the reference ping;
    ``range_m`` and ``bearing`` (rad from the bow, positive to starboard) of the target's
    centre from the vehicle reference point (``auvgw.slam.models.RangeBearing``), with
    ``covariance`` 2 x 2 over (range, bearing); ``position`` (2,) the centre in the pose frame
    and ``position_covariance`` (2 x 2, m^2, without pose uncertainty); ``n_returns``,
    ``n_pings``, ``t_first`` / ``t_last`` (s) of its returns.
    """

    t: float
    pose: FArray
    range_m: float
    bearing: float
    covariance: FArray
    position: FArray
    position_covariance: FArray
    n_returns: int
    n_pings: int
    t_first: float
    t_last: float

    @property
    def z(self) -> FArray:
        """The measurement ``(range, bearing)``."""
        return np.array([self.range_m, self.bearing])

    @classmethod
    def from_fit(
        cls,
        fit: PointFit,
        pose: FArray,
        psi: float,
        origin: FArray,
        t: float,
        t_support: FArray,
        mount: SonarMount,
    ) -> PointObservation:
        """From a fit in B (the head at ``origin`` with forward mark ``psi`` in the pose frame,
        vehicle ``pose``, time ``t``), with its returns' times ``t_support``."""
        # B -> vehicle frame: q_v = m + R(yaw) q_b
        cy_, sy_ = math.cos(mount.yaw_rad), math.sin(mount.yaw_rad)
        rb = np.array([[cy_, -sy_], [sy_, cy_]])
        q = np.array([mount.x_m, mount.y_m]) + rb @ fit.centre
        cov_v = rb @ fit.covariance @ rb.T
        r = float(np.hypot(q[0], q[1]))
        g = np.array([[q[0] / r, q[1] / r], [-q[1] / r**2, q[0] / r**2]])
        cp, sp = math.cos(psi), math.sin(psi)
        rw = np.array([[cp, -sp], [sp, cp]])
        return cls(
            t=float(t),
            pose=np.asarray(pose, float).copy(),
            range_m=r,
            bearing=float(wrap_angle(math.atan2(q[1], q[0]))),
            covariance=g @ cov_v @ g.T,
            position=np.asarray(origin, float) + rw @ fit.centre,
            position_covariance=rw @ fit.covariance @ rw.T,
            n_returns=int(fit.support.size),
            n_pings=fit.n_pings,
            t_first=float(np.min(t_support)),
            t_last=float(np.max(t_support)),
        )
