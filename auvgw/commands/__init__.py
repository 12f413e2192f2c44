"""Subcommands of the ``auvgw`` CLI: :data:`COMMANDS` names each one's module.

A command module defines ``register(subparsers)``, which adds its parser and sets
``func=run``; ``run(args) -> int`` is the exit code. The shared option helpers are in
:mod:`auvgw.commands.common`."""

#: command name -> (module, one-line help), in the order ``auvgw --help`` lists them. Only the
#: module of the command being run is imported, so ``auvgw --help`` imports none of them (no
#: Zenoh, numpy or scipy at start-up).
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": (
        "auvgw.commands.demo",
        "run the emulated vehicle, gateway, fusion, SLAM and Rerun recording (main job)",
    ),
    "decode": ("auvgw.commands.decode", "decode a capture file to JSON lines"),
    "router": (
        "auvgw.commands.router",
        "run a Zenoh router (for multi-process / multi-host buses)",
    ),
    "run": (
        "auvgw.commands.run",
        "run the gateway daemon (devices -> Zenoh) from a TOML configuration",
    ),
    "record": (
        "auvgw.commands.record",
        "record a vehicle's raw bus traffic (all devices, receive times) to an MCAP file",
    ),
    "replay": ("auvgw.commands.replay", "republish an MCAP recording (raw and decoded) as if live"),
    "verify": (
        "auvgw.commands.verify",
        "check recordings for damage (chunk CRCs, summary) and their signatures",
    ),
    "sign": ("auvgw.commands.sign", "sign recordings (Ed25519, FILE.mcap.sig) or make a key"),
    "export": (
        "auvgw.commands.export",
        "convert a recording of the earlier layout to the ROS 2 profile (--ros2)",
    ),
    "viz": ("auvgw.commands.viz", "log the bus to Rerun (a .rrd file or a running viewer)"),
    "sim": (
        "auvgw.commands.sim",
        "run the emulated vehicle (world + device emulators on virtual ports)",
    ),
    "fusion": (
        "auvgw.commands.fusion",
        "INS + DVL dead reckoning: odometry on the bus, or over a recording",
    ),
    "slam": ("auvgw.commands.slam", "SLAM tools: evaluation, and the SLAM stage (slam run)"),
    "slam-run": ("auvgw.commands.slam_run", "run the SLAM stage (same as 'slam run')"),
    "swath": (
        "auvgw.commands.swath",
        "GeoSwath raw pings -> swaths (XYZ 88) for the bathymetric SLAM, on the bus",
    ),
    "ros2": (
        "auvgw.commands.ros2",
        "the vehicle on ROS 2 (rmw_zenoh): bridge, list the graph, echo a topic",
    ),
    "foxglove": ("auvgw.commands.foxglove", "serve the bus to the Foxglove app (WebSocket)"),
    "pilot": ("auvgw.commands.pilot", "fly a mission file with the reference autopilot (--check)"),
}
