"""The GeoSwath in Rerun: emulated raw pings through the Rerun stage (in-process and as bus
envelopes) beside the swaths the swath stage makes of them, read back from a real ``.rrd``: the
raw-ping entity of each side holds the latest ping's samples at plausible angles and ranges, and
the layout shows it next to the swath view. The sample times count wavelengths, so the ranges
hold only with the model's frequency: it comes from the gateway configuration the emulator
writes (``[devices.<name>.geoswath] model_khz``, what ``auvgw run --viz-rrd`` reads)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from auvgw.config.gateway import parse_gateway_config
from auvgw.drivers.geoswath import default_codec
from auvgw.envelope import encode_envelope
from auvgw.sim_devices.runner import gateway_config
from auvgw.stages.swath import SwathStage, SwathStageConfig
from auvgw.testing.geoswath import survey_context
from auvgw.viz import entities as ent
from auvgw.viz.blueprint import RAW_PING_VIEW
from auvgw.viz.logger import RerunLogger, VizOptions
from auvgw.viz.options import gateway_viz_options
from auvgw.viz.readback import read_layouts, read_recording
from auvgw.viz.stage import VizStage

LAG_S = 0.2  # host receive time - device time of every ping
MAX_SAMPLES = 1500


def test_raw_pings_beside_the_swath_in_a_recording(tmp_path: Path) -> None:
    em = survey_context(tmp_path, {"model_khz": 500})  # 95 m range: about 4000 samples a ping
    codec = default_codec()
    rrd = tmp_path / "gs.rrd"
    gw_cfg = parse_gateway_config(gateway_config(em.endpoints()))
    (gs,) = gw_cfg.devices  # the emulator's device, its model (500 kHz, not the default 250)
    assert gw_cfg.devices[gs].geoswath is not None
    assert gw_cfg.devices[gs].geoswath.frequency_hz == em.frequency == 500_000
    opts = gateway_viz_options(gw_cfg, VizOptions(raw_ping_period_s=0.9,
                               raw_ping_max_samples=MAX_SAMPLES, time_kind="duration"))  # fmt: skip
    logger = RerunLogger(rrd=rrd, options=opts)
    viz = VizStage(logger, "auv1")
    swath = SwathStage(
        SwathStageConfig(device=gs, processing={"frequency_hz": em.frequency}),
        on_publish=lambda key, payload, t_ns: viz.handle_sample(key, payload, t_ns),
    )
    pings = []
    try:
        for k in range(14):  # 3.5 s at 4 Hz, sides alternating
            for d in em.prepare(50.0 + k / em.rate_hz):
                ping = codec.decode_ping(d)
                pings.append(ping)
                t_ns = int((float(ping.header["ping_time"]) + LAG_S) * 1e9)
                swath.feed(gs, t_ns, ping)
                if k % 2:  # the starboard pings as bus envelopes, the port ones in-process
                    payload, _ = encode_envelope(ping, gs, t_ns, k, wire="geoswath")
                    assert viz.handle_sample(f"auv/auv1/sensor/{gs}/geoswathping", payload,
                                             t_ns) == "logged"  # fmt: skip
                else:
                    assert viz.on_message(gs, t_ns, ping) == "logged"
        swath.flush()
    finally:
        em.close()
        logger.close()
    assert swath.stats.swaths >= 3 and logger.stats().errors == 0 and viz.stats.errors == 0
    rec = read_recording(rrd)
    assert len(rec[ent.SOUNDINGS].times) > 0  # the processed swaths
    c = float(pings[0].arrays["minisvs"]["velocity"][0])
    for side, name in ((0, "port"), (1, "starboard")):
        rows = rec[f"{ent.RAW_PING}/{gs}/{name}"]
        # one view per 0.9 device s of each side's 2 Hz pings: 50, 51, 52, 53 (+ offset)
        assert len(rows.times) == 4
        xy = np.asarray(rows.values("Points2D:positions")[-1], dtype=np.float64)
        colours = rows.values("Points2D:colors")[-1]
        last = [p for p in pings if int(p.header["side"]) == side][-1]  # the latest ping shown
        n = last.count("raa")
        assert len(xy) == len(colours) == len(range(0, n, math.ceil(n / MAX_SAMPLES)))
        angle, rng = xy[:, 0], xy[:, 1]
        # angles within the fan, nearly all on the ping's side (port negative: the others are
        # water-column noise), ranges within the ping's listening time
        sgn = 1.0 if side == 1 else -1.0
        assert np.all(np.abs(angle) <= 90.0) and np.mean(sgn * angle > 0.0) > 0.9
        max_range = c * float(last.header["ping_length"]) / 2000.0  # ping_length in ms
        assert 0.0 < rng.max() <= max_range + 0.5 and rng.min() >= 0.0
        # the samples' own geometry: the strong returns lie on the seabed under the vehicle
        # (slant range x cos angle = the altitude the ping's ECHO record gives, +- 15 % on the
        # survey's slopes), the weak ones before it are the water column
        strong = np.asarray(last.arrays["raa"]["amplitude"], float)[:: math.ceil(n / MAX_SAMPLES)]
        seabed = (strong > 2000.0) & (np.abs(angle) > 10.0) & (np.abs(angle) < 60.0)
        alt = float(last.arrays["echo"]["depth1"][0])
        depth = rng[seabed] * np.cos(np.radians(angle[seabed]))
        assert seabed.sum() > 100 and abs(float(np.median(depth)) - alt) < 0.15 * alt
    # the layout, re-sent once the first raw ping came: the raw-ping view on its entities,
    # beside the swath & bathymetry view; the first layout had none
    layouts = [{name: (cls, origin) for cls, name, origin in v} for v in read_layouts(rrd)]
    assert len(layouts) == 2
    (raw,) = [v for v in layouts if RAW_PING_VIEW in v]
    assert raw[RAW_PING_VIEW] == ("2D", ent.RAW_PING)
    assert raw["Swath & bathymetry (NED m, colour = depth)"] == ("3D", ent.WORLD)


def test_the_gateway_device_names_its_model(tmp_path: Path) -> None:
    """``[devices.<name>.geoswath] model_khz``: the frequency the broadcast ping does not carry
    (the Rerun stage's raw-ping ranges); 250 kHz when left out, a wrong model named, and the
    table refused on another format."""
    from auvgw.config.gateway import load_gateway_config
    from auvgw.ground.errors import ConfigError
    from auvgw.viz.options import gateway_viz_options

    udp = '[devices.{name}.transport]\nkind = "udp"\nport = {port}\n'
    head = 'vehicle = "auv1"\n'

    def write(body: str) -> Path:
        p = tmp_path / "gw.toml"
        p.write_text(head + body)
        return p

    cfg = load_gateway_config(write(
        '[devices.gs1]\nformat = "geoswath"\n[devices.gs1.geoswath]\nmodel_khz = 500\n'
        + udp.format(name="gs1", port=47001)
        + '[devices.gs2]\nformat = "geoswath"\n' + udp.format(name="gs2", port=47002)
    ))  # fmt: skip
    assert gateway_viz_options(cfg).geoswath_frequencies_hz == {"gs1": 500e3, "gs2": 250e3}
    with pytest.raises(ConfigError, match=r"gs1.*geoswath.*model_khz"):
        load_gateway_config(write(
            '[devices.gs1]\nformat = "geoswath"\n[devices.gs1.geoswath]\nmodel_khz = 300\n'
            + udp.format(name="gs1", port=47001)
        ))  # fmt: skip
    with pytest.raises(ConfigError, match="'geoswath' only applies to format 'geoswath'"):
        load_gateway_config(write(
            '[devices.mb]\nformat = "kongsberg"\n[devices.mb.geoswath]\nmodel_khz = 250\n'
            + udp.format(name="mb", port=47003)
        ))  # fmt: skip
