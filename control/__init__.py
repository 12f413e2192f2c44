"""The reference autopilot (pure: numpy and the dynamics model, no transports).

:mod:`~auvgw.control.mission` (waypoints, legs, lawnmower, mission files),
:mod:`~auvgw.control.autopilot` (ILOS guidance, heading/depth/speed loops, aborts) and
:mod:`~auvgw.control.closed_loop` (the autopilot flying the 6-DOF model in-process).
"""

if __name__ != "auvgw.control":
    raise ImportError(f"import auvgw.control, not {__name__}: the folder is mapped (setup.py)")
