"""Neural ranging of magnetic beacons (Hou et al. 2019, Secs. 2.1-2.4, 3.2).

**Training set** (:func:`make_training_set`). The paper trains on 1000 field samples from
Weihai; we generate them from the world's dipole model
(:func:`auvgw.sim_devices.world.dipole_field`) in the paper's geometry: the AUV ~6 m above a
beacon on the seabed (Sec. 3.1; ``altitude_m`` +- ``altitude_spread_m`` for the 14.6-15.4 m
seabed), horizontal offsets uniform in a disc of ``max_range_m`` (40 m: beyond Table 4's 25 m
sensor range, so that a beacon at 25-40 m, still above the demodulator's quality gate, is ranged
and then rejected by the range gate instead of being folded into the 25 m disc), a
``moment_am2`` vertical coil (``beacons.json``, A4) with a relative moment spread and an axis
tilt, the INS attitude error rotating the measured NED vector, and the demodulator's noise
(:mod:`~auvgw.slam.magnetic.demod`: median sigma ~0.4 nT per axis at 1 nT sensor noise, plus its
3 % model error). Input: the demodulated in-phase amplitude vector of one beacon in NED (nT;
reading notes A1: three components, not a scalar magnitude, which cannot give a 3-D position).
Output: ``beacon - vehicle`` in NED, metres (A2).

**Inference** (:func:`to_range_bearing`): horizontal range ``hypot(dx, dy)`` and bearing
``atan2(dy, dx) - heading`` (A2, A3, A31) with covariance ``J C J^T`` from the MLP's validation
residual covariance ``C`` (per range bin) and the Jacobian of that conversion.

Train the shipped model (``config/magnetic_mlp.npz``) and write the cross-validation table::

    python -m auvgw.slam.magnetic.ranging --out config/magnetic_mlp.npz \\
        --cv docs/results/magnetic/mlp_cv.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from auvgw.sim_devices.world import dipole_field
from auvgw.slam.magnetic.mlp import MLP, TrainConfig, cross_validate, train
from auvgw.slam.models import wrap_angle

__all__ = [
    "RangingGeometry",
    "fit_ranger",
    "make_training_set",
    "search_configurations",
    "to_range_bearing",
]

#: the paper's Table 3 final row (x, y, z) "correlation coefficient"
PAPER_CV_R = (0.90362, 0.87182, 0.90904)


@dataclass(frozen=True)
class RangingGeometry:
    """The training geometry and error model (module docstring); angles in degrees, field
    noise in nT."""

    max_range_m: float = 40.0
    altitude_m: float = 6.0
    altitude_spread_m: float = 0.6
    moment_am2: float = 500.0
    moment_spread: float = 0.05
    axis_tilt_deg: float = 3.0
    heading_error_deg: float = 0.3
    tilt_error_deg: float = 0.1
    demod_sigma_nt: float = 0.4
    demod_rel_sigma: float = 0.03


def _small_rotations(rng: np.random.Generator, n: int, sig: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` rotations by small roll/pitch/yaw errors with std ``sig`` (rad)."""
    from auvgw.slam.magnetic.demod import rotation_body_to_ned

    e = rng.standard_normal((n, 3)) * sig
    return rotation_body_to_ned(e[:, 2], e[:, 1], e[:, 0])


def make_training_set(
    n: int, rng: np.random.Generator, geo: RangingGeometry = RangingGeometry()
) -> tuple[np.ndarray, np.ndarray]:
    """``(x (n, 3) amplitude vectors nT NED, y (n, 3) beacon - vehicle m NED)``."""
    rho = geo.max_range_m * np.sqrt(rng.random(n))
    phi = rng.uniform(-math.pi, math.pi, n)
    dz = geo.altitude_m + rng.uniform(-geo.altitude_spread_m, geo.altitude_spread_m, n)
    delta = np.stack([rho * np.cos(phi), rho * np.sin(phi), dz], axis=1)  # beacon - vehicle
    tilt = np.radians(geo.axis_tilt_deg) * np.abs(rng.standard_normal(n))
    az = rng.uniform(-math.pi, math.pi, n)
    axis = np.stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)], 1)
    mom = geo.moment_am2 * (1 + geo.moment_spread * rng.standard_normal(n))[:, None] * axis
    # one beacon per sample at the origin, the vehicle at -delta: diagonal of the (n, n) field
    b = np.empty((n, 3))
    for i0 in range(0, n, 512):
        sl = slice(i0, min(i0 + 512, n))
        f = dipole_field(-delta[sl], np.zeros((1, 3)), mom[sl])  # (B, N, 3)
        b[sl] = f[np.arange(f.shape[0]), np.arange(f.shape[0])] * 1e9
    rot = _small_rotations(
        rng, n, np.radians([geo.tilt_error_deg, geo.tilt_error_deg, geo.heading_error_deg])
    )
    b = np.einsum("nij,nj->ni", rot, b)
    sig = np.sqrt(geo.demod_sigma_nt**2 + (geo.demod_rel_sigma * b) ** 2)
    return b + rng.standard_normal(b.shape) * sig, delta


