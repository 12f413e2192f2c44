"""``auvgw fusion``: attitude + DVL dead reckoning, on the bus, over a recording or a log.

Online (the fusion stage as its own process)::

    auvgw fusion --vehicle auv1 --connect tcp/127.0.0.1:7447 [--settings fusion.toml]

subscribes to the gateway's decoded messages (``auv/<V>/sensor/...``) of the attitude source
(``attitude``, default device ``ins``: HN-100 serial/CAN, or a DVL's compass) and the velocity
source (``velocity``, default ``dvl``: PD0 or PD6), never "the first seen", and
publishes odometry on ``auv/<V>/nav/odometry`` and counters on ``auv/<V>/status/fusion`` until
SIGINT/SIGTERM (or ``--duration`` seconds); prints ``fusion running`` on stdout once its
subscriptions are declared.

Offline (the same stage, no bus) over a recording made by ``auvgw record``::

    auvgw fusion --recording run.mcap [--out odometry.jsonl]

decodes the recorded raw frames exactly as the gateway did (:func:`auvgw.recording.iter_recording`),
feeds them in recorded order with their receive times, and prints a summary; ``--out`` writes
every odometry sample as one JSON object per line (the bus payload's ``msg``).

Offline over a log from any vehicle (CSV/text with a header row and a column map)::

    auvgw fusion --csv log.csv --columns map.toml [--settings fusion.toml] [--out odometry.jsonl]

DVL calibration (mounting yaw and scale factor, with 1-sigma) from a log with position fixes
(GNSS at the surface, USBL)::

    auvgw fusion calibrate --csv log.csv --columns map.toml [--settings fusion.toml]

Every summary prints the fusion's diagnostics: accepted / rejected / coasting shares, NIS, the
adapted DVL noise and the warnings (more than a third of the fixes rejected, NIS inconsistent).

``--settings FILE`` (TOML or JSON): :class:`~auvgw.stages.fusion.FusionStageConfig`, with the
filter's :class:`~auvgw.fusion.FusionConfig` under ``[filter]`` (see docs/fusion.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from auvgw.bus import add_bus_arguments
from auvgw.commands.common import SubParsers, UserError, add_command, add_duration, open_output

if TYPE_CHECKING:
    from auvgw.fusion.csvlog import CsvLog
    from auvgw.fusion.odometry import Odometry
    from auvgw.fusion.samples import DepthSample, PositionFix
    from auvgw.stages.fusion import FusionStageConfig

log = logging.getLogger(__name__)

__all__ = ["register", "run"]


def register(sub: SubParsers) -> None:
    p = add_command(sub, "fusion", __doc__)
    p.add_argument(
        "action",
        nargs="?",
        choices=["calibrate"],
        help="calibrate: estimate the DVL mounting yaw and scale factor from --csv with fixes",
    )
    p.add_argument("--vehicle", default=None, help="vehicle name (default: settings, auv1)")
    p.add_argument(
        "--settings",
        type=Path,
        default=None,
        metavar="FILE",
        help="stage and filter settings (TOML or JSON)",
    )
    p.add_argument(
        "--ins",
        default=None,
        metavar="DEVICE",
        help="gateway device of the attitude source (default: settings, 'ins')",
    )
    p.add_argument(
        "--dvl",
        default=None,
        metavar="DEVICE",
        help="gateway device of the velocity source (default: settings, 'dvl')",
    )
    add_duration(p, "online: ")
    p.add_argument(
        "--recording",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="offline: run over this recording instead of the bus",
    )
    p.add_argument(
        "--csv",
        type=Path,
        default=None,
        metavar="LOG",
        help="offline: run over a CSV/text log (needs --columns)",
    )
    p.add_argument(
        "--columns",
        type=Path,
        default=None,
        metavar="MAP.toml",
        help="column map of --csv (see docs/fusion.md)",
    )
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="GATEWAY.toml",
        help="offline: gateway configuration replacing the recorded one",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="FILE.jsonl",
        help="offline: write every odometry sample (JSON lines)",
    )
    add_bus_arguments(p)
    p.set_defaults(func=run)


def _settings(args: argparse.Namespace) -> FusionStageConfig:
    from auvgw.stages.fusion import FusionStageConfig, SettingsError, load_stage_config

    try:
        cfg = load_stage_config(args.settings) if args.settings else FusionStageConfig()
    except SettingsError as exc:
        raise UserError(str(exc)) from None
    update = {
        k: v
        for k, v in (("vehicle", args.vehicle), ("ins_device", args.ins), ("dvl_device", args.dvl))
        if v is not None
    }
    return cfg.model_copy(update=update) if update else cfg


def run(args: argparse.Namespace) -> int:
    cfg = _settings(args)
    if args.action == "calibrate":
        return _calibrate(args, cfg)
    if args.csv is not None:
        return _csv(args, cfg)
    if args.recording is not None:
        return _offline(args, cfg)
    if args.out is not None or args.config is not None:
        raise UserError("--out and --config are for --recording (offline) runs")
    return _online(args, cfg)


def _read_log(args: argparse.Namespace) -> CsvLog:
    from auvgw.fusion.csvlog import LogError, load_column_map, read_csv_log

    if args.csv is None or args.columns is None:
        raise UserError("a log needs --csv LOG and --columns MAP.toml")
    try:
        log_ = read_csv_log(args.csv, load_column_map(args.columns))
    except LogError as exc:
        raise UserError(str(exc)) from None
    if log_.bad_cells:
        print(f"warning: {log_.bad_cells} bad cells skipped; first: {log_.first_error}",
              file=sys.stderr)
    return log_


def _calibrate(args: argparse.Namespace, cfg: FusionStageConfig) -> int:
    from auvgw.fusion.calibrate import CalibrationError, calibrate_dvl
    from auvgw.fusion.frames import wrap_angle

    log_ = _read_log(args)
    corr = cfg.filter.heading_correction()
    ins = [s._replace(heading=wrap_angle(s.heading + corr)) for s in log_.ins]
    try:
        cal = calibrate_dvl(ins, log_.dvl, log_.fixes, cfg.filter.dvl)
    except CalibrationError as exc:
        raise UserError(f"{args.csv}: {exc}") from None
    print(f"{args.csv}: {len(log_.ins)} attitude samples, {len(log_.dvl)} DVL fixes, "
          f"{len(log_.fixes)} position fixes")
    print(cal.describe())
    return 0


def _csv(args: argparse.Namespace, cfg: FusionStageConfig) -> int:
    import heapq

    from auvgw.drivers.spec import to_jsonable
    from auvgw.fusion import NavFilter, iter_filter

    log_ = _read_log(args)
    nav = NavFilter(cfg.filter)
    summary = _Summary()
    depth: list[DepthSample | PositionFix] = [*log_.depth]
    fixes: list[DepthSample | PositionFix] = [*log_.fixes]
    aiding = heapq.merge(depth, fixes, key=lambda x: x.t)
    out_file = open_output(args.out)
    try:
        for o in iter_filter(log_.ins, log_.dvl, depth=aiding, nav=nav):
            summary.add(o)
            if out_file is not None:
                out_file.write(json.dumps(to_jsonable(o), separators=(",", ":")) + "\n")
    finally:
        if out_file is not None:
            out_file.close()
    summary.print(args.csv)
    print_diagnostics(nav.diagnostics.summary())
    print(f"fusion counters: {json.dumps({'filter': vars(nav.stats)})}", file=sys.stderr)
    if summary.n == 0:
        print(f"no odometry: {args.csv} has no usable attitude rows", file=sys.stderr)
        return 1
    return 0


def print_diagnostics(d: dict[str, Any]) -> None:
    """The fusion's diagnostics as a few readable lines (shares, NIS, noise, warnings)."""
    tot, win = d["total"], d["window"]

    def pct(x: float | None) -> str:
        return "-" if x is None else f"{100.0 * x:.1f} %"

    print(
        f"  DVL fixes            {tot['fixes']}: accepted {pct(tot['accepted_share'])}, "
        f"rejected {pct(tot['rejected_share'])}, forced {pct(tot['forced_share'])}; "
        f"coasting {pct(tot['coasting_share'])} of epochs"
    )
    nis = win["nis_mean_per_dof"]
    sig = ", ".join("-" if s is None else f"{s:.4f}" for s in d["dvl_noise_sigma_mps"])
    print(
        f"  last {d['window_s']:g} s        NIS per dof "
        f"{'-' if nis is None else f'{nis:.2f}'} (consistent: {win['nis_consistent']}); "
        f"DVL noise (m/s per axis) {sig}"
    )
    dev = d.get("compass_deviation")
    if dev is not None and dev["has_gyro"]:
        co, sg = dev["coefficients_deg"], dev["sigma_deg"]
        terms = ", ".join(f"{k} {co[k]:+.2f} +- {sg[k]:.2f}" for k in co)
        print(
            f"  compass deviation    (deg) {terms}; gyro bias {dev['gyro_bias_dps']:+.4f} deg/s; "
            f"{'applied' if dev['applied'] else 'not applied (not confident yet)'}"
        )
    for w in d["warnings"]:
        print(f"  WARNING: {w}")


