"""Configuration models and shipped configuration files (tables, DBCs, scenarios)."""
