"""Zenoh's send queue per link (``[bus] tx_queue_batches``): Zenoh's default of two 64 KiB batches
per priority overflowed under a burst of multibeam pings while its sending thread waited for a
CPU, and a ``CongestionControl.DROP`` sample was dropped after 1 ms (docs/bus.md, Payloads)."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from auvgw.bus import zenoh_config
from auvgw.config.bus import TX_QUEUE_BATCHES, BusConfig


def queue_sizes(cfg: BusConfig) -> dict[str, int]:
    return json.loads(zenoh_config(cfg).get_json("transport/link/tx/queue/size"))


def test_the_data_priorities_queue_the_configured_batches_and_control_keeps_zenohs():
    default = queue_sizes(BusConfig())
    assert TX_QUEUE_BATCHES == 16
    assert {p: default[p] for p in ("data_high", "data", "data_low")} == dict.fromkeys(
        ("data_high", "data", "data_low"), 16)  # fmt: skip
    assert default["control"] == default["real_time"] == 2  # Zenoh's own, untouched
    assert queue_sizes(BusConfig(tx_queue_batches=3))["data"] == 3


@pytest.mark.parametrize("bad", [0, 65, 2.5])
def test_a_queue_out_of_range_is_refused(bad):
    with pytest.raises(ValidationError, match="tx_queue_batches"):
        BusConfig(tx_queue_batches=bad)
