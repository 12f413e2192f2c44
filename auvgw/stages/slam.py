"""The online landmark-SLAM stage: fusion odometry and MSIS scan lines from the bus (or fed
in-process), pose and map onto it. The pipeline itself (pose interpolation, feature extraction,
association, filter stepping, heading aiding) is :class:`auvgw.slam.landmark.online.LandmarkOnline`,
which runs without a bus; this module only chooses the MSIS head, counts and publishes.

Published (envelopes of the declared messages of :mod:`auvgw.slam.outputs`) on
``auv/<v>/slam/<pipeline>/pose`` a :class:`~auvgw.slam.outputs.PoseEstimate`: ``t``, ``x``,
``y``, ``heading``, ``cov`` (3 x 3 over x, y, heading), an evenly spaced subsample of the
``particles`` with their ``weights``, ``neff``; and on ``auv/<v>/slam/<pipeline>/landmarks`` a
:class:`~auvgw.slam.outputs.PointMap`: ``t``, ``mean``, ``cov``, ``ids``, ``lines`` (``rho``,
``theta``, ``cov``, ``p0``, ``p1`` in the map frame) and ``line_landmarks``, each time the
pipeline has an estimate due (every ``publish_period_s`` of odometry time) and at
:meth:`SlamStage.flush`.
Counters on ``auv/<v>/status/slam-<pipeline>``.

Times are seconds on the odometry clock (the clock of the gateway's receive stamps online: the
host clock, or the vehicle-paced one of a gateway ``[clock]`` section; a ping's time is its
receive stamp, SeaNet heads carry no clock), so the stage runs the same at any emulation speed;
only the status period and the counters' ``t_ns`` are host-clock health.

In-process (``auvgw slam-run``, tests) call :meth:`SlamStage.feed_odometry` and
:meth:`SlamStage.feed` (the work happens on the calling thread); ``auvgw demo`` uses
:meth:`~SlamStage.post_odometry` / :meth:`~SlamStage.post`, which only queue for the stage's
worker thread, so the gateway's reader threads are never held up by the filter. On the bus
:meth:`SlamStage.start` subscribes to ``nav/odometry`` and ``sensor/<msis>/mtheaddata`` through
the same worker. The pipeline is only touched under the stage's lock.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from auvgw.drivers import registry
from auvgw.drivers import seanet as sn
from auvgw.fusion.odometry import Odometry
from auvgw.slam.landmark.online import (
    LandmarkOnline,
    LandmarkOnlineConfig,
    OnlineStats,
    compose_increments,
)
from auvgw.stages.base import BusCounters, Stage, StageConfig

log = logging.getLogger(__name__)

__all__ = ["SlamStage", "SlamStageConfig", "SlamStats", "compose_increments"]

#: the gateway's key kind of imaging-sonar pings (the device registry's role ``sonar``: SeaNet
#: ``mtHeadData``); a second sonar kind would make the stage subscribe to each
(HEADDATA_KIND,) = registry.kinds_with_role("sonar")


class SlamStageConfig(LandmarkOnlineConfig, StageConfig):
    """Settings of the SLAM stage: the pipeline's (:class:`LandmarkOnlineConfig`) and the
    bus's: ``vehicle``; ``pipeline``, the key segment (default the algorithm name);
    ``msis_device``, gateway device of the head (None: the first head seen); status period and
    queue size."""

    pipeline: str | None = None
    msis_device: str | None = None

    @property
    def pipeline_name(self) -> str:
        """The ``<pipeline>`` key segment."""
        return self.pipeline or self.algorithm


@dataclass
class SlamStats(OnlineStats, BusCounters):
    """Counters of the stage (``received``: scan lines of the MSIS head) and its pipeline."""

    published: int = 0  #: pose + landmark publications


class SlamStage(Stage):
    """Odometry + MSIS scan lines -> SLAM pose and map (see the module docstring).

    ``session``: publish on it (None: in-process only). ``on_publish``: called with ``(key,
    envelope bytes, t_ns)`` at every publication (the demo logs them into Rerun).
    """

    name = "slam"
    status_schema = "SlamStatus"
    outputs = ("pose", "landmarks")
    stats: SlamStats

    def __init__(
        self,
        config: SlamStageConfig | None = None,
        session: zenoh.Session | None = None,
        on_publish: Callable[[str, bytes, int], object] | None = None,
    ) -> None:
        self.config = cfg = config or SlamStageConfig()
        super().__init__(cfg, SlamStats(), session, on_publish=on_publish)
        self.online = LandmarkOnline(cfg, stats=self.stats)
        self.sources["sonar"] = cfg.msis_device

    @property
    def msis_device(self) -> str | None:
        """The gateway device of the MSIS head used (None: none seen yet)."""
        return self.sources.get("sonar")

    @property
    def track(self) -> list[tuple[float, float, float, float]]:
        """SLAM poses at every publication: (t s, x, y, heading)."""
        return self.online.track

    @property
    def component(self) -> str:
        """Status / liveliness component name."""
        return f"slam-{self.config.pipeline_name}"

    def key(self, what: str) -> str:
        """``auv/<v>/slam/<pipeline>/<what>``."""
        return self.keys.slam(self.config.pipeline_name, what)

    def input_keys(self) -> list[str]:
        """The key expressions the stage subscribes to: odometry and the MSIS scan lines."""
        return [self.keys.odometry(), self.keys.sensor(self.config.msis_device or "*",
                                                       HEADDATA_KIND)]  # fmt: skip

    # -- in-process use -----------------------------------------------------------------------
    def feed_odometry(self, o: Odometry) -> None:
        """One odometry sample (in time order)."""
        with self._lock:
            if self.online.add_odometry(o):
                self._publish(o.t)

    def feed(self, device: str, t_recv_ns: int, message: object) -> None:
        """One decoded gateway message (the gateway's ``on_message`` signature); scan lines of
        the MSIS head are used, everything else is ignored. ``t_recv_ns``: the odometry clock."""
        if not isinstance(message, sn.HeadData):
            return
        if not self.from_source("sonar", device):
            return
        with self._lock:
            self.stats.received += 1
            self.online.add_ping(t_recv_ns / 1e9, message)

    def accepts(self, device: str, message: object) -> bool:
        """Only scan lines are queued by :meth:`Stage.post`."""
        return isinstance(message, sn.HeadData)

    def flush(self) -> None:
        """End of data: publish the latest estimate (pings newer than the odometry stay out)."""
        with self._lock:
            t = self.online.finish()
            if t is not None:
                self._publish(t)

    # -- output -------------------------------------------------------------------------------
    def _publish(self, t: float) -> None:
        self.stats.published += 1
        on = self.online
        self.publish_message("pose", on.pose_message(t), t)
        self.publish_message("landmarks", on.landmarks_message(t), t)

    def status_fields(self) -> dict[str, object]:
        """Algorithm, MSIS device, extractor, map sizes, Neff and resamples."""
        return {"algorithm": self.config.algorithm, "msis_device": self.msis_device,
                **self.online.summary()}  # fmt: skip