def _online(args: argparse.Namespace, cfg: FusionStageConfig) -> int:
    from auvgw.commands.run import serve_stage
    from auvgw.stages.fusion import FusionStage

    stage = serve_stage(
        args,
        lambda session: FusionStage(cfg, session),
        lambda st: f"fusion running: vehicle {cfg.vehicle}, odometry on {st.keys.odometry()}",
        lambda st: st.source_keys(),
    )
    _print_counters(stage.counters())
    return 0


def _offline(args: argparse.Namespace, cfg: FusionStageConfig) -> int:
    from auvgw.recording import RecordingError, iter_recording
    from auvgw.stages.fusion import FusionStage

    gw_cfg = None
    if args.config is not None:
        from auvgw.commands.common import load_or_fail

        gw_cfg = load_or_fail(args.config)
    out_file = open_output(args.out)  # closed in finally
    summary = _Summary()

    def on_odometry(o: Odometry) -> None:
        summary.add(o)
        if out_file is not None:
            from auvgw.drivers.spec import to_jsonable

            out_file.write(json.dumps(to_jsonable(o), separators=(",", ":")) + "\n")

    stage = FusionStage(cfg, on_odometry=on_odometry)
    try:
        for rec in iter_recording(args.recording, config=gw_cfg):
            device = rec.key.rsplit("/", 1)[-1]
            for msg in rec.messages:
                stage.feed(device, rec.t_recv_ns, msg)
        stage.flush()
    except RecordingError as exc:
        raise UserError(str(exc)) from None
    finally:
        if out_file is not None:
            out_file.close()
    summary.print(args.recording)
    print_diagnostics(stage.nav.diagnostics.summary())
    _print_counters(stage.counters())
    if summary.n == 0:
        print("no odometry: the recording has no usable INS messages", file=sys.stderr)
        return 1
    return 0


