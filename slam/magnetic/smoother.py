"""MB-SLAM as a batch smoother: the whole run's odometry and beacon sightings solved at once.

Issue 28's third estimator beside the EKF and the first-estimates Jacobian EKF
(:mod:`~auvgw.slam.magnetic.filters`): if MB-SLAM fails on the sparse field because of the EKF's
linearisation (its inconsistency), a nonlinear least-squares smoother over the same data, which
re-linearises every pose and beacon at every iteration and uses the future as well as the past,
should not. It is offline (it needs the whole run) and uses the true association (each
sighting's beacon id), so it bounds what any MB-SLAM estimator can get from these data.

Unknowns: the pose ``(x, y, heading)`` at the start and at every scan (NED, m, rad) and each
sighted beacon ``(x, y)``. Factors (whitened residuals):

* start: the known initial pose (weight ``1e3``), as the filters' ``P0 = 0``;
* odometry between consecutive scans: the controls of the steps between them composed from the
  origin with the motion model (eqs. 19-20), ``d``, with covariance ``S`` propagated through its
  Jacobians from zero; residual ``[R(-phi_a) (p_b - p_a) - d_xy, wrap(phi_b - phi_a - d_phi)]``
  in the frame of the earlier pose, whitened by ``S^-1/2``;
* sighting: eq. (21)'s range and bearing, residual ``z - h`` whitened by ``R^-1/2``, Jacobian
  eq. (22) (:class:`~auvgw.slam.models.RangeBearing`).

Solved by Levenberg-Marquardt on the sparse normal equations from dead reckoning's poses (and
each beacon where its first sighting puts it), the initial guess an online smoother would have.
Pose marginals for the NEES come from the final information matrix (every ``nees_every``-th
scan).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from auvgw.slam.models import MotionModel, RangeBearing, wrap_angle

__all__ = ["SmootherResult", "odometry_increments", "smooth"]


@dataclass
class SmootherResult:
    """Poses ``(n + 1, 3)`` (the start, then every scan), beacons ``(B, 2)`` with their ids and
    2x2 marginal covariances, the scans ``nees_scans`` whose pose marginals ``pose_cov (k, 3, 3)``
    were computed, iterations run and the final cost (half the sum of squared whitened
    residuals)."""

    poses: np.ndarray
    beacons: np.ndarray
    beacon_ids: np.ndarray
    beacon_cov: np.ndarray
    nees_scans: np.ndarray
    pose_cov: np.ndarray
    iterations: int
    cost: float


def odometry_increments(
    motion: MotionModel, controls: np.ndarray, q: np.ndarray, dt: float, bounds: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The controls ``bounds[j] .. bounds[j + 1] - 1`` composed from the origin: increments
    ``(S, 3)`` in the frame of the segment's first pose and their covariances ``(S, 3, 3)``
    (``Q`` propagated through eq. 20's Jacobians from zero). All segments at once."""
    starts, ends = bounds[:-1], bounds[1:]
    n_seg = len(starts)
    x = np.zeros((n_seg, 3))
    p = np.zeros((n_seg, 3, 3))
    for m in range(int((ends - starts).max())):
        on = starts + m < ends
        u = controls[np.minimum(starts + m, len(controls) - 1)]
        fx, fu = motion.jacobians(x, u, dt)
        pn = fx @ p @ fx.transpose(0, 2, 1) + fu @ q @ fu.transpose(0, 2, 1)
        xn = motion.f(x, u, dt, wrap=False)
        x = np.where(on[:, None], xn, x)
        p = np.where(on[:, None, None], pn, p)
    return x, p


def _whiteners(cov: np.ndarray) -> np.ndarray:
    """``W`` with ``W^T W = cov^-1`` for each ``cov (k, n, n)``."""
    return np.linalg.inv(np.linalg.cholesky(cov))


