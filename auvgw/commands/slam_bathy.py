"""``auvgw slam eval --pipeline bathymetric``: Monte Carlo comparison of the bathymetric
PF-SLAM filters (mtm-pf, bpslam, dr) on a survey scenario, the measures of Zhang et al. 2021.

Example (the paper's simulated-data experiment analog, N = 400)::

    auvgw slam eval --pipeline bathymetric --scenario config/scenarios/bathy_survey.json \\
        --algorithms mtm-pf,bpslam,dr --runs 20 --particles 400 --jobs 2 \\
        --out docs/results/bathymetric/n400

``--set KEY=VALUE`` overrides any :class:`~auvgw.slam.bathymetric.config.BathyConfig` value
(``--set lccd=false``, ``--set radius_m=20``). With ``--out`` writes ``tables.md`` (with the
command line), ``results.json`` and three PNGs (map, trajectories, error over time).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from auvgw.commands.common import UserError, study_algorithms
from auvgw.ground.errors import format_validation_error

__all__ = ["command_line", "parse_sets", "run"]


def parse_sets(items: list[str] | None) -> dict[str, object]:
    """``["lccd=false", "radius_m=20"]`` -> ``{"lccd": False, "radius_m": 20}`` (JSON values,
    bare words as strings)."""
    out: dict[str, object] = {}
    for item in items or []:
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = json.loads(val)
        except json.JSONDecodeError:
            out[key.strip()] = val
    return out


def command_line(args: argparse.Namespace) -> str:
    """The command line equivalent to ``args`` (recorded with the tables)."""
    parts = ["auvgw", "slam", "eval", "--pipeline", "bathymetric", "--scenario", str(args.scenario)]
    parts += ["--algorithms", args.algorithms, "--runs", str(args.runs)]
    parts += ["--particles", str(args.particles), "--seed", str(args.seed)]
    for s in args.set or []:
        parts += ["--set", s]
    if args.max_steps is not None:
        parts += ["--max-steps", str(args.max_steps)]
    if args.dask:
        parts += ["--dask", args.dask]
    else:
        parts += ["--jobs", str(args.jobs)]
    if args.out is not None:
        parts += ["--out", str(args.out)]
    return " ".join(shlex.quote(p) for p in parts)


def run(args: argparse.Namespace) -> int:
    """Run the bathymetric study, print the table; returns the exit code."""
    from pydantic import ValidationError

    from auvgw.config.scenario import ScenarioError, load_scenario
    from auvgw.slam.bathymetric.config import BathyConfig
    from auvgw.slam.bathymetric.filters import FILTERS
    from auvgw.slam.bathymetric.study import (
        BathyStudy,
        format_bathy_table,
        monte_carlo,
        plot_bathy,
        summary,
    )
    from auvgw.slam.evaluation.executor import ExecutorError, open_executor

    algorithms = study_algorithms(args, FILTERS)
    try:
        cfg = BathyConfig(**{"n_particles": args.particles, **parse_sets(args.set)})
    except ValidationError as exc:
        bad = format_validation_error(exc, "--set").replace("\n", "; ")
        raise UserError(f"{bad} (see BathyConfig in docs/slam_bathymetric.md)") from None
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise UserError(str(exc)) from None
    study = BathyStudy(scenario, algorithms, args.runs, cfg, args.seed, args.max_steps)
    command = command_line(args)
    title = f"{scenario.name}: {args.runs} runs, N = {cfg.n_particles}" + (
        f" ({', '.join(args.set)})" if args.set else ""
    )
    try:
        with open_executor(args.jobs, args.dask) as ex:
            if args.no_progress:
                results = monte_carlo(study, ex)
            else:
                from tqdm import tqdm

                with tqdm(
                    total=args.runs * len(algorithms),
                    desc=scenario.name,
                    unit="run",
                    file=sys.stderr,
                ) as bar:
                    results = monte_carlo(study, ex, lambda _r: bar.update(1))
    except ExecutorError as exc:
        raise UserError(str(exc)) from None
    except ScenarioError as exc:
        raise UserError(str(exc)) from None
    sums = {a: summary([r for r in results if r.algorithm == a]) for a in algorithms}
    print(format_bathy_table(title, sums))
    if args.out is not None:
        out: Path = args.out
        out.mkdir(parents=True, exist_ok=True)
        md = f"Made by:\n\n```\n{command}\n```\n\n" + format_bathy_table(title, sums, True)
        (out / "tables.md").write_text(md)
        (out / "results.json").write_text(
            json.dumps(
                {
                    "command": command,
                    "config": cfg.model_dump(),
                    "summaries": sums,
                    "final_errors": {
                        a: [r.final_error_m for r in results if r.algorithm == a]
                        for a in algorithms
                    },
                    # truth-labelled closures of each run (A22), for the per-run false share
                    "loops_per_run": {
                        a: [
                            {"tp": r.tp, "fp": r.fp, "tn": r.tn, "fn": r.fn}
                            for r in results
                            if r.algorithm == a
                        ]
                        for a in algorithms
                    },
                    # per run: overturned closures, weak crossings and the error budget
                    # (evaluate.error_budget)
                    "extra_per_run": {
                        a: [r.extra for r in results if r.algorithm == a] for a in algorithms
                    },
                },
                indent=1,
            )
        )
        plot_bathy(results, study, out, title)
        print(f"tables: {out / 'tables.md'}", file=sys.stderr)
    return 0
