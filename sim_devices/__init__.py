"""Emulated vehicle: world model, one emulator per device, virtual ports, fault injection."""
