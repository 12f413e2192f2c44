"""The pipeline registry (auvgw.slam.pipelines): every record's targets exist and agree with
their stage, the demo's choice per shipped scenario, the Rerun stage's views, the closed-loop
pilot a record of kind "control" that the SLAM commands leave out; and a toy pipeline
registered here, in the test, runs through ``auvgw slam run`` and ``auvgw slam eval`` without a
line of the commands knowing it (docs/adding-a-pipeline.md shows the same example)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from auvgw.commands.demo_parts import (
    DemoContext,
    DemoPlan,
    DemoProcess,
    InProcessContext,
    InProcessPlan,
)
from auvgw.commands.demo_report import SlamReport, Track, _report, print_vs_truth
from auvgw.config.scenario import load_scenario
from auvgw.fusion.odometry import Odometry
from auvgw.ground.paths import config_file
from auvgw.slam import pipelines
from auvgw.slam.history import HeldSamples
from auvgw.slam.outputs import PoseEstimate
from auvgw.stages.base import BusCounters, PipelineStage, StageConfig

# -- the registry ---------------------------------------------------------------------------------


@pytest.mark.parametrize("record", pipelines.of_kind("slam"), ids=lambda r: r.name)
def test_every_record_names_what_exists(record: pipelines.Pipeline) -> None:
    online, stage = pipelines.load(record.online), pipelines.load(record.stage)
    assert isinstance(online, type) and issubclass(stage, PipelineStage | _landmark_stage())
    run = pipelines.load(record.run)
    assert all(callable(getattr(run, f)) for f in ("add_arguments", "live", "offline"))
    assert callable(pipelines.load(record.evaluation))
    assert set(stage.outputs) <= set(record.output_names)  # the viz knows every output
    assert config_file(f"scenarios/{record.demo_scenario}.json").is_file()
    assert (Path(__file__).parents[2] / "docs" / record.doc).is_file()


def _landmark_stage() -> type:
    from auvgw.stages.slam import SlamStage

    return SlamStage


@pytest.mark.parametrize("record", pipelines.of_kind("slam"), ids=lambda r: r.name)
def test_the_demo_runs_each_pipeline_on_its_own_scenario(record: pipelines.Pipeline) -> None:
    scn = load_scenario(config_file(f"scenarios/{record.demo_scenario}.json"))
    assert pipelines.for_demo(scn) is record


#: each shipped pipeline's processes in `demo --processes` on its scenario: (name, started after
#: the sim's clock, its `auvgw` command), the components waited for, its status component
DEMO_PLANS = {
    "magnetic": ([("slam", True, ["slam", "run", "--pipeline", "magnetic"])],
                 {"magnetometer", "acoustic", "slam-magnetic"}, "slam-magnetic"),
    "bathymetric": ([("slam", False, ["slam", "run", "--pipeline", "bathymetric"])],
                    {"multibeam", "slam-bathymetric"}, "slam-bathymetric"),
    "landmark": ([("slam", False, ["slam-run"])], {"msis", "slam-vb-aufastslam"},
                 "slam-vb-aufastslam"),
}  # fmt: skip


@pytest.mark.parametrize("record", pipelines.of_kind("slam"), ids=lambda r: r.name)
def test_each_record_gives_its_demo_processes(record: pipelines.Pipeline) -> None:
    """The processes ``demo --processes`` starts for a pipeline come from its record, each on
    the demo's bus (its hub, an endpoint of its own); one started after the sim's clock is
    given the clock's epoch."""
    path = config_file(f"scenarios/{record.demo_scenario}.json")
    ports = iter(range(2, 10))
    ctx = DemoContext(path, load_scenario(path), "auv1", "tcp/127.0.0.1:1",
                      lambda: f"tcp/127.0.0.1:{next(ports)}")  # fmt: skip
    plan = pipelines.load(record.demo_processes)(ctx)
    procs, alive, component = DEMO_PLANS[record.name]
    argvs = [p.argv(123 if p.after_clock else None) for p in plan.processes]
    assert [(p.name, p.after_clock, a[:len(cmd)]) for p, a, (_, _, cmd)
            in zip(plan.processes, argvs, procs, strict=True)] == procs  # fmt: skip
    assert plan.alive == alive and plan.component == component and plan.display
    for argv in argvs:
        i = argv.index("--connect")
        assert argv[i + 1] == "tcp/127.0.0.1:1" and argv[i + 2] == "--listen"
    assert len({a[a.index("--listen") + 1] for a in argvs}) == len(argvs)
    if record.name == "magnetic":
        assert argvs[0][argvs[0].index("--clock-epoch-ns") + 1] == "123"


