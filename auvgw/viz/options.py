"""Tuning of the Rerun logger (no Rerun import: the CLI builds these without loading the SDK)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from auvgw.config.gateway import GatewayConfig

__all__ = ["VizOptions", "gateway_viz_options"]


@dataclass(frozen=True)
class VizOptions:
    """Tuning of :class:`RerunLogger` (defaults suit an AUV at 1-3 m/s)."""

    #: ``ned`` (x north, y east) or ``xy`` (x right, y up) for positions and headings
    map_frame: Literal["ned", "xy"] = "ned"
    #: ``timestamp`` (device times are POSIX seconds) or ``duration`` (seconds since any zero)
    time_kind: Literal["timestamp", "duration"] = "timestamp"
    #: items the queue holds before calls are dropped (and counted)
    queue_size: int = 20_000
    #: device seconds between batch sends (send_columns) of the buffered streams, trajectory
    #: segments and poses; also after this many host seconds when the device clock stalls. The
    #: live view lags by up to this much; each entity costs about 1 kB of chunk header per send
    flush_period_s: float = 2.0
    #: a buffered stream is sent early when it holds this many rows
    max_batch_rows: int = 5_000
    #: a low-rate stream waits for this many rows, at most ``max_latency_s`` (device or host
    #: seconds), so that it does not cost one chunk per flush
    min_batch_rows: int = 10
    max_latency_s: float = 5.0
    #: a trajectory keeps a new vertex when it moved at least this far (m)
    track_min_step_m: float = 0.1
    #: length of the heading arrow of a pose (m)
    pose_arrow_m: float = 3.0
    #: confidence ellipses at this many standard deviations
    ellipse_sigma: float = 2.0
    #: vertices of one ellipse line strip
    ellipse_vertices: int = 33
    #: half length of a drawn line feature without end points (m)
    line_half_length_m: float = 25.0
    #: particles kept of a cloud (evenly spaced subsample)
    max_particles: int = 200
    #: side of the square MSIS fan image (pixels); the range scale spans half of it
    fan_pixels: int = 256
    #: device seconds between fan image logs within a sweep (a completed sweep is always logged)
    fan_period_s: float = 1.0
    #: JPEG quality of the fan image (1-100), or None for lossless (about 3x larger)
    fan_jpeg_quality: int | None = None
    #: bathymetric grid cell (m) and the largest grid (cells)
    bathy_cell_m: float = 1.0
    bathy_max_cells: int = 4_000_000
    #: device seconds between logs of the gridded mean-depth image
    bathy_period_s: float = 10.0
    #: colour range of depths (m); None: set from the first swath
    depth_range: tuple[float, float] | None = None
    #: highest rate (Hz, device time) of the vehicle's Transform3D (the series keep every sample)
    vehicle_pose_hz: float = 20.0
    #: time constant (device s) of the magnetometer's running mean; the "change" view shows the
    #: field minus it
    mag_baseline_s: float = 10.0
    #: device seconds between two logs of the counters table (health/counters)
    counters_period_s: float = 1.0
    #: magnetic arrow length per nT (m/nT): 1e-4 draws 50 000 nT as 5 m
    mag_arrow_m_per_nt: float = 1e-4
    #: the GeoSwath's sonar frequency (Hz): its RAA sample times count wavelengths, and the
    #: broadcast ping does not say (the swath stage's ``frequency_hz``)
    geoswath_frequency_hz: float = 250_000.0
    #: per GeoSwath device, its frequency (Hz), where known (a gateway device's model)
    geoswath_frequencies_hz: dict[str, float] = field(default_factory=dict)
    #: device seconds between two raw-ping views of one GeoSwath side (the latest ping is shown)
    raw_ping_period_s: float = 1.0
    #: samples drawn of a raw ping at most (every k-th sample beyond)
    raw_ping_max_samples: int = 4096


def gateway_viz_options(cfg: GatewayConfig, options: VizOptions | None = None) -> VizOptions:
    """``options`` (default :class:`VizOptions`) with each GeoSwath device's frequency from its
    gateway configuration (``[devices.<name>.geoswath] model_khz``)."""
    freqs = {
        name: dev.geoswath.frequency_hz
        for name, dev in cfg.devices.items()
        if dev.geoswath is not None
    }
    return replace(options or VizOptions(), geoswath_frequencies_hz=freqs)
