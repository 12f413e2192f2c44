"""The fusion stage: samples in (any order within the latency bound), odometry out at INS rate.

:class:`NavFilter` is the one object used online (the bus stage feeds it decoded messages as they
arrive) and offline (:func:`auvgw.fusion.offline.run_filter` feeds it arrays). It owns a
:class:`~auvgw.fusion.align.ReorderBuffer` (fixed lag ``max_latency_s``), a
:class:`~auvgw.fusion.ekf.DeadReckoningEKF` and the bottom-lock policy:

* a DVL fix without bottom lock (or without any valid component) is not used; the filter is
  *coasting* from then on, and also when no fix was accepted for ``dvl_timeout_s``;
* while coasting the body velocity is held at its last estimate (no acceleration integration)
  with the larger ``coast_velocity_random_walk``, so the velocity and position covariance grow;
* when lock returns, the next fix is an ordinary update (its large prior covariance lets it
  through the gate); after ``dvl_gate_max_rejections`` consecutive gate rejections the velocity
  covariance is re-initialised and the next fix accepted (re-acquisition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from auvgw.fusion.align import AidingSample, BufferStats, ReorderBuffer, interpolate_ins
from auvgw.fusion.config import FusionConfig
from auvgw.fusion.deviation import CompassDeviationEstimator
from auvgw.fusion.diagnostics import FixRecord, FusionDiagnostics
from auvgw.fusion.ekf import DeadReckoningEKF
from auvgw.fusion.frames import beam_to_instrument, dcm_body_to_ned, wrap_angle
from auvgw.fusion.odometry import MotionIncrement, Odometry
from auvgw.fusion.samples import DepthSample, DvlFrame, DvlSample, InsSample, PositionFix

__all__ = ["FusionStats", "NavFilter"]


@dataclass
class FusionStats:
    """Counters of one filter run (samples)."""

    ins_used: int = 0
    ins_bad: int = 0  #: non-finite INS samples (dropped)
    ins_gaps: int = 0  #: INS intervals longer than max_ins_gap_s
    dvl_updates: int = 0
    dvl_rejected: int = 0  #: failed the innovation gate
    dvl_reacquired: int = 0  #: forced acceptances after repeated rejections
    dvl_no_lock: int = 0  #: fixes without bottom lock or without a valid component
    depth_updates: int = 0
    position_updates: int = 0
    position_rejected: int = 0  #: position fixes that failed their gate


@dataclass
class _Gate:
    """Consecutive gate rejections of one kind of fix: after ``limit`` of them the next fix is
    forced through (re-acquisition)."""

    limit: int
    rejections: int = 0

    @property
    def force(self) -> bool:
        return self.rejections >= self.limit

    def passed(self, ok: bool) -> bool:
        """Count the outcome of one update; returns ``ok``."""
        self.rejections = 0 if ok else self.rejections + 1
        return ok


class NavFilter:
    """INS + DVL (+ depth) dead reckoning; see the module docstring for the policies.

    ``push*`` return the :class:`Odometry` outputs that became final (INS samples older than the
    newest INS time minus ``max_latency_s``), oldest first; :meth:`flush` releases the rest.
    """

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self.buffer = ReorderBuffer(self.config.max_latency_s, self.config.max_pending)
        self.stats = FusionStats()
        self.ekf: DeadReckoningEKF | None = None
        self.last: Odometry | None = None
        self._ins: InsSample | None = None
        self._lock = False
        self._last_fix_t = -math.inf
        self._last_depth_t = -math.inf
        self._dvl_gate = _Gate(self.config.dvl_gate_max_rejections)
        self._position_gate = _Gate(self.config.dvl_gate_max_rejections)
        self._heading_corr = self.config.heading_correction()
        self._declination = math.radians(self.config.magnetic_declination_deg)
        self.diagnostics = FusionDiagnostics(self.config.diagnostics_window_s)
        self.deviation = (
            None
            if self.config.compass_deviation == "off"
            else CompassDeviationEstimator.from_config(self.config)
        )
        self.diagnostics.compass_deviation = self.deviation
        # back-correction of the past deviation (see _back_correct): sum of J dp phi^T (2 x 4,
        # row-major), sum of J dp d_applied, the shift applied so far, this step's d_applied
        self._dev_S = [0.0] * 8
        self._dev_a = [0.0, 0.0]
        self._dev_shift = (0.0, 0.0)
        self._dev_d = 0.0
        self._dev_updates = 0

    @property
    def buffer_stats(self) -> BufferStats:
        return self.buffer.stats

    # ---- input --------------------------------------------------------------------------
    def push(self, sample: InsSample | DvlSample | DepthSample | PositionFix) -> list[Odometry]:
        """Buffer any sample; return the outputs that became final."""
        if isinstance(sample, InsSample):
            return self.push_ins(sample)
        if isinstance(sample, DvlSample | DepthSample | PositionFix):
            self.buffer.add_aiding(sample)
            return []
        raise TypeError(f"NavFilter cannot use a {type(sample).__name__}")

    def push_ins(self, sample: InsSample) -> list[Odometry]:
        """Buffer an INS sample (non-finite ones are counted and dropped); return the outputs
        that became final."""
        if not sample.is_finite():
            self.stats.ins_bad += 1
            return []
        if self._heading_corr:
            sample = sample._replace(heading=wrap_angle(sample.heading + self._heading_corr))
        self.buffer.add_ins(sample)
        return self._drain(flush=False)

    def push_dvl(self, sample: DvlSample) -> list[Odometry]:
        """Buffer a DVL fix (used when the INS has moved past its time)."""
        return self.push(sample)

    def push_depth(self, sample: DepthSample) -> list[Odometry]:
        """Buffer a pressure depth (used when the INS has moved past its time)."""
        return self.push(sample)

    def flush(self) -> list[Odometry]:
        """Process everything buffered (end of a recording, or shutdown)."""
        return self._drain(flush=True)

    # ---- processing ---------------------------------------------------------------------
    def coasting(self, t: float) -> bool:
        """Bottom-lock policy at time ``t``: no lock, or no accepted DVL fix for the timeout."""
        return (not self._lock) or (t - self._last_fix_t > self.config.dvl_timeout_s)

    def _drain(self, flush: bool) -> list[Odometry]:
        out = []
        for ins, events in self.buffer.release(flush):
            if self.deviation is not None:
                ins = self._correct_deviation(ins)
            if self.ekf is None:
                self.ekf = DeadReckoningEKF(self.config, ins)
                self._ins = ins
                for e in events:  # only those exactly at the first INS time
                    self._apply(e, ins)
                out.append(self._output(ins, None, gap=False))
            else:
                out.append(self._step(ins, events))
        return out

    def _correct_deviation(self, ins: InsSample) -> InsSample:
        """Feed the deviation estimate with the magnetic heading (the source's heading with the
        configured offset, without the declination: the deviation is a function of the magnetic
        heading) and subtract the estimated deviation where it is confident."""
        est = self.deviation
        assert est is not None
        compass = wrap_angle(ins.heading - self._declination)
        est.add(ins.t, compass, ins.roll, ins.pitch, ins.rates)
        d = est.correction(compass)
        self._dev_d = d
        return ins._replace(heading=wrap_angle(ins.heading - d)) if d else ins

    def _back_correct(self, p0: tuple[float, float, float]) -> None:
        """Correct the position for the deviation of the past steps, as far as the estimate
        has improved since (the linearised effect of a heading error ``eps`` on a displacement
        ``dp`` is ``eps J dp``, ``J`` the 90 deg rotation; the same cross-term an EKF with the
        coefficients as states would build): accumulate ``S = sum J dp phi^T`` and ``a = sum
        d_applied J dp``; once the estimate is confident at every heading, shift the position by
        ``-(S c - a)`` (what is not shifted yet)."""
        est, ekf = self.deviation, self.ekf
        if est is None or not self.config.compass_deviation_back_correct:
            return
        assert ekf is not None
        p1 = ekf.position()
        jn, je = p0[1] - p1[1], p1[0] - p0[0]  # J dp
        S, a, d = self._dev_S, self._dev_a, self._dev_d
        for i, f in enumerate(est.last_phi):
            S[i] += jn * f
            S[4 + i] += je * f
        a[0] += d * jn
        a[1] += d * je
        if est.updates == self._dev_updates or not est.confident_everywhere():
            return
        self._dev_updates = est.updates
        c = est.x[2:].tolist()
        tn = a[0] - sum(s * ci for s, ci in zip(S[:4], c, strict=True))
        te = a[1] - sum(s * ci for s, ci in zip(S[4:], c, strict=True))
        ekf.shift_position(tn - self._dev_shift[0], te - self._dev_shift[1])
        self._dev_shift = (tn, te)

    def _step(self, s: InsSample, events: list[AidingSample]) -> Odometry:
        ekf = self.ekf
        a = self._ins
        assert ekf is not None and a is not None
        p0 = ekf.position()
        if not events:  # the usual INS step
            inc_cov = ekf.propagate(a, s, self.coasting(a.t))
        else:
            cur = a
            inc_cov = np.zeros((3, 3))
            for e in events:
                if e.t > cur.t:
                    mid = interpolate_ins(a, s, e.t)
                    inc_cov = inc_cov + ekf.propagate(cur, mid, self.coasting(cur.t))
                    cur = mid
                self._apply(e, cur)
            if s.t > cur.t:
                inc_cov = inc_cov + ekf.propagate(cur, s, self.coasting(cur.t))
        self._ins = s
        self._back_correct(p0)
        gap = s.t - a.t > self.config.max_ins_gap_s
        if gap:
            self.stats.ins_gaps += 1
        self.stats.ins_used += 1
        return self._output(s, inc_cov, gap)

    def _apply(self, e: AidingSample, ins: InsSample) -> None:
        """Apply one aiding sample at its own time; ``ins`` is the INS state at ``e.t``."""
        ekf = self.ekf
        assert ekf is not None
        cfg = self.config
        if isinstance(e, DvlSample):
            vel, frame = self._dvl_velocity(e, ins)
            has_v = e.bottom_lock and any(math.isfinite(c) for c in vel)
            self._lock = has_v
            if has_v:
                force = self._dvl_gate.force
                if force:
                    ekf.reset_velocity_covariance(cfg.initial.velocity_sigma_mps)
                    self.stats.dvl_reacquired += 1
                speed = math.sqrt(sum(c * c for c in ekf.velocity_body()))
                sigma = e.fom if math.isfinite(e.fom) else cfg.dvl_sigma(speed)
                ok, nis, norm = ekf.update_dvl(vel, frame, ins.rates, force=force, sigma=sigma)
                self.diagnostics.add_fix(
                    FixRecord(
                        e.t, ok, force, nis, int(np.isfinite(norm).sum()), tuple(norm.tolist())
                    )
                )
                self.diagnostics.noise_sigma = ekf.dvl_noise_sigma()
                if self._dvl_gate.passed(ok):
                    self._last_fix_t = e.t
                    self.stats.dvl_updates += 1
                else:
                    self.stats.dvl_rejected += 1
            else:
                self.stats.dvl_no_lock += 1
            if math.isfinite(e.depth):
                ekf.update_depth(e.depth, cfg.depth_sigma_m, cfg.dvl.lever_arm_m, ins)
                self._last_depth_t = e.t
                self.stats.depth_updates += 1
        elif isinstance(e, PositionFix):
            if not (math.isfinite(e.north) and math.isfinite(e.east) and e.sigma_m > 0):
                return
            ok, _ = ekf.update_position(
                e.north, e.east, e.sigma_m, force=self._position_gate.force
            )
            if self._position_gate.passed(ok):
                self.stats.position_updates += 1
            else:
                self.stats.position_rejected += 1
        else:
            if not math.isfinite(e.depth):
                return
            sigma = e.sigma if math.isfinite(e.sigma) else cfg.depth_sigma_m
            ekf.update_depth(e.depth, sigma, cfg.depth_lever_arm_m, ins)
            self._last_depth_t = e.t
            self.stats.depth_updates += 1

    def _dvl_velocity(self, e: DvlSample, ins: InsSample) -> tuple[tuple[float, ...], DvlFrame]:
        """A fix's velocity in the axes the EKF takes ("instrument" or "body"), corrected for
        the scale factor: beam speeds by least squares (Janus geometry of the mount), earth
        (NED) velocities turned into body axes with the filter's attitude at the fix time."""
        mount = self.config.dvl
        k = 1.0 / mount.scale_factor
        frame = e.frame
        if frame == "beam":
            if len(e.velocity) != 4:  # not a 4-beam record: no valid component (no lock)
                return (math.nan, math.nan, math.nan), "instrument"
            v = beam_to_instrument(
                e.velocity, math.radians(mount.beam_angle_deg), mount.beam_convex
            )
            return tuple((k * v).tolist()), "instrument"
        if frame == "earth":
            ekf = self.ekf
            assert ekf is not None
            C = dcm_body_to_ned(ins.roll, ekf.pitch(ins), ekf.heading(ins))
            v = C.T @ np.asarray(e.velocity[:3], dtype=float)
            return tuple((k * v).tolist()), "body"
        if k != 1.0:
            return tuple(k * c for c in e.velocity[:3]), frame
        return e.velocity, frame

    def _output(self, s: InsSample, inc_cov: np.ndarray | None, gap: bool) -> Odometry:
        ekf = self.ekf
        assert ekf is not None
        P = ekf.P.copy()
        P.flags.writeable = False
        psi = ekf.heading(s)
        th = ekf.pitch(s)
        u, v, w = ekf.velocity_body()
        px, py, pz = ekf.position()
        cr, sr = math.cos(s.roll), math.sin(s.roll)
        cp, sp = math.cos(th), math.sin(th)
        ch, sh = math.cos(psi), math.sin(psi)
        lx = cp * u + sp * (sr * v + cr * w)
        ly = cr * v - sr * w
        lz = -sp * u + cp * (sr * v + cr * w)
        prev = self.last
        inc = None
        if prev is not None and inc_cov is not None:
            inc = _increment(prev, s.t, px, py, pz, psi, inc_cov)
        odo = Odometry(
            t=s.t,
            x=px,
            y=py,
            z=pz,
            roll=s.roll,
            pitch=th,
            heading=psi,
            velocity_ned=(ch * lx - sh * ly, sh * lx + ch * ly, lz),
            velocity_body=(u, v, w),
            angular_rate=s.rates,
            covariance=P,
            bottom_lock=self._lock,
            coasting=self.coasting(s.t),
            dvl_age_s=_age(s.t, self._last_fix_t),
            depth_age_s=_age(s.t, self._last_depth_t),
            ins_gap=gap,
            increment=inc,
        )
        self.diagnostics.add_output(s.t, odo.coasting)
        self.last = odo
        return odo