def test_lookups_and_their_errors() -> None:
    assert pipelines.names("slam") == ["magnetic", "bathymetric", "landmark"]
    assert pipelines.names() == ["magnetic", "bathymetric", "landmark", "pilot"]
    assert pipelines.names("control") == ["pilot"] and pipelines.sections() == ("pilot",)
    assert pipelines.for_section("pilot") is pipelines.get("pilot")
    assert pipelines.for_section("slam") is None and pipelines.for_segment("pilot") is not (
        pipelines.get("pilot"))  # a SLAM segment named pilot is a landmark filter's
    assert pipelines.default().name == "landmark"
    # the landmark stage's key segment is its algorithm's name
    assert pipelines.for_segment("vb-aufastslam") is pipelines.get("landmark")
    assert pipelines.for_segment("bathymetric").view_of("map") == "dem"
    assert pipelines.get("landmark").view_of("map") == "landmarks"
    assert pipelines.get("magnetic").view_of("observations") == "ranges"
    assert pipelines.get("magnetic").view_of("cloud") is None
    with pytest.raises(KeyError, match="unknown pipeline 'sonar'; known: magnetic"):
        pipelines.get("sonar")
    with pytest.raises(ValueError, match="already registered"):
        pipelines.register(pipelines.get("magnetic"))
    with pytest.raises(ValueError, match="unknown view 'mesh'"):
        pipelines.Output("map", "mesh")
    with pytest.raises(KeyError, match="unknown pipeline kind 'sonar'"):
        pipelines.of_kind("sonar")
    with pytest.raises(ValueError, match=r"pipeline pilot \(control\) has no run"):
        pipelines.get("pilot").entry("run")
    common = {"online": "m:C", "stage": "m:S", "outputs": ()}
    with pytest.raises(ValueError, match="unknown kind 'steer'"):
        pipelines.Pipeline("x", "x", kind="steer", **common)
    with pytest.raises(ValueError, match="a control record needs command, demo_option, demo_run"):
        pipelines.Pipeline("x", "x", kind="control", **common)
    with pytest.raises(ValueError, match="a slam record needs run, evaluation, eval_algorithms"):
        pipelines.Pipeline("x", "x", **common)


# -- the closed-loop pilot: a record of kind "control" ---------------------------------------------


def test_the_pilot_record_names_what_exists() -> None:
    """Its pure class, its stage (whose outputs are the record's, on ``auv/<v>/pilot/``), its
    command (registered), its demo option and entry, its scenario and page."""
    from auvgw.commands import COMMANDS
    from auvgw.stages.base import Stage

    rec = pipelines.get("pilot")
    assert rec.kind == "control" and rec.section == "pilot"
    assert isinstance(pipelines.load(rec.online), type)
    stage = pipelines.load(rec.stage)
    assert issubclass(stage, Stage) and not issubclass(stage, PipelineStage)
    assert set(stage.outputs) == set(rec.output_names)
    assert {o.what: o.view for o in rec.outputs} == {"state": "setpoints", "command": "commands",
                                                     "ack": None}  # fmt: skip
    assert COMMANDS[rec.name][0] == rec.command and callable(rec.entry("command").register)
    assert callable(rec.entry("demo_run"))
    assert config_file(f"scenarios/{rec.demo_scenario}.json").is_file()
    assert (Path(__file__).parents[2] / "docs" / rec.doc).is_file()


