"""Offline tuning screen for the survey demo's bathymetric settings (issues 28, 33): the
survey route(s) x filter variants x seeds, with the survey's own INS + DVL errors as the DR.

    nice -n 10 .venv/bin/python benchmarks/screen_bathy_survey.py \
        --variants '{"sharpR90": {"radius_m": 90.0, ...}}' --seeds 11 12 \
        [--scenario config/scenarios/survey.json ...]

Each variant is a set of filter settings over the demo's ``DEMO_FILTER`` (``bathy_run``); each row
prints the DR's and mtm-pf's final and RMS error (smoothed and filtered, m), the accepted closures,
the ping of the first and each closure's own error: its end relative to its loop point, estimate
against truth (``|(s_end - s_loop) - (x_end - x_loop)|``, m; median and max), and the filter's CPU
seconds. Tuning seeds only (below 1000) with ``--variants``: this is what the demo's settings are
chosen on; test seeds (1000 on) only with ``--frozen FILE``, the variants of a committed file (issue
28's held-out rule).

``--nav-heading`` (issue 28): each swath rotated by the DR's INS heading error (and/or by a constant
``--heading-offset-deg``), as the online stage rotates it with the odometry's heading (the screen,
like the paper's A30, uses the true one otherwise); a variant with ``heading_bias`` also prints the
filter's heading offset (final mean +- spread) against the swaths' own error, and its RMS error
against that error and against its change since ping 0 (a heading error constant over the whole
route turns the track and the map alike about the known start: no closure can see it).
``--delay-s D ...`` (issue 28, the along-track question): each swath is placed with the pose of
``D`` s after its ping, as the online stage did when it used the swath's receive stamp; one row per
delay (0: as before). Every row also splits the errors into x (north: along the survey's lines) and
y (east: across them), and each closure's own error into its along- and across-track parts (the
vehicle's frame at the closure's end; signed medians: a delay shows as a constant along-track part).
``--save DIR`` (issue 28, the gauge): each row's truth, DR, filtered and smoothed positions and
the DR's INS heading error at every second ping (and the last) as
``DIR/<scenario>-<seed>-<variant>.npz`` (``evaluate.save_tracks``), a ``gauge`` line per row
(the errors raw and after the best rotation about the start, the floor), and at the end
``bathy_gauge``'s table of every row and its summary.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from bathy_gauge import figures, table
from study_bathy_demo import dr_model
from study_bathy_heldout import _git_rev

from auvgw.commands.bathy_run import DEMO_FILTER
from auvgw.config.scenario import Scenario
from auvgw.ground.paths import config_file
from auvgw.sim_devices.world import World
from auvgw.slam.bathymetric.config import BathyConfig
from auvgw.slam.bathymetric.evaluate import run_filter, save_tracks
from auvgw.slam.bathymetric.filters import rotate
from auvgw.slam.bathymetric.simulate import BathyRun, DRModel, simulate_survey
from auvgw.slam.evaluation.heldout import seed_split


def delayed(sim: BathyRun, delay_s: float) -> BathyRun:
    """``sim`` with every swath placed with the truth, DR and heading of ``delay_s`` s after its
    ping (linear between pings; the pings whose delayed time is past the end dropped): the
    filter then sees soundings measured ``delay_s`` before the pose they are stored with."""
    if delay_s == 0.0:
        return sim
    keep = sim.t + delay_s <= sim.t[-1]
    t = sim.t[keep] + delay_s

    def at(v: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, sim.t, v[:, i]) for i in range(v.shape[1])])

    hd = np.interp(t, sim.t, np.unwrap(sim.heading))
    return BathyRun(t=t, truth=at(sim.truth), dr=at(sim.dr), heading=hd,
                    offsets=sim.offsets[keep], depth=sim.depth[keep], name=sim.name,
                    meta=sim.meta)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class HeadingTap(DRModel):
    """A :class:`DRModel` that keeps the INS heading error of the last run it drew."""

    psi: list[np.ndarray] = dataclasses.field(default_factory=list)

    def errors(self, truth: np.ndarray, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        e, psi = self.errors_and_heading(truth, dt_s, rng)
        self.psi[:] = [psi]
        return e


def nav_heading(sim: BathyRun, psi: np.ndarray) -> BathyRun:
    """``sim`` with every swath rotated by the navigation's heading error ``psi`` (rad, per DR
    step; the first ping takes the first step's), as the online stage places it with the
    odometry's heading where the offline screen (A30) uses the true one."""
    p = np.concatenate([psi[:1], psi])
    return dataclasses.replace(sim, offsets=rotate(sim.offsets, p[:, None]))


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", help="JSON: name -> settings over DEMO_FILTER")
    ap.add_argument("--frozen", type=Path,
                    help="a committed JSON file of variants instead: the only way to test seeds "
                         "(>= 1000)")  # fmt: skip
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 12])
    ap.add_argument(
        "--delay-s",
        type=float,
        nargs="+",
        default=[0.0],
        help="place each swath with the pose this many s after its ping (s)",
    )
    ap.add_argument(
        "--nav-heading",
        action="store_true",
        help="rotate each swath by the DR's INS heading error, as the online stage does",
    )
    ap.add_argument(
        "--heading-offset-deg",
        type=float,
        default=0.0,
        help="rotate each swath by this constant heading error as well (deg)",
    )
    ap.add_argument("--scenario", nargs="+", default=[str(config_file("scenarios/survey.json"))])
    ap.add_argument("--save", type=Path, metavar="DIR",
                    help="keep each row's tracks as DIR/<scenario>-<seed>-<variant>.npz and print "
                         "the gauge table")  # fmt: skip
    a = ap.parse_args()
    gauged: dict[str, dict[str, float]] = {}
    if (a.variants is None) == (a.frozen is None):
        ap.error("give --variants or --frozen")
    if a.frozen is not None:
        rev = _git_rev(a.frozen)
        if not rev:
            ap.error(f"--frozen {a.frozen}: not committed (freeze the settings first)")
        print(f"frozen settings: {a.frozen} at commit {rev}")
        variants = json.loads(a.frozen.read_text())
    else:
        if any(seed_split(s) != "tuning" for s in a.seeds):
            ap.error("--seeds: tuning seeds only (below 1000) with --variants; --frozen for test")
        variants = json.loads(a.variants)
    for path in a.scenario:
        data = json.loads(Path(path).read_text())
        dr = HeadingTap(**dataclasses.asdict(dr_model(data["devices"], "insdvl", 0.0)))
        data["duration_s"] = 1800
        mb = {"rate_hz": 0.85, "options": {"n_beams": 141, "swath_factor": 12}}
        data["devices"] = {"multibeam": mb}
        scn = Scenario.model_validate(data)
        world = World.from_scenario(scn)
        for seed, delay in ((s, d) for s in a.seeds for d in a.delay_s):
            sim = simulate_survey(scn, np.random.default_rng(seed), dr=dr, world=world)
            psi = np.zeros(len(sim.t) - 1)
            if a.nav_heading or a.heading_offset_deg:
                psi = dr.psi[0] * a.nav_heading + np.radians(a.heading_offset_deg)
                sim = nav_heading(sim, psi)
                p = np.degrees(psi)
                print(f"  swath heading error: mean {p.mean():+.2f} deg, std {p.std():.2f}")
            sim = delayed(sim, delay)
            d_dr = sim.dr - sim.truth
            e_dr = np.hypot(*d_dr.T)
            print(f"{Path(path).stem} seed {seed} delay {delay:g} s: DR final {e_dr[-1]:.2f} m, "
                  f"RMS {rms(e_dr):.2f} m (x {rms(d_dr[:, 0]):.2f}, y {rms(d_dr[:, 1]):.2f})",
                  flush=True)  # fmt: skip
            for name, kw in variants.items():
                cfg = BathyConfig(n_particles=200, **{**DEMO_FILTER, **kw})
                t0 = time.process_time()
                res, f = run_filter("mtm-pf", sim, cfg, np.random.default_rng([seed, 1]))
                cpu = time.process_time() - t0
                d = res.final - sim.truth
                e = np.hypot(*d.T)
                d_on = res.online - sim.truth
                acc = [lp for lp in f.loops if lp.accepted]
                own_xy = np.array([(lp.s_end - lp.s_loop)
                                   - (sim.truth[lp.t_end] - sim.truth[lp.t_loop])
                                   for lp in acc]).reshape(-1, 2)  # fmt: skip
                own = np.hypot(*own_xy.T)
                first = acc[0].t_end if acc else "-"
                med, top = (np.median(own), own.max()) if len(own) else (np.nan, np.nan)
                # the closures' own errors in the frame of the vehicle at the closure's end
                h = sim.heading[[lp.t_end for lp in acc]] if acc else np.zeros(0)
                along = own_xy[:, 0] * np.cos(h) + own_xy[:, 1] * np.sin(h)
                cross = -own_xy[:, 0] * np.sin(h) + own_xy[:, 1] * np.cos(h)
                ma, mc = (np.median(along), np.median(cross)) if len(own) else (np.nan, np.nan)
                if cfg.heading_bias:  # the filter's heading offset against the swaths' own
                    hb = np.degrees(f.heading_log[: len(sim.t)])
                    hp = np.degrees(np.concatenate([psi[:1], psi]))[: len(hb)]
                    print(f"    {name} heading offset: final {hb[-1, 0]:+.2f} +- "
                          f"{hb[-1, 1]:.2f} deg "
                          f"(swath's {hp[-1]:+.2f}); RMS error {rms(hb[:, 0] - hp):.2f} deg, "
                          f"against its change since ping 0 {rms(hb[:, 0] - hp + hp[0]):.2f}, "
                          f"mean spread {hb[:, 1].mean():.2f} deg", flush=True)  # fmt: skip
                print(f"  {name}: final {e[-1]:.2f} RMS {rms(e):.2f} (x {rms(d[:, 0]):.2f}, y "
                      f"{rms(d[:, 1]):.2f}) filt {rms(res.err_online):.2f} (x "
                      f"{rms(d_on[:, 0]):.2f}, y {rms(d_on[:, 1]):.2f}); closures {len(acc)}/"
                      f"{len(f.loops)}, first at ping {first}, own error median {med:.2f} max "
                      f"{top:.2f}, signed median along {ma:+.2f} across {mc:+.2f}; CPU "
                      f"{cpu:.0f} s", flush=True)  # fmt: skip
                if a.save is not None:
                    tag = f"{Path(path).stem}-{seed}-{name}" + (f"-d{delay:g}" if delay else "")
                    ins = np.concatenate([dr.psi[0][:1], dr.psi[0]])[: len(sim.t)]
                    save_tracks(a.save / f"{tag}.npz", sim.t, ins, 2, truth=sim.truth,
                                dr=sim.dr, filtered=res.online, smoothed=res.final)  # fmt: skip
                    with np.load(a.save / f"{tag}.npz") as z:
                        g = gauged[tag] = figures(z)
                    print(f"    gauge: DR yaw {g['dr_angle_deg']:+.3f} deg, aligned final / RMS "
                          f"{g['dr_al_final']:.2f} / {g['dr_al_rmse']:.2f}; floor "
                          f"{g['floor_final']:.2f} / {g['floor_rmse']:.2f}; SLAM smoothed yaw "
                          f"{g['smoothed_angle_deg']:+.3f} deg, aligned final / filt / smoothed "
                          f"{g['filtered_al_final']:.2f} / {g['filtered_al_rmse']:.2f} / "
                          f"{g['smoothed_al_rmse']:.2f}", flush=True)  # fmt: skip
    if gauged:
        print()
        print(table(gauged))


if __name__ == "__main__":
    main()
