"""auvgw: hardware-in-the-loop sensor gateway for autonomous underwater vehicles."""

__version__ = "0.1.0"
