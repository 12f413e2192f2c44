"""Beacon demodulation: MS3A samples + INS attitude -> per-beacon amplitude vectors in NED.

The AMB-SLAM paper (Hou et al. 2019) feeds "the magnetic flux density" of each beacon to its MLP
but describes no signal processing (reading notes A7, section 6.3). This module is the missing
step, pure numpy:

1. **Rotate to NED first** (:func:`rotate_to_ned`): ``B_ned = R(heading, pitch, roll) B_body``
   with the INS attitude at each sample's time. In body axes the Earth field (~56 000 nT) moves
   by thousands of nT during a turn; in NED it is a constant plus the slow rotation error of the
   INS attitude, which the background polynomial absorbs.
2. **Sliding least squares** (:func:`demodulate`) over windows of ``window_s`` seconds, one every
   ``hop_s`` seconds, stamped at the window centre. Per axis, the model is

       B(t) = sum_p c_p (t - t_c)^p                                  (background, p <= detrend)
            + sum_f sum_q (t - t_c)^q [a_fq cos(2 pi f t) + b_fq sin(2 pi f t)]   (q <= amp_order)

   fitted jointly for all channels ``f`` (a lock-in amplifier generalised to several tones and a
   varying amplitude). The amplitude vector of channel ``f`` is ``a_f0`` (3 axes, nT): the
   in-phase amplitude at the window centre. ``amp_order >= 1`` lets the amplitude vary linearly
   over the window (at 5 m/s the range to a beacon changes by up to 10 m in 2 s); the default
   ``amp_order = 2`` also follows the peak of a close pass.
3. **Sign** (``phase = "synchronous"``, default): the emulated beacons are driven phase-locked
   to the vehicle clock (moment ``m cos(2 pi f t)``, ``World.beacon_fields``), so the in-phase
   coefficient carries the dipole sign and the quadrature one is noise (it is reported as a
   check). ``phase = "unsynchronised"`` takes the principal real direction of the complex
   amplitude ``a + i b`` and fixes the sign by the convention "D component >= 0": right for a
   vertical dipole below the sensor within ~54.7 deg of its axis (horizontal range < sqrt(2) x
   altitude), sign-flipped beyond, so in that mode only the magnitude is trustworthy.
4. **Quality**: per channel the standard deviations of the three amplitude components from the
   fit residual (``sigma = sqrt(RSS / dof)`` times the coefficient's ``sqrt((A^T A)^-1)``) and
   ``snr = |a| / sqrt(sum sigma^2)``.

**Frequency plan** (:func:`plan_frequencies`). Two constant tones ``df`` apart are orthogonal
over a window ``T`` when ``df * T`` is an integer; a single-tone lock-in leaks
``|sinc(pi df T)|`` of its neighbour (0.935 for the original 0.1 Hz spacing at T = 2 s). A
beacon passed at 5 m/s is not a constant tone: its amplitude modulation has sidebands of about
``v / r`` Hz, and a polynomial amplitude of order ``q`` makes channels closer than about
``(q + 1) / T`` nearly collinear. The plan: channels spaced ``(amp_order + 1) / T`` (1.5 Hz at
T = 2 s, q = 2: 1.0, 2.5, ..., 8.5 Hz), fitted jointly, reused between beacons more than
``reuse_distance_m`` apart (2 x 25 m sensor range + 20 m margin). Leakage (measured, tested in
``tests/slam/test_magnetic_demod.py``): a silent channel next to a beacon passed at 6 m reads within
4 of its own stated sigmas of zero (at most ~4 % of the neighbour's peak, flagged by a low
``snr``); at 0.5 Hz spacing with q = 2 the ghost exceeded the real beacon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "BeaconAmplitudes",
    "DemodConfig",
    "demodulate",
    "plan_frequencies",
    "rotate_to_ned",
    "rotation_body_to_ned",
]


@dataclass(frozen=True)
class DemodConfig:
    """Demodulator settings. ``window_s`` T (s), ``hop_s`` output period (s, 0.2 = the paper's
    5 Hz observations), ``detrend`` background polynomial order, ``amp_order`` amplitude
    polynomial order, ``model_rel_sigma`` the relative error of an amplitude polynomial over the
    window added in quadrature to the stated sigma (curvature of ``1/r^3``: measured up to ~7 %
    at a 6 m closest approach at 5 m/s with ``amp_order = 2``, T = 2 s; 3 % keeps normalised
    errors near N(0, 1)), ``phase`` the sign resolution (module docstring), ``min_fill`` the least
    fraction of the window's nominal samples a window needs (dropouts), ``rate_hz`` the nominal
    magnetometer rate (MS3A emulator: 20 Hz)."""

    window_s: float = 2.0
    hop_s: float = 0.2
    detrend: int = 1
    amp_order: int = 2
    model_rel_sigma: float = 0.03
    phase: Literal["synchronous", "unsynchronised"] = "synchronous"
    min_fill: float = 0.8
    rate_hz: float = 20.0


@dataclass(frozen=True)
class BeaconAmplitudes:
    """Demodulated windows: ``t (W,)`` window centres (s); ``freqs (F,)`` the channels (Hz);
    ``amp (W, F, 3)`` in-phase amplitude vectors (nT, NED) at the centre; ``quad (W, F, 3)`` the
    quadrature amplitudes (nT; noise for synchronous beacons); ``sigma (W, F, 3)`` their
    standard deviations (nT); ``snr (W, F)`` ``|amp| / |sigma|``; ``n (W,)`` samples used."""

    t: np.ndarray
    freqs: np.ndarray
    amp: np.ndarray
    quad: np.ndarray
    sigma: np.ndarray
    snr: np.ndarray
    n: np.ndarray


def rotation_body_to_ned(heading: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` body (x fwd, y stbd, z down) -> NED, ZYX Euler angles
    (rad), ``R = Rz(heading) Ry(pitch) Rx(roll)``, vectorised."""
    h, p, r = (np.asarray(a, float).reshape(-1) for a in (heading, pitch, roll))
    ch, sh, cp, sp, cr, sr = np.cos(h), np.sin(h), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    out = np.empty((h.size, 3, 3))
    out[:, 0] = np.stack([ch * cp, ch * sp * sr - sh * cr, ch * sp * cr + sh * sr], axis=1)
    out[:, 1] = np.stack([sh * cp, sh * sp * sr + ch * cr, sh * sp * cr - ch * sr], axis=1)
    out[:, 2] = np.stack([-sp, cp * sr, cp * cr], axis=1)
    return out


