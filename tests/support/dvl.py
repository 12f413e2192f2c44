"""The emulated Pathfinder DVL of the tests: a scenario (a vehicle that turns, follows the terrain
and crabs in a current; :data:`BASE`) with one DVL, and the emulator run offline (no clock, no
port) beside its ground truth; shared by tests/sim_devices/test_dvl_emulator.py and
tests/service/test_envelope_bytes.py."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from auvgw.config.scenario import Scenario
from auvgw.sim_devices.clock import SimClock
from auvgw.sim_devices.closedloop import ClosedLoopTruth
from auvgw.sim_devices.dvl import DvlEmulator
from auvgw.sim_devices.emulator import SimContext
from auvgw.sim_devices.vehicle import Truth, simulate
from auvgw.sim_devices.world import World

__all__ = ["BASE", "offline", "scenario"]

#: a vehicle that turns (roll), follows the terrain (pitch, heave) and crabs in a current (sway)
BASE: dict[str, Any] = {
    "name": "dvl-test",
    "seed": 5,
    "duration_s": 120.0,
    "vehicle": {
        "waypoints": [[0, 0], [70, 0], [70, 50], [0, 50]],
        "speed_mps": 1.5,
        "altitude_m": 12.0,
        "max_yaw_rate_dps": 12.0,
        "accept_radius_m": 3.0,
        "lookahead_m": 6.0,
        "current_mps": [0.2, -0.15],
    },
    "terrain": {"kind": "procedural", "depth_m": 30.0, "relief_m": 4.0, "wavelength_m": 40.0,
                "octaves": 2, "seed": 4},
}


def scenario(dvl: dict[str, Any] | None = None, **changes: Any) -> Scenario:
    """:data:`BASE` with top-level keys replaced and one device ``dvl`` (its options'
    ``serial`` off unless given)."""
    data = copy.deepcopy(BASE)
    data.update(changes)
    dvl = dict(dvl or {})
    dvl.setdefault("options", {})
    dvl["options"] = {"serial": False, **dvl["options"]}
    data["devices"] = {"dvl": dvl}
    return Scenario.model_validate(data)


def offline(
    scn: Scenario, tmp_path: Path
) -> tuple[DvlEmulator, Truth | ClosedLoopTruth, World]:
    """The emulator without a clock or a port (``frame_at(t)`` gives the bytes of one ping),
    and the ground truth at any time."""
    world = World.from_scenario(scn)
    truth = simulate(scn, world)
    ctx = SimContext(scn, world, truth, SimClock(0), tmp_path / "ports")
    return DvlEmulator(ctx), ctx.truth, world
