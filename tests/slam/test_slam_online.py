"""The online landmark-SLAM pipeline without a bus (:class:`LandmarkOnline`) and the state
history it places pings with (:class:`StateHistory`)."""

from __future__ import annotations

import math
from dataclasses import asdict

import pytest

from auvgw.slam.history import StateHistory
from auvgw.slam.landmark.online import LandmarkOnline, LandmarkOnlineConfig
from auvgw.testing import slam_harbour

#: the emulated harbour run of the landmark SLAM stage (a module-scoped fixture)
harbour_run = slam_harbour.harbour_run


def test_history_interpolates_angles_the_short_way_and_trims():
    h = StateHistory(3, angles=(2,))
    assert h.at(0.0) is None and h.last_t is None
    assert h.append(0.0, (0.0, 0.0, math.pi - 0.1))
    assert h.append(1.0, (2.0, -4.0, -math.pi + 0.1))  # across +-pi: 0.2 rad, not 2 pi - 0.2
    assert not h.append(1.0, (9.0, 9.0, 0.0))  # not after the newest: refused
    mid = h.at(0.5)
    assert mid is not None
    assert mid[:2] == pytest.approx([1.0, -2.0])
    assert abs(abs(mid[2]) - math.pi) < 1e-12
    q = h.at(0.75)
    assert q is not None and q[2] == pytest.approx(-math.pi + 0.05)
    assert h.at(-0.1) is None
    first = h.at(-0.1, hold_first=True)
    assert first is not None and first[2] == pytest.approx(math.pi - 0.1)
    last = h.at(5.0)
    assert last is not None and last[:2] == pytest.approx([2.0, -4.0])
    for k in range(2, 10):
        h.append(float(k), (float(k), 0.0, 0.0))
    h.trim(6.5)
    assert h.first_t == 6.0 and len(h) == 4  # the state just before 6.5 stays
    with pytest.raises(ValueError, match="3"):
        h.append(20.0, (1.0, 2.0))


@pytest.mark.e2e
def test_pipeline_without_a_bus_gives_the_stage_estimates(harbour_run):
    """The pure pipeline fed the harbour run gives the very poses the stage published, and its
    counters are the stage's."""
    *_, stage, published, events, cfg = harbour_run
    online = LandmarkOnline(LandmarkOnlineConfig(**cfg.model_dump(
        include=set(LandmarkOnlineConfig.model_fields))))  # fmt: skip
    due = 0
    for ev in events:
        if ev[0] == "odometry":
            due += online.add_odometry(ev[1])
        elif ev[1] == "msis":
            online.add_ping(ev[2] / 1e9, ev[3])
    assert online.finish() == online.track[-1][0]
    assert due + 1 == len(online.track)
    assert online.track == stage.track
    poses = [b for k, b, _ in published if k.endswith("/pose")]
    assert [p["x"] for p in poses] == [x for _, x, _, _ in online.track]
    c = stage.counters()["stage"]
    for k, v in asdict(online.stats).items():
        assert c[k] == v, k
    assert online.stats.updates >= 3 and online.summary()["landmarks"] >= 3
    body = online.landmarks_message(online.track[-1][0])
    assert body.mean.shape == (online.summary()["landmarks"], 2)


@pytest.mark.e2e
def test_pings_wait_for_the_odometry_that_covers_them(harbour_run):
    """A ping ahead of the odometry is held (not placed with a stale pose); one older than
    the whole odometry history is counted and dropped; too many waiting drop the oldest."""
    *_, events, _ = harbour_run
    odo = [e[1] for e in events if e[0] == "odometry"][:50]
    pings = [(e[2] / 1e9, e[3]) for e in events if e[0] == "message" and e[1] == "msis"]
    online = LandmarkOnline(LandmarkOnlineConfig(max_pending_pings=3))
    for t, m in pings[:5]:
        online.add_ping(t + odo[0].t + 100.0, m)  # far ahead of any odometry
    assert online.stats.pings_dropped == 2 and online.stats.pings == 0
    online.add_odometry(odo[0])
    online.add_ping(odo[0].t - 1.0, pings[0][1])  # before the history: dropped
    assert online.stats.pings_before_odometry == 1 and online.stats.pings == 0
    online.add_ping(odo[0].t, pings[0][1])  # covered: used at once
    assert online.stats.pings == 1
