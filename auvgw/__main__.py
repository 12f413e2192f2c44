"""``python -m auvgw``: the same as the ``auvgw`` console script."""

from auvgw.cli import entry

entry()
