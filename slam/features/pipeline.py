"""The MSIS feature stage: pings in, line and point features out (Cui et al. 2020, sec. 2.2).

:class:`SonarFeatureExtractor` chains the pieces of this package for one head:

1. beam preprocessing (sec. 2.2.1, :func:`~.beams.detect_returns`): threshold, local maxima,
   minimum distance;
2. the sector buffer (sec. 2.2.2, :class:`~.lines.SectorBuffer`): each ping's returns with the
   vehicle pose *at that ping* (from the fusion odometry online, from the truth in
   simulation), so motion during the scan is compensated;
3. voting in the frame of the newest ping (sec. 2.2.3, :func:`~.lines.extract_lines`): lines
   whose whole visibility window has been scanned are reported and their returns withdrawn;
4. point targets among the remaining returns (:func:`~.points.extract_points`), reported once
   the scan has passed them.

The paper votes whenever a new beam brings returns; here every ``vote_every``-th ping votes
while the buffer holds returns (a ping without returns can complete a line's window too).
``vote_every`` 1 is the paper's rhythm; the default 4 (7.2 deg at a 1.8 deg step) delays a
feature by at most three pings and cuts the cost fourfold (a vote re-expresses the whole
buffer in the newest ping's frame).

Push pings one at a time online (:meth:`~SonarFeatureExtractor.push_ping`), or run a whole
:class:`~.beams.ScanLines` with a pose source offline (:meth:`~SonarFeatureExtractor.run`).
Frames and units as in :mod:`.beams`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .beams import (
    BeamSettings,
    PoseSource,
    ScanLines,
    SonarMount,
    detect_returns,
    poses_at,
)
from .lines import (
    BufferedReturns,
    HoughSettings,
    LineFit,
    LineObservation,
    SectorBuffer,
    covers,
    extract_lines,
)
from .points import PointObservation, PointSettings, extract_points, segment_distance

__all__ = ["FeatureSettings", "Features", "SonarFeatureExtractor"]

FArray = np.ndarray


@dataclass(frozen=True)
class FeatureSettings:
    """Everything the feature stage needs: ``beam`` preprocessing, ``hough`` line voting,
    ``points`` (None: no point features), the head's ``mount``, the buffer's ``sector_rad``
    (180 deg) and ``max_age_s``, vote every ``vote_every`` pings, and ``line_memory_s``: how
    long an extracted line keeps returns near it from being taken for point targets (s)."""

    beam: BeamSettings
    hough: HoughSettings = field(default_factory=HoughSettings)
    points: PointSettings | None = field(default_factory=PointSettings)
    mount: SonarMount = field(default_factory=SonarMount)
    sector_rad: float = math.pi
    max_age_s: float = 120.0
    vote_every: int = 4
    line_memory_s: float = 60.0


@dataclass
class Features:
    """Features found so far, in the order found."""

    lines: list[LineObservation] = field(default_factory=list)
    points: list[PointObservation] = field(default_factory=list)

    def extend(self, other: Features) -> None:
        self.lines.extend(other.lines)
        self.points.extend(other.points)

    def __bool__(self) -> bool:
        return bool(self.lines or self.points)


class SonarFeatureExtractor:
    """Streaming MSIS feature extraction for one head (see the module docstring)."""

    def __init__(self, settings: FeatureSettings) -> None:
        self.settings = settings
        self.buffer = SectorBuffer(settings.sector_rad, settings.max_age_s, settings.mount)
        self._since_vote = 0
        self._recent: list[tuple[float, FArray]] = []  # (time, endpoints in the pose frame)
        self.pings = 0
        self.votes = 0

    def reset(self) -> None:
        """Forget the buffer and the recent lines (a new run, a relocalised pose frame)."""
        self.buffer.clear()
        self._recent.clear()
        self._since_vote = 0

    def push_ping(
        self,
        t: float,
        bearing: float,
        intensity: FArray,
        bin_length: float,
        pose: FArray,
        bin_offset: float = 0.5,
    ) -> Features:
        """One ping: time ``t`` (s), head ``bearing`` (rad), its bins, bin length (m) and the
        vehicle ``pose`` (x, y, heading) at ``t``. Returns the features it completed."""
        scan = ScanLines(np.array([t]), np.array([bearing]),
                         np.asarray(intensity, float)[None, :], np.array([bin_length]),
                         bin_offset)  # fmt: skip
        r = detect_returns(scan, self.settings.beam)
        return self.push_returns(t, bearing, r.range_m, r.intensity, r.bin_length, pose)

    def push_returns(
        self,
        t: float,
        bearing: float,
        ranges: FArray,
        intensity: FArray,
        bin_length: FArray | float,
        pose: FArray,
    ) -> Features:
        """One ping already preprocessed (sec. 2.2.1): its returns' ranges (m), intensities
        and bin length (m, the range noise unless the settings give one)."""
        self.pings += 1
        self.buffer.push(t, bearing, pose, ranges, intensity, bin_length)
        self._since_vote += 1
        if self._since_vote < self.settings.vote_every or self.buffer.n_returns == 0:
            return Features()
        self._since_vote = 0
        return self._vote()

    def run(self, scan: ScanLines, poses: PoseSource | FArray) -> Features:
        """A whole run of pings (in time order) with their poses (a pose source, or (N, 3)
        per-ping poses, or one pose): all features, in the order found."""
        r = detect_returns(scan, self.settings.beam)
        pose = poses_at(poses, scan.t, np.arange(len(scan)))
        bounds = np.searchsorted(r.ping, np.arange(len(scan) + 1))
        out = Features()
        for i in range(len(scan)):
            a, b = bounds[i], bounds[i + 1]
            out.extend(
                self.push_returns(
                    float(scan.t[i]), float(scan.bearing[i]), r.range_m[a:b],
                    r.intensity[a:b], scan.bin_length[i], pose[i],
                )
            )  # fmt: skip
        return out

    # -- one vote ---------------------------------------------------------------------------
    def _vote(self) -> Features:
        s = self.settings
        self.votes += 1
        br = self.buffer.returns()
        pose, origin, psi, t_ref = self.buffer.frame()
        h = s.hough
        sr = br.sigma_r if h.sigma_range_m is None else h.sigma_range_m
        out = Features()
        used: list[FArray] = []
        fits = extract_lines(br.sx, br.sy, br.ang, br.rng, br.ping, h, sr)
        in_line = np.zeros(len(br), bool)
        for f in fits:
            in_line[f.support] = True
            if covers(br.path, f.theta - h.window, f.theta + h.window):
                obs = LineObservation.from_fit(
                    f, pose, psi, origin, t_ref, br.t[f.support], s.mount
                )
                out.lines.append(obs)
                used.append(br.ids[f.support])
                self._recent.append((t_ref, obs.endpoints))
        self._recent = [(t, e) for t, e in self._recent if t_ref - t <= s.line_memory_s]
        if s.points is not None:
            out.points = self._points(br, fits, in_line, pose, psi, origin, t_ref, used)
        if used:
            self.buffer.remove(np.concatenate(used))
        return out

    def _points(
        self,
        br: BufferedReturns,
        fits: list[LineFit],
        in_line: FArray,
        pose: FArray,
        psi: float,
        origin: FArray,
        t_ref: float,
        used: list[FArray],
    ) -> list[PointObservation]:
        s = self.settings
        ps = s.points
        assert ps is not None
        px, py = br.px, br.py
        # lines of this vote (in B) and recent ones (pose frame -> B)
        segs = [f.endpoints() for f in fits]
        if self._recent:
            c, sn = math.cos(psi), math.sin(psi)
            for _, e in self._recent:
                d = e - origin
                segs.append(np.stack([c * d[:, 0] + sn * d[:, 1], -sn * d[:, 0] + c * d[:, 1]],
                                     axis=1))  # fmt: skip
        free = ~in_line
        if segs:
            free &= segment_distance(px, py, np.array(segs)) > ps.line_clearance_m
        if np.count_nonzero(free) < ps.min_returns:
            return []
        sr = br.sigma_r if ps.sigma_range_m is None else ps.sigma_range_m
        path = br.path
        steps = np.abs(np.diff(path))
        steps = steps[steps > 0]
        step = float(np.median(steps)) if steps.size else ps.beam_width_rad
        fits_p = extract_points(
            br.sx, br.sy, br.ang, br.rng, br.ping, path, ps, sr, step, eligible=free
        )
        out = []
        for f in fits_p:
            # complete once the scan has passed both sides by a beam width, a step and the
            # angle of the isolation radius (no later ping can add to it or break its isolation)
            margin = ps.beam_width_rad + 1.5 * step + math.atan2(ps.isolation_m, f.distance)
            if path.min() > f.a_min - margin or path.max() < f.a_max + margin:
                continue
            out.append(
                PointObservation.from_fit(f, pose, psi, origin, t_ref, br.t[f.support], s.mount)
            )
            used.append(br.ids[f.support])
        return out
