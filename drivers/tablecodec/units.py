"""Table units and the decoded (SI) units they convert to."""

from __future__ import annotations

import math

_G0 = 9.80665
_DEG = math.pi / 180.0

#: table units -> (decoded units, factor). Decoded units are SI, except magnetic flux density,
#: which the project carries in nT.
UNITS: dict[str, tuple[str, float]] = {
    "": ("", 1.0),
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "us": ("s", 1e-6),
    "rad": ("rad", 1.0),
    "mrad": ("rad", 1e-3),
    "urad": ("rad", 1e-6),
    "deg": ("rad", _DEG),
    "rad/s": ("rad/s", 1.0),
    "mrad/s": ("rad/s", 1e-3),
    "deg/s": ("rad/s", _DEG),
    "m/s^2": ("m/s^2", 1.0),
    "mm/s^2": ("m/s^2", 1e-3),
    "g": ("m/s^2", _G0),
    "mg": ("m/s^2", _G0 * 1e-3),
    "m/s": ("m/s", 1.0),
    "cm/s": ("m/s", 1e-2),
    "mm/s": ("m/s", 1e-3),
    "m": ("m", 1.0),
    "cm": ("m", 1e-2),
    "mm": ("m", 1e-3),
    "nT": ("nT", 1.0),
    "uT": ("nT", 1e3),
    "T": ("nT", 1e9),
    "G": ("nT", 1e5),
    "mG": ("nT", 1e2),
}


def si_units(units: str) -> tuple[str, float]:
    """``(decoded units, factor)`` for table units ``units``; KeyError when unknown."""
    return UNITS[units]
