"""The pipeline registry: one record per pipeline, the one place a pipeline is declared.

A record is of a kind (:data:`KINDS`): ``"slam"`` (landmark, bathymetric, magnetic: an
estimate of the vehicle and its map, under ``auv/<v>/slam/<name>/``, evaluated by ``slam eval``,
run by ``slam run``, picked by the demo's scenario) or ``"control"`` (the closed-loop pilot:
set-points and commands under ``auv/<v>/<name>/``, a command of its own, picked by a demo
option). Every list of pipelines the rest of the project needs is derived from
:data:`PIPELINES`, filtered on the kind (:func:`of_kind`): the ``--pipeline`` choices and help
of ``auvgw slam eval`` and ``auvgw slam run`` (SLAM records only), the evaluation each one runs
and its default algorithms, the stage ``slam run`` serves or replays a recording through and
the options it adds to that command, the pipeline ``auvgw demo`` runs on a scenario and the
processes ``auvgw demo --processes`` starts for it, the demo option that runs a control
pipeline, the bus sections the Rerun stage subscribes to and the Rerun view each output goes
to (:mod:`auvgw.viz.stage`). A new pipeline is its own files plus one :class:`Pipeline` record
here (``docs/adding-a-pipeline.md``).

Like the device registry (:mod:`auvgw.drivers.registry`), it names classes and functions by
``"module:attribute"`` strings and imports none of them, so reading it costs nothing and the
algorithms' layer never imports the service: :func:`load` imports a target when it is used.
"""

from __future__ import annotations

import importlib
from dataclasses import KW_ONLY, dataclass
from typing import Any

__all__ = [
    "KINDS",
    "OUTPUT_VIEWS",
    "PIPELINES",
    "Output",
    "Pipeline",
    "default",
    "for_demo",
    "for_section",
    "for_segment",
    "get",
    "load",
    "names",
    "of_kind",
    "register",
    "sections",
    "unregister",
]

#: the kinds of pipeline: what each is, and where its outputs go
KINDS: dict[str, str] = {
    "slam": "an estimate of the vehicle and its map: outputs on auv/<v>/slam/<name>/<what>; "
    "slam eval, slam run, the demo's scenario",
    "control": "a closed loop on the vehicle: outputs on auv/<v>/<name>/<what>; a command of its "
    "own, a demo option",
}

#: what a pipeline output is, i.e. the Rerun view it goes to (docs/viz.md, "JSON accepted")
OUTPUT_VIEWS: dict[str, str] = {
    "pose": "the pipeline's pose estimate (x, y m NED, heading rad, cov): its trajectory, the "
    "particles it carries",
    "landmarks": "a point map (mean, cov, ids), optional line features and acoustic beacon",
    "dem": "a DEM tile (cell_m, x0, y0, depth grid m): one disc per cell in depth colours",
    "cloud": "seabed points [[x, y, depth], ...] (m, NED, depth down): accumulated",
    "path": "a smoothed trajectory (t, x, y m NED per pose) sent once at the end: its own track "
    "beside the filtered one",
    "ranges": "one beacon observation (z = [range m, bearing rad] from x, y, heading): a line "
    "from the vehicle to where it places the beacon",
    "setpoints": "an autopilot's state (t, mode, leg, cross_track / along_track m, heading_d / "
    "pitch_d rad, depth_d m, speed_d m/s, abort_reason): its track errors and set-points as "
    "series, an event at each change of mode",
    "commands": "an actuator command (t, rpm, rudder / stern rad): the fins (deg) and the shaft "
    "(rpm) as series",
}


@dataclass(frozen=True)
class Output:
    """One output of a pipeline's stage: its key segment ``what`` (``auv/<v>/slam/<p>/<what>``,
    a control pipeline's ``auv/<v>/<p>/<what>``) and its view (a key of :data:`OUTPUT_VIEWS`;
    None: not shown, a protocol message such as the pilot's lock-step ``ack``)."""

    what: str
    view: str | None

    def __post_init__(self) -> None:
        if self.view is not None and self.view not in OUTPUT_VIEWS:
            raise ValueError(f"output {self.what}: unknown view {self.view!r}")


