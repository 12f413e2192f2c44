"""Maps the design card's top-level folders into the single ``auvgw`` import namespace.

``drivers/`` is ``auvgw.drivers``, ``fusion/`` is ``auvgw.fusion`` and so on; subpackages are
found by walking each folder, so adding one needs no edit here.
"""

from pathlib import Path

from setuptools import find_packages, setup

ROOTS = {
    "auvgw": "auvgw",
    "auvgw.ground": "ground",
    "auvgw.drivers": "drivers",
    "auvgw.fusion": "fusion",
    "auvgw.slam": "slam",
    "auvgw.sim_devices": "sim_devices",
    "auvgw.control": "control",
    "auvgw.config": "config",
    # the test house: tests and benchmarks import it without editing sys.path
    "auvgw.testing": "tests/support",
}

packages: list[str] = []
package_dir: dict[str, str] = {}
for name, folder in ROOTS.items():
    packages.append(name)
    package_dir[name] = folder
    for sub in find_packages(where=folder):
        packages.append(f"{name}.{sub}")
        package_dir[f"{name}.{sub}"] = str(Path(folder, *sub.split(".")))

setup(
    packages=packages,
    package_dir=package_dir,
    package_data={
        "auvgw.config": [
            "*.toml", "vehicles/*.toml", "missions/*.toml", "*.dbc", "*.json", "scenarios/*.json",
            "security/*.toml",
        ]
    },
    include_package_data=True,
)
