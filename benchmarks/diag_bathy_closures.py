"""Every loop closure of one mtm-pf run (issue 14, LCCD study): where it ended (truth at
``t_end``, m NED), whether that lies in a sand-wave field of the scenario, its truth label
(A22, ``evaluate.label_loops``), LCCD's decision, and the loop-interval error before and after
its jump (m). Same survey and filter draws as run ``--run`` of ``auvgw slam eval --seed S``.

    nice -n 10 .venv/bin/python benchmarks/diag_bathy_closures.py \
        --scenario config/scenarios/bathy_sandfield.json --run 7 [--set lccd=false ...]
"""

from __future__ import annotations

import argparse
import zlib

import numpy as np

from auvgw.config.scenario import load_scenario
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import label_loops, run_filter
from auvgw.slam.bathymetric.simulate import simulate_survey


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="config/scenarios/bathy_sandfield.json")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--run", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    scn = load_scenario(args.scenario)
    world = World.from_scenario(scn)
    rng = np.random.default_rng(np.random.SeedSequence([args.seed, args.run]))
    sim = simulate_survey(scn, rng, world=world)
    extra = dict(kv.split("=", 1) for kv in args.set)
    cfg = BathyConfig.model_validate({**extra, "n_particles": args.particles})
    frng = np.random.default_rng(
        np.random.SeedSequence([args.seed, args.run, zlib.crc32(b"mtm-pf")])
    )
    res, f = run_filter("mtm-pf", sim, cfg, frng, run=args.run)
    fields = [fl.extent_m for fl in scn.terrain.sand_fields]
    print(f"{scn.name} run {args.run} seed {args.seed} {args.set}: final {res.final_error_m:.1f} m")
    err = np.linalg.norm(f.trajectory() - sim.truth, axis=1)
    eb = res.extra
    print(
        f"error budget: last accepted closure at ping {eb['last_closure_ping']:.0f}, final "
        f"trajectory's error there {eb['err_at_last_closure_m']:.1f} m, accrued since "
        f"{eb['accrued_since_m']:.1f} m (DR's drift since {eb['dr_drift_since_m']:.1f} m)"
    )
    print(
        "rate = -V/(t_end - t_loop) (eq. 25: the DR drift per ping the closure implies, mm per "
        "axis); true = DR's own over the interval; e_loop, e_end: the final trajectory's error"
    )
    print(
        "t_end t_loop   x_end   y_end field valid accepted err_before err_after "
        "     rate (mm)      true (mm) e_loop e_end"
    )
    for lc, valid in zip(f.loops, label_loops(f, sim.truth), strict=True):
        x, y = sim.truth[lc.t_end]
        in_field = any(x0 <= x <= x1 and y0 <= y <= y1 for x0, x1, y0, y1 in fields)
        true_d = sim.truth[lc.t_end] - sim.truth[lc.t_loop]
        before = np.linalg.norm((lc.s_end_before - lc.s_loop) - true_d)
        after = np.linalg.norm((lc.s_end - lc.s_loop) - true_d)
        span = max(lc.t_end - lc.t_loop, 1)
        rate = -lc.v_end / span * 1e3
        true = ((sim.dr[lc.t_end] - sim.dr[lc.t_loop]) - true_d) / span * 1e3
        print(
            f"{lc.t_end:5d} {lc.t_loop:6d} {x:7.0f} {y:7.0f} {'yes' if in_field else 'no':>5} "
            f"{'yes' if valid else 'no':>5} {'yes' if lc.accepted else 'no':>8} "
            f"{before:10.1f} {after:9.1f} {rate[0]:6.1f} {rate[1]:6.1f}  {true[0]:6.1f} "
            f"{true[1]:6.1f} {err[lc.t_loop]:6.1f} {err[lc.t_end]:5.1f}"
        )


if __name__ == "__main__":
    main()
