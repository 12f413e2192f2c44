"""The SLAM pipelines' outputs as declared messages, encoded on the bus like the sensors' (the
decoded-message envelope, docs/bus.md#payloads) instead of JSON documents.

One message per view of the pipeline registry (:data:`auvgw.slam.pipelines.OUTPUT_VIEWS`):

* :class:`PoseEstimate` (``pose``): ``t`` (s, odometry clock), ``x``, ``y`` (m, NED),
  ``heading`` (rad), ``cov`` (3 x 3 over x, y, heading, or 2 x 2 over x, y), and what a pipeline
  adds: a subsample of its ``particles`` (rows x, y, heading) with their ``weights``, ``neff``,
  the dead-reckoning position ``dr`` at the same time, the ``ping`` index, ``t_mag``;
* :class:`PointMap` (``landmarks``): point landmarks ``mean`` (N x 2 m), ``cov`` (N x 2 x 2 m^2),
  ``ids``; optional :class:`LineSet` layers (``lines``: observed walls placed with the SLAM pose,
  with end points; ``line_landmarks``: the filter's wall landmarks) and the ``acoustic_beacon``;
* :class:`Dem` (``dem``): a DEM tile, ``depth`` (rows over x, m down, NaN where empty), cell
  ``[i][j]`` centred at ``x0 + (i + 0.5) cell_m, y0 + (j + 0.5) cell_m``;
* :class:`Cloud` (``cloud``): seabed ``points`` (N x 3: x, y, depth m, NED);
* :class:`BeaconRange` (``ranges``): one demodulated beacon observation seen from a pose;
* :class:`Track` (``path``): a smoothed trajectory, sent once at the end (times ``t`` s, ``x``,
  ``y`` m NED), with the times of the accepted loop closures ``closures_t`` and the ``loops``
  (accepted, rejected).

Their field names are the names of the JSON documents they replace, so ``to_jsonable(message)``
is that document (NaN as null): the recorder, the ROS 2 bridge and ``slam run --out`` read the
same fields as before.
"""

from __future__ import annotations

import numpy as np

from auvgw.drivers.spec import message

__all__ = ["BeaconRange", "Cloud", "Dem", "LineSet", "PointMap", "PoseEstimate", "Track"]


@message
class PoseEstimate:
    """A pipeline's pose estimate (see the module docstring)."""

    TYPE = "SlamPose"

    t: float
    x: float
    y: float
    heading: float
    cov: np.ndarray | None = None
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None
    neff: float | None = None
    algorithm: str | None = None
    dr: tuple[float, float] | None = None
    ping: int | None = None
    t_mag: float | None = None


@message
class LineSet:
    """Line features ``(rho m, theta rad)`` in the map frame with their 2 x 2 covariances
    (N x 2 x 2) and, for observed walls, their end points ``p0``, ``p1`` (N x 2 m)."""

    TYPE = "SlamLineSet"

    rho: np.ndarray
    theta: np.ndarray
    cov: np.ndarray
    p0: np.ndarray | None = None
    p1: np.ndarray | None = None


@message
class PointMap:
    """A pipeline's landmark map (see the module docstring)."""

    TYPE = "SlamPointMap"

    t: float
    mean: np.ndarray
    cov: np.ndarray
    ids: np.ndarray
    lines: LineSet | None = None
    line_landmarks: LineSet | None = None
    acoustic_beacon: tuple[float, float] | None = None


@message
class Dem:
    """A DEM tile (see the module docstring); ``pings`` in the filter, ``loops`` (accepted,
    rejected loop closures)."""

    TYPE = "SlamDem"

    t: float
    cell_m: float
    x0: float
    y0: float
    depth: np.ndarray
    pings: int = 0
    loops: tuple[int, int] = (0, 0)


@message
class Cloud:
    """Seabed points placed by the corrected trajectory (see the module docstring)."""

    TYPE = "SlamCloud"

    t: float
    points: np.ndarray


@message
class BeaconRange:
    """One beacon observation: window centre ``t`` (s), channel ``freq`` (Hz), amplitude
    ``amp_nt`` (nT, NED), ``snr``, ``z`` (range m, bearing rad from the heading) with its
    covariance ``r``, seen from ``x``, ``y`` (m), ``heading`` (rad)."""

    TYPE = "SlamBeaconRange"

    t: float
    freq: float
    amp_nt: tuple[float, float, float]
    snr: float
    z: tuple[float, float]
    r: np.ndarray
    x: float
    y: float
    heading: float


@message
class Track:
    """A smoothed trajectory (see the module docstring)."""

    TYPE = "SlamTrack"

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    closures_t: np.ndarray
    loops: tuple[int, int] = (0, 0)
