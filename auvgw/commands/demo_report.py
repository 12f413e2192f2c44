"""``auvgw demo``'s report (both modes): the summary printed and ``summary.json``, the errors
of dead reckoning and the SLAM estimate against the truth, each pipeline's own lines."""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from auvgw.commands.demo_parts import _TruthTail
from auvgw.slam import pipelines
from auvgw.subscribe import slam_output

if TYPE_CHECKING:
    from auvgw.config.scenario import Scenario


@dataclass
class Track:
    """A horizontal track: vehicle times (s), NED positions (m) and headings (rad; NaN where
    the source gives none)."""

    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    h: list[float] = field(default_factory=list)

    def add(self, t: float, x: float, y: float, h: float = math.nan) -> None:
        self.t.append(t)
        self.x.append(x)
        self.y.append(y)
        self.h.append(h)

    def add_odometry(
        self, t: float, x: float, y: float, coasting: bool, h: float = math.nan
    ) -> None:
        """Dead reckoning is scored from its first DVL fix: before it the filter has no
        velocity and holds its start position whatever the vehicle does (how long depends on
        which port the gateway opened first), after it the fix's correction carries back."""
        if self.t or not coasting:
            self.add(t, x, y, h)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.asarray(self.t), np.asarray(self.x), np.asarray(self.y)

    def xy_at(self, times: np.ndarray) -> np.ndarray:
        """(n, 2) NED positions (m) interpolated at ``times`` (vehicle s; held at the ends)."""
        t, x, y = self.arrays()
        return np.column_stack([np.interp(times, t, x), np.interp(times, t, y)])

    def at(self, times: list[float]) -> Track:
        """This track's positions interpolated at ``times`` (vehicle s) inside its own span
        (times outside it are left out; headings NaN): dead reckoning scored at a SLAM stage's
        pose times, so the two are compared at the same instants."""
        ts = np.asarray(times, dtype=float)
        if len(self.t) < 2 or not len(ts):
            return Track()
        ts = ts[(ts >= self.t[0]) & (ts <= self.t[-1])]
        xy = self.xy_at(ts)
        return Track(ts.tolist(), xy[:, 0].tolist(), xy[:, 1].tolist(), [math.nan] * len(ts))


def path_error(est: Track, truth: Track, since: float = -math.inf) -> dict[str, float] | None:
    """Horizontal error of ``est`` against ``truth`` (interpolated at the estimate's times),
    from vehicle time ``since`` (s); ``samples``: the estimates scored, ``outside_truth``: those
    left out, stamped outside the truth log's span (the last swath's pose may be stamped after
    the last truth sample) or before ``since``."""
    te, xe, ye = est.arrays()
    tt, xt, yt = truth.arrays()
    if len(te) < 2 or len(tt) < 2:
        return None
    keep = (te >= max(tt[0], since)) & (te <= tt[-1])
    if keep.sum() < 2:
        return None
    te, xe, ye = te[keep], xe[keep], ye[keep]
    ex = xe - np.interp(te, tt, xt)
    ey = ye - np.interp(te, tt, yt)
    err = np.hypot(ex, ey)
    seg = (tt >= te[0]) & (tt <= te[-1])
    dist = float(np.sum(np.hypot(np.diff(xt[seg]), np.diff(yt[seg]))))
    rmse = float(np.sqrt(np.mean(err**2)))
    return {
        "samples": len(te),
        "outside_truth": int(len(keep) - len(te)),
        "from_s": float(te[0]),
        "distance_m": dist,
        "rmse_m": rmse,
        "rmse_x_m": float(np.sqrt(np.mean(ex**2))),
        "rmse_y_m": float(np.sqrt(np.mean(ey**2))),
        "final_m": float(err[-1]),
        "rmse_pct_distance": 100.0 * rmse / dist if dist > 0 else math.nan,
    }


@dataclass
class _Progress:
    """Prints the vehicle time every 5 host seconds: the newest truth sample's (the sim's own
    clock, which an elastic or lock-step sim holds while the host is behind), not host time."""

    tail: _TruthTail
    duration: float
    last: float = 0.0

    def tick(self) -> None:
        now = time.monotonic()
        if now - self.last > 5.0:
            self.last = now
            print(f"  vehicle t = {self.tail.t:6.1f} s / {self.duration:.0f} s", flush=True)


@dataclass(frozen=True)
class SlamReport:
    """What a pipeline's own lines in the demo's summary are made from (its record's
    ``demo_report`` entry, ``report(r: SlamReport) -> dict``): its name in the summary, its
    stage's last counters (its status), its poses against the truth (:func:`path_error`, from
    dead reckoning's first DVL fix; None: too few), dead reckoning's (at the SLAM's pose times
    when it has any), the truth track (vehicle s, m NED) and a stage's smoothed trajectory with
    its closures' vehicle times (:func:`_smoothed_track`; None: no ``path`` output)."""

    name: str
    counters: dict[str, Any]
    err: dict[str, float] | None
    dead_reckoning: dict[str, float] | None
    truth: Track
    smoothed: tuple[Track, list[float]] | None


