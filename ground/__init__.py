"""The ground floor: what every folder of the project imports (errors, paths, closing, geometry,
device time, processes). It imports nothing of the project, so every layer above may use it.

The layers, lowest first (a folder imports only from its own layer or below; the test
``tests/test_architecture.py`` checks it from the import graph): ``ground/``; ``drivers/`` and
``config/``; ``fusion/``, ``slam/`` and ``sim_devices/``; the service (``auvgw/``); the commands
(``auvgw/commands/``, ``auvgw/cli.py``).
"""

if __name__ != "auvgw.ground":
    raise ImportError(f"import auvgw.ground, not {__name__}: the folder is mapped (setup.py)")
