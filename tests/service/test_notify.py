"""The gateway's notifier: every listener gets every message in order; a failing listener is
logged and does not keep the message from the others."""

from __future__ import annotations

import logging

import pytest

from auvgw.notify import Notifier


def test_listeners_in_order_failures_isolated_and_unsubscribe(caplog: pytest.LogCaptureFixture):
    n = Notifier()
    got: list[tuple[str, str, int, object]] = []
    n.subscribe(lambda d, t, m: got.append(("a", d, t, m)))

    def broken(d: str, t: int, m: object) -> None:
        raise RuntimeError(f"bug on {m}")

    remove_broken = n.subscribe(broken)
    n.subscribe(lambda d, t, m: got.append(("c", d, t, m)))
    assert len(n) == 3
    with caplog.at_level(logging.ERROR, logger="auvgw.notify"):
        assert n.notify("dvl", 7, ["m1", "m2"]) == 2
    assert got == [("a", "dvl", 7, "m1"), ("c", "dvl", 7, "m1"),
                   ("a", "dvl", 7, "m2"), ("c", "dvl", 7, "m2")]  # fmt: skip
    assert "bug on m1" in caplog.text and "bug on m2" in caplog.text
    remove_broken()
    got.clear()
    assert n.notify("ins", 8, ["m3"]) == 0 and len(n) == 2
    assert got == [("a", "ins", 8, "m3"), ("c", "ins", 8, "m3")]
    assert Notifier().notify("ins", 1, ["x"]) == 0