def _report(
    args: argparse.Namespace,
    status: dict[str, Any],
    fusion_counters: dict[str, Any] | None,
    slam: tuple[pipelines.Pipeline, str, dict[str, Any] | None] | None,
    dead_reckoning: Track,
    slam_track: Track,
    truth: Track,
    rrd: Path | None,
    wall: float,
    speed: float,
    extra: dict[str, Any],
    smoothed: tuple[Track, list[float]] | None = None,
) -> dict[str, Any]:
    """Print the summary and write ``summary.json`` (both modes); returns the summary.
    ``slam``: the pipeline's record, its name in the summary and its stage's counters (None:
    no SLAM stage); the record's ``demo_report`` prints the pipeline's own lines and gives its
    entries of ``navigation`` (without one: the error line alone). ``smoothed``: a stage's
    smoothed trajectory and its closures' vehicle times (:func:`_smoothed_track`)."""
    nav = path_error(dead_reckoning, truth)
    _print_summary(status, fusion_counters, nav, rrd, wall)
    navigation: dict[str, Any] = {"dead_reckoning": nav}
    slam_counters: dict[str, Any] | None = None
    record, name, counters = slam if slam is not None else (None, "", None)
    if record is not None and counters is not None:
        slam_counters = counters
        # over the same span as dead reckoning's: from the first DVL fix
        since = dead_reckoning.t[0] if dead_reckoning.t else 0.0
        slam_err = path_error(slam_track, truth, since)
        # dead reckoning at the SLAM's pose times: a ratio of the two compares the same instants
        # (its own last sample can be a second after the SLAM's last pose: up to 1.2 m apart)
        dr_at = path_error(dead_reckoning.at(slam_track.t), truth, since)
        navigation["dead_reckoning_at_slam"] = dr_at
        if record.demo_report is None:
            print_vs_truth(f"SLAM ({name})", slam_err, "not enough SLAM poses or truth to compare")
        else:
            report = pipelines.load(record.demo_report)
            navigation.update(report(SlamReport(name, counters, slam_err, dr_at or nav, truth,
                                                smoothed)))  # fmt: skip
        # a published figure to compare with (paper_rmse_pct_distance): after the others
        paper = navigation.pop("paper_rmse_pct_distance", None)
        navigation.update(slam=slam_err, slam_algorithm=name,
                          paper_rmse_pct_distance=paper)  # fmt: skip
    if slam_counters is not None:
        _save_tracks(args.out / "tracks.npz", dead_reckoning, slam_track, truth, smoothed)
    summary = {"devices": status["devices"], "fusion": fusion_counters, "slam": slam_counters,
               "navigation": navigation,
               "rrd": str(rrd) if rrd else None, "wall_s": wall, "speed": speed,
               **extra}  # fmt: skip
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return summary


def _save_tracks(
    path: Path,
    dead_reckoning: Track,
    slam_track: Track,
    truth: Track,
    smoothed: tuple[Track, list[float]] | None,
) -> None:
    """The run's tracks at the SLAM's pose times, from dead reckoning's first DVL fix and within
    the truth's span (:func:`path_error`'s), as ``path`` (:func:`evaluate.save_tracks`, issue
    28's gauge): the truth, dead reckoning and the smoothed trajectory interpolated there, the
    poses as published, and the odometry's heading error (its heading minus the truth's: what
    a SLAM stage turns its swaths with). Nothing without two such poses."""
    from auvgw.slam.bathymetric.evaluate import save_tracks

    te, xe, ye = slam_track.arrays()
    if len(truth.t) < 2 or not dead_reckoning.t:
        return
    keep = (te >= max(truth.t[0], dead_reckoning.t[0])) & (te <= truth.t[-1])
    if keep.sum() < 2:
        return
    te = te[keep]

    def heading(track: Track) -> np.ndarray:
        return np.interp(te, track.t, np.unwrap(np.asarray(track.h, float)))

    psi = heading(dead_reckoning) - heading(truth)
    psi = (psi + math.pi) % (2.0 * math.pi) - math.pi
    smo = smoothed[0].xy_at(te) if smoothed is not None and len(smoothed[0].t) > 1 else (
        np.full((len(te), 2), math.nan))  # fmt: skip
    save_tracks(path, te, psi, truth=truth.xy_at(te), dr=dead_reckoning.xy_at(te),
                filtered=np.column_stack([xe[keep], ye[keep]]), smoothed=smo)  # fmt: skip


