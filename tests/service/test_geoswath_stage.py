"""The GeoSwath swath stage in-process: emulated pings in, XYZ 88 envelopes out on the swath
device's key, stamped with their reference ping's receive time, taken by the bathymetric stage
as a multibeam's swaths."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.drivers import kongsberg
from auvgw.drivers.geoswath import default_codec
from auvgw.envelope import decode_envelope
from auvgw.stages.bathymetric import BathymetricStage, BathymetricStageConfig, swath_soundings
from auvgw.stages.swath import SwathStage, SwathStageConfig
from auvgw.subscribe import envelope_message
from auvgw.testing.geoswath import survey_context

LAG_S = 0.35  # host receive time - device time of every ping (the stamps' offset)


def test_stage_publishes_swaths_the_bathymetric_stage_takes(tmp_path: Path) -> None:
    em = survey_context(tmp_path)
    codec = default_codec()
    out: list[tuple[str, bytes, int]] = []
    stage = SwathStage(
        SwathStageConfig(device="gs", processing={"frequency_hz": em.frequency}),
        on_publish=lambda key, payload, t_ns: out.append((key, payload, t_ns)),
    )
    try:
        for k in range(22):  # 5.5 s at 4 Hz, sides alternating
            for d in em.prepare(50.0 + k / em.rate_hz):
                ping = codec.decode_ping(d)
                t_recv = int((float(ping.header["ping_time"]) + LAG_S) * 1e9)
                stage.feed("gs", t_recv, ping)
                stage.feed("other", t_recv, ping)  # not the configured device: ignored
        assert len(out) == 4  # 6 swaths closed or open, the last 2 wait for the along window
        stage.flush()
    finally:
        em.close()
    assert len(out) == 6 and stage.stats.swaths == 6 and stage.stats.received == 22
    assert stage.stats.dropped["amplitude"] > 0 and stage.stats.dropped["median"] > 0
    bathy = BathymetricStage(BathymetricStageConfig(multibeam_device="gs_swath"))
    for key, payload, t_ns in out:
        assert key == "auv/auv1/sensor/gs_swath/xyz88"
        env = decode_envelope(payload, key)
        msg = envelope_message(env)
        assert isinstance(msg, kongsberg.XYZ88) and msg.n_beams == 141
        assert env.device == "gs_swath" and env.wire == "geoswath"
        # stamped with its reference ping's receive time, not the later ping that completed it
        assert env.t_recv_ns == t_ns
        assert t_ns * 1e-9 == pytest.approx(msg.device_time + LAG_S, abs=2e-3)
        # the stage's reading of it: the seabed under the swath, placed with the true pose
        across, along, depth = swath_soundings(msg)
        s = em.truth(msg.device_time - em.ctx.epoch)
        ch, sh = math.cos(msg.heading), math.sin(msg.heading)
        x, y = s.x + along * ch - across * sh, s.y + along * sh + across * ch
        err = depth - em.ctx.world.depth(x, y)
        assert len(err) > 120 and float(np.percentile(np.abs(err), 95)) < 0.2
        bathy.feed("gs_swath", t_ns, msg)
    assert bathy.stats.swaths == 6  # taken as the multibeam's swaths (waiting for odometry)


@pytest.mark.e2e
def test_swath_settings_are_checked() -> None:
    """A bad processing value is refused where the stage is configured, ``auvgw swath --set``
    in one line on stderr with exit code 2."""
    import subprocess
    import sys

    with pytest.raises(ValueError, match="n_bins"):
        SwathStageConfig(processing={"n_bins": 0}).swath_processing()
    res = subprocess.run([sys.executable, "-m", "auvgw", "swath", "--set", "bins=141"],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.strip().splitlines() == [
        "auvgw swath: error: --set: processing: SwathProcessing.__init__() got an unexpected "
        "keyword argument 'bins'"
    ]