def test_the_slam_commands_offer_only_slam_pipelines(capsys) -> None:
    """``slam eval`` and ``slam run`` take their choices from the SLAM records; the pilot's
    options stay in ``auvgw pilot``; ``auvgw demo`` has the pilot's option."""
    from auvgw.cli import build_parser

    def options(command: str, *sub: str) -> dict[str, argparse.Action]:
        p = build_parser(command)
        for word in (command, *sub):
            p = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices[
                word]  # fmt: skip
        return {o: a for a in p._actions for o in a.option_strings}

    slam_names = ["magnetic", "bathymetric", "landmark"]
    for sub in ("eval", "run"):
        assert list(options("slam", sub)["--pipeline"].choices) == slam_names
    from auvgw.bus import add_bus_arguments

    bus = argparse.ArgumentParser()
    add_bus_arguments(bus)
    shared = {o for a in bus._actions for o in a.option_strings} | {"--vehicle", "--duration"}
    pilot_only = set(options("pilot")) - shared
    assert "--mission" in pilot_only and not pilot_only & set(options("slam", "run"))
    assert pipelines.get("pilot").demo_option in options("demo")
    with pytest.raises(SystemExit) as exc:
        build_parser("slam").parse_args(["slam", "eval", "--pipeline", "pilot",
                                          "--scenario", "x.json"])  # fmt: skip
    assert exc.value.code == 2 and "invalid choice: 'pilot'" in capsys.readouterr().err


def test_the_rerun_stage_shows_a_control_pipeline_by_its_record(tmp_path: Path) -> None:
    """A control pipeline registered under another name is shown from its record's views, at
    ``<name>/...``; an output without a view is counted, not shown."""
    from auvgw.viz.logger import RerunLogger
    from auvgw.viz.readback import read_recording
    from auvgw.viz.stage import VizStage

    pilot = pipelines.get("pilot")
    helm = pipelines.Pipeline("helm", "a second autopilot (a test)", kind="control",
                              online=pilot.online, stage=pilot.stage, command=pilot.command,
                              outputs=(pipelines.Output("state", "setpoints"),
                                       pipelines.Output("ack", None)),
                              demo_option="--helm", demo_run=pilot.demo_run)  # fmt: skip
    pipelines.register(helm)
    try:
        assert pipelines.sections() == ("pilot", "helm")
        logger = RerunLogger(rrd=tmp_path / "helm.rrd")
        viz = VizStage(logger, "auv1")
        state = {"t": 5.0, "mode": "running", "leg": 1, "cross_track": 1.5, "depth_d": 4.0}
        assert viz.handle_sample("auv/auv1/helm/state", json.dumps(state).encode()) == "logged"
        assert viz.handle_sample("auv/auv1/helm/ack", b'{"t": 5.0, "seq": 1}') == "unknown"
        assert viz.stats.unknown == {"helm:ack": 1}
        viz.stop()
        logger.close()
    finally:
        pipelines.unregister("helm")
    rec = read_recording(tmp_path / "helm.rrd")
    e = rec["helm/track"]
    row = dict(zip(e.static["SeriesLines:names"], e.values("Scalars:scalars")[0], strict=True))
    assert list(e.times) == [5_000_000_000] and row["cross_track_m"] == 1.5
    assert row["depth_d_m"] == 4.0 and "pilot/track" not in rec


def test_held_samples_are_bounded_and_counted() -> None:
    held: HeldSamples[str] = HeldSamples(2)
    assert [held.hold(t, s) for t, s in ((1.0, "a"), (2.0, "b"), (3.0, "c"))] == [0, 0, 1]
    assert (held.dropped, held.held, len(held)) == (1, 3, 2)
    assert list(held.release(None)) == []
    assert list(held.release(2.5)) == [(2.0, "b")]
    assert held.clear() == 1 and len(held) == 0
    with pytest.raises(ValueError, match="limit 0"):
        HeldSamples(0)


# -- a toy pipeline, registered in the test --------------------------------------------------------
# Its whole code: a pure online class, a stage, a run module (this one) and one record.


class ToyOnline:
    """Dead reckoning every ``every``-th odometry sample: the pose ``(t, x, y, heading)``."""

    def __init__(self, every: int) -> None:
        self.every = every
        self.seen = 0

    def add(
        self, t: float, x: float, y: float, heading: float
    ) -> tuple[float, float, float, float] | None:
        self.seen += 1
        return (t, x, y, heading) if self.seen % self.every == 0 else None


class ToyConfig(StageConfig):
    every: int = 5


@dataclass
class ToyStats(BusCounters):
    published: int = 0


class ToyStage(PipelineStage):
    name = "toy"
    outputs = ("pose",)
    stats_type = ToyStats
    stats: ToyStats
    config: ToyConfig

    def setup(self) -> None:
        self.online = ToyOnline(self.config.every)

    def input_keys(self) -> list[str]:
        return [self.keys.odometry()]

    def feed_odometry(self, o: Odometry) -> None:
        with self._lock:
            pose = self.online.add(o.t, o.x, o.y, o.heading)
            if pose is not None:
                self.stats.published += 1
                self.track.append(pose)
                self.publish_message("pose", PoseEstimate(*pose), pose[0])