def _print_summary(
    status: dict[str, Any],
    fusion: dict[str, Any] | None,
    err: dict[str, float] | None,
    rrd: Path | None,
    wall_s: float,
) -> None:
    print()
    print("device            connected  frames  bad  skipped  decode_err  messages")
    for name, d in sorted(status["devices"].items()):
        msgs = ", ".join(f"{k} {v}" for k, v in sorted(d["messages"].items()))
        print(f"{name:<17} {d['connected']!s:<9} {d['frames']:>7} {d['bad_frames']:>4} "
              f"{d['skipped_bytes']:>8} {d['decode_errors']:>11}  {msgs}")  # fmt: skip
    print()
    if fusion is None:
        print("fusion: no INS data, not started")
    else:
        st = fusion["stage"]
        print(f"fusion: {st.get('received', 0)} messages in, {st.get('published', 0)} "
              f"odometry out; filter {json.dumps(fusion['filter'])}")  # fmt: skip
    if err is None:
        print("navigation error: not enough odometry or truth to compare")
    else:
        print(
            f"dead reckoning vs truth over {err['distance_m']:.0f} m from its first DVL fix: "
            f"RMSE {err['rmse_m']:.2f} m "
            f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
            f"RMSE/distance {err['rmse_pct_distance']:.3f} %"
        )
    if rrd is not None:
        size = rrd.stat().st_size / 1e6 if rrd.is_file() else 0.0
        print(f"Rerun recording: {rrd} ({size:.1f} MB) - open it with: rerun {rrd}")
    print(f"wall time {wall_s:.0f} s")


def print_vs_truth(label: str, err: dict[str, float] | None, missing: str, tail: str = "") -> None:
    """``<label> vs truth``: the error (m, RMSE / distance x 100, then ``tail``), or ``missing``
    without one."""
    if err is None:
        print(f"{label} vs truth: {missing}")
        return
    print(f"{label} vs truth over {err['distance_m']:.0f} m: RMSE {err['rmse_m']:.2f} m "
          f"(x {err['rmse_x_m']:.2f}, y {err['rmse_y_m']:.2f}), final {err['final_m']:.2f} m, "
          f"RMSE/distance x 100 {err['rmse_pct_distance']:.3f} %{tail}")  # fmt: skip


def _smoothed_track(payloads: list[bytes], epoch_s: float) -> tuple[Track, list[float]] | None:
    """A stage's smoothed trajectory (its ``path`` output: the last of ``payloads``; None
    without one) as a vehicle-time track and its accepted closures' vehicle times (s)."""
    if not payloads:
        return None
    body = slam_output(payloads[-1])
    track = Track([t - epoch_s for t in body["t"]], list(body["x"]), list(body["y"]))
    return track, [t - epoch_s for t in body.get("closures_t", [])]


def _map_summary(last: list[bytes], scn: Scenario) -> dict[str, Any]:
    """``{"bathymetric_map": ...}``: a stage's last DEM (its ``dem`` output) against the
    scenario's true terrain (depth of each cell centre): cells, mean / median |error| m, share
    under 2 m (the paper's registration measure); empty when no map was published."""
    if not last:
        return {}
    from auvgw.sim_devices.world import World

    body = slam_output(last[-1])
    grid = np.array([[math.nan if v is None else v for v in row] for row in body["depth"]], float)
    i, j = np.nonzero(np.isfinite(grid))
    cell = float(body["cell_m"])
    x = float(body["x0"]) + (i + 0.5) * cell
    y = float(body["y0"]) + (j + 0.5) * cell
    err = np.abs(grid[i, j] - World.from_scenario(scn).depth(x, y))
    out: dict[str, Any] = {"cells": len(err), "pings": body.get("pings"),
                           "loops": body.get("loops"),
           "mean_abs_error_m": float(err.mean()) if len(err) else None,
           "median_abs_error_m": float(np.median(err)) if len(err) else None,
           "share_under_2m": float(np.mean(err < 2.0)) if len(err) else None}  # fmt: skip
    if len(err):
        print(f"bathymetric map vs true terrain: {out['cells']} cells of {cell:g} m, mean "
              f"|error| {out['mean_abs_error_m']:.2f} m, {100 * out['share_under_2m']:.1f} % "
              "under 2 m")  # fmt: skip
    return {"bathymetric_map": out}


def print_gain(name: str, err: dict[str, float] | None, dr: dict[str, float] | None) -> None:
    """The SLAM estimate against dead reckoning: RMSE and final error ratios (< 1: SLAM
    better)."""
    if err is None or dr is None or not dr["rmse_m"] or not dr["final_m"]:
        return
    rmse, final = err["rmse_m"] / dr["rmse_m"], err["final_m"] / dr["final_m"]
    print(f"  dead reckoning: RMSE/distance x 100 {dr['rmse_pct_distance']:.3f} %, final "
          f"{dr['final_m']:.2f} m; {name} / dead reckoning: RMSE {rmse:.2f}, "
          f"final {final:.2f}")  # fmt: skip
