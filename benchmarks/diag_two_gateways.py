"""Two gateways for one emulated vehicle on separate buses (the issue 27 defect); prints tables.

    .venv/bin/python benchmarks/diag_two_gateways.py [--seconds 14] [--after 5]

``auvgw sim`` serves the INS and the MS3A magnetometer, each on a pty and on an emulated SLCAN
adapter (``ins_can``, ``magnetometer_can``). A first ``auvgw run`` reads them all; a second,
from the same file but on a bus of its own (so the one-gateway check cannot see the first),
runs for ``--seconds`` and is stopped with SIGINT. Printed per device of the first gateway:
connects, outages and reopens at the end, frames in the ``--after`` seconds after the second
exited, and whether it is stale; then the lines of the second's log that name a lock. Before
issue 27 the second opened the SLCAN adapters too (no lock): the first's CAN devices flapped,
and once the second closed the adapters' channels (``C``) the CAN magnetometer stayed silent
for good while ``connected``. Run it on main and on a branch in one sitting.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from auvgw.config.bus import BusConfig
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import AUVGW, endpoint, free_port, wait_until

SCENARIO = {
    "name": "two-gateways",
    "seed": 5,
    "vehicle": {"waypoints": [[0, 0], [400, 0]], "speed_mps": 1.5, "depth_m": 5.0},
    "magnetic_beacons": [{"x": 30, "y": 10, "z": 20, "moment_am2": 500}],
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=14.0, help="how long the second runs (s)")
    p.add_argument("--after", type=float, default=5.0, help="watch this long after it exits (s)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "s.json").write_text(json.dumps(SCENARIO))
        sim = subprocess.Popen(
            [AUVGW, "sim", "--scenario", str(d / "s.json"), "--speed", "1", "--out", str(d / "sim"),
             "--devices", "ins,magnetometer", "--vehicle", "two", "--no-truth-log"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        procs = [sim]
        try:
            assert sim.stdout is not None
            while "running" not in sim.stdout.readline():
                pass
            cfg = str(d / "sim" / "gateway.toml")
            ep1, ep2 = endpoint(free_port()), endpoint(free_port())
            with open(d / "g1.err", "w") as e1, open(d / "g2.err", "w") as e2:
                first = subprocess.Popen([AUVGW, "run", "-c", cfg, "--listen", ep1], stderr=e1)
                procs.append(first)
                with GatewaySubscriber("two", BusConfig(connect=[ep1])) as me:

                    def flowing() -> bool:
                        st = me.status() or {}
                        devs = st.get("devices") or {}
                        return len(devs) == 4 and all(v["frames"] > 0 for v in devs.values())

                    wait_until(flowing, 60, what="the first gateway's four devices")
                    second = subprocess.Popen([AUVGW, "run", "-c", cfg, "--listen", ep2], stderr=e2)
                    procs.append(second)
                    time.sleep(args.seconds)  # (a diagnostic: the second runs this long)
                    second.send_signal(signal.SIGINT)
                    second.wait(30)
                    before = me.status()["devices"]
                    time.sleep(args.after)
                    after = me.status()["devices"]
            print(f"first gateway, {args.seconds:g} s with a second on its own bus, then "
                  f"{args.after:g} s after it exited (exit code {second.returncode}):")  # fmt: skip
            print(f"| device | connects | outages | reopens | frames in the {args.after:g} s after | stale |")  # noqa: E501
            print("|---|---:|---:|---:|---:|---|")
            for name in sorted(after):
                a, b = before[name], after[name]
                print(f"| {name} | {b['connects']} | {b['outages']} | {b.get('reopens', '-')} | "
                      f"{b['frames'] - a['frames']} | {b['stale']} |")  # fmt: skip
            locks = [ln for ln in (d / "g2.err").read_text().splitlines() if "locked" in ln]
            print(f"second gateway: {len(locks)} log line(s) naming a lock")
            for ln in locks[:4]:
                print("  " + ln.split(" WARNING ", 1)[-1][:160])
        finally:
            for proc in reversed(procs):
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
                    try:
                        proc.wait(30)
                    except subprocess.TimeoutExpired:
                        proc.kill()
                        proc.wait()


if __name__ == "__main__":
    main()
