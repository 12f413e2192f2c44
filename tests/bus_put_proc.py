"""A publisher process for the access-control tests: one identity's session, putting on keys.

``python bus_put_proc.py BUS.toml NAME KEY [KEY ...]`` opens the session of the ``[bus]`` table
of BUS.toml (its own certificate), prints ``ready <zid>``, then until SIGTERM/SIGINT puts
``NAME-<n>`` on every KEY in the order given, round ``n`` = 1, 2, ... (one round per 20 ms).
Samples of one session travel in order, so a sample of round ``n`` seen on the last key means
the router has judged every earlier put of that round.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

from auvgw.bus import load_bus_table, open_session
from auvgw.commands.common import handle_stop_signals
from auvgw.config.bus import BusConfig


def main() -> int:
    toml, name, *keys = sys.argv[1:]
    bus = BusConfig(**load_bus_table(Path(toml))).rebased(Path(toml).resolve().parent)
    stop = threading.Event()
    with open_session(bus) as session, handle_stop_signals(stop):
        print(f"ready {session.zid()}", flush=True)
        n = 0
        while not stop.wait(0.02):  # pacing, not a wait for a condition
            n += 1
            for key in keys:
                session.put(key, f"{name}-{n}".encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
