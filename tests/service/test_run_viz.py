"""``auvgw run --viz-rrd``: the gateway's own process records a Rerun file; here from the real
Workhorse capture replayed through a file transport, read back with the Rerun SDK."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from auvgw.drivers.framing import read_file_frames
from auvgw.drivers.pd0 import Pd0Framer, decode
from auvgw.viz.readback import read_recording

pytestmark = pytest.mark.e2e


def test_run_records_every_ensemble_of_a_real_capture(tmp_path, shared_data) -> None:
    capture = shared_data / "pd0" / "RDI_withBT.000"
    cfg = tmp_path / "vehicle.toml"
    cfg.write_text(
        'vehicle = "auv1"\n[devices.dvl]\nformat = "pd0"\n'
        f'transport = {{ kind = "file", path = "{capture}" }}\n'
    )
    rrd = tmp_path / "run.rrd"
    res = subprocess.run(
        [sys.executable, "-m", "auvgw", "run", "--config", str(cfg), "--exit-when-done",
         "--viz-rrd", str(rrd)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    rec = read_recording(rrd)
    assert len(rec["dvl/velocity"]) == 1721 == len(rec["dvl/bottom_lock"])
    # bottom lock logged per ensemble equals the codec's own reading of the file
    ens = [decode(f.data) for f in read_file_frames(Pd0Framer(), capture)]
    lock = [bool(np.all(np.isfinite(e.bottom_track.velocity))) for e in ens]
    logged = [float(np.ravel(v)[0]) for v in rec["dvl/bottom_lock"].values("Scalars:scalars")]
    assert sum(logged) == sum(lock)
