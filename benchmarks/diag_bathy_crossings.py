"""Per-crossing diagnosis of mtm-pf (issue 14): at every closure of one run, where the cloud,
its weighted mean and its best particle sit against the offset that would align the Pmap with
the old map, how wide the cloud is, how many particles carry the weight, and the likelihood of
the crossing over a grid of offsets around that true offset.

    nice -n 10 .venv/bin/python benchmarks/diag_bathy_crossings.py --particles 400 --run 0 \
        --out docs/results/bathymetric/diag_n400_run0.md [--set KEY=VALUE ...]

"True offset": the mean-trajectory map at the old time ``t_loop`` is itself off by the error of
the trajectory there, so the position that aligns the submaps is
``x* = S_p(t) - [(S_p(t) - S_p(t_loop)) - (truth(t) - truth(t_loop))]`` (the relative error of
the mean trajectory between the two times removed). Distances below are to ``x*`` (m).
"""

from __future__ import annotations

import argparse
import sys
import zlib
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.filters import (
    MTMPF,
    mode_odds,
    mode_ratio,
    mode_weights,
    no_match_weight,
)
from auvgw.slam.bathymetric.simulate import simulate_survey


class Probe(MTMPF):
    """MTM-PF recording what every crossing saw (the filter's logic is unchanged)."""

    truth: np.ndarray
    grid_half_m = 20.0
    grid_step_m = 2.0
    grid = True

    def __init__(self, *a: object, **k: object) -> None:
        super().__init__(*a, **k)  # type: ignore[arg-type]
        self.rows: list[dict[str, float]] = []
        self._grid_ll: np.ndarray | None = None
        self._grid_x: np.ndarray | None = None
        self._pending: dict[str, float] | None = None

    def raw_weights(self, x: np.ndarray) -> np.ndarray:
        """log of the un-normalised matched weight at positions ``x`` (G, 2) this ping, with the
        filter's own matching (:meth:`MTMPF.match`; the no-match weight for positions outside R
        or gated out)."""
        out = np.full(len(x), np.log(no_match_weight(self.cfg.n_particles, self.cfg)))
        m = self.match(x)
        if m is not None:
            _, near, w_m, gate = m
            out[near[gate]] = np.log(np.maximum(w_m[gate], 1e-300))
        return out

    def _x_star(self, t_loop: int) -> np.ndarray:
        t = self.t
        rel = (self.traj[t] - self.traj[t_loop]) - (self.truth[t] - self.truth[t_loop])
        return self.traj[t] - rel

    def _crossing(self, w: np.ndarray | None, tlp: np.ndarray) -> None:
        t = self.t
        if w is not None:
            if self.crossing_len == 0:
                self._grid_ll = None
            # likelihood over a grid of offsets (relative to the centroid) around x*
            h = t - self.cfg.t_l
            t_loop = int(cKDTree(self.traj[:h]).query(self.traj[t])[1])
            xs = self._x_star(t_loop)
            g = np.arange(-self.grid_half_m, self.grid_half_m + 1e-9, self.grid_step_m)
            gx, gy = np.meshgrid(g, g, indexing="ij")
            off = np.column_stack([gx.ravel(), gy.ravel()])
            if not self.grid:
                pass
            elif self._grid_ll is None:
                self._grid_ll = np.zeros(len(off))
                self._grid_x = off
            if self.grid:
                self._grid_ll += self.raw_weights(xs + off)
        ending = (
            self.crossing_len
            and (w is None and self.since_match + 1 >= self.cfg.crossing_gap_pings)
        ) or (w is not None and self.crossing_len + 1 >= self.cfg.crossing_max_pings)
        if ending:
            lw = self.logw + (np.log(np.maximum(w, 1e-300)) if w is not None else 0.0)
            wa = np.exp(lw - lw.max())
            wa /= wa.sum()
            h = t - self.cfg.t_l
            c = self.traj[t]
            t_loop = int(cKDTree(self.traj[:h]).query(c)[1])
            xs = self._x_star(t_loop)
            d = np.linalg.norm(self.x - xs, axis=1)
            wm = mode_weights(self.x, wa, self.cfg.mode_radius_m)
            in_mode = wm > 0
            mu_w = wa @ self.x
            row = {
                "mode_err": float(np.linalg.norm(wm @ self.x - xs)),
                "mode_lr": float(wa[in_mode].sum() / in_mode.mean()),
                "mode_ratio": float(
                    mode_ratio(self.x, wa, self.cfg.mode_radius_m, self.cfg.mode_apart_m)
                ),
                "mode_odds": float(
                    mode_odds(self.x, wa, self.cfg.mode_radius_m, self.cfg.mode_apart_m)
                ),
                "w_std": float(np.sqrt((wa @ ((self.x - mu_w) ** 2)).sum() / 2)),
                "t": t,
                "t_loop": t_loop,
                "len": self.crossing_len + (w is not None),
                "centroid_err": float(np.linalg.norm(c - xs)),
                "wmean_err": float(np.linalg.norm(wa @ self.x - xs)),
                "best_err": float(d[np.argmax(wa)]),
                "cloud_std": float(np.sqrt(self.x.var(0).sum() / 2)),
                "nearest": float(d.min()),
                "n_within_2m": int((d < 2).sum()),
                "neff": float(1 / np.sum(wa**2)),
                "mode_share": float(wa[in_mode].sum()),
                "abs_err_before": float(np.linalg.norm(c - self.truth[t])),
            }
            if self._grid_ll is not None and self._grid_x is not None:
                ll = self._grid_ll
                k = int(np.argmax(ll))
                row["ll_peak_off"] = float(np.linalg.norm(self._grid_x[k]))
                p = np.exp(ll - ll.max())
                p /= p.sum()
                mu = p @ self._grid_x
                row["ll_width"] = float(np.sqrt((p @ ((self._grid_x - mu) ** 2)).sum() / 2))
                row["ll_mean_off"] = float(np.linalg.norm(mu))
            self._pending = row
        n_loops = len(self.loops)
        super()._crossing(w, tlp)
        if self._pending is not None and not self.crossing_len:
            row = self._pending
            self._pending = None
            if len(self.loops) > n_loops:
                lc = self.loops[-1]
                row["resampled"] = 1
                row["accepted"] = int(lc.accepted)
                row["after_err"] = float(np.linalg.norm(lc.s_end - self._x_star(lc.t_loop)))
            else:
                row["resampled"] = 0
            self.rows.append(row)


