"""MSIS sonar features for the landmark SLAM filters (Cui et al. 2020, "VRFastSLAM", sec. 2.2).

Pure algorithms on arrays (numpy, scipy): no transports, no Zenoh, no Rerun.

* :mod:`.beams` - sec. 2.2.1 beam preprocessing (threshold, local maxima, minimum distance),
  :class:`ScanLines` input arrays (and the SeaNet ``HeadData`` adapter), motion compensation
  (every return placed with the pose at its own ping).
* :mod:`.lines` - sec. 2.2.2 sector buffer and 2.2.3 Hough voting with the beam-width arc and
  incidence rule; least-squares refined ``(rho, theta)`` lines with covariance.
* :mod:`.points` - clusters of returns to range-bearing point features with covariance.
* :mod:`.pipeline` - :class:`SonarFeatureExtractor`, the streaming stage chaining them.

See ``docs/sonar_features.md``.
"""

from .beams import (
    BeamSettings,
    PlacedReturns,
    PoseSource,
    PoseTrack,
    Returns,
    ScanLines,
    SonarMount,
    detect_returns,
    place_returns,
    place_scan,
    poses_at,
    preprocess_beam,
    scan_lines_from_head_data,
)
from .lines import (
    HoughSettings,
    LineFit,
    LineObservation,
    SectorBuffer,
    extract_lines,
    fit_line,
    hough_votes,
    line_difference,
    line_to_world,
    merge_lines,
)
from .pipeline import Features, FeatureSettings, SonarFeatureExtractor
from .points import (
    PointFit,
    PointObservation,
    PointSettings,
    cluster_returns,
    extract_points,
)

__all__ = [
    "BeamSettings",
    "FeatureSettings",
    "Features",
    "HoughSettings",
    "LineFit",
    "LineObservation",
    "PlacedReturns",
    "PointFit",
    "PointObservation",
    "PointSettings",
    "PoseSource",
    "PoseTrack",
    "Returns",
    "ScanLines",
    "SectorBuffer",
    "SonarFeatureExtractor",
    "SonarMount",
    "cluster_returns",
    "detect_returns",
    "extract_lines",
    "extract_points",
    "fit_line",
    "hough_votes",
    "line_difference",
    "line_to_world",
    "merge_lines",
    "place_returns",
    "place_scan",
    "poses_at",
    "preprocess_beam",
    "scan_lines_from_head_data",
]
