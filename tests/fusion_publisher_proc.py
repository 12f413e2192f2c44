"""Publisher process of tests/commands/test_fusion_stage.py: gateway-style envelopes onto the bus.

``python fusion_publisher_proc.py --connect EP --vehicle V --file ENVELOPES.jsonl``: joins the
bus as a client of EP, waits for the fusion stage's liveliness token (its subscriptions are
declared before it), publishes every ``{"key": ..., "payload": hex}`` line in file order
(envelopes, ``CongestionControl.BLOCK`` so none is dropped), prints ``published N matched
KEYS`` (the keys that had a subscriber) and exits.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import zenoh

from auvgw.bus import Keys, json_encoding, open_session
from auvgw.config.bus import BusConfig


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--vehicle", required=True)
    ap.add_argument("--file", required=True)
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--match-timeout", type=float, default=3.0)
    args = ap.parse_args()
    lines = [json.loads(x) for x in Path(args.file).read_text().splitlines() if x]
    keys = Keys(args.vehicle)
    session = open_session(BusConfig(mode="client", connect=[args.connect]))
    try:
        deadline = time.monotonic() + args.timeout
        while not any(
            r.ok is not None
            for r in session.liveliness().get(keys.alive("fusion"), timeout=1.0)
        ):
            if time.monotonic() > deadline:
                print("no fusion stage", flush=True)
                return 1
            time.sleep(0.1)
        pubs: dict[str, zenoh.Publisher] = {}
        for item in lines:  # declare all first, and wait until each has a subscriber
            if item["key"] not in pubs:
                pubs[item["key"]] = session.declare_publisher(
                    item["key"],
                    encoding=json_encoding(item["type"]),
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
        # keys nobody subscribes to (a device the stage does not use) never match: give the
        # others --match-timeout seconds
        until = time.monotonic() + args.match_timeout
        while not all(p.matching_status.matching for p in pubs.values()):
            if time.monotonic() > until:
                break
            time.sleep(0.05)
        matched = sorted(k for k, p in pubs.items() if p.matching_status.matching)
        for item in lines:
            pubs[item["key"]].put(bytes.fromhex(item["payload"]))
        print(f"published {len(lines)} matched {','.join(matched)}", flush=True)
        time.sleep(0.5)  # let the last samples leave before the session closes
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