def rotate_to_ned(
    b_body: np.ndarray, heading: np.ndarray, pitch: np.ndarray, roll: np.ndarray
) -> np.ndarray:
    """Body-axis field samples ``(N, 3)`` to NED with the attitude at each sample (rad)."""
    rot = rotation_body_to_ned(heading, pitch, roll)
    return np.einsum("nij,nj->ni", rot, np.asarray(b_body, float).reshape(-1, 3))


def plan_frequencies(
    positions: np.ndarray,
    spacing_hz: float = 1.5,
    f0_hz: float = 1.0,
    n_channels: int = 6,
    reuse_distance_m: float = 70.0,
) -> np.ndarray:
    """Frequencies (Hz) for beacons at ``positions (B, 2|3)``: channels ``f0 + k spacing``
    (default 1.0-8.5 Hz, below the 20 Hz MS3A's 10 Hz Nyquist; spacing ``(amp_order + 1) / T``),
    ``k < n_channels``, assigned greedily (beacons in order, the least used free channel) so
    that two beacons closer than ``reuse_distance_m`` never share a channel. Raises
    ``ValueError`` when the channels do not suffice."""
    pos = np.asarray(positions, float)[:, :2]
    chans = f0_hz + np.arange(n_channels) * spacing_hz
    d = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
    out = np.full(len(pos), -1, dtype=int)
    for i in range(len(pos)):
        used = {out[j] for j in range(i) if d[i, j] < reuse_distance_m}
        free = [k for k in range(n_channels) if k not in used]
        if not free:
            raise ValueError(
                f"beacon {i}: {n_channels} channels are not enough for a reuse distance of "
                f"{reuse_distance_m} m; add channels or shorten the distance"
            )
        out[i] = min(free, key=lambda k: (int(np.sum(out[:i] == k)), k))  # spread the load
    return chans[out]


