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

from . import beams, lines, pipeline, points
from .beams import *  # noqa: F403 - the package exports each module's __all__
from .lines import *  # noqa: F403
from .pipeline import *  # noqa: F403
from .points import *  # noqa: F403

__all__ = [*beams.__all__, *lines.__all__, *pipeline.__all__, *points.__all__]
