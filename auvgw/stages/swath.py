"""The GeoSwath swath stage: decoded raw pings in, processed swaths out as a multibeam device.

Subscribes to ``auv/<v>/sensor/<device>/geoswathping`` (the gateway's decoded GeoSwath pings,
:class:`~auvgw.drivers.geoswath.GeoSwathPing`, of ``device`` or of any device) and runs one
:class:`~auvgw.slam.bathymetric.swath_processing.SwathProcessor` per source device. Each swath
it completes is published as an XYZ 88 envelope on ``auv/<v>/sensor/<device>_swath/xyz88``
(``output_device`` replaces the name; ``geoswath_swath`` when ``device`` is None): the
bathymetric stage, the Rerun logger and the ROS 2 bridge take it as they take the Kongsberg
multibeam's (``--multibeam <device>_swath``).

Times: a swath's envelope carries the host receive time of its reference ping (the swath's first
ping, whose NAV position places it): the device-to-host clock offset of the latest ping applied
to the swath's device time, so the bathymetric stage places it with the odometry of the instant
it was pinged, not of the later ping that completed it (the along-track median holds a swath
back ``along_window // 2`` swaths).

Counters on ``auv/<v>/status/swath``: pings, swaths, samples dropped by each filter.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import Field

from auvgw.drivers.geoswath import GeoSwathPing
from auvgw.envelope import encode_envelope
from auvgw.slam.bathymetric.swath_processing import SwathProcessing, SwathProcessor
from auvgw.stages.base import BusCounters, Stage, StageConfig

if TYPE_CHECKING:
    import zenoh

    from auvgw.drivers import kongsberg

__all__ = ["SwathStage", "SwathStageConfig", "SwathStats"]

log = logging.getLogger(__name__)

KIND_IN = "geoswathping"
KIND_OUT = "xyz88"


class SwathStageConfig(StageConfig):
    """``device``: the GeoSwath gateway device (None: every device); ``output_device``: the
    device name the swaths are published under (None: ``<device>_swath``); ``processing``:
    any :class:`~auvgw.slam.bathymetric.swath_processing.SwathProcessing` value by name
    (``frequency_hz``, ``n_bins``, ``swath_rate_hz``, ``lever_arm_m``, ...)."""

    device: str | None = None
    output_device: str | None = None
    processing: dict[str, Any] = Field(default_factory=dict)

    def swath_processing(self) -> SwathProcessing:
        """The processing settings (a ValueError names a bad one)."""
        try:
            return SwathProcessing(**self.processing)
        except TypeError as exc:
            raise ValueError(f"processing: {exc}") from None


@dataclass
class SwathStats(BusCounters):
    """Counters of the stage (``received``: pings used)."""

    swaths: int = 0  #: swaths published
    dropped: dict[str, int] = field(default_factory=dict)  #: samples dropped, by filter


class SwathStage(Stage):
    """GeoSwath pings -> XYZ 88 swaths (see the module docstring)."""

    name = "swath"
    status_schema = "SwathStatus"
    outputs = (KIND_OUT,)

    def __init__(
        self,
        config: SwathStageConfig,
        session: zenoh.Session | None = None,
        on_publish: Callable[[str, bytes, int], object] | None = None,
    ) -> None:
        self.config = config
        self.processing = config.swath_processing()
        super().__init__(config, SwathStats(), session, on_publish=on_publish)
        self.stats: SwathStats
        self._procs: dict[str, SwathProcessor] = {}
        self._offset_s: dict[str, float] = {}  # host receive time - device time, per device
        self._seq = 0

    def out_device(self) -> str:
        """The device name the swaths are published under (one stage per GeoSwath device when
        several should stay apart)."""
        if self.config.output_device:
            return self.config.output_device
        return f"{self.config.device or 'geoswath'}_swath"

    def key(self, what: str) -> str:
        """``auv/<v>/sensor/<output device>/xyz88``."""
        return self.keys.sensor(self.out_device(), what)

    def input_keys(self) -> list[str]:
        return [self.keys.sensor(self.config.device or "*", KIND_IN)]

    def feed(self, device: str, t_recv_ns: int, message: object) -> object:
        """One decoded gateway message: GeoSwath pings of the configured device are processed,
        everything else ignored; publishes the swaths the ping completes."""
        want = self.config.device
        if not isinstance(message, GeoSwathPing) or (want is not None and device != want):
            return None
        with self._lock:
            proc = self._procs.get(device)
            if proc is None:
                proc = self._procs[device] = SwathProcessor(self.processing)
            self._offset_s[device] = t_recv_ns * 1e-9 - float(message.header["ping_time"])
            before = dict(proc.dropped)
            swaths = proc.add(message)
            self.stats.received += 1
            for k, v in proc.dropped.items():
                self.stats.dropped[k] = self.stats.dropped.get(k, 0) + v - before.get(k, 0)
            for sw in swaths:
                self._publish(device, sw)
        return None

    def _publish(self, device: str, swath: kongsberg.XYZ88) -> None:
        t_ns = int((swath.device_time + self._offset_s.get(device, 0.0)) * 1e9)
        self._seq += 1
        payload, enc = encode_envelope(
            swath, self.out_device(), t_ns, self._seq, wire="geoswath", decoded=True
        )
        self.stats.swaths += 1
        self.publish(KIND_OUT, payload, enc, t_ns)

    def flush(self) -> object:
        """The swaths still held by each processor (end of the stream)."""
        with self._lock:
            for device, proc in self._procs.items():
                for sw in proc.flush():
                    self._publish(device, sw)
        return None

    def status_fields(self) -> dict[str, object]:
        return {"device": self.config.device, "output_device": self.out_device()}