def smooth(
    motion: MotionModel,
    controls: np.ndarray,
    q: np.ndarray,
    r: np.ndarray,
    dt: float,
    x0: np.ndarray,
    obs_step: np.ndarray,
    z: list[np.ndarray],
    ids: list[np.ndarray],
    max_iter: int = 200,
    nees_every: int = 25,
    chunk: int = 250,
) -> SmootherResult:
    """Smooth one run: ``controls (K, n_u)`` with noise ``q``, scans after steps ``obs_step
    (n,)`` with sightings ``z[i] (m, 2)`` (range m, bearing rad) of beacons ``ids[i] (m,)``,
    noise ``r`` (2x2), start pose ``x0`` (module docstring)."""
    n = len(obs_step)
    bounds = np.r_[0, np.asarray(obs_step, int)]
    d, s = odometry_increments(motion, controls, np.asarray(q, float), dt, bounds)
    w_odo = _whiteners(s + 1e-12 * np.eye(3))
    # sightings: node (scan + 1), beacon column, z
    node = np.concatenate([np.full(len(zz), i + 1) for i, zz in enumerate(z)]).astype(int)
    bid = np.concatenate([np.asarray(b, int) for b in ids]) if len(ids) else np.zeros(0, int)
    zs = np.concatenate([np.asarray(zz, float).reshape(-1, 2) for zz in z])
    beacon_ids, col = np.unique(bid, return_inverse=True)
    n_b = len(beacon_ids)
    w_obs = _whiteners(np.asarray(r, float).reshape(1, 2, 2))[0]
    rb = RangeBearing()
    poses = np.asarray(x0, float).reshape(1, 3).copy()
    beacons = np.zeros((n_b, 2))
    seen = np.zeros(n_b, bool)
    it_total, cost = 0, 0.0
    # incremental: each chunk starts where the last solution left off
    for end in [*range(chunk, n, chunk), n]:
        grow = np.empty((end + 1 - len(poses), 3))
        for j in range(len(grow)):  # dead reckoning from the last solved pose
            a = poses[-1] if j == 0 else grow[j - 1]
            k = len(poses) - 1 + j
            c, sn = math.cos(a[2]), math.sin(a[2])
            grow[j] = (a[0] + c * d[k, 0] - sn * d[k, 1], a[1] + sn * d[k, 0] + c * d[k, 1],
                       a[2] + d[k, 2])  # fmt: skip
        poses = np.vstack([poses, grow])
        use = node <= end
        fresh = np.nonzero(use & ~seen[col])[0]
        if len(fresh):
            first = fresh[np.unique(col[fresh], return_index=True)[1]]
            beacons[col[first]] = rb.inverse(poses[node[first]], zs[first])
            seen[col[first]] = True
        poses, beacons, cost, it, jac = _levenberg_marquardt(
            poses,
            beacons,
            d[:end],
            w_odo[:end],
            np.asarray(x0, float),
            node[use],
            col[use],
            zs[use],
            w_obs,
            n_b,
            max_iter,
        )
        it_total += it
    n_var = 3 * (n + 1) + 2 * n_b
    lu = splu((jac.T @ jac).tocsc())
    scans = np.arange(0, n, nees_every)
    pose_cov = np.empty((len(scans), 3, 3))
    for k, i in enumerate(scans):
        e = np.zeros((n_var, 3))
        e[3 * (i + 1) + np.arange(3), np.arange(3)] = 1.0
        pose_cov[k] = lu.solve(e)[3 * (i + 1) : 3 * (i + 2)]
    beacon_cov = np.empty((n_b, 2, 2))
    for j in range(n_b):
        e = np.zeros((n_var, 2))
        e[3 * (n + 1) + 2 * j + np.arange(2), np.arange(2)] = 1.0
        beacon_cov[j] = lu.solve(e)[3 * (n + 1) + 2 * j : 3 * (n + 1) + 2 * j + 2]
    poses[:, 2] = wrap_angle(poses[:, 2])
    return SmootherResult(poses, beacons, beacon_ids, beacon_cov, scans, pose_cov, it_total, cost)


