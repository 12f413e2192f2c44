"""The test house (``tests/support/``, imported as ``auvgw.testing``: setup.py maps it, so tests
and benchmarks import it without editing ``sys.path``).

* :func:`wait_until` - poll a condition (never a fixed sleep); :func:`wait_matched` - until
  every Zenoh publisher has a subscriber;
* processes - :class:`Proc`, :class:`Procs` (the ``procs`` fixture), ``AUVGW``, ``PYTHON``,
  free ports (:func:`free_port`, :func:`endpoint`; :mod:`auvgw.ground.procs` is their home);
* ptys - :class:`PtyDevice`;
* config writers - :func:`write_gateway_toml`, :func:`gateway_config_json`;
* data - :func:`pd0_frames`, :func:`local_decoded`, :func:`read_jsonl`, :func:`frame_counters`;
* emulation helpers - :mod:`~auvgw.testing.fusion_emulated`, :mod:`~auvgw.testing.fusion_lowcost`,
  :mod:`~auvgw.testing.slam_helpers`, :mod:`~auvgw.testing.format_samples`,
  :mod:`~auvgw.testing.bathy_helpers`;
* :mod:`~auvgw.testing.e2e_marks` - the pytest plugin (loaded by tests/conftest.py) that fails a
  test not marked ``e2e`` that starts a process, a pty or a Zenoh session.
"""

if __name__ != "auvgw.testing":
    raise ImportError(f"import auvgw.testing, not {__name__}: the folder is mapped (setup.py)")

from auvgw.testing.configs import gateway_config_json, write_gateway_toml
from auvgw.testing.data import frame_counters, local_decoded, pd0_frames, read_jsonl
from auvgw.testing.processes import (
    AUVGW,
    PYTHON,
    REPO,
    SUBSCRIBER,
    Proc,
    Procs,
    endpoint,
    free_port,
    run_demo_processes,
)
from auvgw.testing.ptys import PtyDevice
from auvgw.testing.waiting import wait_matched, wait_until

__all__ = [
    "AUVGW",
    "PYTHON",
    "REPO",
    "SUBSCRIBER",
    "Proc",
    "Procs",
    "PtyDevice",
    "endpoint",
    "frame_counters",
    "free_port",
    "gateway_config_json",
    "local_decoded",
    "pd0_frames",
    "read_jsonl",
    "run_demo_processes",
    "wait_matched",
    "wait_until",
    "write_gateway_toml",
]
