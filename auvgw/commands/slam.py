"""``auvgw slam eval``: Monte Carlo evaluation of the landmark SLAM filters on a scenario.

Example (the VB paper's Table 4 first row on Bailey's dense map)::

    auvgw slam eval --scenario config/scenarios/densemap.json \\
        --algorithms fastslam2,ufastslam,vb-afastslam,vb-aufastslam --runs 30 \\
        --noise n=2,p=0.1 --jobs 2 --out docs/results/table4

The VR paper's claims on the harbour with line features (quay walls observed as (rho, theta)
lines, the AUV on its waypoints)::

    auvgw slam eval --scenario config/scenarios/harbour.json --features lines \\
        --algorithms fastslam1,fastslam2,vrfastslam --runs 10 --out docs/results/vr_harbour

``--noise`` may be repeated: one table per setting. Prints the tables as text; with ``--out`` also
writes ``tables.md`` (with the command line), ``results.json`` (the summaries) and one PNG per
noise setting (trajectories of run 0, mean Neff over time).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections.abc import Callable
    from concurrent.futures import Executor

    from auvgw.slam.evaluation.metrics import RunResult
    from auvgw.slam.evaluation.runner import Study

from auvgw.commands.common import SubParsers, UserError, study_algorithms
from auvgw.slam import pipelines

__all__ = ["command_line", "parse_noise", "register", "run", "run_landmark", "run_magnetic"]


def parse_noise(text: str) -> tuple[float, float]:
    """``n=2,p=0.3`` -> ``(2.0, 0.3)``: with probability p an observation has covariance n R0."""
    vals: dict[str, float] = {}
    for part in text.split(","):
        key, sep, val = part.partition("=")
        key = key.strip()
        if not sep or key not in ("n", "p"):
            raise UserError(f"--noise {text!r}: expected n=FACTOR,p=PROBABILITY")
        try:
            vals[key] = float(val)
        except ValueError:
            raise UserError(f"--noise {text!r}: {key} must be a number, got {val!r}") from None
    n, p = vals.get("n", 1.0), vals.get("p", 0.0)
    if n < 1.0 or not 0.0 <= p <= 1.0:
        raise UserError(f"--noise {text!r}: need n >= 1 and 0 <= p <= 1")
    return n, p


def register(sub: SubParsers) -> None:
    p = sub.add_parser("slam", help="SLAM tools (evaluation against simulated ground truth)")
    ssub = p.add_subparsers(dest="slam_command", required=True, metavar="SUBCOMMAND")
    e = ssub.add_parser("eval", help="Monte Carlo comparison of SLAM filters")
    e.add_argument("--scenario", required=True, type=Path, help="scenario JSON file")
    e.add_argument(
        "--pipeline",
        default=pipelines.default().name,
        choices=pipelines.names("slam"),
        help="; ".join(f"{p.name}: {p.summary}" for p in pipelines.of_kind("slam")),
    )
    e.add_argument(
        "--variant",
        action="append",
        default=None,
        metavar="KEY=VAL,...",
        help="magnetic pipeline: a study variant (repeatable), e.g. track=mlp,density=first-half",
    )
    e.add_argument(
        "--algorithms",
        default=None,
        help="comma-separated algorithm names (default: "
        + "; ".join(f"{p.name} {p.eval_algorithms}" for p in pipelines.of_kind("slam")) + ")",
    )
    e.add_argument("--runs", type=int, default=10, help="Monte Carlo runs per noise setting")
    e.add_argument(
        "--features",
        default="points",
        choices=["points", "lines"],
        help="observe the point features (range, bearing) or the walls (features.lines) as "
        "(rho, theta) lines",
    )
    e.add_argument(
        "--noise",
        action="append",
        default=None,
        metavar="n=N,p=P",
        help="dynamic observation noise (repeatable); default: the scenario's",
    )
    e.add_argument("--jobs", type=int, default=1, help="worker processes")
    e.add_argument(
        "--dask",
        default=None,
        metavar="ADDRESS",
        help="run the trials on an existing Dask cluster (scheduler tcp://host:8786) instead "
        "of local processes; same results for the same seed",
    )
    e.add_argument(
        "--set",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="bathymetric: override a BathyConfig value (repeatable), e.g. --set lccd=false",
    )
    e.add_argument("--particles", type=int, default=100, help="particles per filter")
    e.add_argument("--association", default="known", choices=["known", "nn", "jcbb"],
                   help="landmark pipeline (magnetic: --variant association=nn|known)")  # fmt: skip
    e.add_argument("--seed", type=int, default=0, help="base seed of the study")
    e.add_argument(
        "--r0-scale",
        type=float,
        default=1.0,
        help="the filters assume this multiple of the true R0 (mis-specified noise)",
    )
    e.add_argument(
        "--oracle-noise",
        action="store_true",
        help="tell the particle filters each observation's true covariance (n R0 in a burst):"
        " the most any noise adaptation can gain",
    )
    e.add_argument("--max-steps", type=int, default=None, help="truncate each run (steps)")
    e.add_argument("--out", type=Path, default=None, help="directory for tables.md, JSON, PNG")
    e.add_argument("--no-progress", action="store_true", help="no progress bar")
    e.set_defaults(func=run)
    from auvgw.commands import slam_run

    slam_run.configure(
        ssub.add_parser(
            "run",
            help=slam_run.HELP,
            description=slam_run.__doc__,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
    )


def command_line(args: argparse.Namespace) -> str:
    """The ``auvgw slam eval`` command line equivalent to ``args`` (recorded with the tables;
    the bathymetric evaluation records its own, :func:`auvgw.commands.slam_bathy.command_line`)."""
    pipe = pipelines.get(args.pipeline)
    parts = ["auvgw", "slam", "eval", "--scenario", str(args.scenario)]
    parts += ["--pipeline", pipe.name] if pipe != pipelines.default() else []
    for t in args.variant or []:
        parts += ["--variant", t]
    parts += ["--features", args.features] if args.features != "points" else []
    parts += ["--algorithms", args.algorithms, "--runs", str(args.runs)]
    for t in args.noise or []:
        parts += ["--noise", t]
    parts += ["--jobs", str(args.jobs)]
    if pipe.particle_filters:
        parts += ["--particles", str(args.particles), "--association", args.association]
    parts += ["--seed", str(args.seed)]
    if args.r0_scale != 1.0:
        parts += ["--r0-scale", f"{args.r0_scale:g}"]
    if args.oracle_noise:
        parts += ["--oracle-noise"]
    if args.max_steps is not None:
        parts += ["--max-steps", str(args.max_steps)]
    if getattr(args, "dask", None):
        parts += ["--dask", args.dask]
    if args.out is not None:
        parts += ["--out", str(args.out)]
    return " ".join(shlex.quote(p) for p in parts)


def _monte_carlo(
    study: Study,
    jobs: int,
    progress: Callable[[RunResult], None] | None,
    executor: Executor | None = None,
) -> list[RunResult]:
    """:func:`~auvgw.slam.evaluation.runner.monte_carlo` with scenario errors (a route the
    vehicle cannot drive) as user errors."""
    from auvgw.config.scenario import ScenarioError
    from auvgw.slam.evaluation.runner import monte_carlo

    try:
        return monte_carlo(study, jobs=jobs, progress=progress, executor=executor)
    except ScenarioError as exc:
        raise UserError(str(exc)) from None


class _Progress(Protocol):
    """A progress bar (tqdm's): one more step done."""

    def update(self, n: float = 1) -> bool | None: ...


def _advance(bar: _Progress) -> Callable[[RunResult], None]:
    def step(_result: RunResult) -> None:
        bar.update(1)

    return step


def run(args: argparse.Namespace) -> int:
    """Run the pipeline's evaluation (its registry record's ``evaluation``, with its default
    ``--algorithms``) and print the tables; returns the exit code."""
    pipe = pipelines.get(args.pipeline)
    if args.algorithms is None:
        args.algorithms = pipe.eval_algorithms
    entry: Callable[[argparse.Namespace], int] = pipe.entry("evaluation")
    return int(entry(args))


def run_magnetic(args: argparse.Namespace) -> int:
    """``slam eval --pipeline magnetic``: :func:`auvgw.slam.magnetic.evaluation.run_cli` with
    the command line recorded beside its tables."""
    from auvgw.slam.magnetic.evaluation import run_cli

    return run_cli(args, command_line(args))


def run_landmark(args: argparse.Namespace) -> int:
    """``slam eval --pipeline landmark``: the Monte Carlo study of the landmark filters, on
    local processes or a Dask cluster (``--dask``)."""
    from contextlib import ExitStack

    from auvgw.slam.evaluation.executor import ExecutorError, open_executor

    with ExitStack() as stack:
        try:
            executor = stack.enter_context(open_executor(1, args.dask)) if args.dask else None
        except ExecutorError as exc:
            raise UserError(str(exc)) from None
        return _run_landmark(args, executor)


def _run_landmark(args: argparse.Namespace, executor: Executor | None) -> int:
    from auvgw.config.scenario import ScenarioError, load_scenario
    from auvgw.slam.evaluation.report import format_table, plot_results, summaries_by_algorithm
    from auvgw.slam.evaluation.runner import Study
    from auvgw.slam.landmark.registry import ALGORITHMS

    algorithms = study_algorithms(args, ALGORITHMS)
    if args.association == "jcbb" and any(not a.endswith("ekf") for a in algorithms):
        raise UserError("--association jcbb is for the EKF family (ekf, shekf, stekf, caekf)")
    try:
        scenario = load_scenario(args.scenario)
        pts = scenario.point_features()
    except ScenarioError as exc:
        raise UserError(str(exc)) from None
    if args.features == "lines" and not scenario.features.lines:
        raise UserError(f"{args.scenario}: --features lines needs walls in features.lines")
    if args.features == "points" and not pts:
        raise UserError(
            f"{args.scenario}: no point features (features.points / points_file); "
            "use --features lines for walls"
        )
    settings = (
        [parse_noise(t) for t in args.noise]
        if args.noise
        else [(scenario.observations.burst_n, scenario.observations.burst_p)]
    )
    command = command_line(args)
    blocks_txt: list[str] = []
    blocks_md: list[str] = []
    summary_json: list[dict[str, object]] = []
    for n, p in settings:
        study = Study(
            scenario=scenario,
            algorithms=algorithms,
            runs=args.runs,
            burst_n=n,
            burst_p=p,
            n_particles=args.particles,
            association=args.association,
            seed=args.seed,
            r0_scale=args.r0_scale,
            max_steps=args.max_steps,
            features=args.features,
            oracle_noise=args.oracle_noise,
        )
        total = args.runs * len(algorithms)
        if args.no_progress:
            results = _monte_carlo(study, args.jobs, None, executor)
        else:
            from tqdm import tqdm

            with tqdm(total=total, desc=f"n={n:g}, p={p:g}", unit="run", file=sys.stderr) as bar:
                results = _monte_carlo(study, args.jobs, _advance(bar), executor)
        sums = summaries_by_algorithm(results, algorithms)
        title = (
            f"{scenario.name}"
            + (f", {args.features}" if args.features != "points" else "")
            + f": n = {n:g}, p = {p:g} ({args.runs} runs, {args.particles} particles,"
            f" {args.association} association"
            + (f", filters assume {args.r0_scale:g} R0" if args.r0_scale != 1.0 else "")
            + (", oracle noise" if args.oracle_noise else "")
            + ")"
        )
        txt = format_table(title, sums)
        print(txt)
        blocks_txt.append(txt)
        blocks_md.append(format_table(title, sums, markdown=True))
        summary_json.append({"n": n, "p": p, "summaries": [asdict(s) for s in sums]})
        if args.out is not None:
            tag = f"_{args.features}" if args.features != "points" else ""
            png = args.out / f"{scenario.name}{tag}_n{n:g}_p{p:g}.png"
            try:
                plot_results(results, algorithms, png, title)
            except ImportError:
                print("matplotlib is not installed: no plot written", file=sys.stderr)
            else:
                print(f"plot: {png}", file=sys.stderr)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        md = [f"Made by:\n\n```\n{command}\n```\n", *blocks_md]
        (args.out / "tables.md").write_text("\n".join(md))
        (args.out / "results.json").write_text(
            json.dumps({"command": command, "settings": summary_json}, indent=1)
        )
        print(f"tables: {args.out / 'tables.md'}", file=sys.stderr)
    return 0
