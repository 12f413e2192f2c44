"""Bus stages: processes (or in-process objects) that consume the gateway's decoded messages and
publish derived data on the bus (:mod:`auvgw.stages.fusion`: dead-reckoning odometry)."""
