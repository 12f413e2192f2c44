"""The AMB-SLAM paper's MLP in numpy (Hou et al. 2019, Secs. 2.2-2.3 and 3.2).

* Scaling, eq. (9): ``x' = 1.8 (x - x_min) / (x_max - x_min) - 0.9`` for inputs and outputs,
  min/max from the *training* data only (reading notes A28), stored with the weights.
* Network, eqs. (4)-(7): hidden layers of tanh (eq. 6, MATLAB's ``tansig``) and a linear output
  (eq. 7, bias indexed by the output k: typo A33). Default hidden sizes ``(40, 20)`` (Sec. 3.2;
  "three hidden layers" in Sec. 2.2 is inconsistent, A8).
* Loss, eq. (10): the mean squared error over outputs and samples, on scaled outputs; goal
  ``8e-4`` (Sec. 3.2).
* Training: ``optimiser="gd"`` is the paper's full-batch steepest descent, eq. (12), learning
  rate 0.01; ``"adam"`` (default, Kingma and Ba 2015, mini-batches) reaches the same goal in far
  fewer epochs. Both stop at the goal MSE or ``max_epochs``. Weight initialisation is "zero-mean
  random" in the paper (A29): Glorot-uniform from the caller's generator.
* An optional input transform (``"cbrt"``, default for ranging): the field vector ``B`` becomes
  ``B |B|^(-2/3)`` (magnitude ``|B|^(1/3)``, proportional to ``1/r`` for a dipole, direction
  kept). Without it eq. (9) squeezes the 3-6 nT of a beacon at 25 m into 1 % of the input range
  set by the ~460 nT of a close pass. ``"none"`` is the paper's raw input.

Arrays in, arrays out; :meth:`MLP.save` / :meth:`MLP.load` use one ``.npz``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

__all__ = ["MLP", "TrainConfig", "cross_validate", "fit_scaler", "train"]

Transform = Literal["none", "cbrt"]


def fit_scaler(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column ``(min, max)`` of ``a (N, D)`` for eq. (9); a constant column gets a span of 1."""
    lo, hi = a.min(axis=0), a.max(axis=0)
    return lo, np.where(hi > lo, hi, lo + 1.0)


