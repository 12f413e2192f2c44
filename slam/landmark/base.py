"""The common interface of the landmark SLAM filters and the particle-filter machinery they share.

Every filter has the same life cycle, driven by the caller with numpy arrays only:

* ``predict(u, dt, rng)``: one motion step with the measured controls ``u`` (odometry: speed and
  steer for :class:`~auvgw.slam.models.BicycleModel`, body velocities and yaw rate for
  :class:`~auvgw.slam.models.VelocityModel`) over ``dt`` seconds;
* ``update(z, rng, ids=None)``: one scan of ``m`` feature observations ``z (m, 2)`` (range m,
  bearing rad for points); ``ids`` are the true feature identities, used only by the ``known``
  association (simulation). The particle filters also take the keywords ``model`` and ``r``:
  ``model`` (default: the filter's own observation model) is the *kind* of the observations;
  each landmark keeps the kind it was created with and is only associated with, predicted and
  updated by observations of its kind, so one filter carries e.g.
  :class:`~auvgw.slam.models.RangeBearing` points and :class:`~auvgw.slam.models.LineFeature`
  walls on the same particles (both are 2-vectors in the same arrays). ``r`` gives the
  observations' own noise covariances ``(m, 2, 2)`` (e.g. a line fit's covariance) instead of
  the filter's ``R0``; the VB filters then use it as given and keep their noise posteriors for
  the filter's own kind;
* ``estimate()`` the pose ``(x, y, heading)``; ``landmarks()`` the map with covariances;
  ``neff`` the effective sample size at the last update (``nan`` for the EKF family).

Particle filters keep their state in preallocated arrays: poses ``x (N, 3)``, log weights
``logw (N,)``, landmark means ``mu (N, C, 2)``, covariances ``cov (N, C, 2, 2)``, landmark count
``n_lm (N,)``, feature identities ``lm_id (N, C)`` (``-1`` when unknown) and kinds
``lm_kind (N, C)`` (index into ``models``; 0 is the filter's own model); the capacity ``C``
doubles when full. Nothing loops over particles in Python.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from auvgw.slam.landmark.association import (
    Association,
    KnownAssociation,
    NearestNeighbour,
    resolve_conflicts,
)
from auvgw.slam.landmark.unscented import sqrt_psd
from auvgw.slam.models import MotionModel, ObservationModel, wrap_angle
from auvgw.slam.resampling import systematic_resample

__all__ = [
    "LandmarkFilter",
    "LandmarkMap",
    "ParticleFilterSLAM",
    "det2",
    "inv2",
    "systematic_resample",
]

LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class LandmarkMap:
    """Estimated features: ``mean (L, 2)``, ``cov (L, 2, 2)`` and the feature ids ``ids (L,)``
    (``-1`` where the filter does not know the identity, i.e. without known association);
    ``kinds (L,)`` the observation-model index of each feature (0: the filter's own model;
    ``None``: all of the filter's own model)."""

    mean: np.ndarray
    cov: np.ndarray
    ids: np.ndarray
    kinds: np.ndarray | None = None

    def of_kind(self, kind: int) -> LandmarkMap:
        """The features of one kind only."""
        if self.kinds is None:
            return self if kind == 0 else LandmarkMap(
                self.mean[:0], self.cov[:0], self.ids[:0], self.kinds
            )  # fmt: skip
        k = self.kinds == kind
        return LandmarkMap(self.mean[k], self.cov[k], self.ids[k], self.kinds[k])


class LandmarkFilter(ABC):
    """Interface shared by all landmark SLAM filters (see the module docstring)."""

    #: short algorithm name, as accepted by :func:`~auvgw.slam.landmark.make_filter`
    name: str = ""

    @abstractmethod
    def predict(self, u: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        """Advance by one motion step with controls ``u`` over ``dt`` seconds."""

    @abstractmethod
    def update(
        self, z: np.ndarray, rng: np.random.Generator, ids: np.ndarray | None = None
    ) -> None:
        """Fuse one scan of observations ``z (m, 2)``; ``ids`` are true feature ids (known
        association only). The particle filters also take ``model`` and ``r`` (other feature
        kinds, per-observation noise: :meth:`ParticleFilterSLAM.update`)."""

    @abstractmethod
    def estimate(self) -> np.ndarray:
        """Pose estimate ``(x m, y m, heading rad)``."""

    @abstractmethod
    def landmarks(self) -> LandmarkMap:
        """Current map with covariances."""

    @property
    @abstractmethod
    def neff(self) -> float:
        """Effective sample size at the last update (before any resampling)."""


# ----------------------------------------------------------------------------- small linalg
def det2(a: np.ndarray) -> np.ndarray:
    """Determinants of ``(..., 2, 2)`` matrices."""
    return a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]


def inv2(a: np.ndarray) -> np.ndarray:
    """Inverses of ``(..., 2, 2)`` matrices (closed form)."""
    d = det2(a)
    out = np.empty_like(a)
    out[..., 0, 0] = a[..., 1, 1] / d
    out[..., 1, 1] = a[..., 0, 0] / d
    out[..., 0, 1] = -a[..., 0, 1] / d
    out[..., 1, 0] = -a[..., 1, 0] / d
    return out


def quad2(v: np.ndarray, s_inv: np.ndarray) -> np.ndarray:
    """``v^T S^-1 v`` for ``v (..., 2)`` and ``S^-1 (..., 2, 2)``."""
    a = s_inv[..., 0, 0] * v[..., 0] + s_inv[..., 0, 1] * v[..., 1]
    b = s_inv[..., 1, 0] * v[..., 0] + s_inv[..., 1, 1] * v[..., 1]
    return v[..., 0] * a + v[..., 1] * b


def mahalanobis_all(
    obs: ObservationModel, x: np.ndarray, mu: np.ndarray, s: np.ndarray, z: np.ndarray
) -> np.ndarray:
    """Eq. (49): ``D[p, j, l] = v^T S^-1 v`` for observation ``j`` against landmark ``l`` of
    particle ``p``; ``x (N, 3)``, ``mu (N, L, 2)``, ``s (N, L, 2, 2)`` (or ``(N, m, L, 2, 2)``
    with per-observation noise), ``z (m, 2)``."""
    zhat = obs.h(x[:, None, :], mu)  # (N, L, 2)
    v = obs.residual(z[None, :, None, :], zhat[:, None, :, :])  # (N, m, L, 2)
    s_inv = inv2(s)
    return quad2(v, s_inv if s_inv.ndim == 5 else s_inv[:, None])


# ----------------------------------------------------------------------------- particle base
class ParticleFilterSLAM(LandmarkFilter):
    """Rao-Blackwellised particle filter base: storage, association, weights, resampling.

    ``q`` is the control-noise covariance (``n_u x n_u``), ``r`` the nominal observation-noise
    covariance ``R0`` (2 x 2) of ``obs``. Other observation models (kinds) join ``models`` at
    their first :meth:`update` (see the module docstring). Resampling happens when
    ``Neff < resample_fraction * N`` (Bailey: 75 of 100; the VB paper: 75 %)."""

    #: whether this filter carries a pose covariance per particle (EKF/UKF proposal)
    has_pose_cov: bool = False

    def __init__(
        self,
        motion: MotionModel,
        obs: ObservationModel,
        q: np.ndarray,
        r: np.ndarray,
        *,
        n_particles: int = 100,
        x0: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        association: Association | None = None,
        resample_fraction: float = 0.75,
        capacity: int = 64,
    ) -> None:
        self.motion = motion
        self.obs = obs
        self.q = np.asarray(q, dtype=float).reshape(motion.n_u, motion.n_u)
        self.r = np.asarray(r, dtype=float).reshape(2, 2)
        self.n = int(n_particles)
        self.association: Association = association or KnownAssociation()
        self.resample_fraction = float(resample_fraction)
        n = self.n
        self.x = np.tile(np.asarray(x0, dtype=float), (n, 1))
        self.pcov = np.zeros((n, 3, 3)) if self.has_pose_cov else None
        self.logw = np.full(n, -np.log(n))
        cap = max(int(capacity), 4)
        self.mu = np.zeros((n, cap, 2))
        self.cov = np.zeros((n, cap, 2, 2))
        self.lm_id = np.full((n, cap), -1, dtype=np.int64)
        self.lm_kind = np.zeros((n, cap), dtype=np.int8)
        self.n_lm = np.zeros(n, dtype=np.int64)
        #: observation models by kind; ``obs`` (kind 0) is the one of the current update
        self.models: list[ObservationModel] = [obs]
        self._kind = 0
        #: the current update's noise is the caller's ``r`` (the VB filters then keep theirs)
        self._noise_given = False
        self._id_slot: dict[tuple[int, int], int] = {}
        self._neff = float(n)
        self._rows = np.arange(n)
        self._lq = sqrt_psd(self.q, jitter=0.0)
        self.resample_count = 0

    # ---------------------------------------------------------------- interface
    @property
    def neff(self) -> float:
        return self._neff

    def neff_of_weights(self) -> float:
        """Effective sample size of the current weights (after any resampling/reduction)."""
        w = self.weights()
        return float(1.0 / np.sum(w * w))

    def weights(self) -> np.ndarray:
        """Normalised particle weights ``(N,)``."""
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def estimate(self) -> np.ndarray:
        w = self.weights()
        h = self.x[:, 2]
        return np.array(
            [w @ self.x[:, 0], w @ self.x[:, 1], np.arctan2(w @ np.sin(h), w @ np.cos(h))]
        )

    def landmarks(self) -> LandmarkMap:
        """The map: with known association (all particles share slots) the weighted mixture
        moments per feature; otherwise the map of the highest-weight particle."""
        w = self.weights()
        if isinstance(self.association, KnownAssociation):
            k = int(self.n_lm[0])
            mu = self.mu[:, :k]
            kinds = self.lm_kind[0, :k].astype(np.int64)
            mean = np.einsum("p,pli->li", w, mu)
            d = mu - mean
            for i in range(2):
                ang = np.array([m.feature_angular[i] for m in self.models])[kinds]  # (k,)
                if ang.any():  # circular mean: line angles near +-pi must not average to 0
                    s = np.einsum("p,pl->l", w, np.sin(mu[..., i]))
                    c = np.einsum("p,pl->l", w, np.cos(mu[..., i]))
                    mean[:, i] = np.where(ang, np.arctan2(s, c), mean[:, i])
                    d[..., i] = np.where(ang, wrap_angle(mu[..., i] - mean[:, i]), d[..., i])
            cov = np.einsum("p,plij->lij", w, self.cov[:, :k]) + np.einsum(
                "p,pli,plj->lij", w, d, d
            )
            return LandmarkMap(mean, cov, self.lm_id[0, :k].copy(), kinds)
        b = int(np.argmax(w))
        k = int(self.n_lm[b])
        return LandmarkMap(
            self.mu[b, :k].copy(), self.cov[b, :k].copy(), self.lm_id[b, :k].copy(),
            self.lm_kind[b, :k].astype(np.int64),
        )  # fmt: skip

    def update(
        self,
        z: np.ndarray,
        rng: np.random.Generator,
        ids: np.ndarray | None = None,
        *,
        model: ObservationModel | None = None,
        r: np.ndarray | None = None,
    ) -> None:
        """Fuse one scan of observations ``z (m, 2)`` of kind ``model`` (default: the filter's
        own model) with noise ``r (m, 2, 2)`` (default ``R0``; required for another kind)."""
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        m = z.shape[0]
        if m == 0:
            return
        ids_arr = None if ids is None else np.asarray(ids, dtype=np.int64).reshape(-1)
        kind = self.kind_of(model)
        if r is None and kind != 0:
            raise ValueError(
                f"observations of {type(model).__name__} (not the filter's own model) need "
                "their noise covariances r (m, 2, 2)"
            )
        rr = self.r if r is None else np.asarray(r, dtype=float)
        if rr.shape not in ((2, 2), (m, 2, 2)):
            raise ValueError(f"r: one 2 x 2 noise covariance per observation, ({m}, 2, 2)")
        # the update runs with the kind's model and noise in ``obs`` / ``r`` (every subclass
        # hook reads them there), on the landmarks of that kind only
        saved = self.obs, self.r
        self.obs, self.r, self._kind, self._noise_given = self.models[kind], rr, kind, r is not None
        try:
            slots = self._associate(z, ids_arr)
            self._observe(z, slots, ids_arr, rng)
        finally:
            self.obs, self.r = saved
            self._kind, self._noise_given = 0, False
        self._normalise_and_resample(rng)

    def observe_heading(self, psi: float, var: float, rng: np.random.Generator) -> None:
        """An absolute heading measurement ``psi`` (rad, from north towards east; e.g. the INS
        yaw that eq. (3) of the VB paper drives its motion model with) of variance ``var``
        (rad^2): filters with a pose Gaussian per particle (EKF/UKF proposals) condition it
        (``H = [0, 0, 1]``) and weigh with ``N(v; 0, P_hh + var)``, FastSLAM 1.0 weighs with
        ``N(v; 0, var)``; then the usual resampling test."""
        v = wrap_angle(psi - self.x[:, 2])  # (N,)
        s = np.full(self.n, float(var))
        if self.pcov is not None:
            s = s + self.pcov[:, 2, 2]
            k = self.pcov[:, :, 2] / s[:, None]  # (N, 3) Kalman gain
            self.x = self.x + k * v[:, None]
            self.x[:, 2] = wrap_angle(self.x[:, 2])
            self.pcov = self.pcov - k[:, :, None] * self.pcov[:, None, 2, :]
        self.logw = self.logw - 0.5 * (v * v / s + np.log(2 * np.pi * s))
        self._normalise_and_resample(rng)

    def kind_of(self, model: ObservationModel | None) -> int:
        """The kind index of observations of ``model`` (registered on first use; ``None``: the
        filter's own model, 0). Models of the same class are the same kind."""
        if model is None:
            return 0
        for i, known in enumerate(self.models):
            if type(known) is type(model):
                return i
        if len(self.models) >= 127:
            raise ValueError("too many observation models for one filter")
        self.models.append(model)
        return len(self.models) - 1

    # ---------------------------------------------------------------- association
    def _associate(self, z: np.ndarray, ids: np.ndarray | None) -> np.ndarray:
        """Slots ``(N, m)``: ``>= 0`` an existing landmark, ``-1`` new, ``-2`` ignored."""
        a = self.association
        if isinstance(a, KnownAssociation):
            if ids is None:
                raise ValueError("known association needs the observation ids")
            k = self._kind
            row = np.array([self._id_slot.get((k, int(i)), -1) for i in ids], dtype=np.int64)
            return np.broadcast_to(row, (self.n, row.shape[0])).copy()
        if isinstance(a, NearestNeighbour):
            lmax = int(self.n_lm.max())
            if lmax == 0:
                return np.full((self.n, z.shape[0]), -1, dtype=np.int64)
            s = self._association_cov(lmax)
            d = mahalanobis_all(self.obs, self._association_pose(), self.mu[:, :lmax], s, z)
            valid = np.arange(lmax)[None, :] < self.n_lm[:, None]
            valid &= self.lm_kind[:, :lmax] == self._kind
            d = np.where(valid[:, None, :], d, np.inf)
            slots, best = a.assign(d)
            return resolve_conflicts(slots, best)
        raise TypeError(f"{type(a).__name__} association is not supported by particle filters")

    def _association_pose(self) -> np.ndarray:
        return self.x

    def _association_cov(self, lmax: int) -> np.ndarray:
        """Innovation covariances ``(N, lmax, 2, 2)`` of every landmark (for eq. 49);
        ``(N, m, lmax, 2, 2)`` with per-observation noise ``r (m, 2, 2)``."""
        mu = self.mu[:, :lmax]
        x = self._association_pose()[:, None, :]
        hx, hm = self.obs.jacobians(x, mu)
        s = hm @ self.cov[:, :lmax] @ np.swapaxes(hm, -1, -2)
        if self.pcov is not None:
            s = s + hx @ self.pcov[:, None] @ np.swapaxes(hx, -1, -2)
        if self.r.ndim == 3:
            return s[:, None] + self.r[None, :, None]
        return s + self.r

    # ---------------------------------------------------------------- subclass hooks
    @abstractmethod
    def _observe(
        self, z: np.ndarray, slots: np.ndarray, ids: np.ndarray | None, rng: np.random.Generator
    ) -> None:
        """Weights, pose and map update for one scan (slots from :meth:`_associate`)."""

    def _resample_extra(self, idx: np.ndarray) -> None:
        """Reorder subclass per-particle state after resampling."""

    # ---------------------------------------------------------------- shared pieces
    def _gather(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(known mask (N, m), safe slots, mu (N, m, 2), cov (N, m, 2, 2))``."""
        known = slots >= 0
        s = np.where(known, slots, 0)
        r = self._rows[:, None]
        return known, s, self.mu[r, s], self.cov[r, s]

    def _scatter(self, known: np.ndarray, s: np.ndarray, mu: np.ndarray, cov: np.ndarray) -> None:
        ri, ji = np.nonzero(known)
        si = s[ri, ji]
        m = mu[ri, ji]
        self.obs.wrap_feature(m)
        self.mu[ri, si] = m
        c = cov[ri, ji]
        self.cov[ri, si] = 0.5 * (c + np.swapaxes(c, -1, -2))

    def _feature_terms(
        self, x: np.ndarray, mu: np.ndarray, cov: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linearised (EKF) terms of observing landmarks ``mu (N, m, 2)`` from poses
        ``x (N, 3)``: innovation ``v (N, m, 2)``, its covariance without noise
        ``S_f = H_m P H_m^T`` and the cross-covariance ``P H_m^T``. The UKF filters override
        this with the unscented transform (eqs. 37-41)."""
        xb = x[:, None, :]
        zhat = self.obs.h(xb, mu)
        _, hm = self.obs.jacobians(xb, mu)
        v = self.obs.residual(z[None], zhat)
        pmz = cov @ np.swapaxes(hm, -1, -2)
        return v, hm @ pmz, pmz

    @staticmethod
    def _feature_apply(
        mu: np.ndarray,
        cov: np.ndarray,
        v: np.ndarray,
        sf: np.ndarray,
        pmz: np.ndarray,
        r: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Kalman update of landmarks with noise ``r`` (eqs. 42-45): returns ``(mu, cov)``."""
        pzz = sf + r
        k = pmz @ inv2(pzz)
        mu_new = mu + np.einsum("...ij,...j->...i", k, v)
        cov_new = cov - k @ pzz @ np.swapaxes(k, -1, -2)
        return mu_new, cov_new

    def _add_features(
        self,
        z: np.ndarray,
        slots: np.ndarray,
        ids: np.ndarray | None,
        r: np.ndarray | None = None,
    ) -> None:
        """Initialise the features of observations with slot ``-1`` at each particle's pose
        (inverse model; covariance ``G R G^T``, ``r (N, 2, 2)`` per particle, else the scan's
        ``R``: per observation or nominal)."""
        new = slots == -1
        if not new.any():
            return
        cnt = new.sum(axis=1)
        self._ensure_capacity(int((self.n_lm + cnt).max()))
        pos = self.n_lm[:, None] + np.cumsum(new, axis=1) - 1
        ri, ji = np.nonzero(new)
        si = pos[ri, ji]
        if r is not None:
            rr = r[ri]
        elif self.r.ndim == 3:
            rr = self.r[ji]
        else:
            rr = np.broadcast_to(self.r, (ri.size, 2, 2))
        mean, cov = self._init_features(ri, z[ji], rr)
        self.mu[ri, si] = mean
        self.cov[ri, si] = cov
        self.lm_kind[ri, si] = self._kind
        if ids is not None and isinstance(self.association, KnownAssociation):
            self.lm_id[ri, si] = ids[ji]
            for j in np.nonzero(new[0])[0]:
                self._id_slot[(self._kind, int(ids[j]))] = int(pos[0, j])
        self.n_lm += cnt

    def _init_features(
        self, ri: np.ndarray, z: np.ndarray, r: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of new features for particles ``ri`` observed as ``z (M, 2)``
        with noise ``r (M, 2, 2)``."""
        x = self.x[ri]
        g = self.obs.inverse_jacobian(x, z)
        mean = self.obs.inverse(x, z)
        return mean, g @ r @ np.swapaxes(g, -1, -2)

    def _ensure_capacity(self, need: int) -> None:
        cap = self.mu.shape[1]
        if need <= cap:
            return
        new_cap = max(need, 2 * cap)
        n = self.n
        mu = np.zeros((n, new_cap, 2))
        cov = np.zeros((n, new_cap, 2, 2))
        ids = np.full((n, new_cap), -1, dtype=np.int64)
        kinds = np.zeros((n, new_cap), dtype=np.int8)
        mu[:, :cap], cov[:, :cap], ids[:, :cap] = self.mu, self.cov, self.lm_id
        kinds[:, :cap] = self.lm_kind
        self.mu, self.cov, self.lm_id, self.lm_kind = mu, cov, ids, kinds

    def _normalise_and_resample(self, rng: np.random.Generator) -> None:
        lw = self.logw - self.logw.max()
        w = np.exp(lw)
        w /= w.sum()
        self.logw = np.log(np.maximum(w, 1e-300))
        self._neff = float(1.0 / np.sum(w * w))
        self._reduce_degeneracy(w, rng)

    def _reduce_degeneracy(self, w: np.ndarray, rng: np.random.Generator) -> None:
        """Resample (systematic) when ``Neff < resample_fraction * N``."""
        if self._neff < self.resample_fraction * self.n:
            self._resample(systematic_resample(w, rng))

    def _resample(self, idx: np.ndarray) -> None:
        self.x = self.x[idx]
        if self.pcov is not None:
            self.pcov = self.pcov[idx]
        self.mu = self.mu[idx]
        self.cov = self.cov[idx]
        self.lm_id = self.lm_id[idx]
        self.lm_kind = self.lm_kind[idx]
        self.n_lm = self.n_lm[idx]
        self.logw = np.full(self.n, -np.log(self.n))
        self._resample_extra(idx)
        self.resample_count += 1

    def _sample_controls(self, u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Controls plus noise ``N(0, Q)`` per particle ``(N, n_u)``."""
        noise = rng.standard_normal((self.n, self.motion.n_u)) @ self._lq.T
        return u + noise

    @staticmethod
    def _circular_mean_pose(x: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.array(
            [
                w @ x[:, 0],
                w @ x[:, 1],
                wrap_angle(np.arctan2(w @ np.sin(x[:, 2]), w @ np.cos(x[:, 2]))),
            ]
        )
