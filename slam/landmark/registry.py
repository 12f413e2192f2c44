"""Build any landmark filter by name with one signature."""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from typing import Any

import numpy as np

from auvgw.slam.landmark.association import JCBB, Association, KnownAssociation, NearestNeighbour
from auvgw.slam.landmark.base import LandmarkFilter
from auvgw.slam.models import MotionModel, ObservationModel

__all__ = ["ALGORITHMS", "DISPLAY_NAMES", "make_association", "make_filter"]


#: the particle filters' arguments, which the EKF family does not take
_PARTICLE_ARGS = ("n_particles", "resample_fraction")


def _lazy(
    module: str, cls: str, drop: tuple[str, ...] = (), **fixed: Any
) -> Callable[..., LandmarkFilter]:
    """A factory of ``auvgw.slam.landmark.<module>.<cls>`` importing it on first use: the
    ``fixed`` keyword arguments, then the caller's less those named in ``drop``."""

    def build(**kw: Any) -> LandmarkFilter:
        filt: type[LandmarkFilter] = getattr(import_module(f"auvgw.slam.landmark.{module}"), cls)
        for name in drop:
            kw.pop(name, None)
        return filt(**fixed, **kw)

    return build


#: algorithm name -> factory taking the keyword arguments of :func:`make_filter`
ALGORITHMS: dict[str, Callable[..., LandmarkFilter]] = {
    "fastslam1": _lazy("fastslam", "FastSLAM1"),
    "fastslam2": _lazy("fastslam", "FastSLAM2"),
    "ufastslam": _lazy("ufastslam", "UFastSLAM"),
    "vb-afastslam": _lazy("vb", "VBAFastSLAM"),
    "vb-aufastslam": _lazy("vb", "VBAUFastSLAM"),
    "vrfastslam": _lazy("vrfastslam", "VRFastSLAM"),
    "ekf": _lazy("ekfslam", "EKFSLAM", _PARTICLE_ARGS, adaptive="none"),
    "shekf": _lazy("ekfslam", "EKFSLAM", _PARTICLE_ARGS, adaptive="sage-husa"),
    "stekf": _lazy("ekfslam", "EKFSLAM", _PARTICLE_ARGS, adaptive="strong-tracking"),
    "caekf": _lazy("ekfslam", "EKFSLAM", _PARTICLE_ARGS, adaptive="combined"),
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
    association: str | Association = "known",
    **options: Any,
) -> LandmarkFilter:
    """A filter by algorithm name (see :data:`ALGORITHMS`); ``q`` control noise, ``r`` nominal
    observation noise ``R0``; ``options`` go to the filter class (``n_particles``, ``x0``,
    ``resample_fraction`` of :class:`~auvgw.slam.landmark.base.LandmarkFilter` and each
    class's own; the EKF family ignores the particle filters' two)."""
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
        association=assoc,
        **options,
    )
