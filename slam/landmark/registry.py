"""Build any landmark filter by name with one signature."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from auvgw.slam.landmark.association import JCBB, Association, KnownAssociation, NearestNeighbour
from auvgw.slam.landmark.base import LandmarkFilter
from auvgw.slam.models import MotionModel, ObservationModel

__all__ = ["ALGORITHMS", "DISPLAY_NAMES", "make_association", "make_filter"]


def _fastslam1(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.fastslam import FastSLAM1

    return FastSLAM1(**kw)


def _fastslam2(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.fastslam import FastSLAM2

    return FastSLAM2(**kw)


def _ufastslam(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.ufastslam import UFastSLAM

    return UFastSLAM(**kw)


def _vba(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.vb import VBAFastSLAM

    return VBAFastSLAM(**kw)


def _vbau(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.vb import VBAUFastSLAM

    return VBAUFastSLAM(**kw)


def _vr(**kw: Any) -> LandmarkFilter:
    from auvgw.slam.landmark.vrfastslam import VRFastSLAM

    return VRFastSLAM(**kw)


def _ekf(adaptive: str) -> Callable[..., LandmarkFilter]:
    def build(**kw: Any) -> LandmarkFilter:
        from auvgw.slam.landmark.ekfslam import EKFSLAM

        kw.pop("n_particles", None)
        kw.pop("resample_fraction", None)
        return EKFSLAM(adaptive=adaptive, **kw)

    return build


#: algorithm name -> factory taking the keyword arguments of :func:`make_filter`
ALGORITHMS: dict[str, Callable[..., LandmarkFilter]] = {
    "fastslam1": _fastslam1,
    "fastslam2": _fastslam2,
    "ufastslam": _ufastslam,
    "vb-afastslam": _vba,
    "vb-aufastslam": _vbau,
    "vrfastslam": _vr,
    "ekf": _ekf("none"),
    "shekf": _ekf("sage-husa"),
    "stekf": _ekf("strong-tracking"),
    "caekf": _ekf("combined"),
}

#: names used in the papers' tables
DISPLAY_NAMES: dict[str, str] = {
    "fastslam1": "FastSLAM1.0",
    "fastslam2": "FastSLAM2.0",
    "ufastslam": "UFastSLAM",
    "vb-afastslam": "VB-AFastSLAM",
    "vb-aufastslam": "VB-AUFastSLAM",
    "vrfastslam": "VRFastSLAM",
    "ekf": "EKF-SLAM",
    "shekf": "SHEKF-SLAM",
    "stekf": "STEKF-SLAM",
    "caekf": "CAEKF-SLAM",
}


def make_association(name: str) -> Association:
    """``known``, ``nn`` or ``jcbb`` with default gates."""
    table: dict[str, Association] = {
        "known": KnownAssociation(),
        "nn": NearestNeighbour(),
        "jcbb": JCBB(),
    }
    try:
        return table[name]
    except KeyError:
        raise ValueError(f"unknown association {name!r}; choose from {sorted(table)}") from None


def make_filter(
    name: str,
    motion: MotionModel,
    obs: ObservationModel,
    q: np.ndarray,
    r: np.ndarray,
    *,
    n_particles: int = 100,
    x0: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    association: str | Association = "known",
    resample_fraction: float = 0.75,
    **options: Any,
) -> LandmarkFilter:
    """A filter by algorithm name (see :data:`ALGORITHMS`); ``q`` control noise, ``r`` nominal
    observation noise ``R0``; extra ``options`` go to the filter class."""
    try:
        factory = ALGORITHMS[name]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}; choose from {sorted(ALGORITHMS)}") from None
    assoc = make_association(association) if isinstance(association, str) else association
    return factory(
        motion=motion,
        obs=obs,
        q=q,
        r=r,
        n_particles=n_particles,
        x0=x0,
        association=assoc,
        resample_fraction=resample_fraction,
        **options,
    )