# the run module's three functions (the record's ``run`` is this module)
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument_group("toy pipeline").add_argument("--toy-every", type=int, default=5)


def live(args: argparse.Namespace) -> int:
    from auvgw.commands.slam_common import serve_slam

    cfg = ToyConfig(vehicle=args.vehicle, every=args.toy_every)
    return serve_slam(args, lambda session: ToyStage(cfg, session), "toy")


def offline(args: argparse.Namespace) -> int:
    from auvgw.commands.slam_common import Paths, check_recording, replay_recording
    from auvgw.subscribe import slam_output

    check_recording(args)
    poses: list[dict[str, Any]] = []
    stage = ToyStage(ToyConfig(every=args.toy_every),
                     on_publish=lambda key, payload, _t: poses.append(slam_output(payload, key)))
    paths = Paths()
    replay_recording(args, stage, paths)
    print(json.dumps({"odometry": len(paths.dr), "track": stage.track, "poses": poses}))
    return 0


def evaluate(args: argparse.Namespace) -> int:
    print(f"toy evaluation of {args.algorithms} on {args.scenario.name}")
    return 0


def accepts(scn: Any) -> bool:
    return scn.name == "toy-world"


def demo_plan(ctx: DemoContext) -> DemoPlan:
    argv = ["slam", "run", "--pipeline", "toy", "--vehicle", ctx.vehicle, *ctx.bus_args()]
    return DemoPlan((DemoProcess("slam", lambda _: argv),), frozenset({"ins", "slam-toy"}),
                    "slam-toy", "toy (every n-th odometry sample)")  # fmt: skip


def demo_inprocess(ctx: InProcessContext) -> InProcessPlan:
    stage = ToyStage(ToyConfig(vehicle=ctx.gw_cfg.vehicle), session=ctx.session,
                     on_publish=ctx.on_publish)  # fmt: skip
    return InProcessPlan(stage, "toy (every n-th odometry sample)")


def demo_report(r: SlamReport) -> dict[str, Any]:
    print(f"toy: {r.counters['stage']['published']} poses")
    print_vs_truth(f"SLAM ({r.name})", r.err, "not enough poses or truth to compare")
    return {}


TOY = pipelines.Pipeline(
    "toy",
    "dead reckoning, every n-th odometry sample (a test)",
    online=f"{__name__}:ToyOnline",
    stage=f"{__name__}:ToyStage",
    run=__name__,
    evaluation=f"{__name__}:evaluate",
    eval_algorithms="dr",
    outputs=(pipelines.Output("pose", "pose"),),
    demo_scenario="harbour",
    demo_processes=f"{__name__}:demo_plan",
    demo_accepts=f"{__name__}:accepts",
    demo_inprocess=f"{__name__}:demo_inprocess",
    demo_report=f"{__name__}:demo_report",
)


@pytest.fixture
def toy() -> Iterator[pipelines.Pipeline]:
    assert sys.modules[__name__]  # the record's targets are this module's names
    pipelines.register(TOY)
    try:
        yield TOY
    finally:
        pipelines.unregister("toy")
    assert "toy" not in pipelines.names()


REC_S = 8.0