def _age(t: float, since: float) -> float:
    return t - since if since > -math.inf else math.nan


def _increment(
    prev: Odometry, t1: float, x: float, y: float, z: float, psi: float, cov_ned: np.ndarray
) -> MotionIncrement:
    """The motion from ``prev`` to the new pose, in the level body frame of ``prev``;
    ``cov_ned`` is the increment covariance with the displacement in NED axes."""
    dt = t1 - prev.t
    c, s = math.cos(prev.heading), math.sin(prev.heading)
    dn, de = x - prev.x, y - prev.y
    dx = c * dn + s * de
    dy = -s * dn + c * de
    dh = wrap_angle(psi - prev.heading)
    # rotate the displacement block by T = [[c, s], [-s, c]]
    (snn, sne, snh), (_, see, seh), (_, _, shh) = cov_ned.tolist()
    cxx = c * c * snn + 2.0 * c * s * sne + s * s * see
    cyy = s * s * snn - 2.0 * c * s * sne + c * c * see
    cxy = (c * c - s * s) * sne + c * s * (see - snn)
    cxh = c * snh + s * seh
    cyh = -s * snh + c * seh
    cov = np.array([[cxx, cxy, cxh], [cxy, cyy, cyh], [cxh, cyh, shh]])
    cov.flags.writeable = False
    return MotionIncrement(
        t0=prev.t,
        t1=t1,
        dx=dx,
        dy=dy,
        dz=z - prev.z,
        dheading=dh,
        covariance=cov,
        dt=dt,
        v_forward=dx / dt,
        v_starboard=dy / dt,
        yaw_rate=dh / dt,
    )
