"""The SLAM outputs as declared messages (auvgw.slam.outputs): each one through the envelope and
back is the same message, its field map is the JSON document it replaced (NaN as null), and
``slam_output`` reads both forms and refuses anything else with the key in its error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from auvgw.bus import decode_envelope, encode_envelope
from auvgw.slam.outputs import BeaconRange, Cloud, Dem, LineSet, PointMap, PoseEstimate
from auvgw.subscribe import envelope_message, slam_output

RNG = np.random.default_rng(3)

MESSAGES = [
    PoseEstimate(1.0, 2.0, -3.0, 0.5, np.eye(3) * 0.1, RNG.normal(size=(5, 3)),
                 np.full(5, 0.2), 4.2, "vb-aufastslam"),
    PoseEstimate(1.5, 2.0, 3.0, -0.5, np.eye(2), dr=(1.0, 2.5), ping=3),
    PoseEstimate(2.0, 2.0, 3.0, 0.1, np.eye(3), t_mag=1.9),
    PointMap(1.0, np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, int)),
    PointMap(1.0, RNG.normal(size=(3, 2)), np.tile(np.eye(2), (3, 1, 1)), np.arange(3),
             LineSet(np.ones(2), np.zeros(2), np.tile(np.eye(2), (2, 1, 1)), np.ones((2, 2)),
                     np.zeros((2, 2))),
             LineSet(np.ones(1), np.ones(1), np.eye(2)[None]), (250.0, -250.0)),
    Dem(3.0, 2.0, -10.0, 4.0, np.array([[20.5, np.nan], [21.0, 22.25]]), 40, (2, 1)),
    Cloud(3.0, RNG.normal(size=(7, 3))),
    BeaconRange(4.0, 2.5, (1.0, 2.0, 3.0), 14.0, (12.5, 0.4), np.eye(2) * 0.3, 1.0, 2.0, 0.3),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip_through_the_envelope(msg) -> None:
    payload, enc = encode_envelope(msg, "slam-x", 4_000_000_000, 7)
    env = decode_envelope(payload, "auv/a/slam/x/y")
    assert str(enc).endswith(f"/{msg.TYPE}") and (env.device, env.seq) == ("slam-x", 7)
    back = envelope_message(env)
    assert back == msg and type(back) is type(msg)
    again, _ = encode_envelope(back, "slam-x", 4_000_000_000, 7)
    assert again == payload  # the same bytes


def test_the_field_map_is_the_json_it_replaced() -> None:
    payload, _ = encode_envelope(MESSAGES[5], "slam-bathymetric", 3_000_000_000, 1)
    body = slam_output(payload, "auv/a/slam/bathymetric/map")
    assert body == {
        "type": "SlamDem", "t": 3.0, "cell_m": 2.0, "x0": -10.0, "y0": 4.0,
        "depth": [[20.5, None], [21.0, 22.25]], "pings": 40, "loops": [2, 1],
    }  # fmt: skip
    json.dumps(body)  # JSON-ready
    pose = slam_output(encode_envelope(MESSAGES[1], "s", 1, 1)[0])
    assert (pose["x"], pose["dr"], pose["ping"], pose["particles"]) == (2.0, [1.0, 2.5], 3, None)


def test_slam_output_reads_json_and_refuses_the_rest() -> None:
    assert slam_output(b'{"t": 1.0, "x": 2.0, "y": 3.0}') == {"t": 1.0, "x": 2.0, "y": 3.0}
    with pytest.raises(ValueError, match="auv/a/slam/p/pose: not a JSON object"):
        slam_output(b'{"t": 1.0', "auv/a/slam/p/pose")
    with pytest.raises(ValueError, match="auv/a/slam/p/pose"):
        slam_output(b"\x93\x01\x02\x03", "auv/a/slam/p/pose")
