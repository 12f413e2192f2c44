"""The closed loop across processes: ``auvgw sim`` (closed-loop scenario: the REMUS 100 dynamics
driven by the emulated actuators' CAN controller) and ``auvgw run`` in their own processes, this
process on the bus as the "autopilot": it reads the INS the gateway publishes and publishes
``ActuatorCommand`` envelopes on ``auv/<v>/cmd/actuators``; the gateway checks them and sends
them over the SLCAN adapter to the controller, whose state drives the vehicle.

A proportional-derivative heading / pitch hold written here (not the project's autopilot)
holds the heading, then a 30 deg setpoint change turns the vehicle as the INS reports it; bad
commands are refused and counted; a jammed rudder (the sim's fault control file) shows in the
feedback's fault word. Waits on samples and counters, never on fixed sleeps."""

from __future__ import annotations

import json
import math
import time

import numpy as np

from auvgw.bus import Keys
from auvgw.config.bus import BusConfig
from auvgw.drivers.actuators import COMMAND_TYPE, FAULT_BITS, actuators_can, fault_names
from auvgw.envelope import encode_envelope
from auvgw.subscribe import GatewaySubscriber
from auvgw.testing import AUVGW, REPO, endpoint, free_port, wait_matched, wait_until

SCENARIO = REPO / "config" / "scenarios" / "closed_loop.json"
SPEED = 2.0
DEG = math.pi / 180


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class Pilot:
    """The test's heading / pitch hold: one command per 5 INS samples (20 Hz)."""

    def __init__(self, session, keys: Keys) -> None:
        self.pub = session.declare_publisher(keys.cmd("actuators"))
        self.cmd = actuators_can().types[COMMAND_TYPE]
        self.seq = 0
        self.href = 0.0
        self.n = 0
        self.headings: list[float] = []

    def put(self, msg) -> None:
        self.pub.put(encode_envelope(msg, "pilot", time.time_ns(), self.seq)[0])

    def on_ins(self, m) -> None:
        self.headings.append(m.heading)
        self.n += 1
        if self.n % 5:
            return
        rud = float(np.clip(_wrap(m.heading - self.href) + 4 * m.rate_z, -0.35, 0.35))
        stern = float(np.clip(m.pitch + 4 * m.rate_y, -0.35, 0.35))
        self.seq = (self.seq + 1) % 65536
        self.put(self.cmd(seq=self.seq, shaft_rpm=1000.0, rudder=rud, stern=stern))


def test_bus_commands_steer_the_emulated_vehicle(procs, tmp_path) -> None:
    out = tmp_path / "sim"
    sim = procs.start(
        [AUVGW, "sim", "--scenario", str(SCENARIO), "--speed", str(SPEED), "--duration", "200",
         "--out", str(out), "--no-truth-log", "--start-delay", "4"],
        "sim",
    )  # fmt: skip
    sim.wait_line("gateway config:", 60)
    ep = endpoint(free_port())
    procs.gateway(out / "gateway.toml", "gateway", "--listen", ep)
    keys = Keys("auv1")
    with GatewaySubscriber("auv1", BusConfig(connect=[ep])) as me:
        ins = me.stream("ins", "ins")
        fb = me.stream("actuators", "actuatorstate")
        pilot = Pilot(me.session, keys)
        assert me.wait_ready(60)
        wait_matched(pilot.pub)
        wait_until(lambda: (me.status("actuators") or {}).get("connected"), 60, what="CAN up")

        def settled(href: float, last_s: float, tol_deg: float) -> bool:
            h = pilot.headings[-int(last_s * 100) :]
            return len(h) == int(last_s * 100) and all(
                abs(_wrap(x - href)) < tol_deg * DEG for x in h
            )

        def fly_until(cond, max_vehicle_s: float, what: str) -> None:
            for _ in range(int(max_vehicle_s * 10)):
                fly(0.1)
                if cond():
                    return
            tail = np.degrees(pilot.headings[-100:]).round(1)
            raise AssertionError(f"{what}: not within {max_vehicle_s} vehicle s; {tail}")

        def fly(vehicle_s: float) -> None:
            n = int(vehicle_s * 100)  # INS at 100 Hz
            for _ in range(n):
                env = ins.get(10)
                assert env is not None, "INS stopped"
                pilot.on_ins(env.message)

        for _ in ins.iter(0):  # what came while waiting: old news to a controller
            pass
        # the pilot takes over whenever the processes are up: the vehicle may have started to
        # depart (open-loop unstable; the thruster stopped 1 s after vehicle time 0 by the
        # command timeout, so it slows down). It holds the heading the vehicle has, taken
        # again every vehicle second, until the vehicle keeps it for 2 s
        fly(0.05)
        pilot.href = pilot.headings[-1]
        for k in range(300):
            fly(0.1)
            if settled(pilot.href, 2.0, 3.0):
                break
            if k % 10 == 9:
                pilot.href = pilot.headings[-1]
        else:
            raise AssertionError(f"no straight flight in 30 vehicle s: {pilot.headings[-100:]}")
        start = pilot.href
        for _ in range(6):  # the setpoint turns 30 deg at 5 deg/s
            pilot.href = _wrap(pilot.href + 5 * DEG)
            fly(1.0)
        # the INS says it turned 30 deg and stays there
        fly_until(lambda: settled(start + 30 * DEG, 1.0, 4.0), 20.0, "the 30 deg turn")

        # the controller applied the pilot's commands: its feedback echoes their sequence
        states = [e.message for e in fb.iter(0)]  # what has arrived (it keeps coming)
        assert states and pilot.seq - 5 <= states[-1].cmd_seq <= pilot.seq
        assert all(s.faults == 0 for s in states[-20:])

        # bad commands are refused and counted, never forwarded
        st0 = me.status("actuators")["commands"]
        pilot.put(pilot.cmd(seq=pilot.seq, shaft_rpm=1000.0, rudder=0.0, stern=0.0))  # stale
        pilot.put(pilot.cmd(seq=pilot.seq + 1, shaft_rpm=9999.0, rudder=0.0, stern=0.0))
        pilot.pub.put(b"\x93not an envelope")
        st = wait_until(
            lambda: (c := me.status("actuators")["commands"])["out_of_range"] > st0["out_of_range"]
            and c, 20, what="refusals counted",
        )  # fmt: skip
        assert st["stale_seq"] == st0["stale_seq"] + 1
        assert st["out_of_range"] == st0["out_of_range"] + 1
        st = wait_until(lambda: (c := me.status("actuators")["commands"])["malformed"] and c, 20,
                        what="the malformed one counted")  # fmt: skip
        assert st["forwarded"] >= pilot.seq - 2 and st["malformed"] == 1
        dev = me.status("actuators")
        assert dev["bad_frames"] == 0 and dev["decode_errors"] == 0
        assert dev["messages"]["ActuatorState"] >= len(states)

        # a jammed rudder (fault control file of the sim): the fault word says so
        (out / "faults.json").write_text(json.dumps({"actuators": {"rudder_jam": [[0, 1e6]]}}))

        def jammed():
            fly(0.1)
            return any(e.message.faults & FAULT_BITS["rudder_jammed"] for e in fb.iter(0))

        wait_until(jammed, 30, interval=0, what="rudder_jammed in the fault word")
        fly(0.5)
        last = [e.message for e in fb.iter(0)][-1]
        assert "rudder_jammed" in fault_names(last.faults)
