"""Magnetic-beacon SLAM (AMB-SLAM, Hou et al. 2019): beacon demodulation, neural ranging and the
AMB-/MB-SLAM filters. Arrays in, arrays out: no transports, Zenoh or Rerun."""