@dataclass(frozen=True)
class Pipeline:
    """One pipeline.

    ``name``: its ``--pipeline`` value and key segment (``auv/<v>/slam/<name>/...``; a control
    pipeline's bus section, ``auv/<v>/<name>/...``); ``summary``: one line for the commands'
    help; ``kind``: a key of :data:`KINDS`; ``online``: ``"module:Class"`` of its pure online
    class (no bus: arrays and messages in, estimates or commands out); ``stage``:
    ``"module:Class"`` of its bus stage; ``outputs``: what its stage publishes; ``doc``: its
    page in ``docs/``.

    A SLAM record (each of these required): ``run``: the module of its ``slam run`` entry:
    ``add_arguments(parser)`` (its own options), ``live(args)`` and ``offline(args)`` (over
    ``--recording``), each returning the exit code; ``evaluation``: ``"module:callable"`` of
    ``slam eval`` for it, ``run(args) -> exit code``; ``eval_algorithms``: its default
    ``--algorithms``; ``particle_filters``: its evaluation reads ``--particles`` and
    ``--association`` (recorded in the command line); ``demo_scenario``: the shipped scenario
    ``auvgw demo --scenario`` runs it on; ``demo_processes``: ``"module:callable"``,
    ``plan(ctx) -> DemoPlan`` (:mod:`auvgw.commands.demo_parts`), the processes its stage needs
    in ``auvgw demo --processes``, the components the demo waits for and its stage's status
    component and summary name; ``demo_accepts``: ``"module:callable"``,
    ``accepts(scenario) -> bool``, whether the demo runs this pipeline on a scenario (None: the
    fallback, when no other record accepts it); ``demo_inprocess``: ``"module:callable"``,
    ``plan(ctx) -> InProcessPlan`` (:mod:`auvgw.commands.demo_parts`), its stage in the
    in-process ``auvgw demo`` (None: the demo runs no SLAM stage on its scenarios) and its
    summary name; ``demo_report``: ``"module:callable"``, ``report(r: SlamReport) -> dict``
    (:mod:`auvgw.commands.demo_report`), which prints its own lines of the demo's summary and
    gives its entries of ``summary.json``'s ``navigation`` (None: the error line alone);
    ``demo_idle_devices``: emulated devices ``auvgw demo`` turns off on its scenarios unless the
    scenario file turns them on (devices it does not read, which only add lag on a loaded host);
    ``demo_route_speed``: ``auvgw demo --processes`` runs its scenario's whole route at this
    speed (x real time) unless told otherwise (None: the demo's default duration and speed);
    ``any_segment``: its stage's key segment is its
    algorithm's name (the landmark filters), so a segment no record names is this pipeline's;
    ``doc``: its page in ``docs/``.

    A control record: ``command``: the module of its own command (``auvgw <name>``, registered
    in :data:`auvgw.commands.COMMANDS`); ``demo_option``: the ``auvgw demo`` option that runs it
    (its own scenario, ``demo_scenario``); ``demo_run``: ``"module:callable"``,
    ``run(args) -> exit code``, what that option runs.
    """

    name: str
    summary: str
    _: KW_ONLY
    online: str
    stage: str
    outputs: tuple[Output, ...]
    kind: str = "slam"
    run: str = ""  # "": none (a field of the other kind), likewise below
    evaluation: str = ""
    eval_algorithms: str = ""
    demo_scenario: str = ""
    demo_processes: str = ""
    demo_accepts: str | None = None
    demo_inprocess: str | None = None
    demo_report: str | None = None
    demo_idle_devices: tuple[str, ...] = ()
    demo_route_speed: float | None = None
    particle_filters: bool = True
    any_segment: bool = False
    command: str = ""
    demo_option: str = ""
    demo_run: str = ""
    doc: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"pipeline {self.name}: unknown kind {self.kind!r} "
                             f"(one of {', '.join(KINDS)})")  # fmt: skip
        need = {"slam": ("run", "evaluation", "eval_algorithms", "demo_scenario",
                         "demo_processes"),
                "control": ("command", "demo_option", "demo_run")}[self.kind]  # fmt: skip
        if missing := [f for f in need if not getattr(self, f)]:
            raise ValueError(f"pipeline {self.name}: a {self.kind} record needs "
                             f"{', '.join(missing)}")  # fmt: skip

    @property
    def section(self) -> str:
        """The bus section its outputs go under: ``slam`` (``auv/<v>/slam/<name>/<what>``), a
        control pipeline's name (``auv/<v>/<name>/<what>``)."""
        return "slam" if self.kind == "slam" else self.name

    def entry(self, field: str) -> Any:
        """What the record's target ``field`` (``run``, ``evaluation``, ``demo_processes``,
        ``command``, ``demo_run``...) names, imported (:func:`load`); a ValueError naming the
        record when it has none (a field of the other kind)."""
        target = getattr(self, field)
        if not target:
            raise ValueError(f"pipeline {self.name} ({self.kind}) has no {field}")
        return load(target)

    def view_of(self, what: str) -> str | None:
        """The view of output ``what`` (None: not an output of this pipeline)."""
        return next((o.view for o in self.outputs if o.what == what), None)

    @property
    def output_names(self) -> tuple[str, ...]:
        """The outputs' key segments, in order (a stage's ``outputs``)."""
        return tuple(o.what for o in self.outputs)


