"""Subcommands of the ``auvgw`` CLI."""
