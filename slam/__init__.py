"""SLAM algorithms. They take arrays and messages only: no transports, Zenoh or Rerun."""

if __name__ != "auvgw.slam":
    raise ImportError(f"import auvgw.slam, not {__name__}: the folder is mapped (setup.py)")