_C = "auvgw.commands"
_SB = "auvgw.slam.bathymetric"
_SM = "auvgw.slam.magnetic"

#: every pipeline; the demo tries the SLAM ones in this order (the fallback, ``demo_accepts`` None,
#: last of them)
PIPELINES: list[Pipeline] = [
    Pipeline(
        "magnetic",
        "AMB-SLAM on the MS3A magnetometer and the acoustic beacon (amb-slam, acoustic-only, "
        "mb-slam, mb-slam-fej, mb-slam-oc, dr; docs/slam_magnetic.md)",
        online=f"{_SM}.online:MagneticOnline",
        stage="auvgw.stages.magnetic:MagneticStage",
        run=f"{_C}.magnetic_run",
        evaluation=f"{_C}.slam:run_magnetic",
        # MAGNETIC_ALGORITHMS
        eval_algorithms="amb-slam,acoustic-only,mb-slam,mb-slam-fej,mb-slam-oc,dr",
        particle_filters=False,  # EKFs; the association is a --variant key
        outputs=(Output("pose", "pose"), Output("landmarks", "landmarks"),
                 Output("observations", "ranges")),
        demo_scenario="beacons",
        demo_processes=f"{_C}.magnetic_run:demo_plan",
        demo_inprocess=f"{_C}.magnetic_run:demo_inprocess",
        demo_report=f"{_C}.magnetic_run:demo_report",
        demo_accepts=f"{_C}.magnetic_run:demo_accepts",
        doc="slam_magnetic.md",
    ),
    Pipeline(
        "bathymetric",
        "mtm-pf PF-SLAM on the multibeam swaths (mtm-pf, bpslam, dr; "
        "docs/slam_bathymetric.md)",
        online=f"{_SB}.online:OnlineBathy",
        stage="auvgw.stages.bathymetric:BathymetricStage",
        run=f"{_C}.bathy_run",
        evaluation=f"{_C}.slam_bathy:run",
        eval_algorithms="mtm-pf,bpslam,dr",
        outputs=(Output("pose", "pose"), Output("map", "dem"), Output("cloud", "cloud"),
                 Output("track", "path")),
        demo_scenario="survey",
        demo_processes=f"{_C}.bathy_run:demo_plan",
        demo_inprocess=f"{_C}.bathy_run:demo_inprocess",
        demo_report=f"{_C}.bathy_run:demo_report",
        # the MSIS (polled) and the magnetometer (serial and SLCAN) took 118,000 of the 317,000
        # frames of a whole-route run here; the stage reads the INS, DVL and multibeam only
        demo_idle_devices=("msis", "magnetometer"),
        # survey.json's whole route (1812 s) in about 3 minutes: measured with --processes,
        # every INS sample arrives and the stage keeps up; its first loop closure comes with the
        # second line, about 5 minutes in
        demo_route_speed=10.0,
        demo_accepts=f"{_C}.bathy_run:demo_accepts",
        doc="slam_bathymetric.md",
    ),
    Pipeline(
        "landmark",
        "the landmark filters on MSIS point and line features (FastSLAM family, EKF family; "
        "docs/slam_online.md)",
        online="auvgw.slam.landmark.online:LandmarkOnline",
        stage="auvgw.stages.slam:SlamStage",
        run=f"{_C}.slam_run",
        evaluation=f"{_C}.slam:run_landmark",
        eval_algorithms="fastslam1,fastslam2,ufastslam,vb-afastslam,vb-aufastslam",
        # "map": the landmark map under its older name (docs/viz.md, JSON accepted)
        outputs=(Output("pose", "pose"), Output("landmarks", "landmarks"),
                 Output("map", "landmarks")),
        demo_scenario="harbour",
        demo_processes=f"{_C}.slam_run:demo_plan",
        demo_inprocess=f"{_C}.slam_run:demo_inprocess",
        demo_report=f"{_C}.slam_run:demo_report",
        any_segment=True,
        doc="slam_online.md",
    ),
    Pipeline(
        "pilot",
        "the reference autopilot flying a mission file on the fusion's odometry: set-points, "
        "actuator commands (docs/pilot.md)",
        kind="control",
        online="auvgw.control.autopilot:Autopilot",
        stage="auvgw.stages.pilot:PilotStage",
        command=f"{_C}.pilot",
        # "ack": a lock-step sim's answer (auvgw sim --lockstep), not shown
        outputs=(Output("state", "setpoints"), Output("command", "commands"),
                 Output("ack", None)),
        demo_scenario="closed_loop",
        demo_option="--closed-loop",
        demo_run=f"{_C}.demo_closed_loop:run_closed_loop",
        doc="pilot.md",
    ),
]


