"""Bathymetric particle-filter SLAM (Zhang et al. 2021, IEEE Access 9, "Bathymetric Particle
Filter SLAM Based on Mean Trajectory Map Representation"): the mean-trajectory-map particle
filter (MTM-PF), the paper's BPSLAM comparator and dead reckoning, on multibeam swaths.

Pure algorithms: arrays in, arrays out; no transports, Zenoh or Rerun. See
docs/slam_bathymetric.md for the method, parameters and results."""
