"""Emulated vehicle: world model, one emulator per device, virtual ports, fault injection."""

if __name__ != "auvgw.sim_devices":
    raise ImportError(f"import auvgw.sim_devices, not {__name__}: the folder is mapped (setup.py)")