def test_a_toy_pipeline_runs_through_slam_run_and_slam_eval(tmp_path: Path, toy, capsys) -> None:
    from auvgw.cli import main as cli_main
    from auvgw.testing.fusion_emulated import (
        dvl_stream,
        emulate,
        fusion_settings,
        harbour_ins_dvl,
        ins_dvl_frames,
        ins_output,
        write_recording,
    )

    # an INS + DVL recording of the harbour, as `auvgw record` writes it
    scn = harbour_ins_dvl(REC_S + 1.0)
    em = emulate(scn, tmp_path)
    ins, dvl = ins_output(em, 0.0, REC_S), dvl_stream(em, 0.0, REC_S)
    rec = write_recording(tmp_path / "run.mcap", "s1", {"ins": "hn100", "dvl": "pd0"},
                          ins_dvl_frames(ins, dvl), em.truth)  # fmt: skip
    settings, _ = fusion_settings(tmp_path / "fusion.json", "s1", em, ins, dvl)

    argv = ["slam", "run", "--pipeline", "toy", "--recording", str(rec),
            "--fusion-settings", str(settings), "--toy-every", "7"]  # fmt: skip
    assert cli_main(argv) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    n = out["odometry"]
    assert n > 100 and len(out["track"]) == n // 7
    assert out["track"][0][0] < out["track"][-1][0]
    # what it published on the bus: declared messages, one per pose of its track
    assert [[p["t"], p["x"], p["y"], p["heading"]] for p in out["poses"]] == out["track"]
    assert {p["type"] for p in out["poses"]} == {"SlamPose"}

    assert cli_main(["slam", "eval", "--pipeline", "toy", "--scenario", "world.json"]) == 0
    assert capsys.readouterr().out == "toy evaluation of dr on world.json\n"

    # the demo would run it on a scenario it accepts, the Rerun stage shows its pose as a pose
    assert pipelines.for_demo(scn.model_copy(update={"name": "toy-world"})) is toy
    assert pipelines.for_demo(scn) is pipelines.get("landmark")
    assert pipelines.for_segment("toy") is toy and toy.view_of("pose") == "pose"
    # and its processes in `demo --processes` are the ones its record names
    ctx = DemoContext(Path("world.json"), scn, "auv1", "tcp/127.0.0.1:1",
                      lambda: "tcp/127.0.0.1:2")  # fmt: skip
    plan = pipelines.load(toy.demo_processes)(ctx)
    assert [(p.name, p.argv(None)) for p in plan.processes] == [
        ("slam", ["slam", "run", "--pipeline", "toy", "--vehicle", "auv1",
                  "--connect", "tcp/127.0.0.1:1", "--listen", "tcp/127.0.0.1:2"])]  # fmt: skip


def test_a_toy_pipeline_runs_in_the_in_process_demo(tmp_path: Path, toy, capsys) -> None:
    """The in-process demo's part of the toy: its record's stage, made from the demo's context
    and fed odometry, publishes through the demo's hook; the demo's report prints its record's
    lines and writes the same ``navigation`` keys as for a shipped pipeline."""
    gw_cfg = SimpleNamespace(vehicle="auv1", devices={})  # what the toy reads of the sim's
    published: list[str] = []
    ctx = InProcessContext(Path("world.json"), load_scenario(config_file("scenarios/harbour.json")),
                           gw_cfg, 0, None, lambda key, _p, _t: published.append(key))  # type: ignore[arg-type]
    plan = pipelines.load(toy.demo_inprocess)(ctx)
    assert isinstance(plan.stage, ToyStage) and plan.before == {}
    truth, dr = Track(), Track()
    for i in range(20):  # 1 m/s along x; dead reckoning 0.1 m off, the toy's poses 0.2 m
        t = float(i)
        truth.add(t, t, 0.0)
        dr.add(t, t, 0.1)
        plan.stage.feed_odometry(SimpleNamespace(t=t, x=t, y=0.2, heading=0.0))
    slam = Track(*([p[k] for p in plan.stage.track] for k in range(3)))
    assert published == ["auv/auv1/slam/toy/pose"] * 4  # every 5th of 20
    args = argparse.Namespace(out=tmp_path)
    status = {"devices": {}}
    summary = _report(args, status, None, (toy, plan.display, plan.stage.counters()), dr, slam,
                      truth, None, 1.0, 2.0, {})  # fmt: skip
    out = capsys.readouterr().out
    assert "toy: 4 poses\n" in out
    assert "SLAM (toy (every n-th odometry sample)) vs truth over 15 m: RMSE 0.20 m" in out
    nav = json.loads((tmp_path / "summary.json").read_text())["navigation"]
    assert list(nav) == ["dead_reckoning", "dead_reckoning_at_slam", "slam", "slam_algorithm",
                         "paper_rmse_pct_distance"]  # fmt: skip
    # dead reckoning scored at the toy's 4 pose times (every 5th), 0.1 m off at each
    assert nav["dead_reckoning_at_slam"]["samples"] == 4
    assert nav["dead_reckoning_at_slam"]["rmse_m"] == pytest.approx(0.1)
    assert nav["slam_algorithm"] == plan.display and nav["paper_rmse_pct_distance"] is None
    assert nav["slam"]["rmse_m"] == pytest.approx(0.2)
    assert summary["slam"]["stage"]["published"] == 4
