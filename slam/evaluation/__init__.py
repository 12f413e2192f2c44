"""Evaluation of the landmark SLAM filters: Bailey's simulator from a scenario, Monte Carlo runs,
the papers' metrics and tables, plots."""