def fit_ranger(
    x: np.ndarray,
    y: np.ndarray,
    cfg: TrainConfig,
    rng: np.random.Generator,
    holdout: float = 0.1,
    bins: tuple[float, ...] = (0.0, 9.0, 13.0, 17.0, 21.0, 25.0, 30.0, np.inf),
) -> tuple[MLP, np.ndarray]:
    """Train on ``1 - holdout`` of the data (the paper's 90/10 split) and attach the residual
    covariance of the held-out 10 % per bin of predicted ``|beacon - vehicle|`` (m):
    ``(model, training history)``."""
    n_val = max(round(holdout * len(x)), 10)
    perm = rng.permutation(len(x))
    val, tr = perm[:n_val], perm[n_val:]
    net, hist = train(x[tr], y[tr], cfg, rng)
    pred = net.predict(x[val])
    res = y[val] - pred
    edges = np.asarray(bins, float)
    k = np.clip(np.searchsorted(edges, np.linalg.norm(pred, axis=1)) - 1, 0, len(edges) - 2)
    overall = np.cov(res.T)
    covs = np.array([np.cov(res[k == i].T) if np.sum(k == i) > 10 else overall
                     for i in range(len(edges) - 1)])  # fmt: skip
    net.resid_bins, net.resid_cov = edges, covs
    return net, hist


def to_range_bearing(
    delta: np.ndarray, cov: np.ndarray, heading: float
) -> tuple[np.ndarray, np.ndarray]:
    """``beacon - vehicle`` (N, 3) m NED and its covariance (N, 3, 3) -> ``z (N, 2)`` (horizontal
    range m, bearing rad relative to ``heading``: eq. (21)'s measurement) and ``R (N, 2, 2)``."""
    d = np.asarray(delta, float).reshape(-1, 3)
    dx, dy = d[:, 0], d[:, 1]
    r = np.maximum(np.hypot(dx, dy), 1e-3)
    z = np.stack([r, wrap_angle(np.arctan2(dy, dx) - heading)], axis=1)
    j = np.zeros((len(d), 2, 3))
    j[:, 0, 0], j[:, 0, 1] = dx / r, dy / r
    j[:, 1, 0], j[:, 1, 1] = -dy / r**2, dx / r**2
    return z, j @ np.asarray(cov).reshape(-1, 3, 3) @ j.transpose(0, 2, 1)


def search_configurations(
    x: np.ndarray,
    y: np.ndarray,
    rng: np.random.Generator,
    candidates: tuple[tuple[int, ...], ...] = ((10,), (20,), (40,), (20, 10), (40, 20), (60, 30)),
    base: TrainConfig | None = None,
) -> list[dict[str, object]]:
    """The paper's trial-and-error search (Fig. 3): each hidden configuration trained on 90 %,
    scored on the held-out 10 % by MSE (scaled) and per-axis R^2 (eq. 30)."""
    base = base or TrainConfig()
    n_val = len(x) // 10
    perm = rng.permutation(len(x))
    val, tr = perm[:n_val], perm[n_val:]
    rows: list[dict[str, object]] = []
    for hidden in candidates:
        cfg = TrainConfig(**{**base.__dict__, "hidden": hidden})
        net, hist = train(x[tr], y[tr], cfg, rng)
        pred = net.predict(x[val])
        yt = y[val]
        r2 = 1 - ((yt - pred) ** 2).sum(0) / ((yt - yt.mean(0)) ** 2).sum(0)
        rows.append({"hidden": hidden, "train_mse": float(hist[-1]), "epochs": len(hist),
                     "r2": r2.round(4).tolist(),
                     "rmse_m": np.sqrt(((yt - pred) ** 2).mean(0)).round(3).tolist()})  # fmt: skip
    return rows