def _design(dt: np.ndarray, t: np.ndarray, freqs: np.ndarray, cfg: DemodConfig) -> np.ndarray:
    """Design matrices ``(W, S, P)`` for offsets ``dt`` and absolute times ``t`` ``(W, S)``:
    background powers, then per channel and amplitude order (cos, sin)."""
    cols = [dt**p for p in range(cfg.detrend + 1)]
    ph = 2 * math.pi * t[..., None] * freqs  # (W, S, F)
    c, s = np.cos(ph), np.sin(ph)
    for q in range(cfg.amp_order + 1):
        w = dt[..., None] ** q
        for fi in range(len(freqs)):
            cols.append(c[..., fi] * w[..., 0])
            cols.append(s[..., fi] * w[..., 0])
    return np.stack(cols, axis=-1)


def demodulate(
    t: np.ndarray,
    b_ned: np.ndarray,
    freqs: np.ndarray,
    cfg: DemodConfig = DemodConfig(),
    centres: np.ndarray | None = None,
) -> BeaconAmplitudes:
    """Sliding least squares of NED samples ``b_ned (N, 3)`` (nT) at times ``t (N,)`` (s,
    increasing; the beacons' phase reference is t = 0) at channels ``freqs (F,)`` (Hz); see
    the module docstring. Windows with fewer than ``min_fill`` of their nominal samples are
    skipped. ``centres`` (s) overrides the windows (default: every ``hop_s`` from the first
    full window)."""
    t = np.asarray(t, float).reshape(-1)
    b = np.asarray(b_ned, float).reshape(-1, 3)
    freqs = np.unique(np.asarray(freqs, float).reshape(-1))
    if len(t) != len(b):
        raise ValueError(f"{len(t)} times but {len(b)} samples")
    if len(t) and np.any(np.diff(t) <= 0):
        raise ValueError("sample times must increase strictly")
    half = cfg.window_s / 2
    nominal = cfg.window_s * cfg.rate_hz
    n_par = cfg.detrend + 1 + 2 * len(freqs) * (cfg.amp_order + 1)
    empty = BeaconAmplitudes(
        np.zeros(0), freqs, *(np.zeros((0, len(freqs), 3)),) * 3, np.zeros((0, len(freqs))),
        np.zeros(0, int),
    )  # fmt: skip
    if len(t) == 0:
        return empty
    if centres is None:
        centres = np.arange(t[0] + half, t[-1] - half + 1e-9, cfg.hop_s)
    centres = np.asarray(centres, float).reshape(-1)
    lo = np.searchsorted(t, centres - half, side="left")
    hi = np.searchsorted(t, centres + half, side="left")
    n = hi - lo
    keep = (n >= cfg.min_fill * nominal) & (n > n_par + 1)
    centres, lo, n = centres[keep], lo[keep], n[keep]
    if len(centres) == 0:
        return empty
    smax = int(n.max())
    idx = lo[:, None] + np.arange(smax)
    mask = np.arange(smax) < n[:, None]
    idx = np.where(mask, idx, lo[:, None])
    tw = t[idx]
    a = _design(tw - centres[:, None], tw, freqs, cfg) * mask[..., None]
    y = b[idx] * mask[..., None]  # (W, S, 3)
    ata = a.transpose(0, 2, 1) @ a
    aty = a.transpose(0, 2, 1) @ y
    ata_inv = np.linalg.inv(ata)
    coef = ata_inv @ aty  # (W, P, 3)
    res = (y - a @ coef) * mask[..., None]
    dof = np.maximum(n - n_par, 1)
    s2 = (res * res).sum(axis=1) / dof[:, None]  # (W, 3)
    base = cfg.detrend + 1
    f_n = len(freqs)
    ic = base + 2 * np.arange(f_n)  # in-phase at the centre (q = 0)
    diag = np.diagonal(ata_inv, axis1=1, axis2=2)  # (W, P)
    amp = coef[:, ic, :]
    quad = coef[:, ic + 1, :]
    sigma = np.sqrt(diag[:, ic, None] * s2[:, None, :] + (cfg.model_rel_sigma * amp) ** 2)
    if cfg.phase == "unsynchronised":
        z = amp + 1j * quad
        phi = 0.5 * np.angle(np.sum(z * z, axis=-1, keepdims=True))
        amp = np.real(z * np.exp(-1j * phi))
        quad = np.imag(z * np.exp(-1j * phi))
        amp = np.where(amp[..., 2:3] < 0, -amp, amp)
    snr = np.linalg.norm(amp, axis=-1) / np.maximum(np.linalg.norm(sigma, axis=-1), 1e-12)
    return BeaconAmplitudes(centres, freqs, amp, quad, sigma, snr, n)