COLS = [
    ("t", "t", "{:.0f}"),
    ("t_loop", "t_loop", "{:.0f}"),
    ("len", "pings", "{:.0f}"),
    ("abs_err_before", "|S_p - truth|", "{:.1f}"),
    ("centroid_err", "centroid - x*", "{:.1f}"),
    ("wmean_err", "w-mean - x*", "{:.1f}"),
    ("best_err", "best - x*", "{:.1f}"),
    ("after_err", "after - x*", "{:.1f}"),
    ("cloud_std", "cloud std", "{:.1f}"),
    ("nearest", "nearest - x*", "{:.1f}"),
    ("n_within_2m", "n < 2 m", "{:.0f}"),
    ("neff", "Neff", "{:.1f}"),
    ("mode_share", "mode share", "{:.2f}"),
    ("mode_lr", "mode LR", "{:.1f}"),
    ("mode_ratio", "mode ratio", "{:.1f}"),
    ("mode_odds", "mode odds", "{:.2f}"),
    ("w_std", "w std", "{:.1f}"),
    ("mode_err", "mode - x*", "{:.1f}"),
    ("ll_peak_off", "LL peak - x*", "{:.1f}"),
    ("ll_width", "LL width", "{:.1f}"),
    ("resampled", "resampled", "{:.0f}"),
    ("accepted", "accepted", "{:.0f}"),
]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="config/scenarios/bathy_survey.json")
    ap.add_argument("--particles", type=int, default=400)
    ap.add_argument("--run", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--no-grid", action="store_true", help="skip the likelihood grid (faster)")
    a = ap.parse_args(argv)
    scn = Scenario.model_validate_json(Path(a.scenario).read_text())
    world = World.from_scenario(scn)
    sim = simulate_survey(
        scn, np.random.default_rng(np.random.SeedSequence([a.seed, a.run])), world=world
    )
    over = dict(kv.split("=", 1) for kv in a.set)
    cfg = BathyConfig.model_validate({**over, "n_particles": a.particles})
    rng = np.random.default_rng(np.random.SeedSequence([a.seed, a.run, zlib.crc32(b"mtm-pf")]))
    f = Probe(cfg, len(sim.t), rng)
    f.truth = sim.truth
    f.grid = not a.no_grid
    u = sim.controls()
    f.start(sim.dr[0], sim.offsets[0], sim.depth[0])
    for k in range(1, len(sim.t)):
        f.step(u[k - 1], sim.offsets[k], sim.depth[k])
        if k % 200 == 0:
            print(f"\r{k}/{len(sim.t)} pings", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    fin = float(np.linalg.norm(f.trajectory()[-1] - sim.truth[-1]))
    dr = float(np.linalg.norm(sim.dr[-1] - sim.truth[-1]))
    lines = [
        f"`{' '.join(['diag_bathy_crossings.py', *(argv or sys.argv[1:])])}`",
        "",
        f"N = {a.particles}, run {a.run}; final error {fin:.1f} m (DR {dr:.1f} m); "
        f"{len(f.loops)} closures, {sum(lc.accepted for lc in f.loops)} accepted",
        "",
        "| " + " | ".join(c[1] for c in COLS) + " |",
        "|" + "---|" * len(COLS),
    ]
    for r in f.rows:
        lines.append(
            "| " + " | ".join(fmt.format(r[k]) if k in r else "-" for k, _, fmt in COLS) + " |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