def _scale(a: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return 1.8 * (a - lo) / (hi - lo) - 0.9  # eq. (9)


def _unscale(a: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return (a + 0.9) / 1.8 * (hi - lo) + lo


def _transform(x: np.ndarray, kind: str) -> np.ndarray:
    if kind == "none":
        return x
    if kind == "cbrt":
        n = np.linalg.norm(x, axis=-1, keepdims=True)
        return x * np.maximum(n, 1e-12) ** (-2.0 / 3.0)
    raise ValueError(f"unknown input transform {kind!r} (none, cbrt)")


@dataclass
class MLP:
    """Weights ``w[i] (n_in, n_out)``, biases ``b[i] (n_out,)``, eq. (9) scalers, the input
    transform, and ``resid_cov (K, O, O)`` the covariance of validation residuals (output units)
    in ``K`` bins of ``resid_bins`` (edges on the output norm, ``K + 1`` values)."""

    w: list[np.ndarray]
    b: list[np.ndarray]
    x_lo: np.ndarray
    x_hi: np.ndarray
    y_lo: np.ndarray
    y_hi: np.ndarray
    transform: str = "none"
    resid_bins: np.ndarray = field(default_factory=lambda: np.array([0.0, np.inf]))
    resid_cov: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 0)))

    @property
    def sizes(self) -> tuple[int, ...]:
        return (self.w[0].shape[0], *(w.shape[1] for w in self.w))

    def _forward(self, xs: np.ndarray) -> list[np.ndarray]:
        """Activations of every layer for scaled inputs ``xs (N, n_in)``; eqs. (4)-(7)."""
        acts = [xs]
        for i, (w, b) in enumerate(zip(self.w, self.b, strict=True)):
            z = acts[-1] @ w + b  # eq. (4) / eq. (7)
            acts.append(np.tanh(z) if i < len(self.w) - 1 else z)  # eqs. (5)-(6)
        return acts

    def scale_inputs(self, x: np.ndarray) -> np.ndarray:
        return _scale(_transform(np.asarray(x, float), self.transform), self.x_lo, self.x_hi)

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Outputs ``(N, n_out)`` in output units for inputs ``(N, n_in)`` (or one ``(n_in,)``)."""
        x = np.asarray(x, float)
        one = x.ndim == 1
        out = _unscale(self._forward(self.scale_inputs(x.reshape(-1, x.shape[-1])))[-1],
                       self.y_lo, self.y_hi)  # fmt: skip
        return out[0] if one else out

    def covariance(self, y: np.ndarray) -> np.ndarray:
        """Validation-residual covariance ``(N, O, O)`` for predictions ``y (N, O)``."""
        y = np.asarray(y, float).reshape(-1, self.w[-1].shape[1])
        k = np.clip(np.searchsorted(self.resid_bins, np.linalg.norm(y, axis=1)) - 1, 0,
                    len(self.resid_cov) - 1)  # fmt: skip
        return self.resid_cov[k]

    def save(self, path: str | Path) -> None:
        """Weights, scalers and residual covariances to one ``.npz``."""
        arrays: dict[str, Any] = {f"w{i}": w for i, w in enumerate(self.w)}
        arrays |= {f"b{i}": b for i, b in enumerate(self.b)}
        arrays |= {
            "n_layers": len(self.w), "x_lo": self.x_lo, "x_hi": self.x_hi, "y_lo": self.y_lo,
            "y_hi": self.y_hi, "transform": self.transform, "resid_bins": self.resid_bins,
            "resid_cov": self.resid_cov,
        }  # fmt: skip
        np.savez(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> MLP:
        """A model saved by :meth:`save`; a clear error naming the file and the missing key."""
        try:
            with np.load(path, allow_pickle=False) as d:
                n = int(d["n_layers"])
                return cls(
                    w=[d[f"w{i}"] for i in range(n)], b=[d[f"b{i}"] for i in range(n)],
                    x_lo=d["x_lo"], x_hi=d["x_hi"], y_lo=d["y_lo"], y_hi=d["y_hi"],
                    transform=str(d["transform"]), resid_bins=d["resid_bins"],
                    resid_cov=d["resid_cov"],
                )  # fmt: skip
        except KeyError as exc:
            raise ValueError(f"{path}: not an MLP model file (missing {exc})") from None


@dataclass(frozen=True)
class TrainConfig:
    """Training settings: ``hidden`` layer sizes (paper: 40, 20), ``optimiser`` ``adam`` or
    ``gd`` (the paper's eq. 12), ``lr`` (paper: 0.01 for gd; 3e-3 for adam), ``goal_mse`` on
    scaled outputs (paper: 8e-4), ``max_epochs``, ``batch`` (adam mini-batch size), input
    ``transform``."""

    hidden: tuple[int, ...] = (40, 20)
    optimiser: Literal["adam", "gd"] = "adam"
    lr: float = 3e-3
    goal_mse: float = 8e-4
    max_epochs: int = 400
    batch: int = 64
    transform: Transform = "cbrt"


def train(
    x: np.ndarray, y: np.ndarray, cfg: TrainConfig, rng: np.random.Generator
) -> tuple[MLP, np.ndarray]:
    """Train on ``x (N, n_in)``, ``y (N, n_out)``: ``(model, training MSE per epoch)``, eq. (10)
    on scaled outputs, stopping at ``cfg.goal_mse``."""
    x = _transform(np.asarray(x, float), cfg.transform)
    y = np.asarray(y, float)
    x_lo, x_hi = fit_scaler(x)
    y_lo, y_hi = fit_scaler(y)
    xs, ys = _scale(x, x_lo, x_hi), _scale(y, y_lo, y_hi)
    sizes = (x.shape[1], *cfg.hidden, y.shape[1])
    w, b = [], []
    for n_in, n_out in itertools.pairwise(sizes):
        lim = math.sqrt(6.0 / (n_in + n_out))  # Glorot-uniform, zero mean (A29)
        w.append(rng.uniform(-lim, lim, (n_in, n_out)))
        b.append(np.zeros(n_out))
    net = MLP(w, b, x_lo, x_hi, y_lo, y_hi, cfg.transform)
    params = [*net.w, *net.b]
    m1 = [np.zeros_like(p) for p in params]
    m2 = [np.zeros_like(p) for p in params]
    step = 0
    history: list[float] = []
    n = len(xs)
    for _ in range(cfg.max_epochs):
        if cfg.optimiser == "gd":
            batches = [np.arange(n)]
        else:
            perm = rng.permutation(n)
            batches = [perm[i : i + cfg.batch] for i in range(0, n, cfg.batch)]
        for idx in batches:
            grads = _gradients(net, xs[idx], ys[idx])
            step += 1
            for p, g, a, v in zip(params, grads, m1, m2, strict=True):
                if cfg.optimiser == "gd":
                    p -= cfg.lr * g  # eq. (12)
                else:
                    a *= 0.9
                    a += 0.1 * g
                    v *= 0.999
                    v += 0.001 * g * g
                    p -= cfg.lr * (a / (1 - 0.9**step)) / (np.sqrt(v / (1 - 0.999**step)) + 1e-8)
        mse = float(np.mean((net._forward(xs)[-1] - ys) ** 2))  # eq. (10)
        history.append(mse)
        if mse <= cfg.goal_mse:
            break
    return net, np.array(history)


def _gradients(net: MLP, xs: np.ndarray, ys: np.ndarray) -> list[np.ndarray]:
    """Back-propagated gradients of eq. (10) w.r.t. ``[*w, *b]``."""
    acts = net._forward(xs)
    delta = 2.0 * (acts[-1] - ys) / ys.size
    gw: list[np.ndarray] = []
    gb: list[np.ndarray] = []
    for i in range(len(net.w) - 1, -1, -1):
        gw.append(acts[i].T @ delta)
        gb.append(delta.sum(axis=0))
        if i:
            delta = (delta @ net.w[i].T) * (1.0 - acts[i] ** 2)  # tanh' = 1 - tanh^2
    return [*gw[::-1], *gb[::-1]]


def cross_validate(
    x: np.ndarray, y: np.ndarray, cfg: TrainConfig, rng: np.random.Generator, folds: int = 10
) -> dict[str, np.ndarray]:
    """The paper's 10-fold cross-validation (Tables 1-3): consecutive groups, fold ``j`` tests
    on group ``folds - 1 - j`` (experiment A tests on group 10). Per fold and output: Pearson
    ``r`` (Table 3), ``r2`` (eq. 30), ``rmse`` (output units, not in the paper) and ``epochs``."""
    n = len(x)
    groups = np.array_split(np.arange(n), folds)
    r, r2, rmse, epochs = [], [], [], []
    for j in range(folds):
        test = groups[folds - 1 - j]
        tr = np.setdiff1d(np.arange(n), test)
        net, hist = train(x[tr], y[tr], cfg, rng)
        pred = net.predict(x[test])
        yt = y[test]
        r.append([np.corrcoef(pred[:, k], yt[:, k])[0, 1] for k in range(y.shape[1])])
        ss = ((yt - pred) ** 2).sum(axis=0)
        r2.append(1 - ss / ((yt - yt.mean(axis=0)) ** 2).sum(axis=0))  # eq. (30)
        rmse.append(np.sqrt(ss / len(test)))
        epochs.append(len(hist))
    return {
        "r": np.array(r),
        "r2": np.array(r2),
        "rmse": np.array(rmse),
        "epochs": np.array(epochs),
    }
