"""Incremental AMB-SLAM: the core of the online magnetic stage, without any transport.

Inputs arrive one by one, each kind in time order (any interleaving between kinds):

* :meth:`MagneticOnline.add_mag` - one MS3A sample (body axes, nT) with the INS attitude at its
  time. It is rotated to NED at once and buffered; every ``hop_s`` a window of ``window_s`` is
  demodulated (:func:`~auvgw.slam.magnetic.demod.demodulate`), gated and ranged by the MLP
  (:func:`~auvgw.slam.magnetic.evaluation.gate_observations`). The observation belongs to the
  window *centre*, ``window_s / 2`` in the past;
* :meth:`MagneticOnline.add_odometry` - one motion increment (controls ``u`` over ``dt``,
  ending at ``t``);
* :meth:`MagneticOnline.add_acoustic` - one acoustic fix (horizontal range, bearing, 2x2 R).

The filter runs at the *horizon*: the newest window centre (``window_s / 2`` behind the newest
magnetometer sample); every event up to it is applied in time order (prediction, acoustic
anchor update, beacon updates), so each beacon observation meets the pose of its own time.
:meth:`MagneticOnline.pose` is the filter's pose propagated with the odometry not applied yet
(mean and 3x3 covariance): the published estimate is current, the map half a window old.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from auvgw.slam.magnetic.demod import DemodConfig, demodulate, rotate_to_ned
from auvgw.slam.magnetic.evaluation import Variant, gate_observations
from auvgw.slam.magnetic.filters import MagneticSLAM
from auvgw.slam.magnetic.mlp import MLP
from auvgw.slam.models import VelocityModel

__all__ = ["BeaconObservation", "MagneticOnline"]


@dataclass(frozen=True)
class BeaconObservation:
    """One demodulated, ranged beacon observation: window centre ``t`` (s), channel ``freq``
    (Hz), amplitude vector ``amp_nt`` (NED), ``snr``, ``z`` (range m, bearing rad from the
    heading) and its covariance ``r``."""

    t: float
    freq: float
    amp_nt: tuple[float, float, float]
    snr: float
    z: tuple[float, float]
    r: tuple[tuple[float, float], tuple[float, float]]


@dataclass
class MagneticOnline:
    """See the module docstring. ``channels`` the beacon frequencies (Hz)."""

    filt: MagneticSLAM
    net: MLP
    channels: np.ndarray
    cfg: DemodConfig = field(default_factory=DemodConfig)
    gates: Variant = field(default_factory=Variant)

    def __post_init__(self) -> None:
        self._t: list[float] = []
        self._b: list[np.ndarray] = []
        self._h: list[float] = []
        self._next_centre: float | None = None
        self._events: list[tuple[float, int, int, tuple[object, ...]]] = []
        self._seq = itertools.count()
        self.horizon = -np.inf
        self.n_observations = 0

    # ------------------------------------------------------------------ inputs
    def add_mag(
        self, t: float, b_body: np.ndarray, heading: float, pitch: float, roll: float
    ) -> list[BeaconObservation]:
        """One magnetometer sample; returns the observations of the windows it completed."""
        if self._t and t <= self._t[-1]:
            raise ValueError(f"magnetometer sample at {t} s after {self._t[-1]} s: out of order")
        ned = rotate_to_ned(
            np.asarray(b_body, float), np.array([heading]), np.array([pitch]), np.array([roll])
        )[0]
        self._t.append(float(t))
        self._b.append(ned)
        self._h.append(float(heading))
        half = self.cfg.window_s / 2
        if self._next_centre is None:
            self._next_centre = float(t) + half
        out: list[BeaconObservation] = []
        while t >= self._next_centre + half:
            out += self._window(self._next_centre)
            self.horizon = self._next_centre
            self._next_centre += self.cfg.hop_s
        self._trim(self._next_centre - half)
        self._run()
        return out

    def add_odometry(self, t: float, u: np.ndarray, dt: float, q_scale: float = 1.0) -> None:
        """One motion increment (controls of the filter's motion model) ending at ``t``;
        ``q_scale`` scales the filter's control noise ``Q`` for this step (``1/n`` for ``n``
        increments composed into one: the same position variance as ``n`` steps)."""
        self._push(t, 0, (np.asarray(u, float), float(dt), float(q_scale)))
        self._run()

    def add_acoustic(self, t: float, z: np.ndarray, r: np.ndarray) -> None:
        """One acoustic fix at ``t``: horizontal range m and bearing rad (or range only)."""
        self._push(t, 1, (np.asarray(z, float), np.asarray(r, float)))
        self._run()

    # ------------------------------------------------------------------ outputs
    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Current pose ``(x, y, heading)`` and its 3x3 covariance: the filter's, propagated
        with the odometry beyond the horizon."""
        x = self.filt.xs[:3].copy()
        p = self.filt.p[:3, :3].copy()
        m = self.filt.motion
        steps = [e[3] for e in sorted(self._events) if e[1] == 0]
        if isinstance(m, VelocityModel):  # the stage's model: scalar steps, no array overhead
            return _velocity_steps(x, p, steps, np.asarray(self.filt.q, float))
        for u, dt, qs in steps:
            fx, fu = m.jacobians(x, u, dt)  # type: ignore[arg-type]
            x = m.f(x, u, dt)  # type: ignore[arg-type]
            p = fx @ p @ fx.T + fu @ (self.filt.q * qs) @ fu.T
        return x, p

    # ------------------------------------------------------------------ internals
    def _push(self, t: float, kind: int, payload: tuple[object, ...]) -> None:
        heapq.heappush(self._events, (float(t), kind, next(self._seq), payload))

    def _window(self, centre: float) -> list[BeaconObservation]:
        t = np.array(self._t)
        sel = (t >= centre - self.cfg.window_s / 2) & (t < centre + self.cfg.window_s / 2)
        dem = demodulate(
            t[sel], np.array(self._b)[sel], self.channels, self.cfg, np.array([centre])
        )
        if len(dem.t) == 0:
            return []
        heading = np.interp(dem.t, t, np.unwrap(np.array(self._h)))
        w, c, z, r = gate_observations(dem, self.net, heading, self.gates)
        out = []
        for j in range(len(w)):
            self._push(float(dem.t[w[j]]), 2, (z[j], r[j]))
            out.append(BeaconObservation(
                t=float(dem.t[w[j]]), freq=float(dem.freqs[c[j]]),
                amp_nt=tuple(dem.amp[w[j], c[j]].tolist()),
                snr=float(dem.snr[w[j], c[j]]), z=(float(z[j, 0]), float(z[j, 1])),
                r=((float(r[j, 0, 0]), float(r[j, 0, 1])), (float(r[j, 1, 0]), float(r[j, 1, 1]))),
            ))  # fmt: skip
        self.n_observations += len(out)
        return out

    def _trim(self, t_min: float) -> None:
        k = int(np.searchsorted(self._t, t_min))
        if k > 0:
            del self._t[:k], self._b[:k], self._h[:k]

    def _run(self) -> None:
        rng = np.random.default_rng(0)
        while self._events and self._events[0][0] <= self.horizon:
            _, kind, _, payload = heapq.heappop(self._events)
            if kind == 0:
                u, dt, qs = payload
                q = self.filt.q
                self.filt.q = q * qs
                try:
                    self.filt.predict(u, dt, rng)  # type: ignore[arg-type]
                finally:
                    self.filt.q = q
            elif kind == 1:
                if self.filt.anchor is not None:
                    z, r = payload
                    self.filt.anchor_update(z, r)  # type: ignore[arg-type]
            else:
                z, r = payload
                self.filt.update_each(np.asarray(z)[None], np.asarray(r)[None])


def _velocity_steps(
    x: np.ndarray, p: np.ndarray, steps: list[tuple[object, ...]], q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:class:`VelocityModel` predictions of ``(x, y, heading)`` and its 3x3 covariance over
    ``steps`` ``(u, dt, q_scale)``: the model's ``f`` and Jacobians written out for one pose
    (the same numbers, without the per-call array overhead)."""
    px, py, h = (float(v) for v in x)
    for u, dt, qs in steps:
        vx, vy, w = (float(v) * dt for v in u)  # type: ignore[attr-defined, operator]
        s, c = math.sin(h), math.cos(h)
        fx = np.array([[1.0, 0.0, -vx * s - vy * c], [0.0, 1.0, vx * c - vy * s], [0, 0, 1.0]])
        fu = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) * dt
        p = fx @ p @ fx.T + fu @ (q * qs) @ fu.T
        px, py, h = px + vx * c - vy * s, py + vx * s + vy * c, h + w
    return np.array([px, py, math.remainder(h, math.tau)]), p