def _levenberg_marquardt(
    poses: np.ndarray,
    beacons: np.ndarray,
    d: np.ndarray,
    w_odo: np.ndarray,
    x0: np.ndarray,
    node: np.ndarray,
    col: np.ndarray,
    zs: np.ndarray,
    w_obs: np.ndarray,
    n_b: int,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray, float, int, sp.csr_matrix]:
    """Levenberg-Marquardt over ``len(d) + 1`` poses and ``n_b`` beacons (module docstring);
    returns the solution, its cost, the iterations and the final Jacobian."""
    n = len(d)
    n_var = 3 * (n + 1) + 2 * n_b
    rb = RangeBearing()

    def linearise(poses: np.ndarray, beacons: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        a, b = poses[:-1], poses[1:]
        c, sn = np.cos(a[:, 2]), np.sin(a[:, 2])
        dp = b[:, :2] - a[:, :2]
        e = np.stack([c * dp[:, 0] + sn * dp[:, 1] - d[:, 0],
                      -sn * dp[:, 0] + c * dp[:, 1] - d[:, 1],
                      wrap_angle(b[:, 2] - a[:, 2] - d[:, 2])], axis=1)  # fmt: skip
        ja = np.zeros((n, 3, 3))
        ja[:, 0, 0], ja[:, 0, 1] = -c, -sn
        ja[:, 1, 0], ja[:, 1, 1] = sn, -c
        ja[:, 0, 2] = -sn * dp[:, 0] + c * dp[:, 1]
        ja[:, 1, 2] = -c * dp[:, 0] - sn * dp[:, 1]
        ja[:, 2, 2] = -1.0
        jb = np.zeros((n, 3, 3))
        jb[:, 0, 0], jb[:, 0, 1] = c, sn
        jb[:, 1, 0], jb[:, 1, 1] = -sn, c
        jb[:, 2, 2] = 1.0
        res = [1e3 * (poses[0] - x0), np.einsum("kij,kj->ki", w_odo, e).ravel()]
        rows = [np.arange(3)]
        cols = [np.arange(3)]
        vals = [np.full(3, 1e3)]
        r0 = 3 + 3 * np.arange(n)
        for blk, c0 in ((w_odo @ ja, 3 * np.arange(n)), (w_odo @ jb, 3 + 3 * np.arange(n))):
            rows.append(np.repeat(r0[:, None] + np.arange(3), 3, axis=1).ravel())
            cols.append(np.tile(c0[:, None] + np.arange(3), 3).ravel())
            vals.append(blk.ravel())
        if len(zs):
            v = zs - rb.h(poses[node], beacons[col])
            v[:, 1] = wrap_angle(v[:, 1])
            hx, hm = rb.jacobians(poses[node], beacons[col])
            res.append((v @ w_obs.T).ravel())
            ro = 3 + 3 * n + 2 * np.arange(len(zs))
            for blk, c0, k in ((-w_obs @ hx, 3 * node, 3), (-w_obs @ hm, 3 * (n + 1) + 2 * col, 2)):
                rows.append(np.repeat(ro[:, None] + np.arange(2), k, axis=1).ravel())
                cols.append(np.tile(c0[:, None] + np.arange(k), 2).ravel())
                vals.append(blk.ravel())
        jac = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 + 3 * n + 2 * len(zs), n_var),
        )
        return np.concatenate(res), jac

    lam, it = 1e-3, 0
    res, jac = linearise(poses, beacons)
    cost = 0.5 * float(res @ res)
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        h = (jac.T @ jac).tocsc()
        g = jac.T @ res
        step = splu((h + lam * sp.diags(h.diagonal() + 1e-9)).tocsc()).solve(-g)
        p_new = poses + step[: 3 * (n + 1)].reshape(-1, 3)
        b_new = beacons + step[3 * (n + 1) :].reshape(-1, 2)
        r_new, j_new = linearise(p_new, b_new)
        c_new = 0.5 * float(r_new @ r_new)
        if c_new < cost:
            done = cost - c_new < 1e-6 * cost
            poses, beacons, res, jac, cost = p_new, b_new, r_new, j_new, c_new
            lam = max(lam / 10, 1e-9)
            if done:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return poses, beacons, cost, it, jac
