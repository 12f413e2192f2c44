"""The in-process demo's truth-log follower: every sample once, in order, with two pollers."""

from __future__ import annotations

import json
import threading
from pathlib import Path

from auvgw.commands.demo_parts import _TruthTail


def test_two_pollers_feed_every_sample_once_in_order(tmp_path: Path) -> None:
    """The demo polls from its main loop and from the INS reader that starts dead reckoning; a
    line written in pieces is fed once it is whole."""
    path = tmp_path / "truth.jsonl"
    path.write_text("")
    fed: list[float] = []
    tail = _TruthTail(path, lambda s: fed.append(s["t"]))
    n = 2000
    done = threading.Event()

    def poll_until_done() -> None:
        while not done.is_set():
            tail.poll()

    pollers = [threading.Thread(target=poll_until_done) for _ in range(2)]
    for p in pollers:
        p.start()
    with path.open("a", buffering=1) as fh:
        for i in range(n):
            line = json.dumps({"t": i / 10, "x": 0.0, "y": 0.0, "heading": 0.0}) + "\n"
            fh.write(line[:7])  # a partial line first: not fed until its end arrives
            fh.flush()
            fh.write(line[7:])
    done.set()
    for p in pollers:
        p.join()
    tail.poll()
    assert fed == [i / 10 for i in range(n)]
    assert tail.t == (n - 1) / 10
