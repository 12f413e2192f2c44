"""SLAM algorithms. They take arrays and messages only: no transports, Zenoh or Rerun."""
