"""A subscriber process for the gateway tests: collects typed envelopes through
:class:`auvgw.subscribe.GatewaySubscriber` and writes them as JSON lines.

Prints ``READY`` once its subscription is known to the gateway (a status sample arrived, or, with
``--announce``, right after declaring its liveliness token), then ``DONE <n>`` at the end.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from auvgw.config.bus import BusConfig
from auvgw.drivers.spec import to_jsonable
from auvgw.subscribe import GatewaySubscriber


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicle", required=True)
    ap.add_argument("--mode", default="peer")
    ap.add_argument("--connect", action="append", default=[])
    ap.add_argument("--device", default=None)
    ap.add_argument("--count", type=int, required=True, help="stop after this many envelopes")
    ap.add_argument("--out", required=True)
    ap.add_argument("--first-timeout", type=float, default=60.0)
    ap.add_argument("--idle", type=float, default=20.0, help="stop when nothing came for this")
    ap.add_argument("--announce", default=None, help="declare alive/<NAME> instead of waiting")
    ap.add_argument("--raw", action="store_true", help="collect raw frames, not envelopes")
    args = ap.parse_args()

    bus = BusConfig(mode=args.mode, connect=args.connect)
    n = 0
    with GatewaySubscriber(args.vehicle, bus) as sub, open(args.out, "w") as out:
        stream = sub.stream(device=args.device, raw=args.raw)
        if args.announce:
            sub.announce(args.announce)
        elif not sub.wait_ready(30.0):
            print("NO GATEWAY", flush=True)
            return 3
        print("READY", flush=True)
        timeout = args.first_timeout
        while n < args.count:
            env = stream.get(timeout)
            if env is None:
                break
            timeout = args.idle
            if args.raw:
                rec = {
                    "key": env.key,
                    "seq": env.seq,
                    "t_recv_ns": env.t_recv_ns,
                    "offset": env.offset,
                    "data": env.data.hex(),
                }
                out.write(json.dumps(rec) + "\n")
                n += 1
                continue
            rec = {
                "key": env.key,
                "type": env.type,
                "device": env.device,
                "t_recv_ns": env.t_recv_ns,
                "seq": env.seq,
                "typed": env.message is not None,
                "msg": to_jsonable(env.message) if env.message is not None else env.body,
                "t_arrival_ns": time.time_ns(),
            }
            out.write(json.dumps(rec) + "\n")
            n += 1
        out.flush()  # every line is in the file before DONE is announced
        print(f"DONE {n} dropped={stream.dropped}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
