"""``python -m auvgw``: the same as the ``auvgw`` console script."""

import sys

from auvgw.cli import main

sys.exit(main())