def _cv_table(name: str, cv: dict[str, np.ndarray]) -> list[str]:
    lines = [f"### {name}", "", "| fold (test group) | R x | R y | R z | RMSE x m | RMSE y m |"
             " RMSE z m | epochs |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for j in range(len(cv["r"])):
        r, e = cv["r"][j], cv["rmse"][j]
        lines.append(
            f"| {chr(65 + j)} ({len(cv['r']) - j}) | {r[0]:.4f} | {r[1]:.4f} |"
            f" {r[2]:.4f} | {e[0]:.2f} | {e[1]:.2f} | {e[2]:.2f} | {cv['epochs'][j]} |"
        )
    r, e = cv["r"].mean(0), cv["rmse"].mean(0)
    lines.append(
        f"| **mean** | **{r[0]:.4f}** | **{r[1]:.4f}** | **{r[2]:.4f}** | **{e[0]:.2f}**"
        f" | **{e[1]:.2f}** | **{e[2]:.2f}** | |"
    )
    p = PAPER_CV_R
    lines.append(f"| paper Table 3 | {p[0]} | {p[1]} | {p[2]} | - | - | - | 3950 |")
    return [*lines, ""]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Train the shipped ranging model; optionally run the search and the 10-fold CV."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="model .npz")
    ap.add_argument("--samples", type=int, default=31290, help="the paper's 30x-weights rule")
    ap.add_argument("--seed", type=int, default=2019)
    ap.add_argument("--optimiser", choices=["adam", "gd"], default="adam")
    ap.add_argument("--cv", type=Path, default=None, help="write the search + 10-fold CV table")
    ap.add_argument(
        "--cv-range",
        type=float,
        default=25.0,
        help="disc radius (m) of the search and CV data: Table 4's 25 m sensor range",
    )
    ap.add_argument("--cv-only", action="store_true", help="do not train the shipped model")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    cfg = TrainConfig(optimiser=a.optimiser, lr=0.01 if a.optimiser == "gd" else 3e-3,
                      max_epochs=400 if a.optimiser == "adam" else 20000)  # fmt: skip
    if not a.cv_only:
        x, y = make_training_set(a.samples, rng)
        t0 = time.perf_counter()
        net, hist = fit_ranger(x, y, cfg, rng)
        took = time.perf_counter() - t0
        msg = f"trained {net.sizes} in {took:.1f} s, {len(hist)} epochs, final training MSE"
        print(f"{msg} {hist[-1]:.2e} (goal {cfg.goal_mse:g})", file=sys.stderr)
        net.save(a.out)
    if a.cv is not None:
        geo = RangingGeometry(max_range_m=a.cv_range)
        md = [
            "# MLP ranging: configuration search and 10-fold cross-validation",
            "",
            f"Made by: `python -m auvgw.slam.magnetic.ranging --out {a.out} --cv {a.cv}"
            f"{' --cv-only' if a.cv_only else ''}` (seed {a.seed}, optimiser {a.optimiser});"
            f" data: horizontal offsets within --cv-range {a.cv_range:g} m (Table 4's sensor"
            " range), otherwise `RangingGeometry`'s defaults. RMSE in metres.",
            "",
            "## Configuration search (90/10 holdout, 5000 samples)",
            "",
            "| hidden | train MSE | epochs | R2 x, y, z | RMSE m x, y, z |",
            "|---|---|---|---|---|",
        ]
        for row in search_configurations(*make_training_set(5000, rng, geo), rng):
            md.append(
                f"| {row['hidden']} | {row['train_mse']:.2e} | {row['epochs']} |"
                f" {row['r2']} | {row['rmse_m']} |"
            )
        md += ["", "## 10-fold cross-validation (Tables 1-3 procedure)", ""]
        for n in (1000, 5000):
            xs, ys = make_training_set(n, rng, geo)
            md += _cv_table(f"{n} samples", cross_validate(xs, ys, cfg, rng))
        a.cv.parent.mkdir(parents=True, exist_ok=True)
        a.cv.write_text("\n".join(md) + "\n")  # fmt: skip
        print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
