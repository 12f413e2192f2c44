"""Configuration models and shipped configuration files (tables, DBCs, scenarios)."""

if __name__ != "auvgw.config":
    raise ImportError(f"import auvgw.config, not {__name__}: the folder is mapped (setup.py)")
