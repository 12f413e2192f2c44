"""Landmark SLAM family: FastSLAM 1.0/2.0, Unscented FastSLAM, VB-AFastSLAM, VB-AUFastSLAM,
VRFastSLAM and the EKF-SLAM family (plain, Sage-Husa, strong tracking, combined).

All filters share one interface (:class:`~auvgw.slam.landmark.base.LandmarkFilter`) and the models
of :mod:`auvgw.slam.models`; build them by name with :func:`make_filter`.
"""

from __future__ import annotations

from auvgw.slam.landmark.base import LandmarkFilter, LandmarkMap
from auvgw.slam.landmark.registry import ALGORITHMS, make_filter

__all__ = ["ALGORITHMS", "LandmarkFilter", "LandmarkMap", "make_filter"]