def of_kind(kind: str) -> list[Pipeline]:
    """The records of ``kind`` (a key of :data:`KINDS`), in registry order."""
    if kind not in KINDS:
        raise KeyError(f"unknown pipeline kind {kind!r}; known: {', '.join(KINDS)}")
    return [p for p in PIPELINES if p.kind == kind]


def names(kind: str | None = None) -> list[str]:
    """Every pipeline's name (of ``kind``; None: every kind), in registry order."""
    return [p.name for p in (PIPELINES if kind is None else of_kind(kind))]


def get(name: str) -> Pipeline:
    """The record of pipeline ``name`` (KeyError names the known ones)."""
    for p in PIPELINES:
        if p.name == name:
            return p
    raise KeyError(f"unknown pipeline {name!r}; known: {', '.join(names())}")


def default() -> Pipeline:
    """The SLAM pipeline commands run unless told otherwise (the fallback: ``demo_accepts``
    None)."""
    return next(p for p in of_kind("slam") if p.demo_accepts is None)


def for_segment(segment: str) -> Pipeline | None:
    """The SLAM pipeline publishing under ``auv/<v>/slam/<segment>/``: the record of that name,
    else the one whose segment is its algorithm's name (None: no such record)."""
    slam = of_kind("slam")
    for p in slam:
        if p.name == segment:
            return p
    return next((p for p in slam if p.any_segment), None)


def sections() -> tuple[str, ...]:
    """The bus sections of the pipelines that are not SLAM (``pilot``: ``auv/<v>/pilot/**``)."""
    return tuple(p.section for p in PIPELINES if p.kind != "slam")


def for_section(section: str) -> Pipeline | None:
    """The pipeline (not SLAM) publishing under ``auv/<v>/<section>/`` (None: none)."""
    return next((p for p in PIPELINES if p.kind != "slam" and p.section == section), None)


def for_demo(scenario: Any) -> Pipeline:
    """The SLAM pipeline ``auvgw demo`` runs on a loaded scenario: the first record whose
    ``demo_accepts`` takes it, else the fallback."""
    for p in of_kind("slam"):
        if p.demo_accepts is not None and load(p.demo_accepts)(scenario):
            return p
    return default()


def register(pipeline: Pipeline) -> None:
    """Add a record (a SLAM one before the fallback, so the demo tries it first); a name taken
    is a ValueError. For a site's own pipeline, and tests."""
    if pipeline.name in names():
        raise ValueError(f"pipeline {pipeline.name!r} is already registered")
    at = PIPELINES.index(default()) if pipeline.kind == "slam" else len(PIPELINES)
    PIPELINES.insert(at, pipeline)


def unregister(name: str) -> None:
    """Remove the record of ``name`` (tests)."""
    PIPELINES.remove(get(name))


def load(target: str) -> Any:
    """The object a ``"module:attribute"`` string names (imports the module); a bare module
    name gives the module."""
    module, _, attr = target.partition(":")
    mod = importlib.import_module(module)
    return getattr(mod, attr) if attr else mod
