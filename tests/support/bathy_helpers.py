"""Shared pieces of the bathymetric SLAM tests: a tiny crossing survey and a Dask LocalCluster."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: a 2 km-ish survey whose last leg crosses the first line (about 450 pings at 1 Hz)
TINY: dict[str, Any] = {
    "name": "tiny_survey",
    "vehicle": {
        "waypoints": [[0, 0], [200, 0], [200, 60], [60, 60], [60, -40]],
        "speed_mps": 2.0,
        "depth_m": 0.5,
        "dt_s": 0.1,
    },
    "terrain": {
        "kind": "mixed",
        "depth_m": 30,
        "relief_m": 3,
        "wavelength_m": 80,
        "octaves": 3,
        "seed": 2,
        "extent_m": [-50, 250, -50, 100],
    },
    "devices": {"multibeam": {"rate_hz": 1.0, "options": {"n_beams": 61}}},
}


@contextmanager
def local_cluster() -> Iterator[str]:
    """A small in-process Dask cluster; yields its scheduler address."""
    import distributed

    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        yield cluster.scheduler_address