class _Summary:
    """Running summary of an offline run (no list of every sample kept)."""

    def __init__(self) -> None:
        self.n = 0
        self.first: Odometry | None = None
        self.last: Odometry | None = None
        self.distance = 0.0
        self.coasting = 0

    def add(self, o: Odometry) -> None:
        if self.first is None:
            self.first = o
        if o.increment is not None:
            self.distance += math.hypot(o.increment.dx, o.increment.dy)
        self.coasting += bool(o.coasting)
        self.last = o
        self.n += 1

    def print(self, path: Path) -> None:
        if self.first is None or self.last is None:
            return
        a, b = self.first, self.last
        sig = math.sqrt(max(float(b.cov_xy.trace()), 0.0))
        print(f"{path}: {self.n} odometry samples over {b.t - a.t:.1f} s")
        print(f"  distance travelled   {self.distance:.1f} m")
        print(
            f"  final position       x {b.x:.2f} m, y {b.y:.2f} m, z {b.z:.2f} m, "
            f"heading {math.degrees(b.heading):.1f} deg"
        )
        print(
            f"  final horizontal 1-sigma (rss) {sig:.3f} m "
            f"({100.0 * sig / self.distance if self.distance else math.nan:.3f} % of distance)"
        )
        print(f"  coasting             {100.0 * self.coasting / self.n:.1f} % of samples")


def _print_counters(c: Mapping[str, object]) -> None:
    keep = {k: c[k] for k in ("stage", "adapter", "ins_device", "dvl_device", "filter", "buffer")}
    print(f"fusion counters: {json.dumps(keep)}", file=sys.stderr)
